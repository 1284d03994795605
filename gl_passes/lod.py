"""Levels of detail of a scene object for the cluster depth images (§4.5, beyond the
thesis; issue 17): meshoptimizer's simplifier (gl_passes.reconstruction.simplify,
absolute error bound) run on the object's surface rather than on its vertex list.

Two things in real meshes stop the simplifier when it is given their vertices as
they are: a hard edge (a book, a tile) splits a corner into one vertex per face
normal, which it keeps as a seam, and a double-sided sheet (a curtain, a leaf) has
each face twice with opposite windings, whose shared corners it must lock. So the
positions are welded first and each copy of a doubled face goes to its own side,
simplified on its own; every corner of a simplified triangle then takes, among the
object's vertices at that position, the one whose normal is closest to the
triangle's (the side's copy of the corner, the face's normal at a hard edge), so
the levels index the scene's own vertex buffer and shade as the original does.
"""

from __future__ import annotations

import numpy as np

from gl_passes.reconstruction import simplify


def occurrence_rank(keys: np.ndarray) -> np.ndarray:
    """(n,) int: for each row of keys (n, k), how many equal rows come before it."""
    if not len(keys):
        return np.zeros(0, np.int64)
    _, group = np.unique(keys, axis=0, return_inverse=True)
    group = group.ravel()
    order = np.argsort(group, kind="stable")
    sorted_group = group[order]
    starts = np.r_[0, np.flatnonzero(np.diff(sorted_group)) + 1]
    rank = np.empty(len(keys), np.int64)
    rank[order] = np.arange(len(keys)) - np.repeat(starts, np.diff(np.r_[starts, len(keys)]))
    return rank


def closest_normal_vertices(weld: np.ndarray, normals: np.ndarray, corners: np.ndarray,
                            face_normals: np.ndarray) -> np.ndarray:
    """(m, 3) vertex indices: per corner (welded position id, corners (m, 3)) the
    vertex at that position (weld (V,): position id of each vertex) whose normal
    (normals (V, 3)) has the largest dot product with its face's normal (m, 3)."""
    order = np.argsort(weld, kind="stable")
    counts = np.bincount(weld)
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    slot = np.arange(len(weld)) - np.repeat(starts, counts)
    table = np.full((len(counts), int(counts.max())), -1, np.int64)
    table[weld[order], slot] = order
    cand = table[corners]  # (m, 3, G)
    dots = np.einsum("mcgk,mk->mcg", normals[np.maximum(cand, 0)], face_normals)
    dots[cand < 0] = -np.inf
    return np.take_along_axis(cand, dots.argmax(axis=2)[..., None], axis=2)[..., 0]


def lod_faces(vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray, max_error: float) -> np.ndarray:
    """(M, 3) uint32 faces over the object's vertices (V, 3) / normals (V, 3): the
    surface of faces (F, 3) simplified with an absolute error of at most max_error
    (world units) as measured by meshoptimizer, welded and sided as the module says."""
    if not len(faces):
        return np.zeros((0, 3), np.uint32)
    positions, weld = np.unique(np.asarray(vertices, np.float32), axis=0, return_inverse=True)
    weld = weld.ravel()
    welded = weld[np.asarray(faces, np.int64)]
    side = occurrence_rank(np.sort(welded, axis=1))
    parts = [simplify(positions, welded[side == s], max_error).astype(np.int64) for s in range(int(side.max()) + 1)]
    tri = np.concatenate(parts)
    if not len(tri):
        return np.zeros((0, 3), np.uint32)
    p = positions.astype(np.float64)[tri]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return closest_normal_vertices(weld, np.asarray(normals, np.float64), tri, n).astype(np.uint32)

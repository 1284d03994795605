"""Quad splats: a reconstruction's isolated quads drawn as point sprites in shadow
maps (thesis Alg. 5 over Alg. 4's meshes; beyond the thesis).

A depth-image sample that no neighbour joins (a grass blade a pixel wide, a twig
seen across) becomes a quad of its own, two triangles sharing a diagonal. Drawn
as triangles it costs a vertex-bound rasteriser four vertices and two triangle
setups per shadow map; as a splat it costs one vertex and one point. The splat's
vertex stage projects the quad's four corners into the map, sizes a point sprite
to hold their window box, and its fragment stage keeps a texel only where its
centre lies in either triangle, at that triangle's plane depth
(shaders/shadow_splat.*): the same texels and depths as the triangles, up to the
rasteriser's tie rule on edges.

An isolated quad is a piece of exactly two triangles (found by vertex use counts:
the diagonal's two vertices used by those two triangles alone, each other corner
by one of them). Only quads at most SPLAT_PIXELS across in the capturing image
are splats, which keeps every sprite small in a shadow map of the same order of
resolution; the shader clamps a sprite at the implementation's largest point.
"""

from __future__ import annotations

import moderngl
import numpy as np

from gl_passes.context import GLContext
from gl_passes.indexed import IndexedBuffers

#: Largest extent (x or y, pixels of the capturing image) of a quad made a splat.
SPLAT_PIXELS = 4.0
#: Bytes per splat: four vec3 corners (s0, s1, o0, o1).
SPLAT_BYTES = 48


def isolated_quads(triangles: np.ndarray) -> np.ndarray:
    """(Q,2) indices into `triangles` (M,3) of the pairs that form isolated quads:
    two triangles sharing an edge whose vertices no other triangle uses, and whose
    other corners only the one triangle uses. Each triangle is in at most one pair."""
    tri = np.asarray(triangles, np.int64).reshape(-1, 3)
    if len(tri) < 2:
        return np.zeros((0, 2), np.int64)
    use = np.bincount(tri.ravel())
    u = use[tri]
    cand = np.flatnonzero((np.sort(u, axis=1) == (1, 2, 2)).all(axis=1))
    # the two vertices each candidate shares, as one key
    shared = np.sort(np.where(u[cand] == 2, tri[cand], -1), axis=1)[:, 1:]
    key = shared[:, 0] * len(use) + shared[:, 1]
    order = np.argsort(key, kind="stable")
    ks = key[order]
    first = np.flatnonzero(ks[1:] == ks[:-1])  # a vertex of use 2 is in two triangles: no key thrice
    return np.stack([cand[order[first]], cand[order[first + 1]]], axis=1)


def quad_corners(positions: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """(Q,4,3) float32 corners s0, s1 (the shared diagonal), o0, o1 (the other corner
    of the first and of the second triangle) of `quads` (Q,2,3), triangle pairs of
    `isolated_quads` as vertex indices into `positions` (N,3)."""
    q = np.asarray(quads, np.int64).reshape(-1, 2, 3)
    a, b = q[:, 0], q[:, 1]
    in_b = (a[:, :, None] == b[:, None, :]).any(axis=2)  # (Q,3): a's vertices that b shares
    in_a = (b[:, :, None] == a[:, None, :]).any(axis=2)
    rows = np.arange(len(q))
    shared = np.sort(np.where(in_b, a, -1), axis=1)[:, 1:]
    idx = np.column_stack([shared, a[rows, np.argmin(in_b, axis=1)], b[rows, np.argmin(in_a, axis=1)]])
    return np.asarray(positions, np.float32)[idx]


def split_quads(triangles: np.ndarray, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(body (M−2Q,3), quads (Q,2,3)) of `triangles` (M,3): the isolated quads at
    most SPLAT_PIXELS across apart (in the input order of their first triangles),
    the other triangles in theirs. pixels: (N,2) the vertices' pixel coordinates
    in the capturing image."""
    tri = np.asarray(triangles).reshape(-1, 3)
    pairs = isolated_quads(tri)
    px = np.asarray(pixels, np.float64)[tri[pairs].reshape(-1, 6)]  # (Q,6,2)
    small = (px.max(axis=1) - px.min(axis=1)).max(axis=1, initial=0.0) <= SPLAT_PIXELS
    pairs = pairs[small]
    pairs = pairs[np.argsort(pairs[:, 0], kind="stable")]
    body = np.ones(len(tri), bool)
    body[pairs.ravel()] = False
    return tri[body], tri[pairs]


class QuadSplats(IndexedBuffers):
    """Isolated quads on the GPU as splats: one vertex of four vec3 corners per quad
    (`quad_corners`), no index buffer. `draw(prog, instances)` draws them as points
    with the splat program (shadow_splat.vert/.frag). Owns its buffer: call `release()`."""

    def __init__(self, gl: GLContext, corners: np.ndarray) -> None:
        data = np.ascontiguousarray(corners, np.float32).reshape(-1, 12)
        super().__init__(gl, gl.ctx.buffer(data.tobytes() or b"\0" * SPLAT_BYTES), None)
        self.count = len(data)

    def vertex_format(self, prog: moderngl.Program) -> tuple[str, ...]:
        return ("3f 3f 3f 3f", "in_s0", "in_s1", "in_o0", "in_o1")

    def draw(self, prog: moderngl.Program, instances: int = 1) -> None:
        """Draw every splat with the splat program `prog`, `instances` times."""
        self.gl.check_thread()
        if self.count:
            self.vao(prog).render(moderngl.POINTS, vertices=self.count, instances=instances)


__all__ = ["SPLAT_PIXELS", "QuadSplats", "isolated_quads", "quad_corners", "split_quads"]

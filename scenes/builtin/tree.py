"""Tree: a branching trunk of closed tapered cylinders and many two-sided leaves.

Stands in for the thesis's tree scene (§2.3.3 with Tables 2–7: 11.3 万 = 113k triangles), the
hardest scene for depth-image sampling (most disocclusion, §3.4). The skeleton has five
levels: trunk (≈3.2 m) → 6 limbs → 30 branches → 150 shoots → twigs, each a curved
capped tube (``geometry.tubes``; 12, 10, 8, 6, 4 sides) starting inside its parent.
Leaves are two-sided diamond quads (4 triangles, 10–17 cm long) on the shoots and twigs.
Twigs (600) and leaves (22 800) are proportional to detail; the three upper skeleton
levels are fixed, so triangles ≈ 10k + 103k × detail. The tree is about 7.3 m tall
with a crown about 5–6 m across, on a modest ground disc (``geometry.footprint_disc``:
diameter 1.4 × the tree's footprint, ≈ 8 m, 48 triangles) so that the tree and not a
ground plane fills views framed on the scene (thesis Fig. 8/9).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenes.builtin import geometry as g
from scenes.model import Material, Scene

DESCRIPTION = "tree: 5-level branching skeleton of closed cylinders with ~23k two-sided leaves (thesis §2.3.3, 113k)"

# (count or count per detail, segments, sides) per level; level 4 (twigs) scales with detail
_LEVELS = ((1, 8, 12), (6, 6, 10), (30, 4, 8), (150, 3, 6), (600, 2, 4))
LEAVES_PER_DETAIL = 22800
GROUND_SCALE = 1.4  # ground disc diameter / tree footprint
GROUND_SEGMENTS = 48

_BARK = Material(albedo=(0.30, 0.22, 0.16))
_LEAF_A = Material(albedo=(0.13, 0.36, 0.08))
_LEAF_B = Material(albedo=(0.24, 0.44, 0.10))
_GROUND = Material(albedo=(0.33, 0.30, 0.22))


def _level_counts(detail: float) -> list[int]:
    return [c for c, _, _ in _LEVELS[:-1]] + [g.scaled_count(_LEVELS[-1][0], detail)]


def estimate_triangles(detail: float) -> int:
    branches = sum(n * g.tube_triangles(k, s) for n, (_, k, s) in zip(_level_counts(detail), _LEVELS, strict=True))
    return branches + 4 * g.scaled_count(LEAVES_PER_DETAIL, detail) + g.disc_triangles(GROUND_SEGMENTS)


@dataclass
class _Branches:
    """One level: start (n,3), unit direction (n,3), bend (n,3), length (n,), radius
    at start and end (n,). Centre line p(s) = start + L·(s·d + s²/2·bend), s ∈ [0,1]."""

    start: np.ndarray
    direction: np.ndarray
    bend: np.ndarray
    length: np.ndarray
    r0: np.ndarray
    r1: np.ndarray

    def point(self, idx: np.ndarray, s: np.ndarray) -> np.ndarray:
        s = s[:, None]
        return self.start[idx] + self.length[idx, None] * (s * self.direction[idx] + 0.5 * s**2 * self.bend[idx])

    def tangent(self, idx: np.ndarray, s: np.ndarray) -> np.ndarray:
        t = self.direction[idx] + s[:, None] * self.bend[idx]
        return t / np.linalg.norm(t, axis=1, keepdims=True)

    def radius(self, idx: np.ndarray, s: np.ndarray) -> np.ndarray:
        return self.r0[idx] + (self.r1[idx] - self.r0[idx]) * s

    def paths(self, segments: int) -> np.ndarray:
        n = len(self.length)
        s = np.linspace(0.0, 1.0, segments + 1)
        idx = np.repeat(np.arange(n), segments + 1)
        return self.point(idx, np.tile(s, n)).reshape(n, segments + 1, 3)

    def radii(self, segments: int) -> np.ndarray:
        s = np.linspace(0.0, 1.0, segments + 1)
        return self.r0[:, None] + (self.r1 - self.r0)[:, None] * s[None, :]


def _random_perpendicular(t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    u, w = g.orthonormal_basis(t)
    a = rng.uniform(0.0, 2.0 * np.pi, len(t))
    return np.cos(a)[:, None] * u + np.sin(a)[:, None] * w


def _children(parent: _Branches, n: int, angle: tuple[float, float], length_ratio: float, s_range: tuple[float, float],
              rng: np.random.Generator) -> _Branches:
    idx = rng.integers(0, len(parent.length), n) if n >= len(parent.length) else rng.permutation(len(parent.length))[:n]
    idx = np.sort(idx, kind="stable")
    s = rng.uniform(*s_range, n)
    t = parent.tangent(idx, s)
    perp = _random_perpendicular(t, rng)
    a = rng.uniform(*angle, n)
    d = np.cos(a)[:, None] * t + np.sin(a)[:, None] * perp
    d[:, 1] += 0.25  # grow slightly upward
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    length = parent.length[idx] * length_ratio * (1.15 - 0.5 * s) * rng.uniform(0.8, 1.2, n)
    bend = rng.normal(0.0, 0.25, (n, 3)) + np.array([0.0, 0.15, 0.0])  # gentle curve, upward
    r_parent = parent.radius(idx, s)
    r0 = r_parent * rng.uniform(0.55, 0.75, n)
    start = parent.point(idx, s) - d * r_parent[:, None] * 0.5  # start inside the parent
    return _Branches(start, d, bend, length, r0, r0 * 0.55)


def _skeleton(detail: float, rng: np.random.Generator) -> list[_Branches]:
    trunk = _Branches(start=np.array([[0.0, -0.1, 0.0]]), direction=np.array([[0.0, 1.0, 0.0]]),
                      bend=np.array([[0.06, 0.0, -0.04]]), length=np.array([3.3]), r0=np.array([0.28]),
                      r1=np.array([0.17]))
    counts = _level_counts(detail)
    specs = (((0.6, 1.0), 1.05, (0.5, 1.0)), ((0.5, 1.0), 0.7, (0.2, 1.0)),
             ((0.5, 1.0), 0.6, (0.15, 1.0)), ((0.4, 1.0), 0.55, (0.1, 1.0)))
    levels = [trunk]
    for n, (angle, ratio, s_range) in zip(counts[1:], specs, strict=True):
        levels.append(_children(levels[-1], n, angle, ratio, s_range, rng))
    return levels


def _leaves(levels: list[_Branches], n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(n,3) leaf base points and (n,3,3) leaf frames [lateral, along, normal]."""
    shoots, twigs = levels[3], levels[4]
    on_twig = rng.random(n) < 0.7
    pts = np.empty((n, 3))
    tan = np.empty((n, 3))
    for mask, lv in ((on_twig, twigs), (~on_twig, shoots)):
        k = int(mask.sum())
        idx = rng.integers(0, len(lv.length), k)
        s = rng.uniform(0.25, 1.0, k)
        pts[mask] = lv.point(idx, s)
        tan[mask] = lv.tangent(idx, s)
    perp = _random_perpendicular(tan, rng)
    a = rng.uniform(0.5, 1.1, n)
    along = np.cos(a)[:, None] * tan + np.sin(a)[:, None] * perp
    along[:, 1] -= 0.35  # droop
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    up = np.array([0.0, 1.0, 0.0]) + rng.normal(0.0, 0.5, (n, 3))
    lat = np.cross(along, up)
    ln = np.linalg.norm(lat, axis=1, keepdims=True)
    bad = ln[:, 0] < 1e-6
    if np.any(bad):
        lat[bad], _ = g.orthonormal_basis(along[bad])
        ln[bad] = 1.0
    lat /= ln
    normal = np.cross(lat, along)
    return pts, np.stack([lat, along, normal], axis=2)  # columns


# leaf template in its own frame: x lateral, y along the leaf, z its front normal
_LEAF = g.as_mesh(np.array([[0.0, 0.0, 0.0], [0.5, 0.35, 0.0], [0.0, 1.0, 0.0], [-0.5, 0.35, 0.0]]),
                np.array([[0, 1, 2], [0, 2, 3]]))


def build(detail: float, rng: np.random.Generator) -> Scene:
    levels = _skeleton(detail, rng)
    bark = g.merge([g.tubes(lv.paths(k), lv.radii(k), sides)
                    for lv, (_, k, sides) in zip(levels, _LEVELS, strict=True)])
    n_leaves = g.scaled_count(LEAVES_PER_DETAIL, detail)
    pts, frames = _leaves(levels, n_leaves, rng)
    size = rng.uniform(0.10, 0.17, n_leaves)
    scales = np.column_stack([0.5 * size, size, np.ones(n_leaves)])
    shade = rng.random(n_leaves) < 0.5
    leaves = []
    for name, mask, mat in (("leaves_dark", ~shade, _LEAF_A), ("leaves_light", shade, _LEAF_B)):
        if np.any(mask):
            leaves.append((name, g.instances(_LEAF, pts[mask], frames[mask], scales[mask]), mat))
    leaf_meshes = [mesh for _, mesh, _ in leaves]
    ground = g.footprint_disc([bark, *leaf_meshes], GROUND_SCALE, GROUND_SEGMENTS)
    objects = [g.make_object("ground", ground, _GROUND), g.make_object("branches", bark, _BARK)]
    objects += [g.make_object(name, mesh, mat, double_sided=True) for name, mesh, mat in leaves]
    lo, hi = g.scene_bounds([ground, bark, *leaf_meshes])
    return Scene(objects=objects, sun_direction=(0.35, 0.8, 0.45),
                 area_light=g.overhead_area_light(lo, hi, fraction=0.25), name="tree")

"""Triangle chunks: the unit of view-dependent culling of a scene's draws.

Each object's triangles (a contiguous range of one index buffer) are split into
runs of at most `size` triangles, each with its AABB and its normal cone. A chunk
whose box lies outside the view frustum, or whose every triangle faces away from
the eye (so GL's back-face culling would discard each), is skipped; the visible
chunks of one object that follow each other are drawn as one run. Skipping never
changes a pixel: it drops only triangles the rasteriser would have discarded.
Used by the G-buffer pass (SceneGPU.draw with a camera) and by the cluster depth
images (gl_passes.reflections).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from functools import cached_property

import numpy as np

#: Triangles per chunk (a balance between culling grain and draw calls).
CHUNK = 512
#: The 8 corners of a box as (x, y, z) picks of (min, max).
_CORNERS = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], bool)


@dataclass(frozen=True)
class ChunkTable:
    """Per chunk (n,): obj (0-based object), first (first face in the index
    buffer), count (faces), bounds (n, 2, 3) AABB min/max in world units, cones
    (n, 8) normal cones (chunk_cones)."""

    obj: np.ndarray
    first: np.ndarray
    count: np.ndarray
    bounds: np.ndarray
    cones: np.ndarray

    def __len__(self) -> int:
        return len(self.first)

    @cached_property
    def corners(self) -> np.ndarray:
        """(n, 8, 3) the boxes' corners (box_corners), computed once per table."""
        return box_corners(self.bounds)


def chunk_table(vertices: np.ndarray, faces: np.ndarray, ranges: list[tuple[int, int]],
                size: int = CHUNK) -> ChunkTable:
    """Chunks of `faces` (F, 3) indexing `vertices` (V, 3), object k owning the
    rows ranges[k] = (first, count), in runs of at most `size` triangles."""
    obj, first, count = [], [], []
    for k, (f0, n) in enumerate(ranges):
        for a in range(0, n, size):
            obj.append(k)
            first.append(f0 + a)
            count.append(min(size, n - a))
    first_a = np.asarray(first, np.int64)
    if len(first_a):
        tri = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]  # (F,3,3)
        lo = np.minimum.reduceat(tri.min(axis=1), first_a, axis=0)
        hi = np.maximum.reduceat(tri.max(axis=1), first_a, axis=0)
    else:
        lo = hi = np.zeros((0, 3))
    return ChunkTable(obj=np.asarray(obj, np.int64), first=first_a, count=np.asarray(count, np.int64),
                      bounds=np.stack([lo, hi], axis=1).astype(np.float64),
                      cones=chunk_cones(vertices, faces, first_a))


def chunk_cones(vertices: np.ndarray, faces: np.ndarray, first: np.ndarray) -> np.ndarray:
    """(n, 8) per run of triangles starting at `first` (a run ends where the next
    begins, the last at len(faces)): c (3), the centre of its AABB; a (3), the unit
    mean of its triangles' geometric normals n_i (counter-clockwise winding, the GL
    front face); ε = max |n_i − a|; m = min n_i·(v0_i − c) (scene units). A
    zero-area triangle is never rasterised and bounds neither ε nor m."""
    v = np.asarray(vertices, np.float64)
    tri = v[np.asarray(faces, np.int64)]  # (F,3,3)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1)
    live = length > 0
    n = np.where(live[:, None], n / np.maximum(length, 1e-300)[:, None], 0.0)
    first = np.asarray(first, np.int64)
    if len(first) == 0:
        return np.zeros((0, 8))
    lo = np.minimum.reduceat(tri.min(axis=1), first, axis=0)
    hi = np.maximum.reduceat(tri.max(axis=1), first, axis=0)
    c = 0.5 * (lo + hi)
    a = np.add.reduceat(n, first, axis=0)
    a /= np.maximum(np.linalg.norm(a, axis=1), 1e-300)[:, None]
    run = np.repeat(np.arange(len(first)), np.diff(np.append(first, len(tri))))
    dev = np.where(live, np.linalg.norm(n - a[run], axis=1), 0.0)
    off = np.where(live, np.einsum("ij,ij->i", n, tri[:, 0] - c[run]), np.inf)
    eps = np.maximum.reduceat(dev, first)
    m = np.minimum.reduceat(off, first)
    return np.concatenate([c, a, eps[:, None], m[:, None]], axis=1)


def box_corners(bounds: np.ndarray) -> np.ndarray:
    """(n, 8, 3) corners of boxes (n, 2, 3) (min, max)."""
    b = np.asarray(bounds, np.float64)
    return np.where(_CORNERS[None], b[:, 1][:, None, :], b[:, 0][:, None, :])


def boxes_in_frustum(view_proj: np.ndarray, bounds: np.ndarray, corners: np.ndarray | None = None) -> np.ndarray:
    """(n,) bool: boxes (n, 2, 3) that may intersect the frustum of the 4×4
    `view_proj` (culled when all 8 corners are outside one clip-space plane);
    corners: their box_corners when already at hand (ChunkTable.corners)."""
    corners = box_corners(bounds) if corners is None else corners
    vp = np.asarray(view_proj, np.float64)
    hom = corners @ vp[:, :3].T + vp[:, 3]
    x, y, z, w = (hom[..., k] for k in range(4))
    out = (np.all(x < -w, 1) | np.all(x > w, 1) | np.all(y < -w, 1) | np.all(y > w, 1)
           | np.all(z < -w, 1) | np.all(z > w, 1))
    return ~out


def facing_away(eye: np.ndarray, cones: np.ndarray) -> np.ndarray:
    """(n,) bool: runs of triangles (chunk_cones) all of whose triangles face away
    from the point `eye`, so back-face culling (GL_BACK, ccw front) discards every
    one of them: n_i·(v0_i − e) = n_i·(v0_i − c) + n_i·(c − e) ≥ m + a·(c − e) −
    ε·|c − e| > 0. Conservative (false only costs a draw)."""
    if len(cones) == 0:
        return np.zeros(0, bool)
    d = cones[:, :3] - np.asarray(eye, np.float64)
    bound = cones[:, 7] + np.einsum("ij,ij->i", cones[:, 3:6], d) - cones[:, 6] * np.linalg.norm(d, axis=1)
    return bound > 1e-6 * np.maximum(np.linalg.norm(d, axis=1), 1e-12)


def nearest_first(bounds: np.ndarray, sel: np.ndarray, point: np.ndarray) -> np.ndarray:
    """The chunk indices `sel` ordered by the distance of their boxes (bounds: (n, 2, 3)
    min/max) from `point`, nearest first (0 inside a box; ties keep their order)."""
    sel = np.asarray(sel, np.int64)
    p = np.asarray(point, np.float64)
    lo, hi = bounds[sel, 0], bounds[sel, 1]
    return sel[np.argsort(np.linalg.norm(np.clip(p, lo, hi) - p, axis=1), kind="stable")]


def runs(table: ChunkTable, sel: np.ndarray) -> Iterator[tuple[int, int, int]]:
    """(object, first face, face count) of the runs of consecutive chunks in `sel`
    (chunk indices in drawing order; ascending stretches of one object each make
    one run): one draw per run."""
    sel = np.asarray(sel, np.int64)
    if len(sel) == 0:
        return
    obj = table.obj[sel]
    # a run starts at the first chunk, after a gap in the indices and at a change of object
    start = np.flatnonzero(np.r_[True, (np.diff(sel) != 1) | (obj[1:] != obj[:-1])])
    last = sel[np.r_[start[1:] - 1, len(sel) - 1]]
    first = table.first[sel[start]]
    count = table.first[last] + table.count[last] - first
    yield from zip(obj[start].tolist(), first.tolist(), count.tolist(), strict=True)

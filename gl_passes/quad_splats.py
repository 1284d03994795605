"""Quad splats: the triangles of a reconstruction's small pieces drawn as point
sprites in shadow maps (thesis Alg. 5 over Alg. 4's meshes; beyond the thesis).

A depth-image sample that no neighbour joins (a grass blade a pixel wide, a twig
seen across) becomes a quad of its own, two triangles sharing a diagonal, and a
few joined samples a piece of a few quads. Drawn as triangles such a piece costs
a vertex-bound rasteriser about as many vertices as triangles and more per
shadow map; as splats it costs one vertex and one point per quad. The splat's
vertex stage projects the quad's four corners into the map, sizes a point sprite
to hold their window box, and its fragment stage keeps a texel only where its
centre lies in either triangle, at that triangle's plane depth
(shaders/shadow_splat.*): the same texels and depths as the triangles, up to the
rasteriser's tie rule on edges (a texel centre on an edge two splats, or a splat
and a triangle, share is kept by both, at the same depth).

The triangles of pieces (connected through shared vertices) of at most
SPLAT_PIECE triangles are matched in pairs that share an edge (quads); a triangle
left over is a splat on its own (its corners a, b, c, c). Only splats at most
SPLAT_PIXELS across in the capturing image are made, which keeps every sprite
small in a shadow map of the same order of resolution; the shader clamps a
sprite at the implementation's largest point. SPLAT_PIECE is the bench's choice
(bench/results/soft_shadows.md, Fig. 20).
"""

from __future__ import annotations

import moderngl
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from gl_passes.context import GLContext
from gl_passes.indexed import IndexedBuffers

#: Largest extent (x or y, pixels of the capturing image) of a splat.
SPLAT_PIXELS = 4.0
#: Pieces of at most this many triangles are drawn as splats.
SPLAT_PIECE = 64
#: Bytes per splat: four vec3 corners (s0, s1, o0, o1).
SPLAT_BYTES = 48


def triangle_pieces(triangles: np.ndarray) -> np.ndarray:
    """(M,) int the piece of each of `triangles` (M,3): triangles joined through
    shared vertex indices share a label (labels need not be consecutive)."""
    tri = np.asarray(triangles, np.int64).reshape(-1, 3)
    if len(tri) == 0:
        return np.zeros(0, np.int64)
    n = int(tri.max()) + 1
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]]])
    graph = coo_matrix((np.ones(len(edges), np.int8), (edges[:, 0], edges[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1][tri[:, 0]]


def splat_pairs(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(pairs (P,2), singles (L,)) indices into `triangles` (M,3) of the triangles in
    pieces (connected through shared vertices) of at most SPLAT_PIECE triangles:
    matched in pairs that share an edge (quads, s0–s1 their diagonal), greedily
    (each triangle pairs with the lowest-numbered free neighbour that picks it back,
    round by round: a maximal matching), the rest on their own."""
    tri = np.asarray(triangles, np.int64).reshape(-1, 3)
    m = len(tri)
    if m == 0:
        return np.zeros((0, 2), np.int64), np.zeros(0, np.int64)
    n = int(tri.max()) + 1
    piece = triangle_pieces(tri)
    small = np.flatnonzero(np.bincount(piece)[piece] <= SPLAT_PIECE)
    # the edges two small triangles share (an edge of three or more triangles pairs none)
    ends = np.sort(tri[small][:, [0, 1, 1, 2, 2, 0]].reshape(-1, 3, 2), axis=2).reshape(-1, 2)
    key = ends[:, 0] * n + ends[:, 1]
    order = np.argsort(key, kind="stable")
    owner = np.repeat(small, 3)[order]
    _, start, count = np.unique(key[order], return_index=True, return_counts=True)
    twice = start[count == 2]
    a, b = owner[twice], owner[twice + 1]
    partner = np.full(m, -1, np.int64)
    while len(a):
        src, dst = np.concatenate([a, b]), np.concatenate([b, a])
        by = np.lexsort((dst, src))
        first = by[np.r_[True, src[by][1:] != src[by][:-1]]]
        pick = np.full(m, -1, np.int64)
        pick[src[first]] = dst[first]
        mutual = np.flatnonzero((pick >= 0) & (pick[np.maximum(pick, 0)] == np.arange(m)))
        partner[mutual] = pick[mutual]
        free = (partner[a] < 0) & (partner[b] < 0)
        a, b = a[free], b[free]
    lo = small[(partner[small] > small)]
    return np.stack([lo, partner[lo]], axis=1), small[partner[small] < 0]


def quad_corners(positions: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """(Q,4,3) float32 corners s0, s1 (the shared diagonal), o0, o1 (the other corner
    of the first and of the second triangle) of `quads` (Q,2,3), triangle pairs
    sharing an edge as vertex indices into `positions` (N,3)."""
    q = np.asarray(quads, np.int64).reshape(-1, 2, 3)
    a, b = q[:, 0], q[:, 1]
    in_b = (a[:, :, None] == b[:, None, :]).any(axis=2)  # (Q,3): a's vertices that b shares
    in_a = (b[:, :, None] == a[:, None, :]).any(axis=2)
    rows = np.arange(len(q))
    shared = np.sort(np.where(in_b, a, -1), axis=1)[:, 1:]
    idx = np.column_stack([shared, a[rows, np.argmin(in_b, axis=1)], b[rows, np.argmin(in_a, axis=1)]])
    return np.asarray(positions, np.float32)[idx]


def splat_corners(positions: np.ndarray, quads: np.ndarray, singles: np.ndarray) -> np.ndarray:
    """(Q+L,4,3) float32 corners of the splats of `quads` (Q,2,3) (`quad_corners`)
    and of the lone triangles `singles` (L,3) (a, b, c, c: the second triangle is
    the first again)."""
    lone = np.asarray(singles, np.int64).reshape(-1, 3)[:, [0, 1, 2, 2]]
    return np.concatenate([quad_corners(positions, quads), np.asarray(positions, np.float32)[lone]])


def split_splats(triangles: np.ndarray, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(body (M−2Q−L,3), quads (Q,2,3), singles (L,3)) of `triangles` (M,3): the
    splats of `splat_pairs` at most SPLAT_PIXELS across apart (each in the input
    order of its first triangle), the other triangles in theirs. pixels: (N,2) the
    vertices' pixel coordinates in the capturing image."""
    tri = np.asarray(triangles).reshape(-1, 3)
    pairs, singles = splat_pairs(tri)

    def small(rows: np.ndarray) -> np.ndarray:
        px = np.asarray(pixels, np.float64)[tri[rows].reshape(rows.shape[0], 3 * rows.shape[1])]  # (S,3|6,2)
        return rows[(px.max(axis=1) - px.min(axis=1)).max(axis=1, initial=0.0) <= SPLAT_PIXELS]

    pairs = small(pairs)
    pairs = pairs[np.argsort(pairs[:, 0], kind="stable")]
    singles = np.sort(small(singles[:, None])[:, 0])
    body = np.ones(len(tri), bool)
    body[pairs.ravel()] = False
    body[singles] = False
    return tri[body], tri[pairs], tri[singles]


class QuadSplats(IndexedBuffers):
    """Splats on the GPU: one vertex of four vec3 corners per splat (`splat_corners`),
    no index buffer; `triangles`: how many of the mesh's triangles they stand for.
    `draw(prog, instances)` draws them as points with the splat program
    (shadow_splat.vert/.frag). Owns its buffer: call `release()`."""

    def __init__(self, gl: GLContext, corners: np.ndarray, triangles: int) -> None:
        data = np.ascontiguousarray(corners, np.float32).reshape(-1, 12)
        super().__init__(gl, gl.ctx.buffer(data.tobytes() or b"\0" * SPLAT_BYTES), None)
        self.count, self.triangles = len(data), int(triangles)

    def vertex_format(self, prog: moderngl.Program) -> tuple[str, ...]:
        return ("3f 3f 3f 3f", "in_s0", "in_s1", "in_o0", "in_o1")

    def draw(self, prog: moderngl.Program, instances: int = 1) -> None:
        """Draw every splat with the splat program `prog`, `instances` times."""
        self.gl.check_thread()
        if self.count:
            self.vao(prog).render(moderngl.POINTS, vertices=self.count, instances=instances)


__all__ = ["SPLAT_PIECE", "SPLAT_PIXELS", "QuadSplats", "quad_corners", "splat_corners", "splat_pairs", "split_splats",
           "triangle_pieces"]

"""Quad splats: the triangles of a reconstruction's small pieces rasterised by a
compute pass in shadow maps (thesis Alg. 5 over Alg. 4's meshes; beyond the thesis).

A depth-image sample that no neighbour joins (a grass blade a pixel wide, a twig
seen across) becomes a quad of its own, two triangles sharing a diagonal, and a
few joined samples a piece of a few quads. Drawn as triangles such a piece costs
a software rasteriser a vertex stage, a clip test and a triangle setup per
triangle and map, all on one thread (llvmpipe runs only the fragment stage on
several); each texel-sized quad then covers a texel or so. A compute pass
(`SplatRaster`, shaders/shadow_splat.comp) runs one invocation per quad and map
on every thread: it projects the quad's four corners into the map and keeps, for
every texel centre in either triangle, that triangle's plane depth by an atomic
min in an integer depth image; a pass over the tile rows of the batch then writes
those depths into the depth atlas through the depth test, emptying the image as
it reads it (shadow_splat_resolve.frag). That pass is a fixed cost per batch: a
batch with few splats for its texels draws their triangles instead
(`ShadowSettings.splat_raster_min`, `SplatRaster.pays`). The same texels
and depths as the triangles, up to the rasteriser's tie rule on edges and its
sub-pixel snapping of the vertices (a texel centre on an edge two splats, or a
splat and a triangle, share is kept by both, at the same depth).

The triangles of pieces (connected through shared vertices) of at most
SPLAT_PIECE triangles are matched in pairs that share an edge (quads); a triangle
left over is a splat on its own (its corners a, b, c, c). Only splats at most
SPLAT_PIXELS across in the capturing image are made, which keeps every splat a
few texels across in a shadow map of the same order of resolution (the compute
pass loops over the texels of its box). SPLAT_PIECE is set by hand, not swept: the
reconstructions' lone samples and small clusters fall below it, their large
continuous patches far above (Fig. 20 reports the share of triangles drawn as splats).
"""

from __future__ import annotations

import moderngl
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from gl_passes.bindings import Units
from gl_passes.context import GLContext
from gl_passes.releasable import Releasable, ReleasedOnError
from gl_passes.shaders import compute_program, program

#: Largest extent (x or y, pixels of the capturing image) of a splat.
SPLAT_PIXELS = 4.0
#: Pieces of at most this many triangles are drawn as splats.
SPLAT_PIECE = 64
#: Bytes per splat: four vec3 corners (s0, s1, o0, o1).
SPLAT_BYTES = 48
#: local_size_x of shadow_splat.comp, local_size_x/y of shadow_splat_clear.comp, and
#: the most work groups per dispatch row.
RASTER_GROUP = 64
CLEAR_GROUP = 16
MAX_GROUPS = 65535
#: The splat depth image's empty texel (above every depth's bits: 1.0 is 0x3f800000).
EMPTY_DEPTH = "0xFFFFFFFFu"
#: Units of the splat shaders (gl_passes.bindings).
SPLAT_UNITS = Units(images=("splat_depth",), storage=("splats",))


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


def splats_last(triangles: np.ndarray, pixels: np.ndarray) -> tuple[np.ndarray, int, int]:
    """(triangles (M,3), quads Q, singles L): `triangles` in the order
    `MeshGPU.from_records` reads splats from, the body (`split_splats`) first, then
    the Q quads' triangles in pairs, then the L lone triangles. pixels: as for
    `split_splats`."""
    body, quads, singles = split_splats(triangles, pixels)
    return np.concatenate([body, quads.reshape(-1, 3), singles]), len(quads), len(singles)


class QuadSplats(Releasable):
    """Splats on the GPU: a storage buffer of four vec3 corners per splat
    (`splat_corners`, 12 float32), read by `SplatRaster`; `triangles`: how many of
    the mesh's triangles they stand for. Owns its buffer: call `release()`."""

    def __init__(self, gl: GLContext, corners: np.ndarray, triangles: int) -> None:
        gl.check_thread()
        data = np.ascontiguousarray(corners, np.float32).reshape(-1, 12)
        self.gl = gl
        self.buffer = gl.ctx.buffer(data.tobytes() or b"\0" * SPLAT_BYTES)
        self.count, self.triangles = len(data), int(triangles)

    @property
    def nbytes(self) -> int:
        """Bytes of the storage buffer."""
        return self.buffer.size

    def release(self) -> None:
        self.gl.check_thread()
        self.buffer.release()


class SplatRaster(Releasable):
    """The compute rasteriser of quad splats into a batch of shadow maps laid out as
    `tiles`² tiles of `res`² texels (the depth atlas of `gl_passes.shadows`): one
    integer depth image of the atlas's size, made at the first batch it draws splats in.
    Per batch: `begin(light_vp, maps)`, `draw(splats)` for each splat set, then
    `resolve(fbo)` into the depth atlas bound for drawing. Its fixed cost per batch,
    the resolve's pass over the batch's tile rows, is what `pays` weighs. Owns the image: call
    `release()`."""

    def __init__(self, gl: GLContext, batch: int, tiles: int, res: int) -> None:
        gl.check_thread()
        self.gl, self.batch, self.tiles, self.res = gl, batch, tiles, res
        defines = {"EMPTY": EMPTY_DEPTH, **SPLAT_UNITS.defines()}
        self.raster_prog = compute_program(gl, "shadow_splat.comp", {"MAPS_PER_DRAW": str(batch), **defines})
        self.clear_prog = compute_program(gl, "shadow_splat_clear.comp", defines)
        self.resolve_prog = program(gl, "fullscreen.vert", "shadow_splat_resolve.frag", defines=defines)
        self.image: moderngl.Texture | None = None
        self.resolve_vao: moderngl.VertexArray | None = None
        self.maps = 0  # maps of the current batch (`begin`)
        self._dirty = False  # splats drawn and not resolved

    def begin(self, light_vp: bytes, maps: int) -> None:
        """A new batch of `maps` maps: their cameras, `light_vp` the batch's
        world → clip matrices as the uniform array holds them (`batch` column-major
        4×4 float32, rows past `maps` unused). The depth image is empty between
        batches (emptied when made, and by `resolve` as it reads it); it is emptied
        here only after a batch that drew splats but was not resolved."""
        self.gl.check_thread()
        if not 0 < maps <= self.batch:
            raise ValueError(f"{maps} maps for a batch of {self.batch}")
        self.maps = maps
        self.raster_prog["u_light_vp"].write(light_vp)
        if self.image is None:
            size = self.tiles * self.res
            with ReleasedOnError() as made:
                image = made(self.gl.ctx.texture((size, size), 1, dtype="u4"))
                vao = self.gl.ctx.vertex_array(self.resolve_prog, [])
            self.image, self.resolve_vao = image, vao
            self._dirty = True
        # image accesses of separate commands are ordered by barriers only: the last
        # resolve's reads and resets, or the clear, before the splats' atomics
        self.gl.ctx.memory_barrier()
        if self._dirty:
            SPLAT_UNITS.bind_image("splat_depth", self.image, read=False, write=True)
            groups = -(-self.image.width // CLEAR_GROUP)
            self.clear_prog.run(groups, groups)
            self.gl.ctx.memory_barrier()
            self._dirty = False

    def rows(self, maps: int) -> int:
        """Tile rows that `maps` maps of a batch fill (tile i: row i // tiles)."""
        return -(-maps // self.tiles)

    def pays(self, splats: int, maps: int, density: float) -> bool:
        """Whether a batch of `maps` maps rasterises `splats` splats by this pass at
        `density` (`ShadowSettings.splat_raster_min`): splats × maps at least
        `density` per texel of the tile rows that `resolve` passes over."""
        return splats > 0 and splats * maps >= density * self.rows(maps) * self.tiles * self.res**2

    def draw(self, splats: QuadSplats) -> None:
        """Rasterise `splats` into the batch's maps (tile i ← map i)."""
        self.gl.check_thread()
        if not splats.count:
            return
        if self.image is None:
            raise ValueError("draw() before begin()")
        prog = self.raster_prog
        groups = -(-splats.count // RASTER_GROUP)
        gx = min(groups, MAX_GROUPS)
        for name, value in (("u_res", self.res), ("u_tiles", self.tiles), ("u_count", splats.count),
                            ("u_groups_x", gx)):
            prog[name].value = value
        SPLAT_UNITS.bind_storage("splats", splats.buffer)
        SPLAT_UNITS.bind_image("splat_depth", self.image, read=True, write=True)
        self._dirty = True
        prog.run(gx, -(-groups // gx), self.maps)

    def resolve(self, fbo: moderngl.Framebuffer) -> None:
        """Write the splats' depths into `fbo`'s depth atlas through the depth test,
        which the caller has on, over the tile rows of the batch's maps, emptying
        the depth image's texels as they are read."""
        self.gl.check_thread()
        if self.image is None or self.resolve_vao is None:
            return
        self.gl.ctx.memory_barrier()
        SPLAT_UNITS.bind_image("splat_depth", self.image, read=True, write=True)
        fbo.use()
        viewport = fbo.viewport
        fbo.viewport = (0, 0, self.image.width, self.rows(self.maps) * self.res)
        try:
            self.resolve_vao.render(moderngl.TRIANGLES, vertices=3)
        finally:
            fbo.viewport = viewport
        self._dirty = False

    def release(self) -> None:
        self.gl.check_thread()
        if self.resolve_vao is not None:
            self.resolve_vao.release()
            self.resolve_vao = None
        if self.image is not None:
            self.image.release()
            self.image = None


__all__ = ["SPLAT_PIECE", "SPLAT_PIXELS", "QuadSplats", "SplatRaster", "quad_corners", "splat_corners", "splat_pairs",
           "split_splats", "splats_last", "triangle_pieces"]

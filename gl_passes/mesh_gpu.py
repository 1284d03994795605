"""An indexed triangle mesh on the GPU (reconstructions, thesis Ch. 3): one vertex
buffer of 16-byte vertices (position xyz float32, colour RGBA8 packed in the
fourth float's bits) and one uint32 index buffer. Occluders for shadow maps take
either this or a SceneGPU: both draw with `draw(prog)` and bind `in_position`.
A mesh may end in triangles that shadow maps rasterise as splats (quads and
lone triangles, `gl_passes.quad_splats`): its triangles are the same either way.
"""

from __future__ import annotations

import moderngl
import numpy as np

from gl_passes.context import GLContext
from gl_passes.indexed import IndexedBuffers
from gl_passes.quad_splats import QuadSplats, splat_corners
from gl_passes.readback import read_buffer
from gl_passes.releasable import ReleasedOnError

#: Bytes per vertex: vec3 position + one uint of packed RGBA8 colour.
VERTEX_BYTES = 16


def pack_colors(color: np.ndarray) -> np.ndarray:
    """(…,3) linear colours in [0,1] → (…,) uint32 RGBA8 (alpha 255): the colour word
    of a vertex record, and of a depth image as the reconstruction shaders read it."""
    c = np.clip(np.rint(np.asarray(color, np.float64) * 255), 0, 255).astype(np.uint32)
    return c[..., 0] | (c[..., 1] << 8) | (c[..., 2] << 16) | np.uint32(255 << 24)


def pack_vertices(positions: np.ndarray, colors: np.ndarray | None = None) -> np.ndarray:
    """(N,3) positions and optional (N,3) linear colours in [0,1] → (N,4) float32
    records as the GPU holds them (colour quantised to 8 bits per channel)."""
    n = len(positions)
    out = np.zeros((n, 4), np.float32)
    out[:, :3] = positions
    if colors is not None:
        out[:, 3] = pack_colors(colors).view(np.float32)
    return out


def unpack_vertices(records: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N,4) float32 vertex records → (positions (N,3) float32, colours (N,4) uint8 RGBA)."""
    rec = np.ascontiguousarray(records, np.float32)
    packed = rec[:, 3].view(np.uint32)
    rgba = np.stack([(packed >> s) & 0xFF for s in (0, 8, 16, 24)], axis=1).astype(np.uint8)
    return rec[:, :3].copy(), rgba


class MeshGPU(IndexedBuffers):
    """Indexed mesh in GL buffers. `vbo` holds `n_vertices` records, `ibo`
    `n_triangles` × 3 uint32 indices (either may be larger than that: only the
    prefix is used). `splats`: None, or the splats that the last
    splats.triangles triangles form. Owns the buffers: call `release()`."""

    def __init__(self, gl: GLContext, vbo: moderngl.Buffer, ibo: moderngl.Buffer, n_vertices: int,
                 n_triangles: int) -> None:
        super().__init__(gl, vbo, ibo)
        self.n_vertices, self.n_triangles = int(n_vertices), int(n_triangles)
        self.splats: QuadSplats | None = None

    @classmethod
    def from_arrays(cls, gl: GLContext, positions: np.ndarray, triangles: np.ndarray,
                    colors: np.ndarray | None = None) -> MeshGPU:
        """Upload (N,3) positions, (M,3) vertex indices and optional (N,3) colours."""
        return cls.from_records(gl, pack_vertices(np.asarray(positions, np.float32), colors), triangles)

    @classmethod
    def from_records(cls, gl: GLContext, records: np.ndarray, triangles: np.ndarray, quads: int = 0,
                     singles: int = 0) -> MeshGPU:
        """Upload (N,4) float32 vertex records (`pack_vertices`) and (M,3) vertex
        indices. The last 2·quads + singles triangles are splats, which shadow maps
        rasterise as splats (`gl_passes.quad_splats.split_splats`): quads, pairs in a row
        that share an edge, then lone triangles."""
        gl.check_thread()
        rec = np.ascontiguousarray(records, np.float32).reshape(-1, 4)
        tri = np.ascontiguousarray(triangles, np.uint32).reshape(-1, 3)
        n_splat = 2 * quads + singles
        if quads < 0 or singles < 0 or n_splat > len(tri):
            raise ValueError(f"{quads} quads and {singles} lone triangles need {n_splat} of the {len(tri)} triangles")
        with ReleasedOnError() as made:
            vbo = made(gl.ctx.buffer(rec.tobytes() or b"\0" * VERTEX_BYTES))
            ibo = made(gl.ctx.buffer(tri.tobytes() or b"\0" * 12))
            mesh = cls(gl, vbo, ibo, len(rec), len(tri))
            if n_splat:
                first = len(tri) - n_splat
                corners = splat_corners(rec[:, :3], tri[first:first + 2 * quads], tri[first + 2 * quads:])
                mesh.splats = QuadSplats(gl, corners, n_splat)
            return mesh

    @property
    def body_triangles(self) -> int:
        """Triangles that the splats do not stand for (all of them without splats)."""
        return self.n_triangles - (self.splats.triangles if self.splats else 0)

    @property
    def nbytes(self) -> int:
        """Bytes of GPU buffers held, the splats' included."""
        return super().nbytes + (self.splats.nbytes if self.splats else 0)

    def vertex_format(self, prog: moderngl.Program) -> tuple[str, ...]:
        return ("3f 4x", "in_position")

    def draw(self, prog: moderngl.Program, instances: int = 1, quads: bool = True) -> None:
        """Draw every triangle with `prog` (which reads `in_position`); quads=False
        leaves out the splats' triangles (the shadow maps' `SplatRaster` draws `splats` instead)."""
        self.gl.check_thread()
        n = self.n_triangles if quads else self.body_triangles
        if n:
            self.vao(prog).render(moderngl.TRIANGLES, vertices=3 * n, instances=instances)

    def release(self) -> None:
        if self.splats is not None:
            self.splats.release()
            self.splats = None
        super().release()

    def read_records(self) -> tuple[np.ndarray, np.ndarray]:
        """(vertex records (N,4) float32 as `pack_vertices` makes them, triangles (M,3) uint32)."""
        self.gl.check_thread()
        nv, nt = self.n_vertices, self.n_triangles
        rec = read_buffer(self.vbo, np.float32, 4 * nv).reshape(-1, 4)
        tri = read_buffer(self.ibo, np.uint32, 3 * nt).reshape(-1, 3)
        return rec, tri

    def read(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(positions (N,3) float32, colours (N,4) uint8 RGBA, triangles (M,3) uint32)."""
        rec, tri = self.read_records()
        pos, rgba = unpack_vertices(rec)
        return pos, rgba, tri

"""Reflection offset (thesis §5.4.2): forward-warp the keyframe's reflections by
their best-match offsets into the intermediate reflection image.

A grid mesh with one vertex per keyframe pixel (two triangles per 2×2 block; the
vertex is the pixel index, no vertex buffer) is drawn in the keyframe's image
space with every vertex moved by its offset; triangles that cross a depth
discontinuity never change within a keyframe's life, so `prepare()` leaves them
(and non-reflective vertices) out of the keyframe's index buffer, and the
geometry shader drops those that hold an invalid vertex or grow more than
`growth` times (thesis: 16); depth d + r keeps the nearest reflected surface where
moved triangles overlap. The valid samples are drawn as points too: with
integer offsets the pixel centres of a mesh moved by whole pixels lie on its
triangles' edges and vertices, where the rasteriser's tie rule, not the mesh,
would decide coverage; the points lie POINT_BIAS farther, so they only fill
pixels no kept triangle covers (a triangle's interpolation holds the sub-pixel
offsets, a point snaps to the pixel it falls in). Output: the intermediate image
(Lr, r), a keyframe-sized rgba32f texture; a pixel is reliable where something
covered it, r >= 0 (ray lengths), the rest keeps r = UNCOVERED.
"""

from __future__ import annotations

import moderngl
import numpy as np

from gl_passes.best_match import set_kf_uniforms
from gl_passes.context import GLContext
from gl_passes.keyframe import REUSE_UNITS, KeyframeTextures
from gl_passes.readback import read_texture
from gl_passes.releasable import Releasable, release_gl
from gl_passes.shaders import program
from gl_passes.uniforms import set_uniform

POINT_BIAS = 1e-3  # relative depth bias of the sample points behind the triangles
UNCOVERED = -1.0  # the intermediate image's r where no triangle or sample point covers a pixel


def same_surface(pos: np.ndarray, nrm: np.ndarray, depth: np.ndarray, obj: np.ndarray, ok: np.ndarray,
                 dy: int, dx: int, tol: float) -> np.ndarray:
    """(H−dy, W−dx) bool: pixel (y, x) and (y + dy, x + dx) are both `ok` and on one
    surface (reuse_common.glsl's kf_same_surface: same object, each within `tol`
    (world units per unit depth) × its depth of the other's tangent plane)."""
    h, w = depth.shape
    a, b = (slice(0, h - dy), slice(0, w - dx)), (slice(dy, h), slice(dx, w))
    diff = pos[b] - pos[a]
    return (ok[a] & ok[b] & (obj[a] == obj[b]) & (obj[a] > 0)
            & (np.abs(np.sum(diff * nrm[a], -1)) <= tol * depth[a])
            & (np.abs(np.sum(diff * nrm[b], -1)) <= tol * depth[b]))


def grid_indices(pos: np.ndarray, nrm: np.ndarray, depth: np.ndarray, obj: np.ndarray, ok: np.ndarray,
                 tol: float) -> np.ndarray:
    """Index buffer of the keyframe's grid mesh (arrays (H,W[,3]) in GL row order,
    row 0 = bottom, as the vertex index y·W + x): triangles (T·3,) uint32 whose
    vertex pairs are all `ok` and on one surface. (The samples drawn as points are
    the keyframe's reflective pixels, KeyframeTextures.pixels.)"""
    h, w = depth.shape
    hor = same_surface(pos, nrm, depth, obj, ok, 0, 1, tol)    # (x, y)–(x+1, y)
    ver = same_surface(pos, nrm, depth, obj, ok, 1, 0, tol)    # (x, y)–(x, y+1)
    dia = same_surface(pos, nrm, depth, obj, ok, 1, 1, tol)    # (x, y)–(x+1, y+1)
    ids = np.arange(h * w, dtype=np.uint32).reshape(h, w)
    p00, p10, p11, p01 = ids[:-1, :-1], ids[:-1, 1:], ids[1:, 1:], ids[1:, :-1]
    t1 = hor[:-1] & ver[:, 1:] & dia                            # (00, 10, 11)
    t2 = dia & hor[1:] & ver[:, :-1]                            # (00, 11, 01)
    tris = np.concatenate([np.stack([p00[t1], p10[t1], p11[t1]], 1), np.stack([p00[t2], p11[t2], p01[t2]], 1)])
    return np.ascontiguousarray(tris.reshape(-1), np.uint32)


class ReflectionOffsetPass(Releasable):
    """§5.4.2 on `gl`'s thread; `run()` returns the intermediate texture (Lr, r;
    reliable where r >= 0)."""

    def __init__(self, gl: GLContext) -> None:
        gl.check_thread()
        self.gl = gl
        defines = REUSE_UNITS.defines()
        names = ("reflection_offset.vert", "reflection_offset.frag", "reflection_offset.geom")
        self.mesh_prog = program(gl, *names, defines=defines)
        self.point_prog = program(gl, *names, defines={**defines, "POINTS": "1"})
        self._buffers: list[moderngl.Buffer] = []
        self._vaos: list[moderngl.VertexArray] = []
        self._counts = (0, 0)
        self.size: tuple[int, int] | None = None
        self.inter: moderngl.Texture | None = None
        self._depth: moderngl.Texture | None = None
        self._fbo: moderngl.Framebuffer | None = None

    def _ensure(self, size: tuple[int, int]) -> None:
        if self.size == size:
            return
        self._free()
        ctx = self.gl.ctx
        self.inter = ctx.texture(size, 4, dtype="f4")
        self.inter.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self._depth = ctx.depth_texture(size)
        self._fbo = ctx.framebuffer([self.inter], self._depth)
        self.size = size

    def prepare(self, keyframe: KeyframeTextures, plane_tol: float) -> None:
        """Build the keyframe's grid-mesh index buffers (its continuous triangles and
        reflective samples; read back once per keyframe)."""
        self.gl.check_thread()
        self._free_mesh()
        t = keyframe.target.textures
        # vertex ids count GL rows (row 0 = bottom), as the warp's shaders index texels
        pos = read_texture(t["position"], gl_rows=True)[..., :3].astype(np.float64)
        nrm = read_texture(t["normal"], gl_rows=True)[..., :3].astype(np.float64)
        depth = read_texture(t["depth"], gl_rows=True).astype(np.float64)
        obj = read_texture(t["obj_id"], gl_rows=True)
        r = keyframe.ray_length[::-1]  # (H,W) row 0 = top, as the tracer gives it
        ok = (np.isfinite(r) | np.isposinf(r)) & (obj > 0)
        cam = keyframe.camera
        tol = plane_tol * cam.pixel_footprint
        tris = grid_indices(pos, nrm, depth, obj, ok, tol)
        ctx = self.gl.ctx
        buf = ctx.buffer(tris.tobytes() if len(tris) else np.zeros(1, np.uint32).tobytes())
        self._buffers.append(buf)
        self._vaos.append(ctx.vertex_array(self.mesh_prog, [], index_buffer=buf, index_element_size=4))
        self._vaos.append(ctx.vertex_array(self.point_prog, [], index_buffer=keyframe.pixels, index_element_size=4))
        self._counts = (len(tris), keyframe.n_pixels)

    def run(self, keyframe: KeyframeTextures, offsets: moderngl.Texture, growth: float, plane_tol: float,
            reflected_jump: float) -> moderngl.Texture:
        self.gl.check_thread()
        ctx = self.gl.ctx
        w, h = keyframe.target.size
        self._ensure((w, h))
        assert self._fbo is not None and self.inter is not None
        self._fbo.use()
        self._fbo.viewport = (0, 0, w, h)
        self._fbo.clear(0.0, 0.0, 0.0, UNCOVERED, depth=1.0)
        keyframe.bind()
        REUSE_UNITS.bind_texture("u_offsets_tex", offsets)
        depth_max = keyframe.camera.far + keyframe.max_ray_length
        for prog in (self.mesh_prog, self.point_prog):
            set_kf_uniforms(prog, keyframe, plane_tol)
            set_uniform(prog, "u_depth_scale", 1.0 / max(depth_max, 1e-6))
            set_uniform(prog, "u_growth", float(growth))
            set_uniform(prog, "u_reflected_jump", float(reflected_jump))
            set_uniform(prog, "u_point_bias", POINT_BIAS)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE)
        ctx.depth_func = "<"
        if self._counts[0]:
            self._vaos[0].render(moderngl.TRIANGLES, vertices=self._counts[0])
        if self._counts[1]:
            self._vaos[1].render(moderngl.POINTS, vertices=self._counts[1])
        ctx.disable(moderngl.DEPTH_TEST)
        return self.inter

    def _free(self) -> None:
        for obj in (self._fbo, self._depth, self.inter):
            if obj is not None:
                release_gl(obj)
        self._fbo = self._depth = self.inter = None
        self.size = None

    def _free_mesh(self) -> None:
        for obj in (*self._vaos, *self._buffers):
            obj.release()
        self._vaos, self._buffers, self._counts = [], [], (0, 0)

    def release(self) -> None:
        self.gl.check_thread()
        self._free()
        self._free_mesh()

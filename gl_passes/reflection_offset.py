"""Reflection offset (thesis §5.4.2): forward-warp the keyframe's reflections by
their best-match offsets into the intermediate reflection image.

A grid mesh with one vertex per keyframe pixel (two triangles per 2×2 block,
generated from gl_VertexID, no vertex buffer) is drawn in the keyframe's image
space with every vertex moved by its offset; the geometry shader drops triangles
that cross a depth discontinuity, hold an invalid vertex or grow more than
`growth` times (thesis: 16), and depth d + r keeps the nearest reflected surface
where moved triangles overlap. The valid samples are drawn as points too: with
integer offsets the pixel centres of a mesh moved by whole pixels lie on its
triangles' edges and vertices, where the rasteriser's tie rule, not the mesh,
would decide coverage; the points lie POINT_BIAS farther, so they only fill
pixels no kept triangle covers (a triangle's interpolation holds the sub-pixel
offsets, a point snaps to the pixel it falls in). Output: the intermediate image (Lr, r) and the
reliability mask (1 where covered), both keyframe-sized rgba32f / r32f textures.
"""

from __future__ import annotations

import moderngl

from gl_passes.best_match import set_kf_uniforms
from gl_passes.context import GLContext
from gl_passes.keyframe import REUSE_UNITS, KeyframeTextures
from gl_passes.releasable import Releasable
from gl_passes.shaders import program
from gl_passes.uniforms import set_uniform

POINT_BIAS = 1e-3  # relative depth bias of the sample points behind the triangles


class ReflectionOffsetPass(Releasable):
    """§5.4.2 on `gl`'s thread; `run()` returns (intermediate, reliable) textures."""

    def __init__(self, gl: GLContext) -> None:
        gl.check_thread()
        self.gl = gl
        defines = REUSE_UNITS.defines()
        names = ("reflection_offset.vert", "reflection_offset.frag", "reflection_offset.geom")
        self.mesh_prog = program(gl, *names, defines=defines)
        self.point_prog = program(gl, *names, defines={**defines, "POINTS": "1"})
        self.mesh_vao = gl.ctx.vertex_array(self.mesh_prog, [])
        self.point_vao = gl.ctx.vertex_array(self.point_prog, [])
        self.size: tuple[int, int] | None = None
        self.inter: moderngl.Texture | None = None
        self.reliable: moderngl.Texture | None = None
        self._depth: moderngl.Texture | None = None
        self._fbo: moderngl.Framebuffer | None = None

    def _ensure(self, size: tuple[int, int]) -> None:
        if self.size == size:
            return
        self._free()
        ctx = self.gl.ctx
        self.inter = ctx.texture(size, 4, dtype="f4")
        self.reliable = ctx.texture(size, 1, dtype="f4")
        for t in (self.inter, self.reliable):
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self._depth = ctx.depth_texture(size)
        self._fbo = ctx.framebuffer([self.inter, self.reliable], self._depth)
        self.size = size

    def run(self, keyframe: KeyframeTextures, offsets: moderngl.Texture, growth: float, plane_tol: float,
            reflected_jump: float) -> tuple[moderngl.Texture, moderngl.Texture]:
        self.gl.check_thread()
        ctx = self.gl.ctx
        w, h = keyframe.target.size
        self._ensure((w, h))
        assert self._fbo is not None and self.inter is not None and self.reliable is not None
        self._fbo.use()
        self._fbo.viewport = (0, 0, w, h)
        self._fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
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
        if w > 1 and h > 1:
            self.mesh_vao.render(moderngl.TRIANGLES, vertices=6 * (w - 1) * (h - 1))
        self.point_vao.render(moderngl.POINTS, vertices=w * h)
        ctx.disable(moderngl.DEPTH_TEST)
        return self.inter, self.reliable

    def _free(self) -> None:
        for obj in (self._fbo, self._depth, self.inter, self.reliable):
            if obj is not None:
                obj.release()
        self._fbo = self._depth = self.inter = self.reliable = None
        self.size = None

    def release(self) -> None:
        self.gl.check_thread()
        self._free()
        self.mesh_vao.release()
        self.point_vao.release()

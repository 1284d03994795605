"""Reflection offset (thesis §5.4.2) as a compute rasteriser of the keyframe's grid
mesh: the same mesh, vertex moves, triangle drops, sample points and d + r depth
resolution as gl_passes.reflection_offset (which draws it through GL's vertex,
geometry and fragment stages), rasterised in two compute passes over the keyframe's
reflective pixels: an atomic depth minimum per pixel, then the fragments at that
minimum write the intermediate image (Lr, r; reliable where r >= 0).

Why a second rasteriser of one mesh: on a CPU rasteriser (Mesa llvmpipe) GL's
vertex stage is the bottleneck, and the mesh has two triangles per reflective
keyframe pixel — more than most scenes — while each triangle covers about half a
pixel; a compute invocation per 2×2 block that tests the one or two pixel centres
its triangles can reach does the same work without the vertex pipeline
(bench/results/temporal.md measures both). The coverage rule differs from GL's
only where a pixel centre lies exactly on an edge: here the top-left rule with
each shared edge evaluated identically from both sides, so the mesh is
watertight by construction (GL's fixed-point snapping decides those pixels in
the mesh pass, where the sample points cover for it).

`prepare()` once per keyframe (the continuity of each block's triangles, on the
GPU: reflection_grid.comp); `run()` per frame.
"""

from __future__ import annotations

import moderngl
import numpy as np

from gl_passes.best_match import set_kf_uniforms
from gl_passes.context import GLContext
from gl_passes.keyframe import REUSE_UNITS, KeyframeTextures
from gl_passes.reflection_offset import POINT_BIAS, UNCOVERED
from gl_passes.releasable import Releasable, release_gl
from gl_passes.shaders import compute_program
from gl_passes.uniforms import set_uniform

GROUP = 64  # local size of reflection_grid.comp and reflection_splat.comp
_CLEAR_DEPTH = np.float32(1.0).view(np.uint32)  # the depth buffer's clear value (GL's 1.0), as bits


class ReflectionSplatPass(Releasable):
    """§5.4.2 on `gl`'s thread, the interface of ReflectionOffsetPass: `prepare()`
    per keyframe, `run()` → the intermediate rgba32f texture (Lr, r; r = UNCOVERED
    where nothing covers a pixel), keyframe-sized, GL orientation."""

    def __init__(self, gl: GLContext) -> None:
        gl.check_thread()
        self.gl = gl
        defines = REUSE_UNITS.defines()
        self.grid_prog = compute_program(gl, "reflection_grid.comp", defines)
        self.depth_prog = compute_program(gl, "reflection_splat.comp", defines)
        self.resolve_prog = compute_program(gl, "reflection_splat.comp", {**defines, "RESOLVE": "1"})
        self.size: tuple[int, int] | None = None
        self.grid: moderngl.Texture | None = None
        self.zbuf: moderngl.Texture | None = None
        self.inter: moderngl.Texture | None = None
        self._fbo: moderngl.Framebuffer | None = None
        self._clear_bytes = b""

    def _ensure(self, size: tuple[int, int]) -> None:
        if self.size == size:
            return
        self._free()
        ctx = self.gl.ctx
        self.grid = ctx.texture(size, 1, dtype="u4")
        self.zbuf = ctx.texture(size, 1, dtype="u4")
        self.inter = ctx.texture(size, 4, dtype="f4")
        for t in (self.grid, self.zbuf, self.inter):
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self._fbo = ctx.framebuffer([self.inter])
        self._clear_bytes = np.full(size[0] * size[1], _CLEAR_DEPTH, np.uint32).tobytes()
        self.size = size

    def prepare(self, keyframe: KeyframeTextures, plane_tol: float) -> None:
        """The keyframe's grid: which triangles of each reflective pixel's 2×2 block exist."""
        self.gl.check_thread()
        self._ensure(keyframe.target.size)
        assert self.grid is not None
        w, h = keyframe.target.size
        self.grid.write(bytes(4 * w * h))
        keyframe.bind()
        REUSE_UNITS.bind_image("u_grid_img", self.grid, read=False, write=True)
        REUSE_UNITS.bind_storage("Pixels", keyframe.pixels)
        p = self.grid_prog
        set_kf_uniforms(p, keyframe, plane_tol)
        set_uniform(p, "u_count", int(keyframe.n_pixels))
        if keyframe.n_pixels:
            p.run((keyframe.n_pixels + GROUP - 1) // GROUP, 1, 1)
        self.gl.ctx.memory_barrier()

    def run(self, keyframe: KeyframeTextures, offsets: moderngl.Texture, growth: float, plane_tol: float,
            reflected_jump: float) -> moderngl.Texture:
        self.gl.check_thread()
        ctx = self.gl.ctx
        self._ensure(keyframe.target.size)
        assert self._fbo is not None and self.zbuf is not None and self.grid is not None
        assert self.inter is not None
        self._fbo.clear(0.0, 0.0, 0.0, UNCOVERED)
        self.zbuf.write(self._clear_bytes)
        keyframe.bind()
        REUSE_UNITS.bind_texture("u_offsets_tex", offsets)
        REUSE_UNITS.bind_texture("u_grid", self.grid)
        REUSE_UNITS.bind_storage("Pixels", keyframe.pixels)
        depth_max = keyframe.camera.far + keyframe.max_ray_length
        groups = (keyframe.n_pixels + GROUP - 1) // GROUP
        for prog in (self.depth_prog, self.resolve_prog):
            set_kf_uniforms(prog, keyframe, plane_tol)
            set_uniform(prog, "u_count", int(keyframe.n_pixels))
            set_uniform(prog, "u_depth_scale", 1.0 / max(depth_max, 1e-6))
            set_uniform(prog, "u_growth", float(growth))
            set_uniform(prog, "u_reflected_jump", float(reflected_jump))
            set_uniform(prog, "u_point_bias", POINT_BIAS)
        if groups:
            REUSE_UNITS.bind_image("u_zbuf", self.zbuf, read=True, write=True)
            self.depth_prog.run(groups, 1, 1)
            ctx.memory_barrier()
            REUSE_UNITS.bind_image("u_zbuf", self.zbuf, read=True, write=False)
            REUSE_UNITS.bind_image("u_inter_img", self.inter, read=False, write=True)
            self.resolve_prog.run(groups, 1, 1)
            ctx.memory_barrier()
        return self.inter

    def _free(self) -> None:
        for obj in (self._fbo, self.grid, self.zbuf, self.inter):
            if obj is not None:
                release_gl(obj)
        self._fbo = self.grid = self.zbuf = self.inter = None
        self.size = None

    def release(self) -> None:
        self.gl.check_thread()
        self._free()

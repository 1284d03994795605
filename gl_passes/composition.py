"""Composition (thesis §5.4.3): depth-based reprojection of the intermediate
reflection image into the new view, and the pixels to recompute.

reflection_compose.comp classifies every new-frame pixel on a reflector as reused
(the keyframe sees its surface point and the intermediate image is reliable
there), disoccluded (the keyframe does not see it) or unreliable; the caller
recomputes the last two with its tracer and blends with the diffuse colour by s.
"""

from __future__ import annotations

import moderngl
import numpy as np

from gl_passes.best_match import set_kf_uniforms
from gl_passes.context import GLContext
from gl_passes.gbuffer import RenderTarget
from gl_passes.keyframe import REUSE_UNITS, KeyframeTextures
from gl_passes.readback import read_buffer
from gl_passes.releasable import Releasable
from gl_passes.shaders import compute_program
from gl_passes.uniforms import set_uniform

GROUP = 64  # reflection_compose.comp local size (one invocation per reflective pixel)
#: Per-pixel classes of the composition (the flag image).
NOT_REFLECTIVE, REUSED, DISOCCLUDED, UNRELIABLE = 0, 1, 2, 3


class CompositionPass(Releasable):
    """§5.4.3 on `gl`'s thread, over the new frame's reflective pixels only (a list):
    `run()` returns their reflection (Lr rgb, r) and flags (REUSED / DISOCCLUDED /
    UNRELIABLE)."""

    def __init__(self, gl: GLContext) -> None:
        gl.check_thread()
        self.gl = gl
        self.prog = compute_program(gl, "reflection_compose.comp", REUSE_UNITS.defines())
        self._results: moderngl.Buffer | None = None
        self._flags: moderngl.Buffer | None = None
        self._ids: moderngl.Buffer | None = None

    def _ensure(self, n: int) -> None:
        if self._results is not None and self._results.size >= 16 * n:
            return
        self._free()
        cap = max(n, 1024)
        self._results = self.gl.ctx.buffer(reserve=16 * cap)
        self._flags = self.gl.ctx.buffer(reserve=4 * cap)
        self._ids = self.gl.ctx.buffer(reserve=4 * cap)

    def run(self, frame: RenderTarget, keyframe: KeyframeTextures, inter: moderngl.Texture, plane_tol: float,
            pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`pixels` (N,) the new frame's pixels on reflectors, y·W + x with row 0 at
        the top → (reflection (N,4) float32: Lr rgb, r; flags (N,) uint8 of REUSED /
        DISOCCLUDED / UNRELIABLE), in the order of `pixels`."""
        self.gl.check_thread()
        w, h = frame.size
        n = len(pixels)
        if n == 0:
            return np.zeros((0, 4), np.float32), np.zeros(0, np.uint8)
        self._ensure(n)
        assert self._results is not None and self._flags is not None and self._ids is not None
        self._ids.write(np.asarray(pixels, np.uint32))  # the shader flips the rows
        keyframe.bind()
        t = frame.textures
        for name, tex in (("u_position", t["position"]), ("u_obj", t["obj_id"]), ("u_inter", inter)):
            REUSE_UNITS.bind_texture(name, tex)
        for name, buf in (("Pixels", self._ids), ("Results", self._results), ("Flags", self._flags)):
            REUSE_UNITS.bind_storage(name, buf)
        p = self.prog
        set_kf_uniforms(p, keyframe, plane_tol)
        set_uniform(p, "u_kf_view_proj", keyframe.camera.view_projection())
        set_uniform(p, "u_size", (int(w), int(h)))
        set_uniform(p, "u_count", int(n))
        p.run((n + GROUP - 1) // GROUP, 1, 1)
        self.gl.ctx.memory_barrier()
        res = read_buffer(self._results, np.float32, 4 * n).reshape(n, 4)
        fl = read_buffer(self._flags, np.uint32, n).astype(np.uint8)
        return res, fl

    def _free(self) -> None:
        for buf in (self._results, self._flags, self._ids):
            if buf is not None:
                buf.release()
        self._results = self._flags = self._ids = None

    def release(self) -> None:
        self.gl.check_thread()
        self._free()

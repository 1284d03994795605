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
from gl_passes.readback import read_texture
from gl_passes.releasable import Releasable
from gl_passes.shaders import compute_program
from gl_passes.uniforms import set_uniform

GROUP = 8  # reflection_compose.comp local size (x and y)
#: Per-pixel classes of the composition (the flag image).
NOT_REFLECTIVE, REUSED, DISOCCLUDED, UNRELIABLE = 0, 1, 2, 3


class CompositionPass(Releasable):
    """§5.4.3 on `gl`'s thread. `run()` returns (reflection (H,W,4) float32: Lr rgb,
    r; flags (H,W) uint8 of NOT_REFLECTIVE / REUSED / DISOCCLUDED / UNRELIABLE),
    row 0 = top."""

    def __init__(self, gl: GLContext) -> None:
        gl.check_thread()
        self.gl = gl
        self.prog = compute_program(gl, "reflection_compose.comp", REUSE_UNITS.defines())
        self._out: moderngl.Texture | None = None
        self._flag: moderngl.Texture | None = None

    def _ensure(self, size: tuple[int, int]) -> None:
        if self._out is not None and self._out.size == size:
            return
        self._free()
        self._out = self.gl.ctx.texture(size, 4, dtype="f4")
        self._flag = self.gl.ctx.texture(size, 1, dtype="f4")

    def run(self, frame: RenderTarget, keyframe: KeyframeTextures, inter: moderngl.Texture,
            reliable: moderngl.Texture, plane_tol: float) -> tuple[np.ndarray, np.ndarray]:
        self.gl.check_thread()
        size = frame.size
        self._ensure(size)
        assert self._out is not None and self._flag is not None
        keyframe.bind()
        t = frame.textures
        for name, tex in (("u_position", t["position"]), ("u_obj", t["obj_id"]), ("u_material", t["material"]),
                          ("u_inter", inter), ("u_reliable", reliable)):
            REUSE_UNITS.bind_texture(name, tex)
        REUSE_UNITS.bind_image("u_out", self._out, read=False, write=True)
        REUSE_UNITS.bind_image("u_flag", self._flag, read=False, write=True)
        p = self.prog
        set_kf_uniforms(p, keyframe, plane_tol)
        set_uniform(p, "u_kf_view_proj", keyframe.camera.view_projection())
        set_uniform(p, "u_size", tuple(int(x) for x in size))
        p.run((size[0] + GROUP - 1) // GROUP, (size[1] + GROUP - 1) // GROUP, 1)
        self.gl.ctx.memory_barrier()
        return read_texture(self._out), read_texture(self._flag).astype(np.uint8)

    def _free(self) -> None:
        for tex in (self._out, self._flag):
            if tex is not None:
                tex.release()
        self._out = self._flag = None

    def release(self) -> None:
        self.gl.check_thread()
        self._free()

"""Best reflection-pixel match (thesis §5.4.1, Alg. 9) as a compute pass.

For every reflective pixel s of the keyframe's reflection depth image, the
offset (texel units, GL orientation) to the pixel s* whose tangent plane best
reflects the keyframe's reflected point R toward the new eye; see best_match.comp
for the distance, the descent and the invalid cases. Three offset images rotate:
the previous frame's offsets start this frame's search (Alg. 9, O_p → O_c), or
with `predict` where the previous search ended (also when invalid), the
extrapolation of the two previous frames' valid offsets, or the pixel's own
plane match when its distance is the lesser (best_match.comp).
"""

from __future__ import annotations

import moderngl
import numpy as np

from gl_passes.context import GLContext
from gl_passes.keyframe import REUSE_UNITS, KeyframeTextures
from gl_passes.readback import read_texture
from gl_passes.releasable import Releasable
from gl_passes.shaders import compute_program
from gl_passes.uniforms import set_uniform

GROUP = 64  # best_match.comp local size (one invocation per reflective keyframe pixel)


class BestMatchPass(Releasable):
    """Alg. 9 on `gl`'s thread. `run()` returns the current offset image
    (rgba32f: ox, oy, valid 0/1, steps); `reset()` invalidates the previous
    offsets (a new keyframe)."""

    def __init__(self, gl: GLContext) -> None:
        gl.check_thread()
        self.gl = gl
        self.prog = compute_program(gl, "best_match.comp", REUSE_UNITS.defines())
        self._offsets: list[moderngl.Texture] = []
        self._current = 0
        self._history = 0  # offset images computed since the last reset (valid previous frames)

    def _ensure(self, size: tuple[int, int]) -> None:
        if self._offsets and self._offsets[0].size == size:
            return
        self._free()
        for _ in range(3):
            t = self.gl.ctx.texture(size, 4, dtype="f4")
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self._offsets.append(t)
        self.reset()

    def reset(self) -> None:
        """No valid previous offsets (every search starts at its own pixel): the
        next run ignores the older offset images (nothing is cleared)."""
        self._history = 0

    @property
    def offsets(self) -> moderngl.Texture:
        return self._offsets[self._current]

    def run(self, keyframe: KeyframeTextures, eye_new: np.ndarray, max_steps: int, plane_tol: float,
            direct: bool = False, predict: bool = False) -> moderngl.Texture:
        """Offsets for the new eye (world units); direct=True: offset 0 for every
        reflective pixel (the direct-reprojection baseline); predict: resume invalid
        searches where they ended, start from the extrapolation of the two
        previous frames' offsets where both are valid, or from the pixel's plane
        match where it is closer (best_match.comp)."""
        self.gl.check_thread()
        size = keyframe.target.size
        self._ensure(size)
        prev, self._current = self._current, (self._current + 1) % 3
        prev2 = (self._current + 1) % 3
        keyframe.bind()
        REUSE_UNITS.bind_image("u_prev", self._offsets[prev], read=True, write=False)
        REUSE_UNITS.bind_image("u_prev2", self._offsets[prev2], read=True, write=False)
        REUSE_UNITS.bind_image("u_offsets", self._offsets[self._current], read=False, write=True)
        p = self.prog
        set_kf_uniforms(p, keyframe, plane_tol)
        set_uniform(p, "u_eye_old", np.asarray(keyframe.camera.eye))
        set_uniform(p, "u_eye_new", np.asarray(eye_new, np.float64))
        set_uniform(p, "u_max_steps", int(max_steps))
        set_uniform(p, "u_direct", int(direct))
        set_uniform(p, "u_predict", int(predict))
        set_uniform(p, "u_history", int(min(self._history, 2)))
        set_uniform(p, "u_kf_view_proj", keyframe.camera.view_projection())
        set_uniform(p, "u_count", int(keyframe.n_pixels))
        REUSE_UNITS.bind_storage("Pixels", keyframe.pixels)
        if keyframe.n_pixels:
            p.run((keyframe.n_pixels + GROUP - 1) // GROUP, 1, 1)
        self.gl.ctx.memory_barrier()
        self._history += 1
        return self.offsets

    def read(self) -> np.ndarray:
        """The current offsets (H,W,4), row 0 = top: (ox, oy, valid, steps) with oy
        in GL orientation (up)."""
        return read_texture(self.offsets)

    def _free(self) -> None:
        for t in self._offsets:
            t.release()
        self._offsets = []

    def release(self) -> None:
        self.gl.check_thread()
        self._free()


def set_kf_uniforms(prog: moderngl.Program | moderngl.ComputeShader, keyframe: KeyframeTextures,
                    plane_tol: float) -> None:
    """The keyframe uniforms of reuse_common.glsl: size, pixel angle, tolerance."""
    cam = keyframe.camera
    set_uniform(prog, "u_kf_size", tuple(int(x) for x in keyframe.target.size))
    set_uniform(prog, "u_pixel_angle", cam.pixel_footprint)
    set_uniform(prog, "u_plane_tol", float(plane_tol))

"""Keyframes of the temporal reflection reuse (thesis Ch. 5): the reflection depth
image of §5.3 and the keyframe policy of §5.4.4.

A keyframe's reflection depth image B holds per pixel s (B.1) the normal s.n and
depth s.d, (B.2) the specular factor s.f, (B.3) the reflected colour s.Lr and
(B.4) the reflected-ray length s.r. B.1–B.2 come from the G-buffer pass, B.3–B.4
from a tracer (gl_passes.reprojection.Tracer). On the GPU the keyframe's G-buffer
textures are kept as they are (position, normal, depth, object id) and B.3–B.4 go
into one rgba32f texture (Lr, r); `REUSE_UNITS` names the units every reuse shader
binds them to (reuse_common.glsl).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import moderngl
import numpy as np

from gl_passes.bindings import Units
from gl_passes.context import GLContext
from gl_passes.gbuffer import RenderTarget
from gl_passes.readback import read_texture, write_texture
from gl_passes.releasable import ReleasedOnError
from gl_passes.shaders import compute_program
from gl_passes.uniforms import set_uniform
from scenes.camera import Camera

#: Units of the reuse shaders (keyframe_pack.comp, best_match.comp, reflection_offset.*,
#: reflection_grid.comp, reflection_splat.comp, reflection_compose.comp).
REUSE_UNITS = Units(
    images=("u_prev", "u_prev2", "u_offsets", "u_grid_img", "u_zbuf", "u_inter_img",
            "u_kf_position_img", "u_kf_normal_img"),
    storage=("Pixels", "Results", "Flags"),
    textures=("u_kf_position", "u_kf_normal", "u_kf_depth", "u_kf_obj", "u_kf_reflection", "u_offsets_tex",
              "u_position", "u_obj", "u_inter", "u_grid"),
)

def scatter_pixels(flat: np.ndarray, values: np.ndarray, shape: tuple[int, ...], fill: float) -> np.ndarray:
    """An image of `shape` (H,W[,C]) holding `values` (N[,C]) at the flat pixels
    `flat` (y·W + x) and `fill` elsewhere."""
    n = shape[0] * shape[1]
    out = np.zeros((n, *shape[2:]), values.dtype) if fill == 0 else np.full((n, *shape[2:]), fill, values.dtype)
    out[flat] = values
    return out.reshape(shape)


#: Reflection-ray length used for rays that miss (they read the sky, a function of
#: direction only), in scene diagonals: a far point in that direction.
MISS_DIAGONALS = 100.0


@dataclass
class ReflectionDepthImage:
    """A keyframe's reflection depth image (thesis §5.3), numpy, row 0 = top:
    normal (H,W,3) float32 world unit normals and depth (H,W) float32 eye-space z
    (+inf background) (B.1); specular (H,W) float32 s ∈ [0, 1] (B.2); reflected
    (H,W,3) float32 linear RGB (B.3) and ray_length (H,W) float64 world units
    (+inf: the ray missed; NaN: not reflective) (B.4); camera: the keyframe camera."""

    normal: np.ndarray
    depth: np.ndarray
    specular: np.ndarray
    reflected: np.ndarray
    ray_length: np.ndarray
    camera: Camera

    @property
    def reflective(self) -> np.ndarray:
        """(H,W) bool: pixels with s > 0 on geometry."""
        return (self.specular > 0) & np.isfinite(self.depth)


class KeyframeTextures:
    """The GPU side of a keyframe: its G-buffer target (kept until the next
    keyframe; keyframe_pack.comp puts d into position.w and r into normal.w) and
    the (Lr, r) texture; `bind()` binds them to REUSE_UNITS. `pixels`: a uint32
    buffer of its reflective pixels' indices y·W + x (GL rows, row 0 = bottom;
    `n_pixels` of them), so per-pixel passes run over the reflectors only."""

    def __init__(self, gl: GLContext, target: RenderTarget, camera: Camera, pixels: np.ndarray,
                 reflected: np.ndarray, ray_length: np.ndarray, miss_distance: float) -> None:
        """pixels (N,) int: the traced pixels y·W + x, row 0 at the top, ascending;
        reflected (N,3) float32 and ray_length (N,) float64 there (the Tracer's
        values: +inf a miss, NaN not reflective)."""
        ctx = gl.ctx
        self.target = target
        self.camera = camera
        self._values = (np.asarray(pixels), reflected, ray_length)
        r = np.where(np.isposinf(ray_length), miss_distance, ray_length)
        r[~np.isfinite(r)] = -1.0
        self.max_ray_length = float(r.max(initial=0.0))
        w, h = target.size
        image = np.zeros((h, w, 4), np.float32)  # (Lr, r), r = -1 where not traced
        image[..., 3] = -1.0
        image.reshape(-1, 4)[pixels] = np.column_stack([reflected, r])
        ids = np.flatnonzero(image[::-1, :, 3].ravel() >= 0).astype(np.uint32)  # GL rows
        self.n_pixels = len(ids)
        with ReleasedOnError() as made:
            self.texture = made(ctx.texture(target.size, 4, dtype="f4"))
            self.texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
            write_texture(self.texture, image)
            self.pixels = made(ctx.buffer(ids if len(ids) else np.zeros(1, np.uint32)))
            self._pack(gl)

    @cached_property
    def reflected(self) -> np.ndarray:
        """(H,W,3) float32 reflected colour (B.3), row 0 = top, 0 where not traced."""
        pixels, reflected, _ = self._values
        w, h = self.target.size
        return scatter_pixels(pixels, reflected, (h, w, 3), 0.0)

    @cached_property
    def ray_length(self) -> np.ndarray:
        """(H,W) float64 reflected-ray length (B.4), row 0 = top: +inf a miss, NaN
        not reflective."""
        pixels, _, ray_length = self._values
        w, h = self.target.size
        return scatter_pixels(pixels, ray_length, (h, w), np.nan)

    def _pack(self, gl: GLContext) -> None:
        """keyframe_pack.comp: d → position.w, r → normal.w."""
        prog = compute_program(gl, "keyframe_pack.comp", REUSE_UNITS.defines())
        t = self.target.textures
        self.bind()
        REUSE_UNITS.bind_image("u_kf_position_img", t["position"], read=True, write=True)
        REUSE_UNITS.bind_image("u_kf_normal_img", t["normal"], read=True, write=True)
        w, h = self.target.size
        set_uniform(prog, "u_kf_size", (int(w), int(h)))
        prog.run((w + 7) // 8, (h + 7) // 8, 1)
        gl.ctx.memory_barrier()

    def bind(self) -> None:
        t = self.target.textures
        for name, key in (("u_kf_position", "position"), ("u_kf_normal", "normal"), ("u_kf_depth", "depth"),
                          ("u_kf_obj", "obj_id")):
            REUSE_UNITS.bind_texture(name, t[key])
        REUSE_UNITS.bind_texture("u_kf_reflection", self.texture)

    def image(self) -> ReflectionDepthImage:
        """Read the keyframe back as a ReflectionDepthImage."""
        t = self.target.textures
        tri = read_texture(t["tri_id"])
        return ReflectionDepthImage(
            normal=read_texture(t["normal"])[..., :3].copy(),
            depth=np.where(tri > 0, read_texture(t["depth"]), np.float32(np.inf)).astype(np.float32),
            specular=read_texture(t["material"])[..., 0].copy(), reflected=self.reflected,
            ray_length=self.ray_length, camera=self.camera)

    def release(self) -> None:
        self.texture.release()
        self.pixels.release()


@dataclass
class KeyframePolicy:
    """§5.4.4: the next frame is a keyframe when more than `threshold` of the
    reflective pixels of this frame were recomputed (thesis: 0.3; ReuseSettings
    chooses the threshold)."""

    threshold: float = 0.3
    due: bool = True

    def update(self, recomputed_fraction: float) -> None:
        self.due = recomputed_fraction > self.threshold

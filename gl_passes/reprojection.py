"""Temporal reuse of reflections across frames (thesis Ch. 5, Alg. 8; DESIGN.md
technique 4): `ReflectionReuser(gl, scene_gpu, tracer).next_frame(camera)`.

Per frame (Alg. 8): the diffuse colour, position, normal, object id and s of the
new view (G-buffer pass); then

* keyframe: the tracer computes the reflected colour and ray length of every
  reflective pixel; with the G-buffer they form the reflection depth image
  (§5.3, gl_passes.keyframe), kept until the next keyframe;
* otherwise: best match (§5.4.1, Alg. 9, gl_passes.best_match) → reflection offset
  (§5.4.2, gl_passes.reflection_offset) → composition (§5.4.3,
  gl_passes.composition); the disoccluded and unreliable pixels, and only those,
  are recomputed by the tracer (sparse rays where the tracer can, `Tracer.sparse`);

and the output colour = mix(diffuse, reflected, s). Keyframe policy (§5.4.4,
gl_passes.keyframe.KeyframePolicy): the next frame is a keyframe when more than
`keyframe_threshold` of this frame's reflective pixels were recomputed.

Baselines (ReuseSettings.mode): "direct" — depth reprojection of the keyframe's
reflection as if it were view-independent (offsets all 0, Fig. 34/39 left);
"full" — the tracer on every reflective pixel of every frame.

The tracer is injected (gl_passes never imports reference): the Embree one is
reference.reflection_tracer.EmbreeTracer (exact ray lengths, sparse), the cluster
method gl_passes.cluster_tracer.ClusterTracer (Ch. 4; traces whole frames).
One reuser per camera stream, on its GL context's thread; release() frees its
GL resources (not the tracer's, which the caller owns).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Literal, Protocol

import numpy as np

from gl_passes.best_match import BestMatchPass
from gl_passes.composition import DISOCCLUDED, NOT_REFLECTIVE, UNRELIABLE, CompositionPass
from gl_passes.context import GLContext
from gl_passes.gbuffer import GBufferPass
from gl_passes.keyframe import MISS_DIAGONALS, KeyframePolicy, KeyframeTextures, ReflectionDepthImage, scatter_pixels
from gl_passes.laps import LapClock
from gl_passes.readback import read_texture
from gl_passes.reflection_offset import ReflectionOffsetPass
from gl_passes.reflection_splat import ReflectionSplatPass
from gl_passes.releasable import Releasable
from gl_passes.upload import SceneGPU
from scenes.camera import Camera

#: Flag of pixels traced as part of a keyframe (or by the full-tracing baseline).
TRACED = 4
MODES: tuple[str, ...] = ("reuse", "direct", "full")
WARPS: tuple[str, ...] = ("splat", "mesh")
#: Timed steps (Table 23): diffuse = G-buffer pass and its read-back; keyframe = storing
#: the reflection depth image and its grid mesh; best_match (§5.4.1); reflection_offset
#: (§5.4.2); warp = composition (§5.4.3); recompute = the tracer (all reflective pixels
#: on keyframes and in full tracing); blend = mix(diffuse, reflected, s).
STEPS = ("diffuse", "keyframe", "best_match", "reflection_offset", "warp", "recompute", "blend")


class Tracer(Protocol):
    """Reflections of selected pixels of a camera's image: `trace(camera, pixels)`
    with pixels (N,2) int (x, y), row 0 at the top → (reflected (N,3) float32 linear
    RGB, ray_length (N,) float64 world units, +inf on a miss, NaN where the tracer
    finds no reflective surface). `sparse`: the cost scales with N (ray tracers);
    False: the tracer renders the whole frame whatever N (the cluster method)."""

    name: str
    sparse: bool

    def trace(self, camera: Camera, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


@dataclass(frozen=True)
class ReuseSettings:
    """Parameters of the reuse (thesis values where it gives one).

    mode: "reuse" (Ch. 5), "direct" or "full" (baselines); keyframe_threshold:
    recomputed fraction of the reflective pixels above which the next frame is a
    keyframe (§5.4.4 uses 0.3 and calls it a quality/efficiency choice; 0.2 here:
    fewer pixels recomputed, faster and closer to the full trace on both benchmark
    scenes, bench/results/temporal_sweeps.md); max_steps: bound on Alg. 9's descent steps per pixel
    (a search that reaches it is invalid); growth: area ratio above which a warped
    triangle is dropped (§5.5.1: 16); plane_tolerance: same-surface test (depth
    discontinuity), in pixel footprints; reflected_jump: beyond the thesis, a
    triangle whose vertices' reflected-ray lengths differ by more than this fraction
    is dropped (0 = off, the default and the thesis: its growth limit alone catches
    the gaps of the reflected scene; on, it trades recomputed pixels for less smearing
    at reflected silhouettes; no benchmark measures it, and the stream leaves it off);
    miss_diagonals: the ray length given to rays that miss
    (sky), in scene diagonals; warp: how the grid mesh of §5.4.2 is rasterised —
    "splat" (gl_passes.reflection_splat: compute passes, no vertex pipeline; faster on
    a CPU rasteriser) or "mesh" (gl_passes.reflection_offset: GL's vertex, geometry
    and fragment stages); predict_start: beyond Alg. 9, an invalid search resumes
    where the previous frame's ended, a search starts at the extrapolation of
    the two previous frames' offsets where both are valid, and at the pixel's own
    plane match (its tangent plane's reflection of R toward the new eye, projected
    into the keyframe) where that is closer, which starts the first frames after a
    keyframe next to their match (fewer descent steps, the same local minima; False:
    the previous valid offset or the pixel itself, as the thesis); sync_timings:
    glFinish after each step, so the step times are the steps' own; search_stats:
    read Alg. 9's step counts back after each reused frame (ReuseStats; outside the
    timed steps — a stream can do without)."""

    mode: Literal["reuse", "direct", "full"] = "reuse"
    keyframe_threshold: float = 0.2
    max_steps: int = 64
    growth: float = 16.0
    plane_tolerance: float = 1.0
    reflected_jump: float = 0.0
    miss_diagonals: float = MISS_DIAGONALS
    warp: Literal["splat", "mesh"] = "splat"
    predict_start: bool = True
    sync_timings: bool = True
    search_stats: bool = True

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        if not 0.0 <= self.keyframe_threshold <= 1.0:
            raise ValueError("keyframe_threshold must be in [0, 1]")
        if self.max_steps < 1:
            raise ValueError("max_steps must be >= 1")
        for name in ("growth", "plane_tolerance", "miss_diagonals"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive")
        if self.reflected_jump < 0:
            raise ValueError("reflected_jump must be >= 0")
        if self.warp not in WARPS:
            raise ValueError(f"warp must be one of {WARPS}, got {self.warp!r}")


@dataclass
class ReuseStats:
    """One frame's account: keyframe (this frame was traced as a keyframe);
    reflective pixels; recomputed (traced) of them, split into disoccluded and
    unreliable on reused frames; search steps of Alg. 9 (mean over the keyframe's
    reflective pixels, max) and the invalid matches among them, among which
    step_bound_hits reached max_steps; timings_ms per STEPS plus "total"."""

    keyframe: bool
    reflective: int
    recomputed: int
    disoccluded: int = 0
    unreliable: int = 0
    search_steps_mean: float = 0.0
    search_steps_max: int = 0
    invalid_matches: int = 0
    step_bound_hits: int = 0
    timings_ms: dict[str, float] = field(default_factory=dict)

    @property
    def recomputed_fraction(self) -> float:
        """Recomputed / reflective pixels (0 without reflective pixels)."""
        return self.recomputed / self.reflective if self.reflective else 0.0


@dataclass
class ReuseFrame:
    """One frame of the reuse, the fields of ReflectionBuffers (one sample per
    pixel: specular = s, ray_length of the reflected ray, reused or traced) plus
    flags (H,W) uint8: composition.NOT_REFLECTIVE / REUSED / DISOCCLUDED /
    UNRELIABLE, or TRACED on keyframes and full tracing; and stats. color, diffuse,
    specular and reflective are images; reflected, ray_length and flags are built
    from the per-reflective-pixel values on first use (a stream needs only color).
    pixels (N,) int: the reflective pixels y·W + x (row 0 at the top); per_pixel:
    their (reflected (N,3) float32, ray_length (N,) float64, flags (N,) uint8)."""

    color: np.ndarray
    diffuse: np.ndarray
    specular: np.ndarray
    reflective: np.ndarray
    pixels: np.ndarray
    per_pixel: tuple[np.ndarray, np.ndarray, np.ndarray]
    stats: ReuseStats

    @cached_property
    def reflected(self) -> np.ndarray:
        """(H,W,3) float32 reflected colour, 0 off reflectors."""
        return scatter_pixels(self.pixels, self.per_pixel[0], (*self.specular.shape, 3), 0.0)

    @cached_property
    def ray_length(self) -> np.ndarray:
        """(H,W) float64 reflected-ray length, +inf on a miss, NaN off reflectors."""
        return scatter_pixels(self.pixels, self.per_pixel[1], self.specular.shape, np.nan)

    @cached_property
    def flags(self) -> np.ndarray:
        """(H,W) uint8 per-pixel class (NOT_REFLECTIVE off reflectors)."""
        return scatter_pixels(self.pixels, self.per_pixel[2], self.specular.shape, NOT_REFLECTIVE)

    @property
    def recomputed(self) -> np.ndarray:
        """(H,W) bool: pixels traced in this frame."""
        return self.flags >= DISOCCLUDED


class ReflectionReuser(Releasable):
    """Temporal reflection reuse for one camera stream (Alg. 8) on `gl`'s thread."""

    def __init__(self, gl: GLContext, scene_gpu: SceneGPU, tracer: Tracer,
                 settings: ReuseSettings | None = None) -> None:
        gl.check_thread()
        self.gl = gl
        self.scene_gpu = scene_gpu
        self.tracer = tracer
        self.settings = settings or ReuseSettings()
        self.policy = KeyframePolicy(self.settings.keyframe_threshold)
        self._frame_gb = GBufferPass(gl)
        self._key_gb = GBufferPass(gl)
        self.best_match = BestMatchPass(gl)
        self.offset: ReflectionOffsetPass | ReflectionSplatPass = (
            ReflectionSplatPass(gl) if self.settings.warp == "splat" else ReflectionOffsetPass(gl))
        self.compose = CompositionPass(gl)
        self.keyframe: KeyframeTextures | None = None
        self.frames = 0

    @property
    def miss_distance(self) -> float:
        return self.settings.miss_diagonals * self.scene_gpu.scene.diagonal

    def keyframe_image(self) -> ReflectionDepthImage | None:
        """The current keyframe's reflection depth image (§5.3), read back."""
        return self.keyframe.image() if self.keyframe is not None else None

    def next_frame(self, camera: Camera, keyframe: bool = False) -> ReuseFrame:
        """The frame for `camera` (near/far fitted to the scene when absent); a
        keyframe when the policy says so, or when the caller asks (`keyframe`: it
        knows the keyframe no longer fits, e.g. the camera jumped)."""
        self.gl.check_thread()
        st = self.settings
        ctx = self.gl.ctx
        cam = camera if camera.near is not None else camera.fit_clip(self.scene_gpu.scene.bounds)
        clock = LapClock(ctx, sync=st.sync_timings, ms=dict.fromkeys(STEPS, 0.0))
        lap = clock.lap

        # diffuse components and the new view's geometry (Alg. 8, first line)
        target = self._frame_gb.draw(self.scene_gpu, cam)
        tex = target.textures
        color_s = read_texture(tex["color"])  # rgb: diffuse colour; a: s (0 on the background)
        diffuse, s = color_s[..., :3], np.ascontiguousarray(color_s[..., 3])
        reflective = s > 0
        flat = np.flatnonzero(reflective)  # the reflective pixels, y·W + x with row 0 at the top
        n_refl = len(flat)
        lap("diffuse")
        kf = self.keyframe
        is_key = (keyframe or st.mode == "full" or self.policy.due or kf is None
                  or kf.target.size != (cam.width, cam.height))
        stats = ReuseStats(keyframe=is_key, reflective=n_refl, recomputed=0)
        if is_key:
            refl = np.zeros((n_refl, 3), np.float32)  # per reflective pixel: Lr, r
            rlen = np.full(n_refl, np.nan)
            pix_flags = np.full(n_refl, TRACED, np.uint8)
            self._trace_into(cam, flat, np.arange(n_refl), refl, rlen)
            stats.recomputed = n_refl
            lap("recompute")
            if st.mode != "full":
                self._store_keyframe(cam, flat, refl, rlen)
                self.policy.due = False
            lap("keyframe")
        else:
            assert kf is not None
            offsets = self.best_match.run(kf, np.asarray(cam.eye), st.max_steps, st.plane_tolerance,
                                          direct=st.mode == "direct", predict=st.predict_start)
            lap("best_match")
            inter = self.offset.run(kf, offsets, st.growth, st.plane_tolerance, st.reflected_jump)
            lap("reflection_offset")
            out, pix_flags = self.compose.run(target, kf, inter, st.plane_tolerance, flat)
            # every pixel not reused is traced below, over these rows
            refl = np.array(out[:, :3])
            rlen = out[:, 3].astype(np.float64)
            rlen[rlen >= 0.999 * self.miss_distance] = np.inf
            lap("warp")
            redo = np.flatnonzero(pix_flags >= DISOCCLUDED)
            self._trace_into(cam, flat[redo], redo, refl, rlen)
            stats.recomputed = len(redo)
            stats.disoccluded = int(np.count_nonzero(pix_flags == DISOCCLUDED))
            stats.unreliable = int(np.count_nonzero(pix_flags == UNRELIABLE))
            lap("recompute")
            self.policy.update(stats.recomputed_fraction)
        color = np.array(diffuse)  # (H,W,3), contiguous
        cf = color.reshape(-1, 3)
        sv = s.reshape(-1)[flat][:, None]
        cf[flat] = cf[flat] * (1.0 - sv) + refl * sv
        frame = ReuseFrame(color=color, diffuse=diffuse, specular=s, reflective=reflective,
                           pixels=flat, per_pixel=(refl, rlen, pix_flags), stats=stats)
        lap("blend")
        clock.ms["total"] = clock.total_ms()
        stats.timings_ms = clock.ms
        if not is_key and st.mode == "reuse" and st.search_stats:
            self._search_stats(stats)
        self.frames += 1
        return frame

    def _trace_into(self, cam: Camera, flat: np.ndarray, rows: np.ndarray, reflected: np.ndarray,
                    length: np.ndarray) -> None:
        """Trace the pixels `flat` (y·W + x, row 0 at the top) into rows `rows` of
        the per-reflective-pixel arrays."""
        if len(flat) == 0:
            return
        ys, xs = np.divmod(flat, cam.width)
        col, r = self.tracer.trace(cam, np.stack([xs, ys], axis=1))
        reflected[rows] = col
        length[rows] = r

    def _store_keyframe(self, cam: Camera, pixels: np.ndarray, reflected: np.ndarray, length: np.ndarray) -> None:
        """§5.3: this frame's G-buffer target becomes the keyframe's (the passes swap);
        pixels (N,) y·W + x (row 0 at the top) with their traced values."""
        if self.keyframe is not None:
            self.keyframe.release()
            self.keyframe = None  # not released twice if the new one fails
        self._frame_gb, self._key_gb = self._key_gb, self._frame_gb
        target = self._key_gb.target
        assert target is not None
        self.keyframe = KeyframeTextures(self.gl, target, cam, pixels, reflected, length, self.miss_distance)
        self.offset.prepare(self.keyframe, self.settings.plane_tolerance)
        self.best_match.reset()

    def _search_stats(self, stats: ReuseStats) -> None:
        """Alg. 9's step counts over the keyframe's reflective pixels (read back
        after the timed steps)."""
        assert self.keyframe is not None
        off = self.best_match.read()
        refl = np.isfinite(self.keyframe.ray_length) | np.isposinf(self.keyframe.ray_length)
        steps = off[..., 3][refl]
        valid = off[..., 2][refl] > 0.5
        stats.search_steps_mean = float(steps.mean()) if steps.size else 0.0
        stats.search_steps_max = int(steps.max(initial=0))
        stats.invalid_matches = int((~valid).sum())
        stats.step_bound_hits = int((steps >= self.settings.max_steps).sum())

    def release(self) -> None:
        self.gl.check_thread()
        if self.keyframe is not None:
            self.keyframe.release()
            self.keyframe = None
        for p in (self._frame_gb, self._key_gb, self.best_match, self.offset, self.compose):
            p.release()

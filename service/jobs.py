"""Every render job of the service, typed, in one module.

A job is a callable ``Job[T] = (GLState) -> T`` that the ``RenderWorker`` runs on its
GL thread (DESIGN.md: request handlers never touch GL). Each job below is a small
frozen dataclass — a picklable spec: the scene's content address (also the GPU-cache
key), the scene itself when the caller has it (never pickled: a worker in another
process loads the scene by its address, ``GLState.scene``) and the request parameters
(fitted cameras, methods) — whose result is plain numpy data, so encoding runs off the
GL thread.

Embree work (ray-traced reflections, the soft-shadow truth, visibility-redundancy
sets, the sampling metrics) runs inside these jobs too, on the worker thread without
touching GL: every render path shares the one bounded queue (503 + Retry-After when
full) and the job timeout (504), and Embree never competes with the GL work for the
cores behind the queue's back. Only shading and encoding stay in the thread pool.

=====================  ==============================================================
job                    result
=====================  ==============================================================
``FrameJob``           ``GBuffer`` of one camera
``ReflectionJob``      ``ReflectionResult`` (cluster depth images or env map, Ch. 4)
``RaytraceJob``        (``ReflectionResult`` of the Embree reference, step ms, cache hits; off-GL)
``SoftShadowJob``      (``GBuffer``, visible light samples per pixel, step ms, cache hits; Embree for raytrace)
``ReconstructionJob`` per source image (positions, RGBA8 colours, triangles), Ch. 3
``SetJob``             (depth-image set by GL or Embree, §2.3.2 metrics or None), Ch. 2
=====================  ==============================================================
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from gl_passes.depth_images import DepthImageRenderer, conventional, depth_peeling, non_redundant
from gl_passes.gbuffer import GBuffer
from gl_passes.laps import LapClock
from gl_passes.mesh_gpu import MeshGPU
from gl_passes.reconstruction import ReconstructionSettings, reconstruct_set, render_set
from gl_passes.reflections import DEFAULT_SETTINGS, ClusterReflections
from gl_passes.shadows import ShadowMaps, ShadowSettings, SoftShadowPass
from gl_passes.upload import SceneGPU
from scenes.camera import Camera
from scenes.depth_image import DepthImage
from scenes.lights import PEEL_LAYERS, reference_cameras
from scenes.model import Scene
from service.depth_sets import SetPlan, embree_set, needs_gl, set_metrics
from service.effects import raytrace_cached
from service.soft_shadows import (
    MeshArrays,
    SoftShadowRequest,
    light_problem_message,
    raytrace_counts,
    shadow_light_problem,
)
from service.worker import GLState

T = TypeVar("T")
#: A render job: runs on the worker's GL thread with its GLState.
Job = Callable[[GLState], T]

#: API method name → gl_passes.reflections method name.
GL_REFLECTION_METHODS = {"cluster": "clusters", "envmap": "envmap"}


class SceneJob:
    """Base of the job specs: `scene_key` (content address) and `scene` (or None).
    Pickling drops the scene; the receiving worker loads it by its address."""

    scene_key: str
    scene: Scene | None

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "scene": None}

    def load(self, state: GLState) -> Scene:
        return self.scene if self.scene is not None else state.scene(self.scene_key)


@dataclass(frozen=True)
class FrameJob(SceneJob):
    """The ``GBuffer`` of the scene seen by `camera` (near/far already fitted)."""

    scene_key: str
    scene: Scene | None
    camera: Camera
    cull_back_faces: bool = True

    def __call__(self, state: GLState) -> GBuffer:
        gpu = state.scene_gpu(self.scene_key, self.load(state))
        return state.gbuffer.render(gpu, self.camera, cull_back_faces=self.cull_back_faces)


def _reflection_renderer(gl: Any) -> ClusterReflections:
    """The worker's one cluster renderer, with the settings the benchmarks measure."""
    return ClusterReflections(gl, DEFAULT_SETTINGS)


@dataclass(frozen=True)
class ReflectionJob(SceneJob):
    """Reflections with the GL method `method` (cluster | envmap)."""

    scene_key: str
    scene: Scene | None
    camera: Camera
    method: str
    glossy_rays: int

    def __call__(self, state: GLState) -> Any:
        """The result's timings_ms and cache_hits gain "upload" (the scene's GPU upload,
        ~0 when cached): a later frame of the scene reuses the upload and the renderer's
        per-scene records (cache_hits["scene_setup"])."""
        t0 = time.perf_counter()
        hit = state.has_scene(self.scene_key)
        gpu = state.scene_gpu(self.scene_key, self.load(state))
        upload_ms = (time.perf_counter() - t0) * 1e3
        renderer = state.resource("reflections", _reflection_renderer, pixels=self.camera.width * self.camera.height)
        result = renderer.render(gpu, self.camera, glossy_rays=self.glossy_rays,
                                 method=GL_REFLECTION_METHODS[self.method])
        result.timings_ms["upload"] = upload_ms
        result.cache_hits["upload"] = hit
        return result


@dataclass(frozen=True)
class RaytraceJob(SceneJob):
    """Reflections by the Embree reference with the scene's BVH cached per worker
    (``service.effects.raytrace_cached``): no GL, but queued and timed like every
    render. Returns (result, timings ms, cache hits)."""

    scene_key: str
    scene: Scene | None
    camera: Camera
    glossy_rays: int

    def __call__(self, state: GLState) -> Any:
        return raytrace_cached(self.scene_key, self.load(state), self.camera, self.glossy_rays)


def _shadow_pass(state: GLState, samples: int, pixels: int) -> SoftShadowPass:
    """The worker's soft-shadow pass, for k = `samples` (one at a time: its atlas
    and buffers are remade when k changes; kept maps stay valid for any pass of
    their settings), for a frame of `pixels` receivers."""
    settings = ShadowSettings(samples=samples)
    return state.resource("soft_shadows", lambda gl: SoftShadowPass(gl, settings), settings, pixels)


def _reconstruction(state: GLState, scene_key: str, scene: Scene, cameras: Sequence[Camera], method: str,
                    kind: str, layers: int = PEEL_LAYERS, sides: str = "front"
                    ) -> AbstractContextManager[Sequence[MeshGPU]]:
    """The reconstruction (one mesh per image, `ReconstructionSettings(kind=kind)`)
    of the `method` images of `cameras`, their back faces culled (sides = "front")
    or not ("both"), from the worker's cache when a job before made the same
    (`GLState.kept`): a light's depth images are made once for every frame under it."""
    def build() -> list[MeshGPU]:
        gpu = state.scene_gpu(scene_key, scene)
        sampled = render_set(state.gl, gpu, method, cameras, layers=layers, offsets=kind != "grid",
                             cull_back_faces=sides == "front")
        return reconstruct_set(state.gl, sampled, ReconstructionSettings(kind=kind))

    what = (method, kind, layers if method == "peeling" else 0, sides, tuple(cameras))
    return state.kept(scene_key, what, build)


@dataclass(frozen=True)
class SoftShadowJob(SceneJob):
    """(G-buffer of `camera`, per-pixel visible light samples (H,W) uint16): by shadow
    maps, or for `raytrace` by Embree (after the G-buffer, no GL). The maps depend
    on the light and the occluders only: where all k² of them fit the worker's
    `reconstruction_cache_bytes` they are kept (`GLState.kept`) and the next frame
    under the same light only looks them up; otherwise they are drawn batch by batch
    (`SoftShadowPass.visibility`), over a reconstruction kept where it fits. A light
    the shadow maps cannot render (`shadow_light_problem`) is a ValueError (422)
    before the G-buffer."""

    scene_key: str
    scene: Scene | None
    camera: Camera
    req: SoftShadowRequest
    cull_back_faces: bool = True

    def __call__(self, state: GLState) -> tuple[GBuffer, np.ndarray, dict[str, float], dict[str, bool]]:
        """(G-buffer, visible counts, milliseconds per step, cache hits) (Server-Timing):
        gbuffer, then trace (raytrace), or occluders + shadow_maps (made, or kept from an
        earlier frame: a cache hit) and lookup; occluders_maps_lookup where the maps are
        drawn batch by batch."""
        scene, req = self.load(state), self.req
        problem = None if req.method == "raytrace" else shadow_light_problem(req.light, req.samples, scene.bounds)
        if problem is not None:
            raise ValueError(light_problem_message(problem))  # 422
        clock = LapClock(state.gl.ctx)
        gpu = state.scene_gpu(self.scene_key, scene)
        gbuf = state.gbuffer.render(gpu, self.camera, cull_back_faces=self.cull_back_faces)
        clock.lap("gbuffer")
        if req.method == "raytrace":
            counts = raytrace_counts(self.scene_key, scene, gbuf, req)
            clock.lap("trace")
            return gbuf, counts, clock.ms, {}
        shadows = _shadow_pass(state, req.samples, self.camera.width * self.camera.height)
        if shadows.maps_nbytes > state.reconstruction_cache_bytes:
            with self._occluders(state, scene, gpu) as occ:
                res = shadows.visibility(occ, scene.bounds, gbuf.position, gbuf.normal, gbuf.mask, req.light)
            clock.lap("occluders_maps_lookup")
            return gbuf, res.counts, clock.ms, {}

        made = []

        def maps() -> list[ShadowMaps]:
            made.append(True)
            with self._occluders(state, scene, gpu) as occ:
                clock.lap("occluders", finish=True)
                out = [shadows.render_maps(occ, scene.bounds, req.light)]
                clock.lap("shadow_maps", finish=True)
                return out

        images = (req.reconstruction, req.resolution, req.sides) if req.method != "geometry" else ()
        what = ("shadow maps", req.method, *images, req.light, shadows.settings)
        with state.kept(self.scene_key, what, maps, shadows.maps_nbytes) as kept:
            if not made:
                clock.lap("shadow_maps")
            res = shadows.lookup(kept[0], gbuf.position, gbuf.normal, gbuf.mask)
            clock.lap("lookup")
        return gbuf, res.counts, clock.ms, {"shadow_maps": not made}

    def _occluders(self, state: GLState, scene: Scene, gpu: SceneGPU) -> AbstractContextManager[Sequence[Any]]:
        """The scene itself (`geometry`) or the reconstruction of the light's images."""
        if self.req.method == "geometry":
            return nullcontext([gpu])
        cams = reference_cameras(self.req.light, scene.bounds, self.req.method, self.req.resolution)
        return _reconstruction(state, self.scene_key, scene, cams, self.req.method, self.req.reconstruction,
                               sides=self.req.sides)


@dataclass(frozen=True)
class ReconstructionJob(SceneJob):
    """Per source image (positions, RGBA8 colours, triangles) of the reconstruction;
    `gl_passes.reconstruction.glb_bytes` encodes them off the GL thread."""

    scene_key: str
    scene: Scene | None
    cameras: Sequence[Camera]
    method: str
    kind: str
    layers: int = PEEL_LAYERS
    sides: str = "front"

    def __call__(self, state: GLState) -> list[MeshArrays]:
        with _reconstruction(state, self.scene_key, self.load(state), self.cameras, self.method, self.kind,
                             self.layers, self.sides) as meshes:
            return [m.read() for m in meshes]


@dataclass(frozen=True)
class SetJob(SceneJob):
    """(the set — by GL, or by Embree for visibility redundancy —, its §2.3.2 metrics
    over `metrics_views` intermediate views (Embree; the conventional images of the
    reference cameras rendered beside the set) or None when `metrics_views` is None)."""

    scene_key: str
    scene: Scene | None
    plan: SetPlan
    metrics_views: int | None = None
    seed: int = 0

    def __call__(self, state: GLState) -> tuple[list[DepthImage], dict | None]:
        scene, plan, want_metrics = self.load(state), self.plan, self.metrics_views is not None
        images, conv = _gl_set(state, self.scene_key, scene, plan, want_metrics) \
            if needs_gl(plan, want_metrics) else (None, None)
        if images is None:
            images = embree_set(scene, plan)
        if not want_metrics:
            return images, None
        return images, set_metrics(scene, plan, images, conv, self.metrics_views, self.seed)


def _gl_set(state: GLState, scene_key: str, scene: Scene, plan: SetPlan, want_conventional: bool
            ) -> tuple[list[DepthImage] | None, list[DepthImage] | None]:
    """(the set rendered by GL — None when it is Embree-only —, the conventional
    images of the reference cameras when wanted)."""
    gpu = state.scene_gpu(scene_key, scene)
    drawn = plan.cameras + ([plan.peel_camera] if plan.peel_camera is not None else [])
    renderer = state.resource("depth_images", DepthImageRenderer, pixels=max(c.width * c.height for c in drawn))
    gl = state.gl
    images = None
    if plan.method == "conventional":
        images = conventional(gl, gpu, plan.cameras, renderer=renderer)
    elif plan.method == "peeling":
        assert plan.peel_camera is not None  # plan_set makes it for peeling
        images = depth_peeling(gl, gpu, plan.peel_camera, plan.layers, renderer=renderer)
    elif plan.redundancy == "pixel":
        images = non_redundant(gl, gpu, plan.cameras, renderer=renderer)
    conv = None
    if want_conventional:
        conv = images if plan.method == "conventional" else conventional(gl, gpu, plan.cameras, renderer=renderer)
    return images, conv

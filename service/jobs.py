"""Every render job of the service, typed, in one module.

A job is a callable ``Job[T] = (GLState) -> T`` that the ``RenderWorker`` runs on its
GL thread (DESIGN.md: request handlers never touch GL). Each builder below captures
what the job needs (the scene's content address as the GPU-cache key, the scene, the
fitted cameras) and returns a job whose result is plain numpy data, so encoding runs
off the GL thread.

Embree work (ray-traced reflections, the soft-shadow truth, visibility-redundancy
sets, the sampling metrics) runs inside these jobs too, on the worker thread without
touching GL: every render path shares the one bounded queue (503 + Retry-After when
full) and the job timeout (504), and Embree never competes with the GL work for the
cores behind the queue's back. Only shading and encoding stay in the thread pool.

=====================  ==============================================================
builder                result of the job
=====================  ==============================================================
``frame_job``          ``GBuffer`` of one camera
``reflection_job``     ``ReflectionResult`` (cluster depth images or env map, Ch. 4)
``raytrace_job``       ``ReflectionResult`` of the Embree reference (off-GL)
``soft_shadow_job``    (``GBuffer``, visible light samples per pixel; Embree for raytrace)
``reconstruction_job`` per source image (positions, RGBA8 colours, triangles), Ch. 3
``set_job``            (depth-image set by GL or Embree, §2.3.2 metrics or None), Ch. 2
=====================  ==============================================================
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import numpy as np

from gl_passes.depth_images import DepthImageRenderer, conventional, depth_peeling, non_redundant
from gl_passes.gbuffer import GBuffer
from gl_passes.reconstruction import ReconstructionSettings, reconstruct_set, render_set
from gl_passes.reflections import ClusterReflections
from gl_passes.shadows import ShadowSettings, SoftShadowPass
from scenes.camera import Camera
from scenes.depth_image import DepthImage
from scenes.model import Scene
from service.depth_sets import SetPlan, embree_set, needs_gl, set_metrics
from service.effects import raytrace
from service.soft_shadows import PEEL_LAYERS, MeshArrays, SoftShadowRequest, raytrace_counts, reference_cameras
from service.worker import GLState

T = TypeVar("T")
#: A render job: runs on the worker's GL thread with its GLState.
Job = Callable[[GLState], T]

#: API method name → gl_passes.reflections method name.
GL_REFLECTION_METHODS = {"cluster": "clusters", "envmap": "envmap"}
#: Cluster-image atlas limits for the service: at most 2048² texels and 8 texels per
#: G-buffer sample (the renderer's 4096² default atlas costs about 1.4 GB).
ATLAS_MAX = 2048
ATLAS_BUDGET = 8.0


def frame_job(scene_key: str, scene: Scene, camera: Camera, cull_back_faces: bool = True) -> Job[GBuffer]:
    """The G-buffer of `scene` (GPU upload cached under `scene_key`) seen by `camera`
    (near/far already fitted)."""

    def run(state: GLState) -> GBuffer:
        gpu = state.scene_gpu(scene_key, scene)
        return state.gbuffer.render(gpu, camera, cull_back_faces=cull_back_faces)

    return run


def _reflection_renderer(gl: Any) -> ClusterReflections:
    return ClusterReflections(gl, atlas_max=ATLAS_MAX, atlas_budget=ATLAS_BUDGET)


def reflection_job(scene_key: str, scene: Scene, camera: Camera, method: str, glossy_rays: int) -> Job[Any]:
    """Reflections with the GL method `method` (cluster | envmap)."""

    def run(state: GLState) -> Any:
        gpu = state.scene_gpu(scene_key, scene)
        renderer = state.resource("reflections", _reflection_renderer)
        return renderer.render(gpu, camera, glossy_rays=glossy_rays, method=GL_REFLECTION_METHODS[method])

    return run


def raytrace_job(scene: Scene, camera: Camera, glossy_rays: int) -> Job[Any]:
    """Reflections by the Embree reference (``service.effects.raytrace``): no GL, but
    queued and timed like every render."""

    def run(state: GLState) -> Any:
        return raytrace(scene, camera, glossy_rays)

    return run


def _shadow_pass(state: GLState, samples: int) -> SoftShadowPass:
    return state.resource(f"soft_shadows_{samples}", lambda gl: SoftShadowPass(gl, ShadowSettings(samples=samples)))


def _reconstruct(state: GLState, scene_key: str, scene: Scene, cameras: Sequence[Camera], method: str,
                 kind: str, layers: int = PEEL_LAYERS) -> list:
    gpu = state.scene_gpu(scene_key, scene)
    sampled = render_set(state.gl, gpu, method, cameras, layers=layers, offsets=kind != "grid")
    return reconstruct_set(state.gl, sampled, ReconstructionSettings(kind=kind))


def soft_shadow_job(scene_key: str, scene: Scene, camera: Camera, req: SoftShadowRequest
                    ) -> Job[tuple[GBuffer, np.ndarray]]:
    """(G-buffer of `camera`, per-pixel visible light samples (H,W) uint16): by shadow
    maps, or for `raytrace` by Embree (after the G-buffer, no GL)."""

    def run(state: GLState) -> tuple[GBuffer, np.ndarray]:
        gpu = state.scene_gpu(scene_key, scene)
        gbuf = state.gbuffer.render(gpu, camera)
        if req.method == "raytrace":
            return gbuf, raytrace_counts(scene, gbuf, req)
        if req.method == "geometry":
            occluders, owned = [gpu], []
        else:
            cams = reference_cameras(scene, req.light, req.method, req.resolution)
            owned = _reconstruct(state, scene_key, scene, cams, req.method, req.reconstruction)
            occluders = owned
        try:
            res = _shadow_pass(state, req.samples).visibility(
                occluders, scene.bounds, gbuf.position, gbuf.normal, gbuf.mask, req.light)
        finally:
            for m in owned:
                m.release()
        return gbuf, res.counts

    return run


def reconstruction_job(scene_key: str, scene: Scene, cameras: Sequence[Camera], method: str,
                       kind: str, layers: int = PEEL_LAYERS) -> Job[list[MeshArrays]]:
    """Per source image (positions, RGBA8 colours, triangles) of the reconstruction;
    `gl_passes.reconstruction.glb_bytes` encodes them off the GL thread."""

    def run(state: GLState) -> list[MeshArrays]:
        meshes = _reconstruct(state, scene_key, scene, cameras, method, kind, layers)
        try:
            return [m.read() for m in meshes]
        finally:
            for m in meshes:
                m.release()

    return run


def set_job(scene_key: str, scene: Scene, plan: SetPlan, metrics_views: int | None = None, seed: int = 0
            ) -> Job[tuple[list[DepthImage], dict | None]]:
    """(the set — by GL, or by Embree for visibility redundancy —, its §2.3.2 metrics
    over `metrics_views` intermediate views (Embree; the conventional images of the
    reference cameras rendered beside the set) or None when `metrics_views` is None)."""
    want_metrics = metrics_views is not None

    def run(state: GLState) -> tuple[list[DepthImage], dict | None]:
        images, conv = _gl_set(state, scene_key, scene, plan, want_metrics) if needs_gl(plan, want_metrics) \
            else (None, None)
        if images is None:
            images = embree_set(scene, plan)
        if not want_metrics:
            return images, None
        return images, set_metrics(scene, plan, images, conv, metrics_views, seed)

    return run


def _gl_set(state: GLState, scene_key: str, scene: Scene, plan: SetPlan, want_conventional: bool
            ) -> tuple[list[DepthImage] | None, list[DepthImage] | None]:
    """(the set rendered by GL — None when it is Embree-only —, the conventional
    images of the reference cameras when wanted)."""
    gpu = state.scene_gpu(scene_key, scene)
    renderer = state.resource("depth_images", DepthImageRenderer)
    gl = state.gl
    images = None
    if plan.method == "conventional":
        images = conventional(gl, gpu, plan.cameras, renderer=renderer)
    elif plan.method == "peeling":
        images = depth_peeling(gl, gpu, plan.peel_camera, plan.layers, renderer=renderer)
    elif plan.redundancy == "pixel":
        images = non_redundant(gl, gpu, plan.cameras, renderer=renderer)
    conv = None
    if want_conventional:
        conv = images if plan.method == "conventional" else conventional(gl, gpu, plan.cameras, renderer=renderer)
    return images, conv

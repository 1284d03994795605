"""Every render job of the service, typed, in one module.

A job is a callable ``Job[T] = (GLState) -> T`` that the ``RenderWorker`` runs on its
GL thread (DESIGN.md: request handlers never touch GL). Each builder below captures
what the job needs (the scene's content address as the GPU-cache key, the scene, the
fitted cameras) and returns a job whose result is plain numpy data, so encoding runs
off the GL thread.

=====================  ==============================================================
builder                result of the job
=====================  ==============================================================
``frame_job``          ``GBuffer`` of one camera
``reflection_job``     ``ReflectionResult`` (cluster depth images or env map, Ch. 4)
``soft_shadow_job``    (``GBuffer``, visible light samples per pixel or None for raytrace)
``reconstruction_job`` per source image (positions, RGBA8 colours, triangles), Ch. 3
``set_job``            (GL depth-image set or None, conventional images or None), Ch. 2
=====================  ==============================================================
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import numpy as np

from gl_passes.depth_images import DepthImageRenderer, conventional, depth_peeling, non_redundant
from gl_passes.gbuffer import GBuffer
from gl_passes.reconstruction import ReconstructionSettings, reconstruct_set, render_set
from gl_passes.reflections import DEFAULT_SETTINGS, ClusterReflections
from gl_passes.shadows import ShadowSettings, SoftShadowPass
from scenes.camera import Camera
from scenes.depth_image import DepthImage
from scenes.model import Scene
from service.depth_sets import SetPlan
from service.soft_shadows import PEEL_LAYERS, MeshArrays, SoftShadowRequest, reference_cameras
from service.worker import GLState

T = TypeVar("T")
#: A render job: runs on the worker's GL thread with its GLState.
Job = Callable[[GLState], T]

#: API method name → gl_passes.reflections method name.
GL_REFLECTION_METHODS = {"cluster": "clusters", "envmap": "envmap"}


def frame_job(scene_key: str, scene: Scene, camera: Camera, cull_back_faces: bool = True) -> Job[GBuffer]:
    """The G-buffer of `scene` (GPU upload cached under `scene_key`) seen by `camera`
    (near/far already fitted)."""

    def run(state: GLState) -> GBuffer:
        gpu = state.scene_gpu(scene_key, scene)
        return state.gbuffer.render(gpu, camera, cull_back_faces=cull_back_faces)

    return run


def _reflection_renderer(gl: Any) -> ClusterReflections:
    """The worker's one cluster renderer, with the settings the benchmarks measure."""
    return ClusterReflections(gl, DEFAULT_SETTINGS)


def reflection_job(scene_key: str, scene: Scene, camera: Camera, method: str, glossy_rays: int) -> Job[Any]:
    """Reflections with the GL method `method` (cluster | envmap). The result's
    timings_ms and cache_hits gain "upload" (the scene's GPU upload, ~0 when cached): a
    later frame of the scene reuses the upload and the renderer's per-scene records
    (cache_hits["scene_setup"])."""

    def run(state: GLState) -> Any:
        t0 = time.perf_counter()
        hit = state.has_scene(scene_key)
        gpu = state.scene_gpu(scene_key, scene)
        upload_ms = (time.perf_counter() - t0) * 1e3
        renderer = state.resource("reflections", _reflection_renderer)
        result = renderer.render(gpu, camera, glossy_rays=glossy_rays, method=GL_REFLECTION_METHODS[method])
        result.timings_ms["upload"] = upload_ms
        result.cache_hits["upload"] = hit
        return result

    return run


def _shadow_pass(state: GLState, samples: int) -> SoftShadowPass:
    return state.resource(f"soft_shadows_{samples}", lambda gl: SoftShadowPass(gl, ShadowSettings(samples=samples)))


def _reconstruct(state: GLState, scene_key: str, scene: Scene, cameras: Sequence[Camera], method: str,
                 kind: str, layers: int = PEEL_LAYERS) -> list:
    gpu = state.scene_gpu(scene_key, scene)
    sampled = render_set(state.gl, gpu, method, cameras, layers=layers, offsets=kind != "grid")
    return reconstruct_set(state.gl, sampled, ReconstructionSettings(kind=kind))


def soft_shadow_job(scene_key: str, scene: Scene, camera: Camera, req: SoftShadowRequest
                    ) -> Job[tuple[GBuffer, np.ndarray | None]]:
    """(G-buffer of `camera`, per-pixel visible light samples (H,W) uint16, or None for
    `raytrace`, whose visibility is computed off the GL thread)."""

    def run(state: GLState) -> tuple[GBuffer, np.ndarray | None]:
        gpu = state.scene_gpu(scene_key, scene)
        gbuf = state.gbuffer.render(gpu, camera)
        if req.method == "raytrace":
            return gbuf, None
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


def set_job(scene_key: str, scene: Scene, plan: SetPlan, want_conventional: bool
            ) -> Job[tuple[list[DepthImage] | None, list[DepthImage] | None]]:
    """(the set rendered by GL — None when it is Embree-only —, the conventional
    images of the reference cameras when wanted)."""

    def run(state: GLState) -> tuple[list[DepthImage] | None, list[DepthImage] | None]:
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

    return run

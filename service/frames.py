"""One frame of a stored scene, as ``POST /scenes/{id}/frames`` and the stream render it.

``render(r, scene_id, req)`` loads the scene, runs the frame's jobs (G-buffer,
reflections by method, soft shadows; Embree's too) on the worker and the shading in the
thread pool, and returns a ``Rendered``: the linear colour (what the stream encodes as JPEG or
PNG) and ``encode(fmt)``, the frames endpoint's PNG/EXR encoder of every buffer. The
caller checks the size limits and the memory budget first.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from fastapi import HTTPException

from scenes.camera import Camera
from scenes.lights import light_reach_problem
from scenes.model import AreaLight, Scene
from service.deps import Render
from service.effects import encode_reflections
from service.jobs import FrameJob, RaytraceJob, ReflectionJob, SoftShadowJob
from service.schemas import FrameRequest
from service.soft_shadows import (
    SoftShadowRequest,
    encode_shadowed,
    light_problem_message,
    resolve_light,
    shade,
)
from service.worker import encode_frame


@dataclass(frozen=True)
class Rendered:
    """A rendered frame: linear colour (H,W,3) float32 and the encoder of its buffers
    (``encode("png" | "exr") -> bytes``; CPU only, call it off the event loop);
    reflective and soft-shadow frames add their per-step milliseconds and cache hits (Server-Timing)."""

    color: np.ndarray
    encode: Callable[[str], bytes]
    steps_ms: dict[str, float] = field(default_factory=dict)
    cache_hits: dict[str, bool] = field(default_factory=dict)


async def render(r: Render, scene_id: str, req: FrameRequest) -> Rendered:
    """The frame `req` of scene `scene_id` (HTTPException as the frames endpoint answers)."""
    scene = await r.scene(scene_id)
    camera = req.to_camera().fit_clip(scene.bounds)
    label = f"frame {scene_id[:12]}"
    method, rays = req.effects.reflections, req.effects.glossy_rays
    if req.effects.soft_shadows is not None:
        return await _soft_shadows(r, scene_id, scene, camera, req, label)
    if method == "none":
        gbuf = await r.job(FrameJob(scene_id, scene, camera, req.cull_back_faces), label)
        return Rendered(gbuf.color, lambda fmt: encode_frame(gbuf, fmt))
    if method == "raytrace":
        result, steps, hits = await r.job(RaytraceJob(scene_id, scene, camera, rays), label)
    else:
        result = await r.job(ReflectionJob(scene_id, scene, camera, method, rays), label)
        steps, hits = result.timings_ms, result.cache_hits
    return Rendered(np.asarray(result.color, np.float32), lambda fmt: encode_reflections(result, fmt),
                    dict(steps), dict(hits))


async def _soft_shadows(r: Render, scene_id: str, scene: Scene, camera: Camera, req: FrameRequest,
                        label: str) -> Rendered:
    spec = req.effects.soft_shadows
    assert spec is not None
    light = resolve_light(scene, None if spec.light is None else
                          AreaLight(spec.light.center, spec.light.u, spec.light.v))
    ss = SoftShadowRequest(light, spec.samples, spec.method, spec.reconstruction, spec.resolution, spec.sides)
    if spec.method != "raytrace":  # the rest of the light's check runs in the job (`shadow_light_problem`)
        problem = light_reach_problem(light, scene.bounds)
        if problem is not None:
            raise HTTPException(422, light_problem_message(problem))
    gbuf, counts, steps, hits = await r.job(SoftShadowJob(scene_id, scene, camera, ss, req.cull_back_faces), label)
    t0 = time.perf_counter()
    color = await r.cpu(shade, scene, gbuf, counts, ss)
    return Rendered(color, lambda fmt: encode_shadowed(color, gbuf, counts, fmt),
                    {**steps, "shade": (time.perf_counter() - t0) * 1e3}, hits)

"""Soft shadows and reconstructions for the service (thesis Ch. 3, Alg. 4–5).

GL work (G-buffer, reference images, reconstruction, shadow maps) runs only in
the worker jobs (`service.jobs.SoftShadowJob`, `ReconstructionJob`), on the
worker thread; the Embree truth (`raytrace`) runs in the same job without GL (queued
and timed like the rest), the shading here in the thread pool.
The settings are the benchmark's (`bench/soft_shadows.py`):
`ShadowSettings` with its default shadow-map resolution, reference images of
`resolution`² from the light's 4 corners (peeling: 4 layers from its centre),
`ReconstructionSettings` defaults per kind.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np

from reference.shadows import light_visibility, visible_counts
from scenes.lights import default_area_light, reference_cameras, shadow_map_camera
from scenes.model import AreaLight, Scene
from scenes.shading import area_light_shade
from service import image_io
from service.effects import CASTERS
from service.excerpts import quoted

#: A mesh read back: positions (N,3), RGBA8 colours (N,4), triangles (M,3).
MeshArrays = tuple[np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True)
class SoftShadowRequest:
    """What one frame's soft shadows need (validated by the schema)."""

    light: AreaLight
    samples: int
    method: str
    reconstruction: str
    resolution: int
    sides: str = "front"


def resolve_light(scene: Scene, light: AreaLight | None) -> AreaLight:
    """The request's light, or the default one sized to the scene (diagonal = scene diagonal)."""
    return light if light is not None else default_area_light(scene.bounds, scene.sun_direction)


def light_problem_message(problem: str) -> str:
    """The 422 detail for a soft-shadow light the shadow-map methods cannot render."""
    return (f"soft_shadows light: {problem}; its shadow maps and depth images need the scene in front of it, "
            "within a pinhole's view and MAX_LIGHT_REACH scene diagonals (method raytrace does not)")


def shadow_light_problem(light: AreaLight, samples: int, bounds: tuple[np.ndarray, np.ndarray]) -> str | None:
    """Why `light` cannot be rendered by shadow maps (samples² of them) and depth images
    of the box `bounds` (`scenes.lights.light_camera`'s ValueError), or None. Up to 1024
    cameras to build: `SoftShadowJob` asks it on the worker, before the G-buffer; cached
    per light, as a stream or a series of frames asks the same again."""
    key = tuple(tuple(float(x) for x in getattr(light, f)) for f in ("center", "u", "v"))
    return _light_problem(key, samples, *(tuple(float(x) for x in b) for b in bounds))


@functools.lru_cache(maxsize=256)
def _light_problem(light: tuple, samples: int, lo: tuple, hi: tuple) -> str | None:
    area = AreaLight(*light)
    box = (np.asarray(lo), np.asarray(hi))
    try:
        reference_cameras(area, box, "conventional", 16)
        for sample in area.samples(samples):
            shadow_map_camera(area, sample, box, 16)
    except ValueError as exc:
        return str(exc)
    return None


def raytrace_counts(scene_key: str, scene: Scene, gbuf: Any, req: SoftShadowRequest) -> np.ndarray:
    """The exact Embree truth (CPU, no GL; `SoftShadowJob` runs it), with the scene's
    BVH from the worker's cache (`service.effects.CASTERS`, shared with raytraced reflections)."""
    caster, lock, _, _ = CASTERS.get(scene_key, scene)
    with lock:
        bits = light_visibility(caster, gbuf.position, gbuf.normal, gbuf.mask, req.light, req.samples)
    return visible_counts(bits)


def shade(scene: Scene, gbuf: Any, counts: np.ndarray, req: SoftShadowRequest) -> np.ndarray:
    """(H,W,3) linear colour: the area light's shading with the visible fraction
    on surfaces, the G-buffer's sky elsewhere."""
    albedo = scene.materials[gbuf.obj_id, :3]
    lit = area_light_shade(albedo, gbuf.normal, gbuf.position, req.light, counts / float(req.samples**2))
    return np.where(gbuf.mask[..., None], lit, gbuf.color).astype(np.float32)


def encode_shadowed(color: np.ndarray, gbuf: Any, counts: np.ndarray, fmt: str) -> bytes:
    """PNG (sRGB) or EXR (linear RGB, Z, N, id, object and `visible`: the count of
    visible light samples per pixel)."""
    if fmt == "png":
        return image_io.encode_png(color)
    if fmt == "exr":
        return image_io.encode_exr({"RGB": color, "Z": gbuf.depth, "N": gbuf.normal, "id": gbuf.tri_id,
                                    "object": gbuf.obj_id, "visible": counts.astype(np.uint32)})
    raise ValueError(f"unknown frame format {quoted(fmt)}")



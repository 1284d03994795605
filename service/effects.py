"""Frame effects for the service: reflections by method (thesis Ch. 4).

`cluster` and `envmap` run as GL jobs on the worker thread (`service.jobs.ReflectionJob`);
`raytrace` is the Embree reference: a job too (`RaytraceJob`), queued and timed like
the others, that makes no GL call. All return linear colour (H,W,3) plus the reflection buffers for EXR."""

from __future__ import annotations

from typing import Any

import numpy as np

from reference.reflections import raytrace_reflections
from scenes.camera import Camera
from scenes.model import Scene
from service import image_io


def raytrace(scene: Scene, camera: Camera, glossy_rays: int) -> Any:
    """The Embree reference (CPU, no GL; run as `service.jobs.RaytraceJob`)."""
    return raytrace_reflections(scene, camera, supersample=2, glossy_rays=glossy_rays)


def encode_reflections(result: Any, fmt: str) -> bytes:
    """PNG (sRGB final colour) or EXR (linear RGB final colour, "reflected" RGB,
    "diffuse" RGB, "specular" s and the mirror-ray length "ray_length": +inf on a
    miss, 0 on pixels that reflect nothing, where the result holds NaN)."""
    if fmt == "png":
        return image_io.encode_png(result.color)
    if fmt == "exr":
        return image_io.encode_exr({
            "RGB": result.color, "reflected": result.reflected, "diffuse": result.diffuse,
            "specular": np.asarray(result.specular, np.float32),
            "ray_length": np.nan_to_num(np.asarray(result.ray_length, np.float32), nan=0.0, posinf=np.inf),
        })
    raise ValueError(f"unknown frame format {fmt!r}")

"""Frame effects for the service: reflections by method (thesis Ch. 4).

`cluster` and `envmap` run as GL jobs on the worker (`service.jobs.ReflectionJob`);
`raytrace` is the Embree reference: a job too (`RaytraceJob`), queued and timed like
the others, that makes no GL call. All return linear colour (H,W,3) plus the
reflection buffers for EXR. Both keep what does not depend on the camera per scene
(GPU upload and chunk records on the worker; the Embree BVH per worker here), and
both report their steps for the `Server-Timing` header (`server_timing`)."""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from typing import Any

import numpy as np

from gl_passes.reflections import DEFAULT_SETTINGS
from reference.raycast import RayCaster
from reference.reflections import raytrace_reflections
from scenes.camera import Camera
from scenes.model import Scene
from service import image_io
from service.excerpts import quoted

#: Embree BVHs kept (one per scene content address, least recently used dropped).
BVH_CACHE = 4


class CasterCache:
    """Per-scene Embree RayCasters (BVH built once per scene content address); each
    caster is used by one thread at a time."""

    def __init__(self, size: int = BVH_CACHE) -> None:
        self.size = size
        self._lock = threading.Lock()
        self._casters: OrderedDict[str, tuple[RayCaster, threading.Lock]] = OrderedDict()

    def get(self, key: str, scene: Scene) -> tuple[RayCaster, threading.Lock, float, bool]:
        """(caster, its lock, BVH build ms (0 on a hit), hit). A caster serves the very Scene
        object it was built for: once the store has loaded the scene again (its cache evicted
        the old object) the BVH is built again for the new one, as the renders check."""
        with self._lock:
            entry = self._casters.get(key)
            if entry is not None and entry[0].scene is scene:
                self._casters.move_to_end(key)
                return entry[0], entry[1], 0.0, True
        t0 = time.perf_counter()
        caster = RayCaster(scene)  # built outside the lock: other scenes' frames go on
        build = (time.perf_counter() - t0) * 1e3
        with self._lock:
            entry = self._casters.get(key)
            if entry is None or entry[0].scene is not scene:
                entry = self._casters[key] = (caster, threading.Lock())
            self._casters.move_to_end(key)
            while len(self._casters) > self.size:
                self._casters.popitem(last=False)
        return entry[0], entry[1], build, False


CASTERS = CasterCache()


def raytrace(scene: Scene, camera: Camera, glossy_rays: int) -> Any:
    """The Embree reference (CPU; call off the GL thread), BVH built for this call."""
    return raytrace_reflections(scene, camera, supersample=DEFAULT_SETTINGS.supersample, glossy_rays=glossy_rays)


def raytrace_cached(scene_key: str, scene: Scene, camera: Camera, glossy_rays: int
                    ) -> tuple[Any, dict[str, float], dict[str, bool]]:
    """The Embree reference with the BVH of the scene under `scene_key` cached
    (CPU; call off the GL thread): (result, timings ms {"bvh", "trace"}, cache hits
    {"bvh"})."""
    caster, lock, build, hit = CASTERS.get(scene_key, scene)
    t0 = time.perf_counter()
    with lock:
        result = raytrace_reflections(scene, camera, supersample=DEFAULT_SETTINGS.supersample,
                                      glossy_rays=glossy_rays, caster=caster)
    return result, {"bvh": build, "trace": (time.perf_counter() - t0) * 1e3}, {"bvh": hit}


def server_timing(timings_ms: dict[str, float], hits: dict[str, bool] | None = None) -> str:
    """`Server-Timing` header value: one metric per step, `name;dur=ms`, with
    `desc="cache hit"` / `desc="cache miss"` on the cached steps ("total" excluded)."""
    parts = []
    for name, ms in timings_ms.items():
        if name == "total":
            continue
        desc = "" if hits is None or name not in hits else ';desc="cache ' + ("hit" if hits[name] else "miss") + '"'
        parts.append(f"{name}{desc};dur={ms:.1f}")
    return ", ".join(parts)


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
    raise ValueError(f"unknown frame format {quoted(fmt)}")

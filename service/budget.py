"""The memory budget of one render request (``Settings.max_job_bytes``).

Every render path that allocates by request size is estimated here, from the
request alone, before the scene is loaded or a job is queued; the formulas and their
per-unit costs are documented in ``service.config`` beside the limit. An estimate
over the budget is a 422 that names the estimate, its terms and the budget."""

from __future__ import annotations

from fastapi import HTTPException

from scenes.lights import PEEL_LAYERS
from service.config import (
    FRAME_BYTES_PER_PIXEL,
    RECONSTRUCTION_BYTES_PER_SAMPLE,
    SET_BYTES_PER_PIXEL,
    SHADOW_MAP_RESOLUTION,
    SHADOW_MAPS_PER_DRAW,
    STREAM_REUSER_BYTES_PER_PIXEL,
    Settings,
)
from service.schemas import DepthImagesRequest, FrameRequest, ReconstructionRequest

#: Images of the Fig. 8 rig (scenes.rig.fig8_rig) and of a light's corners.
RIG_IMAGES = 3
LIGHT_IMAGES = 4


def _gib(n: float) -> str:
    return f"{n / 2**30:.2f} GiB" if n >= 2**28 else f"{n / 2**20:.1f} MiB"


def _reconstruction(images: int, resolution: int) -> int:
    return images * resolution * resolution * RECONSTRUCTION_BYTES_PER_SAMPLE


def stream_reuser_bytes(method: str, width: int, height: int) -> int:
    """Bytes a reflective stream's reuser (`method` "cluster" or "raytrace") keeps on its
    worker between frames of width × height (``Settings.stream_reuse_bytes``)."""
    return STREAM_REUSER_BYTES_PER_PIXEL[method] * width * height


def frame_bytes(req: FrameRequest) -> tuple[int, str]:
    """(estimated bytes, the terms in words) of one frame request."""
    px = req.width * req.height
    fx = req.effects
    if fx.soft_shadows is not None:
        ss = fx.soft_shadows
        k2 = ss.samples * ss.samples
        total = px * FRAME_BYTES_PER_PIXEL + px * (k2 // 8 + 8) * 2
        terms = f"{req.width}×{req.height} frame with {ss.samples}² light samples"
        if ss.method not in ("geometry", "raytrace"):
            images = PEEL_LAYERS if ss.method == "peeling" else LIGHT_IMAGES
            total += _reconstruction(images, ss.resolution)
            terms += f", {images} reconstructed images of {ss.resolution}²"
        if ss.method != "raytrace":
            # the depth atlas and the splats' depth image of its size (the worker's pass keeps
            # the image once a reconstruction made it, for the frames after it too)
            total += 2 * SHADOW_MAP_RESOLUTION**2 * min(k2, SHADOW_MAPS_PER_DRAW) * 4
        return total, terms
    if fx.reflections != "none":
        return 4 * px * FRAME_BYTES_PER_PIXEL, f"{req.width}×{req.height} frame with reflections at 2×2 supersamples"
    return px * FRAME_BYTES_PER_PIXEL, f"{req.width}×{req.height} frame"


def set_bytes(req: DepthImagesRequest) -> tuple[int, str]:
    """(estimated bytes, terms) of a depth-image set request."""
    if req.method == "peeling":
        n = req.layers
    else:
        n = len(req.cameras) if req.cameras is not None else RIG_IMAGES
    copies = 2 if req.metrics else 1
    total = n * req.width * req.height * SET_BYTES_PER_PIXEL * copies
    terms = f"{n} images of {req.width}×{req.height}" + (" plus their conventional images for metrics"
                                                          if req.metrics else "")
    return total, terms


def reconstruction_bytes(req: ReconstructionRequest) -> tuple[int, str]:
    """(estimated bytes, terms) of a reconstruction request (meshes and the GLB)."""
    if req.method == "peeling":
        n = req.layers
    else:
        n = len(req.cameras) if req.cameras is not None else LIGHT_IMAGES
    return _reconstruction(n, req.resolution), f"{n} reconstructed images of {req.resolution}²"


def check_budget(settings: Settings, estimate: tuple[int, str]) -> None:
    """422 when the estimate exceeds ``max_job_bytes``."""
    need, terms = estimate
    if need > settings.max_job_bytes:
        raise HTTPException(422, f"request needs an estimated {_gib(need)} ({terms}), over the memory budget of "
                                 f"{_gib(settings.max_job_bytes)} per job (DEPTHVIEW_MAX_JOB_BYTES); render fewer "
                                 "or smaller images")

"""Embree tracer for the temporal reflection reuse (thesis Ch. 5, §5.3 B.3–B.4 and
the recomputation of §5.4.3): reflected colour and exact reflected-ray length of
selected pixels only (sparse rays), by the rules of reference.reflections at one
sample per pixel. It satisfies gl_passes.reprojection's Tracer protocol
structurally; reference never imports gl_passes."""

from __future__ import annotations

import numpy as np

from reference.raycast import RayCaster
from reference.reflections import DEFAULT_CHUNK, _shade_samples
from scenes.camera import Camera
from scenes.model import Scene


class EmbreeTracer:
    """`trace(camera, pixels)` → (reflected (N,3) float32 linear RGB, ray_length (N,)
    float64 world units: +inf on a miss, NaN where Embree's primary ray does not hit
    a reflective surface — there reflected is the pixel's diffuse colour) for integer
    pixels (N,2) = (x, y), row 0 at the top: one primary ray through each pixel
    centre, then its mirror ray (or glossy lobe, `glossy_rays` rays). The BVH is
    built once per tracer. per_viewpoint=True casts the primary rays with the exact
    per-viewpoint culling of raytrace_reflections (a BVH of the front faces built per
    eye; its cost: bench/results/reflections_notes.json, per_viewpoint_primary_rays_cost);
    the default False restarts past back faces in the one BVH (identical but where a
    back face is coplanar with a front face), so the cost scales with the pixels
    asked for."""

    name = "embree"
    sparse = True

    def __init__(self, scene: Scene, glossy_rays: int = 8, caster: RayCaster | None = None,
                 per_viewpoint: bool = False) -> None:
        self.scene = scene
        self.per_viewpoint = bool(per_viewpoint)
        self.glossy_rays = int(glossy_rays)
        self.caster = caster if caster is not None else RayCaster(scene)

    def trace(self, camera: Camera, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        px = np.asarray(pixels, np.int64).reshape(-1, 2)
        if len(px) == 0:
            return np.zeros((0, 3), np.float32), np.zeros(0, np.float64)
        dirs = camera.directions_at(px)
        sh = _shade_samples(self.caster, np.asarray(camera.eye, np.float64), dirs, self.glossy_rays, True,
                            DEFAULT_CHUNK, self.per_viewpoint)
        reflected = np.where(sh.reflective[:, None], sh.reflected, sh.diffuse).astype(np.float32)
        return reflected, sh.length

    def release(self) -> None:
        """Nothing on the GPU (the protocol's release)."""

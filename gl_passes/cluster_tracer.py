"""The cluster-depth-image method (thesis Ch. 4) as a tracer for the temporal reuse
(Ch. 5, gl_passes.reprojection.Tracer): it renders the whole frame at one sample
per pixel, whatever pixels are asked for (not sparse), and returns theirs."""

from __future__ import annotations

import numpy as np

from gl_passes.context import GLContext
from gl_passes.reflections import DEFAULT_SETTINGS, ClusterReflections, ClusterSettings
from gl_passes.releasable import Releasable
from gl_passes.upload import SceneGPU
from scenes.camera import Camera


class ClusterTracer(Releasable):
    """`trace(camera, pixels)` by ClusterReflections.render(supersample=1): reflected
    (N,3) (the diffuse colour where the cluster pass sees no reflector) and the
    marched ray length (N,) (+inf: miss, NaN: not reflective). Owns its
    ClusterReflections, made with `settings` (the service's and the bench's by default)."""

    name = "clusters"
    sparse = False

    def __init__(self, gl: GLContext, scene_gpu: SceneGPU, glossy_rays: int = 8,
                 settings: ClusterSettings = DEFAULT_SETTINGS) -> None:
        self.scene_gpu = scene_gpu
        self.glossy_rays = int(glossy_rays)
        self.renderer = ClusterReflections(gl, settings)

    def trace(self, camera: Camera, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        px = np.asarray(pixels, np.int64).reshape(-1, 2)
        if len(px) == 0:
            return np.zeros((0, 3), np.float32), np.zeros(0, np.float64)
        res = self.renderer.render(self.scene_gpu, camera, glossy_rays=self.glossy_rays, supersample=1)
        xs, ys = px[:, 0], px[:, 1]
        col = np.where(res.reflective[..., None], res.reflected, res.diffuse)[ys, xs]
        return col.astype(np.float32), res.ray_length[ys, xs]

    def release(self) -> None:
        self.renderer.release()

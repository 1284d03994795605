"""Depth images: the samples a pinhole view captures (thesis Ch. 2, §2.2).

Shared by the GL passes that render them and the Embree reference that judges
them, so it lives here (no GL, no Embree).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenes.camera import Camera


@dataclass
class DepthImage:
    """One depth image, row 0 = top. camera has near/far set; color (H,W,3)
    float32 linear; depth (H,W) float32 eye-space z (+inf = no sample); normal,
    position (H,W,3) float32 world space; tri_id (H,W) uint32 (0 = no sample)."""

    camera: Camera
    color: np.ndarray
    depth: np.ndarray
    normal: np.ndarray
    position: np.ndarray
    tri_id: np.ndarray

    @property
    def mask(self) -> np.ndarray:
        """(H,W) bool: pixel holds a sample."""
        return self.tri_id > 0

    @property
    def n_samples(self) -> int:
        return int(self.mask.sum())

    @classmethod
    def from_buffers(cls, camera: Camera, buffers: object) -> DepthImage:
        """From any object with color/depth/normal/position/tri_id arrays (the GL
        G-buffer or the reference RayBuffers)."""
        b = buffers
        return cls(camera, b.color, b.depth, b.normal, b.position, b.tri_id)  # type: ignore[attr-defined]

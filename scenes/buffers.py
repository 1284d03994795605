"""Per-pixel frame buffers: the layout shared by the GL G-buffer pass and the
Embree reference's primary-ray buffers, so the two can be compared field by field."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class FrameBuffers:
    """Per-pixel buffers, row 0 = top. color (H,W,3) float32 linear; depth (H,W)
    float32 positive eye-space z (+inf background); normal, position (H,W,3)
    float32 world space; tri_id (H,W) uint32; obj_id (H,W) uint16; specular,
    glossiness (H,W) float32."""

    color: np.ndarray
    depth: np.ndarray
    normal: np.ndarray
    position: np.ndarray
    tri_id: np.ndarray
    obj_id: np.ndarray
    specular: np.ndarray
    glossiness: np.ndarray

    @property
    def mask(self) -> np.ndarray:
        """(H,W) bool: pixel covered by geometry."""
        return self.tri_id > 0


@dataclass
class ReflectionBuffers:
    """Reflection output at OUTPUT resolution, shared by the GL cluster method and
    the Embree reference (thesis Ch. 4): color, reflected, diffuse (H,W,3) float32
    linear RGB; specular (H,W) float32 mean s; reflective (H,W) bool; ray_length
    (H,W) float64 mean mirror-ray length (+inf if a sample missed, NaN where no
    sample is reflective)."""

    color: np.ndarray
    reflected: np.ndarray
    diffuse: np.ndarray
    specular: np.ndarray
    reflective: np.ndarray
    ray_length: np.ndarray

"""Per-pixel frame buffers: the layout shared by the GL G-buffer pass and the
Embree reference's primary-ray buffers, so the two can be compared field by field,
and the other records both sides exchange (reflections, cluster diagnostics)."""

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


@dataclass
class ClusterDiagnostics:
    """What the cluster depth images of a reflection frame hold (thesis Ch. 4):
    written by the GL pass (gl_passes.reflections, render(diagnostics=True)) and
    read by the thesis's occlusion-error test (§4.4 / §4.7.1: a reflected ray meets
    an object the cluster image did not sample; reference.occlusion). Arrays are
    numpy, row 0 = top.

    cluster_of_sample (ss·H, ss·W) int32: each sample's cluster (index into the
    result's cameras and the arrays below), −1 for non-reflective samples;
    layer_depths (L = 4, Ha, Wa) float32: the used atlas area of the layers
    (other objects; the cluster's reflector; the reflector's second surface; the
    other objects' second surface), each texel the linear depth along its cluster
    camera's axis (= clip w of view_proj; ≥ 1e30 where empty); viewports (K, 4)
    int64 (x, y, w, h) of each cluster image in layer_depths with y its TOP row
    (w = h = 0: no image, invalid camera); view_proj (K, 4, 4) float64 (its NDC z
    bounds near/far); clip_planes (K, 4) float64 (n, c): the image holds only
    n·X ≥ c (the fitting plane clip)."""

    cluster_of_sample: np.ndarray
    layer_depths: np.ndarray
    viewports: np.ndarray
    view_proj: np.ndarray
    clip_planes: np.ndarray

"""Embree ground truth and error metrics for soft shadows (thesis Ch. 3, Alg. 5, §3.4.2).

Alg. 5 resolves, per output pixel, which of the k×k samples of a rectangular area
light (`AreaLight.samples(k)`, cell centres, fixed order) the surface point sees.
The truth here casts one Embree occlusion ray per pixel and light sample against the
original geometry; the metrics compare any approximation (the GL pass through
reconstructed depth images) with it, never trusting GL.

Visibility bits (a contract shared with the GL pass): per pixel an array of
`n_words(k)` = ceil(k²/32) uint32 words, light sample s (row s of
`light.samples(k)`) is bit (s % 32) of word (s // 32); a set bit means visible.
Bits ≥ k² of the last word are always 0.

Rules shared with the GL pass:

* tangent plane: a light sample s with n·(s − P) ≤ 0 (on or behind the tangent
  plane of the surface point P with normal n) is not visible; no ray is cast;
* light side: the light emits along −(u × v) only; a point P on or behind the light's
  plane sees none of its samples (the GL pass needs the whole scene box in front of
  the light, so its receivers are never there);
* occlusion: any triangle on the segment blocks it, whichever side faces the ray
  (no back-face culling);
* pixels outside the mask get all-zero words.

Errors (§3.4.2): per pixel, the visibility error is the number of light samples
resolved wrongly, popcount(approx XOR truth); the intensity error is the absolute
signed sum of those wrong decisions, |count_approx − count_truth| (a wrongly lit and
a wrongly shadowed sample cancel). Both are reported as mean and max over the pixels
of the mask.

This module never imports gl_passes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from reference.raycast import RayCaster
from scenes.lights import light_normal
from scenes.model import AreaLight

#: Ray origins are lifted off the surface along the unit normal by this fraction of
#: the scene scale (see `surface_offset`).
SURFACE_OFFSET_REL = 1e-5
#: Relative shortening of each occlusion segment at the light-sample end (a light
#: fixture modelled at the light's position must not shadow its own samples).
END_REL_EPS = 1e-4
#: Rays per batch handed to Embree: bounds the temporary memory of `light_visibility`.
RAY_CHUNK = 1 << 20
#: `error_picture`: colour = clip(gain · |count_approx − count_truth| / k², 0, 1), so an
#: error of 1/16 of the light's samples (16 of 256 at k = 16) saturates.
ERROR_GAIN = 16.0
#: `error_picture`: grey level of pixels outside the mask.
MASK_GREY = 0.2


def n_words(k: int) -> int:
    """Number of uint32 words holding the k×k visibility bits of one pixel: ceil(k²/32)."""
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
    return (k * k + 31) // 32


def surface_offset(caster: RayCaster) -> float:
    """Distance (world units) by which occlusion rays start off the surface along the
    normal: SURFACE_OFFSET_REL × max(scene diagonal, largest |coordinate| of the scene
    box). The second term keeps the offset above float32 position error for scenes
    far from the origin."""
    lo, hi = caster.scene.bounds
    scale = max(caster.scene.diagonal, float(np.max(np.abs(np.concatenate([lo, hi])))), 1e-6)
    return SURFACE_OFFSET_REL * scale


def _unit(v: np.ndarray) -> np.ndarray:
    """Rows of v (N,3) scaled to unit length; zero rows stay zero."""
    length = np.linalg.norm(v, axis=1, keepdims=True)
    return np.where(length > 0, v / np.maximum(length, 1e-300), 0.0)


def in_front(points: np.ndarray, normals: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """(N,S) bool: light sample strictly in front of the tangent plane, n·(s − P) > 0
    (§3.4.2 rule shared with GL). points, normals (N,3), samples (S,3), world units."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    s = np.asarray(samples, np.float64).reshape(-1, 3)
    return (n @ s.T) - np.einsum("ij,ij->i", n, p)[:, None] > 0


def _pack_into(words: np.ndarray, vis: np.ndarray, first: int) -> None:
    """OR the visibility of samples first … first+m−1 (vis (N,m) bool) into words (N,W) uint32."""
    for j in range(vis.shape[1]):
        s = first + j
        words[:, s >> 5] |= vis[:, j].astype(np.uint32) << np.uint32(s & 31)


def _visibility_rows(caster: RayCaster, p: np.ndarray, n: np.ndarray, samples: np.ndarray,
                     words: np.ndarray, offset: float) -> None:
    """Fill words (N,W) uint32 for surface points p (N,3) with unit normals n (N,3),
    a chunk of light samples at a time (at most RAY_CHUNK rays per batch)."""
    origin = p + n * offset
    m = max(1, RAY_CHUNK // max(len(p), 1))
    for first in range(0, len(samples), m):
        chunk = samples[first:first + m]
        front = in_front(p, n, chunk)
        pi, sj = np.nonzero(front)
        vis = np.zeros(front.shape, bool)
        if len(pi):
            vis[pi, sj] = ~caster.occluded(origin[pi], chunk[sj], cull_back_faces=False, rel_eps=END_REL_EPS)
        _pack_into(words, vis, first)


def light_visibility(caster: RayCaster, points: np.ndarray, normals: np.ndarray, mask: np.ndarray,
                     light: AreaLight, k: int) -> np.ndarray:
    """Ground-truth visibility bits of the k×k light samples (Alg. 5, §3.4.2).

    points (H,W,3) world positions and normals (H,W,3) world normals of the visible
    surface (e.g. a G-buffer; read only where mask (H,W) bool is True). Returns
    (H,W,n_words(k)) uint32, sample s at bit s % 32 of word s // 32 (module docstring).

    Per pixel in front of the light's plane and light sample in front of the pixel's
    tangent plane, one occlusion ray from
    P + n̂·`surface_offset(caster)` (n̂ the unit normal; the offset is
    SURFACE_OFFSET_REL of the scene scale, so a float32 position slightly below its
    own surface does not shadow itself) to the sample, shortened by END_REL_EPS of
    its length at the sample; any triangle on it, front or back, blocks it. Batches
    hold at most RAY_CHUNK rays (pixels × light samples), so memory stays bounded."""
    h, w = np.asarray(mask).shape
    out = np.zeros((h, w, n_words(k)), np.uint32)
    m = np.asarray(mask, bool)
    p = np.asarray(points, np.float64).reshape(h, w, 3)[m]
    n = _unit(np.asarray(normals, np.float64).reshape(h, w, 3)[m])
    samples = light.samples(k)
    words = np.zeros((len(p), out.shape[2]), np.uint32)
    offset = surface_offset(caster)
    lit_side = (p - np.asarray(light.center, np.float64)) @ -light_normal(light) > 0
    p, n, rows = p[lit_side], n[lit_side], np.nonzero(lit_side)[0]
    lit = np.zeros((len(p), out.shape[2]), np.uint32)
    for lo in range(0, len(p), RAY_CHUNK):
        _visibility_rows(caster, p[lo:lo + RAY_CHUNK], n[lo:lo + RAY_CHUNK], samples,
                         lit[lo:lo + RAY_CHUNK], offset)
    words[rows] = lit
    out[m] = words
    return out


def visible_counts(bits: np.ndarray) -> np.ndarray:
    """(H,W) uint16 number of visible light samples: popcount over the words of
    bits (H,W,n_words) uint32 (§3.4.2)."""
    b = np.asarray(bits)
    if b.dtype != np.uint32:
        raise ValueError(f"visibility bits must be uint32, got {b.dtype}")
    return _popcount(b).sum(axis=-1, dtype=np.uint16)


#: Set bits of each byte value 0…255 (popcount fallback for numpy < 2.0).
_BYTE_BITS = np.unpackbits(np.arange(256, dtype=np.uint8)[:, None], axis=1).sum(axis=1).astype(np.uint8)


def _popcount(words: np.ndarray) -> np.ndarray:
    """(...,W) uint8 set bits of each uint32 word (np.bitwise_count where numpy has it)."""
    if hasattr(np, "bitwise_count"):
        return np.bitwise_count(words)
    w = np.ascontiguousarray(words)
    return _BYTE_BITS[w.view(np.uint8)].reshape(*w.shape, 4).sum(axis=-1, dtype=np.uint8)


def _check_pair(approx_bits: np.ndarray, truth_bits: np.ndarray) -> None:
    if np.shape(approx_bits) != np.shape(truth_bits):
        raise ValueError(f"bit arrays differ in shape: {np.shape(approx_bits)} vs {np.shape(truth_bits)}")


def error_maps(approx_bits: np.ndarray, truth_bits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel soft-shadow errors (§3.4.2) of approx_bits against truth_bits, both
    (H,W,n_words) uint32. Returns (visibility (H,W) uint16 = number of light samples
    resolved wrongly = popcount(approx XOR truth), signed (H,W) int16 = count_approx −
    count_truth, > 0 where the approximation is too bright). Needs k ≤ 181."""
    _check_pair(approx_bits, truth_bits)
    a, t = np.asarray(approx_bits), np.asarray(truth_bits)
    visibility = visible_counts(a ^ t)
    signed = visible_counts(a).astype(np.int16) - visible_counts(t).astype(np.int16)
    return visibility, signed


@dataclass(frozen=True)
class ShadowErrors:
    """Soft-shadow errors over the pixels of a mask (§3.4.2), in light samples: the
    visibility error (samples resolved wrongly) and the intensity error (|signed sum
    of the wrong decisions|), mean and max. All 0 for an empty mask."""

    visibility_mean: float
    visibility_max: float
    intensity_mean: float
    intensity_max: float


def shadow_errors(approx_bits: np.ndarray, truth_bits: np.ndarray, mask: np.ndarray) -> ShadowErrors:
    """§3.4.2 errors of approx_bits against truth_bits ((H,W,n_words) uint32 each) over
    the pixels where mask (H,W) bool is True."""
    visibility, signed = error_maps(approx_bits, truth_bits)
    m = np.asarray(mask, bool)
    if not m.any():
        return ShadowErrors(0.0, 0.0, 0.0, 0.0)
    vis = visibility[m].astype(np.float64)
    inten = np.abs(signed[m].astype(np.float64))
    return ShadowErrors(float(vis.mean()), float(vis.max()), float(inten.mean()), float(inten.max()))


def error_picture(approx_bits: np.ndarray, truth_bits: np.ndarray, mask: np.ndarray, k: int,
                  gain: float = ERROR_GAIN) -> np.ndarray:
    """(H,W,3) float32 RGB in [0,1] visualising the intensity error (Fig. 16, Table 8):
    green where the approximation is too bright (more visible samples than the
    truth), red where too dark, with value clip(gain · |count_approx − count_truth| /
    k², 0, 1) (default gain ERROR_GAIN: an error of 1/16 of the samples saturates);
    black where the counts agree, grey MASK_GREY outside mask (H,W) bool."""
    _, signed = error_maps(approx_bits, truth_bits)
    value = np.clip(gain * np.abs(signed.astype(np.float32)) / float(k * k), 0.0, 1.0)
    pic = np.zeros((*signed.shape, 3), np.float32)
    pic[..., 0] = np.where(signed < 0, value, 0.0)
    pic[..., 1] = np.where(signed > 0, value, 0.0)
    pic[~np.asarray(mask, bool)] = MASK_GREY
    return pic


def _slab_blocked(p: np.ndarray, d: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(...) bool: does the open segment p + t·d, t ∈ (0,1), overlap the closed box
    [lo, hi] over a positive length? p, d (...,3) float64; lo, hi (3,)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - p) / d, (hi - p) / d
    near, far = np.minimum(t1, t2), np.maximum(t1, t2)
    inside = (lo <= p) & (p <= hi)  # a segment parallel to a slab: all or nothing
    parallel = d == 0
    near = np.where(parallel, np.where(inside, -np.inf, np.inf), near)
    far = np.where(parallel, np.where(inside, np.inf, -np.inf), far)
    enter = np.maximum(near.max(axis=-1), 0.0)
    leave = np.minimum(far.min(axis=-1), 1.0)
    return enter < leave


def box_visibility(points: np.ndarray, normals: np.ndarray, samples: np.ndarray,
                   box_lo: np.ndarray, box_hi: np.ndarray) -> np.ndarray:
    """(N,S) bool ANALYTIC visibility of light samples (S,3) from surface points (N,3)
    with normals (N,3) past one axis-aligned box [box_lo, box_hi] (3,) (world units):
    the closed-form truth for a box over a plane (§3.4.2). A sample is visible when it
    is in front of the tangent plane (`in_front`) and the open segment P → s does not
    pass through the box (slab test; merely touching an edge or face does not block)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    s = np.asarray(samples, np.float64).reshape(-1, 3)
    lo, hi = np.asarray(box_lo, np.float64), np.asarray(box_hi, np.float64)
    out = in_front(p, normals, s)
    rows = max(1, RAY_CHUNK // max(len(s), 1))
    for a in range(0, len(p), rows):
        pa = p[a:a + rows, None, :]
        out[a:a + rows] &= ~_slab_blocked(pa, s[None, :, :] - pa, lo, hi)
    return out

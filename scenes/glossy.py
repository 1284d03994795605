"""Glossy reflection lobe shared by the GL passes and the Embree reference (§4.6).

A glossy surface of glossiness g reflects rays spread uniformly (by solid angle)
in a cone around the mirror direction with half-angle `lobe_half_angle(g)`; the
n rays of a pixel follow a deterministic Fibonacci spiral over the cone cap so
GL and reference sample the same lobe. Reflections reach only nearby geometry:
the reflected ray's useful length is `glossy_far(diagonal, g)`, and its colour
fades to the pixel's diffuse colour over the last FADE_FRACTION of that length.
"""

from __future__ import annotations

import numpy as np

MAX_HALF_ANGLE_DEG = 25.0  # lobe half-angle at g = 1
MIN_FAR_FRACTION = 0.05    # far plane at g = 1, as a fraction of the scene diagonal
FADE_FRACTION = 0.25       # fade to diffuse over the last quarter before the far plane


def lobe_half_angle(g: np.ndarray | float) -> np.ndarray:
    """Cone half-angle in radians for glossiness g ∈ [0, 1] (0 = mirror)."""
    return np.radians(MAX_HALF_ANGLE_DEG) * np.clip(np.asarray(g, np.float64), 0.0, 1.0)


def glossy_far(diagonal: float, g: np.ndarray | float) -> np.ndarray:
    """Far distance (world units) of reflected rays: the scene diagonal for a
    mirror, shrinking linearly to MIN_FAR_FRACTION·diagonal at g = 1."""
    g = np.clip(np.asarray(g, np.float64), 0.0, 1.0)
    return diagonal * (1.0 - (1.0 - MIN_FAR_FRACTION) * g)


def fade_weight(t: np.ndarray, far: np.ndarray, g: np.ndarray | float) -> np.ndarray:
    """Weight of the reflected colour for a hit at distance t (1 = full
    reflection, 0 = diffuse): 1 for mirrors (g = 0), else a linear ramp to 0 over
    the last FADE_FRACTION·far before far."""
    g = np.asarray(g, np.float64)
    w = np.clip((np.asarray(far, np.float64) - t) / (FADE_FRACTION * np.asarray(far, np.float64)), 0.0, 1.0)
    return np.where(g > 0, w, 1.0)


def lobe_offsets(n: int) -> np.ndarray:
    """(n,2) float64 points (cos φ·ρ, sin φ·ρ) on the unit disc, ρ = sqrt((i+½)/n)
    on a golden-angle spiral: equal solid-angle cells of a small cone cap."""
    i = np.arange(n) + 0.5
    rho = np.sqrt(i / n)
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([rho * np.cos(phi), rho * np.sin(phi)], axis=1)


def lobe_directions(mirror: np.ndarray, g: np.ndarray | float, n: int) -> np.ndarray:
    """(...,n,3) unit directions of the lobe around unit mirror directions
    (...,3): offset k tilts the axis by ρ_k·half-angle toward φ_k in a frame
    built from the axis (the same frame formula as in GLSL)."""
    m = np.asarray(mirror, np.float64)
    half = np.broadcast_to(lobe_half_angle(g), m.shape[:-1])
    # Orthonormal frame (branchless, Duff et al. 2017).
    sign = np.where(m[..., 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + m[..., 2])
    b = m[..., 0] * m[..., 1] * a
    t1 = np.stack([1 + sign * m[..., 0] ** 2 * a, sign * b, -sign * m[..., 0]], axis=-1)
    t2 = np.stack([b, sign + m[..., 1] ** 2 * a, -m[..., 1]], axis=-1)
    off = lobe_offsets(n)
    # Tilt by angle ρ·half toward φ: offset ρ(cos φ, sin φ) scaled by tan(ρ·half)/ρ.
    rho = np.linalg.norm(off, axis=1)
    scale = np.tan(rho * half[..., None]) / rho  # (..., n)
    ox, oy = off[:, 0] * scale, off[:, 1] * scale
    d = m[..., None, :] + ox[..., None] * t1[..., None, :] + oy[..., None] * t2[..., None, :]
    return d / np.linalg.norm(d, axis=-1, keepdims=True)

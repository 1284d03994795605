"""Local shading and the procedural sky, in numpy (DESIGN.md "Conventions").

The GLSL twin is gl_passes/shaders/common.glsl; its constants are injected from
here (`glsl_defines`) so the two cannot drift apart. Colours are linear RGB.
"""

from __future__ import annotations

import numpy as np

from scenes.model import AMBIENT, AreaLight

SKY_ZENITH = (0.18, 0.36, 0.78)
SKY_HORIZON = (0.78, 0.84, 0.92)
SKY_GROUND = (0.30, 0.27, 0.24)
SUN_GLOW = (0.9, 0.8, 0.6)
SUN_GLOW_EXPONENT = 64.0


def local_shade(albedo: np.ndarray, normal: np.ndarray, sun: np.ndarray) -> np.ndarray:
    """albedo (...,3) × (AMBIENT + (1 − AMBIENT)·max(0, n·l)); normal (...,3) unit,
    sun (3,) unit direction toward the sun. Returns (...,3) float32."""
    ndl = np.maximum(0.0, np.einsum("...k,k->...", normal.astype(np.float32), np.asarray(sun, np.float32)))
    return (albedo * (AMBIENT + (1.0 - AMBIENT) * ndl)[..., None]).astype(np.float32)


def sky(direction: np.ndarray, sun: np.ndarray) -> np.ndarray:
    """Environment radiance for unit directions (...,3) → (...,3) float32: a
    zenith/horizon/ground gradient linear in d.y plus a sun glow."""
    d = direction.astype(np.float32)
    h = np.clip(d[..., 1], -1.0, 1.0)[..., None]
    zen, hor, gnd = (np.asarray(c, np.float32) for c in (SKY_ZENITH, SKY_HORIZON, SKY_GROUND))
    up = hor + (zen - hor) * h
    down = hor + (gnd - hor) * (-h)
    c = np.where(h >= 0, up, down)
    glow = np.maximum(0.0, np.einsum("...k,k->...", d, np.asarray(sun, np.float32))) ** SUN_GLOW_EXPONENT
    return (c + np.asarray(SUN_GLOW, np.float32) * glow[..., None]).astype(np.float32)


def glsl_defines() -> dict[str, str]:
    """The shading constants as GLSL #define values."""

    def vec3(c: tuple[float, float, float]) -> str:
        return "vec3(" + ", ".join(repr(float(x)) for x in c) + ")"

    return {
        "AMBIENT": repr(float(AMBIENT)),
        "SKY_ZENITH": vec3(SKY_ZENITH),
        "SKY_HORIZON": vec3(SKY_HORIZON),
        "SKY_GROUND": vec3(SKY_GROUND),
        "SUN_GLOW": vec3(SUN_GLOW),
        "SUN_GLOW_EXPONENT": repr(float(SUN_GLOW_EXPONENT)),
    }


def area_light_shade(albedo: np.ndarray, normal: np.ndarray, position: np.ndarray, light: AreaLight,
                     visible_fraction: np.ndarray) -> np.ndarray:
    """Shaded image of the soft-shadow output (§3.3, Alg. 5): albedo (...,3) ×
    (AMBIENT + (1 − AMBIENT)·max(0, n·l)·visible_fraction), with normal (...,3) unit,
    position (...,3) world units, l the unit direction from the point to the light's
    centre and visible_fraction (...,) in [0, 1] the share of the k×k light samples
    the point sees. Returns (...,3) float32."""
    to_light = np.asarray(light.center, np.float64) - np.asarray(position, np.float64)
    length = np.linalg.norm(to_light, axis=-1, keepdims=True)
    l_dir = to_light / np.maximum(length, 1e-30)
    ndl = np.maximum(0.0, np.einsum("...k,...k->...", np.asarray(normal, np.float64), l_dir))
    lit = AMBIENT + (1.0 - AMBIENT) * ndl * np.asarray(visible_fraction, np.float64)
    return (np.asarray(albedo, np.float64) * lit[..., None]).astype(np.float32)

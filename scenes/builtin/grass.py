"""Grass: thin two-sided curved blades on a ground plane.

Stands in for the thesis's grass scene (§2.3.3 with Tables 2–7: 5.6 万 = 56k triangles; the
grass scene of §3.4.3, Fig. 20 is the one whose complexity is varied). Blades are pointed
ribbons of 4 segments (7 triangles per side, 14 with ``geometry.two_sided``), 0.12–0.5 m
tall and 5–10 mm wide at the base, leaning and curving in random directions, on a
3 m × 3 m patch (partly clumped). The blade count is proportional to detail (4000 at
detail 1: blades get denser, the patch keeps its size); the ground is a grid facing up.
"""

from __future__ import annotations

import numpy as np

from scenes.builtin import geometry as g
from scenes.model import Material, Scene

DESCRIPTION = "grass: ~4k thin two-sided curved blades on a 3 m ground patch (thesis §2.3.3, 56k triangles)"

BLADES_PER_DETAIL = 4000
SEGMENTS = 4
HALF = 1.5  # m, half the side of the patch
GROUND_RES = 10

_BLADE_A = Material(albedo=(0.16, 0.42, 0.07))
_BLADE_B = Material(albedo=(0.30, 0.50, 0.12))
_SOIL = Material(albedo=(0.30, 0.22, 0.14))


def estimate_triangles(detail: float) -> int:
    n = g.scaled_count(BLADES_PER_DETAIL, detail)
    res = g.scaled_res(GROUND_RES, detail)
    return 2 * n * g.ribbon_triangles(SEGMENTS, pointed=True) + g.grid_triangles(res, res)


def _blades(n: int, rng: np.random.Generator, blade_width: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Blade centre lines (n, SEGMENTS+1, 3), half widths (n, SEGMENTS+1, scaled by
    blade_width) and side vectors (n, 3) for ``geometry.ribbons`` (front = side × up)."""
    clumped = rng.random(n) < 0.5
    n_clumps = max(1, n // 40)
    centres = rng.uniform(-HALF * 0.9, HALF * 0.9, (n_clumps, 2))
    base = rng.uniform(-HALF, HALF, (n, 2))
    which = rng.integers(0, n_clumps, n)
    base = np.where(clumped[:, None], centres[which] + rng.normal(0.0, 0.08, (n, 2)), base)
    base = np.clip(base, -HALF, HALF)
    height = np.clip(rng.lognormal(np.log(0.26), 0.3, n), 0.12, 0.5)
    width = rng.uniform(0.0025, 0.005, n) * blade_width  # half width at the base
    azimuth = rng.uniform(0.0, 2.0 * np.pi, n)  # lean direction
    lean0 = rng.uniform(0.0, 0.35, n)  # radians from vertical at the base
    curl = rng.uniform(0.2, 1.3, n) * (height / 0.3)  # extra bend toward the tip
    s = np.arange(SEGMENTS) / SEGMENTS + 0.5 / SEGMENTS  # segment midpoints
    theta = lean0[:, None] + curl[:, None] * s[None, :] ** 1.5  # (n, SEGMENTS)
    dir_h = np.stack([np.cos(azimuth), np.sin(azimuth)], 1)
    step = (height / SEGMENTS)[:, None]
    dy = np.cumsum(np.cos(theta) * step, axis=1)
    dh = np.cumsum(np.sin(theta) * step, axis=1)
    paths = np.zeros((n, SEGMENTS + 1, 3))
    paths[:, 0, 0], paths[:, 0, 2] = base[:, 0], base[:, 1]
    paths[:, 1:, 0] = base[:, 0:1] + dh * dir_h[:, 0:1]
    paths[:, 1:, 2] = base[:, 1:2] + dh * dir_h[:, 1:2]
    paths[:, 1:, 1] = dy
    paths[:, 0, 1] = -0.005  # root slightly below the ground
    t = np.linspace(0.0, 1.0, SEGMENTS + 1)
    half_widths = width[:, None] * np.sqrt(np.clip(1.0 - t**1.6, 0.0, None))[None, :] * (1.0 + 0.6 * t * (1 - t))
    half_widths[:, -1] = 0.0
    twist = azimuth + np.pi / 2 + rng.normal(0.0, 0.3, n)
    sides = np.stack([np.cos(twist), np.zeros(n), np.sin(twist)], 1)
    return paths, half_widths, sides


def build(detail: float, rng: np.random.Generator, blade_width: float = 1.0) -> Scene:
    """The grass scene; blade_width scales every blade's width (a variant for the
    soft-shadow benchmark; the blades keep their centre lines and count)."""
    if not (np.isfinite(blade_width) and blade_width > 0):
        raise ValueError(f"blade_width must be positive and finite, got {blade_width!r}")
    n = g.scaled_count(BLADES_PER_DETAIL, detail)
    paths, half_widths, sides = _blades(n, rng, blade_width)
    shade = rng.random(n) < 0.5  # two shades of green, by blade
    res = g.scaled_res(GROUND_RES, detail)
    ground = g.grid((-HALF, 0.0, -HALF), (0.0, 0.0, 2 * HALF), (2 * HALF, 0.0, 0.0), res, res)
    objects = [g.make_object("ground", ground, _SOIL)]
    for name, mask, mat in (("blades_dark", ~shade, _BLADE_A), ("blades_light", shade, _BLADE_B)):
        if np.any(mask):
            blades = g.ribbons(paths[mask], half_widths[mask], sides[mask])
            objects.append(g.make_object(name, blades, mat, double_sided=True))
    lo, hi = g.scene_bounds([ground, (paths.reshape(-1, 3), np.zeros((0, 3)))])
    return Scene(objects=objects, sun_direction=(0.3, 0.85, 0.45),
                 area_light=g.overhead_area_light(lo, hi, fraction=0.25), name="grass")

"""Bird's nest: a bowl of tangled thin twigs on a modest ground disc.

Stands in for the thesis's nest scene (§2.3.3, Fig. 8–9, Tables 2–7: 6.7 万 = 67k
triangles), the scene with the most intricate occlusion. Every twig is a thin closed
5-sided prism bent along 3 segments (36 triangles, ``geometry.tubes``); twig centres
fill a flattened bowl-shaped shell (outer diameter ≈ 0.7 m, height ≈ 0.37 m) and the
twigs run mostly around the bowl, following its curvature. The nest sits on a modest
ground disc (``geometry.footprint_disc``: diameter 1.4 × the nest's footprint, ≈ 1.0 m,
48 triangles) so that, as in the thesis's Fig. 8/9, the nest and not a ground plane fills
views framed on the scene. The number of twigs is proportional to detail (1860 at
detail 1), so triangles ≈ 67k × detail.
"""

from __future__ import annotations

import numpy as np

from scenes.builtin import geometry as g
from scenes.model import Material, Scene

DESCRIPTION = "bird's nest: ~1.9k thin bent twig prisms woven into a bowl (thesis §2.3.3, 67k triangles)"

TWIGS_PER_DETAIL = 1860
SIDES = 5
SEGMENTS = 3
GROUND_SCALE = 1.4  # ground disc diameter / nest footprint
GROUND_SEGMENTS = 48

_BARK = Material(albedo=(0.32, 0.22, 0.13))
_STRAW = Material(albedo=(0.55, 0.45, 0.28))
_GROUND = Material(albedo=(0.35, 0.32, 0.25))


def estimate_triangles(detail: float) -> int:
    twigs = g.scaled_count(TWIGS_PER_DETAIL, detail) * g.tube_triangles(SEGMENTS, SIDES)
    return twigs + g.disc_triangles(GROUND_SEGMENTS)


def _twig_paths(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(n, SEGMENTS+1, 3) twig polylines and (n, SEGMENTS+1) radii, in metres."""
    r_in, r_out, flat = 0.17, 0.30, 0.7  # shell radii, vertical flattening
    # polar angle from straight down; more twigs towards the (thicker) rim
    psi = np.deg2rad(112.0) * np.sqrt(rng.random(n)) ** 0.8
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    rho = rng.uniform(r_in, r_out, n)
    radial = np.stack([np.sin(psi) * np.cos(phi), -np.cos(psi), np.sin(psi) * np.sin(phi)], 1)
    e_phi = np.stack([-np.sin(phi), np.zeros(n), np.cos(phi)], 1)
    e_psi = np.stack([np.cos(psi) * np.cos(phi), np.sin(psi), np.cos(psi) * np.sin(phi)], 1)
    alpha = rng.normal(0.0, 0.7, n)  # mostly circumferential
    lift = rng.normal(0.0, 0.25, n)  # some twigs poke in or out of the shell
    d = np.cos(alpha)[:, None] * e_phi + np.sin(alpha)[:, None] * e_psi + lift[:, None] * radial
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    length = rng.uniform(0.09, 0.24, n)
    s = np.linspace(-0.5, 0.5, SEGMENTS + 1)
    pts = rho[:, None, None] * radial[:, None, :] + (length[:, None] * s)[:, :, None] * d[:, None, :]
    # follow the bowl: pull every point back toward the twig's shell radius, plus a
    # little random bending; points near the axis are left alone
    norm = np.linalg.norm(pts, axis=2, keepdims=True)
    target = rho[:, None, None] * (1.0 + 0.6 * lift[:, None, None] * s[None, :, None])
    pts = pts * (0.7 + 0.3 * target / np.maximum(norm, 1e-6))
    pts += rng.normal(0.0, 0.012, pts.shape) * length[:, None, None] / 0.15
    pts[:, :, 1] = pts[:, :, 1] * flat + r_out * flat + 0.01  # bottom near y = 0
    radius0 = rng.uniform(0.0022, 0.0050, n)
    radii = radius0[:, None] * np.linspace(1.0, 0.6, SEGMENTS + 1)[None, :]
    return pts, radii


def build(detail: float, rng: np.random.Generator) -> Scene:
    n = g.scaled_count(TWIGS_PER_DETAIL, detail)
    paths, radii = _twig_paths(n, rng)
    light = rng.random(n) < 0.3  # 30 % pale straw-like twigs
    twigs_dark = g.tubes(paths[~light], radii[~light], SIDES)
    twigs_light = g.tubes(paths[light], radii[light], SIDES)
    ground = g.footprint_disc([twigs_dark, twigs_light], GROUND_SCALE, GROUND_SEGMENTS)
    objects = [g.make_object("ground", ground, _GROUND)]
    for name, mesh, mat in (("twigs_dark", twigs_dark, _BARK), ("twigs_light", twigs_light, _STRAW)):
        if len(mesh[1]):
            objects.append(g.make_object(name, mesh, mat))
    lo, hi = g.scene_bounds([ground, twigs_dark, twigs_light])
    return Scene(objects=objects, sun_direction=(0.4, 0.8, 0.3),
                 area_light=g.overhead_area_light(lo, hi, fraction=0.25), name="nest")

"""Mirror: a planar mirror (s = 1, g = 0) facing a sphere, a box and a cylinder on a floor.

A small test scene (≈ 4k triangles at detail 1) for the cluster depth images of
Chapter 4: a planar mirror is the case where the cluster camera must be the mirrored
eye exactly, with no occlusion error (§4.4; DESIGN.md, technique 3). The mirror is a
single-sided 2.4 m × 1.6 m grid in the plane z = −1.5 facing +Z (toward the objects),
with a thin closed backing box 5 mm behind it. Floor: a 6 m square grid facing up. All
tessellations grow with √detail (triangles ∝ detail). No randomness.
"""

from __future__ import annotations

import numpy as np

from scenes.builtin import geometry as g
from scenes.model import Material, Scene

DESCRIPTION = "planar mirror (s=1, g=0) facing a sphere, a box and a cylinder on a floor (small test scene)"

MIRROR_Z = -1.5
FLOOR_HALF = 3.0

#: An oblique viewpoint (metres) from which the mirror fills part of the frame beside the
#: objects it reflects: the view the reflection tests and benchmarks share.
VIEW_EYE = (2.5, 1.6, 3.0)
VIEW_TARGET = (0.0, 0.9, -0.5)

_MIRROR = Material(albedo=(0.9, 0.9, 0.9), specular=1.0, glossiness=0.0)
_FRAME = Material(albedo=(0.25, 0.16, 0.10))
_FLOOR = Material(albedo=(0.6, 0.58, 0.55))
_RED = Material(albedo=(0.7, 0.12, 0.1))
_BLUE = Material(albedo=(0.12, 0.25, 0.7))
_GREEN = Material(albedo=(0.15, 0.55, 0.15))


def _res(detail: float) -> dict[str, int]:
    return {"floor": g.scaled_res(24, detail), "mirror_u": g.scaled_res(12, detail, 1),
            "mirror_v": g.scaled_res(8, detail, 1), "lat": g.scaled_res(24, detail, 4),
            "lon": g.scaled_res(48, detail, 6), "box": g.scaled_res(2, detail), "cyl": g.scaled_res(48, detail, 6)}


def estimate_triangles(detail: float) -> int:
    r = _res(detail)
    return (g.grid_triangles(r["floor"], r["floor"]) + g.grid_triangles(r["mirror_u"], r["mirror_v"])
            + g.box_triangles(1) + g.sphere_triangles(r["lat"], r["lon"]) + g.box_triangles(r["box"])
            + g.tube_triangles(1, r["cyl"]))


def build(detail: float, rng: np.random.Generator) -> Scene:
    del rng  # deterministic scene
    r = _res(detail)
    floor = g.grid((-FLOOR_HALF, 0.0, -FLOOR_HALF), (0.0, 0.0, 2 * FLOOR_HALF), (2 * FLOOR_HALF, 0.0, 0.0),
                   r["floor"], r["floor"])
    mirror = g.grid((-1.2, 0.1, MIRROR_Z), (2.4, 0.0, 0.0), (0.0, 1.6, 0.0), r["mirror_u"], r["mirror_v"])
    backing = g.box((-1.25, 0.05, MIRROR_Z - 0.06), (1.25, 1.75, MIRROR_Z - 0.005))
    sphere = g.uv_sphere((-0.55, 0.35, -0.35), 0.35, r["lat"], r["lon"])
    half = np.array([0.25, 0.25, 0.25])
    cube = g.transform(g.box(-half, half, r["box"]), rotation=g.rotation_y(0.5), translation=(0.55, 0.25, 0.0))
    cyl = g.cylinder((0.05, 0.0, 0.65), (0.05, 0.6, 0.65), 0.2, r["cyl"])
    objects = [
        g.make_object("floor", floor, _FLOOR),
        g.make_object("mirror", mirror, _MIRROR),
        g.make_object("mirror_backing", backing, _FRAME),
        g.make_object("sphere", sphere, _RED),
        g.make_object("box", cube, _BLUE),
        g.make_object("cylinder", cyl, _GREEN),
    ]
    lo, hi = g.scene_bounds([floor, mirror, sphere, cube, cyl])
    return Scene(objects=objects, sun_direction=(0.3, 0.8, 0.5),
                 area_light=g.overhead_area_light(lo, hi, fraction=0.25, height=3.0), name="mirror")

"""Cornell box: a closed 2 m room open toward the camera (+Z), two blocks, coloured walls.

A small classic test scene (< 5k triangles at detail 1), not from the thesis. Floor,
ceiling and back wall are white, the left wall (x = −1) red and the right wall (x = +1)
green; all walls are grids facing into the room (``geometry.room_walls``), so a camera
in front of the opening at z > 1 looks in. A tall block (0.6 × 1.2 × 0.6 m) and a
short cube (0.6 m) stand on the floor, rotated about +Y; their sides are subdivided.
The area light (0.5 m square, ¼ of the room width) hangs just under the ceiling. Wall
and block tessellation grows with √detail, so triangles ∝ detail. No randomness.
"""

from __future__ import annotations

import numpy as np

from scenes.builtin import geometry as g
from scenes.model import AreaLight, Material, Scene

DESCRIPTION = "Cornell box: 2 m room open toward +Z, red/green side walls, two rotated blocks (small test scene)"

LO, HI = (-1.0, 0.0, -1.0), (1.0, 2.0, 1.0)
WALL_RES = 16  # cells per 2 m wall edge at detail 1
BLOCK_RES = 4  # cells per block side edge at detail 1

_WHITE = Material(albedo=(0.73, 0.73, 0.73))
_RED = Material(albedo=(0.63, 0.065, 0.05))
_GREEN = Material(albedo=(0.14, 0.45, 0.09))
_BLOCK = Material(albedo=(0.72, 0.70, 0.66))


def _cell(detail: float) -> float:
    return 2.0 / g.scaled_res(WALL_RES, detail)


def estimate_triangles(detail: float) -> int:
    walls = g.room_wall_triangles(LO, HI, _cell(detail), ("floor", "ceiling", "back", "left", "right"))
    return walls + 2 * g.box_triangles(g.scaled_res(BLOCK_RES, detail))


def _block(size: tuple[float, float, float], xz: tuple[float, float], yaw: float, divisions: int) -> g.Mesh:
    half = np.asarray(size) / 2
    mesh = g.box(-half, half, divisions)
    return g.transform(mesh, rotation=g.rotation_y(yaw), translation=(xz[0], half[1], xz[1]))


def build(detail: float, rng: np.random.Generator) -> Scene:
    del rng  # deterministic scene
    walls = g.room_walls(LO, HI, _cell(detail), ("floor", "ceiling", "back", "left", "right"))
    div = g.scaled_res(BLOCK_RES, detail)
    objects = [
        g.make_object("white_walls", g.merge([walls["floor"], walls["ceiling"], walls["back"]]), _WHITE),
        g.make_object("red_wall", walls["left"], _RED),
        g.make_object("green_wall", walls["right"], _GREEN),
        g.make_object("tall_block", _block((0.6, 1.2, 0.6), (-0.35, -0.3), 0.30, div), _BLOCK),
        g.make_object("short_block", _block((0.6, 0.6, 0.6), (0.4, 0.3), -0.30, div), _BLOCK),
    ]
    light = AreaLight(center=(0.0, 1.98, 0.0), u=(0.5, 0.0, 0.0), v=(0.0, 0.0, 0.5))
    return Scene(objects=objects, sun_direction=(0.25, 0.55, 0.8), area_light=light, name="cornell")

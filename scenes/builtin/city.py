"""City: box buildings of varied heights on a street grid.

Stands in for the thesis's city scene (§2.3.3 with Tables 2–7: 5 万 = 50k triangles), the
scene with large occluders and deep occluded regions. Square blocks (40 m, 12 m
streets) sit on an asphalt ground grid; each block has a raised pavement slab and four
lots; each lot has a building made of four closed boxes (``geometry.boxes``): a main
volume, an upper tier (setback or tower), and two rooftop units (plant rooms, water
tanks). Heights fall off from the centre (main volumes 6–140 m, towers on top of the
tall ones reach ≈ 200 m downtown); the city at detail 1 is ≈ 0.9 km across. The number of
blocks is proportional to detail (250 at detail 1, 204 triangles each): the city grows
outward from the centre, block by block, in order of distance.
"""

from __future__ import annotations

import math

import numpy as np

from scenes.builtin import geometry as g
from scenes.model import Material, Scene

DESCRIPTION = "city: ~1k box buildings with setbacks and rooftop units on a street grid (thesis §2.3.3, 50k triangles)"

BLOCKS_PER_DETAIL = 250
BLOCK = 40.0  # m
STREET = 12.0  # m
GROUND_RES = 8
BOXES_PER_BUILDING = 4

_ASPHALT = Material(albedo=(0.18, 0.18, 0.19))
_PAVEMENT = Material(albedo=(0.55, 0.54, 0.50))
_FACADES = (
    ("buildings_concrete", Material(albedo=(0.62, 0.60, 0.56))),
    ("buildings_brick", Material(albedo=(0.55, 0.30, 0.22))),
    ("buildings_glass", Material(albedo=(0.35, 0.45, 0.55))),
)
_ROOF = Material(albedo=(0.40, 0.40, 0.42))


def estimate_triangles(detail: float) -> int:
    blocks = g.scaled_count(BLOCKS_PER_DETAIL, detail)
    res = g.scaled_res(GROUND_RES, detail)
    return blocks * (12 + 4 * 12 * BOXES_PER_BUILDING) + g.grid_triangles(res, res)


def _block_centres(n: int) -> np.ndarray:
    """(n,2) block centres: the n grid cells nearest the origin (stable order)."""
    side = int(math.ceil(math.sqrt(n))) + 1
    pitch = BLOCK + STREET
    idx = np.arange(side) - (side - 1) / 2.0
    gx, gz = np.meshgrid(idx, idx, indexing="ij")
    cells = np.stack([gx.ravel(), gz.ravel()], 1) * pitch
    order = np.lexsort((np.arange(len(cells)), np.round(np.hypot(cells[:, 0], cells[:, 1]), 6)))
    return cells[order[:n]]


def build(detail: float, rng: np.random.Generator) -> Scene:
    n_blocks = g.scaled_count(BLOCKS_PER_DETAIL, detail)
    blocks = _block_centres(n_blocks)
    slab_h = 0.15
    pavement = g.boxes(np.column_stack([blocks[:, 0], np.full(n_blocks, slab_h / 2), blocks[:, 1]]),
                       np.tile([BLOCK, slab_h, BLOCK], (n_blocks, 1)))
    # four lots per block (lot size 20 m); one building per lot
    lot_off = np.array([[-1, -1], [-1, 1], [1, -1], [1, 1]]) * (BLOCK / 4)
    lots = (blocks[:, None, :] + lot_off[None]).reshape(-1, 2)
    n = len(lots)
    lot = BLOCK / 2
    dist = np.hypot(lots[:, 0], lots[:, 1])
    radius = max(float(dist.max()), 1.0)
    downtown = np.exp(-((dist / (0.45 * radius)) ** 2))
    height = 6.0 + rng.gamma(2.0, 6.0, n) + 110.0 * downtown * rng.random(n) ** 1.5
    height = np.minimum(height, 140.0)
    fw = rng.uniform(0.55, 0.85, n) * (lot - 2.0)
    fd = rng.uniform(0.55, 0.85, n) * (lot - 2.0)
    ox = rng.uniform(-1, 1, n) * (lot - 2.0 - fw) / 2
    oz = rng.uniform(-1, 1, n) * (lot - 2.0 - fd) / 2
    cx, cz = lots[:, 0] + ox, lots[:, 1] + oz
    main_c = np.column_stack([cx, slab_h + height / 2, cz])
    main_s = np.column_stack([fw, height, fd])
    # upper tier: a tower on tall buildings, a low setback storey on the others
    tower = height > 40.0
    tier_h = np.where(tower, height * rng.uniform(0.2, 0.6, n), rng.uniform(3.0, 6.0, n))
    tier_f = np.where(tower, rng.uniform(0.45, 0.75, n), rng.uniform(0.6, 0.9, n))
    tier_w, tier_d = fw * tier_f, fd * tier_f
    tier_ox = rng.uniform(-1, 1, n) * (fw - tier_w) / 2
    tier_oz = rng.uniform(-1, 1, n) * (fd - tier_d) / 2
    top = slab_h + height
    tier_c = np.column_stack([cx + tier_ox, top + tier_h / 2, cz + tier_oz])
    tier_s = np.column_stack([tier_w, tier_h, tier_d])
    # two rooftop units on the tier roof
    roof_y = top + tier_h
    unit_w = rng.uniform(1.5, 4.5, (n, 2))
    unit_d = rng.uniform(1.5, 4.5, (n, 2))
    unit_h = rng.uniform(1.2, 4.0, (n, 2))
    unit_x = cx[:, None] + tier_ox[:, None] + rng.uniform(-0.3, 0.3, (n, 2)) * np.maximum(tier_w[:, None] - 4.5, 0)
    unit_z = cz[:, None] + tier_oz[:, None] + rng.uniform(-0.3, 0.3, (n, 2)) * np.maximum(tier_d[:, None] - 4.5, 0)
    units = g.boxes(np.column_stack([unit_x.ravel(), (roof_y[:, None] + unit_h / 2).ravel(), unit_z.ravel()]),
                    np.column_stack([unit_w.ravel(), unit_h.ravel(), unit_d.ravel()]),
                    yaw=rng.uniform(-0.3, 0.3, 2 * n))
    facade = rng.integers(0, len(_FACADES), n)

    side = float(np.abs(blocks).max()) + BLOCK / 2 + STREET
    res = g.scaled_res(GROUND_RES, detail)
    ground = g.grid((-side, 0.0, -side), (0.0, 0.0, 2 * side), (2 * side, 0.0, 0.0), res, res)
    objects = [g.make_object("ground", ground, _ASPHALT), g.make_object("pavement", pavement, _PAVEMENT)]
    for k, (name, mat) in enumerate(_FACADES):
        m = facade == k
        if np.any(m):
            mesh = g.boxes(np.concatenate([main_c[m], tier_c[m]]), np.concatenate([main_s[m], tier_s[m]]))
            objects.append(g.make_object(name, mesh, mat))
    objects.append(g.make_object("rooftop_units", units, _ROOF))
    lo, hi = g.scene_bounds([ground, units, (main_c + main_s / 2, np.zeros((0, 3)))])
    return Scene(objects=objects, sun_direction=(0.45, 0.75, 0.35),
                 area_light=g.overhead_area_light(lo, hi, fraction=0.25), name="city")

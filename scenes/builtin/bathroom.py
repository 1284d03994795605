"""Bathroom: tiled walls, basin, toilet, bathtub and a wall mirror; about half reflective.

Stands in for the thesis's bathroom (盥洗室) scene of Chapter 4 (§4.7, Table 12: 9 万 =
90k triangles, 4.4 万 diffuse and 4.6 万 reflective; Fig. 22: 15 reflective objects).
Room: 3.2 m (x) × 2.8 m (z) × 2.5 m, floor at y = 0, walls facing inward, no ceiling.
The lower 1.5 m of the back, left and right walls are covered by 10 cm tiles (closed
thin boxes with grout gaps), the floor by 20 cm tiles.

Reflectors, one object each: the wall mirror (s = 1, g = 0; a single-sided grid facing
+Z in front of a closed backing box), the vessel basin, the toilet (oval bowl, tank, seat)
and the oval bathtub (glazed ceramic, s 0.35, g 0.1; surfaces of revolution with inner
walls), and chrome fittings (s 0.9, g 0.05): basin tap, bath tap with shower rose, towel
rail. Diffuse: walls, tiles, cabinet, towel, bottles, shelf, a potted plant, bath mat,
toilet roll, soap.

Tessellation ∝ √detail and tile and leaf counts ∝ detail: triangles ≈ 90k × detail.
"""

from __future__ import annotations

import numpy as np

from scenes.builtin import geometry as g
from scenes.model import Material, Scene

DESCRIPTION = ("bathroom: tiled walls, wall mirror (s=1), basin, toilet, bathtub and chrome fittings "
               "(thesis §4.7, 90k triangles, ~half reflective)")

ROOM_LO, ROOM_HI = (-1.6, 0.0, -1.4), (1.6, 2.5, 1.4)
TILE_TOP = 1.5  # m, height of the wall tiling
TILE_T = 0.008  # m, tile thickness

_MIRROR = Material(albedo=(0.9, 0.9, 0.9), specular=1.0, glossiness=0.0)
_CERAMIC = Material(albedo=(0.93, 0.93, 0.92), specular=0.35, glossiness=0.1)
_CHROME = Material(albedo=(0.8, 0.8, 0.82), specular=0.9, glossiness=0.05)

_PLASTER = Material(albedo=(0.85, 0.84, 0.80))
_WALL_TILES = Material(albedo=(0.55, 0.70, 0.75))
_FLOOR_TILES = Material(albedo=(0.40, 0.38, 0.36))
_GROUT = Material(albedo=(0.75, 0.75, 0.72))
_CABINET = Material(albedo=(0.72, 0.62, 0.48))
_TOWEL = Material(albedo=(0.80, 0.35, 0.30))
_BOTTLES = Material(albedo=(0.30, 0.55, 0.75))
_POT = Material(albedo=(0.85, 0.85, 0.82))
_LEAVES = Material(albedo=(0.15, 0.42, 0.12))
_MAT = Material(albedo=(0.30, 0.45, 0.65))
_PAPER = Material(albedo=(0.95, 0.95, 0.93))
_FRAME = Material(albedo=(0.2, 0.2, 0.22))

_CALIBRATION = (1_000.0, 90_900.0)  # estimate = a + b·detail, fitted to the built counts


def estimate_triangles(detail: float) -> int:
    a, b = _CALIBRATION
    return int(round(a + b * detail))


def _res(detail: float) -> dict[str, int]:
    r = g.scaled_res
    return {
        "wall_cell_inv": r(10, detail), "tiles_per_m": r(10, detail, 2), "floor_tiles_per_m": r(5, detail, 1),
        "mirror_u": r(32, detail), "mirror_v": r(24, detail),
        "basin_seg": r(128, detail, 8), "basin_prof": r(64, detail, 10),
        "bowl_seg": r(96, detail, 8), "bowl_prof": r(48, detail, 10),
        "seat_prof": r(16, detail, 4), "tub_seg": r(128, detail, 8), "tub_prof": r(48, detail, 10),
        "pipe_k": r(24, detail, 2), "pipe_s": r(16, detail, 3), "box_div": r(4, detail),
        "bottle_seg": r(32, detail, 6), "bottle_prof": r(24, detail, 6),
        "pot_seg": r(64, detail, 8), "pot_prof": r(40, detail, 10), "leaves": g.scaled_count(300, detail),
        "roll_seg": r(48, detail, 6), "soap_lat": r(12, detail, 4), "soap_lon": r(24, detail, 6),
    }


def _tiles(r: dict[str, int]) -> tuple[g.Mesh, g.Mesh]:
    """Wall tiles (back, left, right walls up to TILE_TOP) and floor tiles, as boxes."""
    lo, hi = np.array(ROOM_LO), np.array(ROOM_HI)
    centres, sizes = [], []
    n_per_m = r["tiles_per_m"]
    ny = max(1, int(round(TILE_TOP * n_per_m)))
    for wall in ("back", "left", "right"):
        axis = 0 if wall == "back" else 2  # horizontal axis along the wall
        length = hi[axis] - lo[axis]
        nh = max(1, int(round(length * n_per_m)))
        th, tv = length / nh, TILE_TOP / ny
        gap = 0.15 * min(th, tv)
        a, b = np.meshgrid((np.arange(nh) + 0.5) * th + lo[axis], (np.arange(ny) + 0.5) * tv, indexing="ij")
        c = np.zeros((a.size, 3))
        s = np.zeros((a.size, 3))
        c[:, axis], c[:, 1] = a.ravel(), b.ravel()
        s[:, axis], s[:, 1] = th - gap, tv - gap
        if wall == "back":
            c[:, 2], s[:, 2] = lo[2] + TILE_T / 2, TILE_T
        else:
            c[:, 0] = lo[0] + TILE_T / 2 if wall == "left" else hi[0] - TILE_T / 2
            s[:, 0] = TILE_T
        centres.append(c)
        sizes.append(s)
    wall_tiles = g.boxes(np.concatenate(centres), np.concatenate(sizes))
    nf = r["floor_tiles_per_m"]
    nx, nz = max(1, int(round((hi[0] - lo[0]) * nf))), max(1, int(round((hi[2] - lo[2]) * nf)))
    tx, tz = (hi[0] - lo[0]) / nx, (hi[2] - lo[2]) / nz
    gap = 0.05 * min(tx, tz)
    a, b = np.meshgrid((np.arange(nx) + 0.5) * tx + lo[0], (np.arange(nz) + 0.5) * tz + lo[2], indexing="ij")
    n = a.size
    floor_tiles = g.boxes(np.column_stack([a.ravel(), np.full(n, TILE_T / 2), b.ravel()]),
                          np.tile([tx - gap, TILE_T, tz - gap], (n, 1)))
    return wall_tiles, floor_tiles


def _mirror(r: dict[str, int]) -> tuple[g.Mesh, g.Mesh]:
    z = ROOM_LO[2] + 0.03
    mirror = g.grid((-0.5, 1.15, z), (0.8, 0.0, 0.0), (0.0, 0.9, 0.0), r["mirror_u"], r["mirror_v"])
    backing = g.box((-0.53, 1.12, ROOM_LO[2] + TILE_T), (0.33, 2.08, z - 0.003))
    return mirror, backing


def _basin(r: dict[str, int]) -> g.Mesh:
    prof = g.vessel_profile(np.array([(0, 0), (0.08, 0), (0.14, 0.03), (0.2, 0.1), (0.22, 0.15)]), 0.012,
                            r["basin_prof"])
    return g.transform(g.lathe(prof, r["basin_seg"]), scale=(1.0, 1.0, 0.75), translation=(-0.1, 0.82, -1.1))


def _toilet(r: dict[str, int]) -> g.Mesh:
    bowl_prof = g.vessel_profile(np.array([(0, 0), (0.1, 0), (0.12, 0.1), (0.11, 0.2), (0.17, 0.36), (0.19, 0.4)]),
                                 0.015, r["bowl_prof"])
    bowl = g.transform(g.lathe(bowl_prof, r["bowl_seg"]), scale=(0.9, 1.0, 1.2), translation=(0.95, 0.0, -0.85))
    seat_prof = g.resample_polyline(np.array([(0.13, 0.0), (0.2, 0.0), (0.2, 0.025), (0.13, 0.025)]),
                                    r["seat_prof"], closed=True)
    seat = g.transform(g.lathe(seat_prof, r["bowl_seg"], closed=True), scale=(0.9, 1.0, 1.2),
                       translation=(0.95, 0.401, -0.85))
    tank = g.box((0.75, 0.4, -1.39), (1.15, 0.8, -1.19), r["box_div"])
    return g.merge([bowl, seat, tank])


def _tub(r: dict[str, int]) -> g.Mesh:
    prof = g.vessel_profile(np.array([(0, 0), (0.25, 0), (0.33, 0.08), (0.36, 0.4), (0.37, 0.55)]), 0.03,
                            r["tub_prof"])
    return g.transform(g.lathe(prof, r["tub_seg"]), scale=(1.0, 1.0, 2.4), translation=(-1.2, 0.0, 0.4))


def _fittings(r: dict[str, int]) -> tuple[g.Mesh, g.Mesh, g.Mesh]:
    k, s = r["pipe_k"], r["pipe_s"]
    t = np.linspace(0.0, 1.0, k + 1)[:, None]
    # basin tap: a pillar behind the basin and a goose-neck spout arching over it
    pillar = np.column_stack([np.full(k + 1, -0.1), 0.82 + 0.25 * t[:, 0], np.full(k + 1, -1.33)])
    a = np.pi * t[:, 0]
    neck = np.column_stack([np.full(k + 1, -0.1), 1.07 + 0.09 * np.sin(a), -1.33 + 0.08 * (1 - np.cos(a))])
    basin_tap = g.merge([g.tubes(pillar[None], 0.016, s), g.tubes(neck[None], 0.01, s)])
    # bath tap on the left wall with a riser and a shower rose
    x0 = ROOM_LO[0] + TILE_T
    spout = np.column_stack([x0 + 0.15 * t[:, 0] ** 0.7, 0.75 - 0.05 * t[:, 0] ** 2, np.full(k + 1, 1.2)])
    riser = np.column_stack([np.full(k + 1, x0 + 0.05), 0.75 + 1.15 * t[:, 0], np.full(k + 1, 1.2)])
    arm = np.column_stack([x0 + 0.05 + 0.25 * t[:, 0], 1.9 + 0.05 * np.sin(np.pi * t[:, 0]), np.full(k + 1, 1.2)])
    rose = g.cylinder((x0 + 0.3, 1.92, 1.2), (x0 + 0.3, 1.86, 1.2), 0.07, max(s, 8))
    bath_tap = g.merge([g.tubes(spout[None], 0.018, s), g.tubes(riser[None], 0.012, s), g.tubes(arm[None], 0.01, s),
                        rose])
    # towel rail on the right wall: two bars on short brackets
    x1 = ROOM_HI[0] - TILE_T
    bars = np.array([[[x1 - 0.07, y, 0.05], [x1 - 0.07, y, 0.85]] for y in (0.95, 1.15)])
    brackets = np.array([[[x1, y, z], [x1 - 0.07, y, z]] for y in (0.95, 1.15) for z in (0.1, 0.8)])
    rail = g.merge([g.tubes(bars, 0.012, s), g.tubes(brackets, 0.01, max(3, s // 2))])
    return basin_tap, bath_tap, rail


def _bottles(r: dict[str, int], rng: np.random.Generator) -> g.Mesh:
    shapes = (((0, 0), (0.03, 0), (0.032, 0.02), (0.03, 0.14), (0.012, 0.17), (0.012, 0.2), (0, 0.2)),
              ((0, 0), (0.025, 0), (0.028, 0.1), (0.02, 0.12), (0.008, 0.14), (0, 0.145)),
              ((0, 0), (0.04, 0), (0.042, 0.06), (0.035, 0.18), (0.015, 0.21), (0, 0.22)))
    spots = ((0.15, 0.82, -1.3), (0.22, 0.82, -1.25), (-1.55, 1.57, 0.7), (-1.52, 1.57, 0.85), (-1.55, 1.57, 1.0))
    parts = []
    for i, pos in enumerate(spots):
        prof = g.solid_profile(np.array(shapes[i % 3], dtype=np.float64) * rng.uniform(0.9, 1.1), r["bottle_prof"])
        parts.append(g.transform(g.lathe(prof, r["bottle_seg"]), translation=pos))
    return g.merge(parts)


def _plant(r: dict[str, int], rng: np.random.Generator) -> tuple[g.Mesh, g.Mesh]:
    pos = np.array([1.05, 0.0, 0.95])
    prof = g.vessel_profile(np.array([(0, 0), (0.09, 0), (0.11, 0.04), (0.13, 0.26), (0.14, 0.3)]), 0.012,
                            r["pot_prof"])
    soil_prof = np.array([(0, 0.22), (0.125, 0.22), (0.127, 0.25), (0, 0.25)])
    pot = g.merge([g.transform(g.lathe(prof, r["pot_seg"]), translation=pos),
                   g.transform(g.lathe(soil_prof, r["pot_seg"]), translation=pos)])
    n, k = r["leaves"], 5
    azim = rng.uniform(0, 2 * np.pi, n)
    length = rng.uniform(0.25, 0.42, n)
    lean = rng.uniform(0.05, 0.5, n)[:, None] + rng.uniform(0.3, 1.2, n)[:, None] * ((np.arange(k) + 0.5) / k)
    step = (length / k)[:, None]
    dy, dh = np.cumsum(np.cos(lean) * step, 1), np.cumsum(np.sin(lean) * step, 1)
    paths = np.repeat((pos + (0, 0.24, 0) + rng.normal(0, 0.03, (n, 3)) * (1, 0, 1))[:, None], k + 1, 1)
    paths[:, 1:, 0] += dh * np.cos(azim)[:, None]
    paths[:, 1:, 2] += dh * np.sin(azim)[:, None]
    paths[:, 1:, 1] += dy
    hw = np.maximum(0.003, rng.uniform(0.008, 0.016, n)[:, None] * np.sin(np.pi * np.linspace(0, 1, k + 1)) ** 0.6)
    hw[:, -1] = 0.0
    leaves = g.ribbons(paths, hw, np.column_stack([-np.sin(azim), np.zeros(n), np.cos(azim)]))  # one side
    return pot, leaves


def build(detail: float, rng: np.random.Generator) -> Scene:
    r = _res(detail)
    walls = g.room_walls(ROOM_LO, ROOM_HI, 1.0 / r["wall_cell_inv"], ("back", "front", "left", "right", "floor"))
    wall_tiles, floor_tiles = _tiles(r)
    mirror, backing = _mirror(r)
    basin_tap, bath_tap, rail = _fittings(r)
    pot, leaves = _plant(r, rng)
    d = r["box_div"]
    cabinet = g.merge([g.box((-0.48, 0.1, -1.39), (0.28, 0.82, -0.88), d),
                       g.box((-0.46, 0.0, -1.37), (0.26, 0.1, -0.92))])
    shelf = g.box((ROOM_LO[0] + TILE_T, 1.54, 0.6), (ROOM_LO[0] + 0.12, 1.57, 1.1))
    towel = g.merge([g.box((ROOM_HI[0] - 0.095, 0.55, 0.15), (ROOM_HI[0] - 0.075, 1.15, 0.75), d),
                     g.box((ROOM_HI[0] - 0.08, 0.75, 0.16), (ROOM_HI[0] - 0.055, 1.15, 0.74), d)])
    roll = g.lathe(g.resample_polyline(np.array([(0.02, -0.05), (0.055, -0.05), (0.055, 0.05), (0.02, 0.05)]),
                                       12, closed=True), r["roll_seg"], closed=True)
    roll = g.transform(roll, rotation=np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),
                       translation=(ROOM_HI[0] - TILE_T - 0.062, 0.7, -0.7))
    soap = g.ellipsoid((-0.38, 0.84, -1.2), (0.045, 0.018, 0.03), r["soap_lat"], r["soap_lon"])
    objects = [
        g.make_object("mirror", mirror, _MIRROR),
        g.make_object("basin", _basin(r), _CERAMIC),
        g.make_object("toilet", _toilet(r), _CERAMIC),
        g.make_object("bathtub", _tub(r), _CERAMIC),
        g.make_object("basin_tap", basin_tap, _CHROME),
        g.make_object("bath_tap", bath_tap, _CHROME),
        g.make_object("towel_rail", rail, _CHROME),
        g.make_object("walls", g.merge([walls[k] for k in ("back", "front", "left", "right")]), _PLASTER),
        g.make_object("floor_grout", walls["floor"], _GROUT),
        g.make_object("wall_tiles", wall_tiles, _WALL_TILES),
        g.make_object("floor_tiles", floor_tiles, _FLOOR_TILES),
        g.make_object("mirror_backing", backing, _FRAME),
        g.make_object("cabinet", cabinet, _CABINET),
        g.make_object("shelf", shelf, _CABINET),
        g.make_object("towel", towel, _TOWEL),
        g.make_object("bottles", _bottles(r, rng), _BOTTLES),
        g.make_object("plant_pot", pot, _POT),
        g.make_object("plant_leaves", leaves, _LEAVES, double_sided=True),
        g.make_object("bath_mat", g.box((-0.75, TILE_T, 0.1), (-0.2, TILE_T + 0.012, 0.9)), _MAT),
        g.make_object("toilet_roll", roll, _PAPER),
        g.make_object("soap", soap, _PAPER),
    ]
    return Scene(objects=objects, sun_direction=(0.25, 0.9, 0.35),
                 area_light=g.overhead_area_light(ROOM_LO, ROOM_HI, fraction=0.25, height=ROOM_HI[1] + 0.2),
                 name="bathroom")

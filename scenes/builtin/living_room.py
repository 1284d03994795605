"""Living room: a furnished room where about half of the triangles are reflective.

Stands in for the thesis's living-room scene of Chapter 4 (§4.7, Table 12: 28 万 = 280k
triangles, 15 万 diffuse and 13 万 reflective; Fig. 22: the reflectors are separate
objects). Room: 6 m (x) × 5 m (z) × 2.7 m, floor at y = 0, four walls facing inward
and no ceiling (a camera outside looks in through culled walls; the sun and the area
light shine in from above).

Reflectors, one object each (s = specular factor, g = glossiness, §4.2/§4.6):
mirror-like floor (s 0.8, g 0), glossy round table (s 0.5, g 0.3), five vases
(s 0.7, g 0–0.1; surfaces of revolution with a lip and an inner wall), a teapot-like
pot with spout and handle (s 0.6, g 0.05), a metal floor-lamp stand (s 0.6, g 0.2), a
fruit bowl (s 0.5, g 0.1) and a lacquered sideboard (s 0.4, g 0.2).
Diffuse: walls, rug, sofa with ellipsoid cushions, chairs, two bookshelves full of box
books, two potted plants with arching two-sided leaves, fruit, lamp shade, curtains
(two-sided wavy grids) and pictures.

Curved surfaces are tessellated with resolutions ∝ √detail, repeated items (books,
leaves) are ∝ detail, so the triangle count is ≈ 280k × detail. Randomness (book sizes,
leaves, curtain folds) comes from the seeded generator only.
"""

from __future__ import annotations

import numpy as np

from scenes.builtin import geometry as g
from scenes.model import Material, Scene

DESCRIPTION = ("living room: reflective floor, glossy table, 5 specular vases, teapot, lamp, bowl among "
               "diffuse furniture, books and plants (thesis §4.7, 280k triangles, ~half reflective)")

ROOM_LO, ROOM_HI = (-3.0, 0.0, -2.5), (3.0, 2.7, 2.5)
TABLE_XZ = (0.1, -0.2)
TABLE_TOP = 0.74

# --- materials ---------------------------------------------------------------------------------
_FLOOR = Material(albedo=(0.45, 0.32, 0.22), specular=0.8, glossiness=0.0)
_TABLE = Material(albedo=(0.35, 0.20, 0.12), specular=0.5, glossiness=0.3)
_VASES = (
    Material(albedo=(0.10, 0.22, 0.45), specular=0.7, glossiness=0.0),
    Material(albedo=(0.55, 0.12, 0.10), specular=0.7, glossiness=0.05),
    Material(albedo=(0.85, 0.85, 0.80), specular=0.7, glossiness=0.1),
    Material(albedo=(0.12, 0.40, 0.30), specular=0.7, glossiness=0.0),
    Material(albedo=(0.75, 0.60, 0.20), specular=0.7, glossiness=0.05),
)
_TEAPOT = Material(albedo=(0.80, 0.80, 0.82), specular=0.6, glossiness=0.05)
_LAMP_STAND = Material(albedo=(0.70, 0.55, 0.30), specular=0.6, glossiness=0.2)
_BOWL = Material(albedo=(0.90, 0.90, 0.92), specular=0.5, glossiness=0.1)
_SIDEBOARD = Material(albedo=(0.08, 0.08, 0.09), specular=0.4, glossiness=0.2)

_WALLS = Material(albedo=(0.82, 0.78, 0.70))
_RUG = Material(albedo=(0.45, 0.15, 0.12))
_SOFA = Material(albedo=(0.30, 0.35, 0.42))
_CUSHIONS = Material(albedo=(0.40, 0.45, 0.55))
_CHAIRS = Material(albedo=(0.50, 0.36, 0.22))
_SHELF = Material(albedo=(0.60, 0.48, 0.34))
_BOOKS = Material(albedo=(0.55, 0.35, 0.25))
_POTS = Material(albedo=(0.62, 0.33, 0.20))
_SOIL = Material(albedo=(0.20, 0.14, 0.09))
_LEAVES = Material(albedo=(0.12, 0.38, 0.10))
_FRUIT = Material(albedo=(0.85, 0.45, 0.08))
_SHADE = Material(albedo=(0.92, 0.88, 0.75))
_CURTAINS = Material(albedo=(0.70, 0.62, 0.45))
_FRAMES = Material(albedo=(0.15, 0.12, 0.10))
_CANVAS = Material(albedo=(0.35, 0.50, 0.60))

# --- shapes: vase outlines (r, y) from the bottom pole to the lip, metres ---------------------------
_VASE_SHAPES = (  # (outline, position x, z (y = stand height), wall thickness)
    (((0, 0), (0.12, 0), (0.17, 0.08), (0.22, 0.35), (0.18, 0.6), (0.09, 0.78), (0.08, 0.85), (0.12, 0.9)),
     (1.55, 0.0, -2.1), 0.012),
    (((0, 0), (0.10, 0), (0.13, 0.05), (0.14, 0.4), (0.11, 0.6), (0.10, 0.65), (0.14, 0.7)),
     (-2.35, 0.0, 1.0), 0.012),
    (((0, 0), (0.05, 0), (0.09, 0.05), (0.10, 0.12), (0.06, 0.2), (0.025, 0.26), (0.032, 0.3)),
     (TABLE_XZ[0] + 0.25, TABLE_TOP, TABLE_XZ[1] - 0.2), 0.006),
    (((0, 0), (0.06, 0), (0.10, 0.05), (0.14, 0.15), (0.15, 0.22), (0.16, 0.25)),
     (2.75, 0.8, -0.4), 0.008),
    (((0, 0), (0.05, 0), (0.06, 0.03), (0.05, 0.3), (0.04, 0.4), (0.06, 0.45)),
     (2.75, 0.8, 0.8), 0.006),
)


def _res(detail: float) -> dict[str, int]:
    r = g.scaled_res
    return {
        "floor_x": r(110, detail), "floor_z": r(92, detail),
        "table_seg": r(160, detail, 8), "table_prof": r(40, detail, 6),
        "vase_seg": r(112, detail, 8), "vase_prof": r(72, detail, 10),
        "pot_seg": r(96, detail, 8), "pot_prof": r(48, detail, 6),
        "spout_k": r(24, detail, 2), "spout_s": r(16, detail, 3),
        "lamp_seg": r(64, detail, 8), "lamp_prof": r(48, detail, 8),
        "bowl_seg": r(96, detail, 8), "bowl_prof": r(40, detail, 10),
        "box_div": r(4, detail),
        "wall_cell_inv": r(10, detail),  # cells per metre
        "cush_lat": r(24, detail, 4), "cush_lon": r(48, detail, 6),
        "fruit_lat": r(16, detail, 4), "fruit_lon": r(32, detail, 6),
        "shade_seg": r(96, detail, 8), "shade_prof": r(24, detail, 4),
        "potplant_seg": r(64, detail, 8), "potplant_prof": r(40, detail, 10),
        "curtain_u": r(40, detail, 2), "curtain_v": r(60, detail, 2),
        "books": g.scaled_count(1500, detail), "leaves": g.scaled_count(1900, detail),
    }


_CALIBRATION = (1_500.0, 280_000.0)  # estimate = a + b·detail, fitted to the built counts


def estimate_triangles(detail: float) -> int:
    a, b = _CALIBRATION
    return int(round(a + b * detail))


def _vases(r: dict[str, int]) -> list[g.Mesh]:
    out = []
    for outline, pos, thick in _VASE_SHAPES:
        prof = g.vessel_profile(np.array(outline, dtype=np.float64), thick, r["vase_prof"])
        out.append(g.transform(g.lathe(prof, r["vase_seg"]), translation=pos))
    return out


def _table(r: dict[str, int]) -> g.Mesh:
    y0, y1 = TABLE_TOP - 0.04, TABLE_TOP
    top = g.solid_profile(np.array([(0, y0), (0.45, y0), (0.57, y0 + 0.002), (0.6, y0 + 0.02), (0.57, y1 - 0.002),
                                    (0.45, y1), (0, y1)]), r["table_prof"])
    stand = g.solid_profile(np.array([(0, 0), (0.28, 0), (0.3, 0.02), (0.12, 0.05), (0.05, 0.12), (0.045, 0.4),
                                      (0.05, 0.6), (0.12, y0 - 0.01), (0.14, y0), (0, y0)]), r["table_prof"])
    pos = (TABLE_XZ[0], 0.0, TABLE_XZ[1])
    return g.merge([g.transform(g.lathe(top, r["table_seg"]), translation=pos),
                    g.transform(g.lathe(stand, r["table_seg"]), translation=pos)])


def _teapot(r: dict[str, int]) -> g.Mesh:
    body = g.solid_profile(np.array([(0, 0), (0.07, 0), (0.10, 0.03), (0.11, 0.08), (0.095, 0.13), (0.06, 0.15),
                                     (0.05, 0.16), (0.03, 0.165), (0.012, 0.175), (0.016, 0.19), (0, 0.195)]),
                           r["pot_prof"])
    k = r["spout_k"]
    s = np.linspace(0.0, 1.0, k + 1)[:, None]
    # quadratic Bézier spout from inside the body up and out (+x)
    p0, p1, p2 = np.array([0.07, 0.05, 0.0]), np.array([0.17, 0.06, 0.0]), np.array([0.2, 0.16, 0.0])
    spout = (1 - s) ** 2 * p0 + 2 * s * (1 - s) * p1 + s**2 * p2
    spout_r = np.linspace(0.022, 0.009, k + 1)
    a = np.linspace(-0.45 * np.pi, 0.45 * np.pi, k + 1)
    handle = np.stack([-0.085 - 0.06 * np.cos(a), 0.085 + 0.055 * np.sin(a), np.zeros(k + 1)], 1)
    mesh = g.merge([g.lathe(body, r["pot_seg"]), g.tubes(spout[None], spout_r[None], r["spout_s"]),
                    g.tubes(handle[None], 0.009, r["spout_s"])])
    return g.transform(mesh, rotation=g.rotation_y(0.6),
                       translation=(TABLE_XZ[0] - 0.2, TABLE_TOP, TABLE_XZ[1] + 0.1))


def _bowl_and_fruit(r: dict[str, int], rng: np.random.Generator) -> tuple[g.Mesh, g.Mesh]:
    prof = g.vessel_profile(np.array([(0, 0), (0.04, 0), (0.08, 0.02), (0.11, 0.06), (0.125, 0.085)]), 0.006,
                            r["bowl_prof"])
    pos = np.array([TABLE_XZ[0] + 0.1, TABLE_TOP, TABLE_XZ[1] + 0.3])
    bowl = g.transform(g.lathe(prof, r["bowl_seg"]), translation=pos)
    ang = np.arange(6) * (2 * np.pi / 6) + rng.uniform(-0.2, 0.2, 6)
    centres = [pos + (0.0, 0.045, 0.0)] + [pos + (0.055 * np.cos(t), 0.06, 0.055 * np.sin(t)) for t in ang]
    fruit = g.merge([g.uv_sphere(c, 0.034 * rng.uniform(0.9, 1.1), r["fruit_lat"], r["fruit_lon"])
                     for c in centres])
    return bowl, fruit


def _lamp(r: dict[str, int]) -> tuple[g.Mesh, g.Mesh]:
    stand = g.solid_profile(np.array([(0, 0), (0.17, 0), (0.18, 0.015), (0.1, 0.035), (0.02, 0.06), (0.015, 0.3),
                                      (0.015, 0.8), (0.015, 1.3), (0.03, 1.38), (0.03, 1.42), (0, 1.44)]),
                            r["lamp_prof"])
    shade = g.resample_polyline(np.array([(0.26, 1.22), (0.16, 1.55), (0.154, 1.55), (0.254, 1.22)]),
                                r["shade_prof"], closed=True)
    pos = (2.45, 0.0, -2.0)
    return (g.transform(g.lathe(stand, r["lamp_seg"]), translation=pos),
            g.transform(g.lathe(shade, r["shade_seg"], closed=True), translation=pos))


def _sideboard(r: dict[str, int]) -> g.Mesh:
    d = r["box_div"]
    x0, x1, z0, z1 = 2.5, 2.97, -1.0, 1.2
    body = g.box((x0, 0.15, z0), (x1, 0.76, z1), d)
    top = g.box((x0 - 0.02, 0.76, z0 - 0.02), (x1, 0.8, z1 + 0.02), d)
    corners = [(x, z) for x in (x0 + 0.05, x1 - 0.05) for z in (z0 + 0.05, z1 - 0.05)]
    legs = g.tubes(np.array([[[x, 0.0, z], [x, 0.16, z]] for x, z in corners]), 0.02, 8)
    return g.merge([body, top, legs])


def _sofa(r: dict[str, int]) -> tuple[g.Mesh, g.Mesh]:
    d = r["box_div"]
    x0, x1, z0, z1 = -1.1, 1.1, -2.45, -1.55
    frame = g.merge([
        # overlapping (not just touching) closed boxes: seat base, back, two arms
        g.box((x0 + 0.15, 0.08, z0 + 0.15), (x1 - 0.15, 0.4, z1 - 0.01), d),
        g.box((x0, 0.08, z0), (x1, 0.9, z0 + 0.2), d),
        g.box((x0, 0.08, z0 + 0.15), (x0 + 0.2, 0.65, z1), d),
        g.box((x1 - 0.2, 0.08, z0 + 0.15), (x1, 0.65, z1), d),
        g.tubes(np.array([[[x, 0.0, z], [x, 0.09, z]] for x in (x0 + 0.08, x1 - 0.08) for z in (z0 + 0.08, z1 - 0.08)]),
                0.03, 8),
    ])
    lat, lon = r["cush_lat"], r["cush_lon"]
    cushions = []
    for x in (-0.6, 0.0, 0.6):
        cushions.append(g.ellipsoid((x, 0.47, -1.97), (0.3, 0.09, 0.36), lat, lon))
        cushions.append(g.ellipsoid((x, 0.68, -2.15), (0.3, 0.22, 0.08), lat, lon))
    for x in (-0.75, 0.75):
        cushions.append(g.transform(g.ellipsoid((0, 0, 0), (0.2, 0.2, 0.07), lat, lon),
                                    rotation=g.rotation_y(0.3 * np.sign(x)), translation=(x, 0.68, -2.0)))
    return frame, g.merge(cushions)


def _chairs(r: dict[str, int]) -> g.Mesh:
    d = max(1, r["box_div"] // 2)
    parts = []
    for k, ang in enumerate((0.0, np.pi / 2, np.pi, 3 * np.pi / 2)):
        if k == 3:
            continue  # the side toward the sofa stays free
        seat = g.box((-0.22, 0.44, -0.22), (0.22, 0.48, 0.22), d)
        back = g.box((-0.21, 0.46, 0.175), (0.21, 0.95, 0.225), d)  # overlaps the seat
        legs = g.tubes(np.array([[[x, 0.0, z], [x, 0.45, z]] for x in (-0.19, 0.19) for z in (-0.19, 0.19)]), 0.018, 8)
        chair = g.merge([seat, back, legs])
        dx, dz = np.sin(ang), np.cos(ang)
        parts.append(g.transform(chair, rotation=g.rotation_y(ang),
                                 translation=(TABLE_XZ[0] + 0.85 * dx, 0.0, TABLE_XZ[1] + 0.85 * dz)))
    return g.merge(parts)


def _bookshelves(r: dict[str, int], rng: np.random.Generator) -> tuple[g.Mesh, g.Mesh]:
    """Two shelf units against the left wall and their books (n ∝ detail, upright boxes)."""
    x0, x1 = -2.98, -2.63
    units = ((-1.9, -0.2), (-0.1, 1.6))  # z ranges
    shelf_y = np.linspace(0.08, 1.98, 7)  # shelf boards (top surfaces); 6 rows of books
    frame = []
    rows = []  # (z0, z1, y) per row
    for z0, z1 in units:
        frame += [g.box((x0, 0.0, z0), (x1, 2.02, z0 + 0.03)), g.box((x0, 0.0, z1 - 0.03), (x1, 2.02, z1)),
                  g.box((x0, 0.0, z0 + 0.01), (x0 + 0.02, 2.02, z1 - 0.01))]  # back, overlapping the sides
        frame += [g.box((x0 + 0.01, y - 0.025, z0 + 0.02), (x1, y, z1 - 0.02)) for y in shelf_y]
        rows += [(z0 + 0.035, z1 - 0.035, y) for y in shelf_y[:-1]]
    rows_a = np.array(rows)
    n = r["books"]
    row = (np.arange(n) * len(rows_a)) // n
    per_row = np.bincount(row, minlength=len(rows_a))
    w = rng.uniform(0.6, 1.4, n)
    row_sum = np.bincount(row, weights=w, minlength=len(rows_a))
    length = (rows_a[:, 1] - rows_a[:, 0]) * 0.92
    thick = w / row_sum[row] * length[row]  # books fill 92 % of each row
    end = np.cumsum(thick)
    start_of_row = np.concatenate([[0], np.cumsum(per_row)[:-1]])
    offset = np.concatenate([[0.0], end])[start_of_row][row]
    zc = rows_a[row, 0] + (end - offset) - thick / 2 + 0.04 * length[row] * (row % 2)
    h = rng.uniform(0.17, 0.27, n)
    depth = rng.uniform(0.16, 0.24, n)
    centres = np.column_stack([x0 + 0.02 + depth / 2, rows_a[row, 2] + h / 2, zc])
    books = g.boxes(centres, np.column_stack([depth, h, thick * 0.97]))
    return g.merge(frame), books


def _plants(r: dict[str, int], rng: np.random.Generator) -> tuple[g.Mesh, g.Mesh, g.Mesh]:
    spots = (np.array([-2.2, 0.0, 1.7]), np.array([2.2, 0.0, 1.7]))
    prof = g.vessel_profile(np.array([(0, 0), (0.14, 0), (0.16, 0.05), (0.2, 0.38), (0.21, 0.42)]), 0.015,
                            r["potplant_prof"])
    pots = g.merge([g.transform(g.lathe(prof, r["potplant_seg"]), translation=p) for p in spots])
    soil_prof = np.array([(0, 0.33), (0.19, 0.33), (0.195, 0.36), (0, 0.36)])
    soil = g.merge([g.transform(g.lathe(soil_prof, r["potplant_seg"]), translation=p) for p in spots])
    n = r["leaves"]
    k = 6
    which = np.arange(n) % 2
    base = np.stack(spots)[which] + np.column_stack([rng.normal(0, 0.04, n), np.full(n, 0.35), rng.normal(0, 0.04, n)])
    azim = rng.uniform(0, 2 * np.pi, n)
    length = rng.uniform(0.3, 0.62, n)
    lean0 = rng.uniform(0.05, 0.6, n)
    curl = rng.uniform(0.8, 2.2, n)
    s = (np.arange(k) + 0.5) / k
    theta = lean0[:, None] + curl[:, None] * s[None, :] ** 1.3
    step = (length / k)[:, None]
    dy = np.cumsum(np.cos(theta) * step, axis=1)
    dh = np.cumsum(np.sin(theta) * step, axis=1)
    paths = np.repeat(base[:, None, :], k + 1, axis=1)
    paths[:, 1:, 0] += dh * np.cos(azim)[:, None]
    paths[:, 1:, 2] += dh * np.sin(azim)[:, None]
    paths[:, 1:, 1] += dy
    t = np.linspace(0, 1, k + 1)
    width = rng.uniform(0.025, 0.045, n)
    hw = np.maximum(0.004, width[:, None] * np.sin(np.pi * t)[None, :] ** 0.8)
    hw[:, -1] = 0.0
    side = np.column_stack([-np.sin(azim), np.zeros(n), np.cos(azim)])
    leaves = g.ribbons(paths, hw, side)  # one side; the object is double-sided
    return pots, soil, leaves


def _curtains(r: dict[str, int], rng: np.random.Generator) -> g.Mesh:
    parts = []
    for z0 in (-1.75, 1.35):
        v, f = g.grid((2.93, 2.6, z0), (0.0, -2.55, 0.0), (0.0, 0.0, 0.6), r["curtain_u"], r["curtain_v"])
        v = v.astype(np.float64)
        phase = rng.uniform(0, 2 * np.pi)
        v[:, 0] -= 0.03 * (1.0 + np.sin((v[:, 2] - z0) * 2 * np.pi / 0.15 + phase)) * (1.2 - (v[:, 1] / 2.6) * 0.4)
        parts.append(g.as_mesh(v, f))  # one side; the object is double-sided
    return g.merge(parts)


def _pictures() -> tuple[g.Mesh, g.Mesh]:
    frames, canvases = [], []
    for x0, x1, y0, y1 in ((-0.9, -0.1, 1.25, 1.85), (0.1, 0.9, 1.25, 1.85), (-2.2, -1.4, 1.3, 1.9)):
        z = -2.5
        frames.append(g.box((x0, y0, z), (x1, y1, z + 0.03)))
        canvases.append(g.quad((x0 + 0.05, y0 + 0.05, z + 0.032), (x1 - x0 - 0.1, 0, 0), (0, y1 - y0 - 0.1, 0)))
    return g.merge(frames), g.merge(canvases)


def build(detail: float, rng: np.random.Generator) -> Scene:
    r = _res(detail)
    cell = 1.0 / r["wall_cell_inv"]
    walls = g.room_walls(ROOM_LO, ROOM_HI, cell, ("back", "front", "left", "right"))
    size_x, size_z = ROOM_HI[0] - ROOM_LO[0], ROOM_HI[2] - ROOM_LO[2]
    floor = g.grid((ROOM_LO[0], 0.0, ROOM_LO[2]), (0.0, 0.0, size_z), (size_x, 0.0, 0.0), r["floor_z"], r["floor_x"])
    bowl, fruit = _bowl_and_fruit(r, rng)
    lamp_stand, lamp_shade = _lamp(r)
    sofa, cushions = _sofa(r)
    shelves, books = _bookshelves(r, rng)
    pots, soil, leaves = _plants(r, rng)
    frames, canvases = _pictures()
    objects = [
        g.make_object("floor", floor, _FLOOR),
        g.make_object("table", _table(r), _TABLE),
        *[g.make_object(f"vase_{i + 1}", m, mat) for i, (m, mat) in enumerate(zip(_vases(r), _VASES, strict=True))],
        g.make_object("teapot", _teapot(r), _TEAPOT),
        g.make_object("lamp_stand", lamp_stand, _LAMP_STAND),
        g.make_object("bowl", bowl, _BOWL),
        g.make_object("sideboard", _sideboard(r), _SIDEBOARD),
        g.make_object("walls", g.merge(list(walls.values())), _WALLS),
        g.make_object("rug", g.box((-1.5, 0.0, -1.4), (1.7, 0.012, 1.0)), _RUG),
        g.make_object("sofa", sofa, _SOFA),
        g.make_object("cushions", cushions, _CUSHIONS),
        g.make_object("chairs", _chairs(r), _CHAIRS),
        g.make_object("bookshelves", shelves, _SHELF),
        g.make_object("books", books, _BOOKS),
        g.make_object("plant_pots", pots, _POTS),
        g.make_object("soil", soil, _SOIL),
        g.make_object("plant_leaves", leaves, _LEAVES, double_sided=True),
        g.make_object("fruit", fruit, _FRUIT),
        g.make_object("lamp_shade", lamp_shade, _SHADE),
        g.make_object("curtains", _curtains(r, rng), _CURTAINS, double_sided=True),
        g.make_object("picture_frames", frames, _FRAMES),
        g.make_object("pictures", canvases, _CANVAS),
    ]
    return Scene(objects=objects, sun_direction=(0.3, 0.85, 0.45),
                 area_light=g.overhead_area_light(ROOM_LO, ROOM_HI, fraction=0.25, height=ROOM_HI[1] + 0.3),
                 name="living_room")

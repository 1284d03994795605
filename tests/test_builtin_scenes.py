"""Built-in procedural scenes (scenes/builtin): sizes, determinism, mesh validity.

Triangle targets at detail 1 are the thesis's scene sizes (§2.3.3 with Tables 2–7: nest 67k,
grass 56k, city 50k, tree 113k; §4.7: living room 280k with 130k reflective, bathroom
90k with 46k reflective).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from scenes.builtin import BUILTIN_NAMES, builtin_info, estimate_triangles, make_builtin, nest
from scenes.builtin import geometry as g
from scenes.model import Scene
from tests.helpers import face_normals

TARGETS = {"nest": 67_000, "grass": 56_000, "city": 50_000, "tree": 113_000, "living_room": 280_000,
           "bathroom": 90_000}
SMALL = ("cornell", "mirror")
RANDOM_SCENES = ("nest", "grass", "city", "tree", "living_room", "bathroom")
# open (single- or two-sided) surfaces; every other object must be a union of closed, outward solids
OPEN_OBJECTS = {"ground", "floor", "walls", "white_walls", "red_wall", "green_wall", "floor_grout", "mirror",
                "blades_dark", "blades_light", "leaves_dark", "leaves_light", "plant_leaves", "curtains",
                "pictures"}

_CACHE: dict[tuple[str, float, int], Scene] = {}


def built(name: str, detail: float = 1.0, seed: int = 0) -> Scene:
    key = (name, detail, seed)
    if key not in _CACHE:
        _CACHE[key] = make_builtin(name, detail, seed)
    return _CACHE[key]


def closed_and_outward(v: np.ndarray, f: np.ndarray) -> tuple[bool, float]:
    """(watertight, smallest signed volume over connected components)."""
    m = trimesh.Trimesh(v, f, process=True)
    labels = trimesh.graph.connected_component_labels(m.face_adjacency, node_count=len(m.faces))
    tri = m.triangles.astype(np.float64)
    signed = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0
    per_component = np.bincount(labels, weights=signed)
    return bool(m.is_watertight), float(per_component.min())


# --- registry ----------------------------------------------------------------------------------------


def test_names_and_info() -> None:
    assert BUILTIN_NAMES == ("nest", "grass", "city", "tree", "living_room", "bathroom", "cornell", "mirror")
    info = builtin_info()
    assert [i["name"] for i in info] == list(BUILTIN_NAMES)
    for i in info:
        assert set(i) == {"name", "description", "default_triangles"}
        assert isinstance(i["description"], str) and len(i["description"]) > 20
        assert i["default_triangles"] == built(i["name"]).n_triangles


@pytest.mark.parametrize("name", BUILTIN_NAMES)
def test_builds_valid_mesh(name: str) -> None:
    s = built(name)
    assert isinstance(s, Scene) and s.name == name
    assert 1 <= len(s.objects) < 40
    assert len({o.name for o in s.objects}) == len(s.objects)
    v, f, n = s.vertices, s.faces, s.normals
    assert v.dtype == np.float32 and f.dtype == np.uint32 and n.dtype == np.float32
    assert np.all(np.isfinite(v)) and np.all(np.isfinite(n))
    assert int(f.max()) < len(v)
    for o in s.objects:
        assert o.n_triangles > 0, o.name
        assert int(o.faces.max()) < len(o.vertices), o.name
        assert 0 <= o.material.specular <= 1 and 0 <= o.material.glossiness <= 1
        assert all(0 <= c <= 1 for c in o.material.albedo)
    # every vertex is used, so every vertex normal is a real (unit) normal
    used = np.zeros(len(v), bool)
    used[f.ravel()] = True
    assert used.all()
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-3)
    # (almost) no zero-area triangles
    area = np.linalg.norm(face_normals(v, f), axis=1) / 2
    assert np.mean(area <= 1e-12 * max(s.diagonal, 1.0) ** 2) < 1e-4
    # y up, ground at y = 0, centred near the origin, lights set
    lo, hi = s.bounds
    assert -0.15 <= lo[1] <= 0.05 and hi[1] > 0.1
    assert np.all(np.abs(s.center[[0, 2]]) <= 0.25 * s.diagonal)
    assert s.area_light is not None
    corners = s.area_light.corners()
    assert np.all(corners[:, 1] > lo[1])
    edge = np.linalg.norm(s.area_light.u)
    assert 0.1 <= edge / max(hi[0] - lo[0], hi[2] - lo[2]) <= 0.5
    assert np.isclose(np.linalg.norm(s.sun_direction), 1.0) and s.sun_direction[1] > 0.3


@pytest.mark.parametrize("name", BUILTIN_NAMES)
def test_triangle_count(name: str) -> None:
    n = built(name).n_triangles
    if name in TARGETS:
        assert abs(n - TARGETS[name]) <= 0.15 * TARGETS[name], n
    else:
        assert 500 <= n < 5_000, n


@pytest.mark.parametrize("name", BUILTIN_NAMES)
def test_deterministic(name: str) -> None:
    a, b = built(name), make_builtin(name, 1.0, 0)
    assert a is not b
    for x, y in ((a.vertices, b.vertices), (a.faces, b.faces), (a.normals, b.normals), (a.materials, b.materials)):
        assert x.dtype == y.dtype and np.array_equal(x, y)
    assert a.sun_direction == b.sun_direction and a.area_light == b.area_light
    assert [o.name for o in a.objects] == [o.name for o in b.objects]
    c = make_builtin(name, 1.0, 1)
    assert c.n_triangles == a.n_triangles  # counts depend on detail only
    same = c.vertices.shape == a.vertices.shape and np.array_equal(c.vertices, a.vertices)
    assert same == (name not in RANDOM_SCENES)


@pytest.mark.parametrize("name", BUILTIN_NAMES)
def test_closed_solids_are_closed_and_outward(name: str) -> None:
    s = built(name, 0.25)
    for o in s.objects:
        if o.name in OPEN_OBJECTS:
            continue
        watertight, min_volume = closed_and_outward(o.vertices, o.faces)
        assert watertight, o.name
        assert min_volume > 0, o.name


@pytest.mark.parametrize("name", ["nest", "grass", "city", "tree", "mirror"])
def test_ground_faces_up(name: str) -> None:
    for o in built(name).objects:
        if o.name in ("ground", "floor"):
            assert np.all(face_normals(o.vertices, o.faces)[:, 1] > 0), o.name


@pytest.mark.parametrize("name", ["nest", "tree"])
def test_ground_is_a_modest_base(name: str) -> None:
    # nest and tree stand on a disc ≈ 1.4 × their footprint (not a plane far larger than the
    # object), centred under it, flat at y = 0, so views framed on the scene show the object
    s = built(name)
    ground = next(o for o in s.objects if o.name == "ground")
    rest = np.concatenate([o.vertices for o in s.objects if o.name != "ground"]).astype(np.float64)
    lo, hi = rest.min(0), rest.max(0)
    footprint = max(hi[0] - lo[0], hi[2] - lo[2])
    gv = ground.vertices.astype(np.float64)
    assert np.all(gv[:, 1] == 0.0)
    width = max(np.ptp(gv[:, 0]), np.ptp(gv[:, 2]))
    assert 1.3 <= width / footprint <= 1.5, width / footprint
    np.testing.assert_allclose((gv.min(0) + gv.max(0))[[0, 2]] / 2, ((lo + hi) / 2)[[0, 2]], atol=0.02 * footprint)
    # the scene's horizontal extent is the ground's
    np.testing.assert_allclose(np.array(s.bounds)[:, [0, 2]], [gv.min(0)[[0, 2]], gv.max(0)[[0, 2]]], rtol=1e-6)


def test_disc() -> None:
    v, f = g.disc((1.0, 0.5, -2.0), 0.5, 12)
    assert len(f) == g.disc_triangles(12) == 12 and len(v) == 13
    assert np.all(face_normals(v, f)[:, 1] > 0)  # faces up
    np.testing.assert_allclose(np.linalg.norm(v[1:] - [1.0, 0.5, -2.0], axis=1), 0.5)
    area = np.linalg.norm(face_normals(v, f), axis=1).sum() / 2
    assert area == pytest.approx(0.5 * 12 * 0.25 * math.sin(2 * math.pi / 12))


@pytest.mark.parametrize("name", ["living_room", "bathroom", "cornell"])
def test_room_walls_face_inward(name: str) -> None:
    s = built(name)
    walls = [o for o in s.objects if o.name in ("walls", "white_walls", "red_wall", "green_wall", "floor",
                                                  "floor_grout")]
    assert walls
    lo, hi = s.bounds
    inside = np.array([(lo[0] + hi[0]) / 2, 1.0, (lo[2] + hi[2]) / 2])
    for o in walls:
        fn = face_normals(o.vertices, o.faces)
        centre = o.vertices[o.faces.astype(np.int64)].astype(np.float64).mean(axis=1)
        assert np.all(np.einsum("ij,ij->i", fn, inside - centre) > 0), o.name


def test_two_sided_thin_geometry() -> None:
    # blades and leaves come in front/back pairs: as many faces toward +x as toward -x
    for name, obj in (("grass", "blades_dark"), ("tree", "leaves_light"), ("living_room", "plant_leaves")):
        o = next(o for o in built(name).objects if o.name == obj)
        fn = face_normals(o.vertices, o.faces)
        half = len(fn) // 2
        assert len(fn) % 2 == 0
        assert np.allclose(fn[:half], -fn[half:], atol=1e-9)
        nv = len(o.vertices) // 2
        assert np.array_equal(o.normals[:nv], -o.normals[nv:])


@pytest.mark.parametrize("name", ["living_room", "bathroom"])
def test_reflective_fraction(name: str) -> None:
    s = built(name)
    reflective = sum(o.n_triangles for o in s.objects if o.material.reflective)
    frac = reflective / s.n_triangles
    assert 0.35 <= frac <= 0.65, frac
    n_reflectors = sum(o.material.reflective for o in s.objects)
    assert n_reflectors >= 5


def test_living_room_materials() -> None:
    mats = {o.name: o.material for o in built("living_room").objects}
    assert mats["floor"].specular == pytest.approx(0.8) and mats["floor"].glossiness == 0.0
    assert mats["table"].specular == pytest.approx(0.5) and mats["table"].glossiness == pytest.approx(0.3)
    vases = [m for k, m in mats.items() if k.startswith("vase")]
    assert len(vases) >= 3
    assert all(m.specular == pytest.approx(0.7) and m.glossiness <= 0.1 for m in vases)


@pytest.mark.parametrize("name", ["mirror", "bathroom"])
def test_mirror_material_and_facing(name: str) -> None:
    s = built(name)
    mirrors = [o for o in s.objects if o.material.specular == 1.0 and o.material.glossiness == 0.0]
    assert len(mirrors) == 1
    m = mirrors[0]
    fn = face_normals(m.vertices, m.faces)
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    assert np.allclose(fn, fn[0], atol=1e-6)  # planar
    others = np.concatenate([o.vertices for o in s.objects if o is not m and o.name not in ("walls", "floor")])
    to_objects = others.mean(axis=0) - m.vertices.mean(axis=0)
    assert float(fn[0] @ to_objects) > 0  # single-sided, facing the objects


# --- detail scaling and estimates ---------------------------------------------------------------------


@pytest.mark.parametrize("name", BUILTIN_NAMES)
def test_detail_scales_linearly(name: str) -> None:
    n1, n3 = built(name).n_triangles, built(name, 3.0).n_triangles
    assert 2.6 <= n3 / n1 <= 3.4
    n_small = built(name, 0.1).n_triangles
    assert n_small < n1
    for d in (0.25, 1.0, 3.0):
        actual = built(name, d).n_triangles
        assert abs(estimate_triangles(name, d) - actual) <= 0.15 * actual, (d, actual)


def test_cheap_scene_reaches_3m_triangles_at_detail_60() -> None:
    assert estimate_triangles("grass", 60) >= 3_000_000
    s = make_builtin("grass", 60)
    assert s.n_triangles >= 3_000_000
    assert s.n_triangles == estimate_triangles("grass", 60)


@pytest.mark.slow
@pytest.mark.parametrize("name", BUILTIN_NAMES)
def test_all_scenes_scale_to_detail_60(name: str) -> None:
    s = make_builtin(name, 60)
    if name in SMALL:
        assert s.n_triangles >= 40 * built(name).n_triangles
    else:
        assert s.n_triangles >= 3_000_000
    assert abs(estimate_triangles(name, 60) - s.n_triangles) <= 0.05 * s.n_triangles


def test_extreme_details_build() -> None:
    for name in BUILTIN_NAMES:
        assert make_builtin(name, 0.01).n_triangles > 0


# --- argument validation --------------------------------------------------------------------------------


def test_unknown_name_lists_valid_names() -> None:
    with pytest.raises(ValueError, match="unknown built-in scene 'forest'") as err:
        make_builtin("forest")
    assert all(n in str(err.value) for n in BUILTIN_NAMES)
    with pytest.raises(ValueError, match="valid names"):
        estimate_triangles("Nest", 1.0)
    with pytest.raises(ValueError):
        make_builtin(None)  # type: ignore[arg-type]


@pytest.mark.parametrize("detail", [0.0, 0.005, 60.5, -1.0, math.nan, math.inf, -math.inf])
def test_bad_detail(detail: float) -> None:
    with pytest.raises(ValueError, match="detail"):
        make_builtin("cornell", detail)
    with pytest.raises(ValueError, match="detail"):
        estimate_triangles("cornell", detail)


@pytest.mark.parametrize("detail", ["1", None, True, [1.0]])
def test_detail_wrong_type(detail: object) -> None:
    with pytest.raises(ValueError, match="detail must be a real number"):
        make_builtin("cornell", detail)  # type: ignore[arg-type]


@pytest.mark.parametrize("seed", [-1, 1.5, "3", None, True, 2**64])
def test_bad_seed(seed: object) -> None:
    with pytest.raises(ValueError, match="seed"):
        make_builtin("nest", 0.1, seed)  # type: ignore[arg-type]


def test_detail_bounds_inclusive_and_numpy_args() -> None:
    assert make_builtin("cornell", 0.01).n_triangles > 0
    assert make_builtin("mirror", np.float64(2.0), np.int64(7)).n_triangles == built("mirror", 2.0).n_triangles


# --- geometry primitives -----------------------------------------------------------------------------------


def test_single_twig_and_box_are_watertight() -> None:
    rng = np.random.default_rng(0)
    paths, radii = nest._twig_paths(1, rng)
    twig = g.tubes(paths, radii, nest.SIDES)
    assert len(twig[1]) == g.tube_triangles(nest.SEGMENTS, nest.SIDES)
    m = trimesh.Trimesh(*twig)
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0
    for mesh in (g.box((0, 0, 0), (1, 2, 3)), g.box((-1, -1, -1), (1, 1, 1), 3)):
        m = trimesh.Trimesh(*mesh)
        assert m.is_watertight and m.volume > 0
    assert trimesh.Trimesh(*g.box((0, 0, 0), (1, 2, 3))).volume == pytest.approx(6.0)


@pytest.mark.parametrize("mesh_fn", [
    lambda: g.cylinder((0, 0, 0), (0.3, 1.0, -0.2), 0.1, 7),
    lambda: g.boxes(np.array([[0, 0, 0], [3, 0, 0]]), np.array([[1, 2, 1], [1, 1, 2]]), np.array([0.3, -1.0])),
    lambda: g.uv_sphere((1, 2, 3), 0.5, 8, 16),
    lambda: g.ellipsoid((0, 0, 0), (1, 0.3, 2), 6, 9),
    lambda: g.lathe(g.vessel_profile(np.array([(0, 0), (0.1, 0), (0.2, 0.3), (0.15, 0.5)]), 0.01, 30), 24),
    lambda: g.lathe(g.solid_profile(np.array([(0, 0), (0.2, 0.1), (0.1, 0.4), (0, 0.5)]), 12), 10),
    lambda: g.lathe(np.array([(0.5, 0.0), (0.6, 0.0), (0.6, 0.1), (0.5, 0.1)])[::-1], 16, closed=True),
    lambda: g.transform(g.uv_sphere((0, 0, 0), 1.0, 6, 8), scale=(1.0, -1.0, 1.0)),
])
def test_primitives_closed_and_outward(mesh_fn) -> None:
    v, f = mesh_fn()
    assert v.dtype == np.float32 and f.dtype == np.uint32
    watertight, min_volume = closed_and_outward(v, f)
    assert watertight and min_volume > 0


def test_primitive_triangle_counts() -> None:
    assert len(g.uv_sphere(n_lat=10, n_lon=20)[1]) == g.sphere_triangles(10, 20)
    assert len(g.grid((0, 0, 0), (1, 0, 0), (0, 1, 0), 3, 5)[1]) == g.grid_triangles(3, 5)
    assert len(g.box((0, 0, 0), (1, 1, 1), 4)[1]) == g.box_triangles(4)
    prof = g.solid_profile(np.array([(0, 0), (1, 1), (0, 2)]), 9)
    assert len(g.lathe(prof, 12)[1]) == g.lathe_triangles(9, 12, n_poles=2)


def test_open_surfaces_face_the_right_way() -> None:
    v, f = g.quad((0, 0, 0), (1, 0, 0), (0, 1, 0))
    assert np.all(face_normals(v, f)[:, 2] > 0)  # front = u × v
    paths = np.array([[[0, 0, 0], [0, 0.5, 0], [0, 1, 0]]], dtype=np.float64)
    v, f = g.ribbons(paths, np.array([[0.1, 0.05, 0.0]]), np.array([[1.0, 0.0, 0.0]]))
    assert len(f) == g.ribbon_triangles(2, pointed=True)
    assert np.all(face_normals(v, f)[:, 2] > 0)  # front = side × path direction
    v2, f2 = g.two_sided((v, f))
    fn = face_normals(v2, f2)
    assert len(f2) == 2 * len(f) and np.all(fn[len(f):, 2] < 0)
    n = g.fast_vertex_normals(v2, f2)
    assert np.allclose(n[: len(v), 2], 1.0) and np.allclose(n[len(v):, 2], -1.0)


def test_fast_normals_match_model() -> None:
    from scenes.model import vertex_normals

    v, f = g.lathe(g.solid_profile(np.array([(0, 0), (0.3, 0.2), (0.1, 0.5), (0, 0.6)]), 10), 12)
    assert np.allclose(g.fast_vertex_normals(v, f), vertex_normals(v, f), atol=1e-5)


def test_instances_and_transform() -> None:
    rot = g.rotation_axis_angle(np.array([[0, 1, 0], [1, 0, 0]]), np.array([0.5, 1.0]))
    assert np.allclose(rot @ np.transpose(rot, (0, 2, 1)), np.eye(3), atol=1e-12)
    assert np.allclose(rot[0], g.rotation_y(0.5))
    v, f = g.instances(g.box((0, 0, 0), (1, 1, 1)), np.array([[0, 0, 0], [5, 0, 0]]), rot, np.array([1.0, 2.0]))
    assert len(v) == 48 and len(f) == 24 and int(f.max()) == 47
    merged = g.merge([g.box((0, 0, 0), (1, 1, 1)), g.box((2, 0, 0), (3, 1, 1))])
    assert len(merged[0]) == 48 and int(merged[1][12:].min()) == 24


@pytest.mark.parametrize("name", ["living_room", "bathroom", "cornell"])
def test_rooms_contain_their_contents(name: str) -> None:
    # nothing pokes through the walls or floor, whatever the seed
    for seed in (0, 1, 2):
        s = built(name, 1.0, seed) if seed == 0 else make_builtin(name, 1.0, seed)
        walls = next(o for o in s.objects if o.name in ("walls", "white_walls"))
        lo, hi = walls.vertices.min(axis=0), walls.vertices.max(axis=0)
        assert np.all(s.bounds[0] >= lo - 1e-6) and np.all(s.bounds[1][[0, 2]] <= hi[[0, 2]] + 1e-6)


def test_grass_blade_width_scales_blades_only() -> None:
    """grass.build(blade_width=w): at 1 the built-in scene itself; at 2 every blade
    triangle's area doubles (a ribbon's vertices are its centre line ± half width ×
    a fixed side vector, so each triangle's area is linear in the width), the ground
    stays."""
    from scenes.builtin import builtin_rng, grass

    def area(o) -> float:
        v = o.vertices.astype(np.float64)[o.faces.astype(np.int64)]
        return float(0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1).sum())

    base = make_builtin("grass", 0.1)
    same = grass.build(0.1, builtin_rng("grass"), blade_width=1.0)
    wide = grass.build(0.1, builtin_rng("grass"), blade_width=2.0)
    for a, b, c in zip(base.objects, same.objects, wide.objects, strict=True):
        assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, c.faces)
        if a.name == "ground":
            assert np.array_equal(a.vertices, c.vertices)
        else:
            assert area(c) == pytest.approx(2.0 * area(a), rel=1e-5)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="blade_width"):
            grass.build(0.1, builtin_rng("grass"), blade_width=bad)

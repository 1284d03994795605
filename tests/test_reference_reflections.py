"""Embree reflection reference (reference/reflections.py) and image metrics
(reference/image_metrics.py), checked against plain geometry."""

from __future__ import annotations

import numpy as np
import pytest

from reference.image_metrics import (
    error_image,
    mean_abs_error,
    occlusion_error_mask,
    occlusion_error_percentage,
    psnr,
)
from reference.reflections import (
    ORIGIN_OFFSET,
    envmap_reflections,
    raytrace_reflections,
)
from scenes.camera import Camera
from scenes.glossy import fade_weight, glossy_far, lobe_directions
from scenes.model import Material, Scene, SceneObject
from scenes.shading import local_shade, sky
from service.image_check import assert_images_close
from tests.helpers import assert_images_equal

SUN = tuple(np.array([0.35, 0.85, 0.4]) / np.linalg.norm([0.35, 0.85, 0.4]))  # unit, as Scene stores it


# --- scene helpers -------------------------------------------------------------
def quad(name: str, corners, normal, material: Material, vertex_normal=None) -> SceneObject:
    """Two-triangle quad over 4 corners in order around the rim, wound so the front
    face points along `normal`; flat vertex normals unless given."""
    c = np.asarray(corners, np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    if np.dot(np.cross(c[1] - c[0], c[2] - c[0]), normal) < 0:
        faces = faces[:, ::-1]
    vn = np.asarray(normal if vertex_normal is None else vertex_normal, np.float64)
    vn = np.tile(vn / np.linalg.norm(vn), (4, 1))
    return SceneObject(name, c, faces, vn, material)


# Box faces: (axis, sign, albedo) with distinct colours so each face is identifiable.
BOX_LO = np.array([-0.6, 0.3, -1.5])
BOX_HI = np.array([0.4, 1.1, -0.7])
FACE_ALBEDO = {
    (0, -1): (0.9, 0.1, 0.1), (0, 1): (0.1, 0.9, 0.1),
    (1, -1): (0.1, 0.1, 0.9), (1, 1): (0.9, 0.9, 0.1),
    (2, -1): (0.1, 0.9, 0.9), (2, 1): (0.9, 0.1, 0.9),
}


def box_faces(lo: np.ndarray = BOX_LO, hi: np.ndarray = BOX_HI) -> list[SceneObject]:
    objs = []
    for (axis, sign), albedo in FACE_ALBEDO.items():
        a1, a2 = [k for k in range(3) if k != axis]
        pts = []
        for u, v in ((0, 0), (1, 0), (1, 1), (0, 1)):
            p = np.empty(3)
            p[axis] = hi[axis] if sign > 0 else lo[axis]
            p[a1] = (lo, hi)[u][a1]
            p[a2] = (lo, hi)[v][a2]
            pts.append(p)
        n = np.zeros(3)
        n[axis] = sign
        objs.append(quad(f"box{axis}{sign}", pts, n, Material(albedo)))
    return objs


MIRROR_HALF = 3.0
MIRROR_ALBEDO = (0.5, 0.45, 0.4)


def mirror_floor(s: float = 1.0, g: float = 0.0, half: float = MIRROR_HALF) -> SceneObject:
    h = half
    return quad("mirror", [(-h, 0, -h), (h, 0, -h), (h, 0, h), (-h, 0, h)], (0, 1, 0),
                Material(MIRROR_ALBEDO, specular=s, glossiness=g))


CAM = Camera(eye=(0.5, 2.0, 4.0), target=(0.0, 0.0, -0.5), fov=50.0, width=48, height=48)


def sample_dirs(cam: Camera, ss: int) -> np.ndarray:
    """(H*ss, W*ss, 3) primary directions at the supersample points."""
    return cam.with_size(cam.width * ss, cam.height * ss).pixel_directions()


def slab(o: np.ndarray, d: np.ndarray):
    """Ray/box entry (t (N,), face axis (N,), face sign (N,)); t = inf on a miss.
    Plain slab test in float64."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (BOX_LO - o) / d
        t1 = (BOX_HI - o) / d
    tn = np.minimum(t0, t1)
    tf = np.maximum(t0, t1)
    axis = np.argmax(tn, axis=1)
    tin = tn.max(axis=1)
    tout = tf.min(axis=1)
    hit = (tin <= tout) & (tin > 0)
    sign = np.where(np.take_along_axis(d, axis[:, None], 1)[:, 0] > 0, -1, 1)  # entered through the facing side
    return np.where(hit, tin, np.inf), axis, sign


def assert_within(actual: np.ndarray, expected: np.ndarray, atol: float, mask: np.ndarray, name: str) -> None:
    """Every masked pixel of `actual` within atol of `expected` (error images on failure)."""
    __tracebackhide__ = True
    assert_images_close(actual, expected, tolerance=atol, max_bad_fraction=0.0, mask=mask, name=name)


def expected_planar_mirror(cam: Camera, ss: int):
    """Per sample: (on_mirror (N,), reflected colour (N,3), face key (N,) int or -1
    for sky, safe (N,) hit point not within 1e-3 of a face edge), with the
    reflected ray defined by the eye mirrored in the plane y = 0."""
    d = sample_dirs(cam, ss).reshape(-1, 3)
    e = np.asarray(cam.eye)
    t_plane = -e[1] / d[:, 1]
    p = e + d * t_plane[:, None]
    on = (d[:, 1] < 0) & (np.abs(p[:, 0]) < MIRROR_HALF) & (np.abs(p[:, 2]) < MIRROR_HALF)
    t_box_primary, _, _ = slab(np.broadcast_to(e, d.shape), d)
    on &= ~(t_box_primary < t_plane)  # the box hides the mirror there
    e_mirror = e * np.array([1, -1, 1])  # eye mirrored in the plane
    r = p - e_mirror
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    t, axis, sign = slab(p, r)
    hit = np.isfinite(t)
    q = p + r * np.where(hit, t, 0)[:, None]
    # distance of the box hit point to the edges of its face
    margin = np.full(len(d), np.inf)
    for k in range(3):
        m = hit & (axis != k)
        margin[m] = np.minimum(margin[m], np.minimum(q[m, k] - BOX_LO[k], BOX_HI[k] - q[m, k]))
    col = sky(r, np.asarray(SUN)).astype(np.float64)
    key = np.full(len(d), -1)
    for (ax, sg), albedo in FACE_ALBEDO.items():
        m = hit & (axis == ax) & (sign == sg)
        n = np.zeros(3)
        n[ax] = sg
        col[m] = local_shade(np.asarray(albedo, np.float32), n[None].astype(np.float32), np.asarray(SUN))[0]
        key[m] = ax * 2 + (sg > 0)
    return on, col, key, margin > 1e-3, r


def blocks(x: np.ndarray, cam: Camera, ss: int) -> np.ndarray:
    return x.reshape(cam.height, ss, cam.width, ss, *x.shape[1:])


# --- planar mirror ---------------------------------------------------------------
@pytest.fixture(scope="module")
def mirror_box_scene() -> Scene:
    return Scene([mirror_floor(), *box_faces()], sun_direction=SUN)


@pytest.fixture(scope="module")
def mirror_box_result(mirror_box_scene):
    return raytrace_reflections(mirror_box_scene, CAM, supersample=2)


def test_planar_mirror_reflects_box_by_mirrored_eye(mirror_box_result):
    ss = 2
    on, col, key, safe, _ = expected_planar_mirror(CAM, ss)
    on_b, key_b, safe_b = blocks(on, CAM, ss), blocks(key, CAM, ss), blocks(safe, CAM, ss)
    all_on = on_b.all(axis=(1, 3))
    same_face = (key_b == key_b[:, :1, :, :1]).all(axis=(1, 3)) & (key_b[:, 0, :, 0] >= 0)
    sel = all_on & same_face & safe_b.all(axis=(1, 3))
    expect = blocks(col, CAM, ss).mean(axis=(1, 3))
    res = mirror_box_result
    assert sel.sum() >= 40, "the box should appear in the mirror"
    assert len(np.unique(key_b[:, 0, :, 0][sel])) >= 2, "at least two box faces should be reflected"
    assert np.all(res.reflective[sel]) and np.allclose(res.specular[sel], 1.0)
    assert_within(res.reflected, expect, 1e-6, sel, "reflected")
    assert_within(res.color, expect, 1e-6, sel, "color")  # s = 1: colour = reflected
    # Mirror pixels that see only the sky: average of sky over the 4 mirrored directions.
    sky_px = all_on & (key_b < 0).all(axis=(1, 3))
    assert sky_px.sum() > 100
    assert_within(res.color, expect, 1e-6, sky_px, "sky")
    # Ray length: |Q − P| to the box face, +inf into the sky.
    assert np.all(np.isinf(res.ray_length[sky_px]))
    assert np.all(np.isfinite(res.ray_length[sel]))


def test_planar_mirror_ray_length_matches_geometry(mirror_box_scene):
    cam = CAM.with_size(24, 24)
    res = raytrace_reflections(mirror_box_scene, cam, supersample=1)
    on, _, key, safe, r = expected_planar_mirror(cam, 1)
    d = cam.pixel_directions().reshape(-1, 3)
    e = np.asarray(cam.eye)
    p = e + d * (-e[1] / d[:, 1])[:, None]
    p[:, 1] += ORIGIN_OFFSET * mirror_box_scene.diagonal  # reflected rays start just above the surface
    t, _, _ = slab(p, r)
    sel = on & (key >= 0) & safe
    assert sel.sum() > 10
    np.testing.assert_allclose(res.ray_length.reshape(-1)[sel], t[sel], rtol=1e-4)
    # hit point and hit-triangle normal per sample (the thesis's occlusion test): Q = P + t·r
    # on a box face that faces the ray; NaN exactly where the ray misses or no sample reflects
    hp = res.hit_points_samples.reshape(-1, 3)
    np.testing.assert_allclose(hp[sel], p[sel] + r[sel] * t[sel, None], atol=1e-4)
    assert np.array_equal(np.isfinite(hp).all(axis=1), np.isfinite(res.ray_length_samples.reshape(-1)))
    hn = res.hit_normals_samples.reshape(-1, 3)[sel].astype(np.float64)
    np.testing.assert_allclose(np.linalg.norm(hn, axis=1), 1.0, atol=1e-5)
    assert np.all(np.sum(hn * r[sel], axis=1) < 0)


def test_half_specular_is_exact_average(mirror_box_scene, mirror_box_result):
    half = Scene([mirror_floor(s=0.5), *box_faces()], sun_direction=SUN)
    res = raytrace_reflections(half, CAM, supersample=2)
    on, *_ = expected_planar_mirror(CAM, 2)
    inner = blocks(on, CAM, 2).all(axis=(1, 3))
    assert inner.sum() > 500
    np.testing.assert_allclose(res.specular[inner], 0.5)
    assert_within(res.color, 0.5 * res.diffuse + 0.5 * res.reflected, 1e-6, inner, "color")
    # the diffuse part is the mirror's own local shading; the reflected part does not depend on s
    diff = local_shade(np.asarray(MIRROR_ALBEDO, np.float32), np.array([[0, 1, 0]], np.float32), np.asarray(SUN))[0]
    assert_within(res.diffuse, np.broadcast_to(diff, res.diffuse.shape), 1e-6, inner, "diffuse")
    assert_images_equal(res.reflected, mirror_box_result.reflected, "reflected", mask=inner)


def test_mirror_facing_empty_space_reflects_sky():
    scene = Scene([mirror_floor()], sun_direction=SUN)
    cam = Camera(eye=(0.3, 1.5, 2.5), target=(0.0, 0.0, 0.0), fov=60.0, width=32, height=32)
    res = raytrace_reflections(scene, cam, supersample=2)
    d = sample_dirs(cam, 2).reshape(-1, 3)
    r = d * np.array([1, -1, 1])  # mirrored direction about the plane y = 0
    expect = blocks(sky(r, np.asarray(SUN)).astype(np.float64), cam, 2).mean(axis=(1, 3))
    e = np.asarray(cam.eye)
    p = e + d * (-e[1] / d[:, 1])[:, None]
    on = (d[:, 1] < 0) & (np.abs(p[:, 0]) < MIRROR_HALF) & (np.abs(p[:, 2]) < MIRROR_HALF)
    inner = blocks(on, cam, 2).all(axis=(1, 3))
    assert inner.sum() > 600
    assert_within(res.color, expect, 1e-6, inner, "color")
    assert_within(res.reflected, expect, 1e-6, inner, "reflected")
    assert np.all(np.isinf(res.ray_length[inner]))
    # pixels beyond the mirror's far edge see the sky directly
    outside = blocks(~on, cam, 2).all(axis=(1, 3))
    assert outside.sum() > 20 and not res.reflective[outside].any()
    direct = blocks(sky(d, np.asarray(SUN)).astype(np.float64), cam, 2).mean(axis=(1, 3))
    assert_within(res.color, direct, 1e-6, outside, "direct_sky")


def test_envmap_baseline_is_sky_of_mirror_direction(mirror_box_scene):
    res = envmap_reflections(mirror_box_scene, CAM, supersample=2)
    on, _, _, _, r = expected_planar_mirror(CAM, 2)
    inner = blocks(on, CAM, 2).all(axis=(1, 3))
    expect = blocks(sky(r, np.asarray(SUN)).astype(np.float64), CAM, 2).mean(axis=(1, 3))
    assert inner.sum() > 500
    # the box is ignored: every mirror pixel shows the sky in the mirror direction
    assert_within(res.reflected, expect, 1e-6, inner, "reflected")
    assert_within(res.color, expect, 1e-6, inner, "color")
    assert np.all(np.isinf(res.ray_length[res.reflective]))
    assert np.all(np.isnan(res.ray_length[~res.reflective]))
    assert np.isnan(res.hit_points_samples).all() and np.isnan(res.hit_normals_samples).all()


def test_supersample_equals_block_average_of_double_resolution(mirror_box_scene):
    cam = CAM.with_size(20, 16)
    a = raytrace_reflections(mirror_box_scene, cam, supersample=2, chunk=1000)
    b = raytrace_reflections(mirror_box_scene, cam.with_size(40, 32), supersample=1)
    for name in ("color", "diffuse"):
        avg = blocks(getattr(b, name).reshape(-1, 3), cam, 2).astype(np.float64).sum(axis=(1, 3)) / 4
        assert_images_equal(getattr(a, name), avg.astype(np.float32), name)
    assert_images_equal(a.specular, (blocks(b.specular.reshape(-1), cam, 2).astype(np.float64)
                                     .sum(axis=(1, 3)) / 4).astype(np.float32), "specular")
    np.testing.assert_array_equal(a.reflective, blocks(b.reflective.reshape(-1), cam, 2).any(axis=(1, 3)))
    np.testing.assert_array_equal(a.ray_length_samples, b.ray_length)
    full = blocks(b.reflective.reshape(-1), cam, 2).all(axis=(1, 3))
    avg_r = blocks(b.reflected.reshape(-1, 3), cam, 2).astype(np.float64).sum(axis=(1, 3)) / 4
    assert_images_equal(a.reflected, avg_r.astype(np.float32), "reflected", mask=full)


# --- below-surface rule ------------------------------------------------------------
def test_below_surface_rule_reflects_about_geometric_normal():
    tilt = np.array([0.2, 1.0, 0.0]) / np.linalg.norm([0.2, 1.0, 0.0])
    h = 4.0
    obj = quad("tilted", [(-h, 0, -h), (h, 0, -h), (h, 0, h), (-h, 0, h)], (0, 1, 0),
               Material((0.5, 0.5, 0.5), specular=1.0), vertex_normal=tilt)
    scene = Scene([obj], sun_direction=SUN)
    cam = Camera(eye=(-3.0, 1.0, 0.0), target=(1.0, 0.0, 0.0), fov=50.0, width=32, height=32)
    d = cam.pixel_directions().reshape(-1, 3)
    r = d - 2 * (d @ tilt)[:, None] * tilt
    below = r[:, 1] < 0
    r_geo = d * np.array([1, -1, 1])
    expect = sky(np.where(below[:, None], r_geo, r), np.asarray(SUN)).reshape(32, 32, 3)
    e = np.asarray(cam.eye)
    p = e + d * (-e[1] / d[:, 1])[:, None]
    on = ((d[:, 1] < 0) & (np.abs(p[:, 0]) < h) & (np.abs(p[:, 2]) < h)).reshape(32, 32)
    assert on[below.reshape(32, 32)].sum() > 20 and on[~below.reshape(32, 32)].sum() > 20
    for fn in (envmap_reflections, raytrace_reflections):
        res = fn(scene, cam, supersample=1)
        np.testing.assert_array_equal(res.reflective, on)
        assert_within(res.reflected, expect, 2e-5, on, fn.__name__)


# --- glossy -------------------------------------------------------------------------
def test_glossy_fade_hand_computed():
    """Camera straight down on a glossy floor under a ceiling at height h: the centre
    pixel's lobe rays hit the ceiling at t = h / cos θ_k; each contributes
    w_k·ceiling + (1 − w_k)·diffuse with the shared fade weight."""
    g, h, half = 0.5, 1.4, 1.0
    floor = mirror_floor(s=1.0, g=g, half=half)
    ceil_albedo = (0.2, 0.6, 0.9)
    ceiling = quad("ceiling", [(-half, h, -half), (half, h, -half), (half, h, half), (-half, h, half)], (0, -1, 0),
                   Material(ceil_albedo))
    scene = Scene([floor, ceiling], sun_direction=SUN)
    cam = Camera(eye=(0.05, 0.7, 0.03), target=(0.05, 0.0, 0.03), up=(0.0, 0.0, -1.0), fov=30.0, width=3, height=3)
    k = 16
    res = raytrace_reflections(scene, cam, supersample=1, glossy_rays=k)
    dirs = lobe_directions(np.array([0.0, 1.0, 0.0]), g, k)  # centre pixel: view −Y, mirror +Y
    far = glossy_far(scene.diagonal, g)
    t = (h - ORIGIN_OFFSET * scene.diagonal) / dirs[:, 1]
    w = fade_weight(t, far, g)
    assert np.any((w > 0) & (w < 1)), "the ceiling should sit inside the fade zone"
    diff = local_shade(np.asarray(MIRROR_ALBEDO, np.float32), np.array([0, 1, 0], np.float32), np.asarray(SUN))
    ceil = local_shade(np.asarray(ceil_albedo, np.float32), np.array([0, -1, 0], np.float32), np.asarray(SUN))
    expect = (w[:, None] * ceil + (1 - w[:, None]) * diff).mean(axis=0)
    np.testing.assert_allclose(res.reflected[1, 1], expect, atol=1e-4)
    np.testing.assert_allclose(res.color[1, 1], expect, atol=1e-4)  # s = 1
    np.testing.assert_allclose(res.ray_length[1, 1], h - ORIGIN_OFFSET * scene.diagonal, rtol=1e-5)


def test_glossy_beyond_far_gives_diffuse():
    g = 1.0
    lift = np.array([0.0, 0.7, 0.0])
    scene = Scene([mirror_floor(s=0.7, g=g), *box_faces(BOX_LO + lift, BOX_HI + lift)], sun_direction=SUN)
    far = glossy_far(scene.diagonal, g)
    assert far < BOX_LO[1] + lift[1]  # every lobe ray ends before reaching the box
    res = raytrace_reflections(scene, CAM, supersample=1, glossy_rays=8)
    on = res.reflective
    assert on.sum() > 500
    assert_within(res.reflected, res.diffuse, 1e-6, on, "reflected")
    assert_within(res.color, res.diffuse, 1e-6, on, "color")
    assert np.all(np.isinf(res.ray_length[on]))


def test_glossy_converges_with_more_rays():
    scene = Scene([mirror_floor(s=1.0, g=0.4), *box_faces()], sun_direction=SUN)
    cam = CAM.with_size(32, 32)
    ref = raytrace_reflections(scene, cam, supersample=1, glossy_rays=64).reflected
    errs = [mean_abs_error(raytrace_reflections(scene, cam, supersample=1, glossy_rays=k).reflected, ref)
            for k in (8, 49)]
    assert errs[0] > 0
    assert errs[1] < 0.7 * errs[0], errs


# --- metrics --------------------------------------------------------------------------
def test_mean_abs_error_and_psnr_hand_values():
    a = np.zeros((4, 5, 3))
    b = a + np.array([3, 6, 9]) / 255
    assert mean_abs_error(a, b) == pytest.approx(6 / 255)
    np.testing.assert_allclose(mean_abs_error(a, b, per_channel=True), np.array([3, 6, 9]) / 255)
    mask = np.zeros((4, 5), bool)
    mask[0, :2] = True
    c = b.copy()
    c[0, :2] = 0.5  # only the masked pixels differ from a by 0.5
    assert mean_abs_error(a, c, mask=mask) == pytest.approx(0.5)
    assert mean_abs_error(a, np.full_like(a, 2.0), clip=True) == pytest.approx(1.0)
    assert psnr(a, a) == float("inf")
    assert psnr(a, a + 0.1) == pytest.approx(20.0)  # 10·log10(1 / 0.01)
    e = error_image(a, a + 0.01, scale=50)
    assert e.shape == (4, 5, 3) and e.dtype == np.float32
    np.testing.assert_allclose(e, 0.5, atol=1e-6)
    np.testing.assert_allclose(error_image(a, a + 1.0), 1.0)  # clipped
    assert error_image(np.zeros((2, 2)), np.ones((2, 2)) * 0.002).shape == (2, 2, 3)


def test_occlusion_error_mask_cases():
    inf, nan = np.inf, np.nan
    method = np.array([[1.0, 1.04, 1.06, inf], [inf, 2.0, nan, 5.0]])
    refer = np.array([[1.0, 1.0, 1.0, inf], [3.0, inf, 1.0, 1.0]])
    refl = np.array([[True, True, True, True], [True, True, True, False]])
    m = occlusion_error_mask(method, refer, refl, rel_tol=0.05)
    expect = np.array([[False, False, True, False], [True, True, True, False]])
    np.testing.assert_array_equal(m, expect)
    assert occlusion_error_percentage(m, refl) == pytest.approx(100 * 4 / 7)
    assert occlusion_error_percentage(m, np.zeros_like(refl)) == 0.0
    # abs_tol widens the agreement band: 1.06 vs 1.0 agrees with abs_tol 0.02
    assert not occlusion_error_mask(method, refer, refl, rel_tol=0.05, abs_tol=0.02)[0, 2]


def test_occlusion_error_of_envmap_vs_reference(mirror_box_scene, mirror_box_result):
    """The env-map baseline never intersects anything: its occlusion-error pixels are
    exactly the reflective pixels where the reference hits the box; the reference
    against itself has none."""
    env = envmap_reflections(mirror_box_scene, CAM, supersample=2)
    ref = mirror_box_result
    np.testing.assert_array_equal(env.reflective, ref.reflective)
    m = occlusion_error_mask(env.ray_length, ref.ray_length, ref.reflective)
    np.testing.assert_array_equal(m, ref.reflective & np.isfinite(ref.ray_length))
    assert 0 < occlusion_error_percentage(m, ref.reflective) < 100
    assert not occlusion_error_mask(ref.ray_length, ref.ray_length, ref.reflective).any()


def test_primary_rays_cull_exactly_under_coplanar_back_faces():
    """A tile (thin box) on a wall, seen from behind the wall: the wall's back face
    is culled, the tile's wall-side face (coplanar with the wall, facing the eye) is
    what a back-face-culling rasteriser shows. Restarting past the wall's back face
    would skip the coplanar tile face and see the mirror behind it."""
    wall = quad("wall", [(-1, 0, 0), (1, 0, 0), (1, 2, 0), (-1, 2, 0)], (0, 0, 1), Material((0.8, 0.8, 0.8)))
    # tile box between z = 0 (on the wall) and z = 0.02, fronts outward
    lo, hi = np.array([-0.5, 0.5, 0.0]), np.array([0.5, 1.5, 0.02])
    faces = [quad(f"tile{k}", c, n, Material((0.2, 0.6, 0.7))) for k, (c, n) in enumerate([
        ([(lo[0], lo[1], lo[2]), (hi[0], lo[1], lo[2]), (hi[0], hi[1], lo[2]), (lo[0], hi[1], lo[2])], (0, 0, -1)),
        ([(lo[0], lo[1], hi[2]), (hi[0], lo[1], hi[2]), (hi[0], hi[1], hi[2]), (lo[0], hi[1], hi[2])], (0, 0, 1))])]
    mirror = quad("mirror", [(-2, 0, 1), (2, 0, 1), (2, 2, 1), (-2, 2, 1)], (0, 0, -1), Material((0.9, 0.9, 0.9), 1.0))
    scene = Scene([wall, *faces, mirror], sun_direction=SUN)
    cam = Camera(eye=(0.0, 1.0, -2.0), target=(0.0, 1.0, 0.0), fov=20.0, width=16, height=16)
    res = raytrace_reflections(scene, cam, supersample=1)
    # the centre of the image is the tile's back face (diffuse), not the mirror
    assert not res.reflective[6:10, 6:10].any()
    np.testing.assert_allclose(res.color[8, 8], local_shade(np.array([0.2, 0.6, 0.7]), np.array([0, 0, -1.0]),
                                                             np.asarray(SUN)), atol=1e-5)

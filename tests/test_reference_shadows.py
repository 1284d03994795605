"""Soft-shadow ground truth and §3.4.2 error metrics (reference.shadows): Embree only, no GL."""

from __future__ import annotations

import numpy as np
import pytest

from reference.raycast import RayCaster
from reference.shadows import (
    MASK_GREY,
    ShadowErrors,
    box_visibility,
    error_maps,
    error_picture,
    in_front,
    light_visibility,
    n_words,
    shadow_errors,
    surface_offset,
    visible_counts,
)
from scenes.builtin import geometry as g
from scenes.model import AMBIENT, AreaLight, Scene, SceneObject
from scenes.shading import area_light_shade
from tests.helpers import unpack_bits

# Deliberately "irrational" box and light so that no ray from the grid passes exactly
# through a box edge by a rational coincidence.
BOX_LO = (-0.437, 0.413, -0.371)
BOX_HI = (0.529, 0.907, 0.383)
LIGHT = AreaLight(center=(0.213, 2.71, 0.157), u=(1.37, 0.0, 0.0), v=(0.0, 0.0, -1.19))  # emits −Y


def _ground(half: float = 3.0, y: float = 0.0) -> SceneObject:
    v, f = g.quad((-half, y, -half), (0.0, 0.0, 2 * half), (2 * half, 0.0, 0.0))  # faces +Y
    return SceneObject("ground", v, f)


def _box(lo: tuple[float, ...], hi: tuple[float, ...]) -> SceneObject:
    v, f = g.box(lo, hi)  # closed, outward normals
    return SceneObject("box", v, f)


# --- metrics on hand-counted bits ------------------------------------------------------


def _hand_bits() -> tuple[np.ndarray, np.ndarray]:
    """(approx, truth) (1,3,2) uint32 for k = 8 (64 samples, two words).

    pixel 0: truth {0,1,3}, approx {0,1,2,32}: wrong samples 2 (+1, too bright),
             3 (−1, too dark), 32 (+1) → visibility 3; counts 4 − 3 → signed +1
             (samples 2 and 3 cancel, so intensity 1 < visibility 3);
    pixel 1: equal → 0, 0;
    pixel 2: truth all 64 visible, approx none → visibility 64, signed −64."""
    truth = np.array([[[0b1011, 0], [0xF0F0, 7], [0xFFFFFFFF, 0xFFFFFFFF]]], np.uint32)
    approx = np.array([[[0b0111, 0b1], [0xF0F0, 7], [0, 0]]], np.uint32)
    return approx, truth


def test_visible_counts_by_hand():
    approx, truth = _hand_bits()
    np.testing.assert_array_equal(visible_counts(truth), [[3, 8 + 3, 64]])
    np.testing.assert_array_equal(visible_counts(approx), [[4, 8 + 3, 0]])
    assert visible_counts(truth).dtype == np.uint16
    assert [n_words(k) for k in (1, 5, 6, 8, 16)] == [1, 1, 2, 2, 8]


def test_error_maps_by_hand():
    approx, truth = _hand_bits()
    vis, signed = error_maps(approx, truth)
    np.testing.assert_array_equal(vis, [[3, 0, 64]])
    np.testing.assert_array_equal(signed, [[1, 0, -64]])
    assert vis.dtype == np.uint16 and signed.dtype == np.int16


def test_shadow_errors_by_hand():
    approx, truth = _hand_bits()
    all_px = np.ones((1, 3), bool)
    assert shadow_errors(approx, truth, all_px) == pytest.approx(ShadowErrors(67 / 3, 64.0, 65 / 3, 64.0))
    first_two = np.array([[True, True, False]])
    assert shadow_errors(approx, truth, first_two) == ShadowErrors(1.5, 3.0, 0.5, 1.0)
    assert shadow_errors(approx, truth, np.zeros((1, 3), bool)) == ShadowErrors(0.0, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError):
        shadow_errors(approx[..., :1], truth, all_px)


def test_error_picture_by_hand():
    approx, truth = _hand_bits()
    approx = np.concatenate([approx, approx[:, :1]], axis=1)  # a 4th pixel, outside the mask
    truth = np.concatenate([truth, truth[:, :1]], axis=1)
    mask = np.array([[True, True, True, False]])
    pic = error_picture(approx, truth, mask, k=8)
    assert pic.dtype == np.float32 and pic.shape == (1, 4, 3)
    np.testing.assert_allclose(pic[0, 0], [0.0, 16 * 1 / 64, 0.0])  # too bright by 1 of 64: green
    np.testing.assert_allclose(pic[0, 1], [0.0, 0.0, 0.0])  # no error: black
    np.testing.assert_allclose(pic[0, 2], [1.0, 0.0, 0.0])  # too dark by 64: red, saturated
    np.testing.assert_allclose(pic[0, 3], [MASK_GREY] * 3)


def test_area_light_shade_by_hand():
    light = AreaLight(center=(0.0, 2.0, 0.0), u=(1.0, 0.0, 0.0), v=(0.0, 0.0, -1.0))
    albedo = np.array([[1.0, 0.5, 0.0], [1.0, 1.0, 1.0], [1.0, 1.0, 1.0]])
    normal = np.array([[0.0, 1.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0]])
    position = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 0.0, 0.0]])  # 2nd: light at 45°
    out = area_light_shade(albedo, normal, position, light, np.array([0.5, 1.0, 1.0]))
    assert out.dtype == np.float32
    lit0 = AMBIENT + (1 - AMBIENT) * 0.5
    lit1 = AMBIENT + (1 - AMBIENT) / np.sqrt(2)
    np.testing.assert_allclose(out, [[lit0, 0.5 * lit0, 0.0], [lit1] * 3, [AMBIENT] * 3], rtol=1e-6)


# --- Embree truth against the analytic box-over-plane shadow ---------------------------


@pytest.fixture(scope="module")
def box_scene() -> tuple[RayCaster, np.ndarray, np.ndarray]:
    scene = Scene([_ground(), _box(BOX_LO, BOX_HI)], area_light=LIGHT)
    # The mesh is float32: the analytic box must be exactly the one Embree sees.
    lo = np.asarray(BOX_LO, np.float32).astype(np.float64)
    hi = np.asarray(BOX_HI, np.float32).astype(np.float64)
    return RayCaster(scene), lo, hi


def _receivers(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(points (1,N,3), normals (1,N,3)): a 40×40 jittered grid on the ground (normal
    +Y) under and around the box, plus 8×8 grids on the box's +X and −Z sides (their
    tangent planes reject part of the light)."""
    rng = np.random.default_rng(7)
    t = np.linspace(-2.4, 2.4, 40)
    x, z = np.meshgrid(t, t, indexing="xy")
    ground = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], axis=1)
    ground[:, [0, 2]] += rng.uniform(-0.03, 0.03, (len(ground), 2))
    a, b = np.meshgrid(np.linspace(0.05, 0.95, 8), np.linspace(0.05, 0.95, 8), indexing="xy")
    ys = lo[1] + a.ravel() * (hi[1] - lo[1])
    side_x = np.stack([np.full(a.size, hi[0]), ys, lo[2] + b.ravel() * (hi[2] - lo[2])], axis=1)
    side_z = np.stack([lo[0] + b.ravel() * (hi[0] - lo[0]), ys, np.full(a.size, lo[2])], axis=1)
    points = np.concatenate([ground, side_x, side_z])
    normals = np.concatenate([np.tile([0.0, 1.0, 0.0], (len(ground), 1)), np.tile([1.0, 0.0, 0.0], (64, 1)),
                              np.tile([0.0, 0.0, -1.0], (64, 1))])
    return points[None], normals[None]


def _grazing(points: np.ndarray, normals: np.ndarray, samples: np.ndarray, lo: np.ndarray, hi: np.ndarray,
             delta: float) -> np.ndarray:
    """(N,S) bool: segments passing within about delta of the box boundary (growing
    and shrinking the box by delta changes the analytic answer)."""
    return box_visibility(points, normals, samples, lo - delta, hi + delta) != \
        box_visibility(points, normals, samples, lo + delta, hi - delta)


def test_box_umbra_and_penumbra_match_analytic(box_scene):
    caster, lo, hi = box_scene
    k = 16
    points, normals = _receivers(lo, hi)
    mask = np.ones(points.shape[:2], bool)
    bits = light_visibility(caster, points, normals, mask, LIGHT, k)
    assert bits.shape == (1, points.shape[1], 8) and bits.dtype == np.uint32
    embree = unpack_bits(bits, k)[0]
    p, n = points[0], normals[0]
    samples = LIGHT.samples(k)
    analytic = box_visibility(p, n, samples, lo, hi)
    front = in_front(p, n, samples).sum(axis=1)

    counts = visible_counts(bits)[0].astype(int)
    ground = slice(0, 1600)
    assert (counts[ground] == 0).any()  # umbra
    assert ((counts[ground] > 0) & (counts[ground] < k * k)).sum() > 50  # penumbra
    assert (counts[ground] == k * k).any()  # fully lit
    sides = slice(1600, None)
    assert ((front[sides] > 0) & (front[sides] < k * k)).all()  # the side tangent planes cut the light
    assert (counts[sides] == front[sides]).all()  # nothing blocks the sides' front half-space

    # The rays start surface_offset off the surface, the analytic segments on it: a ray
    # may only disagree where it passes within that offset of the box boundary. The box's
    # edges along X are parallel to the light's sample rows, so such a graze flips a
    # whole row of k samples at once: in this set-up one ground point (index 1055), one
    # row of 12 of its samples in front of the top edge — 12 of 442,368 rays.
    wrong = embree != analytic
    grazing = _grazing(p, n, samples, lo, hi, 2 * surface_offset(caster))
    assert not (wrong & ~grazing).any()
    assert wrong.sum() <= k, f"{wrong.sum()} grazing rays disagree"
    off_points = np.flatnonzero(wrong.any(axis=1))
    assert len(off_points) <= 1
    exact = np.ones(len(p), bool)
    exact[off_points] = False
    np.testing.assert_array_equal(counts[exact], analytic.sum(axis=1)[exact])
    # Analytic segments from the lifted origins: Embree agrees on every ray.
    lifted = box_visibility(p + n * surface_offset(caster), n, samples, lo, hi)
    np.testing.assert_array_equal(embree, lifted)
    np.testing.assert_array_equal(counts, lifted.sum(axis=1))


# --- the shared rules: tangent plane, mask, bit layout ---------------------------------


def _far_scene(light: AreaLight) -> RayCaster:
    """A scene whose only geometry is far from every ray of these tests."""
    return RayCaster(Scene([_ground(half=0.5, y=-50.0)], area_light=light))


def test_tangent_plane_rule_exact_bits():
    # A vertical light whose middle sample row lies exactly in the plane y = 0 of the point.
    light = AreaLight(center=(2.0, 0.0, 0.0), u=(0.0, 0.0, -1.0), v=(0.0, 1.2, 0.0))  # emits −X
    assert np.all(light.samples(3)[3:6, 1] == 0.0)
    caster = _far_scene(light)
    bits = light_visibility(caster, np.zeros((1, 1, 3)), np.array([[[0.0, 1.0, 0.0]]]), np.ones((1, 1), bool),
                            light, 3)
    # samples 0-2 below the plane, 3-5 on it (dot = 0: not visible), 6-8 above
    np.testing.assert_array_equal(bits, [[[0b111000000]]])


def test_tangent_plane_rule_tilted_normals_and_mask():
    light = AreaLight(center=(0.1, 2.0, -0.2), u=(3.0, 0.0, 0.0), v=(0.0, 0.0, -3.0))
    caster = _far_scene(light)
    k = 16
    rng = np.random.default_rng(3)
    h, w = 6, 5
    points = rng.uniform(-0.5, 0.5, (h, w, 3))
    normals = rng.normal(size=(h, w, 3)) + [0.0, 1.5, 0.0]
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    mask = rng.random((h, w)) < 0.7
    points[~mask] = np.nan  # never read
    normals[~mask] = np.nan
    bits = light_visibility(caster, points, normals, mask, light, k)
    assert not bits[~mask].any()
    front = in_front(points[mask], normals[mask], light.samples(k))
    assert 0 < front.mean() < 1
    np.testing.assert_array_equal(unpack_bits(bits[mask], k), front)  # nothing blocks: visible ⇔ in front


@pytest.mark.parametrize(("k", "blocked", "expected"), [
    (5, 13, [0x01FFFFFF ^ (1 << 13)]),
    (8, 37, [0xFFFFFFFF, 0xFFFFFFFF ^ (1 << 5)]),
    (16, 200, [0xFFFFFFFF] * 6 + [0xFFFFFFFF ^ (1 << 8), 0xFFFFFFFF]),
])
def test_bit_layout_one_blocked_sample(k, blocked, expected):
    light = AreaLight(center=(0.0, 2.0, 0.0), u=(1.0, 0.0, 0.0), v=(0.0, 0.0, -1.0))
    # A cube on the midpoint of the segment to sample `blocked`, far narrower than the
    # spacing of the neighbouring rays there (1 / 2k), so it blocks that sample only.
    mid = light.samples(k)[blocked] / 2
    half = 1 / (8 * k)
    caster = RayCaster(Scene([_ground(), _box(tuple(mid - half), tuple(mid + half))], area_light=light))
    points = np.zeros((2, 2, 3))
    normals = np.tile([0.0, 1.0, 0.0], (2, 2, 1))
    mask = np.array([[True, False], [False, False]])
    bits = light_visibility(caster, points, normals, mask, light, k)
    assert bits.shape == (2, 2, n_words(k))
    np.testing.assert_array_equal(bits[0, 0], np.array(expected, np.uint32))
    assert not bits[~mask].any()
    assert visible_counts(bits)[0, 0] == k * k - 1


def test_batching_changes_nothing(monkeypatch):
    import reference.shadows as shadows

    caster = RayCaster(Scene([_ground(), _box(BOX_LO, BOX_HI)], area_light=LIGHT))
    t = np.linspace(-1.5, 1.5, 12)
    x, z = np.meshgrid(t, t, indexing="xy")
    points = np.stack([x, np.zeros_like(x), z], axis=-1)
    normals = np.tile([0.0, 1.0, 0.0], (12, 12, 1))
    mask = np.ones((12, 12), bool)
    mask[3, 4] = False
    whole = light_visibility(caster, points, normals, mask, LIGHT, 8)
    monkeypatch.setattr(shadows, "RAY_CHUNK", 50)  # several pixel chunks, 1 light sample per batch
    np.testing.assert_array_equal(light_visibility(caster, points, normals, mask, LIGHT, 8), whole)
    monkeypatch.setattr(shadows, "RAY_CHUNK", 1000)  # whole pixel set, 6 light samples per batch
    np.testing.assert_array_equal(light_visibility(caster, points, normals, mask, LIGHT, 8), whole)
    assert 0 < visible_counts(whole)[mask].mean() < 64


def test_light_side_rule_points_behind_the_light_see_nothing():
    """The light emits along −(u × v) only: the same rectangle facing away lights
    nothing, and a light hung inside a room lights the floor, not the ceiling."""
    down = AreaLight(center=(0.0, 1.0, 0.0), u=(0.5, 0.0, 0.0), v=(0.0, 0.0, -0.5))  # u × v = +Y: emits −Y
    up = AreaLight(center=down.center, u=down.v, v=down.u)
    caster = _far_scene(down)
    points = np.array([[[0.0, 0.0, 0.0], [0.3, 2.0, 0.1]]])   # a floor point below, a ceiling point above
    normals = np.array([[[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]]])
    mask = np.ones((1, 2), bool)
    np.testing.assert_array_equal(visible_counts(light_visibility(caster, points, normals, mask, down, 4)), [[16, 0]])
    np.testing.assert_array_equal(visible_counts(light_visibility(caster, points, normals, mask, up, 4)), [[0, 16]])

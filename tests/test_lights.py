"""Light setups of Alg. 5 (thesis §3.3–3.4, scenes.lights): the reference cameras
from the light's corners look at the scene, so each reference image spends its
pixels on it; the shadow-map cameras keep the light's axis. No GL, no Embree."""

from __future__ import annotations

import numpy as np
import pytest

from scenes.lights import (
    AXIS_FOV_MAX,
    MAX_LIGHT_REACH,
    SHADOW_MAP_FOV_MAX,
    default_area_light,
    light_camera,
    light_normal,
    light_reach_problem,
    reference_cameras,
    shadow_map_camera,
)
from scenes.model import AreaLight

LO, HI = np.array([-1.0, 0.0, -1.0]), np.array([1.0, 0.5, 1.0])
BOUNDS = (LO, HI)
CORNERS = np.array([[x, y, z] for x in (LO[0], HI[0]) for y in (LO[1], HI[1]) for z in (LO[2], HI[2])])
LIGHT = default_area_light(BOUNDS, (0.3, 0.85, 0.45))


def ndc(cam, points: np.ndarray) -> np.ndarray:
    px, z = cam.project(points)
    assert (z > 0).all()
    return np.stack([px[:, 0] / cam.width * 2 - 1, 1 - px[:, 1] / cam.height * 2], axis=1)


def hull_area(p: np.ndarray) -> float:
    """Area of the convex hull of 2D points (monotone chain, shoelace)."""
    pts = sorted(map(tuple, p))

    def cross(o, a, b) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    def half(seq):
        out: list[tuple[float, float]] = []
        for q in seq:
            while len(out) >= 2 and cross(out[-2], out[-1], q) <= 0:
                out.pop()
            out.append(q)
        return out[:-1]

    h = np.array(half(pts) + half(pts[::-1]))
    x, y = h[:, 0], h[:, 1]
    return 0.5 * abs(float(x @ np.roll(y, -1) - y @ np.roll(x, -1)))


def test_corner_cameras_look_at_the_scene_and_fit_it():
    for cam in reference_cameras(LIGHT, BOUNDS, "non_redundant", 64):
        _, _, f = cam.basis()
        to_centre = (LO + HI) / 2 - np.asarray(cam.eye)
        np.testing.assert_allclose(f, to_centre / np.linalg.norm(to_centre), atol=1e-12)
        # the fov is fitted: the box touches the image border (× the 1.02 margin), inside it
        np.testing.assert_allclose(np.abs(ndc(cam, CORNERS)).max(), 1 / 1.02, rtol=1e-9)
        # the light's v edge stays the image's up
        _, up, _ = cam.basis()
        assert up @ np.asarray(LIGHT.v) > 0.9 * np.linalg.norm(LIGHT.v)


def test_scene_aim_spends_more_pixels_on_the_scene_than_the_light_axis():
    for aimed, axis in zip(reference_cameras(LIGHT, BOUNDS, "conventional", 64),
                           reference_cameras(LIGHT, BOUNDS, "conventional", 64, aim="light"), strict=True):
        _, _, f = axis.basis()
        np.testing.assert_allclose(f, -light_normal(LIGHT), atol=1e-12)
        assert np.linalg.norm(ndc(axis, ((LO + HI) / 2)[None])) > 0.3  # the box sits off the axis
        assert aimed.fov < axis.fov
        # the box's outline covers more than twice the image area
        assert hull_area(ndc(aimed, CORNERS)) > 2 * hull_area(ndc(axis, CORNERS))


def test_the_centre_camera_is_the_same_for_both_aims():
    (a,), (b,) = (reference_cameras(LIGHT, BOUNDS, "peeling", 64, aim=aim) for aim in ("scene", "light"))
    np.testing.assert_allclose(a.basis(), b.basis(), atol=1e-12)
    assert a.eye == b.eye and a.fov == pytest.approx(b.fov, rel=1e-12)


@pytest.mark.parametrize("aim", ["scene", "light"])
def test_a_light_facing_away_is_refused(aim):
    away = AreaLight((0.0, 5.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0))  # u × v = −Y: faces up
    with pytest.raises(ValueError, match="in front of the light"):
        light_camera(away, np.asarray(away.center), BOUNDS, 64, aim=aim)
    with pytest.raises(ValueError, match="aim"):
        light_camera(LIGHT, np.asarray(LIGHT.center), BOUNDS, 64, aim="sideways")


def test_shadow_maps_look_along_the_axis_unless_that_is_too_wide():
    """Alg. 5's maps look along the light's axis (every sample of the default light);
    a sample whose axis map needs more than AXIS_FOV_MAX looks at the box, and a light
    grazing the box (every map wider than SHADOW_MAP_FOV_MAX) is refused."""
    for s in LIGHT.samples(8):
        assert shadow_map_camera(LIGHT, s, BOUNDS, 64) == light_camera(LIGHT, s, BOUNDS, 64)
    huge = AreaLight((0.0, 3.0, 0.0), (0.0, 0.0, 200.0), (200.0, 0.0, 0.0))  # u × v = +Y: emits −Y
    corner = huge.samples(4)[0]
    axis = light_camera(huge, corner, BOUNDS, 64)
    cam = shadow_map_camera(huge, corner, BOUNDS, 64)
    assert axis.fov > AXIS_FOV_MAX and cam.fov < 10
    np.testing.assert_allclose(cam.basis()[2], ((LO + HI) / 2 - corner) / np.linalg.norm((LO + HI) / 2 - corner))
    grazing = AreaLight((0.5, HI[1] + 1e-3, 0.5), (0.0, 0.0, 0.4), (0.4, 0.0, 0.0))
    with pytest.raises(ValueError, match=rf"sees the scene box across 1\d\d\.\d° \(a shadow map covers at most "
                                         rf"{SHADOW_MAP_FOV_MAX:g}°\)"):
        shadow_map_camera(grazing, grazing.samples(2)[0], BOUNDS, 64)


def test_a_light_beyond_the_reach_of_float32_maps_is_refused():
    """BOUNDS' diagonal is √8.25 (2 × 0.5 × 2): a light whose centre lies more than
    MAX_LIGHT_REACH × √8.25 from the box centre, or with an edge longer than that, is
    refused by every light camera, naming the distance in scene diagonals."""
    centre = (LO + HI) / 2
    reach = MAX_LIGHT_REACH * np.sqrt(8.25)
    inside = AreaLight(tuple(centre + [0.0, reach * 0.999, 0.0]), (0.0, 0.0, 1.0), (1.0, 0.0, 0.0))
    beyond = AreaLight(tuple(centre + [0.0, reach * 1.001, 0.0]), (0.0, 0.0, 1.0), (1.0, 0.0, 0.0))
    wide = AreaLight((0.0, 3.0, 0.0), (0.0, 0.0, reach * 1.001), (1.0, 0.0, 0.0))
    assert light_reach_problem(inside, BOUNDS) is None
    assert light_reach_problem(beyond, BOUNDS) == (
        f"the light's centre lies {MAX_LIGHT_REACH * 1.001:.3g} scene diagonals from the scene's centre "
        f"(at most {MAX_LIGHT_REACH:g})")
    assert light_reach_problem(wide, BOUNDS) == (
        f"a light edge is {MAX_LIGHT_REACH * 1.001:.3g} scene diagonals long (at most {MAX_LIGHT_REACH:g})")
    assert shadow_map_camera(inside, inside.samples(2)[0], BOUNDS, 64).fov > 0
    for light in (beyond, wide):
        with pytest.raises(ValueError, match="scene diagonals"):
            shadow_map_camera(light, light.samples(2)[0], BOUNDS, 64)
        with pytest.raises(ValueError, match="scene diagonals"):
            reference_cameras(light, BOUNDS, "conventional", 64)


@pytest.mark.parametrize("aim", ["scene", "light"])
def test_a_tiny_light_has_finite_cameras(aim):
    """Edges of 1e-200 (their squared lengths underflow to 0): the light's v edge still
    gives the cameras' up (it used to be NaN)."""
    tiny = AreaLight((0.2, 3.0, 0.1), (0.0, 0.0, 1e-200), (1e-200, 0.0, 0.0))  # u × v = +Y: emits −Y
    cam = light_camera(tiny, np.asarray(tiny.center), BOUNDS, 64, aim=aim)
    assert np.isfinite(cam.basis()).all() and np.allclose(cam.basis()[1] @ [1.0, 0.0, 0.0], 1.0, atol=0.2)

"""Camera matrices, rays and seeded camera paths (scenes/camera.py)."""

from __future__ import annotations

import numpy as np
import pytest

from scenes.camera import (
    Camera,
    CameraError,
    box_corners,
    camera_step,
    flythrough_path,
    framing_distance,
    look_at_scene,
    moved,
    orbit_path,
    rolled,
    rotated,
    turned,
    zoomed,
)

BOUNDS = (np.array([-1.0, 0.0, -2.0]), np.array([3.0, 2.0, 1.0]))


def test_view_projection_maps_pixel_rays_to_pixel_centres():
    cam = Camera((1, 2, 5), (0.5, 0.5, 0), (0, 1, 0), fov=50, width=40, height=30).fit_clip(BOUNDS)
    d = cam.pixel_directions()
    pts = np.asarray(cam.eye) + 3.0 * d  # points along each pixel's ray
    clip = np.c_[pts.reshape(-1, 3), np.ones(40 * 30)] @ cam.view_projection().T
    ndc = clip[:, :2] / clip[:, 3:4]
    px = (ndc[:, 0] + 1) / 2 * 40
    py = (1 - ndc[:, 1]) / 2 * 30  # row 0 = top
    xs, ys = np.meshgrid(np.arange(40) + 0.5, np.arange(30) + 0.5)
    np.testing.assert_allclose(px, xs.ravel(), atol=1e-9)
    np.testing.assert_allclose(py, ys.ravel(), atol=1e-9)
    xy, z = cam.project(pts)
    np.testing.assert_allclose(xy[..., 0], xs, atol=1e-9)
    np.testing.assert_allclose(z, 3.0 * d @ cam.basis()[2], atol=1e-12)


def test_look_at_hand_values():
    cam = Camera((0, 0, 5), (0, 0, 0), fov=90, width=2, height=2, near=1, far=10)
    v = cam.view_matrix()
    np.testing.assert_allclose(v @ [0, 0, 0, 1], [0, 0, -5, 1])
    p = cam.projection_matrix()
    # A point on the near plane maps to NDC z = -1, on the far plane to +1.
    for z, ndc in ((-1.0, -1.0), (-10.0, 1.0)):
        c = p @ [0, 0, z, 1]
        assert c[2] / c[3] == pytest.approx(ndc)
    # fov 90, 2×2: the top-left pixel centre ray is at 45° / 2 offsets: (-0.5, 0.5, -1) normalised.
    np.testing.assert_allclose(cam.pixel_directions()[0, 0], np.array([-0.5, 0.5, -1]) / np.sqrt(1.5))


@pytest.mark.parametrize("azimuth, elevation, fov", [(20, 15, 50), (35, 25, 45), (-120, 60, 30), (90, -10, 70)])
def test_framing_distance_is_the_least_that_shows_every_corner(azimuth, elevation, fov):
    corners = box_corners(BOUNDS)
    t = framing_distance(BOUNDS, azimuth, elevation, fov)
    px, z = look_at_scene(BOUNDS, azimuth, elevation, t, fov, 100, 100).project(corners)
    assert (z > 0).all() and px.min() > -1e-6 and px.max() < 100 + 1e-6  # all in view ...
    assert min(px.min(), 100 - px.max()) < 1e-6  # ... one on the border
    px, _ = look_at_scene(BOUNDS, azimuth, elevation, 0.99 * t, fov, 100, 100).project(corners)
    assert px.min() < 0 or px.max() > 100  # nearer, one leaves the image


def test_fit_clip_encloses_bounds():
    cam = look_at_scene(BOUNDS, azimuth=10, elevation=20, distance=1.2)
    corners = np.array([[x, y, z] for x in (-1, 3) for y in (0, 2) for z in (-2, 1)], float)
    _, depth = cam.project(corners)
    assert (depth > cam.near).all() and (depth < cam.far).all()
    inside = Camera((1, 1, -0.5), (2, 1, 0)).fit_clip(BOUNDS)
    assert 0 < inside.near < 1e-2 * inside.far


@pytest.mark.parametrize("kwargs, message", [
    ({"eye": (0, 0, 0), "target": (0, 0, 0)}, "coincide"),
    ({"eye": (0, 0, 1), "target": (0, 0, 0), "up": (0, 0, 0)}, "zero"),
    ({"eye": (0, 0, 1), "target": (0, 0, 0), "up": (0, 0, 2)}, "parallel"),
    ({"eye": (0, float("nan"), 1), "target": (0, 0, 0)}, "NaN"),
    ({"eye": (0, 0, 1), "target": (0, float("inf"), 0)}, "NaN or infinite"),
    ({"eye": (0, 0, 1), "target": (0, 0, 0), "fov": 180}, "fov"),
    ({"eye": (0, 0, 1), "target": (0, 0, 0), "width": 0}, "width"),
    ({"eye": (0, 0, 1), "target": (0, 0, 0), "near": 2, "far": 1}, "near"),
])
def test_invalid_cameras_name_the_problem(kwargs, message):
    with pytest.raises(CameraError, match=message):
        Camera(**kwargs)


def test_paths_are_seeded_and_smooth():
    a = orbit_path(BOUNDS, 30, seed=3, jitter=5)
    b = orbit_path(BOUNDS, 30, seed=3, jitter=5)
    c = orbit_path(BOUNDS, 30, seed=4, jitter=5)
    assert [x.eye for x in a] == [x.eye for x in b]
    assert [x.eye for x in a] != [x.eye for x in c]
    f = flythrough_path(BOUNDS, 50, seed=1)
    assert [x.eye for x in f] == [x.eye for x in flythrough_path(BOUNDS, 50, seed=1)]
    eyes = np.array([x.eye for x in f])
    steps = np.linalg.norm(np.diff(eyes, axis=0), axis=1)
    assert steps.max() < 0.2 * np.linalg.norm(BOUNDS[1] - BOUNDS[0])  # no jumps
    for cam in f:
        assert cam.near is not None and cam.far > cam.near


def test_camera_steps_by_hand():
    """turned / moved / zoomed / rolled change exactly what they name, by exactly the
    amount asked, and camera_step measures it back (bench.stream_jumps' targets)."""
    cam = Camera((0.0, 0.0, 4.0), (0.0, 0.0, 0.0), fov=90.0)  # looks down -Z; right +X, up +Y
    left = turned(cam, 90.0)
    np.testing.assert_allclose(left.target, (-4.0, 0.0, 4.0), atol=1e-12)  # positive: to the left
    np.testing.assert_allclose(left.eye, cam.eye)
    np.testing.assert_allclose(left.up, (0.0, 1.0, 0.0), atol=1e-12)
    side = moved(cam, 0.25, (2.0, 0.0, 0.0))  # a quarter of the distance 4, along +X
    assert side.eye == (1.0, 0.0, 4.0) and side.target == (1.0, 0.0, 0.0) and side.up == cam.up
    wide = zoomed(cam, 2.0)  # tan(45°) = 1 → tan(fov/2) = 2
    assert wide.fov == pytest.approx(2 * np.degrees(np.arctan(2.0))) and wide.eye == cam.eye
    roll = rolled(cam, 90.0)  # the up vector turns onto the right one
    np.testing.assert_allclose(roll.up, (1.0, 0.0, 0.0), atol=1e-12)
    assert roll.target == cam.target and roll.eye == cam.eye
    # measured back, on a camera looking obliquely (a path's), every kind alone
    tilted = Camera((0.3, 1.7, 2.2), (-0.4, 0.2, -0.5), fov=55.0).fit_clip(BOUNDS)
    right = tilted.basis()[0]
    for target, (turn, move, zoom, roll_deg) in (
            (turned(tilted, 15.0), (15.0, 0.0, 1.0, 0.0)), (turned(tilted, -45.0), (45.0, 0.0, 1.0, 0.0)),
            (moved(tilted, 0.1, right), (0.0, 0.1, 1.0, 0.0)), (zoomed(tilted, 1.25), (0.0, 0.0, 1.25, 0.0)),
            (zoomed(tilted, 1 / 1.1), (0.0, 0.0, 1 / 1.1, 0.0)), (rolled(tilted, 45.0), (0.0, 0.0, 1.0, 45.0)),
            (rolled(tilted, -10.0), (0.0, 0.0, 1.0, -10.0))):
        step = camera_step(tilted, target)
        np.testing.assert_allclose([step.turn_deg, step.move, step.zoom, step.roll_deg], [turn, move, zoom, roll_deg],
                                   atol=1e-6)
        assert target.near is None and target.far is None  # a new view: its clip planes are fitted again
    for deg in (180.0, -180.0):  # either way round reads +180: the range is (-180, 180]
        assert camera_step(tilted, rolled(tilted, deg)).roll_deg == pytest.approx(180.0)
    with pytest.raises(ValueError, match="nonzero axis"):
        rotated(tilted, 10.0, (0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="nonzero direction"):
        moved(tilted, 0.1, (0.0, 0.0, 0.0))

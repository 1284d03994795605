"""Camera rigs for depth-image sets (thesis Ch. 2, Fig. 8 and §2.3.2).

`fig8_rig`: three reference viewpoints V0, V1, V2 around the scene, all looking
at its centre, plus the depth-peeling viewpoint at their centroid (the red and
white points of Fig. 8). `intermediate_views`: viewpoints uniformly distributed
in the segment (n = 2) or triangle (n = 3) spanned by the reference eyes, used
by the "useful" and "available" sample metrics (§2.3.2, metrics 3 and 4).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from scenes.camera import Camera, CameraError


def fit_distance(fov: float, width: int, height: int, spread_deg: float = 0.0, margin: float = 1.0) -> float:
    """Eye distance, in units of the box diagonal, at which the box's bounding
    sphere (radius diag/2) fills the view of every camera of a `fig8_rig`.

    A camera looking at the sphere's centre from distance D sees the sphere
    within the cone of half-angle asin(r / D); it fits the view when that is at
    most half the narrower field of view, a = min(fov, horizontal fov) / 2:
    D = r / sin(a) = diag / (2 sin a). The rig's eyes lie `spread_deg` off its
    axis at distance d·diag, so the nearest eye of the rig's triangle (its
    centroid: the depth-peeling eye, also the nearest intermediate view) is at
    d·diag·cos(spread). Requiring that one to fit too:

        d = margin / (2 · sin(a) · cos(spread)).

    For fov 45°, square images and spread 20°: d = 0.5 / (0.3827 · 0.9397) ≈ 1.39
    (1.31 for a single camera). Every reference, peeling and intermediate view
    then holds the whole box: no method loses samples at the image borders."""
    v = np.radians(fov) / 2
    h = np.arctan(np.tan(v) * width / height)
    a = min(v, h)
    return float(margin / (2.0 * np.sin(a) * np.cos(np.radians(spread_deg))))


def peeling_camera(cameras: Sequence[Camera]) -> Camera:
    """The peeling viewpoint of a set's cameras (as the Fig. 8 rig places it):
    the single camera, or the eyes' centroid looking at the first camera's target
    with its up, fov and size. Raises CameraError naming it where that camera is
    invalid (the centroid on the target, or the view along up)."""
    if len(cameras) == 1:
        return cameras[0]
    c0 = cameras[0]
    centroid = tuple(float(x) for x in np.mean([c.eye for c in cameras], axis=0))
    try:
        return Camera(centroid, c0.target, c0.up, c0.fov, c0.width, c0.height)
    except CameraError as exc:
        raise CameraError(f"the peeling camera (the eyes' centroid {centroid} looking at the first camera's "
                          f"target) is invalid: {exc}") from None


def fig8_rig(bounds: tuple[np.ndarray, np.ndarray], width: int, height: int, spread_deg: float = 20.0,
             azimuth: float = 35.0, elevation: float = 25.0, distance: float | None = None, fov: float = 45.0
             ) -> tuple[list[Camera], Camera]:
    """The Fig. 8 rig for the box `bounds` (min, max corners).

    The rig axis points from the box centre toward (azimuth, elevation) degrees
    (azimuth about +Y from +Z, as `look_at_scene`). The three eyes lie at
    `distance` × the box diagonal from the centre, `spread_deg` degrees off that
    axis, at 120° steps around it (V0 above the axis, V1 lower left, V2 lower
    right as seen from the scene). All cameras look at the box centre with the
    given vertical fov and width × height pixels, near/far fitted to the box.
    distance None (default): `fit_distance`, the box's bounding sphere just
    fills the view of the nearest camera of the rig (≈ 1.39 for 45°, 20°, square).
    The thesis (Fig. 8, §2.3.3) gives no angles or distances for its rig: the
    20° spread is our choice.

    Returns (cameras [V0, V1, V2], peeling camera at the eyes' centroid)."""
    if not (0.0 < spread_deg < 90.0):
        raise ValueError(f"spread_deg must be in (0, 90), got {spread_deg}")
    lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
    c = (lo + hi) / 2
    diag = float(np.linalg.norm(hi - lo)) or 1.0
    if distance is None:
        distance = fit_distance(fov, width, height, spread_deg)
    a, e = np.radians(azimuth), np.radians(elevation)
    axis = np.array([np.cos(e) * np.sin(a), np.sin(e), np.cos(e) * np.cos(a)])
    # Orthonormal frame around the axis: `up` is the world +Y made orthogonal to it.
    world_up = np.array([0.0, 1.0, 0.0]) if abs(axis[1]) < 0.99 else np.array([0.0, 0.0, 1.0])
    right = np.cross(world_up, axis)
    right /= np.linalg.norm(right)
    up = np.cross(axis, right)
    s = np.radians(spread_deg)
    cams = []
    for k in range(3):
        phi = np.radians(90.0 + 120.0 * k)
        d = np.cos(s) * axis + np.sin(s) * (np.cos(phi) * right + np.sin(phi) * up)
        eye = c + distance * diag * d
        cams.append(Camera(tuple(eye), tuple(c), tuple(world_up), fov, width, height).fit_clip((lo, hi)))
    return cams, peeling_camera(cams).fit_clip((lo, hi))


def intermediate_views(cameras: Sequence[Camera], count: int, seed: int = 0) -> list[Camera]:
    """`count` cameras whose eyes are uniformly distributed (seeded) in the
    simplex spanned by the reference eyes: the segment V0V1 for n = 2, the
    triangle V0V1V2 for n = 3 (uniform barycentric coordinates, i.e. a flat
    Dirichlet draw; for n = 1 every view is V0). Target, up, fov and size are
    cameras[0]'s; near/far are the references' min near / max far when all have
    them (the eyes lie in their convex hull), else left unset."""
    if not cameras:
        raise ValueError("intermediate_views needs at least one reference camera")
    if count < 0:
        raise ValueError("count must be ≥ 0")
    eyes = np.array([cam.eye for cam in cameras], dtype=np.float64)
    rng = np.random.default_rng(seed)
    weights = rng.dirichlet(np.ones(len(cameras)), size=count) if len(cameras) > 1 else np.ones((count, 1))
    ref = cameras[0]
    clip = all(cam.near is not None and cam.far is not None for cam in cameras)
    near = min(cam.near for cam in cameras) if clip else None  # type: ignore[type-var]
    far = max(cam.far for cam in cameras) if clip else None  # type: ignore[type-var]
    out = []
    for w in weights:
        eye = w @ eyes
        out.append(replace(ref, eye=tuple(float(x) for x in eye), near=near, far=far))
    return out

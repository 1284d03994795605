"""Pinhole cameras and camera paths (DESIGN.md, "Conventions").

OpenGL conventions: right-handed world, the camera looks down -Z in eye space,
image row 0 is the top, pixel (x, y) has its centre at (x + 0.5, y + 0.5).
Matrices are float64 (4,4) in row-major numpy layout acting on column vectors.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

#: Near plane as a fraction of the far plane when the eye is inside the scene box
#: (24-bit depth: at 1e-4 a mirror 5 mm in front of its backing z-fought at 4 m in the
#: built-in mirror and bathroom scenes; at 1e-3 the G-buffer's objects match Embree's
#: there, test_camera; geometry nearer the eye than this is clipped).
NEAR_FRACTION = 1e-3


class CameraError(ValueError):
    """An invalid camera (the message names the problem)."""


@dataclass(frozen=True)
class Camera:
    """eye, target, up in world units; fov = vertical field of view in degrees;
    width, height in pixels; near/far in world units (None = derive from the
    scene bounds with `fit_clip`)."""

    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    fov: float = 45.0
    width: int = 512
    height: int = 512
    near: float | None = None
    far: float | None = None

    def __post_init__(self) -> None:
        for name in ("eye", "target", "up"):
            v = np.asarray(getattr(self, name), dtype=np.float64)
            if v.shape != (3,):
                raise CameraError(f"camera {name} must have 3 components")
            if not np.all(np.isfinite(v)):
                raise CameraError(f"camera {name} has a NaN or infinite component")
            object.__setattr__(self, name, tuple(float(x) for x in v))
        fwd = np.subtract(self.target, self.eye)
        if np.linalg.norm(fwd) <= 1e-12 * max(1.0, np.linalg.norm(self.eye)):
            raise CameraError("camera eye and target coincide")
        up = np.asarray(self.up)
        if np.linalg.norm(up) == 0:
            raise CameraError("camera up vector is zero")
        if np.linalg.norm(np.cross(fwd / np.linalg.norm(fwd), up / np.linalg.norm(up))) < 1e-6:
            raise CameraError("camera up vector is parallel to the view direction")
        if not (np.isfinite(self.fov) and 0.0 < self.fov < 180.0):
            raise CameraError(f"camera fov must be in (0, 180) degrees, got {self.fov}")
        if int(self.width) != self.width or int(self.height) != self.height or self.width < 1 or self.height < 1:
            raise CameraError("camera width and height must be positive integers")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        if self.near is not None or self.far is not None:
            if self.near is None or self.far is None or not (0 < self.near < self.far < np.inf):
                raise CameraError("camera needs 0 < near < far (both finite)")

    # --- frame -----------------------------------------------------------------
    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Unit (right, up, forward) vectors in world space."""
        f = np.subtract(self.target, self.eye)
        f = f / np.linalg.norm(f)
        r = np.cross(f, self.up)
        r = r / np.linalg.norm(r)
        u = np.cross(r, f)
        return r, u, f

    @property
    def aspect(self) -> float:
        return self.width / self.height

    @property
    def pixel_footprint(self) -> float:
        """World size of one pixel per unit of eye depth (pixels are square)."""
        return float(2 * np.tan(np.radians(self.fov) / 2) / self.height)

    def describe(self) -> dict:
        """The camera as plain JSON values: eye, target, up, fov (degrees), width, height,
        near, far, and its view and projection matrices (row-major 4×4 lists; OpenGL
        conventions, world → eye → clip) where near and far are set."""
        out: dict = {"eye": list(self.eye), "target": list(self.target), "up": list(self.up), "fov": self.fov,
                     "width": self.width, "height": self.height, "near": self.near, "far": self.far}
        if self.near is not None and self.far is not None:
            out["view"] = self.view_matrix().tolist()
            out["projection"] = self.projection_matrix().tolist()
        return out

    def view_matrix(self) -> np.ndarray:
        """(4,4) world → eye (gluLookAt)."""
        r, u, f = self.basis()
        e = np.asarray(self.eye)
        m = np.eye(4)
        m[0, :3], m[1, :3], m[2, :3] = r, u, -f
        m[:3, 3] = -m[:3, :3] @ e
        return m

    def projection_matrix(self) -> np.ndarray:
        """(4,4) eye → clip (gluPerspective); needs near/far (see fit_clip)."""
        if self.near is None or self.far is None:
            raise CameraError("camera has no near/far planes; call fit_clip first")
        return perspective(self.fov, self.aspect, self.near, self.far)

    def view_projection(self) -> np.ndarray:
        return self.projection_matrix() @ self.view_matrix()

    def with_size(self, width: int, height: int) -> Camera:
        return replace(self, width=width, height=height)

    def fit_clip(self, bounds: tuple[np.ndarray, np.ndarray]) -> Camera:
        """Copy with near/far enclosing the box `bounds` (min, max): far just past
        the farthest corner, near = far·NEAR_FRACTION or the box distance if larger."""
        lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
        _, _, f = self.basis()
        depth = (box_corners((lo, hi)) - np.asarray(self.eye)) @ f
        far = max(float(depth.max()), 1e-3) * 1.01 + 1e-6
        # Closest point of the box to the eye bounds the near plane from below.
        closest = np.clip(self.eye, lo, hi)
        dist = float(np.linalg.norm(closest - np.asarray(self.eye)))
        near = max(far * NEAR_FRACTION, 0.9 * dist * np.cos(np.radians(self.fov) / 2) / np.sqrt(1 + self.aspect**2))
        near = min(near, far * 0.5)
        return replace(self, near=near, far=far)

    # --- rays --------------------------------------------------------------------
    def pixel_directions(self) -> np.ndarray:
        """(H,W,3) float64 unit world-space ray directions through pixel centres."""
        r, u, f = self.basis()
        t = np.tan(np.radians(self.fov) / 2)
        xs = ((np.arange(self.width) + 0.5) / self.width * 2 - 1) * t * self.aspect
        ys = (1 - (np.arange(self.height) + 0.5) / self.height * 2) * t
        d = f + xs[None, :, None] * r + ys[:, None, None] * u
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def directions_at(self, pixels: np.ndarray) -> np.ndarray:
        """(N,3) float64 unit directions through the centres of integer pixels
        (N,2) = (x, y), row 0 at the top; equal to pixel_directions()[y, x]."""
        px = np.asarray(pixels, np.float64).reshape(-1, 2)
        r, u, f = self.basis()
        t = np.tan(np.radians(self.fov) / 2)
        xs = ((px[:, 0] + 0.5) / self.width * 2 - 1) * t * self.aspect
        ys = (1 - (px[:, 1] + 0.5) / self.height * 2) * t
        d = f + xs[:, None] * r + ys[:, None] * u
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (...,3) → (pixel xy (...,2) float64 with row 0 at the top,
        eye-space depth (...,) positive in front of the camera)."""
        p = np.asarray(points, dtype=np.float64)
        r, u, f = self.basis()
        d = p - np.asarray(self.eye)
        z = d @ f
        t = np.tan(np.radians(self.fov) / 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            x = (d @ r) / (z * t * self.aspect)
            y = (d @ u) / (z * t)
        px = (x + 1) / 2 * self.width
        py = (1 - y) / 2 * self.height
        return np.stack([px, py], axis=-1), z


def perspective(fov_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    """(4,4) OpenGL perspective projection."""
    t = 1.0 / np.tan(np.radians(fov_deg) / 2)
    m = np.zeros((4, 4))
    m[0, 0] = t / aspect
    m[1, 1] = t
    m[2, 2] = (far + near) / (near - far)
    m[2, 3] = 2 * far * near / (near - far)
    m[3, 2] = -1.0
    return m


def box_corners(bounds: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """(8,3) float64 corners of the box (min, max)."""
    lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
    return np.array(list(itertools.product(*zip(lo, hi, strict=True))))


def orbit_direction(azimuth: float, elevation: float) -> np.ndarray:
    """(3,) unit vector from a target toward an eye at (azimuth, elevation) degrees
    (azimuth 0 = +Z, 90 = +X; elevation toward +Y)."""
    a, e = np.radians(azimuth), np.radians(elevation)
    return np.array([np.cos(e) * np.sin(a), np.sin(e), np.cos(e) * np.cos(a)])


def framing_distance(bounds: tuple[np.ndarray, np.ndarray], azimuth: float, elevation: float,
                     fov: float) -> float:
    """The least `distance` of `look_at_scene` (in box diagonals) at which every
    corner of the box lies inside a square image of `fov` degrees (so in any image at
    least as wide as tall): per corner q (from the centre), t ≥ q·w + max(|q·r|, |q·u|) /
    tan(fov/2), with w the unit direction to the eye and r, u the image axes."""
    lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
    diag = float(np.linalg.norm(hi - lo)) or 1.0
    w = orbit_direction(azimuth, elevation)
    r = np.cross(-w, (0.0, 1.0, 0.0))
    r /= np.linalg.norm(r)
    u = np.cross(r, -w)
    q = box_corners(bounds) - (lo + hi) / 2
    t = q @ w + np.maximum(np.abs(q @ r), np.abs(q @ u)) / np.tan(np.radians(fov) / 2)
    return float(t.max()) / diag


def look_at_scene(bounds: tuple[np.ndarray, np.ndarray], azimuth: float = 35.0, elevation: float = 25.0,
                  distance: float = 1.6, fov: float = 45.0, width: int = 512, height: int = 512,
                  target: Sequence[float] | None = None, up: Sequence[float] = (0.0, 1.0, 0.0)) -> Camera:
    """A camera looking at `target` (default: the box centre) from (azimuth, elevation)
    degrees at `distance` × the box diagonal; clip planes fitted to the box."""
    lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
    c = (lo + hi) / 2 if target is None else np.asarray(target, dtype=np.float64)
    diag = float(np.linalg.norm(hi - lo)) or 1.0
    eye = c + distance * diag * orbit_direction(azimuth, elevation)
    return Camera(tuple(eye), tuple(c), tuple(up), fov, width, height).fit_clip((lo, hi))


def orbit_path(bounds: tuple[np.ndarray, np.ndarray], frames: int, elevation: float = 25.0,
               distance: float = 1.4, turns: float = 1.0, seed: int = 0, jitter: float = 0.0,
               fov: float = 45.0, width: int = 512, height: int = 512) -> list[Camera]:
    """`frames` cameras orbiting the box centre; a seeded jitter (degrees) on
    elevation makes paths differ reproducibly."""
    rng = np.random.default_rng(seed)
    start = rng.uniform(0, 360)
    cams = []
    for i in range(frames):
        az = start + 360.0 * turns * i / max(frames, 1)
        el = elevation + (rng.uniform(-jitter, jitter) if jitter else 0.0)
        cams.append(look_at_scene(bounds, az, el, distance, fov, width, height))
    return cams


def flythrough_path(bounds: tuple[np.ndarray, np.ndarray], frames: int, seed: int = 0, n_keys: int = 5,
                    fov: float = 55.0, width: int = 512, height: int = 512) -> list[Camera]:
    """A smooth seeded path through the box: Catmull-Rom through `n_keys` random
    key positions inside the box's upper half, always looking at the box centre
    region ahead of the camera."""
    lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
    rng = np.random.default_rng(seed)
    ext = hi - lo
    keys = lo + ext * rng.uniform([0.1, 0.45, 0.1], [0.9, 0.9, 0.9], size=(n_keys, 3))
    look = lo + ext * rng.uniform([0.3, 0.1, 0.3], [0.7, 0.4, 0.7], size=(n_keys, 3))

    def spline(p: np.ndarray, t: float) -> np.ndarray:
        n = len(p)
        s = t * (n - 1)
        i = min(int(s), n - 2)
        u = s - i
        p0, p1, p2, p3 = p[max(i - 1, 0)], p[i], p[i + 1], p[min(i + 2, n - 1)]
        return 0.5 * ((2 * p1) + (-p0 + p2) * u + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u**2
                      + (-p0 + 3 * p1 - 3 * p2 + p3) * u**3)

    cams = []
    for k in range(frames):
        t = k / max(frames - 1, 1)
        eye, tgt = spline(keys, t), spline(look, t)
        cams.append(Camera(tuple(eye), tuple(tgt), (0.0, 1.0, 0.0), fov, width, height).fit_clip((lo, hi)))
    return cams


# --- camera steps ---------------------------------------------------------------------

def _rotation(axis: Sequence[float], degrees: float) -> np.ndarray:
    """(3,3) right-handed rotation by `degrees` about `axis` (Rodrigues)."""
    k = np.asarray(axis, np.float64)
    if not np.linalg.norm(k) > 0:
        raise ValueError(f"a rotation needs a nonzero axis, got {tuple(k)}")
    k = k / np.linalg.norm(k)
    a = np.radians(degrees)
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(a) * kx + (1 - np.cos(a)) * kx @ kx


def rotated(camera: Camera, degrees: float, axis: Sequence[float]) -> Camera:
    """The camera turned rigidly about its eye by `degrees` about the world-space
    `axis` (right-handed): the eye stays, the target keeps its distance, the up vector
    becomes the camera's own up (orthogonal to the view) turned along, so the image
    turns without any other change. near/far are dropped (fit_clip the new view)."""
    rot = _rotation(axis, degrees)
    _, u, _ = camera.basis()
    eye = np.asarray(camera.eye)
    return replace(camera, target=tuple(eye + rot @ (np.asarray(camera.target) - eye)), up=tuple(rot @ u),
                   near=None, far=None)


def turned(camera: Camera, degrees: float) -> Camera:
    """The view direction turned by exactly `degrees` about the camera's up vector
    (positive: to the left), without roll (`rotated`)."""
    return rotated(camera, degrees, camera.basis()[1])


def rolled(camera: Camera, degrees: float) -> Camera:
    """The camera rolled by `degrees` about its view direction (right-handed about
    the forward vector: positive turns the up vector toward the right one); the view
    direction and eye stay (`rotated`)."""
    return rotated(camera, degrees, camera.basis()[2])


def moved(camera: Camera, fraction: float, direction: Sequence[float]) -> Camera:
    """The eye and target translated by `fraction` of the eye's distance to the
    target along the world-space `direction` (normalised): the view direction and the
    field of view stay. near/far are dropped."""
    d = np.asarray(direction, np.float64)
    if not np.linalg.norm(d) > 0:
        raise ValueError(f"a move needs a nonzero direction, got {tuple(d)}")
    shift = fraction * float(np.linalg.norm(np.subtract(camera.target, camera.eye))) * d / np.linalg.norm(d)
    return replace(camera, eye=tuple(np.asarray(camera.eye) + shift),
                   target=tuple(np.asarray(camera.target) + shift), near=None, far=None)


def zoomed(camera: Camera, factor: float) -> Camera:
    """The camera with tan(fov/2) multiplied by `factor` (> 1 widens the view: zoom
    out); near/far are dropped."""
    fov = 2 * np.degrees(np.arctan(factor * np.tan(np.radians(camera.fov) / 2)))
    return replace(camera, fov=float(fov), near=None, far=None)


@dataclass(frozen=True)
class CameraStep:
    """How far camera `b` is from `a` (`camera_step`): turn_deg, the angle between
    their view directions; move, the eye's displacement over a's distance to its
    target; zoom, b's tan(fov/2) over a's; roll_deg, the signed rotation about b's
    view direction left after turning a's frame onto b's view by the least rotation
    (in (-180, 180])."""

    turn_deg: float
    move: float
    zoom: float
    roll_deg: float


def camera_step(a: Camera, b: Camera) -> CameraStep:
    """The step from camera `a` to camera `b` (CameraStep)."""
    _, ua, fa = a.basis()
    _, ub, fb = b.basis()
    cos = float(np.clip(np.dot(fa, fb), -1.0, 1.0))
    axis = np.cross(fa, fb)
    turn = float(np.degrees(np.arccos(cos)))
    u = _rotation(axis, turn) @ ua if np.linalg.norm(axis) > 1e-12 else ua
    roll = float(np.degrees(np.arctan2(np.dot(fb, np.cross(u, ub)), np.dot(u, ub))))
    roll = 180.0 if roll <= -180.0 else roll  # (-180, 180]
    reach = float(np.linalg.norm(np.subtract(a.target, a.eye)))
    move = float(np.linalg.norm(np.subtract(b.eye, a.eye))) / reach
    zoom = float(np.tan(np.radians(b.fov) / 2) / np.tan(np.radians(a.fov) / 2))
    return CameraStep(turn, move, zoom, roll)

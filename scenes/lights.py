"""Area-light setups for soft shadows (thesis §3.3–3.4, Alg. 5), shared by the GL
passes, the Embree reference and the benchmark so that all three use the same
light, the same light-sample positions and the same light cameras (no GL, no Embree).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from scenes.camera import Camera, box_corners
from scenes.model import AreaLight


def default_area_light(bounds: tuple[np.ndarray, np.ndarray], sun: tuple[float, float, float],
                       size: float = 1.0, distance: float = 1.5) -> AreaLight:
    """A square area light facing the scene (§3.4.2: "the light's diagonal equals
    the scene's bounding-box diagonal" at size = 1; Table 10 scales it by `size`).

    Its centre sits `distance` × the box diagonal from the box centre along the
    unit direction `sun` (toward the light); its edges u, v are orthogonal to `sun`,
    each of length size·diag/√2, so the rectangle's diagonal is size·diag."""
    lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
    c = (lo + hi) / 2
    diag = float(np.linalg.norm(hi - lo)) or 1.0
    n = np.asarray(sun, dtype=np.float64)
    n = n / np.linalg.norm(n)
    helper = np.array([0.0, 0.0, 1.0]) if abs(n[1]) > 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(helper, n)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    edge = size * diag / np.sqrt(2.0)
    return AreaLight(tuple(c + distance * diag * n), tuple(u * edge), tuple(v * edge))


#: Least sine of the angle between a light's edges u and v: below it the rectangle
#: is a segment (parallel within 1e-6 rad), with no normal to aim its cameras by.
MIN_LIGHT_SINE = 1e-6


def _unit(x: np.ndarray) -> np.ndarray:
    """x/|x|, with x first scaled by its largest component, so that its length does not
    under- or overflow (edges of 1e-170 or 1e300 world units)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        a = np.asarray(x, np.float64) / np.abs(x).max()
        return a / np.linalg.norm(a)


def _unit_cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """u/|u| × v/|v| (`_unit`)."""
    return np.cross(_unit(u), _unit(v))


def light_sine(u: Sequence[float], v: Sequence[float]) -> float:
    """Sine of the angle between edges u and v (0 where one is zero or not finite)."""
    s = float(np.linalg.norm(_unit_cross(np.asarray(u), np.asarray(v))))
    return s if np.isfinite(s) else 0.0


def light_normal(light: AreaLight) -> np.ndarray:
    """(3,) unit normal of the light rectangle, pointing away from the lit side
    (u × v; `default_area_light` makes it point from the scene toward the light).
    Raises ValueError where u and v are zero or parallel (sine < MIN_LIGHT_SINE)."""
    if light_sine(light.u, light.v) < MIN_LIGHT_SINE:
        raise ValueError("light u and v must be non-zero and not parallel")
    n = _unit_cross(np.asarray(light.u), np.asarray(light.v))
    return n / np.linalg.norm(n)


#: Farthest a light's centre may lie from the scene box's centre, and longest either of
#: its edges may be, in box diagonals, for the shadow maps and depth images of Alg. 5
#: (`light_reach_problem`): they render in float32, and their error against the Embree
#: truth grows with the distance, until (within 10⁶ diagonals) the shadows are gone:
#: bench/results/shadow_light_reach.md.
MAX_LIGHT_REACH = 1000.0


def light_reach_problem(light: AreaLight, bounds: tuple[np.ndarray, np.ndarray]) -> str | None:
    """Why `light` is too far from or too large for the box `bounds` for its shadow maps
    and depth images (more than MAX_LIGHT_REACH box diagonals), or None."""
    lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
    diag = float(np.linalg.norm(hi - lo)) or 1.0
    far = float(np.linalg.norm(np.asarray(light.center, np.float64) - (lo + hi) / 2)) / diag
    edge = max(float(np.linalg.norm(np.asarray(e, np.float64))) for e in (light.u, light.v)) / diag
    if not far <= MAX_LIGHT_REACH:
        return (f"the light's centre lies {far:.3g} scene diagonals from the scene's centre "
                f"(at most {MAX_LIGHT_REACH:g})")
    if not edge <= MAX_LIGHT_REACH:
        return f"a light edge is {edge:.3g} scene diagonals long (at most {MAX_LIGHT_REACH:g})"
    return None


def light_diagonal(light: AreaLight) -> float:
    """Length of the light rectangle's diagonal |u + v| (world units)."""
    return float(np.linalg.norm(np.asarray(light.u, np.float64) + np.asarray(light.v, np.float64)))


#: Where a light camera looks (`light_camera`): "light" along the light's −normal
#: (every shadow map, so all k² maps share one orientation), "scene" at the centre
#: of the scene box (the reference images of Alg. 5, see `reference_cameras`).
AIMS: tuple[str, ...] = ("light", "scene")


def light_camera(light: AreaLight, eye: np.ndarray, bounds: tuple[np.ndarray, np.ndarray],
                 resolution: int, margin: float = 1.02, aim: str = "light") -> Camera:
    """Square pinhole camera at `eye` (a light sample or corner) with the vertical
    fov just wide enough (× margin) to see the whole box `bounds`; near/far fitted
    to the box. aim = "light": looking along the light's −normal (the shadow maps);
    "scene": looking at the box centre (the reference images from the light's
    corners / centre, `reference_cameras`). Either way the light's v edge is the
    image's up; the box must lie in front of the light's plane, the light within
    MAX_LIGHT_REACH of it (ValueError)."""
    if aim not in AIMS:
        raise ValueError(f"aim must be one of {AIMS}, got {aim!r}")
    lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
    problem = light_reach_problem(light, (lo, hi))
    if problem is not None:
        raise ValueError(problem)
    e = np.asarray(eye, dtype=np.float64)
    d = box_corners((lo, hi)) - e
    fwd = -light_normal(light)
    if np.any(d @ fwd <= 0):
        raise ValueError("the scene box is not entirely in front of the light")
    up = np.asarray(light.v, np.float64)
    if aim == "scene":
        centre = (lo + hi) / 2 - e
        centre = centre / np.linalg.norm(centre)
        if np.all(d @ centre > 0):  # else (a light grazing the box) the box is not in front of that axis
            fwd = centre
            up = _unit(up)
            up = up - fwd * (up @ fwd)  # v made orthogonal to the view axis (it is for "light")
    up = _unit(up)
    right = np.cross(fwd, up)
    z = d @ fwd
    t = max(float(np.max(np.abs(d @ right) / z)), float(np.max(np.abs(d @ up) / z))) * margin
    fov = float(np.degrees(2 * np.arctan(t)))
    cam = Camera(tuple(e), tuple(e + fwd), tuple(up), fov, resolution, resolution)
    return cam.fit_clip((lo, hi))


#: A shadow map looks along the light's axis (Alg. 5) unless that needs a wider fov than
#: this (degrees): a light much larger than the scene, or near it, whose off-axis samples
#: see the box far off the axis; such a sample's map looks at the box instead.
AXIS_FOV_MAX = 160.0

#: Widest shadow map (degrees): past it a map's texels at the scene grow so large (its
#: texel per unit depth is 2·tan(fov/2)/resolution) that shadows come out wrong; such a
#: light (e.g. grazing the top of the scene box) is refused for the shadow-map methods.
#: Where the errors jump is measured in bench/results/shadow_light_reach.md.
SHADOW_MAP_FOV_MAX = 179.0


def shadow_map_camera(light: AreaLight, sample: np.ndarray, bounds: tuple[np.ndarray, np.ndarray],
                      resolution: int) -> Camera:
    """The camera of light sample `sample`'s shadow map (Alg. 5): `light_camera` along
    the light's axis, or aimed at the box where that is narrower and the axis needs more
    than AXIS_FOV_MAX. ValueError when the box is not in front of the light or the map
    would need more than SHADOW_MAP_FOV_MAX."""
    cam = light_camera(light, sample, bounds, resolution)
    if cam.fov > AXIS_FOV_MAX:
        aimed = light_camera(light, sample, bounds, resolution, aim="scene")
        cam = aimed if aimed.fov < cam.fov else cam
    if cam.fov > SHADOW_MAP_FOV_MAX:
        raise ValueError(f"a light sample sees the scene box across {cam.fov:.1f}° (a shadow map covers at most "
                         f"{SHADOW_MAP_FOV_MAX:g}°): the light grazes the box")
    return cam


#: Depth-peeling layers rendered from the light's centre (§3.4.2).
PEEL_LAYERS = 4


def reference_cameras(light: AreaLight, bounds: tuple[np.ndarray, np.ndarray], method: str,
                      resolution: int, aim: str = "scene") -> list[Camera]:
    """The reference viewpoints of Alg. 5 (§3.4.2): the light's 4 corners for
    non-redundant and conventional images, its centre for depth peeling; each a
    `light_camera` of resolution² seeing the whole box `bounds`.

    aim = "scene" (default): every camera looks at the box centre, so each image
    spends its resolution² pixels on the scene (§3.4.2's "reference images
    1024²"). aim = "light" (the rule before): every camera looks along the light's
    −normal like the shadow maps; from a corner the box then sits off the axis and
    the fov must grow to hold it, so the scene covers a small share of a corner
    image's pixels (measured in bench/results/soft_shadows.md). The centre camera
    is the same either way (the default light's axis passes through the box centre)."""
    eyes = [np.asarray(light.center)] if method == "peeling" else list(light.corners())
    return [light_camera(light, e, bounds, resolution, aim=aim) for e in eyes]

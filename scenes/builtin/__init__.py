"""Deterministic built-in procedural scenes (DESIGN.md, "Test scenes").

The first four stand in for the thesis's Chapter 2/3 test scenes (§2.3.3 with Tables
2–7, §3.4 with Tables 8–11: bird's nest 67k, grass 56k, city 50k and tree 113k
triangles); living_room (280k, about half of it reflective) and bathroom (90k, about half reflective) stand in for the
Chapter 4 reflection scenes (§4.7); cornell and mirror are small scenes for tests.

``make_builtin(name, detail, seed)`` scales the triangle count roughly linearly with
``detail`` (detail 60 gives ≥ 3 M triangles for the large scenes). Same arguments give
bit-identical arrays: all randomness comes from one ``numpy.random.Generator`` seeded
with (seed, crc32(name)). Units are metres, +Y up, the ground at y = 0.
"""

from __future__ import annotations

import math
import numbers
import zlib
from functools import cache
from types import ModuleType

import numpy as np

from scenes.builtin import bathroom, city, cornell, grass, living_room, mirror, nest, tree
from scenes.model import Scene

BUILTIN_NAMES: tuple[str, ...] = ("nest", "grass", "city", "tree", "living_room", "bathroom", "cornell", "mirror")

#: Allowed range of the detail factor (detail 1 = the thesis's scene sizes).
MIN_DETAIL = 0.01
MAX_DETAIL = 60.0

_MODULES: dict[str, ModuleType] = {
    "nest": nest, "grass": grass, "city": city, "tree": tree, "living_room": living_room,
    "bathroom": bathroom, "cornell": cornell, "mirror": mirror,
}

__all__ = ["BUILTIN_NAMES", "MAX_DETAIL", "MIN_DETAIL", "builtin_info", "builtin_rng", "estimate_triangles",
           "make_builtin"]


def _check_name(name: object) -> ModuleType:
    if not isinstance(name, str) or name not in _MODULES:
        raise ValueError(f"unknown built-in scene {name!r}; valid names: {', '.join(BUILTIN_NAMES)}")
    return _MODULES[name]


def _check_detail(detail: object) -> float:
    if isinstance(detail, bool) or not isinstance(detail, numbers.Real):
        raise ValueError(f"detail must be a real number, got {detail!r}")
    d = float(detail)
    if not math.isfinite(d):
        raise ValueError(f"detail must be finite, got {detail!r}")
    if not (MIN_DETAIL <= d <= MAX_DETAIL):
        raise ValueError(f"detail must be in [{MIN_DETAIL}, {MAX_DETAIL}], got {d!r}")
    return d


def _check_seed(seed: object) -> int:
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral):
        raise ValueError(f"seed must be an integer, got {seed!r}")
    s = int(seed)
    if not (0 <= s < 2**63):
        raise ValueError(f"seed must be in [0, 2**63), got {s}")
    return s


def builtin_rng(name: str, seed: int = 0) -> np.random.Generator:
    """The generator ``make_builtin(name, …, seed)`` builds its scene with (seeded
    with (seed, crc32(name))); for variants of a scene's own build options."""
    return np.random.default_rng([_check_seed(seed), zlib.crc32(name.encode("utf-8"))])


def make_builtin(name: str, detail: float = 1.0, seed: int = 0) -> Scene:
    """Build the built-in scene ``name`` (one of ``BUILTIN_NAMES``).

    detail in [0.01, 60] scales the triangle count roughly linearly; seed ≥ 0 selects
    the random variation (cornell and mirror do not use it). Raises ValueError naming
    the problem for an unknown name, a bad detail or a bad seed.
    """
    module = _check_name(name)
    d = _check_detail(detail)
    scene = module.build(d, builtin_rng(name, seed))
    scene.name = name
    return scene


def estimate_triangles(name: str, detail: float) -> int:
    """Approximate triangle count of ``make_builtin(name, detail)`` without building it
    (a closed-form count of the scene's parts; cheap)."""
    module = _check_name(name)
    return int(module.estimate_triangles(_check_detail(detail)))


@cache
def _default_triangles(name: str) -> int:
    return make_builtin(name, 1.0, 0).n_triangles


def builtin_info() -> list[dict]:
    """[{"name", "description", "default_triangles"}] for every built-in, in
    ``BUILTIN_NAMES`` order; default_triangles is the real count at detail 1 (the
    scenes are built once and the counts cached)."""
    return [
        {"name": n, "description": _MODULES[n].DESCRIPTION, "default_triangles": _default_triangles(n)}
        for n in BUILTIN_NAMES
    ]

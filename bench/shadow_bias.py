"""The shadow maps' bias, chosen by the exact truth (soft-shadow benchmark, part `bias`).

Alg. 5's shadow maps call a receiver point lit or shadowed with a bias
(`gl_passes.shadows.ShadowSettings`: a normal offset, a constant depth bias and a
slope-scaled one, all in shadow-map texels). The geometry shadow maps are the
thesis's truth for Table 8, and the same maps judge every reconstruction, so the
bias is a property of the shadow maps, not of what they hold: it is chosen here
against the independent truth, the original geometry only.

Per scene (k = --sweep-k): the geometry shadow maps' §3.4.2 errors against the exact
Embree truth for every setting of a grid (NORMAL_OFFSETS × DEPTH_BIASES ×
DEPTH_SLOPES), and for each setting the angles at which a plane tilted from the
light gets a wrong decision (`grazing_wrong`: acne). The choice (`choose`): among
the settings without acne, the one whose worst scene is nearest that scene's best
(the least maximum over scenes of mean visibility error / the scene's lowest). The
previous default (PREVIOUS) and the current default are measured again at k = --k.
"""

from __future__ import annotations

import argparse
import itertools
from dataclasses import asdict, replace
from typing import Any

import numpy as np

from bench.common import md_table, progress
from bench.shadow_stage import Stage, unpack_visibility
from gl_passes.context import GLContext
from gl_passes.mesh_gpu import MeshGPU
from gl_passes.shadows import ShadowSettings, SoftShadowPass
from reference.shadows import light_visibility, shadow_errors
from scenes.lights import default_area_light
from scenes.model import AreaLight

#: The grid of the sweep, in shadow-map texels (depth slope: texels per unit tan t).
NORMAL_OFFSETS = (0.0, 0.125, 0.25, 0.375, 0.5, 0.75)
DEPTH_BIASES = (0.5, 1.0, 1.5, 2.0)
DEPTH_SLOPES = (0.0, 0.25, 0.5, 0.75, 1.0)
#: The bias before this part chose one (normal offset 0.75 texels, depth bias 1 texel).
PREVIOUS = ShadowSettings(normal_offset=0.75, depth_bias=1.0, depth_slope=0.0)
#: Tilts of the acne check's plane from facing the light, in degrees.
GRAZING_DEGREES = (0, 60, 80, 88)
#: The acne check's light samples per side, shadow-map resolution and receivers per side.
GRAZING_K, GRAZING_RES, GRAZING_POINTS = 4, 128, 64


def setting_key(s: ShadowSettings) -> str:
    """'normal offset/depth bias/depth slope' of a setting (the JSON's keys)."""
    return f"{s.normal_offset:g}/{s.depth_bias:g}/{s.depth_slope:g}"


def shadow_bias_of(s: ShadowSettings) -> dict[str, float]:
    """The bias fields of a setting (saved with every part's arguments)."""
    return {"normal_offset": s.normal_offset, "depth_bias": s.depth_bias, "depth_slope": s.depth_slope}


def grid() -> list[ShadowSettings]:
    return [ShadowSettings(normal_offset=a, depth_bias=b, depth_slope=c)
            for a, b, c in itertools.product(NORMAL_OFFSETS, DEPTH_BIASES, DEPTH_SLOPES)]


def grazing_plane(degrees: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, AreaLight, np.ndarray]:
    """A 4 × 4 square through the origin, tilted `degrees` from facing a small area
    light 4 above it, about a diagonal of the shadow maps (the worst case for texel
    quantisation): (quad corners (4,3), receivers (P,P,3) and their normals float32 on
    its middle 3.6 × 3.6, the light, and which of the receivers' GRAZING_K² light
    samples lie in front of the plane, (P·P, GRAZING_K²) bool: all of them are lit)."""
    a = np.radians(degrees)
    h, up = np.array([1.0, 0, 1.0]) / np.sqrt(2), np.array([0, 1.0, 0])
    normal = np.sin(a) * h + np.cos(a) * up
    t1 = np.cos(a) * h - np.sin(a) * up
    t2 = np.cross(normal, t1)
    quad = np.array([-2 * t1 - 2 * t2, 2 * t1 - 2 * t2, 2 * t1 + 2 * t2, -2 * t1 + 2 * t2])
    u = (np.arange(GRAZING_POINTS) + 0.5) / GRAZING_POINTS * 3.6 - 1.8
    pa, pb = np.meshgrid(u, u)
    points = (pa[..., None] * t1 + pb[..., None] * t2).astype(np.float32)
    normals = np.broadcast_to(normal, points.shape).astype(np.float32)
    light = AreaLight((0, 4, 0), (0.4, 0, 0), (0, 0, -0.4))
    front = (light.samples(GRAZING_K)[None] - points.reshape(-1, 1, 3).astype(np.float64)) @ normal > 0
    return quad, points, normals, light, front


def grazing_lit(gl: GLContext, settings: ShadowSettings, degrees: float) -> tuple[np.ndarray, np.ndarray]:
    """(what the shadow maps of `settings`' bias decide for the grazing plane's
    receivers, what is true), both (P·P, GRAZING_K²) bool."""
    quad, points, normals, light, front = grazing_plane(degrees)
    s = replace(settings, samples=GRAZING_K, shadow_map_resolution=GRAZING_RES)
    n = GRAZING_POINTS
    with MeshGPU.from_arrays(gl, quad, [[0, 1, 2], [0, 2, 3]]) as mesh, SoftShadowPass(gl, s) as sp:
        r = sp.visibility([mesh], (quad.min(0) - 0.01, quad.max(0) + 0.01), points, normals,
                          np.ones((n, n), bool), light)
    return unpack_visibility(r.bits.reshape(n * n, -1), GRAZING_K**2), front


def grazing_wrong(gl: GLContext, settings: ShadowSettings) -> list[int]:
    """The GRAZING_DEGREES at which the grazing plane gets a wrong decision."""
    return [d for d in GRAZING_DEGREES if not np.array_equal(*grazing_lit(gl, settings, d))]


def part_bias(gl: GLContext, st: Stage, args: argparse.Namespace) -> dict[str, Any]:
    """The geometry shadow maps against the exact truth over the grid (k = sweep_k),
    with each setting's acne angles; PREVIOUS and the default again at k = args.k."""
    bounds = st.scene.bounds
    light = default_area_light(bounds, st.scene.sun_direction)

    def measure(settings: ShadowSettings, k: int, exact: np.ndarray) -> dict[str, float]:
        s = replace(settings, samples=k, shadow_map_resolution=args.shadow_res)
        with SoftShadowPass(gl, s) as sp:
            bits = sp.visibility([st.gpu], bounds, st.points, st.normals, st.mask, light).bits
        return asdict(shadow_errors(bits, exact, st.mask))

    exact = light_visibility(st.caster, st.points, st.normals, st.mask, light, args.sweep_k)
    sweep = {setting_key(s): {**measure(s, args.sweep_k, exact), "acne_degrees": grazing_wrong(gl, s)}
             for s in progress(grid(), args.progress, desc=f"{st.scene.name} bias", leave=False)}
    exact = light_visibility(st.caster, st.points, st.normals, st.mask, light, args.k)
    final = {setting_key(s): measure(s, args.k, exact) for s in (PREVIOUS, ShadowSettings())}
    return {"sweep_k": args.sweep_k, "k": args.k, "sweep": sweep, "final": final}


def worst_ratios(bias: dict[str, dict[str, Any]]) -> dict[str, float]:
    """Per setting measured on every scene of `bias` (scene → part_bias runs): the
    largest over scenes of its mean visibility error / that scene's lowest among them."""
    keys = set.intersection(*(set(r["sweep"]) for r in bias.values()))
    best = {s: min(r["sweep"][key]["visibility_mean"] for key in keys) for s, r in bias.items()}
    return {key: max(r["sweep"][key]["visibility_mean"] / best[s] for s, r in bias.items()) for key in keys}


def choose(bias: dict[str, dict[str, Any]]) -> tuple[str, float] | None:
    """(key, worst ratio): among the settings without acne, the one of the least
    `worst_ratios`; None when no setting is free of acne."""
    worst = worst_ratios(bias)
    first = next(iter(bias.values()))["sweep"]
    clean = [key for key in sorted(worst) if not first[key]["acne_degrees"]]
    if not clean:
        return None
    key = min(clean, key=lambda key: (worst[key], key))
    return key, worst[key]


def _iv(e: dict[str, Any]) -> str:
    return f"{e['intensity_mean']:.3f} · {e['visibility_mean']:.3f}"


def bias_report(part: dict[str, dict[str, Any]]) -> list[str]:
    """Markdown from the part's saved runs (scene → {"runs": part_bias's, ...}): the
    sweep's best settings, with and without acne, the previous default and the
    default; both again at k = --k; whether the default is the choice."""
    if not part:
        return []
    bias = {scene: saved["runs"] for scene, saved in part.items()}
    scenes = sorted(bias)
    first = bias[scenes[0]]
    picked = choose(bias)
    worst = worst_ratios(bias)
    default, previous = setting_key(ShadowSettings()), setting_key(PREVIOUS)
    keys = sorted(worst, key=lambda key: (worst[key], key))
    clean = [key for key in keys if not first["sweep"][key]["acne_degrees"]]
    shown = [key for key in dict.fromkeys([*clean[:5], *keys[:3], previous, default]) if key in worst]

    def row(key: str) -> list[str]:
        no, db, ds = key.split("/")
        acne = ", ".join(f"{d}°" for d in first["sweep"][key]["acne_degrees"]) or "none"
        label = " (previous)" if key == previous else " (default)" if key == default else ""
        return [f"{no} / {db} / {ds}{label}", acne, *(_iv(bias[s]["sweep"][key]) for s in scenes),
                f"{worst[key]:.2f}"]

    lines = ["## Shadow-map bias against the exact truth (geometry shadow maps)", "",
             f"`bench.shadow_bias`: the geometry shadow maps' mean intensity · visibility error against the "
             f"exact Embree truth (k = {first['sweep_k']}) for {len(keys)} settings (normal offset / depth bias "
             "in texels / depth slope in texels per unit tan t, t the angle between the receiver's normal and "
             "the light sample); acne: the tilts of a plane at which it gets a wrong decision (of "
             f"{', '.join(f'{d}°' for d in GRAZING_DEGREES)}); worst: the largest ratio over the scenes of the "
             "visibility error to the scene's lowest in the grid. Rows: the five best settings without acne, the "
             "three best of all, the previous default and the default.", "",
             md_table(["setting", "acne", *scenes, "worst"], [row(key) for key in shown]), ""]
    finals = [bias[s]["final"] for s in scenes]
    again = [key for key in dict.fromkeys([previous, default]) if all(key in f for f in finals)]
    lines += [f"The previous default and the default again at k = {first['k']} (against the exact truth):", "",
              md_table(["setting", *scenes], [[key, *(_iv(f[key]) for f in finals)] for key in again]), ""]
    if picked is None:
        lines.append("No setting of the grid is free of acne; the default is not chosen by this part.")
    elif picked[0] == default:
        before = f" (the previous default: {(worst[previous] - 1) * 100:.0f} %)" if previous in worst else ""
        lines.append(f"The default `ShadowSettings` bias ({default}) is the choice: without acne, every scene within "
                     f"{(picked[1] - 1) * 100:.0f} % of its lowest visibility error in the grid{before}.")
    else:
        lines.append(f"The default `ShadowSettings` bias ({default}) is NOT the choice of this sweep ({picked[0]}, "
                     f"worst {picked[1]:.2f}).")
    return [*lines, ""]

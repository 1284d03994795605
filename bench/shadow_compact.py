"""The compact reconstruction's error bound: triangles, shadow error and Fig. 20's
crossover (soft-shadow benchmark, part `compact`, and the bounds Fig. 20 times).

The compact reconstruction simplifies each image's hybrid mesh with an absolute
error bound (`ReconstructionSettings.compact_error`, measured in the capturing
image: `gl_passes.reconstruction.image_space`). The issue asks for two things of it
at once: shadow maps cheaper than the original grass below 1 M triangles (Fig. 20),
and no more than +10 % mean visibility error over the hybrid reconstruction. Both
move with the bound, in opposite directions; this part measures the trade-off.

Per scene, at k = --k, against the geometry-shadow-map truth (the criterion's): NR
images at --ref-res, their hybrid reconstruction and the compact one at every bound
of BOUNDS, and at WORLD_BOUND in the measure before (`compact_measure="world"`:
world units, footprints at the median depth in every direction). Fig. 20
(`bench.soft_shadows.fig20_level`) times the compact meshes at every bound of BOUNDS
beside the default, so each bound has its crossover.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import asdict
from typing import Any

import numpy as np

from bench.common import md_table, progress
from bench.shadow_stage import Stage
from gl_passes.context import GLContext
from gl_passes.mesh_gpu import MeshGPU
from gl_passes.quad_splats import triangle_pieces
from gl_passes.reconstruction import ReconstructionSettings, reconstruct_set, render_set
from gl_passes.shadows import ShadowSettings, SoftShadowPass
from reference.shadows import shadow_errors
from scenes.lights import default_area_light, reference_cameras

#: Bounds of the sweep (`compact_error`, in the image's pixels; the default among them).
BOUNDS = (0.25, 0.4, 0.5, 0.6, 0.8)
#: The bound measured again in the world measure before (the default of then).
WORLD_BOUND = 0.4
#: Pieces of at most this many triangles (4 samples) count as small in `pieces`.
SMALL_PIECE = 8
#: The issue's limits: compact visibility error over the hybrid's, and Fig. 20's crossover.
MAX_GROWTH = 0.10
MAX_CROSSOVER = 1_000_000


def bound_key(bound: float) -> str:
    return f"{bound:g}"


def part_compact(gl: GLContext, st: Stage, args: argparse.Namespace) -> dict[str, Any]:
    """NR images' hybrid reconstruction and the compact one at every bound (and the
    world measure at WORLD_BOUND): triangles and errors against the geometry truth."""
    bounds = st.scene.bounds
    light = default_area_light(bounds, st.scene.sun_direction)
    settings = {"hybrid": ReconstructionSettings(),
                **{bound_key(b): ReconstructionSettings(kind="compact", compact_error=b) for b in BOUNDS},
                f"world {bound_key(WORLD_BOUND)}": ReconstructionSettings(kind="compact", compact_error=WORLD_BOUND,
                                                                        compact_measure="world")}
    out: dict[str, Any] = {"k": args.k, "runs": {}}
    with SoftShadowPass(gl, ShadowSettings(samples=args.k, shadow_map_resolution=args.shadow_res)) as sp:
        geo = sp.visibility([st.gpu], bounds, st.points, st.normals, st.mask, light).bits
        sampled = render_set(gl, st.gpu, "non_redundant",
                             reference_cameras(light, bounds, "non_redundant", args.ref_res))
        for name, s in progress(settings.items(), args.progress, desc=f"{st.scene.name} compact", leave=False):
            meshes = reconstruct_set(gl, sampled, s)
            try:
                bits = sp.visibility(meshes, bounds, st.points, st.normals, st.mask, light).bits
                out["runs"][name] = {"triangles": sum(m.n_triangles for m in meshes),
                                     "vs_geometry": asdict(shadow_errors(bits, geo, st.mask))}
            finally:
                for m in meshes:
                    m.release()
    return out


def pieces(meshes: Sequence[MeshGPU]) -> dict[str, int]:
    """Connected pieces of `meshes` (triangles joined through shared vertex indices)
    and the triangles in pieces of at most SMALL_PIECE triangles: what a simplifier
    that keeps the topology cannot merge."""
    n_pieces = small = 0
    for m in meshes:
        _, tri = m.read_records()
        size = np.bincount(triangle_pieces(tri))
        size = size[size > 0]
        n_pieces += len(size)
        small += int(size[size <= SMALL_PIECE].sum())
    return {"pieces": n_pieces, "small_piece_triangles": small}


def growth(run: dict[str, Any], name: str) -> float:
    """Mean visibility error of setting `name` over the hybrid's, − 1."""
    vis = {n: run["runs"][n]["vs_geometry"]["visibility_mean"] for n in (name, "hybrid")}
    return vis[name] / vis["hybrid"] - 1


def crossover_of(points: Sequence[tuple[float, float, float]]) -> float | None:
    """Original triangle count where the original's time per shadow map reaches the
    reconstruction's, from (original triangles, original seconds, reconstruction
    seconds) in rising order (linear interpolation between measured levels); None
    if it never does."""
    prev = None
    for tri, geometry, reconstruction in points:
        diff = geometry - reconstruction
        if diff >= 0:
            if prev is None:
                return float(tri)
            (t0, d0), t1 = prev, tri
            return float(t0 + (t1 - t0) * (-d0) / (diff - d0))
        prev = (tri, diff)
    return None


def original_seconds(level: dict[str, Any], fastest: bool = False) -> float:
    """A Fig. 20 level's seconds per shadow map of the original geometry: drawn as
    triangles, or (fastest) the faster of that and the same with its small pieces as
    splats (levels that did not time the latter: as triangles)."""
    t = level["geometry_seconds_per_map"]
    return min(t, level.get("geometry_splats_seconds_per_map", t)) if fastest else t


def _timed(level: dict[str, Any], bound: float, default_bound: float) -> dict[str, Any] | None:
    """A Fig. 20 level's compact meshes at `bound` (triangles, seconds_per_map): its
    "compact" entry for the default bound; None when the level did not time it."""
    if bound == default_bound:
        return level["compact"]
    return level.get("compact_bounds", {}).get(bound_key(bound))


def bound_crossover(levels: list[dict[str, Any]], bound: float, default_bound: float) -> float | None:
    """Fig. 20's crossover of the compact reconstruction at `bound` against the
    original drawn the faster way (`original_seconds`; None when the levels did not
    time it, or it never crosses)."""
    timed = [_timed(lv, bound, default_bound) for lv in levels]
    if any(t is None for t in timed):
        return None
    return crossover_of([(lv["triangles"], original_seconds(lv, fastest=True), t["seconds_per_map"])
                         for lv, t in zip(levels, timed, strict=True)])


def compact_report(compact: dict[str, dict[str, Any]], levels: list[dict[str, Any]] | None,
                   default_bound: float) -> list[str]:
    """The report section from the saved parts (scene → {"args", "runs": what
    `part_compact` returned}) and Fig. 20's levels: per bound, the compact
    reconstruction's mean visibility error over the hybrid's per scene, its
    triangles on grass at Fig. 20's detail 20 and its Fig. 20 crossover."""
    if not compact:
        return []
    ref_res = next(iter(compact.values()))["args"]["ref_res"]
    compact = {s: saved["runs"] for s, saved in compact.items()}  # the part's runs, without its arguments
    scenes = list(compact)
    first = next(iter(compact.values()))
    detail = next((lv for lv in levels or [] if lv["detail"] == 20), None)
    rows, both = [], []
    for name in (n for n in first["runs"] if n != "hybrid"):
        world = name.startswith("world")
        cross = None if world or not levels else bound_crossover(levels, float(name), default_bound)
        timed = None if world or detail is None else _timed(detail, float(name), default_bound)
        worst = max(growth(compact[s], name) for s in scenes)
        label = name + (" (default)" if not world and float(name) == default_bound else "")
        rows.append([label, *(f"{compact[s]['runs'][name]['triangles']:,} · {100 * growth(compact[s], name):+.1f} %"
                              for s in scenes),
                     f"{100 * worst:+.1f} %", f"{timed['triangles']:,}" if timed else "—",
                     f"{cross:,.0f}" if cross is not None else "—"])
        if worst <= MAX_GROWTH and cross is not None and cross < MAX_CROSSOVER:
            both.append(label)
    hybrid = " · ".join(f"{s} {compact[s]['runs']['hybrid']['triangles']:,}" for s in scenes)
    return [f"## The compact reconstruction's error bound (NR images at {ref_res}², k = {first['k']}, against the "
            "geometry truth)", "",
            "Per bound (`compact_error`, pixels of the capturing image across it and footprints at the median "
            "depth along it; \"world\": the measure before, footprints at the median depth in every direction): "
            "triangles of the four images and the mean visibility error over the hybrid reconstruction's, per "
            "scene; the worst scene; grass's compact triangles at Fig. 20's detail 20 and Fig. 20's crossover "
            "against the faster of the original's two ways (both from the Fig. 20 run). "
            f"Hybrid triangles: {hybrid}.", "",
            md_table(["bound", *scenes, "worst", "grass detail 20", "Fig. 20 crossover (faster original)"], rows), "",
            f"Bounds within +{100 * MAX_GROWTH:.0f} % on every scene with a crossover below {MAX_CROSSOVER:,} "
            f"triangles on this machine: {', '.join(both) if both else 'none'}.{_pieces_sentence(detail)}", ""]


def _pieces_sentence(level: dict[str, Any] | None) -> str:
    """What a topology-keeping simplifier of grass at a Fig. 20 level cannot merge."""
    if level is None or "pieces" not in level.get("hybrid", {}):
        return ""
    h, c = level["hybrid"], level["compact"]
    return (f" On grass at detail {level['detail']:g} ({level['triangles']:,} triangles) the NR hybrid meshes are "
            f"{h['pieces']:,} separate pieces, {100 * h['small_piece_triangles'] / h['triangles']:.0f} % of their "
            f"triangles in pieces of at most {SMALL_PIECE // 2} samples (blade fragments a pixel or so wide, each "
            "seen apart from its neighbours); the compact meshes keep the pieces apart (edge collapses keep the "
            f"topology): {c['pieces']:,} pieces, {100 * c['small_piece_triangles'] / c['triangles']:.0f} % of "
            "their triangles in small ones."
            + (f" The shadow maps draw {100 * c['splat_triangles'] / c['triangles']:.0f} % of "
               f"the compact triangles as {c['splats']:,} splats (`gl_passes.quad_splats`)."
               if "splats" in c else ""))

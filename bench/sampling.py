"""Thesis Ch. 2 sampling benchmark: Tables 2-7 and Figs 13-15 on our scenes.

For each scene, the Fig. 8 rig (three reference views V0, V1, V2 around the
scene and the depth-peeling view at their centroid) samples the scene with
three methods: conventional depth images, non-redundant (NR) images (pixel
definition: GL, Alg. 3 in the fragment shader; visibility definition: Embree,
Alg. 2) and 3 depth-peeling layers. The §2.3.2 metrics
(`reference.sampling_metrics`) give:

* Table 2 / 5: redundant samples of conventional images; occluded samples and
  the useful share of them for NR and peeling (pixel / visibility definition).
* Table 4 / 6: available samples per intermediate view, average and minimum.
* Table 3: pictures of occluded (green) and useful (yellow) samples.
* Figs 13-15: redundant / occluded / useful fractions against resolution.
* Table 7: GL time of three images per method, side by side, median.

Run `python -m bench.sampling --help`; results go to bench/results/sampling.*.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from bench.common import (
    RESULTS_DIR,
    Stopwatch,
    load_named_scene,
    machine_info,
    machine_markdown,
    md_table,
    pct,
    progress,
    shared_model_path,
    time_side_by_side,
    write_json,
    write_text,
)
from bench.sampling_notes import criteria_notes, discussion, target_minutes_per_scene
from bench.sampling_report import (
    EARLIER_NOTE,
    METHODS,
    THESIS_T2,
    THESIS_T4,
    THESIS_T5,
    THESIS_T6,
    THESIS_T7,
    criteria_tables,
    ranking_table,
    timing_table,
    view_dependent_table,
    view_independent_table,
)
from reference import REVISION

DEFAULT_SCENES = ("nest", "grass", "city", "tree", "diorama")


# --- rig --------------------------------------------------------------------------

def content_bounds(scene) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the scene without objects named "ground": the object of interest,
    which the thesis's views frame (Fig. 9: the nest fills them); the whole
    scene when it has nothing else. (The grounds of the built-in nest and tree are
    modest discs ≈ 1.4 × the object's footprint; grass and city grounds are the
    patch / street grid the content covers.)"""
    objs = [o for o in scene.objects if o.name != "ground"] or scene.objects
    v = np.concatenate([o.vertices for o in objs]).astype(np.float64)
    return v.min(axis=0), v.max(axis=0)


def make_rig(scene, res: int, distance: float | None, spread: float = 20.0):
    """Fig. 8 rig framed on the scene's content (distance None: `scenes.rig.fit_distance`,
    the content's bounding sphere fills every view), clip planes fitted to the whole scene."""
    from scenes.rig import fig8_rig

    cams, peel = fig8_rig(content_bounds(scene), res, res, spread_deg=spread, distance=distance)
    return [c.fit_clip(scene.bounds) for c in cams], peel.fit_clip(scene.bounds)


# --- one scene ----------------------------------------------------------------------

def render_sets(gl, sg, rc, cams, peel_cam, layers: int = 3) -> dict[str, list]:
    """The four image sets of the benchmark at the cameras' resolution."""
    from gl_passes import depth_images as di
    from reference.visibility import non_redundant_visibility

    return {
        "conventional": di.conventional(gl, sg, cams),
        "nr_pixel": di.non_redundant(gl, sg, cams),
        "nr_visibility": non_redundant_visibility(sg.scene, cams, rc),
        "peeling": di.depth_peeling(gl, sg, peel_cam, layers),
    }


def measure_rig(gl, name: str, res: int, views: int, seed: int, spread: float = 20.0,
                jobs: Callable[[dict[str, list]], dict[str, tuple[list, str]]] | None = None,
                extra_sets: Callable[..., dict[str, list]] | None = None,
                progress: bool = False, prepare: Callable | None = None) -> dict:
    """Render the benchmark's sets for scene `name` on the Fig. 8 rig (`spread`
    degrees) and evaluate `jobs(sets)` (default `metric_jobs`) over `views`
    intermediate views: {"scene", "triangles", "spread_deg", "metrics"} as in
    sampling.json. extra_sets(gl, scene_gpu, caster, cams, peel_cam) adds image sets
    (rendered while the scene is on the GPU) before the jobs are built;
    prepare(scene) → scene changes the loaded scene first (e.g. re-tessellates it)."""
    from gl_passes.upload import SceneGPU
    from reference.raycast import RayCaster
    from reference.sampling_metrics import evaluate_sets
    from scenes.rig import intermediate_views

    scene = load_named_scene(name)
    if prepare is not None:
        scene = prepare(scene)
    rc = RayCaster(scene)
    sg = SceneGPU(gl, scene)
    try:
        cams, peel_cam = make_rig(scene, res, None, spread)
        sets = render_sets(gl, sg, rc, cams, peel_cam)
        if extra_sets is not None:
            sets.update(extra_sets(gl, sg, rc, cams, peel_cam))
    finally:
        sg.release()
    metrics = evaluate_sets(scene, (jobs or metric_jobs)(sets), sets["conventional"],
                            intermediate_views(cams, views, seed=seed), caster=rc, progress=progress)
    return {"scene": name, "triangles": scene.n_triangles, "spread_deg": spread,
            "metrics": {k: m.to_dict() for k, m in metrics.items()}}


def metric_jobs(sets: dict[str, list]) -> dict[str, tuple[list, str]]:
    return {
        "pixel/conventional": (sets["conventional"], "pixel"),
        "pixel/non_redundant": (sets["nr_pixel"], "pixel"),
        "pixel/peeling": (sets["peeling"], "pixel"),
        "visibility/conventional": (sets["conventional"], "visibility"),
        "visibility/non_redundant": (sets["nr_visibility"], "visibility"),
        "visibility/peeling": (sets["peeling"], "visibility"),
    }


def time_methods(gl, sg, cams, peel_cam, res: int, repeat: int, geom: bool) -> dict:
    """Table 7: GL time (ms) to render three images per method, interleaved
    side by side, read-back excluded, ctx.finish() around every call."""
    from gl_passes.depth_images import DepthImageRenderer, prepare_cameras

    cams = prepare_cameras(sg, cams, res)
    peel = prepare_cameras(sg, [peel_cam], res)[0]
    out = {}
    variants = [("prim_id", False)] + ([("geom_shader", True)] if geom else [])
    renderers = []
    fns = {}
    for label, tri_from_geom in list(variants):
        try:
            r = DepthImageRenderer(gl, tri_from_geom=True) if tri_from_geom else DepthImageRenderer(gl)
        except TypeError:  # a renderer without the geometry-shader option
            variants.remove((label, tri_from_geom))
            continue
        renderers.append(r)
        fns[f"{label}/conventional"] = lambda r=r: r.conventional(sg, cams, read=False)
        fns[f"{label}/non_redundant"] = lambda r=r: r.non_redundant(sg, cams, read=False)
        fns[f"{label}/peeling"] = lambda r=r: r.depth_peeling(sg, peel, 3, read=False)
    try:
        timings = time_side_by_side(fns, repeat=repeat, warmup=1, sync=gl.ctx.finish)
    finally:
        for r in renderers:
            r.release()
    for label, _ in variants:
        c, n, p = (timings[f"{label}/{m}"].median_ms for m in METHODS)
        out[label] = {"conventional_ms": c, "non_redundant_ms": n, "peeling_ms": p,
                      "nr_over_conventional": n / c, "nr_over_peeling": n / p,
                      "samples": {m: timings[f"{label}/{m}"].to_dict() for m in METHODS}}
    out["res"] = res
    out["repeat"] = repeat
    return out


def table3_picture(path: Path, scene_name: str, sets: dict[str, list], metrics: dict) -> None:
    """Table 3: per image, occluded samples green, useful ones yellow, the other
    samples dimmed grey; rows NR and peeling for both redundancy definitions."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [("pixel/non_redundant", "nr_pixel"), ("pixel/peeling", "peeling"),
            ("visibility/non_redundant", "nr_visibility"), ("visibility/peeling", "peeling")]
    fig, axes = plt.subplots(len(rows), 3, figsize=(9, 3.2 * len(rows)))
    for r, (key, set_name) in enumerate(rows):
        m = metrics[key]
        for i, im in enumerate(sets[set_name]):
            lum = np.clip(im.color @ np.array([0.3, 0.59, 0.11], np.float32), 0, 1) ** (1 / 2.2)
            rgb = np.repeat((0.45 * lum * im.mask)[..., None], 3, axis=2)
            occ, use = m.occluded_masks[i], m.useful_masks[i]
            rgb[occ & ~use] = (0.1, 0.8, 0.1)
            rgb[use] = (1.0, 0.9, 0.0)
            ax = axes[r, i]
            ax.imshow(rgb, interpolation="nearest")
            ax.set_title(f"{key.replace('/', ' / ')} I{i}\n{pct(m.occluded_frac[i])}, {pct(m.useful_frac[i])}",
                         fontsize=8)
            ax.axis("off")
    fig.suptitle(f"{scene_name}: occluded (green + yellow) and useful occluded (yellow) samples\n"
                 "title: occluded / samples, useful / occluded", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def has_ground(scene) -> bool:
    return any(o.name == "ground" for o in scene.objects) and len(scene.objects) > 1


def without_ground(scene):
    """The scene without its objects named "ground" (same lighting)."""
    from scenes.model import Scene

    return Scene([o for o in scene.objects if o.name != "ground"], scene.sun_direction, scene.area_light,
                 scene.name + "-noground")


def run_scene(name: str, gl, args, sw: Stopwatch, ground: bool = True) -> dict | None:
    """All metrics (+ Table 3 picture, + Table 7 timing when args.timing_res and
    ground) of one scene; ground=False drops its ground plane (None if it has none)."""
    from gl_passes.upload import SceneGPU
    from reference.raycast import RayCaster
    from reference.sampling_metrics import evaluate_sets
    from scenes.rig import intermediate_views

    label = name if ground else f"{name}-noground"
    with sw(f"{label}/load"):
        scene = load_named_scene(name)
        if not ground:
            if not has_ground(scene):
                return None
            scene = without_ground(scene)
        rc = RayCaster(scene)
        sg = SceneGPU(gl, scene)
    try:
        cams, peel_cam = make_rig(scene, args.res, args.distance, getattr(args, "spread", 20.0))
        with sw(f"{label}/render"):
            sets = render_sets(gl, sg, rc, cams, peel_cam)
        views = intermediate_views(cams, args.views, seed=args.seed)
        with sw(f"{label}/metrics"):
            metrics = evaluate_sets(scene, metric_jobs(sets), sets["conventional"], views, caster=rc,
                                    progress=args.progress, keep_masks=True)
        pic = args.out / f"sampling_table3_{label}.png"
        table3_picture(pic, label, sets, metrics)
        timing = None
        if args.timing_res and ground:
            with sw(f"{name}/timing"):
                timing = time_methods(gl, sg, cams, peel_cam, args.timing_res, args.timing_repeat, args.timing_geom)
        return {
            "scene": name,
            "ground_removed": not ground,
            "triangles": scene.n_triangles,
            "objects": len(scene.objects),
            "res": args.res,
            "views": args.views,
            "rig": {"eyes": [c.eye for c in cams], "peeling_eye": peel_cam.eye, "target": cams[0].target,
                    "fov": cams[0].fov, "spread_deg": getattr(args, "spread", 20.0),
                    "distance_x_content_diagonal": float(np.linalg.norm(np.subtract(cams[0].eye, cams[0].target))
                                                         / np.linalg.norm(np.subtract(*content_bounds(scene))))},
            "metrics": {k: m.to_dict() for k, m in metrics.items()},
            "table3_png": pic.name,
            "timing": timing,
        }
    finally:
        sg.release()


def run_sweep(name: str, gl, args, sw: Stopwatch) -> dict:
    """Figs 13-15: metrics of both definitions at several resolutions."""
    from gl_passes.upload import SceneGPU
    from reference.raycast import RayCaster
    from reference.sampling_metrics import evaluate_sets
    from scenes.rig import intermediate_views

    scene = load_named_scene(name)
    rc = RayCaster(scene)
    sg = SceneGPU(gl, scene)
    out = {"scene": name, "views": args.sweep_views, "res": [], "metrics": []}
    try:
        for res in progress(args.sweep_res, args.progress, desc=f"sweep {name}", unit="res", leave=False):
            with sw(f"sweep/{name}/{res}"):
                cams, peel_cam = make_rig(scene, res, args.distance, getattr(args, "spread", 20.0))
                sets = render_sets(gl, sg, rc, cams, peel_cam)
                views = intermediate_views(cams, args.sweep_views, seed=args.seed)
                m = evaluate_sets(scene, metric_jobs(sets), sets["conventional"], views, caster=rc)
            out["res"].append(res)
            out["metrics"].append({k: v.to_dict() for k, v in m.items()})
    finally:
        sg.release()
    return out


def sweep_plots(sweep: dict, out_dir: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    res = sweep["res"]
    figs = [
        ("13", "redundant samples of conventional images", "conventional", "redundant_frac"),
        ("14", "occluded samples of non-redundant images (issue reading)", "non_redundant", "occluded_frac"),
        ("15", "useful share of occluded samples (non-redundant, issue reading)", "non_redundant",
         "useful_frac_of_occluded"),
    ]
    names = []
    for num, title, method, key in figs:
        fig, ax = plt.subplots(figsize=(5, 3.6))
        for red, style in (("pixel", "-o"), ("visibility", "--s")):
            for i, color in ((1, "tab:blue"), (2, "tab:orange")):
                ys = [100 * m[f"{red}/{method}"][key][i] for m in sweep["metrics"]]
                ax.plot(res, ys, style, color=color, label=f"{red} definition, I{i}")
        if method == "non_redundant":
            for i, color in ((1, "tab:green"), (2, "tab:red")):
                ys = [100 * m["pixel/peeling"][key][i] for m in sweep["metrics"]]
                ax.plot(res, ys, ":^", color=color, label=f"peeling (pixel def.), layer {i}")
        ax.set_xscale("log", base=2)
        ax.set_xticks(res, [str(r) for r in res])
        ax.set_xlabel("image resolution (pixels per side)")
        ax.set_ylabel("%")
        ax.set_ylim(0, 100)
        ax.set_title(f"Fig. {num}-like ({sweep['scene']}): {title}", fontsize=8)
        ax.legend(fontsize=6)
        fig.tight_layout()
        fname = f"sampling_fig{num}_{sweep['scene']}.png"
        fig.savefig(out_dir / fname, dpi=100)
        plt.close(fig)
        names.append(fname)
    return names


# --- report -------------------------------------------------------------------------


# --- issue 3's "Done when" -----------------------------------------------------------


def write_report(args, info: dict, results: list[dict], sweep: dict | None, sweep_pngs: list[str],
                 stage_seconds: dict[str, float], wall_s: float, write_json_file: bool = True,
                 variant: list[dict] | None = None, extra_runs: list[dict] | None = None) -> dict:
    """sampling.md (+ sampling.json): extra_runs are the sampling.json contents of
    other runs (e.g. 1024²) whose scenes join the issue-3 criteria section.
    Returns the criteria summary (criteria_tables) written to the json."""
    md = ["# Sampling quality of depth-image sets (thesis Ch. 2, Tables 2-7, Figs 13-15)", ""]
    md += ["## What was run", "",
           f"- Command: `{args.command}`",
           "- Scenes: " + ", ".join(f"{r['scene']} ({r['triangles']:,} triangles)" for r in results),
           f"- Reference images: {args.res}×{args.res}, Fig. 8 rig (3 views + depth-peeling view at their "
           f"centroid, 3 layers), intermediate views: {args.views} uniform in the triangle V0V1V2 "
           f"(seed {args.seed}), each cast at {args.res}×{args.res} with Embree.",
           f"- Table 7 timing: {args.timing_res}×{args.timing_res}, {args.timing_repeat} interleaved rounds after "
           f"1 warm-up round, median" + (f" (redone by `{args.timing_command}`)."
                                          if getattr(args, "timing_command", None) else ".")
           if args.timing_res else "- Table 7 timing: skipped.",
           f"- Ground planes of the built-ins: {getattr(args, 'ground', 'with')} (main tables: as built "
           "unless 'without').",
           (f"- Resolution sweep (Figs 13-15): {', '.join(args.sweep_scenes)} at "
            f"{', '.join(map(str, args.sweep_res))} with {args.sweep_views} intermediate views."
            if args.sweep_scenes else "- Resolution sweep (Figs 13-15): not in this run."),
           f"- Wall time {wall_s / 60:.1f} min. Target of the issue: 1024² images and 1000 intermediate views. "
           + why_reduced(args.res, args.views), ""]
    md += ["## Machine", "", machine_markdown(info), ""]
    md += ["## Definitions", "",
           "See `reference/sampling_metrics.py` (module docstring) and `reference/visibility.py`. In short: "
           "*redundant* = redundant with an earlier image of the same set; *occluded* = not captured by any "
           "conventional image of V0..V2 (same redundancy test; issue reading) or, for NR image I_i, by "
           "C_0..C_{i-1} (thesis reading, §2.3.2 item 2); *useful* = occluded and redundant with (needed "
           "by) at least one intermediate view; *available* = share of an intermediate view's pixels redundant "
           "with some image of the set (visibility definition: the view's surface point is the same layer "
           "along V_i's ray as the sample I_i stores at that texel). Cells read `ours (thesis)`; "
           "fractions are of the image's samples, useful of the occluded ones.", ""]
    t2, d2 = view_independent_table(results, "pixel", THESIS_T2)
    t4, d4 = view_dependent_table(results, "pixel", THESIS_T4, 0)
    t5, d5 = view_independent_table(results, "visibility", THESIS_T5)
    t6, d6 = view_dependent_table(results, "visibility", THESIS_T6, 2)

    def gap(d: list[float] | dict[str, list[float]]) -> str:
        if isinstance(d, dict):
            if not d.get("all"):
                return ""
            return (f"Mean |ours − thesis| over the comparable cells: {np.mean(d['all']):.1f} points (issue "
                    f"reading). Over the NR cells of I1, I2 (occluded and useful): {np.mean(d['nr_all']):.1f} "
                    f"points with the issue reading, {np.mean(d['nr_earlier']):.1f} with the thesis reading."
                    "\n\n" + EARLIER_NOTE) if d.get("nr_earlier") else f"Mean |ours − thesis|: {np.mean(d['all']):.1f}."
        return f"Mean |ours − thesis| over the comparable cells: {np.mean(d):.1f} points." if d else ""

    runs = [(f"{args.res}², {args.views} views", results)]
    runs += [(f"{e['config']['res']}², {e['config']['views']} views", e["scenes"]) for e in extra_runs or []]
    revisions = [scene_revisions(vars(args), results)] + [scene_revisions(e["config"], e["scenes"])
                                                          for e in extra_runs or []]
    crit_md, crit = criteria_tables(runs, results)
    md += ["## Issue 3, \"Done when\": the criteria, scene by scene", "",
           "Runs: " + "; ".join(f"{label} ({'this file' if k == 0 else 'see ' + e['_path']}"
                                f"{revision_note(rev)})"
                                for k, ((label, _), e, rev) in enumerate(zip(runs, [{}] + list(extra_runs or []),
                                                                               revisions, strict=True))) + ".", "",
           crit_md, criteria_notes(), ""]
    md += ["## Table 2: view-independent metrics, pixel definition [%]", "", t2, "", gap(d2), ""]
    md += ["## Table 4: available samples, pixel definition [%]", "", t4, "", gap(d4), ""]
    md += ["## Table 5: view-independent metrics, visibility definition [%]", "", t5, "", gap(d5), ""]
    md += ["## Table 6: available samples, visibility definition [%]", "", t6, "", gap(d6), ""]
    md += ["## The thesis's claims, checked", "",
           "Totals over the three images; the thesis finds NR ahead on both counts (§2.3.3).", "",
           ranking_table(results), ""]
    if variant:
        v2, e2 = view_independent_table(variant, "pixel", THESIS_T2)
        v4, e4 = view_dependent_table(variant, "pixel", THESIS_T4, 0)
        v5, e5 = view_independent_table(variant, "visibility", THESIS_T5)
        v6, e6 = view_dependent_table(variant, "visibility", THESIS_T6, 2)
        md += ["## Variant: the same scenes without their ground planes", "",
               "The built-in scenes stand on a large ground plane; much of what the NR images add is ground "
               "outside V0's view, visible from V1/V2 (so not occluded). The thesis's models show no ground. "
               "Same rig, resolution and views; pictures `sampling_table3_<scene>-noground.png`.", "",
               "### Table 2 (pixel definition)", "", v2, "", gap(e2), "",
               "### Table 4 (pixel definition)", "", v4, "", gap(e4), "",
               "### Table 5 (visibility definition)", "", v5, "", gap(e5), "",
               "### Table 6 (visibility definition)", "", v6, "", gap(e6), "",
               "### The thesis's claims, checked", "", ranking_table(variant), ""]
    md += ["## Table 7: GL time for three images per method", "", timing_table(results), "",
           "Absolute times are software rasterisation (llvmpipe) on a shared CPU; compare ratios only.", ""]
    md += ["## Table 3: occluded and useful samples", ""]
    md += [f"- {r['scene']}: ![{r['scene']}]({r['table3_png']})" for r in results]
    md += [""]
    if sweep:
        md += ["## Figs 13-15: resolution sweep", "",
               f"Scene {sweep['scene']}, {sweep['views']} intermediate views. Solid: pixel definition, dashed: "
               "visibility definition (I1 blue, I2 orange).", ""]
        md += [f"![{p}]({p})" for p in sweep_pngs]
        rows = []
        for res, m in zip(sweep["res"], sweep["metrics"], strict=True):
            rows.append([res] + [pct(m[f"{d}/conventional"]["redundant_frac"][i]) for d in ("pixel", "visibility")
                                 for i in (1, 2)]
                        + [pct(m[f"{d}/non_redundant"]["occluded_frac"][i]) for d in ("pixel", "visibility")
                           for i in (1, 2)]
                        + [pct(m[f"{d}/non_redundant"]["useful_frac_of_occluded"][i])
                           for d in ("pixel", "visibility") for i in (1, 2)]
                        + [pct(m[f"pixel/{k}"]["available_avg"], 1) for k in METHODS])
        md += ["", md_table(["res", "conv red. px I1", "px I2", "vis I1", "vis I2", "NR occ. px I1", "px I2",
                             "vis I1", "vis I2", "NR useful px I1", "px I2", "vis I1", "vis I2",
                             "avail. px conv", "NR", "peel"], rows), ""]
    md += [discussion(), "## Stage times [s]", "",
           md_table(["stage", "seconds"], [[k, f"{v:.1f}"] for k, v in stage_seconds.items()]), ""]
    write_text(args.out / "sampling.md", "\n".join(md))
    if not write_json_file:
        return crit
    write_json(args.out / "sampling.json", {
        "command": args.command,
        "config": {k: v for k, v in vars(args).items() if k not in ("out", "command", "report_only")},
        "machine": info, "wall_s": wall_s, "stage_seconds": stage_seconds, "scenes": results,
        "scenes_without_ground": variant or [], "sweep": sweep, "criteria": crit,
        "extra_runs": [e["_path"] for e in extra_runs or []],
        "thesis": {"table2": THESIS_T2, "table4": THESIS_T4, "table5": THESIS_T5, "table6": THESIS_T6,
                   "table7": THESIS_T7},
        "mean_abs_gap_points": {
            **{f"table{t}_{k}": float(np.mean(d[k])) if d.get(k) else None for t, d in (("2", d2), ("5", d5))
               for k in ("all", "nr_all", "nr_earlier")},
            "table4": float(np.mean(d4)) if d4 else None, "table6": float(np.mean(d6)) if d6 else None},
    })
    return crit


def why_reduced(res: int, views: int) -> str:
    """The report's sentence on how this run relates to the issue's target."""
    if (res, views) == (1024, 1000):
        return "This run is the target configuration."
    minutes = target_minutes_per_scene() or "tens of"  # measured by the target run, when it is there
    return (f"This run uses {res}² and {views} views: on this shared 2-core machine the Embree casts of 1000 "
            "intermediate views per scene (plus the visibility-definition layer walks) at 1024² take "
            f"{minutes} min per scene (`sampling_1024_1000v/`, run scene by scene and joined with --merge), so the "
            "defaults are sized to finish within about 10 minutes; pass --res 1024 --views 1000 for the target.")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--scenes", default=",".join(DEFAULT_SCENES),
                    help="comma list of built-in names and/or 'diorama' (skipped when absent)")
    ap.add_argument("--res", type=int, default=512, help="reference image and intermediate view size")
    ap.add_argument("--views", type=int, default=100, help="intermediate views for useful/available samples")
    ap.add_argument("--distance", type=float, default=None,
                    help="rig distance × content diagonal (default: the content's bounding sphere fills every "
                         "view of the rig, scenes.rig.fit_distance: 1.39 for fov 45°, spread 20°)")
    ap.add_argument("--spread", type=float, default=20.0, help="rig spread: degrees between each eye and the axis")
    ap.add_argument("--sweep-scenes", default="nest", help="comma list for the Figs 13-15 sweep ('' = none)")
    ap.add_argument("--sweep-res", default="64,128,256,512,1024", help="comma list of resolutions")
    ap.add_argument("--sweep-views", type=int, default=20)
    ap.add_argument("--timing-res", type=int, default=1024, help="Table 7 resolution (0 = skip timing)")
    ap.add_argument("--timing-repeat", type=int, default=5)
    ap.add_argument("--no-timing-geom", dest="timing_geom", action="store_false",
                    help="skip the geometry-shader triangle-id variant in Table 7")
    ap.add_argument("--ground", choices=("with", "without", "both"), default="both",
                    help="built-in scenes as built, without their ground planes, or both (the second as a variant)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: 128² images, 30 views, sweep 64-256 with 10 views, timing at 512, 3 rounds")
    ap.add_argument("--no-progress", dest="progress", action="store_false")
    ap.add_argument("--timing-only", action="store_true",
                    help="redo only Table 7 (--timing-res, --timing-repeat) for the scenes of the sampling.json in "
                         "--out, replace its timing and rewrite sampling.md")
    ap.add_argument("--report-only", action="store_true",
                    help="rewrite sampling.md (and the sweep plots) from the sampling.json in --out, no rendering")
    ap.add_argument("--out", type=Path, default=RESULTS_DIR)
    ap.add_argument("--merge", type=Path, nargs="+", default=[],
                    help="sampling.json files of per-scene runs with the same --res and --views: write their union "
                         "to --out (sampling.json + sampling.md), no rendering")
    ap.add_argument("--extra-json", type=Path, action="append", default=[],
                    help="sampling.json of another run (e.g. 1024²) to include in the issue-3 criteria section")
    args = ap.parse_args(argv)
    if args.quick:
        args.res, args.views, args.sweep_res, args.sweep_views = 128, 30, "64,128,256", 10
        args.timing_res, args.timing_repeat = min(args.timing_res, 512) if args.timing_res else 0, 3
    args.scenes = [s for s in args.scenes.split(",") if s]
    args.sweep_scenes = [s for s in args.sweep_scenes.split(",") if s]
    args.sweep_res = [int(r) for r in args.sweep_res.split(",") if r]
    args.command = "python -m bench.sampling " + " ".join(argv if argv is not None else sys.argv[1:])
    args.reference_revision = REVISION  # recorded in the run's config
    return args


def scene_revisions(config: dict, scenes: list[dict]) -> dict[str, int]:
    """{scene: reference revision it was measured against}: a scene's own
    "reference_revision" (set by --merge from its part's run), else the run's
    `config`'s, else 1 (runs from before revisions were recorded)."""
    run_revision = config.get("reference_revision", 1)
    return {r["scene"]: r.get("reference_revision", run_revision) for r in scenes}


def revision_note(revisions: dict[str, int]) -> str:
    """'' for a run whose scenes all measured the current reference, else which
    scenes measured which earlier revision (`revisions` from scene_revisions)."""
    old = {}
    for scene, rev in revisions.items():
        if rev < REVISION:
            old.setdefault(rev, []).append(scene)
    if not old:
        return ""
    rules = f"before revision {REVISION}'s rules (`reference.REVISION`)"
    (rev, scenes), *_ = old.items()
    if len(old) == 1 and len(scenes) == len(revisions):
        return f"; measured against reference revision {rev}, {rules}"
    which = "; ".join(f"{', '.join(sc)} measured against reference revision {r}" for r, sc in old.items())
    return f"; {which}, {rules}; the other scenes against revision {REVISION}"


def load_extra(args: argparse.Namespace) -> list[dict]:
    """The --extra-json runs, each with "_path" (relative to --out when inside it)."""
    out = []
    for p in args.extra_json:
        data = json.loads(Path(p).read_text())
        try:
            data["_path"] = str(Path(p).resolve().relative_to(Path(args.out).resolve()))
        except ValueError:
            data["_path"] = str(p)
        out.append(data)
    return out


def report_only(args: argparse.Namespace) -> int:
    """Rewrite sampling.md from the sampling.json of an earlier run (no rendering)."""
    path = args.out / "sampling.json"
    data = json.loads(path.read_text())
    cfg = argparse.Namespace(**{**data["config"], "out": args.out, "command": data["command"]})
    sweep = data.get("sweep")
    pngs = sweep_plots(sweep, args.out) if sweep else []
    extra = load_extra(args)
    # The json's derived fields follow the report (the criteria over this run and the extra runs).
    data["criteria"] = write_report(cfg, data["machine"], data["scenes"], sweep, pngs, data["stage_seconds"],
                                    data["wall_s"], write_json_file=False,
                                    variant=data.get("scenes_without_ground"), extra_runs=extra)
    data["extra_runs"] = [e["_path"] for e in extra]
    write_json(path, data)
    print(f"rewrote {args.out / 'sampling.md'} (and the criteria in sampling.json)", file=sys.stderr)
    return 0


def merge_runs(args: argparse.Namespace) -> int:
    """One report from per-scene runs of the same configuration (e.g. the
    1024²/1000-view target, run scene by scene so a long run lands in parts):
    their scenes in the given order, stage times and wall times summed, Table 3
    pictures referenced where they lie."""
    out = Path(args.out)
    parts = [(Path(p), json.loads(Path(p).read_text())) for p in args.merge]
    keys = {(d["config"]["res"], d["config"]["views"], d["config"].get("seed", 0)) for _, d in parts}
    if len(keys) != 1:
        raise SystemExit(f"--merge: runs differ in (res, views, seed): {sorted(keys)}")
    scenes, stages = [], {}
    for path, d in parts:
        revisions = scene_revisions(d["config"], d["scenes"])
        for r in d["scenes"]:
            r["reference_revision"] = revisions[r["scene"]]
            png = path.parent / r["table3_png"]
            r["table3_png"] = os.path.relpath(png, out)
            scenes.append(r)
        stages.update(d["stage_seconds"])
    base = parts[0][1]
    data = {**base, "scenes": scenes, "stage_seconds": stages, "wall_s": sum(d["wall_s"] for _, d in parts),
            "command": " ; ".join(d["command"] for _, d in parts), "scenes_without_ground": [], "sweep": None,
            "merged_from": [os.path.relpath(p, out) for p, _ in parts]}
    data["config"]["scenes"] = [r["scene"] for r in scenes]
    data["config"]["reference_revision"] = min(r["reference_revision"] for r in scenes)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "sampling.json", data)
    return report_only(args)


def timing_only(args: argparse.Namespace) -> int:
    """Redo Table 7 for the scenes of an earlier run's sampling.json (same rig)."""
    from gl_passes.context import create_gl_context
    from gl_passes.upload import SceneGPU

    path = args.out / "sampling.json"
    data = json.loads(path.read_text())
    cfg = data["config"]
    gl = create_gl_context()
    for r in data["scenes"]:
        if r.get("ground_removed"):
            continue
        scene = load_named_scene(r["scene"])
        sg = SceneGPU(gl, scene)
        try:
            cams, peel_cam = make_rig(scene, cfg["res"], cfg.get("distance"), cfg.get("spread", 20.0))
            r["timing"] = time_methods(gl, sg, cams, peel_cam, args.timing_res, args.timing_repeat, args.timing_geom)
        finally:
            sg.release()
        t = r["timing"]["prim_id"]
        print(f"{r['scene']}: NR/conv {t['nr_over_conventional']:.2f} NR/peel {t['nr_over_peeling']:.2f}",
              file=sys.stderr)
    gl.release()
    data["config"]["timing_command"] = args.command
    data["config"]["timing_res"], data["config"]["timing_repeat"] = args.timing_res, args.timing_repeat
    write_json(path, data)
    return report_only(args)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.merge:
        return merge_runs(args)
    if args.report_only:
        return report_only(args)
    if args.timing_only:
        return timing_only(args)
    from gl_passes.context import create_gl_context

    t0 = time.perf_counter()
    gl = create_gl_context()
    info = machine_info(gl)
    sw = Stopwatch()
    scenes = []
    for name in args.scenes:
        if name == "diorama" and shared_model_path(name) is None:
            print("diorama: shared model not present, skipped", file=sys.stderr)
            continue
        scenes.append(name)
    args.out.mkdir(parents=True, exist_ok=True)
    results, variant = [], []
    passes = {"with": [True], "without": [False], "both": [True, False]}[args.ground]
    jobs = [(n, g) for g in passes for n in scenes]
    for name, ground in progress(jobs, args.progress, desc="scenes", unit="scene"):
        res = run_scene(name, gl, args, sw, ground=ground)
        if res is None:
            continue
        (results if ground == passes[0] else variant).append(res)
        r = res["metrics"]
        occ = [round(x, 3) for x in r["pixel/non_redundant"]["occluded_frac"]]
        print(f"{name}{'' if ground else ' (no ground)'}: NR occluded {occ} "
              f"available px conv/NR/peel {r['pixel/conventional']['available_avg']:.3f}/"
              f"{r['pixel/non_redundant']['available_avg']:.3f}/{r['pixel/peeling']['available_avg']:.3f}",
              file=sys.stderr)
    sweep, sweep_pngs = None, []
    for name in args.sweep_scenes[:1]:
        sweep = run_sweep(name, gl, args, sw)
        sweep_pngs = sweep_plots(sweep, args.out)
    write_report(args, info, results, sweep, sweep_pngs, sw.seconds, time.perf_counter() - t0, variant=variant,
                 extra_runs=load_extra(args))
    gl.release()
    print(f"wrote {args.out / 'sampling.md'} ({(time.perf_counter() - t0) / 60:.1f} min)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

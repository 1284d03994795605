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

DEFAULT_SCENES = ("nest", "grass", "city", "tree", "diorama")
METHODS = ("conventional", "non_redundant", "peeling")
METHOD_LABEL = {"conventional": "conventional", "non_redundant": "non-redundant", "peeling": "depth peeling"}

# --- the thesis's numbers (§2.3.3), percent ------------------------------------------
# Tables 2 / 5: conventional redundant per image; NR and peeling (occluded, useful).
THESIS_T2 = {
    "nest": {"conv": [0, 70, 80], "nr": [(0, 0), (62, 89), (76, 86)], "peel": [(10, 99), (46, 2), (52, 71)]},
    "grass": {"conv": [0, 54, 69], "nr": [(0, 0), (56, 85), (75, 80)], "peel": [(15, 99), (51, 4), (71, 79)]},
    "city": {"conv": [0, 82, 84], "nr": [(0, 0), (73, 40), (80, 23)], "peel": [(1, 100), (78, 7), (88, 8)]},
    "tree": {"conv": [0, 23, 35], "nr": [(0, 0), (84, 99), (88, 98)], "peel": [(44, 99), (63, 98), (72, 97)]},
}
THESIS_T5 = {
    "nest": {"conv": [0, 80, 87], "nr": [(0, 0), (55, 66), (66, 61)], "peel": [(10, 99), (39, 38), (45, 55)]},
    "grass": {"conv": [0, 58, 74], "nr": [(0, 0), (48, 80), (73, 85)], "peel": [(15, 99), (48, 81), (69, 76)]},
    "city": {"conv": [0, 87, 87], "nr": [(0, 0), (74, 29), (80, 9)], "peel": [(1, 100), (75, 10), (88, 6)]},
    "tree": {"conv": [0, 49, 67], "nr": [(0, 0), (36, 92), (54, 96)], "peel": [(44, 99), (30, 95), (45, 94)]},
}
# Tables 4 / 6: available samples (avg, min) for conventional, NR, peeling.
THESIS_T4 = {
    "nest": [(90, 89), (93, 92), (92, 89)], "grass": [(86, 81), (96, 91), (93, 88)],
    "city": [(97, 96), (98, 97), (96, 91)], "tree": [(55, 53), (59, 57), (55, 48)],
}
THESIS_T6 = {
    "nest": [(95.25, 94.46), (99.84, 99.73), (99.50, 98.82)], "grass": [(86.61, 83.61), (99.72, 99.35), (99.57, 98.15)],
    "city": [(98.91, 97.64), (99.82, 99.32), (99.37, 94.23)], "tree": [(85.36, 83.63), (98.61, 97.78), (97.65, 93.94)],
}
# Table 7: milliseconds for three 1024² images (GTX 570).
THESIS_T7 = {"nest": (1.8, 3.6, 3.3), "grass": (1.7, 3.0, 3.2), "city": (1.6, 3.3, 2.7), "tree": (2.1, 6.4, 6.5)}


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

def _cell(ours: float, thesis: float | None, digits: int = 0) -> str:
    s = f"{100 * ours:.{digits}f}"
    return s if thesis is None else f"{s} ({thesis:g})"


def _pair(occ: float, use: float, thesis: tuple | None) -> str:
    s = f"{100 * occ:.0f} ({100 * use:.0f})"
    return s if thesis is None else f"{s} · thesis {thesis[0]:g} ({thesis[1]:g})"


def _earlier_fracs(m: dict, red: str) -> tuple[list[float], list[float]] | None:
    """NR occluded samples under the thesis's literal reading (I_i vs C_0..C_{i-1})
    as fractions of the conventional image C_i's samples (the view's scene
    samples), and their useful share; None for runs without those counts."""
    nr, cv = m[f"{red}/non_redundant"], m[f"{red}/conventional"]
    if nr.get("occluded_earlier") is None:
        return None
    occ = [o / c if c else 0.0 for o, c in zip(nr["occluded_earlier"], cv["samples"], strict=True)]
    use = [u / o if o else 0.0 for u, o in zip(nr["useful_earlier"], nr["occluded_earlier"], strict=True)]
    return occ, use


def view_independent_table(results: list[dict], red: str, thesis: dict) -> tuple[str, dict[str, list[float]]]:
    """Table 2/5 with ours (thesis) cells; also |ours − thesis| in points: "all"
    over every comparable cell (conventional redundancy; occluded and useful of
    NR, issue reading, and peeling), "nr_all" / "nr_earlier" over NR's occluded
    and useful cells of I1, I2 under each reading of "occluded" (issue: fractions
    of the image's samples; thesis, literal item 2: fractions of C_i's samples).
    """
    diffs: dict[str, list[float]] = {"all": [], "nr_all": [], "nr_earlier": []}
    rows = []
    for r in results:
        t = thesis.get(r["scene"])
        m = r["metrics"]
        conv = m[f"{red}/conventional"]["redundant_frac"]
        cells = []
        for i in range(3):
            cells.append(_cell(conv[i], t["conv"][i] if t else None))
            if t:
                diffs["all"].append(abs(100 * conv[i] - t["conv"][i]))
        rows.append([r["scene"], "conventional: redundant", *cells])
        nr, pe = m[f"{red}/non_redundant"], m[f"{red}/peeling"]
        # (row label, thesis key, gap lists: "all" over I0-I2, "nr_*" over I1-I2, occluded, useful)
        variants = [("non-redundant: occluded (useful), issue reading", "nr", ("all", "nr_all"),
                     nr["occluded_frac"], nr["useful_frac_of_occluded"])]
        lit = _earlier_fracs(m, red)
        if lit is not None:
            variants.append(("non-redundant: occluded (useful), thesis reading ¹", "nr", ("nr_earlier",), *lit))
        variants.append(("depth peeling: occluded (useful)", "peel", ("all",), pe["occluded_frac"],
                         pe["useful_frac_of_occluded"]))
        for label, key, gap_keys, occ, use in variants:
            cells = []
            for i in range(3):
                th = t[key][i] if t else None
                cells.append(_pair(occ[i], use[i], th))
                if th:
                    for k in gap_keys:
                        if k == "all" or i > 0:
                            diffs[k] += [abs(100 * occ[i] - th[0]), abs(100 * use[i] - th[1])]
            rows.append([r["scene"], label, *cells])
    return md_table(["scene", "metric [%]", "I0 (V0 / peel layer 0)", "I1", "I2"], rows), diffs


EARLIER_NOTE = ("¹ Thesis reading (§2.3.2 item 2 read literally, `reference/sampling_metrics.py`): NR image I_i's "
                "samples not captured by C_0..C_{i-1}, in percent of the conventional image C_i's samples (the "
                "view's scene samples), useful in percent of those; the issue reading tests every image against "
                "all of C_0..C_2 and divides by the image's own samples. Peeling layers are tested against all "
                "of C_0..C_2 in both readings.")


def view_dependent_table(results: list[dict], red: str, thesis: dict, digits: int) -> tuple[str, list[float]]:
    diffs: list[float] = []
    rows = []
    for r in results:
        t = thesis.get(r["scene"])
        row = [r["scene"]]
        for k, method in enumerate(METHODS):
            mm = r["metrics"][f"{red}/{method}"]
            th = t[k] if t else (None, None)
            row += [_cell(mm["available_avg"], th[0], digits), _cell(mm["available_min"], th[1], digits)]
            if t:
                diffs += [abs(100 * mm["available_avg"] - th[0]), abs(100 * mm["available_min"] - th[1])]
        rows.append(row)
    head = ["scene"] + [f"{METHOD_LABEL[m]} {s}" for m in METHODS for s in ("avg", "min")]
    return md_table(head, rows), diffs


def timing_table(results: list[dict]) -> str:
    rows = []
    for r in results:
        tm = r.get("timing")
        if not tm:
            continue
        th = THESIS_T7.get(r["scene"])
        for label in ("prim_id", "geom_shader"):
            if label not in tm:
                continue
            t = tm[label]
            thr = f"{th[1] / th[0]:.2f} / {th[1] / th[2]:.2f}" if th else "—"
            rows.append([r["scene"], "gl_PrimitiveID" if label == "prim_id" else "geometry shader",
                         f"{t['conventional_ms']:.1f}", f"{t['non_redundant_ms']:.1f}", f"{t['peeling_ms']:.1f}",
                         f"{t['nr_over_conventional']:.2f}", f"{t['nr_over_peeling']:.2f}",
                         f"{th[0]} / {th[1]} / {th[2]}" if th else "—", thr])
    return md_table(["scene", "triangle id from", "conventional [ms]", "NR [ms]", "peeling [ms]", "NR/conv",
                     "NR/peel", "thesis ms (conv / NR / peel)", "thesis NR/conv / NR/peel"], rows)


DISCUSSION = """\
### Why our numbers differ from the thesis

* **Scenes.** The thesis's bird's nest, grass, city and tree models are not
  available; ours are procedural stand-ins with the same triangle budgets
  (`scenes/builtin`) but a different depth complexity. All metrics depend on
  how much hidden, front-facing geometry lies behind what V0..V2 see, so
  per-cell gaps of tens of points are expected; the orderings are what can be
  compared (section "The thesis's claims, checked").
* **Ground.** The nest and the tree stand on modest ground discs (1.4 × their
  footprint); grass and city grounds are the patch and the street grid the
  content covers. (Earlier runs used 1.5 m / 12 m ground quads around the
  nest / tree: the plane filled the image corners with ground that NR images
  mostly drop as redundant or keep as non-occluded, and lowered the NR
  occluded fractions; the counts of useful occluded samples barely changed.)
* **Tiny triangles and resolution.** The nest's twigs and the tree's leaves
  are a few pixels or less at 512²: pixel redundancy (same triangle id at the
  reprojected texel) then misses much of the true redundancy, so conventional
  redundancy is lower, NR images keep visible samples that only differ by
  triangle, and pixel-definition availability is low. The sweep (Figs 13-15)
  shows pixel-definition values converging toward the visibility-definition
  ones as the resolution grows, as §2.3.3 states; it also shows NR overtaking
  the conventional set in pixel-definition availability only from 512² up.
* **Rig.** Fig. 8 gives no numbers: we use `scenes.rig.fig8_rig` (eyes 20° off
  a common axis at elevation 25°, fov 45°) framed on the scene without its
  ground: the content box's bounding sphere just fits the narrowest view of the
  rig (`scenes.rig.fit_distance`, 1.39 × the content diagonal), so every
  reference, peeling and intermediate view holds the whole content. Clip
  planes are fitted to the whole scene. Only the tree's ground disc reaches
  past the peeling view: 0.5 % of the tree's intermediate-view samples lie
  outside the peeling camera's frustum (inside all of V0..V2's), which lowers
  peeling's available fraction on the tree by at most that much (measured at
  128², 20 views; nest, grass, city: 0 %). A wider spread makes V1/V2 less
  redundant and NR images less deep.
* **Views.** Fewer intermediate views than the thesis's 1000 lower the useful
  fraction slightly (a sample needed by a rare view can be missed) and raise
  the minimum available fraction.
* **Depth peeling.** Its first layer comes from the centroid, itself an
  intermediate view, so its occluded samples are almost all useful; its deeper
  layers are complete images of the hidden layers, so in absolute counts
  peeling often collects more occluded samples than our sparse NR images.
  The thesis's layer 1 is nearly useless on the nest, grass and city (2, 4,
  7 % of its occluded samples, Table 2) where ours is not (80, 99, 46 % at
  512², 200 views): peeling *without* back-face culling gives 6 % on our
  closed nest and city models, its layer 1 being their inside
  (`bench/results/peeling_sides.md`, `python -m bench.peeling_sides`). The
  thesis's Table 5 layer-1 and layer-2 shares fit our culled peeling better
  (mean gap 20 against 33 points), so no single peeling matches both
  tables; we keep the culled peeling the issue asks for (it has more useful
  occluded samples on every scene). Against the two-sided peeling, NR's
  useful occluded samples under the issue's reading still trail on 4 / 4
  scenes (pixel) and 2 / 4 (visibility).
* **Definitions.** Where §2.3.2 is not precise we chose (see
  `reference/sampling_metrics.py`): occluded is computed under both readings
  (the issue's: not captured by any of the n conventional images, fraction of
  the image's samples; the thesis's literal item 2: NR I_i against C_0..C_{i-1},
  fraction of C_i's samples); visibility-definition availability compares with the
  *layer* of what each image stores within one texel. Background pixels are
  not samples. GL samples tested with Embree are not exactly consistent at
  silhouettes: conventional images show ~1e-4 "occluded" samples and peeling
  layers ~0.5-1 % visibility-redundant ones (float32 positions on thin twigs
  and leaves, whose occlusion ray grazes the occluder's edge).
* **Timing.** Table 7 in the thesis is a GTX 570; ours is Mesa llvmpipe on a
  shared 2-core CPU, so absolute times are ~100× larger and only the ratios are
  comparable. On llvmpipe the NR pass's extra cost (one reprojection and
  texture fetch per previous image per fragment) is small against rasterising
  and shading 50-113k triangles on the CPU, so NR/conventional is lower than
  the thesis's 1.8-3.0; NR/peeling is close to the thesis's (≈1). The thesis
  blames its geometry shader for the tree's cost; the geometry-shader variant
  rows measure that set-up here. The machine is shared: with 5 rounds single
  ratios moved by ±20 % between runs, hence the interleaved rounds stated
  under "What was run" (compare the two variants of a scene).
"""


def ranking_table(results: list[dict]) -> str:
    """The thesis's qualitative claims, checked per scene and definition: NR
    images hold more useful occluded samples than peeling, and more available
    samples per view than conventional images and peeling."""
    rows = []
    for r in results:
        for red in ("pixel", "visibility"):
            m = r["metrics"]
            nr, pe, cv = (m[f"{red}/{k}"] for k in METHODS[1:] + METHODS[:1])
            rows.append([
                r["scene"], red,
                f"{nr['total']['occluded']:,} / {pe['total']['occluded']:,}",
                f"{nr['total']['useful']:,} / {pe['total']['useful']:,}",
                yes_no(nr["total"]["useful"] > pe["total"]["useful"]),
                f"{100 * nr['available_avg']:.1f} / {100 * cv['available_avg']:.1f} / {100 * pe['available_avg']:.1f}",
                yes_no(nr["available_avg"] >= max(cv["available_avg"], pe["available_avg"])),
            ])
    return md_table(["scene", "definition", "occluded samples NR / peel", "useful samples NR / peel",
                     "NR more useful", "available avg NR / conv / peel [%]", "NR most available"], rows)


# --- issue 3's "Done when" -----------------------------------------------------------

#: Issue 3, criterion (d): at 1024², NR time ≤ 2.5 × conventional and ≤ 1.3 × peeling.
MAX_NR_OVER_CONV, MAX_NR_OVER_PEEL = 2.5, 1.3
CRITERIA_SCENES = ("nest", "grass", "city", "tree")


CRITERIA_NOTES = """\
### What the criteria show, and why (measured)

* **The issue's target configuration, 1024² with 1000 intermediate views**
  (`sampling_1024_1000v/`: 105 min on this 2-core machine, 18-43 min per
  scene, with the Embree reference caster split across threads), gives the
  same verdicts as the 1024²/60-view run on every scene and definition: (a)
  4 / 4; (b) with visibility 4 / 4, with pixel 1 / 4 (nest; NR trails the
  conventional set on average by 0.21 / 0.72 / 0.86 points on grass / city /
  tree, and on the minimum by 0.57 / 0.61 points on grass / tree); (c) with the
  thesis's reading 4 / 4 under both definitions (NR 1.22-2.47× peeling's
  useful occluded samples), with the issue's reading pixel 0 / 4, visibility
  1 / 4 (city). From 60 to 1000 views the averages moved by at most 0.3
  points; the minima fell by up to 0.3 points for NR and the conventional
  set and by 0.3-2.2 points for peeling (views near the rig's corners see
  past the centroid's layers); useful counts grew by 1-28 % (a sample needed
  only by a rare view), for NR and peeling alike.
* **(a) holds.** The visibility NR sets (Embree) have no visibility-redundant
  sample. The GL pixel NR sets show 0-11 pixel-redundant samples out of
  1e5-3e5 when the reference re-tests them, and every one is a texel-edge
  tie: its projection lies within 1e-4 texel of a texel edge (measured on nest
  and grass at 1024²), where GL's float32 Alg. 3 and the reference's float64
  projection fall on neighbouring texels; at 2048² (12 views) one tree
  sample in 6e5 lies 3.4e-3 texel from the edge (not counted as a tie: the
  float32 error in texel units grows with the resolution); the same sets
  rendered by Embree in float64 (`reference.visibility.non_redundant_reference`,
  `bench/results/tessellation.md`) have none. (Until this run the visibility NR
  sets also showed 0-1 such sample: `non_redundant_visibility` tested the
  float64 hit point but stored it as float32, and an occlusion ray grazing an
  edge could answer differently for the two; it now tests the stored point.)
* **(b) holds with the visibility definition on all four scenes** at 512² and
  1024² (NR ahead of conventional by 1.4-6.5 points and of peeling by 1.0-1.7
  points on average; on the minimum by 2.8-8.0 and 2.3-5.5 points). **With
  the pixel definition NR stays ahead of peeling but falls 0.15-1.5 points
  below the conventional set**
  on grass, city and tree (and on nest at 512²; at 1024² nest holds). The
  mechanism, measured on grass and nest at 512² (10 views): per view NR loses
  3.4 % (grass) / 2.4 % (nest) of the samples the conventional set makes
  available and gains 2.4 % / 2.1 %; 100 % of the lost samples are on a
  triangle that C1 or C2 holds at their texel and that NR dropped there as
  pixel-redundant with an earlier image, while the frame sample's own
  projection into that earlier image lands on a texel of another triangle
  (silhouettes of thin blades, twigs and leaves, and building edges). Alg. 3
  forces this, whatever the implementation: it keeps or drops a whole texel by
  its centre, and in an 8×8 case counted by hand (offset scene,
  `tests/test_sampling_metrics.py`) the NR set, with no redundant sample, makes
  6 of a frame's 8 columns available where the conventional set makes all 8
  (visibility definition: 8 and 8). It is
  the pixel definition's texel granularity: the gap shrinks from 512² to
  1024² (grass 0.98 → 0.15, city 1.09 → 0.54, tree 1.46 → 0.84 points; nest
  −0.32 → +0.86) as pixel redundancy converges to visibility redundancy, and
  at 2048² (12 views, `sampling_2048/`) (b) holds with the pixel definition on
  nest, grass and city (NR ahead of conventional by 0.3-1.9 points) and the
  tree ties (average −0.01 point, minimum +0.2). The gap belongs to Alg. 3,
  not to our GL pass, and it follows the triangles' size against the texel
  (`bench/results/tessellation.md`, `python -m bench.tessellation`, 1024², 60
  views): the same NR sets rendered by Embree
  (`reference.visibility.non_redundant_reference`) give the GL sets'
  availability to ≤ 0.05 point; splitting every triangle into 4 and 16, with
  the surfaces unchanged (visibility metrics move ≤ 0.14 point), takes (b)
  with the pixel definition from 1 / 4 scenes to 0 / 4, and NR's average
  lead over the conventional set from −0.84 … +0.86 points (as tessellated)
  to −2.09 … −0.95 (16 triangles each). Finer triangles do not reproduce the
  thesis's tree row either (its conventional set loses 30 points from Table 6
  to Table 4, yet NR is 4 points ahead): our tree's conventional set loses
  5-15 points that way (1× to 16×) and NR trails more the finer it gets.
* **(c) holds with the thesis's reading of "occluded" on 4 / 4 scenes, under
  both redundancy definitions, at 512² and at 1024² (NR ahead of peeling by
  1.16-2.6× in useful occluded samples); with the issue's reading it fails
  (pixel 0 / 4, visibility 1 / 4, city).** The two readings
  (`reference/sampling_metrics.py`, both computed in every run): the issue
  summarises occluded samples as "not captured by the conventional images of
  V0..Vn-1"; §2.3.2 item 2 says, for an NR image from PPC_i, "not captured by
  the conventional images of PPC_j, j = 0..i-1", and for peeling "by any
  conventional image". We report both and judge (c) on the thesis's text,
  which is the spec, for three measured reasons: (1) the thesis's own tree
  row (conventional I1 23 % redundant, NR I1 84 % occluded) is impossible
  under the issue's reading, where NR I1's first-layer samples (≥ 77 % of
  C1's pixels) are captured by C1; (2) its NR cells are reproduced far better
  under the literal reading, with percentages of C_i's samples: mean gap over
  the NR occluded/useful cells 29.0 → 18.9 points (pixel, 512²), 26.7 → 17.9
  (pixel, 1024²), 15.4 → 14.0 and 15.0 → 13.7 (visibility), e.g. nest NR I1
  53 % (91 %) against the thesis's 62 % (89 %) at 1024²; (3) under the issue's
  reading, an NR image's first-layer samples, seen from V_i and thus needed
  by the views near V_i, never count, while peeling's layer L0 counts in
  full although it is itself a conventional image of an intermediate view.
  Why the issue's reading goes against NR on our scenes (measured, per-image
  table above): *L0 is an intermediate view*, so its occluded samples are
  ~100 % useful, and with the pixel definition it is inflated by reprojection
  misses on sub-pixel triangles (L0 has 2.2-4.4× more occluded samples under
  the pixel than the visibility definition on nest, tree and grass);
  *our peeling layers 1-2 are far more useful than the thesis's* (useful
  share of L1's occluded samples 80 / 99 / 46 / 75 % on nest, grass, city,
  tree, pixel, 512², against 2 / 4 / 7 / 98 %): our occluders (twigs 4-10 mm,
  blades, leaves) are thin against the rig's eye baseline; and *NR images
  spend most samples on first-layer surfaces* V0 (or V0, V1) does not see.
  Ground, framing and borders are not the cause (variant without ground: < 1 %
  change; every view holds the content). The rig's spread, which Fig. 8 does
  not give, moves the issue-reading verdict but does not rescue it
  (`bench/results/rig_spread.md`, `python -m bench.rig_spread`, spreads
  5-30°, 512², 100 views): with the pixel definition (c) holds on 0 / 4 scenes
  at every spread; with the visibility definition on 3 / 4 at 5°, 2 / 4 at
  10-15°, 1 / 4 at 20° and 0 / 4 at 30°; with the thesis's reading on 4 / 4 at
  5-20°. (b) with the pixel definition fails at 512² at every spread. The
  thesis's conventional redundancy does not pin the spread down (mean gap
  12.6-15.1 points over the spreads, visibility; 16.2-22.6, pixel), so we keep
  20° rather than pick the value that favours NR.
* **(d) holds**: NR/conventional 1.16-1.32 and NR/peeling 0.91-1.07 at 1024²
  with either triangle-id source (llvmpipe, 15 interleaved rounds; Table 7).
  With 5 rounds one reading (grass, geometry shader) came out at NR/peeling
  1.34: single ratios on this shared 2-core machine move by ±20 %.
"""


def yes_no(ok: bool) -> str:
    """A criterion's verdict cell: "yes", or "**no**" in bold."""
    return "yes" if ok else "**no**"


def criteria_rows(results: list[dict], run: str) -> list[dict]:
    """Criteria (a)-(c) per scene and redundancy definition of one run: (a) the
    NR set has no redundant sample; (b) NR's available samples, average and
    minimum over the intermediate views, ≥ conventional's and ≥ peeling's; (c) NR
    holds at least as many useful occluded samples (totals over the 3 images)
    as peeling."""
    rows = []
    for r in results:
        if r["scene"] not in CRITERIA_SCENES:
            continue
        for red in ("pixel", "visibility"):
            m = r["metrics"]
            cv, nr, pe = (m[f"{red}/{k}"] for k in METHODS)
            rows.append({
                "scene": r["scene"], "run": run, "definition": red,
                "a_nr_redundant": nr["total"]["redundant"],
                "a_edge_ties": sum(nr.get("redundant_edge_ties") or [0]),
                "a": nr["total"]["redundant"] == sum(nr.get("redundant_edge_ties") or [0]),
                "avail_avg": (nr["available_avg"], cv["available_avg"], pe["available_avg"]),
                "avail_min": (nr["available_min"], cv["available_min"], pe["available_min"]),
                "b": (nr["available_avg"] >= max(cv["available_avg"], pe["available_avg"])
                      and nr["available_min"] >= max(cv["available_min"], pe["available_min"])),
                "useful": (nr["total"]["useful"], pe["total"]["useful"]),
                "c": nr["total"]["useful"] >= pe["total"]["useful"],
                # The thesis's literal reading of "occluded" (None for runs made before it was counted).
                "useful_earlier": ((nr["total"]["useful_earlier"], pe["total"]["useful_earlier"])
                                   if nr["total"].get("useful_earlier") is not None else None),
                "c_earlier": (nr["total"]["useful_earlier"] >= pe["total"]["useful_earlier"]
                              if nr["total"].get("useful_earlier") is not None else None),
                "nr_images": {k: nr.get(k) for k in ("samples", "occluded", "useful", "occluded_earlier",
                                                      "useful_earlier")},
                "peel_images": {k: pe[k] for k in ("samples", "occluded", "useful")},
            })
    return rows


def verdict_counts(rows: list[dict]) -> tuple[str, str, str]:
    """'k / n' scenes where (b), (c) with the issue's reading and (c) with the
    thesis's reading hold, over `criteria_rows` of one definition."""
    n = len(rows)
    return (f"{sum(bool(x['b']) for x in rows)} / {n}", f"{sum(bool(x['c']) for x in rows)} / {n}",
            f"{sum(bool(x['c_earlier']) for x in rows)} / {n}")


def criteria_tables(runs: list[tuple[str, list[dict]]], timing_results: list[dict]) -> tuple[str, dict]:
    """Markdown for issue 3's criteria over several runs (label, results) and the
    Table 7 timing, plus a JSON-ready summary."""
    rows = [row for label, res in runs for row in criteria_rows(res, label)]
    def useful_cell(pair: tuple[int, int] | None, ok: bool | None) -> str:
        return "—" if pair is None else f"{pair[0]:,} / {pair[1]:,} · {yes_no(bool(ok))}"

    table = md_table(
        ["scene", "run", "definition", "(a) NR redundant", "available avg NR / conv / peel [%]",
         "available min NR / conv / peel [%]", "(b) holds", "(c) useful occluded NR / peel, thesis reading",
         "(c) useful occluded NR / peel, issue reading"],
        [[r["scene"], r["run"], r["definition"],
          f"{r['a_nr_redundant']:,}" + (f" ({r['a_edge_ties']:,} ties)" if r["a_edge_ties"] else "")
          + f" · {yes_no(r['a'])}",
          " / ".join(f"{100 * x:.2f}" for x in r["avail_avg"]), " / ".join(f"{100 * x:.2f}" for x in r["avail_min"]),
          yes_no(r["b"]), useful_cell(r["useful_earlier"], r["c_earlier"]), useful_cell(r["useful"], r["c"])]
         for r in rows])
    counts = []
    summary: dict = {"rows": [{k: v for k, v in r.items() if not k.endswith("_images")} for r in rows]}

    def verdict(n: int | None, total: int) -> str:
        return "—" if n is None else f"{n} / {total} ({'holds' if n >= 3 else '**fails**'}: needs ≥ 3)"

    for label, _ in runs:
        for red in ("pixel", "visibility"):
            sel = [r for r in rows if r["run"] == label and r["definition"] == red]
            nc, nb = sum(r["c"] for r in sel), sum(r["b"] for r in sel)
            ne = None if any(r["c_earlier"] is None for r in sel) else sum(r["c_earlier"] for r in sel)
            counts.append([label, red, f"{sum(r['a'] for r in sel)} / {len(sel)}", f"{nb} / {len(sel)}",
                           verdict(ne, len(sel)), verdict(nc, len(sel))])
            summary[f"{label}/{red}"] = {"a": sum(r["a"] for r in sel), "b": nb, "c": nc, "c_earlier": ne,
                                         "scenes": len(sel)}
    count_table = md_table(["run", "definition", "(a) scenes", "(b) scenes", "(c) scenes, thesis reading",
                            "(c) scenes, issue reading"], counts)
    trows = []
    for r in timing_results:
        tm = r.get("timing")
        if r["scene"] not in CRITERIA_SCENES or not tm:
            continue
        for label in ("prim_id", "geom_shader"):
            if label in tm:
                t = tm[label]
                ok = t["nr_over_conventional"] <= MAX_NR_OVER_CONV and t["nr_over_peeling"] <= MAX_NR_OVER_PEEL
                trows.append([r["scene"], "gl_PrimitiveID" if label == "prim_id" else "geometry shader",
                              f"{tm['res']}²", f"{t['nr_over_conventional']:.2f}", f"{t['nr_over_peeling']:.2f}",
                              yes_no(ok)])
                summary.setdefault("d", {})[f"{r['scene']}/{label}"] = ok
    ttable = md_table(["scene", "triangle id from", "res", "NR / conv (≤ 2.5)", "NR / peel (≤ 1.3)", "(d) holds"],
                      trows)
    drows = []
    for r in rows:
        n, p = r["nr_images"], r["peel_images"]
        def pair(xs: list[int] | None) -> str:
            return "—" if xs is None else " / ".join(f"{x:,}" for x in xs[1:])

        drows.append([r["scene"], r["run"], r["definition"], pair(n["samples"]), pair(n["occluded_earlier"]),
                      pair(n["useful_earlier"]), pair(n["occluded"]), pair(n["useful"]),
                      " / ".join(f"{x:,}" for x in p["samples"]), " / ".join(f"{x:,}" for x in p["occluded"]),
                      " / ".join(f"{x:,}" for x in p["useful"])])
    dtable = md_table(["scene", "run", "definition", "NR samples I1 / I2", "NR occluded I1 / I2 (thesis r.)",
                       "NR useful I1 / I2 (thesis r.)", "NR occluded I1 / I2 (issue r.)",
                       "NR useful I1 / I2 (issue r.)",
                       "peel samples L0 / L1 / L2", "peel occluded L0 / L1 / L2", "peel useful L0 / L1 / L2"], drows)
    md = ["Criteria (a)-(c) per scene and redundancy definition; (a) counts the NR set's samples redundant "
          "with an earlier image of the set, and in parentheses those of them that are texel-edge float ties "
          "(pixel definition: the projection is within 1e-3 texel of a texel edge, where GL's float32 Alg. 3 "
          "and the reference's float64 test may pick neighbouring texels; `reference.sampling_metrics`); (a) "
          "holds when every redundant sample is such a tie. Available samples in percent of the "
          "intermediate view's samples (average and minimum over the views); useful occluded samples are "
          "totals over the three images.", "", table, "", count_table, "",
          *(["Criterion (d), Table 7 timing (median of interleaved rounds):", "", ttable, ""] if trows else
            ["Criterion (d), Table 7 timing: not timed in this run.", ""]),
          "Where the useful occluded samples come from (per image; NR I0 = C0 has none by construction; "
          "peeling layer L0 is the conventional image of the centroid view):", "", dtable, ""]
    return "\n".join(md), summary


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
    crit_md, crit = criteria_tables(runs, results)
    md += ["## Issue 3, \"Done when\": the criteria, scene by scene", "",
           "Runs: " + "; ".join(f"{label} ({'this file' if k == 0 else 'see ' + e['_path']})"
                                for k, ((label, _), e) in enumerate(zip(runs, [{}] + list(extra_runs or []),
                                                                          strict=True))) + ".", "",
           crit_md, CRITERIA_NOTES, ""]
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
    md += [DISCUSSION, "## Stage times [s]", "",
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
    return (f"This run uses {res}² and {views} views: on this shared 2-core machine the Embree casts of 1000 "
            "intermediate views per scene (plus the visibility-definition layer walks) at 1024² take 17-43 min per "
            "scene (`sampling_1024_1000v/`, run scene by scene and joined with --merge), so the defaults are sized "
            "to finish within about 10 minutes; pass --res 1024 --views 1000 for the target.")


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
    return args


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
        for r in d["scenes"]:
            png = path.parent / r["table3_png"]
            r["table3_png"] = os.path.relpath(png, out)
            scenes.append(r)
        stages.update(d["stage_seconds"])
    base = parts[0][1]
    data = {**base, "scenes": scenes, "stage_seconds": stages, "wall_s": sum(d["wall_s"] for _, d in parts),
            "command": " ; ".join(d["command"] for _, d in parts), "scenes_without_ground": [], "sweep": None,
            "merged_from": [os.path.relpath(p, out) for p, _ in parts]}
    data["config"]["scenes"] = [r["scene"] for r in scenes]
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

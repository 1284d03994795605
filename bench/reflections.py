"""Cluster depth-image reflections vs Embree vs environment map (thesis §4.7, Tables 12–14, 19).

For each scene (default: the built-in living_room and bathroom, the thesis's two
Chapter 4 scenes, plus the small planar `mirror` scene):

* Table 12-like triplet at --res (512²): environment map | Embree | ours (PNG,
  sRGB), with ×50 error images against Embree, per-channel mean absolute errors on
  the 0–255 scale (the thesis's "6, 3, 9") and the occlusion-error percentage;
* Table 13/14: frame times of ours (median of --repeat, per-step breakdown:
  G-buffer, clustering, cluster cameras, depth images, intersection, resolve) and
  Embree (BVH build + tracing, the thesis rebuilt the BVH every frame of its
  dynamic scenes), fps ratio ours/Embree, at 512² and 2048²;
* Table 19 / §4.7.1: occlusion-error pixel percentage (max/mean over the frames)
  and cluster counts along an orbit path and a fly-through path.

Occlusion error, two metrics (percentages of the reflective pixels):

* thesis (§4.4 / §4.7.1, reference.occlusion): the true (Embree) mirror-ray hit of a
  reflective sample is not held by its cluster's depth image (outside the image or
  not stored in any of its layers); counted per reflected ray (the thesis's
  "reflective pixels" are its 2×2-supersampled first-pass pixels, one mirror ray
  each; the issue's 3.5 % criterion is judged on it) and per output pixel (any of
  its 4 rays; stricter);
* strict (reference.image_metrics.occlusion_error_mask): our mirror-ray length
  differs from Embree's by > 5 % (or one of them misses); it also counts every
  failure of our march (Alg. 7) on a surface the image does hold, and is reported
  beside the thesis's, split into "not captured" (also a thesis error) and
  "captured" (a march failure or length disagreement on a held surface).

The thesis measured 900–1000 frames per path on a GTX 570; here everything runs on
a CPU-only shared machine (Mesa llvmpipe + embreex), where one 512² frame of
either method takes seconds, so the paths have --frames frames (default 24) at
--path-res (default 512², the output resolution of the issue) — the reason is run time, not method.

    python -m bench.reflections [--scenes living_room bathroom mirror] [--res 512]
        [--timing-res 256 512 1024 2048] [--frames 24] [--path-res 512] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from bench.common import (
    RESULTS_DIR,
    git_revision,
    load_named_scene,
    machine_info,
    machine_markdown,
    md_table,
    span,
    write_json,
    write_text,
)
from gl_passes.context import create_gl_context
from gl_passes.reflections import DEFAULT_SETTINGS, STEPS, ClusterReflections
from gl_passes.upload import SceneGPU
from reference.image_metrics import (
    error_image,
    mean_abs_error,
    occlusion_error_mask,
    occlusion_error_percentage,
)
from reference.occlusion import captured_by_clusters, uncaptured_error_mask, uncaptured_ray_percentage
from reference.raycast import RayCaster
from reference.reflections import envmap_reflections, raytrace_reflections
from scenes.camera import flythrough_path, orbit_path


def to_png(img: np.ndarray, path: Path) -> None:
    from PIL import Image

    srgb = np.where(img <= 0.0031308, 12.92 * img, 1.055 * np.power(np.clip(img, 0, None), 1 / 2.4) - 0.055)
    Image.fromarray((np.clip(srgb, 0, 1) * 255 + 0.5).astype(np.uint8)).save(path)


def view_camera(scene, res: int):
    """The Table 12 view: frame 1 of the fly-through path (inside the room)."""
    return flythrough_path(scene.bounds, 8, width=res, height=res)[1]


def occlusion_metrics(ours, ref) -> tuple[dict, np.ndarray, np.ndarray]:
    """Both occlusion-error metrics of one frame (module docstring): ({percentages of
    the reflective pixels}, strict mask, thesis mask). ours must be rendered with
    diagnostics=True. Keys: occlusion_pct (strict), occlusion_thesis_ray_pct (thesis,
    per reflected ray = first-pass reflective pixel), occlusion_thesis_pct (thesis,
    output pixels with any such ray),
    strict_not_captured_pct (strict and thesis), strict_captured_pct (strict only: a
    march failure or length disagreement where the image holds the true hit, or a
    hit of ours where Embree's ray escapes), thesis_only_pct (not held, yet our length
    agrees within 5 %)."""
    mask = ref.reflective
    strict = occlusion_error_mask(ours.ray_length, ref.ray_length, mask)
    cap = captured_by_clusters(ours.diagnostics, ref.hit_points_samples, ref.hit_normals_samples)
    thesis = uncaptured_error_mask(ref.reflective_samples, ref.hit_points_samples, cap, ref.supersample) & mask
    pct = {"occlusion_pct": occlusion_error_percentage(strict, mask),
           "occlusion_thesis_ray_pct": uncaptured_ray_percentage(ref.reflective_samples, ref.hit_points_samples, cap),
           "occlusion_thesis_pct": occlusion_error_percentage(thesis, mask),
           "strict_not_captured_pct": occlusion_error_percentage(strict & thesis, mask),
           "strict_captured_pct": occlusion_error_percentage(strict & ~thesis, mask),
           "thesis_only_pct": occlusion_error_percentage(thesis & ~strict, mask)}
    return pct, strict, thesis


def triplet(name, scene, sg, refl, caster, res, out_dir: Path) -> dict:
    cam = view_camera(scene, res)
    ours = refl.render(sg, cam, diagnostics=True)
    ref = raytrace_reflections(scene, cam, caster=caster)
    env = envmap_reflections(scene, cam, caster=caster)
    mask = ref.reflective
    row = {"scene": name, "res": res, "clusters": ours.n_clusters, "reflective_pct": 100 * float(mask.mean())}
    for label, img in (("ours", ours.color), ("envmap", env.color)):
        row[f"mae_{label}_255"] = (mean_abs_error(img, ref.color, per_channel=True) * 255).tolist()
        row[f"mae_{label}_reflective_255"] = (mean_abs_error(img, ref.color, mask, per_channel=True) * 255).tolist()
    pct, occ, thesis = occlusion_metrics(ours, ref)
    row.update(pct)
    strip = np.concatenate([env.color, ref.color, ours.color], axis=1)
    errs = np.concatenate([error_image(env.color, ref.color), np.zeros_like(ref.color),
                           error_image(ours.color, ref.color)], axis=1)
    occ_img = np.zeros_like(ref.color)
    occ_img[mask] = 0.25
    occ_img[occ & ~thesis] = (1.0, 0.8, 0.0)   # strict only: captured, our march disagrees
    occ_img[thesis & ~occ] = (0.2, 0.4, 1.0)   # thesis only: not captured, our length agrees anyway
    occ_img[occ & thesis] = (1.0, 0.0, 0.0)    # both: the true hit is not in the cluster image
    to_png(strip, out_dir / f"reflections_{name}_triplet.png")
    from PIL import Image

    Image.fromarray((errs * 255).astype(np.uint8)).save(out_dir / f"reflections_{name}_error_x50.png")
    Image.fromarray((occ_img * 255).astype(np.uint8)).save(out_dir / f"reflections_{name}_occlusion.png")
    return row


def timing(name, scene, sg, refl, res, repeat) -> dict:
    """Frame time per step of ours (median of `repeat` frames after a warm-up that
    also fills the per-scene caches, as the service's second frame) and of Embree
    (BVH build shown apart; trace with the BVH cached), both with the settings'
    supersampling and glossy rays (the same rays on both sides), and beside them the
    frame's quality against that Embree image: MAE per channel (0–255) and the
    thesis occlusion error per reflected ray (one more frame, diagnostics=True)."""
    st = refl.settings
    cam = view_camera(scene, res)
    refl.render(sg, cam)  # warm-up (program compile, atlas allocation, per-scene records)
    runs = [refl.render(sg, cam) for _ in range(repeat)]
    steps = {k: float(np.median([r.timings_ms[k] for r in runs])) for k in (*STEPS, "total")}
    t0 = time.perf_counter()
    caster = RayCaster(scene)
    build = (time.perf_counter() - t0) * 1e3
    t0 = time.perf_counter()
    ref = raytrace_reflections(scene, cam, supersample=st.supersample, glossy_rays=st.glossy_rays, caster=caster)
    trace = (time.perf_counter() - t0) * 1e3
    ours = refl.render(sg, cam, diagnostics=True)
    occ = occlusion_metrics(ours, ref)[0]
    return {"scene": name, "res": res, "clusters": runs[-1].n_clusters, "atlas": runs[-1].atlas_size,
            "ours_ms": steps, "embree_build_ms": build, "embree_trace_ms": trace,
            "fps_ours": 1e3 / steps["total"], "fps_embree": 1e3 / (build + trace),
            "speedup": (build + trace) / steps["total"], "trace_ratio": steps["total"] / trace,
            "mae_255": [float(x) * 255 for x in mean_abs_error(ours.color, ref.color, per_channel=True)],
            "occlusion_thesis_ray_pct": occ["occlusion_thesis_ray_pct"],
            "clustering_passes_ms": ours.clustering_ms}


def path_stats(name, scene, sg, refl, caster, frames, res) -> list[dict]:
    out = []
    for pname, cams in (("orbit", orbit_path(scene.bounds, frames, distance=0.9, width=res, height=res)),
                        ("flythrough", flythrough_path(scene.bounds, frames, width=res, height=res))):
        per: dict[str, list[float]] = {}
        clusters, refl_pct = [], []
        for cam in cams:
            ours = refl.render(sg, cam, diagnostics=True)
            ref = raytrace_reflections(scene, cam, caster=caster)
            for key, value in occlusion_metrics(ours, ref)[0].items():
                per.setdefault(key, []).append(value)
            clusters.append(ours.n_clusters)
            refl_pct.append(100 * float(ref.reflective.mean()))
        row = {"scene": name, "path": pname, "frames": frames, "res": res,
               "clusters_max": max(clusters), "clusters_mean": float(np.mean(clusters)),
               "reflective_pct_max": max(refl_pct), "reflective_pct_mean": float(np.mean(refl_pct)),
               "clusters": clusters}
        for key, values in per.items():  # occlusion_pct (strict), occlusion_thesis_pct, breakdown
            row[f"{key}_max"], row[f"{key}_mean"], row[key] = max(values), float(np.mean(values)), values
        out.append(row)
    return out


MAE_BOUND_255 = 6.0        # issue 4: image MAE per channel (thesis Fig. 26: 6, 3, 9)
OCCLUSION_BOUND_PCT = 3.5  # issue 4: occlusion-error pixels, average along the paths (thesis bathroom 2.75 %)
ROOMS = ("living_room", "bathroom")
#: issue 17: ours / Embree trace time (BVH cached) per output resolution.
TRACE_RATIO_BOUND = {512: 2 / 3, 2048: 1 / 4}
#: issue 17: the thesis occlusion error per ray at the Table 12 view before it
#: (bench/results/reflections.md of issue 4); allowed: + 0.3 points.
OCCLUSION_BASELINE_PCT = {"living_room": 1.03, "bathroom": 2.16}
OCCLUSION_METRICS_TEXT = (
    "Occlusion error, two metrics (percent of the reflective pixels): **thesis** (§4.4 / §4.7.1, "
    "`reference.occlusion`): a reflective sample's true (Embree) mirror-ray hit is not held by its cluster's "
    "depth image (outside the image, or no stored layer within ±1 texel has it on its tangent plane within 1 % "
    "of depth) — the thesis's definition, counted per reflected ray (the thesis's \"reflective pixels\" are the "
    "pixels of its first pass, which runs at the 2×2 supersampled resolution, one mirror ray each; §4.2, §4.7.1), "
    "on which the 3.5 % criterion is judged, and per output pixel (an error when any of its 4 rays is; "
    "stricter); **strict** "
    "(`reference.image_metrics.occlusion_error_mask`): our mirror-ray length differs from Embree's by > 5 % or "
    "one of them misses — it also counts every failure of our march (Alg. 7) on a surface the image does hold. "
    "Breakdown of the strict errors: *not captured* (also thesis errors) and *captured* (the image holds the "
    "true hit but our march found another length, or found a hit where Embree's ray escapes).")


#: One-off measurements the report's prose quotes (with how they were measured).
NOTES_JSON = RESULTS_DIR / "reflections_notes.json"
FRACTION_WORDS = {2: "half", 3: "a third", 4: "a quarter", 5: "a fifth"}


def speed_directions() -> list[str]:
    """Markdown of issue 17's speed directions (NOTES_JSON "speed_directions": what
    each gave, measured side by side, and whether it was kept)."""
    notes = json.loads(NOTES_JSON.read_text()).get("speed_directions")
    if not notes:
        return []
    return ["### Speed directions tried (issue 17)", "", notes["about"], "",
            md_table(["direction", "change", "measured", "kept"],
                     [[r["direction"], r["change"], r["measured"], r["kept"]] for r in notes["rows"]]), ""]


def step_breakdown(timings: list[dict]) -> str:
    """What the step breakdown says, its numbers from the timing rows of the rooms
    (lowest and highest resolution) and NOTES_JSON."""
    rooms = [t for t in timings if t["scene"] in ROOMS]
    lo, hi = min(t["res"] for t in rooms), max(t["res"] for t in rooms)
    at = {(t["scene"], t["res"]): t for t in rooms}
    names = sorted({t["scene"] for t in rooms})
    growth = [at[n, hi]["embree_trace_ms"] / at[n, lo]["embree_trace_ms"] for n in names]
    clusters = [t["clusters"] for t in rooms]
    share = np.mean([at[n, hi]["ours_ms"]["intersection"] / at[n, hi]["embree_trace_ms"] for n in names])
    part = FRACTION_WORDS.get(round(1 / share), f"{100 * share:.0f} %")
    layer_cost = json.loads(NOTES_JSON.read_text())["fourth_layer_depth_image_cost_pct"]["value"]
    return (
        f"What the breakdown says: Embree's cost grows with the rays (about {span(growth, '.0f', '–')}× "
        f"from {lo}² to {hi}²), ours splits "
        "into steps that grow with the samples (G-buffer, clustering, cluster cameras' extent passes, "
        "intersection, resolve) and one that does not: the cluster depth images, every cluster's frustum-culled "
        "triangles drawn into four layers, on llvmpipe about half vertex work (its CPU vertex pipeline) "
        "and half rasterisation and fragments (the speed directions below) "
        f"({min(clusters)}–{max(clusters)} clusters). At "
        f"{lo}² that step is the largest and keeps us below Embree; at {hi}² it is amortised and the per-ray "
        f"march (a few texel fetches per step; blocks without a possible hit skipped) costs about {part} of "
        f"Embree's trace. The fourth layer (the other objects' second surface) adds {layer_cost} % to the depth-image "
        "time and buys most of the drop in occlusion error (the layers sweep below).")


def _mean_max(rows: list[dict], key: str) -> tuple[float, float, int] | None:
    """(mean, max, frames) of the per-frame values `key` over path rows; None when
    the rows predate that metric."""
    vals = [x for p in rows for x in p.get(key, [])]
    return (float(np.mean(vals)), float(np.max(vals)), len(vals)) if vals else None


def done_when(quality: list[dict], timings: list[dict], paths: list[dict]) -> list[str]:
    """Markdown lines: each "Done when" criterion of issue 4 and whether it holds."""
    lines = []
    worst = max((max(q["mae_ours_255"]) for q in quality), default=float("nan"))
    ok = worst <= MAE_BOUND_255
    lines.append(f"- Image MAE ≤ {MAE_BOUND_255:g}/255 per channel: worst {worst:.2f}/255 — "
                 f"**{'holds' if ok else 'does not hold'}**.")
    mirror = [q for q in quality if q["scene"] == "mirror"]
    if mirror:
        q = mirror[0]
        thesis = q.get("occlusion_thesis_pct", 0.0)
        ok = q["occlusion_pct"] <= 0.05 and thesis <= 0.05 and max(q["mae_ours_255"]) < 1.0
        lines.append(f"- Planar mirror exact (cluster camera = e0, no occlusion error): MAE "
                     f"{max(q['mae_ours_255']):.2f}/255 (< 1 required), occlusion-error px "
                     + (f"thesis {thesis:.2f} %, " if "occlusion_thesis_pct" in q else "")
                     + f"strict {q['occlusion_pct']:.2f} % (≤ 0.05 % required, i.e. a few pixels of the image) — "
                     f"**{'holds' if ok else 'does not hold'}**.")
    for name in ROOMS:
        pp = [p for p in paths if p["scene"] == name]
        if not pp:
            continue
        strict = _mean_max(pp, "occlusion_pct")
        thesis_px = _mean_max(pp, "occlusion_thesis_pct")
        thesis = _mean_max(pp, "occlusion_thesis_ray_pct") or thesis_px
        s_txt = f"strict avg {strict[0]:.2f} %, max {strict[1]:.2f} %"
        if thesis is None:  # results from before the thesis metric: judged on the strict one
            lines.append(f"- {name}: occlusion-error px along the paths ≤ {OCCLUSION_BOUND_PCT:g} % on average: "
                         f"{s_txt} over {strict[2]} frames (thesis definition not measured) — "
                         f"**{'holds' if strict[0] <= OCCLUSION_BOUND_PCT else 'does not hold'}**.")
            continue
        cap = _mean_max(pp, "strict_captured_pct")
        unit = "reflected ray" if _mean_max(pp, "occlusion_thesis_ray_pct") else "output pixel"
        lines.append(f"- {name}: occlusion error along the paths ≤ {OCCLUSION_BOUND_PCT:g} % on average (thesis "
                     f"definition: true hit not held by the cluster image, per {unit}): avg {thesis[0]:.2f} %, max "
                     f"{thesis[1]:.2f} % over {thesis[2]} frames — "
                     f"**{'holds' if thesis[0] <= OCCLUSION_BOUND_PCT else 'does not hold'}**"
                     + (f"; per output pixel (any of its 4 rays) avg {thesis_px[0]:.2f} %, max {thesis_px[1]:.2f} %"
                        if unit == "reflected ray" else "")
                     + "; beside it the strict "
                     f"metric (any ray-length disagreement, march failures included): {s_txt}"
                     + (f", of which {cap[0]:.2f} % on average are pixels whose true hit the image holds (our march "
                        f"found another length or none)" if cap else "")
                     + ".")
    for res in sorted({t["res"] for t in timings}):
        for t in (t for t in timings if t["res"] == res and t["scene"] in ROOMS):
            steps = t["ours_ms"]
            top = max(STEPS, key=lambda k: steps.get(k, 0.0))
            need = ("required: faster than Embree" if res >= 2048
                    else "required: as close to Embree as the step breakdown allows")
            verdict = ("holds" if t["speedup"] > 1.0 else "does not hold") if res >= 2048 else (
                "faster than Embree" if t["speedup"] > 1.0 else "slower than Embree")
            lines.append(f"- {t['scene']} {res}²: ours / Embree speed {t['speedup']:.2f}× ({need}; largest step "
                         f"{top} {steps[top]:.0f} of {steps['total']:.0f} ms) — **{verdict}**.")
    lines += done_when_issue17(quality, timings)
    return lines


def done_when_issue17(quality: list[dict], timings: list[dict]) -> list[str]:
    """Markdown lines: issue 17's criteria (ours ≤ 2/3 of Embree's trace time, BVH
    cached, at 512² and ≤ 1/4 at 2048², the same rays on both sides; MAE ≤ 1/255 per
    channel on average; the thesis occlusion error per ray no more than 0.3 points
    above issue 4's results), for the rooms; rows measured before `trace_ratio`
    existed are skipped."""
    lines = []
    for t in timings:
        if t["scene"] not in ROOMS or "trace_ratio" not in t or t["res"] not in TRACE_RATIO_BOUND:
            continue
        bound = TRACE_RATIO_BOUND[t["res"]]
        ok = t["trace_ratio"] <= bound
        steps = t["ours_ms"]
        before = sum(steps.get(k, 0.0) for k in STEPS[:STEPS.index("intersection")])
        lines.append(f"- issue 17, {t['scene']} {t['res']}²: ours / Embree trace (BVH cached) time "
                     f"{t['trace_ratio']:.2f} (≤ {bound:.2f} required) — **{'holds' if ok else 'does not hold'}**"
                     + ("." if ok else f": {bound * t['embree_trace_ms']:.0f} ms allowed; the steps before the "
                        f"intersection take {before:.0f} ms, the intersection {steps['intersection']:.0f} ms."))
    for q in quality:
        if q["scene"] not in OCCLUSION_BASELINE_PCT or "occlusion_thesis_ray_pct" not in q:
            continue
        base, occ = OCCLUSION_BASELINE_PCT[q["scene"]], q["occlusion_thesis_ray_pct"]
        mae = float(np.mean(q["mae_ours_255"]))
        ok = occ <= base + 0.3 and mae <= 1.0
        lines.append(f"- issue 17, {q['scene']} quality: MAE {mae:.2f}/255 on average (≤ 1 required), occlusion "
                     f"error (thesis, per ray) {occ:.2f} % (≤ {base:.2f} + 0.3 required) — "
                     f"**{'holds' if ok else 'does not hold'}**.")
    return lines


def _sweep_section(sweeps: list[dict], key: str, title: str, text: str, headers: list[str], row) -> list[str]:
    """Markdown of one sweep table (empty when no scene has `key`): title, text, and
    one row per swept value, the scene first, then row(r)."""
    t = [s for s in sweeps if key in s]
    if not t:
        return []
    return [title, "", text, "", md_table(["scene", *headers], [[s["scene"], *row(r)] for s in t for r in s[key]]), ""]


#: How the report names a sweep table without a stamp (bench.reflection_sweeps stamps each table it measures).
UNSTAMPED_SWEEPS = "not stamped"


def sweeps_measured(sweeps: list[dict]) -> list[str]:
    """When and at which commit the sweep tables were measured: a line per stamp,
    naming its tables and scenes."""
    by_stamp: dict[str, tuple[set[str], set[str]]] = {}
    for s in sweeps:
        for k in s:
            if k.startswith("table"):
                keys, scenes = by_stamp.setdefault(s.get("measured", {}).get(k, UNSTAMPED_SWEEPS), (set(), set()))
                keys.add(k.removeprefix("table"))
                scenes.add(s["scene"])
    return [f"- {', '.join(sorted(keys))} ({', '.join(sorted(scenes))}): {stamp}"
            for stamp, (keys, scenes) in by_stamp.items()]


def sweeps_markdown(sweeps: list[dict]) -> list[str]:
    """Markdown for Tables 15–18 and 20 (empty when there are no sweeps)."""
    if not sweeps:
        return []

    def f(x, d=2):
        return f"{x:.{d}f}"

    res = sweeps[0]["res"]
    md = [f"## Parameter sweeps (Tables 15–18, 20; §4.7.2) at {res}² unless stated", "",
          "`bench/reflection_sweeps.py`: the Table 12 view, one parameter at a time, single frames after a "
          "warm-up on the shared machine (compare within a table). Thesis values (GTX 570) in the captions.", "",
          *sweeps_measured(sweeps), ""]
    t = [s for s in sweeps if "table15" in s]
    if t:
        md += ["### Table 15: clusters (thesis: 156 / 141 / 123 / 86 / 32 clusters → 12 / 13 / 15 / 15 / 20 fps)",
               "", "bin_scale multiplies the §4.3 bin counts (> 1: more than 13 × 8 bins on large reflectors, "
               "for this sweep only). Occlusion error: the thesis's definition, per reflected ray.", "",
               md_table(["scene", "bin_scale", "clusters", "fps ours", "occlusion error"],
                        [[s["scene"], r["bin_scale"], r["clusters"], f(r["fps"], 3),
                          f(r["occlusion_thesis_ray_pct"]) + " %"] for s in t for r in s["table15"]]), ""]
    t = [s for s in sweeps if "table16" in s]
    if t:
        md += ["### Table 16: output resolution (thesis: 2048² / 1024² / 512² / 256² → 7.5 / 15 / 23 / 29 fps)", "",
               md_table(["scene", "output", "fps ours"],
                        [[s["scene"], f"{r['res']}²", f(r["fps"], 3)] for s in t for r in s["table16"]]), ""]
    lifted = all("atlas_texels" in r for s in sweeps for r in s.get("table17", []))
    md += _sweep_section(
        sweeps, "table17", "### Table 17: cluster image scale (thesis: 1/2 / 1 / 2 → 15 / 15 / 14 fps)",
        "resolution_scale with the atlas budget lifted (atlas_budget None): the atlas still shrinks uniformly to "
        "atlas_max per side, so where that binds (atlas texels) the scale changes little. Occlusion error: the "
        "thesis's definition, per reflected ray." if lifted
        else "Measured under the default atlas budget, which caps the images' total area whatever the scale.",
        ["image scale", "atlas texels", "fps ours", "occlusion error"],
        lambda r: [r["scale"], _mtexels(r), f(r["fps"], 3), f(r["occlusion_thesis_ray_pct"]) + " %"])
    md += _sweep_section(
        sweeps, "tablelayers", "### Cluster-image layers (beyond the thesis): the other objects' second surface",
        "Non-planar clusters' images get a fourth layer, the second surface of the objects other than the "
        "reflector (their shifted camera e_c is not on the rays, so what a ray meets can hide behind another "
        "object seen from e_c); planar clusters (e_c = e0 on every ray) skip it. Occlusion error: the "
        "thesis's definition, per reflected ray.",
        ["others' 2nd surface", "fps ours", "occlusion error"],
        lambda r: ["on" if r["others_peel"] else "off", f(r["fps"], 3), f(r["occlusion_thesis_ray_pct"]) + " %"])
    md += _sweep_section(
        sweeps, "tablelod", "### Levels of detail (beyond the thesis): the other objects of non-planar cluster images",
        "Each object other than the reflector drawn at the coarsest meshoptimizer level (built once per "
        "scene) whose error is at most `lod_texels` texels of the cluster image at its nearest depth; planar "
        "clusters and the reflector stay at full detail. MAE against Embree (0–255); occlusion error: the "
        "thesis's definition, per reflected ray.",
        ["LOD error bound [texels]", "fps ours", "depth images [ms]", "chunks drawn", "MAE", "occlusion error"],
        lambda r: ["off" if r["lod_texels"] == 0 else r["lod_texels"], f(r["fps"], 3),
                   f(r.get("depth_images_ms", float("nan")), 0), r.get("drawn_chunks", "–"),
                   f(r.get("mae_255", float("nan")), 2), f(r["occlusion_thesis_ray_pct"]) + " %"])
    md += _sweep_section(
        sweeps, "tablebudget", "### Atlas budget (beyond the thesis): texels per G-buffer sample",
        "ClusterSettings atlas_budget caps the cluster images' total area at that many texels per G-buffer "
        "sample: over it the images shrink uniformly but planar mirrors', which keep their texel = sample grid "
        f"(cluster_camera.pack_atlas); the default is {DEFAULT_SETTINGS.atlas_budget:g}. MAE against Embree "
        "(0–255); occlusion error: the thesis's definition, per reflected ray.",
        ["budget [texels / sample]", "atlas texels", "fps ours", "depth images [ms]", "MAE", "occlusion error"],
        lambda r: [r["atlas_budget"], _mtexels(r), f(r["fps"], 3), f(r["depth_images_ms"], 0), f(r["mae_255"], 2),
                   f(r["occlusion_thesis_ray_pct"]) + " %"])
    t = [s for s in sweeps if "table18" in s]
    if t:
        md += ["### Table 18: diffuse triangles (thesis: 289k / 162k / 132k / 63k → 10 / 12 / 15 / 15 fps)", "",
               "Built-in detail 1, 0.5, 0.25 (the whole scene is re-tessellated); Embree = BVH build + trace.", "",
               md_table(["scene", "detail", "triangles", "diffuse triangles", "fps ours", "fps Embree",
                         "ours / Embree"],
                        [[s["scene"], r["detail"], f"{r['triangles']:,}", f"{r['diffuse_triangles']:,}",
                          f(r["fps_ours"], 3), f(r["fps_embree"], 3), f(r["fps_ours"] / r["fps_embree"]) + "×"]
                         for s in t for r in s["table18"]]), ""]
    t = [s for s in sweeps if "table20" in s]
    if t:
        md += ["### Table 20: glossy rays per reflective pixel (thesis, near-mirror: 8 / 49 rays → intersection "
               "112 / 651 ms, Optix 1 / 0.4 fps, ours 6 / 1.4 fps)", "",
               "Rays per G-buffer sample (the thesis's first-pass reflective pixel); Embree traces the same lobe "
               "rays; MAE against that Embree image (0–255).", "",
               md_table(["scene", "rays", "intersection [ms]", "fps ours", "fps Embree", "ours / Embree",
                         "MAE", "MAE on reflective px"],
                        [[s["scene"], r["rays"], f(r["intersection_ms"], 0), f(r["fps_ours"], 3),
                          f(r["fps_embree"], 3), f(r["fps_ours"] / r["fps_embree"]) + "×", f(r["mae_255"]),
                          f(r["mae_reflective_255"])] for s in t for r in s["table20"]]), ""]
    return md


def _mtexels(row: dict) -> str:
    """A sweep row's atlas area in millions of texels ("–" for rows measured before it was recorded)."""
    return f"{row['atlas_texels'] / 1e6:.1f} M" if "atlas_texels" in row else "–"


def _f(x: float, d: int = 1) -> str:
    return f"{x:.{d}f}"


def _pct(x: float | None, d: int = 2) -> str:
    return "—" if x is None else f"{x:.{d}f} %"


def quality_table(quality: list[dict]) -> str:
    """Markdown table of the quality rows (Table 12 / Fig. 26)."""
    f = _f
    return md_table(["scene", "triangles", "reflective px", "clusters", "ours MAE R,G,B (0–255)", "envmap MAE R,G,B",
                     "ours MAE on reflective px", "envmap MAE on reflective px", "occlusion error thesis, per ray",
                     "thesis, per output px", "occlusion-error px strict", "strict: not captured / captured"],
                    [[q["scene"], q.get("triangles", "—"), f(q["reflective_pct"]) + " %", q["clusters"],
                      ", ".join(f(x, 2) for x in q["mae_ours_255"]), ", ".join(f(x, 2) for x in q["mae_envmap_255"]),
                      ", ".join(f(x, 2) for x in q["mae_ours_reflective_255"]),
                      ", ".join(f(x, 2) for x in q["mae_envmap_reflective_255"]),
                      _pct(q.get("occlusion_thesis_ray_pct")), _pct(q.get("occlusion_thesis_pct")),
                      _pct(q["occlusion_pct"]),
                      f"{_pct(q.get('strict_not_captured_pct'))} / {_pct(q.get('strict_captured_pct'))}"]
                     for q in quality])


def timing_table(timings: list[dict]) -> str:
    """Markdown table of the timing rows (Tables 13, 14) with each row's quality."""
    f = _f
    return md_table(["scene", "res", "clusters", *STEPS, "total", "Embree BVH", "Embree trace", "fps ours",
                     "fps Embree", "ours / Embree speed", "ours / Embree trace time", "MAE R,G,B (0–255)",
                     "occlusion error thesis, per ray"],
                    [[t["scene"], t["res"], t["clusters"], *(f(t["ours_ms"].get(k, float("nan"))) for k in STEPS),
                      f(t["ours_ms"]["total"]), f(t["embree_build_ms"]), f(t["embree_trace_ms"]),
                      f(t["fps_ours"], 2), f(t["fps_embree"], 2), f(t["speedup"], 2) + "×",
                      f(t.get("trace_ratio", float("nan")), 2),
                      ", ".join(f"{x:.2f}" for x in t["mae_255"]) if "mae_255" in t else "–",
                      _pct(t.get("occlusion_thesis_ray_pct"))] for t in timings])


def gpu_json(out: Path) -> Path:
    """Where the same benchmark run on a GPU machine keeps its data (`--out <out>_gpu`)."""
    return out.with_name(out.name + "_gpu").with_suffix(".json")


def _growth(rows: dict[int, dict], key: str) -> str:
    """'a → b → c ms' of ours_ms[key] over the resolutions of `rows`."""
    return " → ".join(f"{rows[r]['ours_ms'][key]:.0f}" for r in sorted(rows)) + " ms"


def gpu_section(out: Path, cpu_timings: list[dict]) -> list[str]:
    """Markdown: issue 17 item 4's "same table on a GPU machine", from gpu_json(out)
    when it exists: machine, provenance, quality and timing tables, issue 17's
    criteria on those rows, and what sets them apart from this machine's rows."""
    path = gpu_json(out)
    if not path.exists():
        return []
    data = json.loads(path.read_text())
    timings, measured = data["timings"], data.get("measured", {})
    lines = ["## The same tables on a GPU machine (issue 17 item 4)", "",
             machine_markdown(data["machine"], shared=False), "",
             f"Measured {measured.get('date', '(date not stamped)')} at commit {measured.get('commit', '?')}: "
             f"`{measured.get('command', 'python -m bench.reflections')}`; data in `{path.name}`. "
             + measured.get("where", ""), "",
             quality_table(data["quality"]), "", timing_table(timings), "", *failed_lines(data.get("failed")),
             *done_when_issue17(data["quality"], timings), ""]
    reading = []
    cpu = {(t["scene"], t["res"]): t for t in cpu_timings}
    for name in sorted({t["scene"] for t in timings}):
        rows = {t["res"]: t for t in timings if t["scene"] == name}
        cpu_rows = {r: cpu[name, r] for r in rows if (name, r) in cpu}
        top = {r: max(STEPS, key=lambda k, t=t: t["ours_ms"].get(k, 0.0)) for r, t in rows.items()}
        text = (f"{name}: the largest step is " + ", ".join(f"{top[r]} at {r}²" for r in sorted(rows))
                + f"; clustering {_growth(rows, 'clustering')} on the GPU machine")
        if cpu_rows:
            text += f" against {_growth(cpu_rows, 'clustering')} on the CPU machine"
            hi = max(cpu_rows)
            text += (f"; Embree's trace at {hi}² takes {rows[hi]['embree_trace_ms']:.0f} ms there with "
                     f"{data['machine'].get('cpus_usable')} cores against {cpu_rows[hi]['embree_trace_ms']:.0f} ms "
                     "here (the reference's per-ray shading in numpy, one thread, does not shrink with the cores)")
        passes = rows[max(rows)].get("clustering_passes_ms")
        if passes:  # runs from before the per-pass times have none
            text += (f"; its passes at {max(rows)}² (each waited for): " + ", ".join(
                f"{k} {v:.0f}" for k, v in passes.items()) + f" ms, {max(passes, key=passes.get)} the largest")
        broken = [t for t in rows.values()
                  if np.mean(t["mae_255"]) > 1.0
                  or t["occlusion_thesis_ray_pct"] > OCCLUSION_BASELINE_PCT.get(name, np.inf) + 0.3]
        for t in broken:
            c = cpu.get((name, t["res"]))
            text += (f"; at {t['res']}² the frame is wrong there (MAE {np.mean(t['mae_255']):.2f}/255, occlusion "
                     f"error {t['occlusion_thesis_ray_pct']:.2f} % per ray"
                     + (f", against {np.mean(c['mae_255']):.2f}/255 and {c['occlusion_thesis_ray_pct']:.2f} % on "
                        "the CPU machine)" if c else ")"))
        reading.append(f"- {text}.")
    lines += ["What the GPU rows say (computed from the rows above and this machine's):", "", *reading, ""]
    if data.get("notes"):
        lines += [*(f"- {n}" for n in data["notes"]), ""]
    return lines


def failed_lines(failed: list[dict] | None) -> list[str]:
    """Markdown lines for the timing frames that raised (scene, res, error), if any."""
    return [*(f"- {t['scene']} {t['res']}²: the frame failed: {t['error']}" for t in failed), ""] if failed else []


def write_report(out: Path, info: dict, quality: list[dict], timings: list[dict], paths: list[dict],
                 res: int, frames: int, path_res: int, sweeps: list[dict] | None = None,
                 failed: list[dict] | None = None) -> None:
    """reflections.md; sweeps: Tables 15–18, 20 from bench/reflection_sweeps.py; the
    GPU machine's tables from gpu_json(out) when present; failed: timing frames that
    raised."""
    f = _f

    def mm(p, key):
        return "—" if f"{key}_max" not in p else f"{f(p[key + '_max'], 2)} / {f(p[key + '_mean'], 2)} %"

    md = ["# Reflections with cluster depth images (thesis §4.7, Tables 12–14, 19)", "",
          machine_markdown(info), "",
          "## Done when (issue 4)", "", *done_when(quality, timings, paths), "",
          f"## Quality at {res}² (2×2 supersampled; Table 12 / Fig. 26)", "",
          "Images: `reflections_<scene>_triplet.png` (envmap | Embree | ours), "
          "`reflections_<scene>_error_x50.png` (|envmap − Embree|·50 | — | |ours − Embree|·50), "
          "`reflections_<scene>_occlusion.png` (grey: reflective; red: not captured and strict error; yellow: "
          "strict only (captured, our march disagrees); blue: thesis only (not captured, our length agrees)).", "",
          OCCLUSION_METRICS_TEXT, "",
          quality_table(quality), "",
          "## Frame time per step (Tables 13, 14; ms, median; 2048² single run)", "",
          "Shared 2-core machine (other jobs may run at the same time): repeated runs of the same code "
          "differ by up to ±20 % per step, more for the single 2048² runs.", "",
          timing_table(timings), "", *failed_lines(failed),
          step_breakdown(timings), "", *speed_directions(), *gpu_section(out, timings)]
    if paths:
        md += [f"## Occlusion error and clusters along camera paths ({frames} frames per path at "
               f"{path_res}²; §4.7.1, Table 19)", "",
               f"Fewer than the thesis's 900 frames: each frame costs seconds of CPU for both methods on this "
               f"shared machine (llvmpipe), so {frames} frames per path keep the run within minutes.", "",
               OCCLUSION_METRICS_TEXT, "",
               md_table(["scene", "path", "reflective px max/mean", "occlusion error thesis, per ray max/mean",
                         "thesis, per output px max/mean",
                         "occlusion-error px strict max/mean", "strict, not captured max/mean",
                         "strict, captured max/mean", "clusters max/mean"],
                        [[p["scene"], p["path"], f"{f(p['reflective_pct_max'])} / {f(p['reflective_pct_mean'])} %",
                          mm(p, "occlusion_thesis_ray_pct"), mm(p, "occlusion_thesis_pct"), mm(p, "occlusion_pct"),
                          mm(p, "strict_not_captured_pct"),
                          mm(p, "strict_captured_pct"), f"{p['clusters_max']} / {f(p['clusters_mean'])}"]
                         for p in paths]), ""]
    md += sweeps_markdown(sweeps or [])
    write_text(out.with_suffix(".md"), "\n".join(md))


def report_from_json(out: Path, data: dict) -> None:
    """Rewrite reflections.md from reflections.json's data (sizes and frame counts
    as stored in its rows)."""
    for q in data["quality"]:
        q.setdefault("triangles", int(len(load_named_scene(q["scene"]).faces)))
    paths = data["paths"]
    write_report(out, data["machine"], data["quality"], data["timings"], paths, data["quality"][0]["res"],
                 paths[0]["frames"] if paths else 0, paths[0]["res"] if paths else 0, data.get("sweeps"),
                 data.get("failed"))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["living_room", "bathroom", "mirror"])
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--timing-res", type=int, nargs="+", default=[256, 512, 1024, 2048])
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--path-res", type=int, default=512)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", default=str(RESULTS_DIR / "reflections"))
    ap.add_argument("--report-only", action="store_true", help="rewrite the .md from the existing .json")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    if args.report_only:
        report_from_json(out, json.loads(out.with_suffix(".json").read_text()))
        print(out.with_suffix(".md").read_text())
        return

    gl = create_gl_context()
    refl = ClusterReflections(gl, DEFAULT_SETTINGS)  # what the service renders with
    quality, timings, paths, failed = [], [], [], []
    for name in args.scenes:
        scene = load_named_scene(name)
        sg = SceneGPU(gl, scene)
        caster = RayCaster(scene)
        quality.append(triplet(name, scene, sg, refl, caster, args.res, out.parent))
        quality[-1]["triangles"] = int(len(scene.faces))
        print("quality", quality[-1], flush=True)
        for res in args.timing_res:
            try:
                timings.append(timing(name, scene, sg, refl, res, args.repeat if res <= 1024 else 1))
            except RuntimeError as exc:  # a refused frame (e.g. the clustering's sample check): keep the others
                failed.append({"scene": name, "res": res, "error": str(exc)})
                print("timing failed", failed[-1], flush=True)
                continue
            print("timing", timings[-1], flush=True)
        if args.frames > 0:
            paths.extend(path_stats(name, scene, sg, refl, caster, args.frames, args.path_res))
            print("paths", paths[-2:], flush=True)
        sg.release()
    info = machine_info(gl)
    old = json.loads(out.with_suffix(".json").read_text()) if out.with_suffix(".json").exists() else {}
    sweeps = old.get("sweeps")  # Tables 15–18, 20 come from bench/reflection_sweeps.py
    measured = {"date": time.strftime("%Y-%m-%d", time.gmtime()), "commit": git_revision(),
                "command": "python -m bench.reflections " + " ".join(argv if argv is not None else sys.argv[1:])}
    write_json(out.with_suffix(".json"), {"machine": info, "measured": measured, "quality": quality,
                                          "timings": timings, "paths": paths, **({"sweeps": sweeps} if sweeps else {}),
                                          **({"failed": failed} if failed else {})})
    write_report(out, info, quality, timings, paths, args.res, args.frames, args.path_res, sweeps, failed)
    refl.release()
    print(out.with_suffix(".md").read_text())


if __name__ == "__main__":
    main()

"""Parameter sweeps of the cluster reflections (thesis §4.7.2, Tables 15–18 and 20).

On the Table 12 view of each scene (bench.reflections.view_camera), one parameter
at a time, everything else at its default:

* Table 15: number of clusters (ClusterSettings bin_scale 0.25–2; above 1 large
  reflectors get more than MAXTHETABINS × MAXPHIBINS bins, for this sweep only) —
  fps, and the thesis-defined occlusion error per reflected ray (Fig. 27: more
  clusters, fewer occlusion errors);
* Table 16: output resolution 256²–2048² — fps;
* Table 17: cluster image scale 1/2, 1, 2 (resolution_scale) with the atlas budget
  lifted (under the default budget the images shrink to it whatever the scale) —
  fps, atlas texels and occlusion error;
* budget (beyond the thesis): the atlas budget (ClusterSettings atlas_budget, texels
  per G-buffer sample, non-planar images shrink to it) 4 / 8 / 16 / 32 — fps, atlas
  texels, depth-image time, MAE and occlusion error;
* Table 18: diffuse triangle count (built-in detail 0.25–1) — fps of ours and of
  Embree (BVH build + trace);
* layers (beyond the thesis): the other objects' second surface in non-planar
  cluster images (ClusterSettings others_peel off / on) — fps and occlusion error;
* lod (beyond the thesis): levels of detail of the other objects in non-planar
  cluster images, off and at 0.5 / 1 / 2 texels of error (ClusterSettings
  lod_texels) — fps, depth-image time, chunks drawn, MAE and occlusion error;
* Table 20: glossy reflections with 8 and 49 rays per reflective pixel (the
  G-buffer sample, as the thesis's first-pass pixel) — intersection time, fps of ours
  and of Embree with the same lobe rays, MAE against that Embree image.

Frame times are single renders after one warm-up (medians of `repeat` where
given) on the shared machine; compare within a table only.

    python -m bench.reflection_sweeps [--res 512] [--repeat 2]
        (adds "sweeps" to bench/results/reflections.json and rewrites reflections.md)
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from bench.common import RESULTS_DIR, git_revision, load_named_scene, write_json
from bench.reflections import occlusion_metrics, report_from_json, view_camera
from gl_passes.context import create_gl_context
from gl_passes.reflections import DEFAULT_SETTINGS, ClusterReflections
from gl_passes.upload import SceneGPU
from reference.image_metrics import mean_abs_error
from reference.raycast import RayCaster
from reference.reflections import raytrace_reflections
from scenes.builtin import make_builtin

BIN_SCALES = (2.0, 1.5, 1.0, 0.5, 0.25)
OUTPUT_RES = (2048, 1024, 512, 256)
IMAGE_SCALES = (0.5, 1.0, 2.0)
ATLAS_BUDGETS = (3.0, 4.0, 5.0, 6.0, 8.0, 16.0)
DETAILS = (1.0, 0.5, 0.25)
GLOSSY_RAYS = (8, 49)
OTHERS_PEEL = (False, True)
#: Level-of-detail sweep: off (full detail), then the error bound in texels (lod_texels).
LOD_TEXELS = (0.0, 0.5, 1.0, 2.0)


def _ours(refl: ClusterReflections, sg: SceneGPU, cam, repeat: int, **kw):
    """(last result, median total ms, median intersection ms) after one warm-up."""
    refl.render(sg, cam, **kw)
    runs = [refl.render(sg, cam, **kw) for _ in range(max(1, repeat))]
    return (runs[-1], float(np.median([r.timings_ms["total"] for r in runs])),
            float(np.median([r.timings_ms["intersection"] for r in runs])))


def _embree(scene, cam, **kw):
    """(result, BVH build + trace ms)."""
    t0 = time.perf_counter()
    caster = RayCaster(scene)
    ref = raytrace_reflections(scene, cam, caster=caster, **kw)
    return ref, (time.perf_counter() - t0) * 1e3


def _config_row(gl, sg: SceneGPU, cam, ref, repeat: int, **options) -> dict:
    """fps, cluster count and thesis occlusion error per ray with DEFAULT_SETTINGS changed by `options`."""
    refl = ClusterReflections(gl, DEFAULT_SETTINGS.replace(**options))
    try:
        r, total, _ = _ours(refl, sg, cam, repeat)
        occ = occlusion_metrics(refl.render(sg, cam, diagnostics=True), ref)[0]["occlusion_thesis_ray_pct"]
    finally:
        refl.release()
    return {"clusters": r.n_clusters, "fps": 1e3 / total, "occlusion_thesis_ray_pct": occ,
            "depth_images_ms": r.timings_ms["depth_images"], "drawn_chunks": r.drawn_chunks,
            "atlas_texels": int(r.atlas_size[0] * r.atlas_size[1]),
            "mae_255": float(mean_abs_error(r.color, ref.color) * 255)}


def sweep_scene(gl, name: str, res: int, repeat: int, tables: set[str]) -> dict:
    scene = load_named_scene(name)
    sg = SceneGPU(gl, scene)
    cam = view_camera(scene, res)
    out: dict = {"scene": name, "res": res}
    try:
        ref, _ = _embree(scene, cam)
        # Tables 15, 17, layers, lod and budget: one ClusterSettings field swept (row key,
        # option name, values, other options of the table).
        for table, key, option, values, fixed in (
                ("15", "bin_scale", "bin_scale", BIN_SCALES, {}),
                ("17", "scale", "resolution_scale", IMAGE_SCALES, {"atlas_budget": None}),
                ("layers", "others_peel", "others_peel", OTHERS_PEEL, {}),
                ("lod", "lod_texels", "lod_texels", LOD_TEXELS, {}),
                ("budget", "atlas_budget", "atlas_budget", ATLAS_BUDGETS, {})):
            if table in tables:
                out[f"table{table}"] = rows = []
                for v in values:
                    opts = {"lod_errors": ()} if option == "lod_texels" and v == 0 else {option: v}
                    rows.append({key: v, **_config_row(gl, sg, cam, ref, repeat, **fixed, **opts)})
                    print(name, f"T{table}", rows[-1], flush=True)
        refl = ClusterReflections(gl)
        try:
            if "16" in tables:
                rows = []
                for r_out in OUTPUT_RES:
                    _, total, _ = _ours(refl, sg, view_camera(scene, r_out), repeat if r_out <= 1024 else 1)
                    rows.append({"res": r_out, "fps": 1e3 / total})
                    print(name, "T16", rows[-1], flush=True)
                out["table16"] = rows
            if "20" in tables:
                rows = []
                for k in GLOSSY_RAYS:
                    r, total, inter = _ours(refl, sg, cam, 1, glossy_rays=k)
                    ref_k, t_emb = _embree(scene, cam, glossy_rays=k)
                    rows.append({"rays": k, "intersection_ms": inter, "fps_ours": 1e3 / total,
                                 "fps_embree": 1e3 / t_emb,
                                 "mae_255": float(mean_abs_error(r.color, ref_k.color) * 255),
                                 "mae_reflective_255": float(mean_abs_error(r.color, ref_k.color, ref_k.reflective)
                                                             * 255)})
                    print(name, "T20", rows[-1], flush=True)
                out["table20"] = rows
        finally:
            refl.release()
    finally:
        sg.release()
    if "18" in tables:
        rows = []
        refl = ClusterReflections(gl)
        for detail in DETAILS:
            sc = make_builtin(name, detail)
            sgd = SceneGPU(gl, sc)
            try:
                cam_d = view_camera(sc, res)
                _, total, _ = _ours(refl, sgd, cam_d, repeat)
                _, t_emb = _embree(sc, cam_d)
            finally:
                sgd.release()
            diffuse = int(sum(len(o.faces) for o in sc.objects if o.material.specular <= 0))
            rows.append({"detail": detail, "triangles": int(len(sc.faces)), "diffuse_triangles": diffuse,
                         "fps_ours": 1e3 / total, "fps_embree": 1e3 / t_emb})
            print(name, "T18", rows[-1], flush=True)
        refl.release()
        out["table18"] = rows
    return out


def merge_sweeps(old: list[dict], new: list[dict], stamp: str) -> list[dict]:
    """The sweeps of a run (`--tables` a subset) over the earlier ones: per scene, the
    tables measured now replace theirs and are stamped with `stamp` in the scene's
    "measured" (table key → date and commit); the other tables stay as they were."""
    merged = {s["scene"]: dict(s) for s in old}
    for s in new:
        entry = merged.setdefault(s["scene"], {"scene": s["scene"], "res": s["res"]})
        tables = [k for k in s if k.startswith("table")]
        entry.update(s)
        entry["measured"] = {**entry.get("measured", {}), **dict.fromkeys(tables, stamp)}
    return list(merged.values())


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["living_room", "bathroom"])
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--tables", default="15,16,17,18,20,layers,lod,budget",
                    help="comma list; 16 and 18 run on the first scene only")
    ap.add_argument("--out", default=str(RESULTS_DIR / "reflections"))
    args = ap.parse_args(argv)
    out = Path(args.out)
    tables = set(args.tables.split(","))
    gl = create_gl_context()
    sweeps = []
    for i, name in enumerate(args.scenes):
        mine = tables if i == 0 else tables - {"16", "18"}
        sweeps.append(sweep_scene(gl, name, args.res, args.repeat, mine))
    gl.release()
    path = out.with_suffix(".json")
    data = json.loads(path.read_text())
    data["sweeps"] = merge_sweeps(data.get("sweeps", []), sweeps,
                                  time.strftime("%Y-%m-%d", time.gmtime()) + " " + git_revision())
    write_json(path, data)
    report_from_json(out, data)
    print(out.with_suffix(".md").read_text())


if __name__ == "__main__":
    main()

"""Issue 3's criterion (b) against the tessellation of the scenes, surfaces unchanged.

Pixel redundancy (Alg. 3, §2.2) tests whether the triangle id stored at a
reprojected texel equals the sample's own, so its metrics depend on how large
the triangles are against a texel; the thesis gives its scenes only as triangle
counts (§2.3.3). Here every triangle of each scene is split into 4^L by
midpoint subdivision (`subdivided`): the surfaces, and so every metric of the
visibility definition, stay the same (the report checks it), while the pixel
definition sees triangles 2^L times smaller along each edge. Criterion (b) (NR's
available samples ≥ conventional's and peeling's, average and minimum) is then
judged per level with `bench.sampling_report.criteria_rows`. Beside the GL set, the
same NR set is rendered by Embree (`reference.visibility.non_redundant_reference`)
and measured alike, with criterion (a) counted for both.

The report also gives, per scene, the conventional set's available samples under
the pixel definition minus those under the visibility definition: a loss that
comes only from triangle ids against texels (NR plays no part), for our scenes
and for the thesis's (Table 4 − Table 6), to compare how fine the two sets of
scenes are against the texel.

Run `python -m bench.tessellation --help`; results go to bench/results/tessellation.*.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from bench.common import add_scene_args, md_table, report_head, sweep_main, write_text
from bench.sampling import measure_rig, metric_jobs
from bench.sampling_report import (
    criteria_rows,
    granularity_loss,
    lead_ranges,
    redundant_counts,
    reference_gap,
    thesis_granularity_loss,
    verdict_counts,
    visibility_drift,
    yes_no,
)
from scenes.model import Scene


def subdivided(scene: Scene, levels: int) -> Scene:
    """`scene` with every triangle split into 4^levels by midpoint subdivision
    (trimesh.remesh.subdivide, per object): the same surfaces, vertex normals
    interpolated (and renormalised) at the new vertices."""
    import trimesh

    objects = []
    for obj in scene.objects:
        v, f, n = obj.vertices, obj.faces, obj.normals
        for _ in range(levels):
            out = trimesh.remesh.subdivide(v, f, vertex_attributes=None if n is None else {"normal": n})
            v, f = out[0], out[1]
            if n is not None:
                n = out[2]["normal"]
                n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        objects.append(replace(obj, vertices=v, faces=f, normals=n))
    return replace(scene, objects=objects)


def reference_set(gl, sg, rc, cams, peel_cam) -> dict[str, list]:
    """The pixel-definition NR set by Embree (`reference.visibility.non_redundant_reference`)
    on the GL set's cameras: whatever (b) shows, it shows for Alg. 3 itself, not for GL."""
    from reference.visibility import non_redundant_reference

    return {"nr_pixel_reference": non_redundant_reference(sg.scene, cams, "pixel", caster=rc)}


def metric_jobs_with_reference(sets: dict[str, list]) -> dict[str, tuple[list, str]]:
    return {**metric_jobs(sets), "pixel/non_redundant_reference": (sets["nr_pixel_reference"], "pixel")}


def run_level(gl, scenes: list[str], level: int, res: int, views: int, seed: int, progress: bool) -> list[dict]:
    """`bench.sampling`-shaped results (scene, triangles, metrics) at one subdivision level."""
    return [measure_rig(gl, name, res, views, seed, jobs=metric_jobs_with_reference, extra_sets=reference_set,
                        progress=progress, prepare=lambda s: subdivided(s, level)) for name in scenes]


def write_report(out: Path, args: argparse.Namespace, info: dict, runs: dict[int, list[dict]],
                 seconds: float) -> None:
    summary, detail = [], []
    for level, results in runs.items():
        rows = criteria_rows(results, f"L{level}")
        tris = sum(r["triangles"] for r in results)
        for red in ("pixel", "visibility"):
            b, c_issue, c_thesis = verdict_counts([x for x in rows if x["definition"] == red])
            summary.append([str(level), f"{4 ** level}×", f"{tris:,}", red, b, c_issue, c_thesis])
        for x in (x for x in rows if x["definition"] == "pixel"):
            r = next(r for r in results if r["scene"] == x["scene"])
            nr, cv, pe = x["avail_avg"]
            nr_min, cv_min, pe_min = x["avail_min"]
            thesis = thesis_granularity_loss(x["scene"])
            ref = r["metrics"].get("pixel/non_redundant_reference")
            ref_cell = "—" if ref is None else f"{100 * ref['available_avg']:.2f} / {100 * ref['available_min']:.2f}"
            detail.append([x["scene"], str(level), f"{r['triangles']:,}",
                           f"{100 * nr:.2f} / {100 * cv:.2f} / {100 * pe:.2f}",
                           f"{100 * nr_min:.2f} / {100 * cv_min:.2f} / {100 * pe_min:.2f}",
                           ref_cell,
                           f"{100 * (nr - cv):+.2f} / {100 * (nr_min - cv_min):+.2f}", yes_no(x["b"]),
                           f"{granularity_loss(r):+.1f}" + ("" if thesis is None else f" ({thesis:+.1f})")])
    parts = report_head(
        "Issue 3's criterion (b) against the tessellation of the scenes",
        f"python -m bench.tessellation --levels {','.join(str(k) for k in runs)} --scenes {','.join(args.scenes)} "
        f"--res {args.res} --views {args.views} --seed {args.seed}",
        [f"Every triangle of each scene split into 4^L (midpoint subdivision, `bench.tessellation.subdivided`), "
         f"same surfaces; the Fig. 8 rig of `bench.sampling` (20°), {args.res}² images, {args.views} intermediate "
         f"views (seed {args.seed}), the metrics of `reference.sampling_metrics` (reference revision "
         f"{getattr(args, 'reference_revision', 1)}, `reference.REVISION`) and the criteria of `bench.sampling`.",
         f"Check that the surfaces are unchanged: the visibility-definition available samples (every method, "
         f"scene and level) move by at most {visibility_drift(runs):.3f} points from level 0.",
         f"The pixel-definition NR set rendered by Embree instead of GL gives the GL set's available samples "
         f"to within {reference_gap(runs):.3f} points (average and minimum, every scene and level). Criterion "
         "(a), all scenes and levels: the GL NR sets hold {} pixel-redundant samples, {} of them texel-edge "
         "float ties; the Embree NR sets hold {}.".format(*redundant_counts(runs))],
        seconds, info) + [
        "## Summary",
        "",
        "Scenes where the criterion holds (issue 3 needs (b) on all four, (c) on ≥ 3 of 4).",
        "",
        md_table(["level L", "triangles per triangle", "triangles, all scenes", "definition", "(b) scenes",
                  "(c) scenes, issue reading", "(c) scenes, thesis reading"], summary),
        "",
        "NR − conventional, pixel definition, average over the views, range over the scenes: "
        + "; ".join(f"L{k}: {lo:+.2f} … {hi:+.2f} points" for k, (lo, hi) in lead_ranges(runs).items()) + ".",
        "",
        "## Pixel definition, per scene",
        "",
        "Available samples NR / conventional / peeling in % of the intermediate views' samples; the NR set "
        "rendered by Embree instead of GL (`reference.visibility.non_redundant_reference`, same cameras) in "
        "% (average / minimum); NR (GL) − conventional in points (average / minimum). Granularity loss: the "
        "conventional set's available samples "
        "under the pixel minus the visibility definition (average, points), which only triangle ids against "
        "texels cause; in parentheses the thesis's (Table 4 − Table 6).",
        "",
        md_table(["scene", "L", "triangles", "available avg [%]", "available min [%]", "NR by Embree [%]",
                  "NR − conv. [points]", "(b)", "granularity loss [points]"], detail),
        "",
    ]
    write_text(out / "tessellation.md", "\n".join(parts))


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--levels", type=lambda s: [int(x) for x in s.split(",")], default=[0, 1, 2],
                    help="subdivision levels (each splits every triangle into 4)")
    add_scene_args(ap, views=60, res=1024)
    ap.add_argument("--report-only", action="store_true",
                    help="rewrite tessellation.md from tessellation.json in --out")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    return sweep_main(args, "tessellation", args.levels, str, int,
                      lambda gl, k: run_level(gl, args.scenes, k, args.res, args.views, args.seed, args.progress),
                      write_report)


if __name__ == "__main__":
    raise SystemExit(main())

"""Depth peeling with and without back-face culling, against the thesis's Tables 2 and 5.

The issue asks for back-face culling on every image, and §2.3 says all its
renderings cull back faces; yet the thesis's peeling layer 1 is almost never
useful on the nest and the city (2 % and 7 % of its occluded samples, pixel
definition, Table 2), although its layer 2 is (71 %). That pattern is what
peeling *without* culling gives on closed geometry: layer 1 is the inside of the
first surface (its back face), which no intermediate view sees. This benchmark
measures both peelings on our scenes, with the same Fig. 8 rig, intermediate
views and §2.3.2 metrics as `bench.sampling`, and sets the non-redundant images'
useful occluded samples beside both (criterion (c) of issue 3).

The two-sided variant is a diagnostic, not a method of the product: the service
and `bench.sampling` peel with culling on, as the issue asks.

Run `python -m bench.peeling_sides --help`; results go to bench/results/peeling_sides.*.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from bench.common import add_scene_args, measure_with_gl, report_head, write_json, write_text
from bench.sampling import measure_rig
from bench.sampling_report import PEELINGS, THESIS_BY_DEFINITION, layer_table, useful_table


def _two_sided_peeling(gl, sg, rc, cams, peel_cam) -> dict[str, list]:
    from gl_passes import depth_images as di

    renderer = di.DepthImageRenderer(gl, cull_back_faces=False)
    try:
        return {"peeling_two_sided": di.depth_peeling(gl, sg, peel_cam, 3, renderer=renderer)}
    finally:
        renderer.release()


def _jobs(sets: dict[str, list]) -> dict[str, tuple[list, str]]:
    """NR of each definition and both peelings, under both definitions."""
    jobs = {}
    for red in THESIS_BY_DEFINITION:
        jobs[f"{red}/non_redundant"] = (sets["nr_pixel" if red == "pixel" else "nr_visibility"], red)
        for p in PEELINGS:
            jobs[f"{red}/{p}"] = (sets[p], red)
    return jobs


def run_scene(name: str, gl, res: int, views: int, seed: int, progress: bool) -> dict:
    """Metrics of NR (both definitions) and of both peelings on one scene."""
    return measure_rig(gl, name, res, views, seed, jobs=_jobs, extra_sets=_two_sided_peeling, progress=progress)


def write_report(out: Path, args: argparse.Namespace, info: dict, results: list[dict], seconds: float) -> None:
    n = len(results)
    parts = report_head(
        "Depth peeling with and without back-face culling (thesis Tables 2 and 5)",
        f"python -m bench.peeling_sides --scenes {','.join(args.scenes)} --res {args.res} --views {args.views} "
        f"--seed {args.seed}",
        ["Scenes: " + ", ".join(f"{r['scene']} ({r['triangles']:,} triangles)" for r in results),
         f"The Fig. 8 rig of `bench.sampling` at {args.res}×{args.res}; 3 peeling layers from the centroid, "
         f"once with back-face culling (as the issue asks; the product's peeling) and once without; "
         f"{args.views} intermediate views (seed {args.seed}) cast with Embree; metrics of "
         "`reference.sampling_metrics` (the conventional images, whose samples define \"occluded\", cull back "
         "faces in both cases)."],
        seconds, info)
    gap_by_def = {}
    for red in THESIS_BY_DEFINITION:
        table, gaps = layer_table(results, red)
        gap_by_def[red] = gaps
        parts += [
            f"## Peeling layers, {red} definition: occluded % of the layer's samples (useful % of those)",
            "",
            table,
            "",
            f"Mean |ours − thesis| of the useful share over layers L1, L2: culled {gaps['peeling']:.1f} points, "
            f"two-sided {gaps['peeling_two_sided']:.1f} points.",
            "",
        ]
    for red in THESIS_BY_DEFINITION:
        table, wins = useful_table(results, red)
        parts += [
            f"## Useful occluded samples, {red} definition (totals over the three images)",
            "",
            table,
            "",
            f"NR ≥ peeling (criterion (c) needs ≥ 3 of 4 scenes): issue reading — against culled peeling "
            f"{wins['issue/peeling']} / {n}, against two-sided peeling {wins['issue/peeling_two_sided']} / {n}; "
            f"thesis reading — {wins['thesis/peeling']} / {n} and {wins['thesis/peeling_two_sided']} / {n}.",
            "",
        ]
    stronger = sum(r["metrics"][f"{red}/peeling"]["total"]["useful"]
                   >= r["metrics"][f"{red}/peeling_two_sided"]["total"]["useful"]
                   for r in results for red in THESIS_BY_DEFINITION)
    closer = {red: min(PEELINGS, key=lambda p, g=gap_by_def[red]: g[p]) for red in THESIS_BY_DEFINITION}
    name = {"peeling": "the culled peeling", "peeling_two_sided": "the two-sided peeling"}
    parts += [
        "## Reading",
        "",
        f"* Over the useful shares of layers L1 and L2, the thesis's Table 2 (pixel definition) is closer to "
        f"{name[closer['pixel']]}, its Table 5 (visibility definition) to {name[closer['visibility']]}. "
        "Both tables describe the same peeling images (peeling does not depend on the redundancy "
        "definition; only the metric does), and on closed models both of our metrics call a back-face "
        "sample neither captured nor needed"
        + (". So no single peeling of ours reproduces both tables, and the thesis's near-useless layer 1 in "
           "Table 2 (nest 2 %, grass 4 %, city 7 %) is matched on the closed models only by drawing back faces."
           if closer["pixel"] != closer["visibility"] else ".")
        + f" The culled peeling has at least as many useful occluded samples as the two-sided one on "
        f"{stronger} of {n * len(THESIS_BY_DEFINITION)} scene × definition cases; `bench.sampling` keeps it, as the "
        "issue asks.",
        "* How far the variant moves a scene depends on how it is modelled: the nest's twigs (closed "
        "prisms) and the city's blocks are closed, so two-sided layer 1 is their inside. Our grass blades and "
        "tree leaves are two coincident sheets of opposite facing (`scenes.builtin.geometry.two_sided`): "
        "drawn without culling, the back sheet z-fights with the front one, so layer 0 already stores "
        "back-facing triangles at some pixels (never captured by a conventional image, hence \"occluded\", "
        "and never needed by a view), which single-sheet leaves would not do.",
        "",
    ]
    write_text(out / "peeling_sides.md", "\n".join(parts))
    write_json(out / "peeling_sides.json", {"args": {k: v for k, v in vars(args).items() if k != "out"},
                                            "machine": info, "seconds": seconds, "results": results})


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_scene_args(ap, views=200)
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    results, info, seconds = measure_with_gl(
        lambda gl: [run_scene(s, gl, args.res, args.views, args.seed, args.progress) for s in args.scenes])
    write_report(args.out, args, info, results, seconds)
    print(f"wrote {args.out / 'peeling_sides.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

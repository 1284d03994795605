"""Issue 3's criteria against the spread of the Fig. 8 rig, which the thesis does not give.

Fig. 8 shows three reference eyes around the scene and the peeling eye at their
centroid, with no angles. `bench.sampling` uses 20° between each eye and the
rig's axis. This benchmark repeats its metrics for several spreads and reports,
per spread, criteria (b) and (c) of issue 3 (`bench.sampling_report.criteria_rows`)
and the conventional images' redundancy, which depends on the rig and the scene
only (not on NR or peeling), against the thesis's Tables 2 and 5: the spread
whose conventional redundancy is closest to the thesis's is the one calibrated
without looking at the criteria.

Run `python -m bench.rig_spread --help`; results go to bench/results/rig_spread.*.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from bench.common import add_scene_args, md_table, report_head, sweep_main, write_text
from bench.sampling import measure_rig
from bench.sampling_report import THESIS_BY_DEFINITION, conv_gap, criteria_rows, verdict_counts, yes_no


def run_spread(gl, scenes: list[str], spread: float, res: int, views: int, seed: int, progress: bool) -> list[dict]:
    """`bench.sampling`-shaped results (scene, metrics) of every scene at one spread."""
    return [measure_rig(gl, name, res, views, seed, spread, progress=progress) for name in scenes]


def write_report(out: Path, args: argparse.Namespace, info: dict, runs: dict[float, list[dict]],
                 seconds: float) -> None:
    gaps = {red: {s: conv_gap(r, red) for s, r in runs.items()} for red in THESIS_BY_DEFINITION}  # spread → points
    summary, detail = [], []
    for spread, results in runs.items():
        rows = criteria_rows(results, f"{spread:g}°")
        for red in THESIS_BY_DEFINITION:
            rr = [x for x in rows if x["definition"] == red]
            summary.append([f"{spread:g}°", red, f"{gaps[red][spread]:.1f}", *verdict_counts(rr)])
        for x in rows:
            conv = next(r for r in results if r["scene"] == x["scene"])["metrics"][f"{x['definition']}/conventional"]
            t = THESIS_BY_DEFINITION[x["definition"]].get(x["scene"], {}).get("conv")
            red_cell = " / ".join(f"{100 * conv['redundant_frac'][i]:.0f}" for i in (1, 2))
            detail.append([x["run"], x["scene"], x["definition"], red_cell + (f" ({t[1]} / {t[2]})" if t else ""),
                           " / ".join(f"{100 * v:.2f}" for v in x["avail_avg"]),
                           " / ".join(f"{100 * v:.2f}" for v in x["avail_min"]), yes_no(x["b"]),
                           f"{x['useful'][0]:,} / {x['useful'][1]:,}", yes_no(x["c"]),
                           f"{x['useful_earlier'][0]:,} / {x['useful_earlier'][1]:,}",
                           yes_no(x["c_earlier"])])
    best = {red: min(g, key=g.get) for red, g in gaps.items()}
    parts = report_head(
        "Issue 3's criteria against the spread of the Fig. 8 rig",
        f"python -m bench.rig_spread --spreads {','.join(f'{s:g}' for s in runs)} --scenes {','.join(args.scenes)} "
        f"--res {args.res} --views {args.views} --seed {args.seed}",
        [f"Per spread (degrees between each reference eye and the rig's axis; `bench.sampling` uses 20°): the "
         f"Fig. 8 rig framed as in `bench.sampling` (`scenes.rig.fit_distance`), {args.res}² images, "
         f"{args.views} intermediate views (seed {args.seed}), the metrics of `reference.sampling_metrics` and "
         "the criteria of `bench.sampling`."],
        seconds, info) + [
        "## Summary",
        "",
        "Conventional gap: mean |ours − thesis| of the conventional images' redundant share of I1 and I2 "
        "(Table 2 / Table 5), which depends on the rig and the scenes only. (b) and (c): scenes where the "
        "criterion holds (issue 3 needs (b) on all, (c) on ≥ 3 of 4).",
        "",
        md_table(["spread", "definition", "conventional gap [points]", "(b) scenes", "(c) scenes, issue reading",
                  "(c) scenes, thesis reading"], summary),
        "",
        f"The conventional redundancy is closest to the thesis's at {best['pixel']:g}° (pixel definition) and "
        f"{best['visibility']:g}° (visibility definition); over the spreads run, the gap ranges over "
        + " and ".join(f"{min(g.values()):.1f}-{max(g.values()):.1f} points ({red})" for red, g in gaps.items())
        + ", so it pins the spread down only "
        + ("loosely" if max(max(g.values()) - min(g.values()) for g in gaps.values()) < 10
           else "where one definition's gap has a clear minimum")
        + ". The criteria's verdicts by spread are in the summary above.",
        "",
        "## Per scene",
        "",
        "Conventional redundant share of I1 / I2 in % (thesis in parentheses); available samples NR / "
        "conventional / peeling in %; useful occluded samples NR / peeling, totals over the three images.",
        "",
        md_table(["spread", "scene", "definition", "conv. redundant I1 / I2 [%]", "available avg [%]",
                  "available min [%]", "(b)", "useful, issue reading", "(c)", "useful, thesis reading", "(c)"],
                 detail),
        "",
    ]
    write_text(out / "rig_spread.md", "\n".join(parts))


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spreads", type=lambda s: [float(x) for x in s.split(",")], default=[5.0, 10.0, 15.0, 20.0, 30.0])
    add_scene_args(ap, views=100)
    ap.add_argument("--report-only", action="store_true", help="rewrite rig_spread.md from rig_spread.json in --out")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    return sweep_main(args, "rig_spread", args.spreads, lambda s: f"{s:g}", float,
                      lambda gl, s: run_spread(gl, args.scenes, s, args.res, args.views, args.seed, args.progress),
                      write_report)


if __name__ == "__main__":
    raise SystemExit(main())

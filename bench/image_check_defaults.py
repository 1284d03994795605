"""The pytest plugin's default tolerances against what the GL pass differs by, and what they catch.

`service.image_check` states a default (tolerance, allowed share of bad pixels) per
metric (mae, psnr, flip). The documented use (README, "pytest image checks"):
a user's suite compares the frame the service renders with Embree's truth of the
same frame (`depthview_render` / `depthview_reference`); the defaults should pass
there and fail on a real change. This benchmark renders exactly those frames
(`service.testing.render_frame` / `reference_frame`, no effects: the G-buffer's
linear colour) on every built-in scene and the shared diorama, from three azimuths
(30°, 150°, 270°; elevation 30°) at two distances (`look_at_scene` 1.6 and 0.9
diagonals) and at 128² and 256², and compares each GL frame with

- its truth (must pass),
- the truth of a camera turned by 1° in azimuth (a change: must fail),
- itself rendered with the albedo of the object covering the most pixels scaled by
  0.95 (a change: must fail).

For every candidate (tolerance, allowed bad share) of a metric it counts the truth
frames that pass and the changes caught; the selected candidate (`select`) passes
every truth frame with the worst frame's bad share at most 2/3 of the bound and
catches the most changes (ties: the tighter bound). `service.image_check.DEFAULTS`
holds the selection (tests/test_pytest_plugin.py checks it against this run's json).

Run `python -m bench.image_check_defaults`; results go to
bench/results/image_check_defaults.*.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
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
    progress,
    shared_model_path,
    write_json,
    write_text,
)

AZIMUTHS = (30.0, 150.0, 270.0)
DISTANCES = (1.6, 0.9)
TURN_DEG = 1.0
ALBEDO_SCALE = 0.95
#: metric → candidate image-score tolerances (mae: mean, [0, 1] units; psnr: dB; flip: mean FLIP).
TOLERANCES: dict[str, tuple[float, ...]] = {"mae": (0.25 / 255, 0.5 / 255, 1 / 255, 2 / 255),
                                            "psnr": (30.0, 35.0, 40.0, 45.0), "flip": (0.005, 0.01, 0.02, 0.05)}
#: metric → candidate per-pixel thresholds (mae and psnr: a channel's |a − b|; flip: FLIP).
THRESHOLDS: dict[str, tuple[float, ...]] = {"mae": (1 / 255, 2 / 255, 4 / 255, 8 / 255),
                                            "psnr": (10 ** -2.0, 10 ** -1.75, 10 ** -1.5),
                                            "flip": (0.05, 0.1, 0.2, 0.3)}
MAX_BAD = (0.005, 0.01, 0.02, 0.03)
MARGIN = 2 / 3
PAIRS = ("truth", "turned", "albedo")
#: Each pair is compared as linear float colour (EXR references) and as the 8-bit sRGB PNG.
SPACES = ("linear", "srgb")
#: The defaults before this calibration (tolerance, threshold, max bad share; commit fec9d61).
PREVIOUS: dict[str, tuple[float, float, float]] = {"mae": (2 / 255, 2 / 255, 0.005), "psnr": (40.0, 0.01, 0.005),
                                                   "flip": (0.05, 0.05, 0.005)}


def recolour(scene, obj_index: int, scale: float):
    """The scene with one object's albedo scaled (a copy; the scene is not changed)."""
    objs = list(scene.objects)
    o = objs[obj_index]
    objs[obj_index] = dataclasses.replace(o, material=dataclasses.replace(
        o.material, albedo=tuple(float(a) * scale for a in o.material.albedo)))
    return dataclasses.replace(scene, objects=objs)


def as_png(color: np.ndarray) -> np.ndarray:
    """(H,W,3) uint8: the linear colour as the service's PNG holds it."""
    from service.image_io import decode_png, encode_png

    return decode_png(encode_png(color))


def pair_stats(actual: np.ndarray, expected: np.ndarray) -> dict[str, dict]:
    """Per metric: the image score and, per candidate threshold, the share of pixels
    above it."""
    from service.image_check import METRICS, compare_images

    out = {}
    for metric in METRICS:
        c = compare_images(actual, expected, metric=metric)
        out[metric] = {"score": float(f"{c.score:.6g}"),
                       "bad": {f"{t:.6g}": float(f"{(c.pixel_error > t).mean():.6g}") for t in THRESHOLDS[metric]}}
    return out


def measure(scenes: list[str], resolutions: list[int], show_progress: bool) -> tuple[list[dict], dict]:
    """One row per frame (scene, resolution, azimuth, distance) with pair_stats of
    each pair in PAIRS; and the machine (with the GL thread's renderer)."""
    from scenes.camera import look_at_scene
    from service.testing import GLThread, reference_frame, render_frame

    gl = GLThread()
    rows: list[dict] = []
    try:
        jobs = [(s, r, a, d) for s in scenes for r in resolutions for a in AZIMUTHS for d in DISTANCES]
        loaded = {s: load_named_scene(s) for s in scenes}
        for name, res, az, dist in progress(jobs, show_progress, desc="frames"):
            scene = loaded[name]
            cam = look_at_scene(scene.bounds, azimuth=az, elevation=30.0, distance=dist, width=res, height=res)
            turned = look_at_scene(scene.bounds, azimuth=az + TURN_DEG, elevation=30.0, distance=dist,
                                   width=res, height=res)
            frame = render_frame(gl, scene, cam)
            ids, counts = np.unique(frame.obj_id[frame.mask], return_counts=True)
            largest = int(ids[np.argmax(counts)]) - 1  # obj_id is 1-based
            pairs = {"truth": reference_frame(scene, cam).color, "turned": reference_frame(scene, turned).color,
                     "albedo": render_frame(gl, recolour(scene, largest, ALBEDO_SCALE), cam).color}
            rows.append({"scene": name, "triangles": scene.n_triangles, "res": res, "azimuth": az, "distance": dist,
                         "covered": float(frame.mask.mean()), "recoloured": scene.objects[largest].name,
                         "linear": {p: pair_stats(frame.color, img) for p, img in pairs.items()},
                         "srgb": {p: pair_stats(as_png(frame.color), as_png(img)) for p, img in pairs.items()}})
        info = machine_info()
        info.update(gl_backend=gl.backend, gl_renderer=gl.renderer, gl_version=gl.worker.gl_version)
    finally:
        gl.close()
    return rows, info


def score_of(stats: dict) -> float:
    """A pair's image score; +inf where the json holds null (psnr of equal images)."""
    return float("inf") if stats["score"] is None else float(stats["score"])


def score_ok(metric: str, score: float, tol: float, margin: float = 1.0) -> bool:
    """The image score within the tolerance; with margin < 1, within that share of it
    (psnr: of its allowed MSE)."""
    from service.image_check import score_within

    return score_within(metric, score, tol + 10.0 * np.log10(1.0 / margin) if metric == "psnr" else margin * tol)


def passes(pair: dict, metric: str, c: dict) -> bool:
    """The check compare_images makes with candidate c, from pair_stats."""
    s = pair[metric]
    return score_ok(metric, score_of(s), c["tolerance"]) and s["bad"][f"{c['threshold']:.6g}"] <= c["max_bad"]


def candidates(rows: list[dict], metric: str) -> list[dict]:
    """Every (tolerance, threshold, max_bad) of a metric: truth frames passing, the
    worst truth score and bad share, whether all truth frames pass with the margin,
    changes caught per kind."""
    out = []
    frames = [r[space] for r in rows for space in SPACES]
    scores = [score_of(f["truth"][metric]) for f in frames]
    worst_score = min(scores) if metric == "psnr" else max(scores)
    for tol in TOLERANCES[metric]:
        for thr in THRESHOLDS[metric]:
            worst_bad = max(f["truth"][metric]["bad"][f"{thr:.6g}"] for f in frames)
            for max_bad in MAX_BAD:
                c = {"tolerance": tol, "threshold": thr, "max_bad": max_bad, "worst_truth_score": worst_score,
                     "worst_truth_bad": worst_bad}
                c["truth_pass"] = sum(passes(f["truth"], metric, c) for f in frames)
                c["margin_ok"] = bool(score_ok(metric, worst_score, tol, MARGIN) and worst_bad <= MARGIN * max_bad)
                c.update({f"{p}_caught": sum(not passes(f[p], metric, c) for f in frames) for p in PAIRS[1:]})
                out.append(c)
    return out


def looseness(metric: str, c: dict) -> tuple[float, float, float]:
    """Larger is looser: allowed bad share, per-pixel threshold, score tolerance."""
    return c["max_bad"], c["threshold"], -c["tolerance"] if metric == "psnr" else c["tolerance"]


def select(metric: str, cands: list[dict]) -> dict | None:
    """The candidate that passes every truth frame with the margin and catches the
    most changes; ties: the loosest (looseness), which leaves the most room for
    frames this run did not measure."""
    ok = [c for c in cands if c["margin_ok"]]
    return max(ok, key=lambda c: (c["turned_caught"] + c["albedo_caught"], looseness(metric, c)), default=None)


def is_defaults(metric: str, c: dict) -> bool:
    from service.image_check import DEFAULTS

    d = DEFAULTS[metric]
    return bool(np.allclose([c["tolerance"], c["threshold"], c["max_bad"]],
                            [d.tolerance, d.threshold, d.max_bad_fraction], rtol=1e-9, atol=0))


def cand_cells(metric: str, c: dict, n: int) -> list[str]:
    return [f"{c['tolerance']:.4g}", f"{c['threshold']:.4g}", f"{100 * c['max_bad']:.2g} %", f"{c['truth_pass']}/{n}",
            "yes" if c["margin_ok"] else "no", f"{c['turned_caught']}/{n}", f"{c['albedo_caught']}/{n}"]


def report(rows: list[dict], info: dict, command: str, seconds: float, commit: str) -> str:
    from service.image_check import DEFAULTS, METRICS

    n = len(rows) * len(SPACES)  # comparisons per pair
    cand_rows, chosen = [], {}
    for metric in METRICS:
        cands = candidates(rows, metric)
        chosen[metric] = best = select(metric, cands)
        prev = next(c for c in cands if np.allclose([c["tolerance"], c["threshold"], c["max_bad"]], PREVIOUS[metric]))
        shown = [("selected" + (", the defaults" if best and is_defaults(metric, best) else ""), best),
                 ("defaults before (fec9d61)", prev)]
        for thr in THRESHOLDS[metric]:  # the best with the margin at each other threshold
            if best and thr == best["threshold"]:
                continue
            ok = [c for c in cands if c["margin_ok"] and c["threshold"] == thr]
            if ok:
                shown.append(("best at this threshold", select(metric, ok)))
        cand_rows += [[metric, label, *cand_cells(metric, c, n)] for label, c in shown if c is not None]
    worst = []
    for metric in METRICS:
        d = DEFAULTS[metric]
        key = f"{d.threshold:.6g}"
        frames = [(r, sp) for r in rows for sp in SPACES]
        r, rs = max(frames, key=lambda f: f[0][f[1]]["truth"][metric]["bad"].get(key, 0.0))
        s, ss = (min if metric == "psnr" else max)(frames, key=lambda f: score_of(f[0][f[1]]["truth"][metric]))
        worst.append([metric, f"{score_of(s[ss]['truth'][metric]):.4g} ({s['scene']}, {s['res']}², {s['azimuth']:g}°, "
                      f"{s['distance']:g}, {ss})",
                      f"{100 * r[rs]['truth'][metric]['bad'].get(key, float('nan')):.2f} % ({r['scene']}, "
                      f"{r['res']}², {r['azimuth']:g}°, {r['distance']:g}, {rs})"])
    detail = [[r["scene"], f"{r['res']}²", f"{r['azimuth']:g}°", f"{r['distance']:g}", f"{100 * r['covered']:.0f} %",
               *(" · ".join(" / ".join(f"{100 * r[sp][p][m]['bad'].get(f'{DEFAULTS[m].threshold:.6g}', np.nan):.2f}"
                                       for p in PAIRS) for sp in SPACES) for m in METRICS)]
              for r in rows]
    return "\n".join([
        "# The image checks' defaults against the GL pass's difference from Embree",
        "",
        f"Generated by `{command}` at commit {commit} ({seconds:.0f} s). Frames as a user's suite gets them "
        "(`service.testing.render_frame` against `reference_frame`, no effects: the G-buffer's linear colour), "
        "compared with `service.image_check.compare_images`: a check passes when the image score is within the "
        "tolerance and at most the allowed share of pixels is bad (above the per-pixel threshold). "
        f"{len(rows)} frames: {len({r['scene'] for r in rows})} scenes (triangles: "
        + ", ".join(f"{s} {t:,}" for s, t in dict((r["scene"], r["triangles"]) for r in rows).items())
        + f"), azimuths {', '.join(f'{a:g}°' for a in AZIMUTHS)} at elevation 30°, distances "
        f"{' and '.join(f'{d:g}' for d in DISTANCES)} scene diagonals, "
        f"{' and '.join(f'{x}²' for x in sorted({r['res'] for r in rows}))}. Changes: the truth of the camera "
        f"turned by {TURN_DEG:g}° in azimuth; the GL frame with the albedo of the object covering the most pixels × "
        f"{ALBEDO_SCALE:g}. Each pair is compared twice: as linear float colour (as EXR references hold it) and as "
        "the 8-bit sRGB PNG the service returns; the counts below are over both.",
        "",
        "## Machine",
        "",
        machine_markdown(info),
        "",
        "## Candidates",
        "",
        f"Candidates: every tolerance × threshold × allowed bad share of the lists in `bench.image_check_defaults`. "
        f"Margin: every truth comparison passes with its score within {MARGIN:.2g} of the tolerance (psnr: of the "
        f"allowed MSE) and its bad share within {MARGIN:.2g} of the allowed one. Selected: with the margin, the most "
        "changes caught; ties: the loosest. Shown per metric: the selection, the defaults before this calibration, "
        "and the best with the margin at each other threshold. `service.image_check.DEFAULTS`: "
        + ", ".join(f"{m} ({d.tolerance:.4g}, {d.threshold:.4g}, {100 * d.max_bad_fraction:.2g} %)"
                    for m, d in DEFAULTS.items()) + ".",
        "",
        md_table(["metric", "candidate", "tolerance", "threshold", "allowed bad", "truth comparisons passing",
                  "margin", f"turned {TURN_DEG:g}° caught", f"albedo × {ALBEDO_SCALE:g} caught"], cand_rows),
        "",
        "## Worst truth frame under the defaults",
        "",
        md_table(["metric", "worst score (frame: scene, resolution, azimuth, distance, space)",
                  "most bad pixels (frame)"],
                 worst),
        "",
        "## Every frame",
        "",
        "Share of bad pixels in % under each metric's default threshold: truth / turned / albedo, linear · sRGB.",
        "",
        md_table(["scene", "resolution", "azimuth", "distance", "pixels covered", *METRICS], detail),
        "",
    ])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", type=lambda s: s.split(","), default=None,
                    help="comma list (default: every built-in scene and the diorama when present)")
    ap.add_argument("--res", type=lambda s: [int(x) for x in s.split(",")], default=[128, 256])
    ap.add_argument("--out", type=Path, default=RESULTS_DIR)
    ap.add_argument("--no-progress", dest="progress", action="store_false")
    ap.add_argument("--report-only", action="store_true", help="rewrite the report from the json")
    args = ap.parse_args(argv)
    if args.report_only:
        data = json.loads((args.out / "image_check_defaults.json").read_text())
        write_text(args.out / "image_check_defaults.md",
                   report(data["rows"], data["machine"], data["command"], data["seconds"], data["commit"]))
        print(f"rewrote {args.out / 'image_check_defaults.md'}")
        return 0
    from scenes.builtin import BUILTIN_NAMES

    scenes = args.scenes or [*BUILTIN_NAMES, *(["diorama"] if shared_model_path("diorama") else [])]
    command = (f"python -m bench.image_check_defaults --scenes {','.join(scenes)} "
               f"--res {','.join(map(str, args.res))}")
    t0 = time.perf_counter()
    rows, info = measure(scenes, args.res, args.progress)
    seconds = time.perf_counter() - t0
    commit = git_revision()
    from service.image_check import METRICS

    selected = {m: select(m, candidates(rows, m)) for m in METRICS}
    write_json(args.out / "image_check_defaults.json",
               {"command": command, "commit": commit, "seconds": seconds, "machine": info,
                "selected": {m: (c and {k: c[k] for k in ("tolerance", "threshold", "max_bad")})
                             for m, c in selected.items()}, "rows": rows})
    write_text(args.out / "image_check_defaults.md", report(rows, info, command, seconds, commit))
    print(f"wrote {args.out / 'image_check_defaults.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

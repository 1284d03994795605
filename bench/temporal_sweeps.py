"""Sweeps behind the temporal reuse's defaults (thesis §5.4.4, §5.5; gl_passes.reprojection).

* Keyframe threshold (§5.4.4, thesis 0.3): per path, one full-tracing stream and one
  reuse stream per threshold run side by side, frame by frame; per threshold the
  recomputed share of the reflective pixels (keyframes at 100 %), the keyframe
  interval, the mean time per frame (and its ratio to full tracing) and the MAE
  against full tracing.
* Camera speed: the same fly-through path in more or fewer frames (it always spans
  the scene, so fewer frames = a faster camera); per path length the reuse stream
  alone: recomputed share and keyframe interval — what a camera's speed does to the
  reuse, the thesis's paths' speed being unknown.

Embree tracer (exact ray lengths, sparse). Results: bench/results/temporal_sweeps.md
(+ json).

    python -m bench.temporal_sweeps [--scenes living_room bathroom] [--seeds 0] [--frames 500]
        [--res 512] [--thresholds 0.1 0.2 0.3] [--speeds 250 500 1000] [--first 0]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from bench.common import (
    RESULTS_DIR,
    load_named_scene,
    machine_info,
    md_table,
    progress,
    report_head,
    write_json,
    write_text,
)
from bench.temporal import intervals, mae
from gl_passes.context import create_gl_context
from gl_passes.reprojection import ReflectionReuser, ReuseSettings
from gl_passes.upload import SceneGPU
from reference.raycast import RayCaster
from reference.reflection_tracer import EmbreeTracer
from scenes.camera import flythrough_path


def _summary(ms: list[float], rec: list[float], keys: list[bool]) -> dict:
    iv = intervals(keys)
    return {"ms_mean": float(np.mean(ms)), "recomputed_mean": float(np.mean(rec)),
            "keyframe_interval_mean": float(np.mean(iv)), "keyframe_interval_max": int(max(iv))}


def sweep_thresholds(gl, sg, caster: RayCaster, cams: list, thresholds: list[float], desc: str,
                     show: bool) -> list[dict]:
    """One full stream and one reuse stream per threshold along `cams`."""
    full = ReflectionReuser(gl, sg, EmbreeTracer(sg.scene, caster=caster), ReuseSettings(mode="full"))
    reusers = [ReflectionReuser(gl, sg, EmbreeTracer(sg.scene, caster=caster),
                                ReuseSettings(keyframe_threshold=t)) for t in thresholds]
    full_ms: list[float] = []
    per = [{"ms": [], "rec": [], "keys": [], "mae": []} for _ in thresholds]
    for cam in progress(cams, show, desc=desc, unit="frame"):
        ref = full.next_frame(cam)
        full_ms.append(ref.stats.timings_ms["total"])
        for ru, p in zip(reusers, per, strict=True):
            f = ru.next_frame(cam)
            p["ms"].append(f.stats.timings_ms["total"])
            p["rec"].append(f.stats.recomputed_fraction if f.stats.reflective else 0.0)
            p["keys"].append(bool(f.stats.keyframe))
            p["mae"].append(mae(f.color, ref.color))
    for ru in (full, *reusers):
        ru.release()
    fm = float(np.mean(full_ms))
    return [{"threshold": t, **_summary(p["ms"], p["rec"], p["keys"]), "mae_mean": float(np.mean(p["mae"])),
             "full_ms_mean": fm, "speedup": fm / float(np.mean(p["ms"]))} for t, p in zip(thresholds, per, strict=True)]


def sweep_speeds(gl, sg, caster: RayCaster, bounds, seed: int, res: int, lengths: list[int], first: int,
                 desc: str, show: bool) -> list[dict]:
    """The reuse stream alone along the path drawn in `lengths` frames."""
    rows = []
    for n in lengths:
        cams = flythrough_path(bounds, n, seed=seed, width=res, height=res)
        cams = cams[:first] if first else cams
        ru = ReflectionReuser(gl, sg, EmbreeTracer(sg.scene, caster=caster))
        ms, rec, keys = [], [], []
        for cam in progress(cams, show, desc=f"{desc} {n}", unit="frame"):
            f = ru.next_frame(cam)
            ms.append(f.stats.timings_ms["total"])
            rec.append(f.stats.recomputed_fraction if f.stats.reflective else 0.0)
            keys.append(bool(f.stats.keyframe))
        ru.release()
        rows.append({"path_frames": n, "frames": len(cams), **_summary(ms, rec, keys)})
    return rows


def write_report(out: Path, args: argparse.Namespace, info: dict, runs: list[dict], seconds: float) -> None:
    facts = [f"Scenes {', '.join(args.scenes)}; fly-through seeds {args.seeds}; {args.res}²; Embree tracer.",
             f"Thresholds: {args.frames}-frame paths"
             f"{f' (their first {args.first} frames)' if args.first else ''}; times are each stream's own wall "
             "time per frame, streams interleaved frame by frame (a shared machine: ratios, not absolute times).",
             "Camera speed: the reuse stream alone, default settings, whole paths."]
    lines = report_head("Temporal reuse sweeps (thesis §5.4.4)", args.command, facts, seconds, info)
    rows_t = [[r["scene"], r["path"], f"{t['threshold']:g}", f"{100 * t['recomputed_mean']:.1f}",
               f"{t['keyframe_interval_max']} / {t['keyframe_interval_mean']:.1f}", f"{t['ms_mean']:.0f}",
               f"{t['speedup']:.2f}×", f"{t['mae_mean']:.3f}"] for r in runs for t in r["thresholds"]]
    rows_s = [[r["scene"], r["path"], f"{s['path_frames']}", f"{s['frames']}", f"{100 * s['recomputed_mean']:.1f}",
               f"{s['keyframe_interval_max']} / {s['keyframe_interval_mean']:.1f}", f"{s['ms_mean']:.0f}"]
              for r in runs for s in r["speeds"]]
    lines += ["## Keyframe threshold", "",
              "A new keyframe when more than the threshold of a frame's reflective pixels were recomputed "
              "(thesis: 0.3). Lower: more keyframes (each traced in full), fewer pixels recomputed per reused "
              "frame and a smaller error.", "",
              md_table(["scene", "path", "threshold", "recomputed %", "keyframe interval max/avg", "ms / frame",
                        "speedup over full tracing", "MAE vs full (0–255)"], rows_t), ""]
    lines += ["## Camera speed", "",
              "The same path in more frames is a slower camera; the recomputed share falls with the speed.", "",
              md_table(["scene", "path", "path frames", "frames measured", "recomputed %",
                        "keyframe interval max/avg", "ms / frame"], rows_s), ""]
    write_text(out.with_suffix(".md"), "\n".join(lines))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["living_room", "bathroom"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--frames", type=int, default=500)
    ap.add_argument("--first", type=int, default=0,
                    help="the threshold sweep on the first N frames of each path only (0 = all)")
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--thresholds", type=float, nargs="+", default=[0.1, 0.15, 0.2, 0.25, 0.3])
    ap.add_argument("--speeds", type=int, nargs="+", default=[250, 500, 1000], help="path lengths in frames")
    ap.add_argument("--out", default=str(RESULTS_DIR / "temporal_sweeps"))
    ap.add_argument("--no-progress", action="store_true")
    ap.add_argument("--report-only", action="store_true")
    args = ap.parse_args(argv)
    out = Path(args.out)
    if args.report_only:
        data = json.loads(out.with_suffix(".json").read_text())
        write_report(out, argparse.Namespace(**data["args"]), data["machine"], data["runs"], data["seconds"])
        return
    args.command = "python -m bench.temporal_sweeps " + " ".join(
        f"--{k} {' '.join(map(str, v)) if isinstance(v, list) else v}" for k, v in vars(args).items()
        if k in ("scenes", "seeds", "frames", "first", "res", "thresholds", "speeds") and v not in ([], 0))
    t0 = time.perf_counter()
    gl = create_gl_context()
    info = machine_info(gl)
    runs: list[dict] = []
    show = not args.no_progress
    for name in args.scenes:
        scene = load_named_scene(name)
        caster = RayCaster(scene)
        with SceneGPU(gl, scene) as sg:
            for seed in args.seeds:
                cams = flythrough_path(scene.bounds, args.frames, seed=seed, width=args.res, height=args.res)
                cams = cams[:args.first] if args.first else cams
                stem = f"{name} path {seed}"
                runs.append({"scene": name, "path": f"fly-through {seed}",
                             "thresholds": sweep_thresholds(gl, sg, caster, cams, args.thresholds, stem, show),
                             "speeds": sweep_speeds(gl, sg, caster, scene.bounds, seed, args.res, args.speeds,
                                                    0, stem, show)})
                saved = {k: v for k, v in vars(args).items() if k not in ("out", "report_only", "no_progress")}
                write_json(out.with_suffix(".json"), {"args": saved, "machine": info,
                                                      "seconds": time.perf_counter() - t0, "runs": runs})
                write_report(out, args, info, runs, time.perf_counter() - t0)
    gl.release()
    print(out.with_suffix(".md").read_text())


if __name__ == "__main__":
    main()

"""Reflection reuse against the size of one camera step (thesis Ch. 5; the thresholds
of service.stream.camera_jump: service.stream.JUMP_LIMITS, per reflection method).

From keyframe cameras on bench.temporal's fly-through paths (its scenes, seeds and
500-frame paths; --per-path cameras spread along each), target cameras one step
away: a pure turn of the view direction (scenes.camera.turned, alternately left and
right), a pure move of eye and target across the view (moved, in the image-plane
direction with the most room in the scene box; a move leaving the box is left out)
by a fraction of the eye's distance to its target, a zoom of
tan(fov/2) out (× z) and in (÷ z), a pure roll about the view direction (rolled), and,
for the steady state, the path's own camera 0, 1, 5 and 10 frames later. Per target
and tracer (Embree's sparse rays, "raytrace", and the cluster tracer, "cluster", as
the stream makes them, with the stream's ReuseSettings: no timing syncs, no search
statistics): a keyframe at the start camera, `next_frame` at the target (reused, no
forced keyframe), and a keyframe at the target — full tracing by the same tracer, the
reference (so a fresh keyframe's own error is 0 by construction; for the cluster
tracer its error against Embree's keyframe is reported too). The order alternates
between targets (start keyframe, reused frame, target keyframe; or the target
keyframe first), so neither timed frame always runs after the other.
Reported per kind and step: mean absolute error of the reused frame (0-255, as
bench.temporal) over the whole frame, over its reflective pixels and over the pixels
it reused (flags REUSED: recomputed pixels equal the reference, so only this one
measures the reuse's own error at large steps), the recomputed share of its
reflective pixels, and its time against the keyframe's at the target (wall time of
each `next_frame` call, which returns the read-back colour; views under
MIN_REFLECTIVE reflective are left out of the time ratio). Results:
bench/results/stream_jumps.md (+ .json, + _mae.png).

    python -m bench.stream_jumps [--scenes living_room bathroom] [--res 256]
        [--tracers embree clusters] [--per-path 3] [--turns ...] [--moves ...] [--zooms ...]
        [--rolls ...] [--path-steps ...] [--append] [--out bench/results/stream_jumps]
"""

from __future__ import annotations

import argparse
import functools
import itertools
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
from bench.temporal import MAE_BOUND_255, PATH_SEEDS, THESIS_PATH_FRAMES, add_run_args, mae
from gl_passes.cluster_tracer import ClusterTracer
from gl_passes.composition import REUSED
from gl_passes.context import create_gl_context
from gl_passes.reprojection import ReflectionReuser, ReuseSettings
from gl_passes.upload import SceneGPU
from reference.raycast import RayCaster
from reference.reflection_tracer import EmbreeTracer
from scenes.camera import Camera, camera_step, flythrough_path, moved, rolled, turned, zoomed

#: Step sizes per kind: turn (degrees), move (of the eye's distance to its target),
#: zoom (factor on tan(fov/2), out and in), roll (degrees), path (frames later).
TURNS = (2.0, 5.0, 10.0, 15.0, 20.0, 30.0, 45.0, 60.0, 90.0)
#: 0.125-0.2: the fly-throughs step up to 0.101 per frame, so JumpLimits.move must lie above that.
MOVES = (0.05, 0.1, 0.125, 0.15, 0.2, 0.25, 0.5)
ZOOMS = (1.05, 1.1, 1.25, 1.5, 2.0)
ROLLS = (10.0, 45.0, 90.0, 180.0)
PATH_STEPS = (0, 1, 5, 10)
KINDS = ("path", "turn", "move", "zoom_out", "zoom_in", "roll")
#: The kinds camera_jump limits, with the JumpLimits field that does it (and its name).
THRESHOLDS = {"turn": "JumpLimits.turn_deg", "move": "JumpLimits.move", "zoom": "JumpLimits.zoom"}
FIELDS = {"turn": "turn_deg", "move": "move", "zoom": "zoom"}
#: The stream's reflection methods and the tracer each uses.
METHODS = {"raytrace": "embree", "cluster": "clusters"}
UNITS = {"path": "{:g} frames", "turn": "{:g}°", "move": "{:g}", "zoom_out": "×{:g}", "zoom_in": "÷{:g}",
         "roll": "{:g}°"}
XLABELS = {"turn": "turn (degrees)", "move": "move (of the distance to the target)",
           "zoom_out": "tan(fov/2) × z", "zoom_in": "tan(fov/2) ÷ z", "roll": "roll (degrees)"}
#: "Clearly above the steady state": the reused frame's MAE over the pixels it reused
#: over this many times that MAE's mean on the path steps 1-10 (same scene, tracer and
#: keyframe cameras).
CLEARLY = 2.0
#: Views with less than this share of reflective pixels are left out of the time ratio:
#: there both frames cost next to nothing and their ratio is noise.
MIN_REFLECTIVE = 0.01
#: The recommended thresholds keep a margin below the cost crossing: the largest step
#: at which (and below which) Embree's reused frame costs at most this share of a
#: keyframe in every scene. Past it a keyframe forced at a single jump is the cheaper
#: choice: the reused jump frame costs nearly a keyframe and, recomputing more than the
#: keyframe policy's share, makes the next frame a keyframe anyway.
MARGIN_RATIO = 0.8
#: Where a method's reused frame costs over MARGIN_RATIO of a keyframe at every tested
#: step above the fly-throughs' (the cluster tracer), a forced keyframe costs about
#: nothing and removes the error: the threshold is then the smallest tested step at
#: least FLOOR_MARGIN times the fly-throughs' largest step (for the zoom: its logarithm),
#: so that the stream still reuses on paths up to that much faster than bench.temporal's.
FLOOR_MARGIN = 1.5


def room(point: np.ndarray, bounds: tuple[np.ndarray, np.ndarray]) -> float:
    """Distance from `point` to the nearest face of the box (negative outside)."""
    lo, hi = (np.asarray(b, np.float64) for b in bounds)
    return float(np.min(np.minimum(point - lo, hi - point)))


def targets(cams: list[Camera], i: int, bounds, steps: dict[str, tuple],
            sign: float) -> list[tuple[str, float, Camera]]:
    """(kind, step, camera) of the targets from keyframe camera cams[i]: turns to the
    left (sign +1) or right (-1); moves across the view (eye and target), in the one of
    8 directions in the image plane (right, up and between) that leaves the eye the
    most room in the scene box at that move; zooms out and in; rolls; the path's
    later cameras."""
    cam = cams[i]
    right, up, _ = cam.basis()
    sides = [np.cos(a) * right + np.sin(a) * up for a in np.radians(np.arange(0, 360, 45))]

    def side(m: float) -> np.ndarray:
        return max(sides, key=lambda d: room(np.asarray(moved(cam, m, d).eye), bounds))
    out = [("path", float(d), cams[i + int(d)]) for d in steps["path"] if i + int(d) < len(cams)]
    out += [("turn", t, turned(cam, sign * t)) for t in steps["turn"]]
    out += [("move", m, moved(cam, m, side(m))) for m in steps["move"]]
    out += [("zoom_out", z, zoomed(cam, z)) for z in steps["zoom"]]
    out += [("zoom_in", z, zoomed(cam, 1 / z)) for z in steps["zoom"]]
    out += [("roll", r, rolled(cam, r)) for r in steps["roll"]]
    return out


def reused_error(reused, key: np.ndarray) -> tuple[float, int]:
    """(sum of the absolute error on the 0-255 scale, number of pixel-channels) over the
    pixels `reused` (a ReuseFrame) reused (flags REUSED) against the colour `key`."""
    m = reused.flags == REUSED
    d = np.abs(reused.color[m] - key[m])
    return float(d.sum() * 255), int(d.size)


def timed(ru: ReflectionReuser, cam: Camera, keyframe: bool = False):
    """(frame, wall ms) of one `next_frame` call (it returns the read-back colour, so the
    time includes the GPU work even without the reuser's timing syncs)."""
    t = time.perf_counter()
    frame = ru.next_frame(cam, keyframe=keyframe)
    return frame, 1000 * (time.perf_counter() - t)


def measure_keyframe(reusers: dict, cams: list[Camera], i: int, bounds, steps: dict, sign: float,
                     desc: str, show: bool, parity: int = 0) -> list[dict]:
    """Every target of keyframe camera cams[i] with every tracer's reuser: keyframe at
    the start, the reused frame at the target, the keyframe at the target; on every
    other target (by `parity` + its index) the keyframe at the target first."""
    start = cams[i]
    first: dict[str, np.ndarray] = {}
    rows = []
    for j, (kind, step, cam) in enumerate(progress(targets(cams, i, bounds, steps, sign), show, desc=desc,
                                                   unit="target", leave=False)):
        cam = cam.fit_clip(bounds)
        st = camera_step(start, cam)
        key_first = (parity + j) % 2 == 1
        keys: dict[str, np.ndarray] = {}
        for tname, ru in reusers.items():
            if key_first:
                key, key_ms = timed(ru, cam, keyframe=True)
            k0 = ru.next_frame(start, keyframe=True)
            reused, reused_ms = timed(ru, cam)
            if not key_first:
                key, key_ms = timed(ru, cam, keyframe=True)
            first.setdefault(tname, k0.color)
            assert not reused.stats.keyframe and key.stats.keyframe
            keys[tname] = key.color
            s = reused.stats
            err, n = reused_error(reused, key.color)
            row = {"kind": kind, "step": step, "tracer": tname, "turn_deg": st.turn_deg, "move": st.move,
                   "zoom": st.zoom, "roll_deg": st.roll_deg, "mae": mae(reused.color, key.color),
                   "reused_err_sum": err, "reused_n": n,
                   "recomputed": s.recomputed_fraction, "disoccluded": s.disoccluded / max(s.reflective, 1),
                   "unreliable": s.unreliable / max(s.reflective, 1),
                   "reflective": s.reflective / reused.reflective.size,
                   "reused_ms": reused_ms, "keyframe_ms": key_ms, "key_first": key_first,
                   "start_repeat_mae": mae(k0.color, first[tname]),
                   "eye_room": room(np.asarray(cam.eye), bounds)}
            if tname != "embree" and "embree" in keys:
                row["mae_vs_embree"] = mae(reused.color, keys["embree"])
                row["keyframe_mae_vs_embree"] = mae(key.color, keys["embree"])
            rows.append(row)
    return rows


# --- summaries ------------------------------------------------------------------------------

def cells(samples: list[dict]) -> list[dict]:
    """Mean over keyframe cameras per (scene, tracer, kind, step): MAE, MAE over the
    targets' reflective pixels (`mae_reflective`, mean MAE / mean reflective share: the
    reused frame and the keyframe share the G-buffer, so they differ only there; the
    whole frame's MAE also falls when a step turns the view away from reflectors; the
    ratio of means weighs each camera by its reflective pixels, so a view left with a
    few badly reused ones does not dominate), MAE over the pixels the reused frame
    reused (`mae_reused`, mean error sum / mean pixel-channel count, None where none
    was: recomputed pixels equal the reference, so the other two fall as a step
    recomputes more), recomputed share, times (and their ratio: mean reused / mean
    keyframe ms, over the samples at least MIN_REFLECTIVE reflective, `n_timed` of
    them; None where none is), the cluster tracer's MAE against Embree, the measured
    step. Samples whose eye left the scene box (a long move) are left out."""
    groups: dict[tuple, list[dict]] = {}
    for s in samples:
        if s.get("eye_room", 0.0) < 0:  # a move that left the scene box: its view is not the scene's
            continue
        groups.setdefault((s["scene"], s["tracer"], s["kind"], s["step"]), []).append(s)
    out = []
    for (scene, tracer, kind, step), ss in groups.items():
        def mean(k: str, ss=ss) -> float | None:
            vals = [s[k] for s in ss if k in s]
            return float(np.mean(vals)) if vals else None
        timed = [s for s in ss if s["reflective"] >= MIN_REFLECTIVE]
        c = {"scene": scene, "tracer": tracer, "kind": kind, "step": step, "n": len(ss), "n_timed": len(timed),
             **{k: mean(k) for k in ("mae", "recomputed", "disoccluded", "unreliable",
                                     "reflective", "turn_deg", "move", "zoom",
                                     "roll_deg", "mae_vs_embree", "keyframe_mae_vs_embree", "reused_err_sum",
                                     "reused_n")},
             **{k: mean(k, timed) for k in ("reused_ms", "keyframe_ms")},
             "mae_max": float(max(s["mae"] for s in ss))}
        c["time_ratio"] = c["reused_ms"] / c["keyframe_ms"] if timed else None
        c["mae_reflective"] = c["mae"] / c["reflective"] if c["reflective"] else 0.0
        c["mae_reused"] = c["reused_err_sum"] / c["reused_n"] if c["reused_n"] else None
        out.append(c)
    return out


def baselines(cs: list[dict], key: str = "mae_reused") -> dict[tuple[str, str], float]:
    """(scene, tracer) → the steady state: mean `key` (an MAE) of the reused frames
    1 to 10 path frames after their keyframe (the path kind, step > 0)."""
    groups: dict[tuple[str, str], list[float]] = {}
    for c in cs:
        if c["kind"] == "path" and c["step"] > 0 and c.get(key) is not None:
            groups.setdefault((c["scene"], c["tracer"]), []).append(c[key])
    return {k: float(np.mean(v)) for k, v in groups.items()}


#: Fly-through lengths whose frames the thresholds must let through: bench.temporal's tables
#: run 500 frames, its sweeps 250 to 1000 (tests/test_service_stream.py).
PATH_LENGTHS = (250, 500, 1000)


def path_floor(scenes) -> dict[str, float]:
    """The largest step between consecutive frames of bench.temporal's fly-throughs
    (PATH_SEEDS, PATH_LENGTHS) in the built-in `scenes` (any iterable of names; computed
    once per set of names), per threshold kind: turn (degrees), move, zoom (≥ 1, either
    way). A threshold at or below it fires on them."""
    return dict(_path_floor(tuple(scenes)))


@functools.cache
def _path_floor(scenes: tuple[str, ...]) -> tuple[tuple[str, float], ...]:
    out = {"turn": 0.0, "move": 0.0, "zoom": 1.0}
    for name in scenes:
        bounds = load_named_scene(name).bounds
        for frames in PATH_LENGTHS:
            for seed in PATH_SEEDS:
                cams = flythrough_path(bounds, frames, seed=seed)
                for a, b in itertools.pairwise(cams):
                    st = camera_step(a, b)
                    out = {"turn": max(out["turn"], st.turn_deg), "move": max(out["move"], st.move),
                           "zoom": max(out["zoom"], st.zoom, 1 / st.zoom)}
    return tuple(out.items())


def first_failure(v: dict) -> float | None:
    """The first tested step that fails error (a) or cost (b) (`verdicts`)."""
    return min((s for s in (v["error_at"], v["cost_at"]) if s is not None), default=None)


def recommended(v: dict, floor: float) -> float | None:
    """The threshold to use: the margin step (`verdicts`) where it lets the fly-throughs'
    steps through (above `floor`), else the smallest tested step above the floor below
    the first error (a) or cost (b) failure whose reused frame costs at most
    MARGIN_RATIO of a keyframe in every scene (`worst_ratio`); None where none does."""
    if v.get("margin") is not None and v["margin"] > floor:
        return v["margin"]
    fail = first_failure(v)
    passing = [x for x in v["tested"] if floor < x and (fail is None or x < fail)
               and (v["worst_ratio"].get(x) is None or v["worst_ratio"][x] <= MARGIN_RATIO)]
    return min(passing) if passing else None


def above_floor(v: dict, floor: float, kind: str) -> float | None:
    """The smallest tested step below the first error (a) failure at least FLOOR_MARGIN
    times the fly-throughs' largest step `floor` (the zoom: its logarithm)."""
    least = floor ** FLOOR_MARGIN if kind == "zoom" else floor * FLOOR_MARGIN
    ok = [x for x in v["tested"] if x > floor and x >= least and (v["error_at"] is None or x < v["error_at"])]
    return min(ok) if ok else None


def never_cheap(v: dict, floor: float) -> bool:
    """Whether the reused frame costs over MARGIN_RATIO of a keyframe (in some scene) at
    every tested step above `floor`: a forced keyframe there costs about nothing."""
    above = [x for x in v["tested"] if x > floor and v["worst_ratio"].get(x) is not None]
    return bool(above) and all(v["worst_ratio"][x] > MARGIN_RATIO for x in above)


def recommended_for(method: str, v: dict, floor: float, kind: str, cap: float | None = None) -> float | None:
    """A method's threshold: `recommended`; for a method whose reuse is never cheap above
    the fly-throughs (`never_cheap`, the cluster tracer), the smallest step with
    FLOOR_MARGIN above them (`above_floor`), no looser than `cap` (raytrace's)."""
    if method == "raytrace" or not never_cheap(v, floor):
        return recommended(v, floor)
    pick = above_floor(v, floor, kind)
    return pick if cap is None or pick is None else min(pick, cap)


def verdicts(cs: list[dict], base: dict[tuple[str, str], float], policy: float,
             tracer: str = "embree") -> dict[str, dict]:
    """Per kind that camera_jump limits (turn, move, zoom: out and in together) and
    roll, for `tracer`'s cells, the first step at which, in some scene (mean over its
    keyframe cameras): `error_at`, the reused frame's MAE over the pixels it reused
    exceeds CLEARLY × the steady state (`base`, baselines of that MAE); `cost_at`, it
    takes as long as the keyframe at the target; `policy_at`, more than `policy` (the
    keyframe threshold) of its reflective pixels are recomputed (the next frame is a
    keyframe anyway). `keep`: the largest step below the first error or cost failure
    (reuse is fine up to there; None: not even the smallest); `policy_keep`: the
    largest below the first failure of any of the three; `margin`: the largest below
    the first error failure and the first step at which the reused frame costs over
    MARGIN_RATIO of a keyframe (the recommendation); `worst_ratio` / `least_ratio`:
    per step, the largest / smallest reused / keyframe time over the scenes (None:
    no timed sample); `worst_error`: per step, the largest reused-pixel MAE × steady;
    `recomputed`: per step, the least and largest recomputed share; `saving_at_keep`:
    the share of a keyframe's time the reused frame saves there (the least over the
    scenes); `exact`: per step, whether the reused frames equal the
    keyframes (MAE < 0.001, under 0.1 % recomputed)."""
    out = {}
    for kind, names in (("turn", ("turn",)), ("move", ("move",)), ("zoom", ("zoom_out", "zoom_in")),
                        ("roll", ("roll",))):
        mine = [c for c in cs if c["kind"] in names and c["tracer"] == tracer]
        steps = sorted({c["step"] for c in mine})
        at: dict[str, float | None] = {"error_at": None, "cost_at": None, "policy_at": None}
        worst: dict[float, float | None] = {}
        least: dict[float, float | None] = {}
        error: dict[float, float | None] = {}
        recomputed: dict[float, tuple[float, float]] = {}
        for step in steps:
            here = [c for c in mine if c["step"] == step]
            recomputed[step] = (min(c["recomputed"] for c in here), max(c["recomputed"] for c in here))
            ratios = [c["time_ratio"] for c in here if c["time_ratio"] is not None]
            worst[step] = max(ratios) if ratios else None
            least[step] = min(ratios) if ratios else None
            rel = [c["mae_reused"] / base[(c["scene"], c["tracer"])] for c in here
                   if c["mae_reused"] is not None and base.get((c["scene"], c["tracer"]))]
            error[step] = max(rel) if rel else None
            fails = {"error_at": error[step] is not None and error[step] > CLEARLY,
                     "cost_at": worst[step] is not None and worst[step] >= 1.0,
                     "policy_at": any(c["recomputed"] > policy for c in here)}
            for k, failed in fails.items():
                if failed and at[k] is None:
                    at[k] = step

        def largest_below(*limits: float | None, steps=steps) -> float | None:
            first = min((s for s in limits if s is not None), default=None)
            below = [s for s in steps if first is None or s < first]
            return max(below) if below else None
        keep = largest_below(at["error_at"], at["cost_at"])
        over = [x for x in steps if worst[x] is not None and worst[x] > MARGIN_RATIO]
        margin = largest_below(at["error_at"], at["cost_at"], min(over, default=None))
        out[kind] = {**at, "keep": keep,
                     "saving_at_keep": 1 - worst[keep] if keep is not None and worst[keep] is not None else None,
                     "margin": margin, "policy_keep": largest_below(at["error_at"], at["cost_at"], at["policy_at"]),
                     "tested": steps, "worst_ratio": worst, "least_ratio": least, "worst_error": error,
                     "recomputed": recomputed,
                     "exact": {x: bool(em) and all(c["mae"] < 1e-3 and c["recomputed"] < 1e-3 for c in em)
                               for x in steps for em in [[c for c in mine if c["step"] == x]]}}
    return out


# --- report ---------------------------------------------------------------------------------

def _fmt(c: dict | None, key: str, fmt: str) -> str:
    return "—" if c is None or c.get(key) is None else format(c[key], fmt)


def _times(c: dict | None, base: dict, key: str) -> str:
    """A cell's MAE `key` with its multiple of the steady state `base` (—: none)."""
    if c is None or c.get(key) is None:
        return "—"
    b = base.get((c["scene"], c["tracer"]))
    return f"{c[key]:.2f} ({c[key] / b:.1f}×)" if b else f"{c[key]:.2f}"


def summary_table(cs: list[dict], scenes: list[str], tracers: list[str], bases: dict[str, dict]) -> str:
    """One row per kind and step; per tracer (cells: one per scene, ' / ' between) the
    reused frame's MAE over the whole frame, over its reflective pixels and over the
    pixels it reused (each × its steady state, `bases` by key), its recomputed %, and
    reused / keyframe time."""
    idx = {(c["scene"], c["tracer"], c["kind"], c["step"]): c for c in cs}
    head = ["kind", "step", "measured"]
    for t in tracers:
        head += [f"{t}: MAE", "MAE reflective px (× steady)", "MAE reused px (× steady)", "recomputed %",
                 "reused / keyframe time"]
    rows = []
    for kind in KINDS:
        for step in sorted({c["step"] for c in cs if c["kind"] == kind}):
            same = [c for c in cs if c["kind"] == kind and c["step"] == step]
            measured = (f"{np.mean([c['turn_deg'] for c in same]):.1f}°, {np.mean([c['move'] for c in same]):.3f}, "
                        f"×{np.mean([c['zoom'] for c in same]):.3f}, "
                        f"{np.mean([abs(c['roll_deg']) for c in same]):.0f}°" if kind == "path" else "")
            row = [kind, UNITS[kind].format(step), measured]
            for t in tracers:
                cc = [idx.get((s, t, kind, step)) for s in scenes]
                row.append(" / ".join(_fmt(c, "mae", ".2f") for c in cc))
                row.append(" / ".join(_times(c, bases["mae_reflective"], "mae_reflective") for c in cc))
                row.append(" / ".join(_times(c, bases["mae_reused"], "mae_reused") for c in cc))
                row.append(" / ".join(_fmt(c, "recomputed", ".0%").rstrip("%") for c in cc))
                row.append(" / ".join(_fmt(c, "time_ratio", ".2f") for c in cc))
            rows.append(row)
    return md_table(head, rows)


def detail_table(cs: list[dict]) -> str:
    """Every cell: times in ms, the recomputed share split, the cluster tracer against Embree."""
    order = {k: i for i, k in enumerate(KINDS)}
    rows = [[c["scene"], c["tracer"], c["kind"], UNITS[c["kind"]].format(c["step"]), c["n"], f"{c['mae']:.3f}",
             f"{c['mae_max']:.3f}", f"{c['mae_reflective']:.2f}", _fmt(c, "mae_reused", ".2f"),
             f"{100 * c['recomputed']:.1f} ({100 * c['disoccluded']:.1f} + {100 * c['unreliable']:.1f})",
             f"{100 * c['reflective']:.0f}", c.get("n_timed", c["n"]), _fmt(c, "reused_ms", ".0f"),
             _fmt(c, "keyframe_ms", ".0f"), _fmt(c, "time_ratio", ".2f"), _fmt(c, "mae_vs_embree", ".3f"),
             _fmt(c, "keyframe_mae_vs_embree", ".3f")]
            for c in sorted(cs, key=lambda c: (c["scene"], c["tracer"], order[c["kind"]], c["step"]))]
    return md_table(["scene", "tracer", "kind", "step", "keyframe cameras", "MAE mean", "MAE max", "MAE reflective px",
                     "MAE reused px", "recomputed % (disoccluded + unreliable)", "reflective %", "timed",
                     "reused ms", "keyframe ms", "reused / keyframe", "MAE vs Embree's keyframe",
                     "keyframe's MAE vs Embree's"], rows)


def untimed(samples: list[dict]) -> dict[str, int]:
    """Samples left out of the time ratios (under MIN_REFLECTIVE reflective; eye inside
    the scene box), per scene, kind and step (every tracer's sample counts)."""
    out: dict[str, int] = {}
    for s in samples:
        if s.get("eye_room", 0.0) >= 0 and s["reflective"] < MIN_REFLECTIVE:
            k = f"{s['scene']} {s['kind']} {UNITS[s['kind']].format(s['step'])}"
            out[k] = out.get(k, 0) + 1
    return out


def outside(samples: list[dict]) -> dict[str, int]:
    """Samples left out because their eye left the scene box, per kind and step."""
    out: dict[str, int] = {}
    for s in samples:
        if s.get("eye_room", 0.0) < 0:
            k = f"{s['kind']} {UNITS[s['kind']].format(s['step'])} {s['tracer']}"
            out[k] = out.get(k, 0) + 1
    return out


def temporal_steady(path: Path) -> list[list[str]]:
    """bench.temporal's steady state (its mean MAE of ours over its paths) per scene and
    tracer, from its JSON where present."""
    if not path.exists():
        return []
    runs = json.loads(path.read_text())["runs"]
    groups: dict[tuple[str, str, str], list[float]] = {}
    for r in runs:
        groups.setdefault((r["scene"], r["tracer"], f"{r.get('res', '?')}²"), []).append(r["mae_ours_mean"])
    return [[s, t, res, len(v), f"{np.mean(v):.3f}"] for (s, t, res), v in groups.items()]


def current_limits() -> dict[str, dict[str, float]]:
    """service.stream's thresholds per method (JUMP_LIMITS: JumpLimits' turn_deg, move, zoom)."""
    from service.stream import JUMP_LIMITS

    return {m: {k: float(getattr(lim, f)) for k, f in FIELDS.items()} for m, lim in JUMP_LIMITS.items()}


def _step_fmt(kind: str):
    fmt = UNITS["zoom_out"] if kind == "zoom" else UNITS[kind]
    return lambda x: "—" if x is None else fmt.format(x)


def _floor_fmt(kind: str, x: float) -> str:
    """The fly-throughs' largest step of `kind`, to the digits that matter."""
    return {"turn": f"{x:.2f}°", "move": f"{x:.3f}", "zoom": f"×{x:.4f}"}[kind]


def _error_trend(v: dict, f) -> str:
    """How the reused-pixel error (worst scene, × steady) runs over the tested steps."""
    pts = [(x, e) for x, e in v["worst_error"].items() if e is not None]
    if not pts:
        return "no step reused a pixel"
    peak = max(pts, key=lambda p: p[1])
    none = [x for x, e in v["worst_error"].items() if e is None]
    return (f"the error on reused pixels (worst scene) is {pts[0][1]:.1f}× its steady state at {f(pts[0][0])} and "
            f"{pts[-1][1]:.1f}× at {f(pts[-1][0])}, at most {peak[1]:.1f}× (at {f(peak[0])})"
            + (f"; nothing reused at {', '.join(map(f, none))}" if none else ""))


def _ratios(v: dict, xs, f) -> str:
    return ", ".join(f"{f(x)}: {v['worst_ratio'][x]:.2f}" if v["worst_ratio"].get(x) is not None else f"{f(x)}: —"
                     for x in xs)


def _span(xs: list[float]) -> str:
    lo, hi = f"{min(xs):.2f}", f"{max(xs):.2f}"
    return lo if lo == hi else f"{lo}-{hi}"


def _why(method: str, v: dict, fl: float, kind: str, pick: float | None, cap: float | None) -> str:
    """Why `pick` is the method's threshold for `kind` (`recommended_for`)."""
    f = _step_fmt(kind)
    fail = first_failure(v)
    above = [x for x in v["tested"] if x > fl and (fail is None or x < fail)]
    ff = _floor_fmt(kind, fl)
    if method != "raytrace" and never_cheap(v, fl):
        least = [v["least_ratio"][x] for x in v["tested"] if x > fl and v["least_ratio"].get(x) is not None]
        return ("its reused frame costs over " f"{MARGIN_RATIO:g} of a keyframe at every tested step above the "
                f"fly-throughs' (worst scene per step: {_ratios(v, [x for x in v['tested'] if x > fl], f)}; "
                f"least scene {_span(least)}), so a keyframe forced at a jump costs about "
                "what the reused frame would and removes its error: the threshold is the smallest tested step "
                f"at least {FLOOR_MARGIN:g}× the fly-throughs' largest ({ff}"
                + (", on the zoom's logarithm" if kind == "zoom" else "") + ")"
                + (f", no looser than raytrace's {f(cap)}" if cap is not None and pick == cap else "")
                + (" — none passes (a)" if pick is None else ""))
    if pick is not None and pick == v.get("margin"):
        return (f"the largest step passing (a) at which the reused frame costs at most {MARGIN_RATIO:g} of a "
                f"keyframe in every scene (worst: {_ratios(v, [pick], f)})")
    head = (f"the margin step {f(v.get('margin'))} would fire on the fly-throughs, whose frames step up to {ff}"
            if v.get("margin") is not None else f"no tested step keeps the reused frame at {MARGIN_RATIO:g} of a "
            f"keyframe or less from the smallest on (the fly-throughs step up to {ff})")
    if pick is not None:
        skipped = [x for x in above if x < pick]
        return (f"{head}; {f(pick)} is the smallest tested step above {ff} that passes (a) and (b) and costs at "
                f"most {MARGIN_RATIO:g} of a keyframe (worst: {_ratios(v, [pick], f)})"
                + (f"; the steps between cost more ({_ratios(v, skipped, f)})" if skipped else ""))
    upto = f"up to the first failing step {f(fail)}" if fail is not None else "up to the largest tested"
    if not above:
        return f"{head}; the range between {ff} and {f(fail)} is untested"
    return (f"{head}; no tested step above {ff} {upto} costs at most {MARGIN_RATIO:g} of a keyframe "
            f"(worst scene: {_ratios(v, above, f)}): the range from {ff} {upto} has no passing step — a "
            f"threshold there gives up the margin (the smallest such step passing (a) and (b): {f(min(above))})")


def _verdict(cur: float | None, pick: float | None, fail: float | None, fl: float) -> str:
    """How the current threshold `cur` compares (`fail`: the first failing step that counts)."""
    if cur is None:
        return "— (none)"
    word = ("too loose (lets steps through where the reuse fails)" if fail is not None and cur >= fail
            else "fires on the fly-throughs" if cur <= fl
            else "holds" if pick is not None and cur == pick
            else "stricter than recommended" if pick is not None and cur < pick
            else "looser than recommended" if pick is not None
            else "no tested step recommends it (see below)")
    return f"{cur:g}: {word}"


def _roll(v: dict, f, fail: float | None) -> str:
    """The roll line (`fail`: the first failing roll that counts): exact rolls (square
    frames only), what the others recompute and cost."""
    if fail is not None:
        return (f"- roll: from {f(fail)} the reuse fails; a roll threshold would catch it, but the "
                "fly-through paths' look-at cameras spin that much near the vertical (service.stream), so it "
                "would fire on them.")
    exact = [x for x in v["tested"] if x in (90.0, 180.0) and v["exact"].get(x)]
    rest = [x for x in v["tested"] if x not in exact]
    parts = [f"- roll: the error passes at every tested roll (up to {f(max(v['tested']))})"
             + (" and so does the cost" if v["cost_at"] is None
                else f"; the reused frame costs as long as a keyframe from {f(v['cost_at'])}, so a keyframe there "
                "would cost no more, but the error stays within (a) and a roll threshold would fire on the "
                "fly-throughs, whose look-at cameras spin near the vertical (service.stream)")]
    if exact:
        parts.append(f"a roll of {' or '.join(map(f, exact))} maps a square frame's pixels onto pixels (square "
                     "frames only, as here: on a W ≠ H frame a quarter roll swaps the axes and no longer maps the "
                     "frame onto itself), so there the reuse is exact (MAE < 0.001) and recomputes almost nothing "
                     "(< 0.1 %)")
    smallest = min(rest) if rest else None
    for x in rest:
        if x == smallest:
            continue
        lo, hi = (f"{100 * r:.0f}" for r in v["recomputed"][x])
        err, r, r0 = v["worst_error"][x], v["worst_ratio"][x], v["worst_ratio"][smallest]
        if err is None or r is None or r0 is None:
            continue
        what = (f"a {f(x)} roll recomputes {lo if lo == hi else f'{lo}-{hi}'} % of the reflective pixels"
                + (" (the image corners)" if x % 90 else "")
                + f" and costs {r:.2f} of a keyframe (worst scene; a {f(smallest)} roll {r0:.2f}): ")
        what += ("the error on its reused pixels does not rise" if err <= 1.25
                 else "the error on its reused pixels rises") + f" ({err:.1f}× steady)"
        what += (" and the cost stays under a keyframe" if r < 1.0 else f" and the cost reaches {r:.2f} of a keyframe")
        parts.append(what)
    return "; ".join(parts) + ": no roll threshold is needed."


def reading(vds: dict[str, dict], policy: float, floor: dict[str, float], untimed: dict[str, int]) -> list[str]:
    """The closing reading per method (`vds`: method → `verdicts` for its tracer): where
    error or cost rise, what a roll does, the thresholds (`floor`: the fly-throughs'
    largest steps, `path_floor`; `untimed`: samples left out of the time ratios)."""
    current = current_limits()
    pct = f"{100 * policy:.0f} %"
    n_untimed = sum(untimed.values())
    lines = ["## Reading", "",
             f"Criteria, each failing when it fails in some scene (mean over its keyframe cameras): (a) error: "
             f"the reused frame's MAE over the pixels it reused (flags REUSED) exceeds {CLEARLY:g}× its tracer's "
             "steady state (the same MAE of the reused frames 1-10 path frames after their keyframe) — the "
             "recomputed pixels equal the reference (the same tracer's keyframe), so the MAE over the whole frame "
             "or its reflective pixels falls as a step recomputes more and says nothing about the reuse there; "
             "(b) cost: the method's reused frame takes as long as a keyframe at the target. Times are the wall "
             "time of each `next_frame` call (the stream's settings: no timing syncs, so the reuser's own step "
             "timings could miss GPU work in flight); the reused frame and the keyframe at the target alternate in "
             f"order between targets; views under {100 * MIN_REFLECTIVE:g} % reflective are left out of the time "
             f"ratios (their frames cost next to nothing): {n_untimed} samples"
             + (f" ({', '.join(f'{k} × {n}' for k, n in untimed.items())})" if untimed else "") + ". "
             "A threshold fits the data between the last tested step that passes and the first that fails. For "
             f"information, (c): more than {pct} of the reflective pixels recomputed "
             "(ReuseSettings.keyframe_threshold), where the keyframe policy makes the *next* frame a keyframe "
             "anyway; (c) bounds nothing either way (past it a keyframe forced at a single jump saves a little, "
             "while on a camera moving that fast every frame forced keyframes cost more). Where the reused jump "
             "frame costs nearly a keyframe the single-jump saving is small, so the recommended thresholds keep a "
             f"margin: the largest step passing (a) at which the method's reused frame costs at most "
             f"{MARGIN_RATIO:g} of a keyframe in every scene, unless that step would fire on bench.temporal's "
             "fly-throughs (their largest step between frames: "
             f"{floor['turn']:.2f}°, move {floor['move']:.4f}, zoom ×{floor['zoom']:.4f}; paths of "
             f"{', '.join(map(str, PATH_LENGTHS))} frames), where the stream would then stop reusing as "
             "bench.temporal measures: then the smallest tested step above them that passes (a) and (b) and "
             f"costs at most {MARGIN_RATIO:g} of a keyframe, or none. A method whose reused frame costs over "
             f"{MARGIN_RATIO:g} of a keyframe at every step above the fly-throughs' (the cluster tracer) gains "
             "nothing by reusing across a jump, and a forced keyframe removes the error: its thresholds are the "
             f"smallest tested steps at least {FLOOR_MARGIN:g}× the fly-throughs' largest, no looser than "
             "raytrace's.", ""]
    picks: dict[str, dict[str, float | None]] = {}
    for method, vd in vds.items():
        cur = current.get(method, {})
        picks[method] = {}
        rows, say = [], []
        for kind, v in vd.items():
            f = _step_fmt(kind)
            fl = floor.get(kind)
            if kind in THRESHOLDS:
                cap = picks.get("raytrace", {}).get(kind) if method != "raytrace" else None
                pick = recommended_for(method, v, fl, kind, cap)
                picks[method][kind] = pick
                # a method whose reuse is never cheap: its cost (b) is noise about 1, only the error counts
                free = method != "raytrace" and never_cheap(v, fl)
                fail = v["error_at"] if free else first_failure(v)
                verdict = _verdict(cur.get(kind), pick, fail, fl)
            else:
                pick, verdict = v.get("margin"), "— (none)"
            rows.append([kind, f(v["error_at"]), f(v["cost_at"]), f(v["policy_at"]), f(v["keep"]), f(pick), verdict])
            if kind in THRESHOLDS and free:
                ok = [x for x in v["tested"] if v["error_at"] is None or x < v["error_at"]]
                say.append(f"- {kind}: {_error_trend(v, f)}. The error passes (a) up to {f(max(ok, default=None))}"
                           + (f" and fails from {f(fail)}" if fail is not None else " (every tested step)")
                           + f"; the reused frame costs over {MARGIN_RATIO:g} of a keyframe at every step above "
                           + "the fly-throughs' in some scene"
                           + (f" ((b), as long as a keyframe, from {f(v['cost_at'])})" if v["cost_at"] else "")
                           + f"; recomputed > {pct} from {f(v['policy_at'])}. "
                           + "Reused / keyframe time, worst scene: " + _ratios(v, v["tested"], f)
                           + f". Recommended {THRESHOLDS[kind]} = "
                           + (f"{pick:g}" if pick is not None else "none") + ": "
                           + _why(method, v, fl, kind, pick, cap) + f"; now {verdict}.")
            elif kind in THRESHOLDS:
                saving = (f" (there its reused frame saves {v['saving_at_keep']:.0%} of a keyframe's time, worst "
                          "scene)" if v.get("saving_at_keep") is not None else "")
                say.append(f"- {kind}: {_error_trend(v, f)}. Error and cost pass up to {f(v['keep'])}{saving}"
                           + (f" and fail from {f(fail)}" if fail is not None else " (every tested step)")
                           + f"; recomputed > {pct} from {f(v['policy_at'])}. Reused / keyframe time, worst scene: "
                           + _ratios(v, v["tested"], f) + f". Recommended {THRESHOLDS[kind]} = "
                           + (f"{pick:g}" if pick is not None else "none") + ": "
                           + _why(method, v, fl, kind, pick, cap) + f"; now {verdict}.")
            else:
                # the cluster tracer's cost (b) is noise about 1 wherever it recomputes a pixel: only its error counts
                say.append(_roll(v, f, first_failure(v) if method == "raytrace" else v["error_at"]))
        title = ("raytrace (Embree's sparse rays: reuse saves tracing)" if method == "raytrace"
                 else "cluster (the cluster tracer renders whole frames)" if method == "cluster" else method)
        lines += [f"### {title}", "",
                  md_table(["kind", f"(a) reused-px MAE > {CLEARLY:g}× steady from",
                            "(b) reused ≥ keyframe time from", f"(c) recomputed > {pct} from",
                            "largest step passing (a), (b)", "recommended", "current threshold"], rows),
                  "", *say, ""]
    lines += ["Thresholds per method (turn_deg, move, zoom; — : no tested step fits, see above): "
              + "; ".join(f"{m} " + ", ".join(_step_fmt(k)(p.get(k)) for k in THRESHOLDS) for m, p in picks.items())
              + ".", ""]
    return lines


def write_report(out: Path, args: argparse.Namespace, info: dict, data: dict, seconds: float) -> None:
    samples = data["samples"]
    cs = cells(samples)
    base = baselines(cs)
    policy = ReuseSettings().keyframe_threshold
    scenes = list(dict.fromkeys(s["scene"] for s in samples))
    tracers = list(dict.fromkeys(s["tracer"] for s in samples))
    vds = {m: verdicts(cs, base, policy, t) for m, t in METHODS.items() if t in tracers}
    tri = ", ".join(f"{s} {n:,}" for s, n in data["triangles"].items())
    n_keys = len({(s["scene"], s["path"], s["frame"]) for s in samples})
    facts = [f"Scenes (triangles): {tri}; {args.res}²; tracers {', '.join(tracers)}.",
             f"{n_keys} keyframe cameras: frames {', '.join(map(str, data['frames']))} of the "
             f"{args.frames}-frame fly-through paths {', '.join(map(str, args.seeds))} per scene; per target "
             "and tracer a keyframe at the start, the reused frame at the target, a keyframe at the target "
             "(the reference: full tracing by the same tracer), on every other target the keyframe at the "
             "target first; the stream's ReuseSettings (no timing syncs, no search statistics); times: wall "
             "time of each `next_frame` call, which returns the read-back colour.",
             "Turns alternate left and right between keyframe cameras; moves shift eye and target across the view, "
             "in the one of 8 image-plane directions that leaves the eye the most room in the scene box; a move "
             "that still takes the eye out of the box is left out of the means "
             f"({sum(1 for s in samples if s.get('eye_room', 0.0) < 0)} samples: "
             + (", ".join(f"{k} × {n}" for k, n in outside(samples).items()) or "none") + "); zoom out multiplies "
             "tan(fov/2) by z, zoom in divides it.",
             f"A fresh keyframe at the target is the reference, so its own error is 0; the same camera keyframed "
             f"again differs from itself by at most {max(s['start_repeat_mae'] for s in samples):.4f} (MAE, "
             "all tracers: the tracers are deterministic)."]
    lines = report_head("Reflection reuse against one camera step (stream keyframe thresholds)", args.command,
                        facts, seconds, info)
    base_all = baselines(cs, "mae")
    base_refl = baselines(cs, "mae_reflective")
    lines += ["## Steady state", "",
              "The reused frame 1-10 frames along the path after a keyframe camera (the path kind below, "
              "steps 1, 5, 10; mean MAE, 0-255, over the whole frame, over its reflective pixels and over the "
              "pixels it reused) — what a stream's reused frames err on the benchmarked paths:", "",
              md_table(["scene", "tracer", "steady MAE", "steady MAE reflective px", "steady MAE reused px"],
                       [[s, t, f"{base_all[(s, t)]:.3f}", f"{base_refl[(s, t)]:.3f}",
                         f"{base[(s, t)]:.3f}" if (s, t) in base else "—"] for (s, t) in base_all]), ""]
    steady = temporal_steady(RESULTS_DIR / "temporal.json")
    if steady:
        lines += ["bench.temporal's mean MAE of ours along its whole paths (keyframes, MAE 0, included; "
                  "bench/results/temporal.json; another resolution):", "",
                  md_table(["scene", "tracer", "res", "paths", "MAE ours"], steady), ""]
    lines += [f"Issue 14's bound on the paths' MAE: {MAE_BOUND_255:g}.", ""]
    vs = [[scene, t, f"{np.mean(k):.3f}", f"{np.mean(r):.3f}", f"{base_all[(scene, t)]:.3f}"]
          for scene in scenes for t in tracers
          for k, r in [([s["keyframe_mae_vs_embree"] for s in samples
                         if s["scene"] == scene and s["tracer"] == t and "keyframe_mae_vs_embree" in s],
                        [s["mae_vs_embree"] for s in samples
                         if s["scene"] == scene and s["tracer"] == t and "mae_vs_embree" in s])] if k]
    if vs:
        lines += ["Every tracer is compared with its own full tracing (its keyframe at the target), as "
                  "bench.temporal does; a fresh keyframe's error is so 0. Against Embree's keyframe at the same "
                  "targets (mean over all targets, whole-frame MAE):", "",
                  md_table(["scene", "tracer", "its keyframe vs Embree's", "its reused frame vs Embree's",
                            "its steady reuse MAE vs its own keyframe"], vs), ""]
    lines += ["## Error, recomputed share and time against the step", "",
              f"Means over the keyframe cameras of each scene; a cell per scene ({' / '.join(scenes)}). MAE of "
              "the reused frame against the keyframe at the target by the same tracer, over the whole frame "
              "(bench.temporal's), over the target's reflective pixels (the frames differ only there; the "
              "whole frame's MAE falls where a step turns the view away from reflectors) and over the pixels "
              "the reused frame reused (the recomputed ones equal the reference: only this MAE measures the "
              "reuse itself at large steps; —: none reused), each × its steady state; recomputed: share of "
              "the reflective pixels traced in the reused frame; time: the reused frame's over the keyframe's "
              f"at the target (views under {100 * MIN_REFLECTIVE:g} % reflective left out). "
              "'measured' (path steps): the mean turn, move, zoom and roll of the path's step.", "",
              summary_table(cs, scenes, tracers, {"mae_reflective": base_refl, "mae_reused": base}), "",
              f"![MAE on reused pixels and time against the step]({out.name}_mae.png)", ""]
    lines += ["## Every cell", "", detail_table(cs), ""]
    lines += reading(vds, policy, path_floor(scenes), untimed(samples))
    if data.get("notes"):
        lines += data["notes"]
    write_text(out.with_suffix(".md"), "\n".join(lines))


def plot(cs: list[dict], base: dict, path: Path) -> None:
    """MAE over the reused pixels (top) and reused / keyframe time (bottom) against
    the step, one panel per kind, a line per scene and tracer (dotted: its steady state)."""
    try:
        import matplotlib
    except ImportError:
        return
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kinds = [k for k in KINDS if k != "path"]
    fig, axes = plt.subplots(2, len(kinds), figsize=(3.2 * len(kinds), 6), squeeze=False)
    series = list(dict.fromkeys((c["scene"], c["tracer"]) for c in cs))
    for j, kind in enumerate(kinds):
        for n, (scene, tracer) in enumerate(series):
            pts = sorted((c["step"], np.nan if c["mae_reused"] is None else c["mae_reused"],
                          np.nan if c["time_ratio"] is None else c["time_ratio"]) for c in cs
                         if c["kind"] == kind and c["scene"] == scene and c["tracer"] == tracer)
            if not pts:
                continue
            x, y, t = zip(*pts, strict=True)
            color = f"C{n}"
            axes[0, j].plot(x, y, "o-", color=color, label=f"{scene} {tracer}")
            if (scene, tracer) in base:
                axes[0, j].axhline(base[(scene, tracer)], color=color, ls=":", lw=0.8)
            axes[1, j].plot(x, t, "o-", color=color)
        axes[0, j].set_title(kind)
        axes[1, j].axhline(1.0, color="k", lw=0.8)
        axes[1, j].set_xlabel(XLABELS[kind])
    axes[0, 0].set_ylabel("MAE on reused pixels (0-255)")
    axes[1, 0].set_ylabel("reused / keyframe time")
    axes[0, 0].legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def command_line(args: argparse.Namespace) -> str:
    return "python -m bench.stream_jumps " + " ".join(
        " ".join([f"--{k.replace('_', '-')}", *map(str, v if isinstance(v, list) else [v])])
        for k, v in vars(args).items()
        if k in ("scenes", "res", "tracers", "seeds", "frames", "per_path", "turns", "moves", "zooms", "rolls",
                 "path_steps"))


def save(out: Path, args: argparse.Namespace, info: dict, data: dict, seconds: float) -> None:
    saved = {k: v for k, v in vars(args).items() if k not in ("out", "report_only", "no_progress", "append")}
    write_json(out.with_suffix(".json"), {"args": saved, "machine": info, "seconds": seconds, **data})
    cs = cells(data["samples"])
    plot(cs, baselines(cs), out.parent / f"{out.name}_mae.png")
    write_report(out, args, info, data, seconds)


def sample_key(s: dict) -> tuple:
    """What names a sample: scene, path, keyframe camera, tracer, kind, step."""
    return s["scene"], s["path"], s["frame"], s["tracer"], s["kind"], s["step"]


def merged(saved: dict, args: argparse.Namespace, frames: list[int]) -> tuple[dict, float, argparse.Namespace]:
    """--append: the saved run's data and seconds, and arguments naming both runs
    (their commands, the union of their scenes and steps); the keyframe cameras and
    resolution must be the same."""
    old = saved["args"]
    if saved["frames"] != frames or old["res"] != args.res or old["frames"] != args.frames:
        raise SystemExit("--append needs the saved run's resolution, path length and keyframe cameras")
    for k in ("scenes", "tracers", "seeds", "turns", "moves", "zooms", "rolls", "path_steps"):
        setattr(args, k, list(dict.fromkeys([*old[k], *getattr(args, k)])))
        if k not in ("scenes", "tracers", "seeds"):
            setattr(args, k, sorted(getattr(args, k)))
    args.command = f"{old['command']}; {args.command}"
    data = {"samples": saved["samples"], "triangles": saved["triangles"], "frames": frames}
    return data, float(saved["seconds"]), args


def key_frames(frames: int, per_path: int) -> list[int]:
    """Keyframe cameras' indices, spread evenly inside the path (10 frames kept after
    each for the path steps)."""
    return [int(round(frames * (k + 1) / (per_path + 1))) for k in range(per_path)]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_run_args(ap, "stream_jumps", "add these samples to the existing .json's (e.g. larger steps measured later, "
                                     "from the same keyframe cameras; a sample measured again replaces its row)")
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--frames", type=int, default=THESIS_PATH_FRAMES, help="frames of each path (its speed)")
    ap.add_argument("--per-path", type=int, default=3, help="keyframe cameras per path")
    ap.add_argument("--turns", type=float, nargs="*", default=list(TURNS), help="degrees")
    ap.add_argument("--moves", type=float, nargs="*", default=list(MOVES), help="of the eye's distance to its target")
    ap.add_argument("--zooms", type=float, nargs="*", default=list(ZOOMS), help="factors on tan(fov/2), out and in")
    ap.add_argument("--rolls", type=float, nargs="*", default=list(ROLLS), help="degrees")
    ap.add_argument("--path-steps", type=int, nargs="*", default=list(PATH_STEPS), help="frames along the path")
    args = ap.parse_args(argv)
    out = Path(args.out)
    if args.report_only:
        data = json.loads(out.with_suffix(".json").read_text())
        saved = argparse.Namespace(**{**data["args"], "out": args.out})
        cs = cells(data["samples"])
        plot(cs, baselines(cs), out.parent / f"{out.name}_mae.png")
        write_report(out, saved, data["machine"], data, data["seconds"])
        print(f"rewrote {out.with_suffix('.md')}")
        return
    args.command = command_line(args) + (" --append" if args.append else "")
    steps = {"turn": args.turns, "move": args.moves, "zoom": args.zooms, "roll": args.rolls,
             "path": args.path_steps}
    show = not args.no_progress
    t0 = time.perf_counter()
    gl = create_gl_context()
    info = machine_info(gl)
    frames = key_frames(args.frames, args.per_path)
    data: dict = {"samples": [], "triangles": {}, "frames": frames}
    earlier = 0.0
    if args.append and out.with_suffix(".json").exists():
        data, earlier, args = merged(json.loads(out.with_suffix(".json").read_text()), args, frames)
    for name in args.scenes:
        scene = load_named_scene(name)
        data["triangles"][name] = int(scene.n_triangles)
        caster = RayCaster(scene) if "embree" in args.tracers else None
        with SceneGPU(gl, scene) as sg:
            tracers = {t: EmbreeTracer(scene, caster=caster) if t == "embree" else ClusterTracer(gl, sg)
                       for t in sorted(args.tracers, key=lambda t: t != "embree")}  # Embree first: the reference
            # the stream's settings (service.stream): no timing syncs, no search statistics
            reusers = {t: ReflectionReuser(gl, sg, tr, ReuseSettings(sync_timings=False, search_stats=False))
                       for t, tr in tracers.items()}
            n = 0
            for seed in args.seeds:
                cams = flythrough_path(scene.bounds, args.frames, seed=seed, width=args.res, height=args.res)
                for i in frames:
                    sign = 1.0 if n % 2 == 0 else -1.0
                    rows = measure_keyframe(reusers, cams, i, scene.bounds, steps, sign,
                                            f"{name} path {seed} frame {i}", show, parity=n % 2)
                    n += 1
                    new = [{"scene": name, "path": seed, "frame": i, **r} for r in rows]
                    again = {sample_key(r) for r in new}
                    data["samples"] = [r for r in data["samples"] if sample_key(r) not in again] + new
                    save(out, args, info, data, earlier + time.perf_counter() - t0)
            for ru in reusers.values():
                ru.release()
            for tr in tracers.values():
                tr.release()
    gl.release()
    print(out.with_suffix(".md").read_text())


if __name__ == "__main__":
    main()

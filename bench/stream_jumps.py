"""Reflection reuse against the size of one camera step (thesis Ch. 5; the thresholds
of service.stream.camera_jump: JUMP_TURN_DEG, JUMP_MOVE, JUMP_ZOOM).

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
Reported per kind and step: mean absolute error of the reused frame (0-255, mean
over pixels and channels, as bench.temporal), the recomputed share of its reflective
pixels, and its time against the keyframe's at the target (wall time of each
`next_frame` call, which returns the read-back colour; views under MIN_REFLECTIVE
reflective are left out of the time ratio). Results:
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
from bench.temporal import MAE_BOUND_255, PATH_SEEDS, THESIS_PATH_FRAMES
from gl_passes.cluster_tracer import ClusterTracer
from gl_passes.context import create_gl_context
from gl_passes.reprojection import ReflectionReuser, ReuseSettings
from gl_passes.upload import SceneGPU
from reference.raycast import RayCaster
from reference.reflection_tracer import EmbreeTracer
from scenes.camera import Camera, camera_step, flythrough_path, moved, rolled, turned, zoomed

#: Step sizes per kind: turn (degrees), move (of the eye's distance to its target),
#: zoom (factor on tan(fov/2), out and in), roll (degrees), path (frames later).
TURNS = (2.0, 5.0, 10.0, 15.0, 20.0, 30.0, 45.0, 60.0, 90.0)
#: 0.125-0.2: the fly-throughs step up to 0.101 per frame, so JUMP_MOVE must lie above that.
MOVES = (0.05, 0.1, 0.125, 0.15, 0.2, 0.25, 0.5)
ZOOMS = (1.05, 1.1, 1.25, 1.5, 2.0)
ROLLS = (10.0, 45.0, 90.0, 180.0)
PATH_STEPS = (0, 1, 5, 10)
KINDS = ("path", "turn", "move", "zoom_out", "zoom_in", "roll")
#: The kinds camera_jump limits, with the constant that does it and how a step reads.
THRESHOLDS = {"turn": "JUMP_TURN_DEG", "move": "JUMP_MOVE", "zoom": "JUMP_ZOOM"}
UNITS = {"path": "{:g} frames", "turn": "{:g}°", "move": "{:g}", "zoom_out": "×{:g}", "zoom_in": "÷{:g}",
         "roll": "{:g}°"}
XLABELS = {"turn": "turn (degrees)", "move": "move (of the distance to the target)",
           "zoom_out": "tan(fov/2) × z", "zoom_in": "tan(fov/2) ÷ z", "roll": "roll (degrees)"}
#: "Clearly above the steady state": the reused frame's MAE over this many times the
#: mean MAE of the path steps 1-10 (same scene, tracer and keyframe cameras).
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


def mae(a: np.ndarray, b: np.ndarray) -> float:
    """Mean absolute error on the 0-255 scale, over pixels and channels (bench.temporal's)."""
    return float(np.abs(a - b).mean() * 255)


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
            row = {"kind": kind, "step": step, "tracer": tname, "turn_deg": st.turn_deg, "move": st.move,
                   "zoom": st.zoom, "roll_deg": st.roll_deg, "mae": mae(reused.color, key.color),
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
    few badly reused ones does not dominate), recomputed share, times (and their
    ratio: mean reused / mean keyframe ms, over the samples at least MIN_REFLECTIVE
    reflective, `n_timed` of them; None where none is), the cluster tracer's MAE
    against Embree, the measured step. Samples whose eye left the scene box (a long move) are
    left out."""
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
                                     "roll_deg", "mae_vs_embree", "keyframe_mae_vs_embree")},
             **{k: mean(k, timed) for k in ("reused_ms", "keyframe_ms")},
             "mae_max": float(max(s["mae"] for s in ss))}
        c["time_ratio"] = c["reused_ms"] / c["keyframe_ms"] if timed else None
        c["mae_reflective"] = c["mae"] / c["reflective"] if c["reflective"] else 0.0
        out.append(c)
    return out


def baselines(cs: list[dict], key: str = "mae_reflective") -> dict[tuple[str, str], float]:
    """(scene, tracer) → the steady state: mean `key` (an MAE) of the reused frames
    1 to 10 path frames after their keyframe (the path kind, step > 0)."""
    groups: dict[tuple[str, str], list[float]] = {}
    for c in cs:
        if c["kind"] == "path" and c["step"] > 0:
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


def verdicts(cs: list[dict], base: dict[tuple[str, str], float], policy: float) -> dict[str, dict]:
    """Per kind that camera_jump limits (turn, move, zoom: out and in together) and
    roll, the first step at which, in some scene (mean over its keyframe cameras):
    `error_at`, the reused frame's MAE over its reflective pixels exceeds CLEARLY ×
    the steady state of its tracer (`base`, baselines of that MAE); `cost_at`, with
    Embree (the sparse tracer: the cluster tracer renders whole frames, never cheaper)
    it takes as long as the keyframe at the target; `policy_at`, more than `policy`
    (the keyframe threshold) of its reflective pixels are recomputed (the next frame
    is a keyframe anyway). `keep`: the largest step below the first
    error or cost failure (reuse is fine up to there; None: not even the smallest);
    `policy_keep`: the largest below the first failure of any of the three;
    `margin`: the largest below the first error failure and the first step at which
    Embree's reused frame costs over MARGIN_RATIO of a keyframe (the recommendation);
    `worst_ratio`: per step, the largest reused / keyframe time over the scenes (None:
    no timed sample);
    `saving_at_keep`: the share of a keyframe's time Embree's reused frame saves there
    (the least over the scenes); `exact`: per step, whether Embree's reused frames
    equal its keyframes (MAE < 0.001, under 0.1 % recomputed)."""
    out = {}
    for kind, names in (("turn", ("turn",)), ("move", ("move",)), ("zoom", ("zoom_out", "zoom_in")),
                        ("roll", ("roll",))):
        mine = [c for c in cs if c["kind"] in names]
        steps = sorted({c["step"] for c in mine})
        at: dict[str, float | None] = {"error_at": None, "cost_at": None, "policy_at": None}
        for step in steps:
            here = [c for c in mine if c["step"] == step]
            fails = {"error_at": any(c["mae_reflective"] > CLEARLY * base.get((c["scene"], c["tracer"]), np.inf)
                                     for c in here),
                     "cost_at": any(c["time_ratio"] is not None and c["time_ratio"] >= 1.0
                                    for c in here if c["tracer"] == "embree"),
                     "policy_at": any(c["recomputed"] > policy for c in here)}
            for k, failed in fails.items():
                if failed and at[k] is None:
                    at[k] = step
        def largest_below(*limits: float | None, steps=steps) -> float | None:
            first = min((s for s in limits if s is not None), default=None)
            below = [s for s in steps if first is None or s < first]
            return max(below) if below else None
        keep = largest_below(at["error_at"], at["cost_at"])
        ratios = [c["time_ratio"] for c in mine if c["step"] == keep and c["tracer"] == "embree"
                  and c["time_ratio"] is not None]
        worst = {x: max((c["time_ratio"] for c in mine if c["step"] == x and c["tracer"] == "embree"
                         and c["time_ratio"] is not None), default=None) for x in steps}
        over = [x for x in steps if worst[x] is not None and worst[x] > MARGIN_RATIO]
        margin = largest_below(at["error_at"], at["cost_at"], min(over, default=None))
        out[kind] = {**at, "keep": keep, "saving_at_keep": 1 - max(ratios) if ratios else None, "margin": margin,
                     "worst_ratio": worst,
                     "policy_keep": largest_below(at["error_at"], at["cost_at"], at["policy_at"]), "tested": steps,
                     "exact": {x: bool(em) and all(c["mae"] < 1e-3 and c["recomputed"] < 1e-3 for c in em)
                               for x in steps for em in [[c for c in mine
                                                          if c["step"] == x and c["tracer"] == "embree"]]}}
    return out


# --- report ---------------------------------------------------------------------------------

def _fmt(c: dict | None, key: str, fmt: str) -> str:
    return "—" if c is None or c.get(key) is None else format(c[key], fmt)


def summary_table(cs: list[dict], scenes: list[str], tracers: list[str], base: dict) -> str:
    """One row per kind and step; per tracer (cells: one per scene, ' / ' between) the
    reused frame's MAE over the whole frame, over its reflective pixels (× that MAE's
    steady state, `base`), its recomputed %, and reused / keyframe time."""
    idx = {(c["scene"], c["tracer"], c["kind"], c["step"]): c for c in cs}
    head = ["kind", "step", "measured"]
    for t in tracers:
        head += [f"{t}: MAE", "MAE reflective px (× steady)", "recomputed %", "reused / keyframe time"]
    rows = []
    for kind in KINDS:
        for step in sorted({c["step"] for c in cs if c["kind"] == kind}):
            same = [c for c in cs if c["kind"] == kind and c["step"] == step]
            measured = (f"{np.mean([c['turn_deg'] for c in same]):.1f}°, {np.mean([c['move'] for c in same]):.3f}, "
                        f"×{np.mean([c['zoom'] for c in same]):.3f}, "
                        f"{np.mean([abs(c['roll_deg']) for c in same]):.0f}°" if kind == "path" else "")
            row = [kind, UNITS[kind].format(step), measured]
            for t in tracers:
                cc = [(s, idx.get((s, t, kind, step))) for s in scenes]
                row.append(" / ".join(_fmt(c, "mae", ".2f") for _, c in cc))
                row.append(" / ".join(f"{c['mae_reflective']:.2f} ({c['mae_reflective'] / base[(s, t)]:.1f}×)"
                                      if c and base.get((s, t)) else _fmt(c, "mae_reflective", ".2f")
                                      for s, c in cc))
                row.append(" / ".join(_fmt(c, "recomputed", ".0%").rstrip("%") for _, c in cc))
                row.append(" / ".join(_fmt(c, "time_ratio", ".2f") for _, c in cc))
            rows.append(row)
    return md_table(head, rows)


def detail_table(cs: list[dict]) -> str:
    """Every cell: times in ms, the recomputed share split, the cluster tracer against Embree."""
    order = {k: i for i, k in enumerate(KINDS)}
    rows = [[c["scene"], c["tracer"], c["kind"], UNITS[c["kind"]].format(c["step"]), c["n"], f"{c['mae']:.3f}",
             f"{c['mae_max']:.3f}", f"{c['mae_reflective']:.2f}",
             f"{100 * c['recomputed']:.1f} ({100 * c['disoccluded']:.1f} + {100 * c['unreliable']:.1f})",
             f"{100 * c['reflective']:.0f}", c.get("n_timed", c["n"]), _fmt(c, "reused_ms", ".0f"),
             _fmt(c, "keyframe_ms", ".0f"), _fmt(c, "time_ratio", ".2f"), _fmt(c, "mae_vs_embree", ".3f"),
             _fmt(c, "keyframe_mae_vs_embree", ".3f")]
            for c in sorted(cs, key=lambda c: (c["scene"], c["tracer"], order[c["kind"]], c["step"]))]
    return md_table(["scene", "tracer", "kind", "step", "keyframe cameras", "MAE mean", "MAE max", "MAE reflective px",
                     "recomputed % (disoccluded + unreliable)", "reflective %", "timed", "reused ms", "keyframe ms",
                     "reused / keyframe", "MAE vs Embree's keyframe", "keyframe's MAE vs Embree's"], rows)


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


def reading(vd: dict, policy: float, floor: dict[str, float]) -> list[str]:
    """The closing reading: where error or cost rise, what a roll does, the thresholds
    (`floor`: the fly-throughs' largest steps, `path_floor`)."""
    from service.stream import JUMP_MOVE, JUMP_TURN_DEG, JUMP_ZOOM

    current = {"turn": JUMP_TURN_DEG, "move": JUMP_MOVE, "zoom": JUMP_ZOOM}
    pct = f"{100 * policy:.0f} %"
    lines = ["## Reading", "",
             f"Criteria, each failing when it fails in some scene (mean over its keyframe cameras): (a) error: "
             f"the reused frame's MAE over its reflective pixels exceeds {CLEARLY:g}× its tracer's steady state "
             "(the reused frames 1-10 path frames after their keyframe, above); (b) cost: with Embree (the "
             "sparse tracer) the reused frame takes as long as a keyframe at the target — the cluster tracer "
             "renders the whole frame whenever it recomputes a pixel, so its reused frames cost about what its "
             "keyframes cost at every step and only its error counts. A threshold fits the data between the last "
             "tested step that passes and the first that fails. For information, (c): more than "
             f"{pct} of the reflective pixels recomputed (ReuseSettings.keyframe_threshold), where the keyframe "
             "policy makes the *next* frame a keyframe anyway. Past (c) a keyframe forced at a single jump "
             "followed by slow motion saves a little (the reused jump frame costs more than an ordinary reused "
             "frame, and the policy's keyframe follows it), while on a camera moving that fast every frame, "
             "forcing keyframes costs more (a keyframe every frame, against the policy's reused and keyframes in "
             "turn); so (c) bounds nothing either way. Where the reused jump frame costs nearly a keyframe, "
             "though, the single-jump saving is about an ordinary reused frame, so the recommended thresholds "
             f"keep a margin: the largest step passing (a) at which Embree's reused frame costs at most "
             f"{MARGIN_RATIO:g} of a keyframe in every scene, unless that step would fire on bench.temporal's "
             "fly-throughs (their largest step between frames: "
             f"{floor['turn']:.2f}°, move {floor['move']:.4f}, zoom ×{floor['zoom']:.4f}; paths of "
             f"{', '.join(map(str, PATH_LENGTHS))} frames), where the stream would then stop reusing as "
             "bench.temporal measures: then the smallest tested step above them that passes (a) and (b) and at "
             f"which Embree's reused frame costs at most {MARGIN_RATIO:g} of a keyframe, or none.", ""]
    rows, say = [], []
    for kind, v in vd.items():
        fmt = UNITS["zoom_out"] if kind == "zoom" else UNITS[kind]

        def f(x, fmt=fmt) -> str:
            return "—" if x is None else fmt.format(x)
        cur = current.get(kind)
        fail = min((s for s in (v["error_at"], v["cost_at"]) if s is not None), default=None)
        if cur is None:
            verdict = "— (none)"
        else:
            lo = recommended(v, floor[kind])
            word = ("too loose (lets steps through where the reuse fails)" if fail is not None and cur >= fail
                    else "stricter than the data need (forces keyframes where the reuse is cheap and as good)"
                    if lo is not None and cur < lo else "holds")
            verdict = (f"{cur:g}: {word}; data: ≥ {f(lo)}"
                       + (f", < {f(fail)}" if fail is not None else ", no tested step fails"))
        rows.append([kind, f(v["error_at"]), f(v["cost_at"]), f(v["policy_at"]), f(v["keep"]),
                     f(recommended(v, floor[kind]) if kind in THRESHOLDS else v.get("margin")), verdict])
        if kind in THRESHOLDS:
            lim = (f"{v['keep']:g}" + (" or more" if fail is None else "") if v["keep"] is not None
                   else f"below {f(min(v['tested']))}")
            pick = recommended(v, floor[kind])
            above = [x for x in v["tested"] if x > floor[kind] and (fail is None or x < fail)]
            rec = (f"{pick:g}" if pick is not None
                   else f"none (between the fly-throughs' {f(floor[kind])} and the first failing step {f(fail)} "
                   + ("no tested step costs at most the margin: "
                      + ", ".join(f"{f(x)}: {_fmt(v['worst_ratio'], x, '.2f')} of a keyframe" for x in above)
                      if above else "nothing is tested") + ")")
            if pick is not None and pick != v.get("margin"):
                rec += (f" (the margin step {f(v.get('margin'))} would fire on the fly-throughs, whose frames step "
                        f"up to {f(floor[kind])}; {f(pick)} is the smallest tested step above them within the "
                        "margin)")
            saving = (f" (there Embree's reused frame saves {v['saving_at_keep']:.0%} of a keyframe's time)"
                      if v.get("saving_at_keep") is not None else "")
            say.append(f"- {kind}: error and cost pass up to {f(v['keep'])}{saving}"
                       + (f" and fail from {f(fail)}" if fail is not None else " (every tested step)")
                       + f"; recomputed > {pct} from {f(v['policy_at'])}. The data allow {THRESHOLDS[kind]} up to "
                       + f"{lim}; recommended (margin: Embree's reused frame at most {MARGIN_RATIO:g} of a keyframe) "
                       + f"{THRESHOLDS[kind]} = {rec}; now " + verdict + ".")
        elif fail is None:
            exact = [x for x in v["tested"] if x in (90.0, 180.0) and v.get("exact", {}).get(x)]
            say.append(f"- roll: error and cost pass at every tested roll (up to {f(max(v['tested']))})"
                       + (f"; a roll of {' or '.join(map(f, exact))} maps a square frame's pixels onto pixels, "
                          "so there Embree's reuse is exact (MAE < 0.001) and recomputes almost nothing (< 0.1 %)"
                          if exact else "")
                       + (f"; recomputed > {pct} from {f(v['policy_at'])} (the image corners)"
                          if v["policy_at"] is not None else "") + ": no roll threshold is needed.")
        else:
            say.append(f"- roll: from {f(fail)} the reuse fails (error or cost); a roll threshold would catch "
                       "it, but the fly-through paths' look-at cameras spin that much near the vertical "
                       "(service.stream), so it would fire on them.")
    lines += [md_table(["kind", f"(a) MAE > {CLEARLY:g}× steady from", "(b) Embree reused ≥ keyframe time from",
                        f"(c) recomputed > {pct} from", "largest step passing (a), (b)",
                        f"recommended (reused ≤ {MARGIN_RATIO:g} keyframe)", "current threshold"],
                       rows), "", *say, ""]
    return lines


def write_report(out: Path, args: argparse.Namespace, info: dict, data: dict, seconds: float) -> None:
    samples = data["samples"]
    cs = cells(samples)
    base = baselines(cs)
    policy = ReuseSettings().keyframe_threshold
    vd = verdicts(cs, base, policy)
    scenes = list(dict.fromkeys(s["scene"] for s in samples))
    tracers = list(dict.fromkeys(s["tracer"] for s in samples))
    tri = ", ".join(f"{s} {n:,}" for s, n in data["triangles"].items())
    n_keys = len({(s["scene"], s["path"], s["frame"]) for s in samples})
    facts = [f"Scenes (triangles): {tri}; {args.res}²; tracers {', '.join(tracers)}.",
             f"{n_keys} keyframe cameras: frames {', '.join(map(str, data['frames']))} of the "
             f"{args.frames}-frame fly-through paths {', '.join(map(str, args.seeds))} per scene; per target "
             "and tracer a keyframe at the start, the reused frame at the target, a keyframe at the target "
             "(the reference: full tracing by the same tracer), on every other target the keyframe at the "
             "target first; the stream's ReuseSettings (no timing syncs, no search statistics); times: wall "
             "time of each `next_frame` call, which returns the read-back colour.",
             f"Views under {100 * MIN_REFLECTIVE:g} % reflective are left out of the time ratios (both frames "
             f"cost next to nothing there): {sum(untimed(samples).values())} samples"
             + (f" ({', '.join(f'{k} × {n}' for k, n in untimed(samples).items())})" if untimed(samples) else "")
             + ".",
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
    lines += ["## Steady state", "",
              "The reused frame 1-10 frames along the path after a keyframe camera (the path kind below, "
              "steps 1, 5, 10; mean MAE, 0-255, over the whole frame and over its reflective pixels) — what a "
              "stream's reused frames err on the benchmarked paths:", "",
              md_table(["scene", "tracer", "steady MAE", "steady MAE reflective px"],
                       [[s, t, f"{base_all[(s, t)]:.3f}", f"{v:.3f}"] for (s, t), v in base.items()]), ""]
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
              "(bench.temporal's) and over the target's reflective pixels (the frames differ only there; the "
              "whole frame's MAE falls where a step turns the view away from reflectors), × its steady state; "
              "recomputed: share of the reflective pixels "
              "traced in the reused frame; time: the reused frame's over the keyframe's at the target "
              f"(views under {100 * MIN_REFLECTIVE:g} % reflective left out). "
              "'measured' (path steps): the mean turn, move, zoom and roll of the path's step.", "",
              summary_table(cs, scenes, tracers, base), "", "![MAE and time against the step](" +
              f"{out.name}_mae.png)", ""]
    lines += ["## Every cell", "", detail_table(cs), ""]
    lines += reading(vd, policy, path_floor(scenes))
    if data.get("notes"):
        lines += data["notes"]
    write_text(out.with_suffix(".md"), "\n".join(lines))


def plot(cs: list[dict], base: dict, path: Path) -> None:
    """MAE over the reflective pixels (top) and reused / keyframe time (bottom) against
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
            pts = sorted((c["step"], c["mae_reflective"], np.nan if c["time_ratio"] is None else c["time_ratio"])
                         for c in cs
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
    axes[0, 0].set_ylabel("MAE on reflective pixels (0-255)")
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
    ap.add_argument("--scenes", nargs="+", default=["living_room", "bathroom"])
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--tracers", nargs="+", default=["embree", "clusters"], choices=["embree", "clusters"])
    ap.add_argument("--seeds", type=int, nargs="+", default=list(PATH_SEEDS), help="fly-through path seeds")
    ap.add_argument("--frames", type=int, default=THESIS_PATH_FRAMES, help="frames of each path (its speed)")
    ap.add_argument("--per-path", type=int, default=3, help="keyframe cameras per path")
    ap.add_argument("--turns", type=float, nargs="*", default=list(TURNS), help="degrees")
    ap.add_argument("--moves", type=float, nargs="*", default=list(MOVES), help="of the eye's distance to its target")
    ap.add_argument("--zooms", type=float, nargs="*", default=list(ZOOMS), help="factors on tan(fov/2), out and in")
    ap.add_argument("--rolls", type=float, nargs="*", default=list(ROLLS), help="degrees")
    ap.add_argument("--path-steps", type=int, nargs="*", default=list(PATH_STEPS), help="frames along the path")
    ap.add_argument("--out", default=str(RESULTS_DIR / "stream_jumps"))
    ap.add_argument("--no-progress", action="store_true")
    ap.add_argument("--report-only", action="store_true", help="rewrite the .md (and plot) from the existing .json")
    ap.add_argument("--append", action="store_true",
                    help="add these samples to the existing .json's (e.g. larger steps measured later, from the "
                         "same keyframe cameras; a sample measured again replaces its row)")
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

"""What this host charges for a compute dispatch's building blocks, against its Embree rays.

Issue 17's 2048² cell (cluster reflections ≤ 1/4 of Embree's trace time) held on
one session's host and not on the next ones (bench/results/reflections.md, speed
directions): the hosts differ, and not by one factor, since the clustering's
passes (16×16 work groups over the supersampled G-buffer, several barriers, one
atomic or more per sample) slowed more than Embree. This benchmark puts a number on
each host: over a 4096² grid (the 2048² output's 2×2 samples) in 16×16 work groups
(gl_passes/shaders/cost_probe.comp), the time of an empty dispatch, of each
work-group barrier (the slope over 0, 1, 2, 4 barriers) and of one shared-memory and
one contended storage-buffer atomicAdd per invocation; beside them, Embree's time
per closest-hit ray (reference.raycast, rays from the living room's centre in
random directions). Each GL cost is also given in Embree rays (its time per
invocation over Embree's time per ray), which does not depend on the host's
overall speed.

One row per host (CPU model, kernel, GL renderer): a run replaces its host's row and
keeps the others. Run `python -m bench.host_costs`; results go to
bench/results/host_costs.*.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from bench.common import (
    RESULTS_DIR,
    git_revision,
    load_named_scene,
    machine_info,
    md_table,
    time_side_by_side,
    write_json,
    write_text,
)
from gl_passes.context import GLContext, create_gl_context
from gl_passes.shaders import compute_program
from gl_passes.uniforms import set_uniform
from reference.raycast import RayCaster

GRID = 4096  # invocations per side: 2048² output pixels at 2×2 samples
GROUP = 16  # the clustering's work-group side
BARRIER_COUNTS = (0, 1, 2, 4)
ATOMICS = {"shared": 1, "global": 2}  # cost_probe.comp's ATOMIC
SINK_BINDING = 0


def host_key(info: dict) -> str:
    return f"{info.get('cpu')} | {info.get('system')} | {info.get('gl_renderer')}"


def barrier_slope(counts: tuple[int, ...] | list[int], ms: list[float]) -> tuple[float, float]:
    """Least-squares line ms = a + b · barriers: (a, b), b in ms per barrier."""
    b, a = np.polyfit(np.asarray(counts, np.float64), np.asarray(ms, np.float64), 1)
    return float(a), float(b)


def merge_rows(rows: list[dict], row: dict) -> list[dict]:
    """rows with `row` in place of any row of the same host (else appended)."""
    return [r for r in rows if r["host"] != row["host"]] + [row]


def gl_costs(gl: GLContext, repeat: int) -> dict:
    """Median milliseconds of each probe over the grid, interleaved (time_side_by_side)."""
    sink = gl.ctx.buffer(reserve=16)
    probes = {}
    variants = [(f"barriers_{n}", n, 0) for n in BARRIER_COUNTS] + [(f"atomic_{k}", 0, a) for k, a in ATOMICS.items()]
    for name, barriers, atomic in variants:
        prog = compute_program(gl, "cost_probe.comp", {"BARRIERS": str(barriers), "ATOMIC": str(atomic),
                                                       "SINK_BINDING": str(SINK_BINDING)})
        set_uniform(prog, "u_never", 0xFFFFFFFF)

        def run(prog=prog) -> None:
            sink.bind_to_storage_buffer(SINK_BINDING)
            prog.run(GRID // GROUP, GRID // GROUP, 1)
        probes[name] = run
    timings = time_side_by_side(probes, repeat=repeat, warmup=1, sync=gl.ctx.finish)
    sink.release()
    return {name: t.median_ms for name, t in timings.items()}


def embree_ns_per_ray(n_rays: int, repeat: int, seed: int = 0) -> float:
    """Median nanoseconds per closest-hit ray (living room, rays from its centre)."""
    scene = load_named_scene("living_room")
    caster = RayCaster(scene)
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n_rays, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    lo, hi = (np.asarray(b, np.float64) for b in scene.bounds)
    o = np.broadcast_to((lo + hi) / 2, d.shape)
    caster.intersect(o[:1024], d[:1024])  # warm-up
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        caster.intersect(o, d)
        times.append(time.perf_counter() - t0)
    return float(np.median(times)) * 1e9 / n_rays


def host_row(info: dict, ms: dict, ray_ns: float) -> dict:
    n = GRID * GRID
    _, per_barrier = barrier_slope(BARRIER_COUNTS, [ms[f"barriers_{k}"] for k in BARRIER_COUNTS])
    costs_ns = {"dispatch": ms["barriers_0"] * 1e6 / n, "barrier": per_barrier * 1e6 / n,
                **{f"{k}_atomic": (ms[f"atomic_{k}"] - ms["barriers_0"]) * 1e6 / n for k in ATOMICS}}
    return {"host": host_key(info), "revision": git_revision(), "date": time.strftime("%Y-%m-%d"),
            "cpu": info.get("cpu"), "system": info.get("system"), "cpus_usable": info.get("cpus_usable"),
            "gl_renderer": info.get("gl_renderer"), "grid": GRID, "probe_ms": ms,
            "ns_per_invocation": costs_ns, "embree_ns_per_ray": ray_ns,
            "in_embree_rays": {k: v / ray_ns for k, v in costs_ns.items()}}


def write_report(out: Path, rows: list[dict]) -> None:
    table = md_table(
        ["host (CPU · kernel · GL)", "measured", "empty dispatch", "per barrier", "shared atomic",
         "contended atomic", "Embree ns / ray", "barrier / shared atomic / contended, in Embree rays"],
        [[f"{r['cpu']} · {r['system']} · {r['gl_renderer']} ({r['cpus_usable']} CPUs)", f"{r['date']}, {r['revision']}",
          f"{r['probe_ms']['barriers_0']:.0f} ms", f"{r['ns_per_invocation']['barrier'] * GRID * GRID / 1e6:.0f} ms",
          f"{r['ns_per_invocation']['shared_atomic']:.2f} ns", f"{r['ns_per_invocation']['global_atomic']:.2f} ns",
          f"{r['embree_ns_per_ray']:.0f}",
          " / ".join(f"{r['in_embree_rays'][k]:.4f}" for k in ("barrier", "shared_atomic", "global_atomic"))]
         for r in rows])
    md = ["# Host costs: compute-dispatch building blocks against Embree rays (issue 17)", "",
          "`python -m bench.host_costs` (module docstring). Over a 4096² grid in 16×16 work groups "
          "(gl_passes/shaders/cost_probe.comp), medians of interleaved runs: an empty dispatch; each "
          "work-group barrier (slope over 0, 1, 2, 4 barriers, for the whole grid); one shared-memory and one "
          "contended storage-buffer atomicAdd per invocation (ns per invocation). Embree: median ns per "
          "closest-hit ray, living room, rays from its centre. The last column puts the three GL costs per "
          "invocation in Embree rays, which does not depend on the host's overall speed. The clustering's and "
          "the cluster cameras' passes are built of these blocks (bench/results/reflections.md, speed "
          "directions: on llvmpipe they now take runs of samples per invocation, with few atomics and "
          "barriers); a rerun on another host adds its row, to compare where hosts differ.", "", table, ""]
    write_text(out.with_suffix(".md"), "\n".join(md))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--rays", type=int, default=1 << 21)
    ap.add_argument("--out", default=str(RESULTS_DIR / "host_costs"))
    ap.add_argument("--report-only", action="store_true", help="rewrite the .md from the existing .json")
    args = ap.parse_args(argv)
    out = Path(args.out)
    path = out.with_suffix(".json")
    rows = json.loads(path.read_text())["hosts"] if path.exists() else []
    if not args.report_only:
        gl = create_gl_context()
        info = machine_info(gl)
        row = host_row(info, gl_costs(gl, args.repeat), embree_ns_per_ray(args.rays, args.repeat))
        rows = merge_rows(rows, row)
        write_json(path, {"hosts": rows})
        print(json.dumps(row, indent=2))
    write_report(out, rows)


if __name__ == "__main__":
    main()

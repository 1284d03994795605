"""The service under load on loopback (issue 15, item 8): a real ``depthview serve`` process,
real HTTP and WebSocket clients.

* Frames: 1, 4 and 16 concurrent clients, each sending ``POST /scenes/{id}/frames`` (a
  512² PNG of a built-in scene, the camera orbiting a step per request) back to back for
  a fixed time: p50/p99 latency (request sent → whole PNG received) and throughput (frames
  per second), with 1 render worker process and with N (``DEPTHVIEW_WORKERS``).
* Stream: one ``/scenes/{id}/stream`` client sending camera messages at a mouse's rate
  (30 Hz) along a slow orbit, reflections by the cluster method (thesis Ch. 4): frames per
  second and input-to-frame latency (camera message sent → the frame answering it
  received), with the stream's reflection reuse (Ch. 5) and with its full-trace baseline
  (``DEPTHVIEW_STREAM_REFLECTION_MODE=full``: every reflective pixel traced every frame
  by the same tracer).

The clients run in this process and share the machine with the server: on loopback the
measurement includes the client's own CPU time, as a browser's would on one machine.

    python -m bench.service_load [--scene cornell] [--res 512] [--clients 1 4 16] [--workers 1 2]
                                 [--seconds 20] [--stream-scene mirror] [--stream-res 512 384]
                                 [--stream-seconds 20] [--smoke] [--out bench/results/service]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import httpx

from bench.common import RESULTS_DIR, machine_info, md_table, progress, report_head, span, write_json, write_text
from scenes.builtin import make_builtin
from scenes.camera import look_at_scene
from service.config import Settings

ROOT = Path(__file__).resolve().parents[1]
#: Camera messages per second on the stream (a mouse drag sends about one per display frame).
MESSAGE_HZ = 30.0
#: The stream runs: (reflections, DEPTHVIEW_STREAM_REFLECTION_MODE, label).
STREAMS = (("none", "reuse", "no reflections"), ("cluster", "reuse", "cluster, reuse"),
           ("cluster", "full", "cluster, full trace"))
#: Frames: the camera orbits this many degrees per request.
FRAME_STEP_DEG = 3.0
#: Stream: the camera sways in front of the scene (azimuth 0 faces the built-in mirror):
#: ±SWAY_DEG over SWAY_PERIOD_S (about 10°/s on average, a slow drag).
SWAY_DEG, SWAY_PERIOD_S = 30.0, 12.0
#: Orbit distances (× the scene's bounding-box diagonal) of the frames and the stream.
FRAME_DISTANCE, STREAM_DISTANCE = 1.1, 0.45


# --- the server ------------------------------------------------------------------------------
def free_ports(n: int) -> list[int]:
    """n distinct free loopback ports: their sockets are held open until all n are
    picked (one at a time, a port closed before the next pick can be handed out again,
    and two servers then share one port: the second fails to start while the first
    answers for both)."""
    with contextlib.ExitStack() as stack:
        socks = [stack.enter_context(socket.socket()) for _ in range(n)]
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]


@contextlib.contextmanager
def servers(configs: Sequence[tuple[int, str]], data_dir: Path, log: Path) -> Iterator[dict[tuple[int, str], str]]:
    """`depthview serve` processes, one per (workers, stream_reflection_mode), each with that
    many render worker processes on a free loopback port, started together: their base URLs
    once every one answers /readyz. Stopped (SIGTERM) on exit."""
    procs: dict[tuple[int, str], tuple[subprocess.Popen, str]] = {}
    try:
        for (workers, mode), port in zip(configs, free_ports(len(configs)), strict=True):
            environ = {**os.environ, "DEPTHVIEW_WORKERS": str(workers), "DEPTHVIEW_DATA_DIR": str(data_dir),
                       "DEPTHVIEW_STREAM_REFLECTION_MODE": mode}
            with open(log, "ab") as out:
                procs[(workers, mode)] = (subprocess.Popen(
                    [sys.executable, "-m", "service", "serve", "--host", "127.0.0.1", "--port", str(port),
                     "--log-level", "warning"], cwd=ROOT, env=environ, stdout=out, stderr=subprocess.STDOUT),
                    f"http://127.0.0.1:{port}")
        deadline = time.monotonic() + 180
        for proc, base in procs.values():
            while not _ready(base):
                if proc.poll() is not None:
                    raise RuntimeError(f"the server exited ({proc.returncode}); its log: {log.read_text()[-3000:]}")
                if time.monotonic() > deadline:
                    raise RuntimeError(f"the server was not ready within 180 s; its log: {log.read_text()[-3000:]}")
                time.sleep(0.2)
        yield {key: base for key, (_, base) in procs.items()}
    finally:
        for proc, _ in procs.values():
            proc.terminate()
        for proc, _ in procs.values():
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def _ready(base: str) -> bool:
    try:
        return httpx.get(f"{base}/readyz", timeout=5).status_code == 200
    except httpx.TransportError:
        return False


def scene_id(base: str, name: str) -> str:
    r = httpx.post(f"{base}/scenes", json={"builtin": name}, timeout=120)
    r.raise_for_status()
    return r.json()["id"]


def orbit_camera(name: str, azimuth: float, distance: float = FRAME_DISTANCE) -> dict[str, Any]:
    """A camera looking at the scene's centre from `azimuth` degrees (elevation 20°), as JSON."""
    cam = look_at_scene(make_builtin(name).bounds, azimuth=azimuth, elevation=20.0, distance=distance, fov=50.0)
    return {"eye": [float(x) for x in cam.eye], "target": [float(x) for x in cam.target], "fov": 50.0}


def sway_camera(name: str, t: float) -> dict[str, Any]:
    """The stream's camera `t` seconds into the run."""
    return orbit_camera(name, SWAY_DEG * math.sin(2 * math.pi * t / SWAY_PERIOD_S), STREAM_DISTANCE)


#: Service-side counters read from /metrics around each frames cell: (metric, label) → key.
STEPS = {("depthview_step_seconds", 'step="job"'): "job", ("depthview_step_seconds", 'step="encode"'): "encode",
         ("depthview_step_seconds", 'step="scene_load"'): "scene_load",
         ("depthview_queue_wait_seconds", ""): "queue_wait", ("depthview_job_seconds", ""): "worker"}


def scrape(base: str) -> dict[str, float]:
    """Sums and counts of the STEPS counters (seconds) from the server's /metrics."""
    text = httpx.get(f"{base}/metrics", timeout=30).text
    out: dict[str, float] = {}
    for line in text.splitlines():
        for (name, label), key in STEPS.items():
            for part in ("sum", "count"):
                head = f"{name}_{part}" + (f"{{{label}}}" if label else "")
                if line.startswith(head + " "):
                    out[f"{key}_{part}"] = float(line.split()[-1])
    return out


def step_means(before: dict[str, float], after: dict[str, float]) -> dict[str, float | None]:
    """Mean milliseconds per job of each step between two scrapes."""
    out: dict[str, float | None] = {}
    for key in STEPS.values():
        n = after.get(f"{key}_count", 0) - before.get(f"{key}_count", 0)
        if key == "queue_wait":  # counted per job
            n = after.get("worker_count", 0) - before.get("worker_count", 0)
        out[f"{key}_ms"] = (after.get(f"{key}_sum", 0) - before.get(f"{key}_sum", 0)) / n * 1e3 if n else None
    return out


# --- statistics --------------------------------------------------------------------------------
def percentile(values: Sequence[float], q: float) -> float | None:
    """The q-th percentile (nearest rank) of `values`; None when there are none."""
    if not values:
        return None
    ordered = sorted(values)
    return ordered[max(0, math.ceil(q / 100 * len(ordered)) - 1)]


def latency_summary(ms: Sequence[float]) -> dict[str, Any]:
    return {"n": len(ms), "p50_ms": percentile(ms, 50), "p99_ms": percentile(ms, 99),
            "mean_ms": statistics.fmean(ms) if ms else None, "max_ms": max(ms) if ms else None}


# --- frames under load --------------------------------------------------------------------------
async def frame_load(base: str, sid: str, scene: str, res: int, clients: int, seconds: float,
                     first_camera: int = 0) -> dict[str, Any]:
    """`clients` concurrent clients, each on its own connection, sending frame requests back
    to back for `seconds` (requests in flight at the end are finished and counted): the raw
    latencies (ms), statuses and wall seconds."""
    cameras = [orbit_camera(scene, k * FRAME_STEP_DEG) for k in range(int(360 / FRAME_STEP_DEG))]
    latencies: list[float] = []
    statuses: Counter[int] = Counter()
    t0 = time.perf_counter()
    end = t0 + seconds
    last = [t0]

    async def client(k: int) -> None:
        async with httpx.AsyncClient(base_url=base, timeout=300, limits=httpx.Limits(max_connections=1)) as c:
            n = first_camera + k * len(cameras) // max(clients, 1)
            while time.perf_counter() < end:
                body = {"camera": cameras[n % len(cameras)], "width": res, "height": res}
                n += 1
                t = time.perf_counter()
                r = await c.post(f"/scenes/{sid}/frames", json=body)
                done = time.perf_counter()
                statuses[r.status_code] += 1
                if r.status_code == 200:
                    if r.content[:8] != b"\x89PNG\r\n\x1a\n":
                        raise RuntimeError("a 200 frame is not a PNG")
                    latencies.append((done - t) * 1e3)
                last[0] = max(last[0], done)

    await asyncio.gather(*(client(k) for k in range(clients)))
    return {"latencies_ms": latencies, "statuses": statuses, "seconds": last[0] - t0}


def frames_cell(workers: int, clients: int, rounds: list[dict[str, Any]]) -> dict[str, Any]:
    """One table cell from its rounds (frame_load results with the service's counters)."""
    lat = [x for r in rounds for x in r["latencies_ms"]]
    statuses: Counter[int] = sum((Counter(r["statuses"]) for r in rounds), Counter())
    wall = sum(r["seconds"] for r in rounds)
    before = {k: sum(r["before"].get(k, 0.0) for r in rounds) for k in rounds[0]["before"]}
    after = {k: sum(r["after"].get(k, 0.0) for r in rounds) for k in rounds[0]["after"]}
    return {"workers": workers, "clients": clients, "rounds": len(rounds), "seconds": wall, "ok": statuses[200],
            "statuses": dict(statuses), "throughput_fps": statuses[200] / wall,
            "throughput_fps_rounds": [Counter(r["statuses"])[200] / r["seconds"] for r in rounds],
            **latency_summary(lat), "service": step_means(before, after)}


# --- the stream -------------------------------------------------------------------------------
async def stream_run(base: str, sid: str, scene: str, size: tuple[int, int], reflections: str,
                     seconds: float) -> dict[str, Any]:
    """One stream client: camera messages at MESSAGE_HZ along an orbit for `seconds`, after
    a first frame (the keyframe with the scene's upload) that is not counted."""
    import websockets

    url = base.replace("http://", "ws://", 1) + f"/scenes/{sid}/stream"
    sent: dict[int, float] = {}
    frames: list[dict[str, Any]] = []

    def message(msg_id: int, camera: dict[str, Any]) -> str:
        return json.dumps({"id": msg_id, "camera": camera, "width": size[0],
                           "height": size[1], "effects": {"reflections": reflections}})

    async with websockets.connect(url, max_size=None) as ws:
        hello = json.loads(await ws.recv())
        if hello.get("type") != "hello":
            raise RuntimeError(f"no hello: {hello}")
        await ws.send(message(0, sway_camera(scene, 0.0)))
        while True:  # the first frame: not counted
            stats = json.loads(await ws.recv())
            if stats.get("type") == "error":
                raise RuntimeError(f"stream error: {stats}")
            await ws.recv()
            if stats["id"] == 0 and not stats["rest"]:
                break
        t0 = time.perf_counter()

        async def send() -> None:
            k = 1
            while (now := time.perf_counter()) < t0 + seconds:
                sent[k] = now
                await ws.send(message(k, sway_camera(scene, now - t0)))
                k += 1
                await asyncio.sleep(max(0.0, t0 + k / MESSAGE_HZ - time.perf_counter()))

        async def receive() -> None:
            while True:
                stats = json.loads(await ws.recv())
                if stats.get("type") == "error":
                    raise RuntimeError(f"stream error: {stats}")
                image = await ws.recv()
                arrived = time.perf_counter()
                if not stats["rest"] and stats["id"] in sent:
                    frames.append({**stats, "arrived": arrived - t0, "latency_ms": (arrived - sent[stats["id"]]) * 1e3,
                                   "received_bytes": len(image)})
                if arrived > t0 + seconds and stats["id"] == max(sent):  # the last message is answered
                    return

        sender = asyncio.create_task(send())
        await asyncio.wait_for(receive(), seconds + 600)
        await sender
    return {"seconds": seconds, "messages": len(sent), "frames": frames,
            "in_window": sum(1 for f in frames if f["arrived"] <= seconds)}


def stream_summary(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """One table row from a stream kind's runs (stream_run results)."""
    frames = [f for r in runs for f in r["frames"]]
    seconds = sum(r["seconds"] for r in runs)
    in_window = sum(r["in_window"] for r in runs)

    def median(key: str) -> float | None:
        return statistics.median(f[key] for f in frames) if frames else None

    return {"runs": len(runs), "seconds": seconds, "messages": sum(r["messages"] for r in runs),
            "frames": in_window, "fps": in_window / seconds, "fps_runs": [r["in_window"] / r["seconds"] for r in runs],
            "answered": len(frames), "latency": latency_summary([f["latency_ms"] for f in frames]),
            "render_ms_median": median("render_ms"), "queue_wait_ms_median": median("queue_wait_ms"),
            "reused_ratio_mean": statistics.fmean(f["reused_ratio"] for f in frames) if frames else None,
            "keyframes": sum(1 for f in frames if f["keyframe"]), "superseded": sum(f["superseded"] for f in frames),
            "frame_kib_median": median("received_bytes") / 1024 if frames else None}


# --- the run and its report -----------------------------------------------------------------------
def ms(x: float | None) -> str:
    return "—" if x is None else f"{x:.0f}"


def write_report(out: Path, data: dict[str, Any]) -> None:
    args = SimpleNamespace(**data["args"], cores=data["machine"].get("cpus_usable"))
    cmd = "python -m bench.service_load" + (" --smoke" if args.smoke else "")
    cores = data["machine"].get("cpus_usable")
    facts = [f"Frames: `POST /scenes/{{id}}/frames` of the built-in `{args.scene}` scene at {args.res}² (PNG), the "
             f"camera orbiting {FRAME_STEP_DEG:g}° per request; {', '.join(map(str, args.clients))} concurrent "
             f"clients (one connection each, requests back to back) for {args.seconds:g} s per cell, with "
             f"{' and '.join(map(str, args.workers))} render worker processes (`DEPTHVIEW_WORKERS`), each server "
             f"its own process, all up at once; the cells ran in {args.rounds} interleaved rounds (every cell's "
             "share of a round in turn), so load from other jobs on the machine falls on all of them alike.",
             f"Stream: one `/scenes/{{id}}/stream` client on the built-in `{args.stream_scene}` scene at "
             f"{args.stream_res[0]}×{args.stream_res[1]}, camera messages at {MESSAGE_HZ:g} Hz, the camera swaying "
             f"±{SWAY_DEG:g}° in front of the mirror every {SWAY_PERIOD_S:g} s, for {args.stream_seconds:g} s per "
             f"kind in {args.rounds} interleaved rounds, each a new stream whose first frame (a keyframe) is not "
             "counted; "
             "reflections by the cluster method, with the stream's reuse (Ch. 5) and with its full-trace "
             "baseline (`DEPTHVIEW_STREAM_REFLECTION_MODE=full`), and without reflections for reference.",
             "Server and clients on one machine over loopback (the clients' CPU time counts, as a browser's would).",
             "Load average (1, 5, 15 min) before the run {} and after it {}: other jobs shared the machine when "
             "it is above 0.".format(*(" / ".join(f"{x:.1f}" for x in data[k]) for k in ("loadavg_before",
                                                                                        "loadavg_after"))),
             f"Renderer (from `/readyz`): {data['readyz'].get('renderer')} ({data['readyz'].get('backend')})."]
    lines = report_head("Service under load: frames and the stream", cmd, facts, data["seconds"], data["machine"])
    lines += ["## Frames", "",
              f"Latency: request sent → whole PNG received. Throughput: PNG frames answered per second. This "
              f"machine has {cores} usable cores, so N = {cores} worker processes (one per core) is the most worth "
              "measuring here, and the service process, the clients and the workers all share those cores: the "
              "N-worker rows show how far a second GL context carries on this machine, not how the service scales "
              "on one with more cores or GPUs.", ""]
    rows = []
    for run in data["frames"]:
        errors = {k: v for k, v in run["statuses"].items() if str(k) != "200"}
        sv = run.get("service") or {}
        fps = f"{run['throughput_fps']:.1f} ({span(run['throughput_fps_rounds'], '.1f', '–')})"
        rows.append([run["workers"], run["clients"], run["ok"], fps, ms(run["p50_ms"]), ms(run["p99_ms"]),
                     ms(run["mean_ms"]), ms(sv.get("queue_wait_ms")), ms(sv.get("worker_ms")), ms(sv.get("encode_ms")),
                     ", ".join(f"{k}: {v}" for k, v in errors.items()) or "0"])
    lines += [md_table(["workers", "clients", "frames", "frames/s (rounds)", "p50 ms", "p99 ms", "mean ms",
                        "queue wait ms", "worker ms", "encode ms", "errors"], rows), "",
              "The last three columns are the service's own means per frame (from `/metrics` around each cell): "
              "the job's wait in the render queue, the job on its worker as the service sees it (rendering, and "
              "for worker processes the G-buffer's transfer back), and the PNG encoding in the service process.", ""]
    by = {(r["workers"], r["clients"]): r for r in data["frames"]}
    one = by.get((min(args.workers), min(args.clients)))
    if one and one["ok"]:
        sv = one["service"]
        all_fps = [r["throughput_fps"] for r in data["frames"] if r["ok"]]
        failed = sum(n for r in data["frames"] for k, n in r["statuses"].items() if str(k) != "200")
        lines += [f"Reading: one client alone gets a {args.res}² frame in {ms(one['p50_ms'])} ms (p50), of which the "
                  f"service counts {ms(sv.get('worker_ms'))} ms on the worker and {ms(sv.get('encode_ms'))} ms of PNG "
                  f"encoding. Every cell delivers {span(all_fps, '.1f', '–')} frames/s; "
                  + client_scaling(args, by) + " " + worker_comparison(args, by)
                  + f" {failed or 'No'} request{'s' if failed != 1 else ''} failed"
                  + (f" ({max(args.clients)} clients stay within the queue of {Settings().queue_size})."
                     if not failed else "."), ""]
    lines += ["## Stream", "",
              "Input-to-frame latency: camera message sent → the frame answering it received (superseded messages "
              "get no frame: latest wins). Frames/s: frames received in the window, at-rest PNG re-sends excluded. "
              "Render: the frame's `render_ms` (queue wait excluded: its own column); reused: the mean share of "
              "reflective pixels reused (0 on keyframes).", ""]
    rows = [[s["label"], s["frames"], f"{s['fps']:.2f} ({span(s['fps_runs'], '.2f', '–')})",
             ms(s["latency"]["p50_ms"]), ms(s["latency"]["p99_ms"]),
             ms(s["render_ms_median"]), ms(s["queue_wait_ms_median"]),
             "—" if s["reused_ratio_mean"] is None else f"{100 * s['reused_ratio_mean']:.0f} %",
             f"{s['keyframes']}/{s['answered']}", s["superseded"]] for s in data["stream"]]
    lines += [md_table(["stream", "frames", "frames/s (rounds)", "latency p50 ms", "latency p99 ms",
                        "render ms (median)", "queue wait ms", "reused", "keyframes", "superseded"], rows), ""]
    st = {s["label"]: s for s in data["stream"]}
    if "cluster, reuse" in st and "cluster, full trace" in st and st["cluster, full trace"]["fps"] > 0:
        r, f = st["cluster, reuse"], st["cluster, full trace"]
        slower = r["render_ms_median"] > f["render_ms_median"]
        p99 = [x["latency"]["p99_ms"] / x["render_ms_median"] for x in (r, f)]
        lines += [f"Reuse against the full trace: {r['fps'] / f['fps']:.2f}× the frames per second, median latency "
                  f"{ms(r['latency']['p50_ms'])} ms against {ms(f['latency']['p50_ms'])} ms, median render "
                  f"{ms(r['render_ms_median'])} ms against {ms(f['render_ms_median'])} ms, with "
                  f"{100 * (r['reused_ratio_mean'] or 0):.0f} % of the reflective pixels reused. With 30 camera "
                  f"messages a second, latest wins kept the p99 latency at {p99[0]:.1f} and {p99[1]:.1f} median "
                  f"render times ({r['superseded']} and {f['superseded']} messages superseded). "
                  + ("On this CPU-only machine a reused frame cost more to render than a fully traced one: the "
                     "reuse's own passes (Alg. 9's search, the warp, the reprojection, all on llvmpipe) outweigh the "
                     f"cluster tracing they save on the {args.stream_scene} scene (a few thousand triangles, one "
                     "planar mirror); " if slower else "")
                  + "`python -m bench.temporal` (issue 14) measures the reuse against full tracing pass by pass.", ""]
    if data.get("plot"):
        lines += [f"![frames under load]({data['plot']})", ""]
    write_text(out.with_suffix(".md"), "\n".join(lines))


def client_scaling(args: SimpleNamespace, by: dict[tuple[int, int], dict[str, Any]]) -> str:
    """Whether more clients raised the throughput of the fewest workers or only queued."""
    w, c0, c1 = min(args.workers), min(args.clients), max(args.clients)
    gain = by[(w, c1)]["throughput_fps"] / by[(w, c0)]["throughput_fps"]
    lat = by[(w, c1)]["p50_ms"] / by[(w, c0)]["p50_ms"]
    how = "only queue" if gain < 1.25 else f"raise throughput {gain:.2f}×"
    return (f"with {w} worker{'s' if w > 1 else ''}, {c1} clients against {c0} {how} (throughput {gain:.2f}×, "
            f"median latency {lat:.1f}×).")


def worker_comparison(args: SimpleNamespace, by: dict[tuple[int, int], dict[str, Any]]) -> str:
    """A sentence per client count: does the second worker's throughput range (over the
    rounds) lie apart from the first's?"""
    if len(args.workers) < 2:
        return ""
    lo, hi = min(args.workers), max(args.workers)
    parts = []
    for c in args.clients:
        a, b = by[(lo, c)]["throughput_fps_rounds"], by[(hi, c)]["throughput_fps_rounds"]
        ratio = by[(hi, c)]["throughput_fps"] / by[(lo, c)]["throughput_fps"]
        if min(b) > max(a):
            verdict = "higher, the rounds' ranges apart"
        elif max(b) < min(a):
            verdict = "lower, the rounds' ranges apart"
        else:
            verdict = "within the rounds' spread"
        parts.append(f"{c} client{'s' if c > 1 else ''} {ratio:.2f}× ({verdict})")
    gain = all(p.endswith("(higher, the rounds' ranges apart)") for p in parts)
    return (f"{hi} worker processes against {lo}: {'; '.join(parts)}. {'A' if gain else 'No'} consistent gain from "
            f"the {'extra GL contexts' if hi > 2 else 'second GL context'} on this machine, whose "
            f"{args.cores or '?'} cores the service process, the clients and other jobs (see the load average) share "
            "with the workers.")


def plot(out: Path, runs: list[dict[str, Any]]) -> str | None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.8))
    for w in sorted({r["workers"] for r in runs}):
        rs = [r for r in runs if r["workers"] == w]
        xs = [r["clients"] for r in rs]
        fps = [r["throughput_fps"] for r in rs]
        spread = [[f - min(r["throughput_fps_rounds"]) for f, r in zip(fps, rs, strict=True)],
                  [max(r["throughput_fps_rounds"]) - f for f, r in zip(fps, rs, strict=True)]]
        a.errorbar(xs, fps, yerr=spread, fmt="o-", capsize=4, label=f"{w} worker{'s' if w > 1 else ''} (rounds)")
        b.plot(xs, [r["p50_ms"] or 0 for r in rs], "o-", label=f"p50, {w} worker{'s' if w > 1 else ''}")
        b.plot(xs, [r["p99_ms"] or 0 for r in rs], "s--", label=f"p99, {w} worker{'s' if w > 1 else ''}")
    for ax, title, unit in ((a, "throughput", "frames / s"), (b, "latency", "ms")):
        ax.set_xscale("log", base=2)
        ax.set_xticks(sorted({r["clients"] for r in runs}), [str(c) for c in sorted({r["clients"] for r in runs})])
        ax.set_xlabel("concurrent clients")
        ax.set_ylabel(unit)
        ax.set_title(title)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        ax.set_ylim(bottom=0)
    fig.tight_layout()
    path = out.with_name(out.name + "_frames.png")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path.name


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="cornell")
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--clients", type=int, nargs="+", default=[1, 4, 16])
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--seconds", type=float, default=24.0, help="seconds per frames cell")
    ap.add_argument("--stream-scene", default="mirror")
    ap.add_argument("--stream-res", type=int, nargs=2, default=[512, 384], metavar=("W", "H"))
    ap.add_argument("--stream-seconds", type=float, default=20.0, help="seconds per stream kind")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds the seconds are split into")
    ap.add_argument("--smoke", action="store_true", help="a few seconds at tiny sizes (tests)")
    ap.add_argument("--out", type=Path, default=RESULTS_DIR / "service")
    ap.add_argument("--no-progress", dest="progress", action="store_false")
    ap.add_argument("--report-only", action="store_true", help="rewrite the report and plot from the JSON")
    args = ap.parse_args(argv)
    if args.report_only:
        data = json.loads(args.out.with_suffix(".json").read_text())
        data["plot"] = plot(args.out, data["frames"])
        write_report(args.out, data)
        print(f"rewrote {args.out.with_suffix('.md')}")
        return 0
    if args.smoke:
        args.res, args.clients, args.workers, args.seconds, args.rounds = 32, [1, 2], [1], 1.0, 1
        args.stream_res, args.stream_seconds = [48, 32], 1.0

    t_start = time.perf_counter()
    data: dict[str, Any] = {"args": {k: v for k, v in vars(args).items() if k not in ("out", "progress")},
                            "frames": [], "stream": [], "loadavg_before": os.getloadavg()}
    configs = [(w, "reuse") for w in args.workers] + [(min(args.workers), "full")]
    with tempfile.TemporaryDirectory(prefix="depthview-load-") as tmp, \
            servers(configs, Path(tmp) / "data", Path(tmp) / "server.log") as bases:
        # every server is up at once (idle ones cost nothing), so the cells can be interleaved
        log = Path(tmp) / "server.log"
        data["readyz"] = httpx.get(f"{bases[configs[0]]}/readyz", timeout=30).json()
        sid = scene_id(bases[(min(args.workers), "reuse")], args.scene)
        for workers in args.workers:  # warm-up: every worker loads and uploads the scene
            asyncio.run(frame_load(bases[(workers, "reuse")], sid, args.scene, args.res, 2 * workers,
                                   min(3.0, args.seconds / 2)))
        # Frames: every (clients, workers) cell a round at a time, rounds interleaved, so load
        # from other jobs on the machine falls on all cells alike.
        cells: dict[tuple[int, int], list[dict[str, Any]]] = {}
        order = [(c, w) for c in args.clients for w in args.workers]
        for k in progress(range(args.rounds * len(order)), args.progress, desc="frames"):
            clients, workers = order[k % len(order)]
            base = bases[(workers, "reuse")]
            before = scrape(base)
            run = asyncio.run(frame_load(base, sid, args.scene, args.res, clients, args.seconds / args.rounds,
                                         first_camera=k))
            cells.setdefault((clients, workers), []).append({**run, "before": before, "after": scrape(base)})
        data["frames"] = [frames_cell(w, c, cells[(c, w)]) for w in args.workers for c in args.clients]
        if not any(r["ok"] for r in data["frames"]):
            raise RuntimeError(f"no frame was answered; the server log:\n{log.read_text()[-3000:]}")
        # Stream: the three kinds a round at a time (each run a new stream: a first keyframe, uncounted)
        ssid = scene_id(bases[(min(args.workers), "reuse")], args.stream_scene)
        runs: dict[str, list[dict[str, Any]]] = {}
        for k in progress(range(args.rounds * len(STREAMS)), args.progress, desc="stream"):
            reflections, mode, label = STREAMS[k % len(STREAMS)]
            runs.setdefault(label, []).append(asyncio.run(stream_run(
                bases[(min(args.workers), mode)], ssid, args.stream_scene, tuple(args.stream_res), reflections,
                args.stream_seconds / args.rounds)))
        data["stream"] = [{"label": label, "mode": mode, **stream_summary(runs[label])}
                          for _, mode, label in STREAMS]
    gl = SimpleNamespace(backend=data["readyz"].get("backend"), renderer=data["readyz"].get("renderer"),
                         version=data["readyz"].get("gl_version"), is_software=data["readyz"].get("software"))
    data["machine"] = machine_info(gl)
    data["seconds"] = time.perf_counter() - t_start
    data["loadavg_after"] = os.getloadavg()
    data["plot"] = plot(args.out, data["frames"])
    write_json(args.out.with_suffix(".json"), data)
    write_report(args.out, data)
    print(f"wrote {args.out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

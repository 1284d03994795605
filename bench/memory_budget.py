"""Peak resident memory one render request adds to a warm service, against its memory-budget estimate.

The service refuses a render request whose estimate (`service.budget`: frame_bytes,
set_bytes, reconstruction_bytes, from the per-unit constants in `service.config`) is
over ``max_job_bytes``. This benchmark checks those estimates. For each request kind
(`kinds`: a frame, cluster reflections, a depth-image set, a reconstruction, soft
shadows, and a few variants) a fresh interpreter runs the real app in-process
(`service.app.create_app` under fastapi's TestClient; ``workers=0``, so the render
worker is a thread of that process; default settings otherwise, so the worker keeps
reconstructions and shadow maps up to ``reconstruction_cache_bytes`` as deployed),
sends a small warm-up request of the same kind (GL context, shaders, scene parse and
upload, the kind's long-lived passes are then not counted), then the measured one.
The peak: after ``gc.collect()`` and ``malloc_trim(0)`` (freed heap handed back, so
memory left over from the warm-up cannot hide the request's), "5" is written to
/proc/self/clear_refs (resets VmHWM), VmRSS is read from /proc/self/status, the
request is sent and answered (its body still held) and VmHWM is read: added = VmHWM
− VmRSS before. On llvmpipe GPU memory is host memory, so the RSS includes it. Where
clear_refs is not writable VmHWM starts at the process's peak so far (the warm-up's).

The estimate is the one the route checks, by the same function on the same
validated request model. Each row gives the added peak in MiB and per unit of the
constant it calibrates (bytes per frame pixel, per depth-image pixel, per
reconstruction sample), the estimate and estimate ÷ measured (< 1: the budget
under-counts that request).

Run `python -m bench.memory_budget`; results go to bench/results/memory_budget.*.
"""

from __future__ import annotations

import argparse
import gc
import json
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from bench.common import RESULTS_DIR, git_revision, machine_info, machine_markdown, md_table, write_json, write_text
from scenes.builtin import mirror
from service.worker import trim_heap

MIB = 2**20
CLEAR_REFS = Path("/proc/self/clear_refs")
#: The built-in mirror scene's oblique view (the mirror fills part of the frame), as the reflections tests.
MIRROR_CAMERA = {"eye": list(mirror.VIEW_EYE), "target": list(mirror.VIEW_TARGET)}


@dataclass(frozen=True)
class Kind:
    """One request kind: `body` is measured after `warm` (same route and scene)."""

    key: str  # for --kinds
    name: str
    scene: str
    route: str  # "frames", "depth-images" or "reconstruction"
    body: dict[str, Any]
    warm: dict[str, Any]
    #: The unit of the constant the row calibrates and how many of them the request has.
    unit: str
    units: Callable[[dict[str, Any]], int] = field(repr=False)
    note: str = ""
    #: Settings overrides of the service (e.g. reconstruction_cache_bytes=0: nothing kept).
    settings: dict[str, Any] = field(default_factory=dict)


def _camera(scene: str) -> dict[str, Any]:
    """The soft-shadow tests' whole-scene view of a built-in scene (mirror: the reflections tests')."""
    if scene == "mirror":
        return MIRROR_CAMERA
    from scenes.builtin import make_builtin
    from scenes.camera import look_at_scene

    cam = look_at_scene(make_builtin(scene).bounds)
    return {"eye": [float(x) for x in cam.eye], "target": [float(x) for x in cam.target]}


def _pixels(b: dict[str, Any]) -> int:
    return b["width"] * b["height"]


def _set_pixels(b: dict[str, Any]) -> int:
    return 3 * _pixels(b)  # the Fig. 8 rig's three images


def _samples(b: dict[str, Any]) -> int:
    res = b.get("resolution") or b["effects"]["soft_shadows"]["resolution"]
    return 4 * res * res  # the light's four corners


def kinds() -> list[Kind]:
    """The five calibration requests of service.config's constants and cheap variants."""
    city, mirror = _camera("city"), _camera("mirror")

    def frame(size: int, fmt: str = "exr", **effects: Any) -> dict[str, Any]:
        return {"camera": mirror if effects.get("reflections") else city, "width": size, "height": size,
                "format": fmt, "effects": effects}

    def shadows(size: int, res: int, samples: int, method: str = "non_redundant") -> dict[str, Any]:
        return frame(size, soft_shadows={"samples": samples, "method": method, "resolution": res})

    def dset(size: int, method: str) -> dict[str, Any]:
        return {"method": method, "width": size, "height": size, "format": "exr"}

    def recon(res: int, method: str) -> dict[str, Any]:
        return {"method": method, "reconstruction": "hybrid", "resolution": res}

    recon_note = "4 images (light corners), hybrid, with its GLB"
    unkept = {"reconstruction_cache_bytes": 0}
    # A k = 16 warm-up would leave 1 GiB of kept maps (its light, other images) that the
    # measured request evicts, its own maps then hidden in the freed memory.
    k16_warm = "warm-up at k = 4 (a k = 16 one keeps 1 GiB of maps the request evicts), so the k = 16 pass is made here"
    return [
        Kind("frame_exr", "frame, EXR", "city", "frames", frame(2048), frame(256), "frame px", _pixels),
        Kind("frame_png", "frame, PNG", "city", "frames", frame(2048, "png"), frame(256, "png"), "frame px",
             _pixels),
        Kind("reflections", "cluster reflections", "mirror", "frames", frame(1024, reflections="cluster"),
             frame(128, reflections="cluster"), "frame px", _pixels, "estimate 4 × the frame's: 2×2 supersamples"),
        Kind("set_conventional", "depth images, conventional", "city", "depth-images", dset(1024, "conventional"),
             dset(128, "conventional"), "image px", _set_pixels, "3 images (Fig. 8 rig)"),
        Kind("set_nr", "depth images, non-redundant", "city", "depth-images", dset(1024, "non_redundant"),
             dset(128, "non_redundant"), "image px", _set_pixels, "3 images (Fig. 8 rig)"),
        Kind("recon_conventional", "reconstruction, conventional", "city", "reconstruction",
             recon(1024, "conventional"), recon(128, "conventional"), "sample", _samples, recon_note),
        Kind("recon_nr", "reconstruction, non-redundant", "city", "reconstruction", recon(1024, "non_redundant"),
             recon(128, "non_redundant"), "sample", _samples, recon_note),
        Kind("recon_conventional_unkept", "reconstruction, conventional, nothing kept", "city", "reconstruction",
             recon(1024, "conventional"), recon(128, "conventional"), "sample", _samples,
             recon_note + "; reconstruction_cache_bytes = 0", unkept),
        Kind("shadows_k16", "soft shadows, NR, k = 16", "city", "frames", shadows(512, 1024, 16),
             shadows(64, 64, 4), "sample", _samples, "NR reconstruction of 4 images at 1024²; k² = 256 maps "
             f"(1 GiB), kept where they fit reconstruction_cache_bytes; {k16_warm}"),
        Kind("shadows_k16_unkept", "soft shadows, NR, k = 16, nothing kept", "city", "frames",
             shadows(512, 1024, 16), shadows(64, 64, 4), "sample", _samples,
             "reconstruction_cache_bytes = 0: maps drawn 16 at a time into one atlas, the reconstruction "
             f"released after the frame; {k16_warm}", unkept),
        Kind("shadows_k4", "soft shadows, NR, k = 4", "city", "frames", shadows(512, 1024, 4), shadows(64, 64, 4),
             "sample", _samples, "NR reconstruction of 4 images at 1024²; 16 maps (one atlas)"),
    ]


# --- measuring ----------------------------------------------------------------------------

def status_kib(name: str, pid: int | str = "self") -> int:
    """A `Vm*` field of /proc/<pid>/status in KiB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(name + ":"):
            return int(line.split()[1])
    raise KeyError(name)


def clear_refs_writable() -> bool:
    try:
        CLEAR_REFS.write_text("5")
        return True
    except OSError:
        return False


def settle() -> None:
    """Collect garbage and hand freed heap back to the system (glibc malloc_trim)."""
    gc.collect()
    trim_heap()


def estimate(kind: Kind) -> tuple[int, str]:
    """service.budget's estimate of the measured request, as the route makes it."""
    from service.budget import frame_bytes, reconstruction_bytes, set_bytes
    from service.schemas import DepthImagesRequest, FrameRequest, ReconstructionRequest

    model, fn = {"frames": (FrameRequest, frame_bytes), "depth-images": (DepthImagesRequest, set_bytes),
                 "reconstruction": (ReconstructionRequest, reconstruction_bytes)}[kind.route]
    return fn(model.model_validate(kind.body))


def post(client: Any, sid: str, kind: Kind, body: dict[str, Any]) -> Any:
    r = client.post(f"/scenes/{sid}/{kind.route}", json=body)
    if r.status_code != 200:
        raise RuntimeError(f"{kind.name}: {r.status_code} {r.text[:500]}")
    return r


def measure_kind(kind: Kind, reset_peak: bool, workers: int = 0) -> tuple[dict[str, Any], dict[str, Any]]:
    """The warm-up, then the measured request of `kind` on a fresh in-process service
    (`reset_peak`: VmHWM reset by clear_refs first; `workers` > 0: that many worker
    processes, whose added peaks are added to the service process's): (its row, the
    service's readiness, which names its GL renderer)."""
    from fastapi.testclient import TestClient

    from service.app import create_app
    from service.config import Settings
    from service.testing import wait_ready

    with tempfile.TemporaryDirectory() as tmp:
        app = create_app(Settings(**{"data_dir": Path(tmp), "workers": workers, "job_timeout_s": 900.0,
                                     **kind.settings}))
        with TestClient(app) as client:
            ready = wait_ready(client, timeout=60.0)
            r = client.post("/scenes", json={"builtin": kind.scene})
            r.raise_for_status()
            sid = r.json()["id"]
            post(client, sid, kind, kind.warm)
            settle()
            pids: list[int | str] = ["self", *(p for p in getattr(app.state.worker, "pids", []) if p)]
            if reset_peak:
                for pid in pids:
                    Path(f"/proc/{pid}/clear_refs").write_text("5")
            before = {pid: status_kib("VmRSS", pid) for pid in pids}
            t0 = time.perf_counter()
            body_bytes = len(post(client, sid, kind, kind.body).content)  # the body is held while VmHWM is read
            seconds = time.perf_counter() - t0
            peak = {pid: status_kib("VmHWM", pid) for pid in pids}
            settle()
            after = status_kib("VmRSS")
    need, terms = estimate(kind)
    by_process = {("service" if pid == "self" else "worker"): (peak[pid] - before[pid]) * 1024 for pid in pids}
    added = sum(by_process.values())
    return {"kind": kind.name, "scene": kind.scene, "route": kind.route, "request": kind.body,
            "warm_up": kind.warm, "note": kind.note, "unit": kind.unit, "units": kind.units(kind.body),
            "rss_before_bytes": before["self"] * 1024, "peak_bytes": peak["self"] * 1024, "added_bytes": added,
            "added_by_process_bytes": by_process, "workers": workers,
            "kept_bytes": (after - before["self"]) * 1024, "settings": kind.settings,
            "response_bytes": body_bytes, "request_seconds": seconds, "estimate_bytes": need,
            "estimate_terms": terms, "estimate_over_measured": need / added if added > 0 else None}, ready


def measure_all(selected: list[Kind], reset_peak: bool, repeat: int, workers: int = 0
                ) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Each kind `repeat` times (in rounds over the kinds) by `measure_kind`, each time
    in a fresh interpreter (no reconstruction, shadow maps or heap left by another
    request): (per kind the row of its largest added peak, with every run's added
    peak in ``added_runs_bytes``; the last service's readiness)."""
    runs: dict[str, list[dict[str, Any]]] = {k.name: [] for k in selected}
    ready: dict[str, Any] = {}
    for _ in range(repeat):
        for kind in selected:
            cmd = [sys.executable, "-m", "bench.memory_budget", "--child", kind.key,
                   "--workers", str(workers), *([] if reset_peak else ["--no-reset"])]
            out = subprocess.run(cmd, capture_output=True, text=True, cwd=Path(__file__).resolve().parents[1])
            if out.returncode != 0:
                raise RuntimeError(f"{kind.name} failed (exit {out.returncode}):\n{out.stderr[-4000:]}")
            data = json.loads(out.stdout.strip().splitlines()[-1])
            row, ready = data["row"], data["ready"]
            runs[kind.name].append(row)
            print(f"{kind.name}: +{row['added_bytes'] / MIB:.0f} MiB, estimate {row['estimate_bytes'] / MIB:.0f} "
                  f"MiB ({row['request_seconds']:.1f} s)", flush=True)
    rows = []
    for kind in selected:
        worst = max(runs[kind.name], key=lambda r: r["added_bytes"])
        rows.append({**worst, "added_runs_bytes": [r["added_bytes"] for r in runs[kind.name]]})
    return rows, ready


# --- the report ---------------------------------------------------------------------------

def size_of(row: dict[str, Any]) -> str:
    b = row["request"]
    if row["route"] == "reconstruction":
        return f"4 × {b['resolution']}²"
    if row["route"] == "depth-images":
        return f"3 × {b['width']}²"
    ss = b.get("effects", {}).get("soft_shadows")
    if ss:
        return f"{b['width']}², k = {ss['samples']}, 4 × {ss['resolution']}²"
    return f"{b['width']}² {b['format'].upper()}"


def report(rows: list[dict[str, Any]], info: dict[str, Any], command: str, seconds: float, commit: str,
           method: str) -> str:
    workers = rows[0].get("workers", 0) if rows else 0

    def split(r: dict[str, Any]) -> str:
        parts = r.get("added_by_process_bytes") or {}
        return "" if not workers else " (" + " + ".join(f"{k} {v / MIB:.0f}" for k, v in parts.items()) + ")"

    table = md_table(
        ["request", "scene", "size", "measured added peak" + (" (service + worker, MiB)" if workers else ""),
         "per unit", "estimate", "estimate ÷ measured", "runs", "kept after", "request s"],
        [[r["kind"], r["scene"], size_of(r), f"{r['added_bytes'] / MIB:.0f} MiB{split(r)}",
          f"{r['added_bytes'] / r['units']:.0f} B / {r['unit']}", f"{r['estimate_bytes'] / MIB:.0f} MiB",
          f"{r['estimate_over_measured']:.2f}" if r["estimate_over_measured"] else "—",
          ", ".join(f"{b / MIB:.0f}" for b in r["added_runs_bytes"]), f"{r['kept_bytes'] / MIB:.0f} MiB",
          f"{r['request_seconds']:.1f}"] for r in rows])
    under = [r for r in rows if r["estimate_over_measured"] is not None and r["estimate_over_measured"] < 1]
    verdict = ("Every estimate is at or above the measured peak." if not under else
               "**The estimate is below the measured peak (the budget under-counts) for:** " + "; ".join(
                   f"{r['kind']} ({size_of(r)}: estimate {r['estimate_bytes'] / MIB:.0f} MiB, measured "
                   f"{r['added_bytes'] / MIB:.0f} MiB, ×{r['estimate_over_measured']:.2f})" for r in under) + ".")
    notes = [f"- {r['kind']}: {r['note']}; estimate terms: {r['estimate_terms']}." for r in rows if r["note"]]
    return "\n".join([
        "# Memory budget: peak resident memory per request against service.budget's estimate", "",
        "## What was run", "",
        f"- Command: `{command}` (module docstring: bench/memory_budget.py)",
        f"- Commit {commit}; wall time {seconds / 60:.1f} min.",
        ("- The real app in-process (TestClient, render worker thread, default settings but `workers=0`), a "
         if not workers else
         f"- The real app (TestClient) with {workers} render worker process(es) (`workers={workers}`; the "
         "service's default is worker processes), the added peaks of the service process and of the worker "
         "process summed, default settings otherwise, a ")
        + "fresh one per kind; each kind first gets a small warm-up request of the same kind (`warm_up` in the "
        "json), then the measured request.",
        f"- Peak: {method}. On llvmpipe GPU memory is host memory, so it is in the RSS.",
        "- Estimate: the route's own function (`service.budget.frame_bytes`, `set_bytes`, "
        "`reconstruction_bytes`) on the same validated request. Per unit: the measured peak over the "
        "request's frame pixels (`FRAME_BYTES_PER_PIXEL`), depth-image pixels (`SET_BYTES_PER_PIXEL`) or "
        "reconstruction samples (`RECONSTRUCTION_BYTES_PER_SAMPLE`; soft shadows: the whole frame's peak over "
        "the samples of its reconstruction).",
        "- Runs: each run's added peak (MiB, each on a fresh service); the row is the largest. Kept after: VmRSS "
        "once the response is dropped and the heap trimmed, minus VmRSS before the request: what the worker keeps "
        "for later requests (reconstructions and shadow maps up to `reconstruction_cache_bytes`, which the "
        "config docstring bounds apart from the per-request budget; targets of the new size).", "",
        "## Machine", "", machine_markdown(info), "",
        "## Results", "", table, "", verdict, "",
        *(["Notes:", "", *notes, ""] if notes else []),
    ])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--kinds", type=lambda s: s.split(","), default=None,
                    help="comma list of kind keys (`kinds`; default: all)")
    ap.add_argument("--repeat", type=int, default=2, help="runs per kind (the largest peak is reported)")
    ap.add_argument("--workers", type=int, default=0,
                    help="worker processes (0: the render worker is a thread of the service process); "
                         "results go to memory_budget_workers<N>.*")
    ap.add_argument("--out", type=Path, default=RESULTS_DIR)
    ap.add_argument("--report-only", action="store_true", help="rewrite the report from the json")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)  # one kind, JSON to stdout
    ap.add_argument("--no-reset", dest="reset", action="store_false", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    by_key = {k.key: k for k in kinds()}
    if args.child:
        row, ready = measure_kind(by_key[args.child], reset_peak=args.reset, workers=args.workers)
        print(json.dumps({"row": row, "ready": ready}))
        return 0
    stem = "memory_budget" + (f"_workers{args.workers}" if args.workers else "")
    if args.report_only:
        data = json.loads((args.out / f"{stem}.json").read_text())
        write_text(args.out / f"{stem}.md", report(data["rows"], data["machine"], data["command"],
                                                   data["seconds"], data["commit"], data["method"]))
        print(f"rewrote {args.out / f'{stem}.md'}")
        return 0
    selected = [by_key[n] for n in args.kinds] if args.kinds else list(by_key.values())
    command = ("python -m bench.memory_budget" + (f" --kinds {','.join(args.kinds)}" if args.kinds else "")
               + (f" --repeat {args.repeat}" if args.repeat != 2 else "")
               + (f" --workers {args.workers}" if args.workers else ""))
    reset = clear_refs_writable()
    method = ("each kind on its own fresh service in a fresh interpreter; VmHWM after the request − VmRSS before "
              "it, " + ("VmHWM reset by writing 5 to /proc/self/clear_refs after gc.collect() and malloc_trim(0)"
                        if reset else "VmHWM not reset (clear_refs not writable): it starts at the warm-up's peak"))
    t0 = time.perf_counter()
    rows, ready = measure_all(selected, reset, args.repeat, args.workers)
    seconds = time.perf_counter() - t0
    gl = SimpleNamespace(backend=ready.get("backend"), renderer=ready.get("renderer"),
                         version=ready.get("gl_version"), is_software=ready.get("software"))
    info = machine_info(gl)
    commit = git_revision()
    write_json(args.out / f"{stem}.json", {"command": command, "commit": commit, "seconds": seconds,
                                           "method": method, "machine": info, "rows": rows})
    write_text(args.out / f"{stem}.md", report(rows, info, command, seconds, commit, method))
    print(f"wrote {args.out / f'{stem}.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

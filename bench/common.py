"""Shared helpers for the benchmark scripts in bench/: what machine and renderer
ran a benchmark, wall-clock timing (repeated, interleaved side by side, median),
scene loading by name, and result writers (Markdown tables + JSON).

Nothing here is specific to one benchmark; scripts write to bench/results/.
"""

from __future__ import annotations

import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, is_dataclass
from pathlib import Path
from typing import Any

import numpy as np

from reference.raycast import usable_cpus  # the reference caster sizes its thread pool by it

RESULTS_DIR = Path(__file__).resolve().parent / "results"
SHARED_SCENES = Path(os.environ.get("DEPTHVIEW_SHARED_SCENES",
                                    Path(__file__).resolve().parents[2] / "shared" / "scenes"))

#: Real models usable by name in benchmarks (path relative to SHARED_SCENES).
SHARED_MODELS = {"diorama": "macross_diorama/scene.glb"}


# --- machine / renderer description ------------------------------------------------

def cpu_model() -> str:
    """CPU model name from /proc/cpuinfo (or platform.processor())."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def memory_gib() -> float | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                return round(int(line.split()[1]) / 2**20, 1)
    except (OSError, ValueError):
        pass
    return None


def _version(mod: str) -> str | None:
    try:
        from importlib.metadata import version

        return version(mod)
    except Exception:  # noqa: BLE001 - any failure means "unknown"
        return None


def git_revision() -> str:
    """The checkout's short commit (with '+' when its tree has changes outside
    bench/results, which a run writes before it is stamped), or '?'."""
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                             check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", ".",
                                ":(exclude)bench/results"], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "?"
    return rev + ("+" if dirty else "")


def machine_info(gl: Any = None) -> dict[str, Any]:
    """Machine, CPU, memory, software versions and (when `gl`, a
    gl_passes.context.GLContext, is given) the GL backend, renderer and version."""
    info: dict[str, Any] = {
        "machine": platform.machine(),
        "system": f"{platform.system()} {platform.release()}",
        "cpu": cpu_model(),
        "cpus_usable": usable_cpus(),
        "cpus_total": os.cpu_count(),
        "memory_gib": memory_gib(),
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "embreex": _version("embreex"),
        "moderngl": _version("moderngl"),
    }
    if gl is not None:
        info["gl_backend"] = getattr(gl, "backend", None)
        info["gl_renderer"] = getattr(gl, "renderer", None)
        info["gl_version"] = getattr(gl, "version", None)
        info["gl_software"] = getattr(gl, "is_software", None)
    return info


def machine_markdown(info: Mapping[str, Any], shared: bool = True) -> str:
    """A short bullet list describing the machine (from `machine_info`); shared: other
    jobs may run on it (this development machine; a GPU machine lent for a session is not)."""
    lines = [f"- CPU: {info.get('cpu')} ({info.get('cpus_usable')} usable of {info.get('cpus_total')} logical "
             f"CPUs{', shared with other jobs' if shared else ', lent for one session'}), "
             f"{info.get('memory_gib')} GiB RAM, {info.get('system')} "
             f"{info.get('machine')}"]
    if info.get("gl_renderer"):
        lines.append(f"- GL: {info.get('gl_renderer')} ({info.get('gl_version')}, backend "
                     f"{info.get('gl_backend')}{', software rasteriser' if info.get('gl_software') else ''})")
    lines.append(f"- Python {info.get('python')}, numpy {info.get('numpy')}, embreex {info.get('embreex')}, "
                 f"moderngl {info.get('moderngl')}")
    return "\n".join(lines)


# --- timing -----------------------------------------------------------------------

@dataclass
class Timing:
    """Wall-clock samples of one timed function, in milliseconds."""

    samples_ms: list[float]

    @property
    def median_ms(self) -> float:
        return statistics.median(self.samples_ms)

    @property
    def min_ms(self) -> float:
        return min(self.samples_ms)

    @property
    def mean_ms(self) -> float:
        return statistics.fmean(self.samples_ms)

    def to_dict(self) -> dict[str, Any]:
        return {"median_ms": self.median_ms, "min_ms": self.min_ms, "mean_ms": self.mean_ms,
                "repeat": len(self.samples_ms), "samples_ms": self.samples_ms}


def time_once(fn: Callable[[], Any], sync: Callable[[], Any] | None = None) -> float:
    """Milliseconds for one call of fn (sync, e.g. ctx.finish, is called before
    starting the clock and before stopping it)."""
    if sync:
        sync()
    t0 = time.perf_counter()
    fn()
    if sync:
        sync()
    return (time.perf_counter() - t0) * 1e3


def time_side_by_side(fns: Mapping[str, Callable[[], Any]], repeat: int = 10, warmup: int = 2,
                      sync: Callable[[], Any] | None = None, rotate: bool = False) -> dict[str, Timing]:
    """Time several functions in one run, interleaved round by round (so load
    changes on a shared machine hit all of them alike): `warmup` untimed rounds,
    then `repeat` timed rounds; rotate: the order turns by one each timed round (no
    function always runs after the same other). Returns name → Timing (use the median)."""
    for _ in range(warmup):
        for fn in fns.values():
            fn()
    if sync:
        sync()
    out = {name: Timing([]) for name in fns}
    names = list(fns)
    for rnd in range(repeat):
        turn = rnd % len(names) if rotate and names else 0
        for name in names[turn:] + names[:turn]:
            out[name].samples_ms.append(time_once(fns[name], sync))
    return out


class Stopwatch:
    """Named wall-clock sections: `with sw("cast"): ...`; sw.seconds is a dict."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}

    def __call__(self, name: str) -> Stopwatch._Section:
        return Stopwatch._Section(self, name)

    class _Section:
        def __init__(self, sw: Stopwatch, name: str) -> None:
            self.sw, self.name = sw, name

        def __enter__(self) -> None:
            self.t0 = time.perf_counter()

        def __exit__(self, *exc: object) -> None:
            self.sw.seconds[self.name] = self.sw.seconds.get(self.name, 0.0) + time.perf_counter() - self.t0


def progress(iterable: Iterable, enabled: bool = True, **kw: Any) -> Iterable:
    """tqdm progress bar around iterable (plain iterable when disabled)."""
    if not enabled:
        return iterable
    from tqdm import tqdm

    return tqdm(iterable, **kw)


# --- scenes -----------------------------------------------------------------------

def shared_model_path(name: str) -> Path | None:
    """Path of a real model from ../shared/scenes by short name, None if absent."""
    rel = SHARED_MODELS.get(name)
    if rel is None:
        return None
    p = SHARED_SCENES / rel
    return p if p.exists() else None


def load_named_scene(name: str, detail: float = 1.0, seed: int = 0):
    """A built-in scene (scenes.builtin) or a shared real model by short name
    (SHARED_MODELS). Raises FileNotFoundError for an absent shared model."""
    if name in SHARED_MODELS:
        p = shared_model_path(name)
        if p is None:
            raise FileNotFoundError(f"shared model {name!r} not found under {SHARED_SCENES}")
        from scenes.loaders import load_scene

        return load_scene(p)
    from scenes.builtin import make_builtin

    return make_builtin(name, detail=detail, seed=seed)


# --- results writers ----------------------------------------------------------------

def jsonable(obj: Any) -> Any:
    """Convert numpy scalars/arrays, dataclasses, Paths and non-finite floats
    (→ None) into plain JSON values."""
    if is_dataclass(obj) and not isinstance(obj, type):
        return jsonable(asdict(obj))
    if hasattr(obj, "to_dict") and callable(obj.to_dict):
        return jsonable(obj.to_dict())
    if isinstance(obj, Mapping):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return jsonable(obj.item())
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_json(path: str | Path, obj: Any) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(jsonable(obj), indent=2) + "\n")
    return path


def write_text(path: str | Path, text: str) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text if text.endswith("\n") else text + "\n")
    return path


def md_table(headers: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    """A GitHub-flavoured Markdown table; cells are str()-ed."""
    head = "| " + " | ".join(str(h) for h in headers) + " |"
    sep = "|" + "|".join("---" for _ in headers) + "|"
    body = ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join([head, sep, *body])


def report_head(title: str, command: str, facts: Sequence[str], seconds: float, info: Mapping[str, Any]) -> list[str]:
    """The opening lines of a benchmark report: title, "What was run" (command,
    `facts` as bullets, wall time) and "Machine" (`machine_markdown(info)`)."""
    return [f"# {title}", "", "## What was run", "", f"- Command: `{command}`", *(f"- {f}" for f in facts),
            f"- Wall time {seconds / 60:.1f} min.", "", "## Machine", "", machine_markdown(info), ""]


def measure_with_gl(measure: Callable[[Any], Any]) -> tuple[Any, dict[str, Any], float]:
    """measure(gl) on a fresh GL context (released after): (its result,
    machine_info(gl), wall seconds)."""
    from gl_passes.context import create_gl_context

    gl = create_gl_context()
    try:
        t0 = time.perf_counter()
        result = measure(gl)
        return result, machine_info(gl), time.perf_counter() - t0
    finally:
        gl.release()


def sweep_main(args: Any, stem: str, values: Sequence[Any], key: Callable[[Any], str], parse_key: Callable[[str], Any],
               measure_one: Callable[[Any, Any], list[dict]],
               write_report: Callable[[Path, Any, dict, dict, float], None]) -> int:
    """main() of a benchmark that measures the rig once per value of one parameter
    (`values`, keyed in JSON by key(value)): measure_one(gl, value) on one GL context,
    then <out>/<stem>.json ({"args", "machine", "seconds", "runs"}) and
    write_report(out, args, machine, runs, seconds); with args.report_only only the
    report is rewritten from that JSON (its saved arguments, `out` from args).
    The arguments saved include `reference_revision` (`reference.REVISION`)."""
    import argparse

    if args.report_only:
        data = json.loads((args.out / f"{stem}.json").read_text())
        saved = argparse.Namespace(**{**data["args"], "out": args.out})
        runs = {parse_key(k): r for k, r in data["runs"].items()}
        write_report(args.out, saved, data["machine"], runs, data["seconds"])
        print(f"rewrote {args.out / f'{stem}.md'}")
        return 0
    from reference import REVISION

    args.reference_revision = REVISION  # recorded with the run's arguments
    runs, info, seconds = measure_with_gl(lambda gl: {v: measure_one(gl, v) for v in values})
    write_json(args.out / f"{stem}.json", {"args": {k: v for k, v in vars(args).items() if k != "out"},
                                           "machine": info, "seconds": seconds,
                                           "runs": {key(v): r for v, r in runs.items()}})
    write_report(args.out, args, info, runs, seconds)
    print(f"wrote {args.out / f'{stem}.md'}")
    return 0


def add_scene_args(ap: Any, views: int, res: int = 512) -> None:
    """--scenes, --res, --views, --seed, --out, --no-progress of the benchmarks
    that measure the Fig. 8 rig on the four thesis scenes (an argparse parser)."""
    ap.add_argument("--scenes", type=lambda s: s.split(","), default=["nest", "grass", "city", "tree"])
    ap.add_argument("--res", type=int, default=res, help="image resolution (square)")
    ap.add_argument("--views", type=int, default=views, help="intermediate views")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=RESULTS_DIR)
    ap.add_argument("--no-progress", dest="progress", action="store_false")


def pct(x: float | None, digits: int = 0) -> str:
    """0.123 → '12%' (digits decimals); None/NaN → '—'."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "—"
    return f"{100 * x:.{digits}f}%"


def span(values: Iterable[float], fmt: str, sep: str = "-") -> str:
    """'lo-hi' of the values (one value when both ends print the same)."""
    vals = list(values)
    lo, hi = format(min(vals), fmt), format(max(vals), fmt)
    return lo if lo == hi else f"{lo}{sep}{hi}"

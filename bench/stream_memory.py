"""Resident memory a reflective stream keeps on its worker between frames, and what its close gives back.

A stream with reflections (``/scenes/{id}/stream``, ``"reflections": "cluster"`` or
``"raytrace"``) keeps one ``ReflectionReuser`` and its tracer on its worker while the
socket is open (thesis Ch. 5: the keyframe's reflection depth image, G-buffers and
buffers of its frame size). This benchmark measures what one such stream costs: in
a fresh interpreter per (method, frame size) a worker state (``service.worker.GLState``,
as a worker builds it) runs the stream jobs themselves (``service.stream.
StreamReflectionJob``, then ``ReleaseStream`` and the worker's ``end_job``) on the
built-in mirror scene. A warm-up stream runs two frames and is closed (shaders,
scene upload, passes); then `streams` streams each run two frames (a keyframe and
one reused frame) and stay open; VmRSS is read after each. Per stream: the mean
step between consecutive streams (the first one can reuse the warm-up's freed
memory), in MiB and in bytes per frame pixel, which ``service.config``'s
``STREAM_REUSER_BYTES_PER_PIXEL`` (the estimate the ``STREAM_REUSE_BYTES`` budget
counts) is rounded up from. Then every stream is closed and VmRSS read twice: after
the releases and a driver settle, and after the worker's ``end_job``, which also
trims the heap (glibc keeps freed memory resident otherwise). On llvmpipe GPU memory is host memory, so the RSS
includes it.

Run `python -m bench.stream_memory`; results go to bench/results/stream_memory.*.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from bench.common import RESULTS_DIR, git_revision, machine_info, machine_markdown, md_table, write_json, write_text

MIB = 2**20
SIZES = ((640, 360), (1280, 720), (1920, 1080))
METHODS = ("cluster", "raytrace")


def rss_mib() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise OSError("no VmRSS")


def measure(method: str, width: int, height: int, streams: int) -> dict[str, Any]:
    """One (method, size) in this process: RSS before, after each stream's two frames, after closing."""
    from gl_passes.context import create_gl_context
    from gl_passes.gbuffer import GBufferPass
    from gl_passes.releasable import settle
    from scenes import builtin
    from scenes.camera import look_at_scene
    from service.stream import ReleaseStream, StreamReflectionJob
    from service.worker import GLState

    gl = create_gl_context()
    state = GLState(gl=gl, gbuffer=GBufferPass(gl))
    scene = builtin.make_builtin("mirror")

    def frame(stream: str, azimuth: float) -> None:
        cam = look_at_scene(scene.bounds, azimuth=azimuth, width=width, height=height).fit_clip(scene.bounds)
        StreamReflectionJob("mirror", scene, cam, method, 8, stream)(state)
        state.end_job()

    frame("warm", 30.0)
    frame("warm", 31.0)
    ReleaseStream("warm")(state)
    state.end_job()
    before = rss_mib()
    after = []
    for i in range(streams):
        frame(f"s{i}", 35.0 + 2 * i)
        frame(f"s{i}", 35.5 + 2 * i)
        after.append(rss_mib())
    for i in range(streams):
        ReleaseStream(f"s{i}")(state)
    settle(gl)
    untrimmed = rss_mib()  # released and settled, the heap not trimmed
    state.end_job()  # what the worker runs after each chore: settle, then trim the heap
    closed = rss_mib()
    per = (after[-1] - after[0]) / max(streams - 1, 1)
    return {"method": method, "width": width, "height": height, "streams": streams, "renderer": gl.renderer,
            "rss_before_mib": before, "rss_after_mib": after, "rss_untrimmed_mib": untrimmed,
            "rss_closed_mib": closed,
            "per_stream_mib": per, "bytes_per_pixel": per * MIB / (width * height)}


def report(rows: list[dict[str, Any]], info: dict[str, Any], command: str, seconds: float, out: Path) -> None:
    table = md_table(
        ["method", "frame", "per stream (MiB)", "bytes per pixel", "RSS before streams", "after each stream",
         "closed, heap not trimmed", "closed (worker's end_job)"],
        [[r["method"], f"{r['width']}×{r['height']}", f"{r['per_stream_mib']:.0f}", f"{r['bytes_per_pixel']:.0f}",
          f"{r['rss_before_mib']:.0f}", " / ".join(f"{x:.0f}" for x in r["rss_after_mib"]),
          f"{r['rss_untrimmed_mib']:.0f}", f"{r['rss_closed_mib']:.0f}"] for r in rows])
    md = ["# Memory a reflective stream keeps on its worker", "",
          f"`{command}` · {seconds:.0f} s · revision {git_revision()} · built-in mirror scene, "
          f"{rows[0]['streams']} streams per row, two frames each (a keyframe and one reused frame)", "",
          machine_markdown(info), "", table, "",
          "RSS in MiB of the process holding the worker state (on llvmpipe GPU memory is host memory). "
          "Per stream: the mean step between consecutive open streams. Closed: every stream's "
          "`ReleaseStream` chore has run and the driver settled (an empty compute dispatch); then the "
          "worker's `end_job`, run after every chore, which also trims the heap (`malloc_trim`).", ""]
    write_text(out.with_suffix(".md"), "\n".join(md))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--streams", type=int, default=3)
    ap.add_argument("--out", default=str(RESULTS_DIR / "stream_memory"))
    ap.add_argument("--one", nargs=3, metavar=("METHOD", "W", "H"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        method, w, h = args.one
        print(json.dumps(measure(method, int(w), int(h), args.streams)))
        return
    t0 = time.time()
    rows = []
    for method in METHODS:
        for w, h in SIZES:
            done = subprocess.run([sys.executable, "-m", "bench.stream_memory", "--streams", str(args.streams),
                                   "--one", method, str(w), str(h)], check=True, capture_output=True, text=True)
            rows.append(json.loads(done.stdout.strip().splitlines()[-1]))
            print(json.dumps(rows[-1]))
    from gl_passes.context import create_gl_context

    info = machine_info(create_gl_context())
    out = Path(args.out)
    write_json(out.with_suffix(".json"), {"rows": rows, "machine": info, "revision": git_revision()})
    report(rows, info, "python -m bench.stream_memory" + (f" --streams {args.streams}" if args.streams != 3 else ""),
           time.time() - t0, out)


if __name__ == "__main__":
    main()

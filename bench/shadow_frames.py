"""Soft-shadow frames along an orbit through the service's render job, with the render
worker keeping the light's reconstruction and shadow maps between frames and without.

The service renders a soft-shadow frame as `service.jobs.SoftShadowJob` on its worker's
`GLState`: the G-buffer of the camera, the light's depth images and their
reconstruction (Alg. 4), k² shadow maps of it and their lookups (Alg. 5). Only the
G-buffer and the lookups depend on the camera; `GLState.kept` keeps the
reconstruction, and the maps where all k² fit, for the next frame under the same light
(the service's default, ``reconstruction_cache_bytes``). Here the same job runs for
every camera of an orbit on two states over one GL context, with that cache and with
none, frame by frame in turn (the machine is shared: the two see the same load). Times
are the job's (the worker's share of a frame; shading and encoding run beside it in the
service and do not change).

Settings: the thin client's (k = 6, reference images 256², both sides of the surfaces,
a 640×480 frame: `service/static/client.js`) on the four soft-shadow scenes and the
cornell room, and the HTTP defaults (k = 16, 1024², back faces culled, 512²) on city,
NR + hybrid throughout.

    python -m bench.shadow_frames [--frames 8] [--http-frames 3] [--out bench/results]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path
from typing import Any

from bench.common import md_table, measure_with_gl, progress, report_head, write_json, write_text
from gl_passes.gbuffer import GBufferPass
from scenes.builtin import make_builtin
from scenes.camera import orbit_path
from scenes.lights import default_area_light
from service.config import Settings
from service.jobs import SoftShadowJob
from service.soft_shadows import SoftShadowRequest
from service.worker import GLState

SCENES = ("city", "grass", "nest", "tree", "cornell")
#: (label, k, reference resolution, sides, frame width, frame height, scenes).
SETTINGS = (("thin client", 6, 256, "both", 640, 480, SCENES), ("HTTP default", 16, 1024, "front", 512, 512, ("city",)))


def orbit(gl: Any, name: str, k: int, res: int, sides: str, width: int, height: int, frames: int
          ) -> dict[str, Any]:
    """Job seconds per frame of `frames` cameras orbiting scene `name`, with the
    reconstruction cache (the service's default size) and without, in turn."""
    scene = make_builtin(name)
    light = default_area_light(scene.bounds, scene.sun_direction)
    req = SoftShadowRequest(light, k, "non_redundant", "hybrid", res, sides)
    states = {"kept": GLState(gl=gl, gbuffer=GBufferPass(gl),
                              reconstruction_cache_bytes=Settings.reconstruction_cache_bytes),
              "remade": GLState(gl=gl, gbuffer=GBufferPass(gl), reconstruction_cache_bytes=0)}
    seconds: dict[str, list[float]] = {key: [] for key in states}
    try:
        for cam in orbit_path(scene.bounds, frames, width=width, height=height):
            job = SoftShadowJob(name, scene, cam, req)
            counts = {}
            for key, st in states.items():
                t0 = time.perf_counter()
                counts[key] = job(st)[1]
                st.gl.ctx.finish()
                seconds[key].append(time.perf_counter() - t0)
            if not (counts["kept"] == counts["remade"]).all():
                raise AssertionError(f"{name}: the kept reconstruction's shadows differ from a fresh one's")
    finally:
        for st in states.values():
            st.release_objects()
    return {"scene": name, "k": k, "res": res, "sides": sides, "width": width, "height": height, "seconds": seconds}


def measure(gl: Any, frames: int, http_frames: int, show: bool) -> list[dict[str, Any]]:
    jobs = [(label, k, res, sides, w, h, name) for label, k, res, sides, w, h, names in SETTINGS for name in names]
    out = []
    for label, k, res, sides, w, h, name in progress(jobs, show, desc="orbits"):
        run = orbit(gl, name, k, res, sides, w, h, http_frames if label == "HTTP default" else frames)
        out.append({"setting": label, **run})
    return out


def write_report(out: Path, args: argparse.Namespace, info: dict[str, Any], runs: list[dict[str, Any]],
                 seconds: float) -> None:
    rows = []
    for r in runs:
        kept, remade = r["seconds"]["kept"], r["seconds"]["remade"]
        later_kept, later_remade = statistics.median(kept[1:]), statistics.median(remade[1:])
        rows.append([r["setting"], r["scene"], f"{r['k']}² · {r['res']}² {r['sides']} · {r['width']}×{r['height']}",
                     len(kept), f"{kept[0]:.2f} / {remade[0]:.2f}", f"{later_kept:.2f}", f"{later_remade:.2f}",
                     f"{later_remade / later_kept:.2f}×"])
    text = report_head(
        "Soft-shadow frames under one light: the reconstruction and shadow maps kept between frames",
        f"python -m bench.shadow_frames --frames {args.frames} --http-frames {args.http_frames}",
        ["`service.jobs.SoftShadowJob` (NR images from the light's 4 corners, hybrid reconstruction, k×k shadow "
         "maps) for each camera of an orbit (`scenes.camera.orbit_path`), on a `GLState` that keeps the "
         "reconstruction and, where all k² fit, the shadow maps (`GLState.kept`, the service's default size: "
         "up to 17×17 maps fit) and on one that keeps none, "
         "frame by frame in turn on one GL context; the job's wall time (G-buffer, depth images, reconstruction, "
         "shadow maps and lookups), not shading or encoding. Both give the same visible-sample counts on every "
         "frame (checked)."],
        seconds, info) + [
        "## Seconds per frame",
        "",
        "Settings: k² light samples · reference images and the sides of the surfaces they keep (`soft_shadows."
        "sides`) · frame. First frame: kept / remade (the kept state "
        "builds its reconstruction and maps there too); later frames: the median of the rest.",
        "",
        md_table(["setting", "scene", "settings", "frames", "first frame", "later frames, kept",
                  "later frames, remade", "remade / kept"], rows),
        "",
    ]
    write_text(out / "shadow_frames.md", "\n".join(text))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=8, help="orbit frames per scene at the thin client's setting")
    ap.add_argument("--http-frames", type=int, default=3, help="orbit frames at the HTTP defaults (city)")
    ap.add_argument("--out", type=Path, default=Path("bench/results"))
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    runs, info, seconds = measure_with_gl(lambda gl: measure(gl, args.frames, args.http_frames,
                                                             not args.no_progress))
    write_json(args.out / "shadow_frames.json", {"args": vars(args), "machine": info, "seconds": seconds,
                                                 "runs": runs})
    write_report(args.out, args, info, runs, seconds)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

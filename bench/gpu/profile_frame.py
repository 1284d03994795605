"""Where a cluster-reflections frame spends its time on this machine's GL driver
(issue 17): the steps' milliseconds with a wait after each, the cluster-camera
extent passes apart, and a cProfile of one frame's Python (top functions by own
time: Python work, or GL calls that wait for the device). For a lent GPU
(bench/gpu/run.sh), where the benchmark's per-step table does not say why.

    python -m bench.gpu.profile_frame --scene living_room --res 512 2048
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import time

from bench.common import load_named_scene
from bench.reflections import view_camera
from gl_passes.context import create_gl_context
from gl_passes.reflections import DEFAULT_SETTINGS, ClusterReflections
from gl_passes.upload import SceneGPU


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="living_room")
    ap.add_argument("--res", type=int, nargs="+", default=[512, 2048])
    ap.add_argument("--top", type=int, default=25)
    args = ap.parse_args()
    gl = create_gl_context()
    print("GL", gl.renderer, flush=True)
    scene = load_named_scene(args.scene)
    with ClusterReflections(gl, DEFAULT_SETTINGS) as refl, SceneGPU(gl, scene) as sg:
        waits: dict[str, list[float]] = {}
        run = refl.extent.run

        def timed_extent(stage, *a, **k):
            gl.ctx.finish()
            t = time.perf_counter()
            out = run(stage, *a, **k)
            waits.setdefault(f"extent stage {stage}", []).append((time.perf_counter() - t) * 1e3)
            return out

        refl.extent.run = timed_extent
        for res in args.res:
            cam = view_camera(scene, res)
            refl.render(sg, cam)  # warm-up
            waits.clear()
            r = refl.render(sg, cam, sync_timings=True)
            print(f"res {res}: steps (waited)", {k: round(v, 1) for k, v in r.timings_ms.items()},
                  {k: [round(x, 1) for x in v] for k, v in waits.items()}, flush=True)
            prof = cProfile.Profile()
            prof.enable()
            r = refl.render(sg, cam)
            prof.disable()
            print(f"res {res}: steps (not waited)", {k: round(v, 1) for k, v in r.timings_ms.items()})
            s = io.StringIO()
            pstats.Stats(prof, stream=s).sort_stats("tottime").print_stats(args.top)
            print(s.getvalue(), flush=True)


if __name__ == "__main__":
    main()

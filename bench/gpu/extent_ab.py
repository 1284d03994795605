"""A/B of the cluster-camera extent pass's two ways of combining a workgroup's
records (shared atomics; a tree in shared memory) on the same frames: the extents
must be equal; milliseconds per stage, median of 3, each dispatch waited for. For a
lent GPU (bench/gpu/run.sh) and this machine alike.

    python -m bench.gpu.extent_ab living_room 512 2048
"""

from __future__ import annotations

import sys
import time

import numpy as np

from bench.common import load_named_scene
from bench.reflections import view_camera
from gl_passes.cluster_camera import ClusterExtentPass
from gl_passes.context import create_gl_context
from gl_passes.reflections import DEFAULT_SETTINGS, ClusterReflections
from gl_passes.upload import SceneGPU


def main(argv: list[str]) -> None:
    gl = create_gl_context()
    print("GL", gl.renderer, flush=True)
    name = argv[0]
    scene = load_named_scene(name)
    variants = {"atomics": ClusterExtentPass(gl, tree=False), "tree": ClusterExtentPass(gl, tree=True)}
    with ClusterReflections(gl, DEFAULT_SETTINGS) as refl, SceneGPU(gl, scene) as sg:
        for res in (int(x) for x in argv[1:]):
            calls = []
            run = refl.extent.run

            def spy(stage, frames, size, eye, run=run, calls=calls):
                calls.append((stage, frames.copy(), size, np.array(eye)))
                return run(stage, frames, size, eye)

            refl.extent.run = spy
            refl.render(sg, view_camera(scene, res))
            del refl.extent.run
            # the frame's G-buffer, bins and remap are still bound: both stages again with each variant
            out, times = {}, {}
            for _ in range(3):
                for vname, v in variants.items():
                    for stage, frames, size, eye in calls:
                        gl.ctx.finish()
                        t = time.perf_counter()
                        out[vname, stage] = v.run(stage, frames, size, eye)
                        times.setdefault((vname, stage), []).append((time.perf_counter() - t) * 1e3)
            for stage in (0, 1):
                same = np.array_equal(out["atomics", stage], out["tree", stage])
                print(f"{name} {res}² stage {stage}: extents equal {same}, ms",
                      {v: round(float(np.median(times[v, stage])), 2) for v in variants}, flush=True)
    for v in variants.values():
        v.release()


if __name__ == "__main__":
    main(sys.argv[1:])

"""G-buffer pass (GL) vs Embree primary ray casting on every built-in scene (issue 2, item 11).

Both produce the same buffers (colour, depth, normal, position, ids). Timed side
by side in one run (interleaved rounds, median) at 512² and 1024²; the figure of
merit is the ratio Embree time / GL time. GL is timed twice: draw only (finished
with ctx.finish) and draw + read-back of all seven buffers.

    python -m bench.render_throughput [--res 512 1024] [--repeat 5] [--scenes ...]
"""

from __future__ import annotations

import argparse

from bench.common import (
    RESULTS_DIR,
    load_named_scene,
    machine_info,
    machine_markdown,
    md_table,
    progress,
    time_side_by_side,
    write_json,
    write_text,
)
from gl_passes.context import create_gl_context
from gl_passes.gbuffer import GBufferPass
from gl_passes.upload import SceneGPU
from reference.raycast import RayCaster
from scenes.builtin import BUILTIN_NAMES
from scenes.camera import look_at_scene


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", type=int, nargs="+", default=[512, 1024])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--scenes", nargs="+", default=list(BUILTIN_NAMES))
    ap.add_argument("--out", default=str(RESULTS_DIR / "render_throughput"))
    args = ap.parse_args(argv)

    gl = create_gl_context()
    gp = GBufferPass(gl)
    rows, records = [], []
    for name in progress(args.scenes, desc="scenes"):
        scene = load_named_scene(name)
        sg = SceneGPU(gl, scene)
        rc = RayCaster(scene)
        for res in args.res:
            cam = look_at_scene(scene.bounds, azimuth=30.0, elevation=30.0, distance=0.9, width=res, height=res)
            t = time_side_by_side({
                "gl_draw": lambda cam=cam, sg=sg: gp.draw(sg, cam),
                "gl_draw_readback": lambda cam=cam, sg=sg: gp.render(sg, cam),
                "embree_gbuffer": lambda cam=cam, rc=rc: rc.gbuffer(cam),
            }, repeat=args.repeat, warmup=1, sync=gl.ctx.finish)
            rec = {"scene": name, "triangles": scene.n_triangles, "res": res,
                   **{k: v.to_dict() for k, v in t.items()},
                   "ratio_embree_over_gl_draw": t["embree_gbuffer"].median_ms / t["gl_draw"].median_ms,
                   "ratio_embree_over_gl_readback": t["embree_gbuffer"].median_ms / t["gl_draw_readback"].median_ms}
            records.append(rec)
            rows.append([name, f"{scene.n_triangles:,}", f"{res}²", f"{t['gl_draw'].median_ms:.1f}",
                         f"{t['gl_draw_readback'].median_ms:.1f}", f"{t['embree_gbuffer'].median_ms:.1f}",
                         f"{rec['ratio_embree_over_gl_draw']:.2f}×", f"{rec['ratio_embree_over_gl_readback']:.2f}×"])
        sg.release()
    info = machine_info(gl)
    md = "\n\n".join([
        "# Render throughput: GL G-buffer pass vs Embree primary rays",
        "Command: `python -m bench.render_throughput "
        f"--res {' '.join(map(str, args.res))} --repeat {args.repeat}`",
        machine_markdown(info),
        "Each cell is the median of the interleaved rounds (ms). *GL draw* = sky + geometry into the 7-target "
        "G-buffer, finished with glFinish; *+readback* adds reading and flipping all buffers to numpy. *Embree* = "
        "primary rays through every pixel centre, back-face culling emulation, the same shading and buffers. "
        "Ratio > 1 means GL is faster. The machine's two cores are shared with other jobs: medians within about "
        "20 % of each other (e.g. draw vs draw+readback at 512², where the read-back sync can even come out "
        "cheaper than glFinish) are not distinguishable in one run. No GPU was lent to this task, so there are "
        "no GPU figures yet.",
        md_table(["scene", "triangles", "res", "GL draw ms", "GL draw+readback ms", "Embree ms",
                  "Embree / GL draw", "Embree / GL+readback"], rows),
    ])
    write_text(args.out + ".md", md)
    write_json(args.out + ".json", {"machine": info, "results": records})
    print(md)
    gp.release()
    gl.release()


if __name__ == "__main__":
    main()

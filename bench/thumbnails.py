"""Render a thumbnail of every built-in scene (local shading, GL G-buffer) for the README.

    python -m bench.thumbnails [--res 256]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from bench.common import RESULTS_DIR
from gl_passes.context import create_gl_context
from gl_passes.gbuffer import GBufferPass
from gl_passes.upload import SceneGPU
from scenes.builtin import BUILTIN_NAMES, make_builtin
from scenes.camera import look_at_scene
from service.image_io import encode_png


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--out", default=str(RESULTS_DIR / "thumbnails"))
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    gl = create_gl_context()
    gp = GBufferPass(gl)
    for name in BUILTIN_NAMES:
        scene = make_builtin(name)
        sg = SceneGPU(gl, scene)
        cam = look_at_scene(scene.bounds, azimuth=30.0, elevation=30.0, distance=0.9, width=args.res, height=args.res)
        (out / f"{name}.png").write_bytes(encode_png(gp.render(sg, cam).color))
        print(f"{name}: {scene.n_triangles:,} triangles -> {out / (name + '.png')}")
        sg.release()
    gp.release()
    gl.release()


if __name__ == "__main__":
    main()

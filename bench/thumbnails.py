"""Render a thumbnail of every built-in scene (local shading, GL G-buffer) for the README.

    .venv/bin/python bench/thumbnails.py [--res 256]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import RESULTS_DIR  # noqa: E402
from gl_passes.context import create_gl_context  # noqa: E402
from gl_passes.gbuffer import GBufferPass  # noqa: E402
from gl_passes.upload import SceneGPU  # noqa: E402
from scenes.builtin import BUILTIN_NAMES, make_builtin  # noqa: E402
from scenes.camera import look_at_scene  # noqa: E402
from service.image_io import encode_png  # noqa: E402


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

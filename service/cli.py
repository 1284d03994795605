"""The ``depthview`` command line (also ``python -m service``).

    depthview serve  [--host H] [--port P] [--data-dir DIR] [--gl-backend egl|osmesa]
    depthview render --scene NAME|FILE [--eye X Y Z] [--target X Y Z] [--up X Y Z] [--fov DEG]
                     [--width W] [--height H] [--detail D] [--seed S] OUTPUT.png|OUTPUT.exr
    depthview scenes [--detail D]

``render`` renders in-process on its own GL context (no server needed). Without
``--eye`` the camera orbits the scene bounds (``--azimuth``, ``--elevation``,
``--distance``) around ``--target``, by default the bounds' centre.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from service.config import Settings

#: Seconds an idle keep-alive connection stays open (uvicorn's timeout_keep_alive).
KEEP_ALIVE_S = 5
#: Seconds a stopping service (SIGTERM, Ctrl-C) waits for requests in flight before it cancels
#: them and shuts down (uvicorn's timeout_graceful_shutdown; it waited indefinitely): less than
#: the 10 s after which `docker stop` kills the container.
GRACEFUL_SHUTDOWN_S = 5


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="depthview", description="Headless depth-image rendering service.")
    p.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("serve", help="run the HTTP service (uvicorn)")
    s.add_argument("--host", default=None, help="bind address (default 127.0.0.1 or DEPTHVIEW_HOST)")
    s.add_argument("--port", type=_port, default=None, help="port (default 8000 or DEPTHVIEW_PORT)")
    s.add_argument("--data-dir", type=Path, default=None,
                   help="scene store directory (default ./data or DEPTHVIEW_DATA_DIR)")
    s.add_argument("--gl-backend", choices=("egl", "osmesa"), default=None,
                   help="GL backend (default: DEPTHVIEW_GL, else EGL with OSMesa fallback)")
    s.add_argument("--log-level", default="info", choices=("critical", "error", "warning", "info", "debug"))

    r = sub.add_parser("render", help="render one frame to a PNG or EXR file (in-process)")
    r.add_argument("--scene", required=True, help="built-in scene name or a .glb/.gltf/.obj/.ply file")
    r.add_argument("--eye", type=float, nargs=3, metavar=("X", "Y", "Z"), help="camera position")
    r.add_argument("--target", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="look-at point, also the orbit's centre without --eye (default: the scene's centre)")
    r.add_argument("--up", type=float, nargs=3, metavar=("X", "Y", "Z"), default=(0.0, 1.0, 0.0))
    r.add_argument("--fov", type=float, default=45.0, help="vertical field of view in degrees")
    r.add_argument("--width", type=int, default=512)
    r.add_argument("--height", type=int, default=512)
    r.add_argument("--azimuth", type=float, default=35.0, help="orbit azimuth (deg) when --eye is not given")
    r.add_argument("--elevation", type=float, default=25.0, help="orbit elevation (deg) when --eye is not given")
    r.add_argument("--distance", type=float, default=1.6, help="orbit distance (× bounds diagonal)")
    r.add_argument("--detail", type=float, default=1.0, help="built-in scene detail")
    r.add_argument("--seed", type=int, default=0, help="built-in scene seed")
    r.add_argument("--no-cull", action="store_true", help="disable back-face culling")
    r.add_argument("--gl-backend", choices=("egl", "osmesa"), default=None)
    r.add_argument("output", type=Path, help="output file: .png (sRGB) or .exr (RGB, Z, N, id, object)")

    c = sub.add_parser("scenes", help="list the built-in scenes with their triangle counts")
    c.add_argument("--detail", type=float, default=None, help="show the triangle estimate at this detail")
    return p


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("depthview")
    except PackageNotFoundError:  # run from a checkout without installing
        return "(not installed)"


def _port(text: str) -> int:
    """An argparse type: a TCP port number 0–65535."""
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid port {text[:20]!r}: not a whole number") from None
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"port {port} is not in 0-65535")
    return port


def _load_scene(spec: str, detail: float, seed: int):  # -> Scene
    from scenes import builtin

    if spec in builtin.BUILTIN_NAMES:
        return builtin.make_builtin(spec, detail=detail, seed=seed)
    path = Path(spec)
    if not path.is_file():
        raise ValueError(f"--scene {spec!r} is neither a built-in ({', '.join(builtin.BUILTIN_NAMES)}) nor a file")
    from scenes.loaders import load_scene

    return load_scene(path)


def cmd_render(args: argparse.Namespace) -> int:
    from gl_passes.context import create_gl_context
    from gl_passes.gbuffer import GBufferPass
    from gl_passes.upload import SceneGPU
    from scenes.camera import Camera, CameraError, look_at_scene
    from service.worker import encode_frame

    fmt = args.output.suffix.lower().lstrip(".")
    if fmt not in ("png", "exr"):
        raise ValueError(f"output must end in .png or .exr, got {args.output.name!r}")
    problem = Settings.from_env().size_problem(args.width, args.height)
    if problem is not None:  # the service's limits (the GL framebuffer fails past them)
        raise ValueError(f"{problem} (DEPTHVIEW_MAX_WIDTH, _HEIGHT, _PIXELS)")
    scene = _load_scene(args.scene, args.detail, args.seed)
    target = tuple(args.target) if args.target is not None else tuple(float(x) for x in scene.center)
    if args.eye is not None:
        camera = Camera(tuple(args.eye), target, tuple(args.up), args.fov, args.width, args.height)
        camera = camera.fit_clip(scene.bounds)
    else:  # orbit the target
        try:
            camera = look_at_scene(scene.bounds, args.azimuth, args.elevation, args.distance, args.fov,
                                   args.width, args.height, target=target, up=tuple(args.up))
        except CameraError as exc:
            if "parallel" not in str(exc):
                raise
            raise CameraError(f"{exc}: at --elevation {args.elevation:g} the orbit looks along --up; "
                              "give another --up") from None
    gl = create_gl_context(args.gl_backend)
    gpu = gp = None
    try:
        gpu = SceneGPU(gl, scene)
        gp = GBufferPass(gl)
        gbuf = gp.render(gpu, camera, cull_back_faces=not args.no_cull)
    finally:
        for obj in (gp, gpu):
            if obj is not None:
                obj.release()
        gl.release()
    data = encode_frame(gbuf, fmt)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_bytes(data)
    covered = int(np.count_nonzero(gbuf.tri_id))
    print(f"{args.output}: {camera.width}x{camera.height} {fmt}, {scene.n_triangles} triangles, "
          f"{covered} pixels covered ({gl.renderer}, {gl.backend})")
    if covered == 0:
        print("depthview render: warning: no pixel shows the scene; the camera looks away from it, or sees only "
              "back faces of one-sided surfaces" + ("" if args.no_cull else " (try --no-cull)"), file=sys.stderr)
    return 0


def cmd_scenes(args: argparse.Namespace) -> int:
    from scenes import builtin
    from service.store import builtin_description

    if args.detail is None:  # exact counts at detail 1 (builds each scene once)
        rows = [(i["name"], int(i["default_triangles"]), i.get("description") or "") for i in builtin.builtin_info()]
    else:  # closed-form estimates, nothing is built
        rows = [(n, int(builtin.estimate_triangles(n, args.detail)), builtin_description(n) or "")
                for n in builtin.BUILTIN_NAMES]
    width = max(len(r[0]) for r in rows) if rows else 4
    head = "triangles" if args.detail is None else f"tris@{args.detail:g}"
    print(f"{'name':<{width}}  {head:>11}  description")
    for name, tris, desc in rows:
        print(f"{name:<{width}}  {tris:>11,}  {desc}")
    return 0


def serve_settings(args: argparse.Namespace, environ: Mapping[str, str] | None = None) -> Settings:
    """Settings of ``depthview serve``: DEPTHVIEW_* variables, overridden by the options given."""
    return Settings.from_env(environ, host=args.host, port=args.port, data_dir=args.data_dir,
                             gl_backend=args.gl_backend)


def ws_max_size(settings: Settings) -> int:
    """Largest WebSocket message the server reads whole: a camera message past
    STREAM_MAX_MESSAGE_BYTES but within MAX_JSON_BYTES gets the stream's 413 error
    message (the stream goes on); a larger one closes the stream (1009)."""
    return max(settings.max_json_bytes, settings.stream_max_message_bytes)


def server_config(settings: Settings, log_level: str = "info") -> Any:
    """The uvicorn configuration of the service: one process (GL contexts live in the
    render worker processes, or on the app's render worker thread with WORKERS=0), the
    h11 protocol with a header read timeout, uvicorn's keep-alive timeout for idle
    connections, a bounded graceful shutdown, and WebSocket messages of at most
    `ws_max_size` (a stream's larger message closes it with 1009; uvicorn's own cap is
    16 MiB)."""
    import uvicorn

    from service.app import create_app
    from service.middleware import header_timeout_protocol

    return uvicorn.Config(create_app(settings), host=settings.host, port=settings.port, log_level=log_level,
                          workers=1, http=header_timeout_protocol(settings.header_timeout_s),
                          ws_max_size=ws_max_size(settings),
                          timeout_keep_alive=KEEP_ALIVE_S, timeout_graceful_shutdown=GRACEFUL_SHUTDOWN_S)


def cmd_serve(args: argparse.Namespace) -> int:
    import uvicorn

    settings = serve_settings(args)
    if settings.data_dir.exists() and not settings.data_dir.is_dir():
        raise ValueError(f"data directory {settings.data_dir} is a file, not a directory")
    uvicorn.Server(server_config(settings, args.log_level)).run()
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``depthview`` console script."""
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.command == "serve" else logging.WARNING,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    handlers = {"serve": cmd_serve, "render": cmd_render, "scenes": cmd_scenes}
    try:
        return handlers[args.command](args)
    except (ValueError, OSError) as exc:  # CameraError, SceneLoadError, bad paths
        print(f"depthview {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())

"""Smoke test of a running depthview service (``make docker-test`` runs it inside the CPU
image, against the image's own ``depthview serve``): readiness, a built-in scene, a PNG
frame, a reflective streamed frame, the thin-client page and a three.js module, the
API docs with their Swagger UI script, the metrics. Standard library and the service's
own dependencies only (Pillow, websockets), so it runs with the image's venv python.
Exit status 0 when every check passes.

    python docker/smoke.py [--url http://127.0.0.1:8000] [--ready-timeout 180]
"""

from __future__ import annotations

import argparse
import asyncio
import io
import json
import sys
import time
import urllib.error
import urllib.request
from typing import Any


def http(url: str, body: dict | None = None, timeout: float = 120.0) -> tuple[int, str, bytes]:
    """(status, content type, body) of a GET, or of a JSON POST when `body` is given."""
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, headers={"content-type": "application/json"} if data else {})
    try:
        with urllib.request.urlopen(req, timeout=timeout) as r:
            return r.status, r.headers.get("content-type", ""), r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.headers.get("content-type", ""), exc.read()


def upload(url: str, data: bytes, timeout: float = 120.0) -> tuple[int, bytes]:
    """(status, body) of a raw scene upload."""
    req = urllib.request.Request(url, data=data, headers={"content-type": "application/octet-stream"})
    try:
        with urllib.request.urlopen(req, timeout=timeout) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


#: A unit quad as OBJ: uploads are parsed by a child of the service's fork server.
QUAD_OBJ = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n"


def check(ok: bool, what: str) -> None:
    print(("ok   " if ok else "FAIL ") + what, flush=True)
    if not ok:
        raise SystemExit(1)


def wait_ready(base: str, timeout: float) -> dict[str, Any]:
    t0, last = time.monotonic(), "no answer"
    while time.monotonic() - t0 < timeout:
        try:
            status, _, body = http(base + "/readyz", timeout=5)
            if status == 200:
                return json.loads(body)
            last = f"{status} {body[:200]!r}"
        except OSError as exc:  # not listening yet
            last = str(exc)
        time.sleep(0.5)
    check(False, f"/readyz answered 200 within {timeout:g} s (last: {last})")
    raise AssertionError  # unreachable


def image_stats(data: bytes, fmt: str) -> tuple[tuple[int, int], int]:
    """(size, number of distinct colours) of an encoded image, checking its format."""
    from PIL import Image

    im = Image.open(io.BytesIO(data))
    check(im.format == fmt, f"the image decodes as {fmt} (got {im.format})")
    return im.size, len(im.convert("RGB").getcolors(maxcolors=im.width * im.height))


async def stream_frame(base: str, scene_id: str, camera: dict) -> tuple[dict, bytes]:
    """One reflective frame from the WebSocket stream: (its stats message, the image)."""
    import websockets

    url = base.replace("http://", "ws://", 1) + f"/scenes/{scene_id}/stream"
    async with websockets.connect(url, max_size=None) as ws:
        hello = json.loads(await asyncio.wait_for(ws.recv(), 30))
        check(hello.get("type") == "hello" and "view" in hello, "the stream says hello with a view")
        await ws.send(json.dumps({"id": 1, "camera": camera, "width": 96, "height": 96,
                                  "effects": {"reflections": "cluster"}}))
        while True:
            msg = json.loads(await asyncio.wait_for(ws.recv(), 120))
            check(msg.get("type") == "frame", f"a frame message: {str(msg)[:300]}")
            image = await asyncio.wait_for(ws.recv(), 30)
            if msg.get("id") == 1:
                return msg, image


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--url", default="http://127.0.0.1:8000")
    p.add_argument("--ready-timeout", type=float, default=180.0)
    args = p.parse_args(argv)
    base = args.url.rstrip("/")

    ready = wait_ready(base, args.ready_timeout)
    check(ready["ready"] and bool(ready.get("renderer")),
          f"/readyz: ready on {ready.get('renderer')} ({ready.get('backend')}, GL {ready.get('gl_version')})")

    status, ctype, body = http(base + "/scenes", {"builtin": "cornell"})
    check(status in (200, 201) and ctype.startswith("application/json"), f"POST /scenes cornell → {status}")
    scene = json.loads(body)
    check(len(scene["id"]) == 64 and scene["builtin"] == "cornell", f"scene id {scene['id'][:12]}…")

    camera = {"eye": [0, 1, 3.5], "target": [0, 1, 0]}
    t0 = time.perf_counter()
    status, ctype, png = http(base + f"/scenes/{scene['id']}/frames",
                              {"camera": camera, "width": 160, "height": 120})
    check(status == 200 and ctype == "image/png", f"POST /frames → {status} {ctype}, {len(png)} bytes "
                                                  f"in {time.perf_counter() - t0:.2f} s")
    check(png[:8] == b"\x89PNG\r\n\x1a\n", "the frame starts with the PNG signature")
    size, colours = image_stats(png, "PNG")
    check(size == (160, 120) and colours > 50, f"the frame is 160×120 with {colours} colours (a rendered scene)")

    status, body = upload(base + "/scenes?format=obj&name=quad", QUAD_OBJ)
    check(status in (200, 201) and json.loads(body)["triangles"] == 2,
          f"POST /scenes of an OBJ → {status} (parsed in a child process, stored in the volume)")

    status, _, body = http(base + "/scenes", {"builtin": "mirror"})
    check(status in (200, 201), f"POST /scenes mirror → {status}")
    mirror = json.loads(body)["id"]
    stats, image = asyncio.run(stream_frame(base, mirror, {"eye": [2.5, 1.6, 3], "target": [0, 0.9, -0.5]}))
    size, colours = image_stats(image, stats["format"].upper())
    check(len(image) == stats["bytes"] and size == (96, 96) and colours > 50,
          f"a streamed reflective frame: {stats['format']} 96×96, {colours} colours, "
          f"render {stats['render_ms']:.0f} ms")

    status, ctype, page = http(base + "/client")
    check(status == 200 and ctype.startswith("text/html") and b"/client/three/build/three.module.js" in page,
          "GET /client serves the page with its three.js import map")
    status, ctype, js = http(base + "/client/static/client.js")
    check(status == 200 and ctype.startswith("text/javascript"), f"GET /client/static/client.js → {status}")
    for module in ("build/three.module.js", "examples/jsm/controls/OrbitControls.js"):
        status, ctype, js = http(base + "/client/three/" + module)
        check(status == 200 and ctype.startswith("text/javascript") and len(js) > 1000,
              f"GET /client/three/{module} → {status}, {len(js)} bytes (three.js from npm ci)")

    status, ctype, page = http(base + "/docs")
    check(status == 200 and ctype.startswith("text/html") and b"/docs/static/swagger-ui-bundle.js" in page,
          "GET /docs serves Swagger UI's page from this host")
    status, ctype, js = http(base + "/docs/static/swagger-ui-bundle.js")
    check(status == 200 and ctype.startswith("text/javascript") and len(js) > 100_000,
          f"GET /docs/static/swagger-ui-bundle.js → {status}, {len(js)} bytes (swagger-ui-dist from npm ci)")

    status, _, text = http(base + "/metrics")
    streamed = [float(line.split()[1]) for line in text.decode().splitlines()
                if line.startswith("depthview_frames_streamed_total ")]
    check(status == 200 and streamed and streamed[0] >= 1, f"GET /metrics counts the streamed frames: {streamed}")
    print("smoke test passed", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

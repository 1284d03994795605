"""HTTP service (service/app.py + worker + store) through FastAPI's TestClient.

Images are tiny (≤ 64×64) to keep the file fast on a software rasteriser."""

from __future__ import annotations

import hashlib
import json
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from gl_passes.upload import SceneGPU
from scenes.builtin import BUILTIN_NAMES, make_builtin
from scenes.camera import Camera
from service import image_io, jobs
from service.config import Settings
from service.store import builtin_id
from service.worker import JobExpired, RenderWorker, WorkerUnavailable
from tests.helpers import (
    ROOT,
    assert_images_equal,
    frame_camera,
    obj_text,
    service,
    service_client,
    shared_scene,
    sphere_on_slab,
    wait_ready,
    wait_until,
)

FRAME_SCENE = "cornell"  # small built-in used for frames
W, H = 48, 32


# --- helpers ---------------------------------------------------------------------------
def frame(client: TestClient, sid: str, camera: dict | None = None, **body) -> object:
    payload = {"camera": camera or frame_camera(FRAME_SCENE), "width": W, "height": H, **body}
    return client.post(f"/scenes/{sid}/frames", json=payload)


def post_raw_json(client: TestClient, url: str, text: str) -> object:
    return client.post(url, content=text.encode(), headers={"content-type": "application/json"})


def details(r) -> str:
    return json.dumps(r.json())


client = service_client()


@pytest.fixture(scope="module")
def cornell_id(client) -> str:
    return builtin_id(FRAME_SCENE)


# --- health, docs, listing ---------------------------------------------------------------
def test_healthz_and_readyz(client):
    assert client.get("/healthz").json() == {"status": "ok"}
    r = client.get("/readyz")
    assert r.status_code == 200
    body = r.json()
    assert body["ready"] is True and body["renderer"] and body["backend"] in ("egl", "osmesa")
    assert isinstance(body["software"], bool) and body["error"] is None


def test_readyz_is_503_until_the_gl_context_exists(tmp_path, monkeypatch):
    import service.worker as worker_mod

    gate = threading.Event()
    real = worker_mod.create_gl_context

    def slow_context(backend=None, device=None):
        assert gate.wait(10)
        return real(backend, device)

    monkeypatch.setattr(worker_mod, "create_gl_context", slow_context)
    with service(tmp_path, ready=False) as c:
        assert c.get("/healthz").status_code == 200
        r = c.get("/readyz")
        assert r.status_code == 503 and r.json()["ready"] is False
        assert "no render worker is ready yet" in r.json()["error"]
        gate.set()
        assert wait_ready(c)["ready"] is True
        # the probe's 503 is its answer, not an error of the service; other refusals there are
        assert c.post("/readyz").status_code == 405
        metrics = c.get("/metrics").text
        assert 'depthview_http_errors_total{class="4xx"} 1' in metrics
        assert re.search(r'depthview_responses_total\{method="GET",route="/readyz",status="503"\} [1-9]', metrics)
        assert 'depthview_http_errors_total{class="5xx"} 0' in metrics


def test_gl_failure_makes_readyz_and_frames_503(tmp_path, monkeypatch):
    import service.worker as worker_mod

    def broken(backend=None, device=None):
        raise RuntimeError("no GPU here")

    monkeypatch.setattr(worker_mod, "create_gl_context", broken)
    with service(tmp_path, ready=False) as c:
        assert c.app.state.worker.wait_ready(5) is False
        r = c.get("/readyz")
        assert r.status_code == 503 and "no GPU here" in r.json()["error"]
        r = frame(c, builtin_id(FRAME_SCENE))
        assert r.status_code == 503 and "Retry-After" in r.headers


def test_openapi_docs(client):
    spec = client.get("/openapi.json").json()
    for path in ("/scenes", "/scenes/{scene_id}", "/scenes/{scene_id}/frames", "/healthz", "/readyz", "/metrics"):
        assert path in spec["paths"]
    assert "BuiltinSceneRequest" in spec["components"]["schemas"]
    assert "FrameRequest" in spec["components"]["schemas"]
    busy = spec["paths"]["/scenes/{scene_id}/frames"]["post"]["responses"]["503"]
    assert busy["headers"]["Retry-After"]["schema"] == {"type": "integer"}
    page = client.get("/docs")
    assert page.status_code == 200 and "/openapi.json" in page.text
    # Swagger UI comes from this host (npm's swagger-ui-dist), not a CDN: the page works offline
    assert "cdn." not in page.text and "//" not in page.text.replace("http://www.w3.org", "")
    for name, ctype in (("swagger-ui-bundle.js", "text/javascript"), ("swagger-ui.css", "text/css")):
        assert f'/docs/static/{name}' in page.text
        r = client.get(f"/docs/static/{name}")
        assert r.status_code == 200 and r.headers["content-type"].startswith(ctype) and len(r.content) > 10_000
    assert client.get("/docs/static/package.json").status_code == 404  # only the page's files


def test_list_includes_every_builtin(client):
    r = client.get("/scenes")
    assert r.status_code == 200
    scenes = r.json()["scenes"]
    defaults = {s["name"]: s for s in scenes if s["default"]}
    assert set(defaults) == set(BUILTIN_NAMES)
    for name, s in defaults.items():
        assert s["id"] == builtin_id(name) and s["kind"] == "builtin" and s["triangles"] > 0
        assert client.get(f"/scenes/{s['id']}").json()["name"] == name


def test_builtin_ids_are_stable(client):
    r = client.post("/scenes", json={"builtin": FRAME_SCENE})
    assert r.status_code == 200 and r.json()["id"] == builtin_id(FRAME_SCENE) and r.json()["default"]
    r2 = client.post("/scenes", json={"builtin": FRAME_SCENE, "params": {"detail": 1, "seed": 0}})
    assert r2.json()["id"] == r.json()["id"]
    r3 = client.post("/scenes", json={"builtin": "nest", "params": {"detail": 0.05, "seed": 7}})
    assert r3.status_code == 201 and r3.json()["id"] not in (r.json()["id"], builtin_id("nest"))
    assert r3.headers["location"] == f"/scenes/{r3.json()['id']}"
    r4 = client.post("/scenes", json={"params": {"seed": 7, "detail": 0.05}, "builtin": "nest"})
    assert r4.status_code == 200 and r4.json()["id"] == r3.json()["id"]
    r5 = client.post("/scenes", json={"builtin": "nest", "params": {"detail": 0.05, "seed": 8}})
    assert r5.json()["id"] != r3.json()["id"]
    assert r3.json()["id"] in {s["id"] for s in client.get("/scenes").json()["scenes"]}


@pytest.mark.parametrize("body, needle", [
    ({"builtin": "no_such_scene"}, "unknown built-in"),
    ({"builtin": "nest", "params": {"detail": 0}}, "detail"),
    ({"builtin": "nest", "params": {"detail": 1000}}, "detail"),
    ({"builtin": "nest", "params": {"seed": -1}}, "seed"),
    ({"builtin": "nest", "params": {"colour": 1}}, "colour"),
    ({"name": "nest"}, "builtin"),
])
def test_bad_builtin_requests(client, body, needle):
    r = client.post("/scenes", json=body)
    assert r.status_code == 422 and needle in details(r)


def test_bad_json_body_is_400(client):
    r = post_raw_json(client, "/scenes", "{not json")
    assert r.status_code == 400


# --- frames --------------------------------------------------------------------------------
def test_png_frame_matches_a_direct_gbuffer_render(client, cornell_id, gl, gbuffer_pass):
    cam = frame_camera()
    r = frame(client, cornell_id, cam)
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "image/png"
    img = image_io.decode_png(r.content)
    assert img.shape == (H, W, 3)
    assert img.std() > 5 and len(np.unique(img.reshape(-1, 3), axis=0)) > 20  # geometry, not a flat image
    # The same camera rendered directly with the G-buffer pass on the test's own context.
    scene = make_builtin(FRAME_SCENE)
    camera = Camera(tuple(cam["eye"]), tuple(cam["target"]), tuple(cam["up"]), cam["fov"], W, H)
    camera = camera.fit_clip(scene.bounds)
    with SceneGPU(gl, scene) as gpu:
        gb = gbuffer_pass.render(gpu, camera)
    assert (gb.tri_id > 0).mean() > 0.2
    assert_images_equal(img, image_io.decode_png(image_io.encode_png(gb.color)))
    assert image_io.encode_png(gb.color) == r.content  # and the very bytes


def test_mirror_frame_has_geometry(client):
    r = frame(client, builtin_id("mirror"), frame_camera("mirror"))
    assert r.status_code == 200, r.text
    img = image_io.decode_png(r.content)
    assert img.shape == (H, W, 3) and img.std() > 5


def test_exr_frame_has_all_channels(client, cornell_id):
    r = frame(client, cornell_id, format="exr")
    assert r.status_code == 200 and r.headers["content-type"] == "image/x-exr"
    ch = image_io.decode_exr(r.content)
    assert set(ch) >= {"RGB", "Z", "N", "id", "object"}
    assert ch["RGB"].shape == (H, W, 3) and ch["N"].shape == (H, W, 3)
    assert ch["Z"].shape == ch["id"].shape == ch["object"].shape == (H, W)
    hit = ch["id"] > 0
    assert hit.any() and np.all(np.isfinite(ch["Z"][hit])) and np.all(ch["Z"][hit] > 0)
    assert np.all(np.isinf(ch["Z"][~hit])) and np.all(ch["object"][~hit] == 0)
    n = np.linalg.norm(ch["N"][hit], axis=-1)
    assert np.allclose(n, 1.0, atol=1e-3)
    n_tris = make_builtin(FRAME_SCENE).n_triangles
    assert int(ch["id"].max()) <= n_tris
    # PNG and EXR describe the same frame.
    png = image_io.decode_png(frame(client, cornell_id).content)
    assert_images_equal(png, image_io.decode_png(image_io.encode_png(ch["RGB"])))


# --- uploads ----------------------------------------------------------------------------------
def test_an_upload_is_hashed_once(client, monkeypatch):
    """The route's stored-content lookup and the store share one hash of the body."""
    import service.store

    hashed = []
    real = service.store.upload_id
    monkeypatch.setattr(service.store, "upload_id", lambda fmt, data: hashed.append(len(data)) or real(fmt, data))
    data = obj_text(3, z=0.125)  # content no other test uploads
    for status in (201, 200):  # new, then stored before
        hashed.clear()
        r = client.post("/scenes", files={"file": ("hashed.obj", data, "text/plain")})
        assert r.status_code == status and hashed == [len(data)], (r.status_code, hashed)


def test_upload_obj_is_content_addressed(client):
    data = obj_text(1)
    expected = hashlib.sha256(b"obj\n" + data).hexdigest()
    r = client.post("/scenes", files={"file": ("quad.obj", data, "text/plain")})
    assert r.status_code == 201, r.text
    info = r.json()
    assert info["id"] == expected and info["kind"] == "upload" and info["format"] == "obj"
    assert info["triangles"] == 2 and info["name"] == "quad" and info["size_bytes"] == len(data)
    again = client.post("/scenes", files={"file": ("other-name.obj", data)})
    assert again.status_code == 200 and again.json()["id"] == expected
    raw = client.post("/scenes?format=obj", content=data, headers={"content-type": "application/octet-stream"})
    assert raw.status_code == 200 and raw.json()["id"] == expected
    by_field = client.post("/scenes", files={"file": ("noext", data)}, data={"format": "obj"})
    assert by_field.status_code == 200 and by_field.json()["id"] == expected
    assert client.get(f"/scenes/{expected}").json()["triangles"] == 2
    assert expected in {s["id"] for s in client.get("/scenes").json()["scenes"]}
    # Render it: the quad spans x, y in [0, 1] at z = 0, facing +z.
    cam = {"eye": [0.5, 0.5, 2.0], "target": [0.5, 0.5, 0.0]}
    ch = image_io.decode_exr(frame(client, expected, cam, format="exr").content)
    assert ch["id"][H // 2, W // 2] in (1, 2) and ch["id"][0, 0] == 0
    assert np.isclose(ch["Z"][H // 2, W // 2], 2.0, rtol=1e-3)


def test_delete_then_get_is_404(client):
    data = obj_text(2)
    sid = client.post("/scenes", files={"file": ("two.obj", data)}).json()["id"]
    assert frame(client, sid, {"eye": [1, 0.5, 3], "target": [1, 0.5, 0]}).status_code == 200
    assert client.delete(f"/scenes/{sid}").status_code == 204
    assert client.get(f"/scenes/{sid}").status_code == 404
    assert frame(client, sid, {"eye": [1, 0.5, 3], "target": [1, 0.5, 0]}).status_code == 404
    assert client.delete(f"/scenes/{sid}").status_code == 404
    assert sid not in {s["id"] for s in client.get("/scenes").json()["scenes"]}
    r = client.delete(f"/scenes/{builtin_id(FRAME_SCENE)}")
    assert r.status_code == 409 and "cannot be deleted" in r.json()["detail"]
    # The same content can come back under the same id.
    assert client.post("/scenes", files={"file": ("two.obj", data)}).json()["id"] == sid


@pytest.mark.parametrize("filename, content, fields, status, needle", [
    ("broken.obj", b"v 0 0 0\nf 1 2 3\n", {}, 422, "OBJ"),
    ("broken.glb", b"glTF\x02\x00\x00\x00garbage", {}, 422, "malformed GLB"),
    ("empty.ply", b"", {}, 422, "empty"),
    ("model.stl", b"solid x\nendsolid x\n", {}, 415, "unsupported scene format 'stl'"),
    ("model", b"v 0 0 0\n", {}, 415, "cannot tell the scene format"),
    ("model.obj", b"v 0 0 0\n", {"format": "fbx"}, 415, "fbx"),
    ("model.obj", b"v 0 0 0\n", {"format": "e$A#\u0089"}, 415, "unsupported scene format"),  # not ASCII: not a 500
])
def test_bad_uploads(client, filename, content, fields, status, needle):
    r = client.post("/scenes", files={"file": (filename, content)}, data=fields)
    assert r.status_code == status, r.text
    assert needle in r.json()["detail"]


def test_upload_without_file_field_or_with_bad_content_type(client):
    r = client.post("/scenes", files={"other": ("a.obj", obj_text())})
    assert r.status_code == 422 and "'file'" in r.json()["detail"]
    r = client.post("/scenes", content=b"hello", headers={"content-type": "text/plain"})
    assert r.status_code == 415
    r = client.post("/scenes", content=b"garbage", headers={"content-type": "multipart/form-data; boundary=x"})
    assert r.status_code == 400 and "malformed multipart" in r.json()["detail"]
    r = client.post("/scenes", content=obj_text(), headers={"content-type": "application/octet-stream"})
    assert r.status_code == 415 and "format" in r.json()["detail"]


def test_multipart_errors_say_what_python_multipart_found(client):
    """Starlette reports every parser error as "Invalid multipart data."; the 400 names the cause."""
    r = client.post("/scenes", files={"file": ("a" * 5000 + ".obj", obj_text())})
    assert r.status_code == 400
    assert "header size exceeded (a part's header line, its file name included, may be at most 4,224 bytes)" \
        in r.json()["detail"]
    r = client.post("/scenes", files={"file": ("b" * 4000 + ".obj", obj_text(z=0.125))})  # content of its own
    assert r.status_code == 201 and r.json()["name"] == "b" * 200  # a long name is fine, cut to 200
    r = client.post("/scenes", content=b"--x\r\nno header end",
                    headers={"content-type": "multipart/form-data; boundary=x"})
    assert r.status_code == 400 and r.json()["detail"] != "malformed multipart body: Invalid multipart data."


# --- bad frame requests ------------------------------------------------------------------------
def test_unknown_and_malformed_scene_ids(client):
    unknown = "0" * 64
    assert client.get(f"/scenes/{unknown}").status_code == 404
    assert frame(client, unknown).status_code == 404
    for bad in ("abc", "A" * 64, "g" * 64, "..%2F..%2Fetc", "0" * 65):
        assert client.get(f"/scenes/{bad}").status_code == 404
        assert frame(client, bad).status_code == 404
        assert client.delete(f"/scenes/{bad}").status_code == 404


@pytest.mark.parametrize("camera_text, loc, needle", [
    ('{"eye": [NaN, 1, 3], "target": [0, 1, 0]}', ["body", "camera", "eye"], "finite"),
    ('{"eye": [0, 1, 3], "target": [0, Infinity, 0]}', ["body", "camera", "target"], "finite"),
    ('{"eye": [0, 1, 3], "target": [0, 1, 0], "up": [0, -Infinity, 0]}', ["body", "camera", "up"], "finite"),
    ('{"eye": [0, 1, 3], "target": [0, 1, 0], "fov": NaN}', ["body", "camera", "fov"], "finite"),
    ('{"eye": [0, 1, 3], "target": [0, 1, 3]}', ["body", "camera"], "eye and target coincide"),
    ('{"eye": [0, 1, 3], "target": [0, 1, 0], "up": [0, 0, 0]}', ["body", "camera"], "up vector is zero"),
    ('{"eye": [0, 1, 3], "target": [0, 1, 0], "up": [0, 0, 2]}', ["body", "camera"], "parallel"),
    ('{"eye": [0, 1, 3], "target": [0, 1, 0], "fov": 180}', ["body", "camera", "fov"], "180"),
    ('{"eye": [0, 1], "target": [0, 1, 0]}', ["body", "camera", "eye", 2], "Field required"),
])
def test_bad_cameras_are_422_naming_the_problem(client, cornell_id, camera_text, loc, needle):
    body = '{"camera": ' + camera_text + ', "width": 32, "height": 32}'
    r = post_raw_json(client, f"/scenes/{cornell_id}/frames", body)
    assert r.status_code == 422, r.text
    errs = r.json()["detail"]
    assert any(e["loc"][:len(loc)] == loc and needle in e["msg"] for e in errs), errs


@pytest.mark.parametrize("extra, needle", [
    ({"width": 0}, "width"),
    ({"height": -3}, "height"),
    ({"width": 5000}, "width 5000 exceeds the limit 4096 (DEPTHVIEW_MAX_WIDTH)"),
    ({"height": 4097}, "height 4097 exceeds the limit 4096 (DEPTHVIEW_MAX_HEIGHT)"),
    ({"width": 1.5}, "width"),
    ({"format": "jpg"}, "format"),
    ({"effects": {"shadows": "pcss"}}, "shadows"),
    ({"effects": {"reflections": "ssr"}}, "reflections method 'ssr' is not available"),
    ({"effects": {"reflections": "cluster", "glossy_rays": 0}}, "glossy_rays"),
    ({"effects": {"reflections": "cluster", "glossy_rays": 65}}, "less than or equal to 64"),
    ({"effects": {"fog": "none"}}, "fog"),
    ({"colour": "red"}, "colour"),
])
def test_bad_frame_parameters(client, cornell_id, extra, needle):
    r = frame(client, cornell_id, **extra)
    assert r.status_code == 422, r.text
    assert needle in details(r)


def test_effects_none_is_accepted(client, cornell_id):
    r = frame(client, cornell_id, effects={"reflections": "none"})
    assert r.status_code == 200


# --- limits ----------------------------------------------------------------------------------------
def test_upload_and_triangle_and_size_limits(tmp_path):
    with service(tmp_path, max_upload_bytes=4096, max_triangles=50, max_width=64, max_height=64,
                 max_pixels=2048) as c:
        big = obj_text(200)  # ~12 KB
        assert len(big) > 4096
        r = c.post("/scenes", files={"file": ("big.obj", big)})
        assert r.status_code == 413 and "4096" in r.json()["detail"]
        r = c.post("/scenes?format=obj", content=big, headers={"content-type": "application/octet-stream"})
        assert r.status_code == 413
        # Streamed without Content-Length: cut off while reading.
        r = c.post("/scenes?format=obj", content=iter([big[:3000], big[3000:]]),
                   headers={"content-type": "application/octet-stream"})
        assert r.status_code == 413 and "DEPTHVIEW_MAX_UPLOAD_BYTES" in r.json()["detail"]
        huge = b"v 0 0 0\n" * 20000  # past the multipart allowance: refused from Content-Length
        r = c.post("/scenes", files={"file": ("huge.obj", huge)})
        assert r.status_code == 413
        # The same multipart body streamed without Content-Length: cut off while parsing.
        body = (b'--bnd\r\nContent-Disposition: form-data; name="file"; filename="huge.obj"\r\n\r\n'
                + huge + b"\r\n--bnd--\r\n")
        r = c.post("/scenes", content=(body[i:i + 8192] for i in range(0, len(body), 8192)),
                   headers={"content-type": "multipart/form-data; boundary=bnd"})
        assert r.status_code == 413 and "4096" in r.json()["detail"]
        # 26 quads = 52 triangles > 50, under 4096 bytes.
        tri = obj_text(26)
        assert len(tri) < 4096
        r = c.post("/scenes", files={"file": ("tri.obj", tri)})
        assert r.status_code == 422 and "52 triangles" in r.json()["detail"] and "50" in r.json()["detail"]
        r = c.post("/scenes", json={"builtin": "nest", "params": {"detail": 0.05}})
        assert r.status_code == 422 and "triangles" in r.json()["detail"] and "limit is 50" in r.json()["detail"]
        ok = c.post("/scenes", files={"file": ("ok.obj", obj_text(2))})
        assert ok.status_code == 201
        sid = ok.json()["id"]
        cam = {"eye": [1, 0.5, 3], "target": [1, 0.5, 0]}
        r = c.post(f"/scenes/{sid}/frames", json={"camera": cam, "width": 65, "height": 16})
        assert r.status_code == 422 and "width 65 exceeds the limit 64" in r.json()["detail"]
        r = c.post(f"/scenes/{sid}/frames", json={"camera": cam, "width": 64, "height": 64})
        assert r.status_code == 422 and "width × height 4096 exceeds the limit 2048" in r.json()["detail"]
        r = c.post(f"/scenes/{sid}/frames", json={"camera": cam, "width": 64, "height": 32})
        assert r.status_code == 200


def test_queue_full_is_503_and_timeout_is_504(tmp_path, cornell_id):
    with service(tmp_path, queue_size=1, job_timeout_s=1.0, retry_after_s=2) as c:
        worker: RenderWorker = c.app.state.worker
        started, release = threading.Event(), threading.Event()

        def blocking(state):
            started.set()
            assert release.wait(20)
            return "released"

        blocker = worker.submit(blocking, timeout=30)
        assert started.wait(10)
        try:
            t0 = time.monotonic()
            r = frame(c, cornell_id)  # queued behind the blocker, never started
            assert r.status_code == 504 and "1 s" in r.json()["detail"]
            assert 0.9 < time.monotonic() - t0 < 30  # it waited out the 1 s limit; above: a hang guard
            # The abandoned job still holds the only queue slot: the queue is full.
            r = frame(c, cornell_id)
            assert r.status_code == 503 and r.headers["retry-after"] == "2"
            assert "queue is full" in r.json()["detail"]
        finally:
            release.set()
        assert blocker.result(10) == "released"
        wait_until(lambda: not (worker.queue_depth or worker.busy), what="an idle worker")
        r = frame(c, cornell_id)  # the worker skipped the abandoned job and carries on
        assert r.status_code == 200
        text = c.get("/metrics").text
        assert 'depthview_jobs_total{outcome="rejected"} 1' in text
        assert 'depthview_jobs_total{outcome="expired"} 1' in text
        assert 'depthview_frame_errors_total{status="503"} 1' in text
        assert 'depthview_frame_errors_total{status="504"} 1' in text


#: The Embree render paths (no GL, or not only GL): url suffix and body.
EMBREE_PATHS = {
    "raytraced reflections": ("frames", {"camera": frame_camera(FRAME_SCENE), "width": W, "height": H,
                                         "effects": {"reflections": "raytrace", "glossy_rays": 1}}),
    "raytraced soft shadows": ("frames", {"camera": frame_camera(FRAME_SCENE), "width": W, "height": H,
                                          "effects": {"soft_shadows": {"samples": 2, "method": "raytrace"}}}),
    "visibility NR set": ("depth-images", {"width": 24, "height": 24, "method": "non_redundant",
                                           "redundancy": "visibility"}),
    "sampling metrics": ("depth-images", {"width": 24, "height": 24, "method": "non_redundant",
                                          "redundancy": "visibility", "metrics": True, "intermediate_views": 2}),
}


def test_embree_paths_are_queued_and_timed_like_gl_jobs(tmp_path, cornell_id, monkeypatch):
    """Every Embree path is one job on the worker thread: behind a busy worker it gets 504
    at the time limit, with the queue full 503 + Retry-After, and on a free worker 200
    (the limit leaves a loaded machine time for the small renders)."""
    with service(tmp_path, queue_size=1, job_timeout_s=2.5, retry_after_s=3) as c:
        worker: RenderWorker = c.app.state.worker
        for name, (suffix, body) in EMBREE_PATHS.items():
            started, release = threading.Event(), threading.Event()

            def blocking(state, started=started, release=release):
                started.set()
                assert release.wait(20)

            blocker = worker.submit(blocking, timeout=30)
            assert started.wait(10)
            try:
                r = c.post(f"/scenes/{cornell_id}/{suffix}", json=body)  # queued behind the blocker
                assert r.status_code == 504 and "2.5 s" in r.json()["detail"], (name, r.text)
                r = c.post(f"/scenes/{cornell_id}/{suffix}", json=body)  # the abandoned job holds the slot
                assert r.status_code == 503 and r.headers["retry-after"] == "3", (name, r.text)
            finally:
                release.set()
            blocker.result(10)
            wait_until(lambda: not (worker.queue_depth or worker.busy), what="an idle worker")
            done = worker.jobs_done
            r = c.post(f"/scenes/{cornell_id}/{suffix}", json=body)
            assert r.status_code == 200, (name, r.text)
            assert worker.jobs_done == done + 1, name  # the whole render was one job
        assert worker.job_thread_ids == {worker.thread_id}
        text = c.get("/metrics").text
        assert f'depthview_jobs_total{{outcome="rejected"}} {len(EMBREE_PATHS)}' in text
        assert f'depthview_jobs_total{{outcome="expired"}} {len(EMBREE_PATHS)}' in text

        # An Embree job that runs past the limit is 504 too (it was in the thread pool,
        # out of the timeout's reach, before): the answer comes while the job still runs.
        running, release, finished = threading.Event(), threading.Event(), threading.Event()

        def slow_raytrace(*args):
            running.set()
            try:
                release.wait(30)
                raise AssertionError("unused")
            finally:
                finished.set()

        monkeypatch.setattr(jobs, "raytrace_cached", slow_raytrace)
        suffix, body = EMBREE_PATHS["raytraced reflections"]
        t0 = time.monotonic()
        try:
            r = c.post(f"/scenes/{cornell_id}/{suffix}", json=body)
            assert r.status_code == 504 and "2.5 s" in r.json()["detail"], r.text
            assert running.is_set() and not finished.is_set()  # the limit ended the wait, not the job
        finally:
            release.set()
        assert time.monotonic() - t0 < 30  # hang guard only: the job waits up to 30 s for `release`


def test_jobs_are_picklable_specs_that_load_their_scene_by_address(client, cornell_id):
    """A job pickles without its scene (only the content address travels) and, on a
    worker, loads the scene from the store by that address."""
    import pickle

    from service.jobs import FrameJob

    scene = client.app.state.store.get_scene(cornell_id)
    cam = Camera(**frame_camera(FRAME_SCENE), width=W, height=H).fit_clip(scene.bounds)
    job = FrameJob(cornell_id, scene, cam)
    data = pickle.dumps(job)
    assert len(data) < 4096  # the camera and the address, not the geometry
    spec = pickle.loads(data)
    assert spec.scene is None and spec.scene_key == cornell_id and spec.camera == cam
    worker: RenderWorker = client.app.state.worker
    loaded, direct = worker.submit(spec).result(30), worker.submit(job).result(30)
    np.testing.assert_array_equal(loaded.color, direct.color)
    missing = FrameJob("0" * 64, None, cam)
    with pytest.raises(LookupError):
        worker.submit(missing).result(30)


def test_concurrent_frames_all_run_on_the_gl_thread(client, cornell_id):
    worker: RenderWorker = client.app.state.worker
    base = frame_camera()
    done_before = worker.jobs_done
    results: list[tuple[int, int, bytes]] = []
    errors: list[BaseException] = []

    def one(k: int) -> None:
        try:
            cam = dict(base, eye=[base["eye"][0] + 0.01 * k, base["eye"][1], base["eye"][2]])
            r = frame(client, cornell_id, cam, width=32, height=32)
            results.append((k, r.status_code, r.content))
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    threads = [threading.Thread(target=one, args=(k,)) for k in range(16)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert not errors and len(results) == 16
    assert all(status == 200 for _, status, _ in results)
    assert all(image_io.decode_png(body).shape == (32, 32, 3) for _, _, body in results)
    assert worker.jobs_done - done_before >= 16
    assert worker.job_thread_ids == {worker.thread_id}
    assert worker.thread_id != threading.get_ident()


def test_metrics_are_prometheus_text(client, cornell_id):
    assert frame(client, cornell_id).status_code == 200
    r = client.get("/metrics")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain")
    values = {}
    for line in r.text.splitlines():
        if line and not line.startswith("#"):
            name, value = line.rsplit(" ", 1)
            values[name] = float(value)
    assert values['depthview_jobs_total{outcome="done"}'] >= 1
    assert values['depthview_frames_total{format="png"}'] >= 1
    assert values["depthview_job_seconds_count"] >= 1 and values["depthview_job_seconds_sum"] > 0
    assert values["depthview_queue_capacity"] == 32 and values["depthview_ready"] == 1
    assert "# TYPE depthview_jobs_total counter" in r.text


#: One exposition-format sample line: name, optional labels with escaped values, a number.
_SAMPLE = re.compile(r'^[a-zA-Z_:][a-zA-Z0-9_:]*(\{[a-zA-Z_]\w*="(?:[^"\\\n]|\\[\\"n])*"'
                     r'(?:,[a-zA-Z_]\w*="(?:[^"\\\n]|\\[\\"n])*")*\})? [-+0-9.eEinfNa]+$')


def test_metrics_labels_cannot_be_injected_or_grow_without_bound(client):
    """Paths and methods come from clients: a redirected path (a trailing slash) with a
    quote, a backslash and a newline, and made-up methods, must neither break the
    exposition format nor add a series per request."""
    def routes() -> set[str]:
        return set(re.findall(r'route="((?:[^"\\]|\\.)*)"', client.get("/metrics").text))

    client.get("/scenes/warm/")
    client.request("BAR", "/scenes")  # 405: counted under /scenes
    routes()  # /metrics itself is counted after its first answer
    before = routes()
    for i in range(5):
        path = f"/scenes/x%22%7D%200%0Adepthview_ready%200%0Ainjected{i}%7Ba%3D%22%5C/"
        assert client.get(path, follow_redirects=False).status_code == 307
        client.request(f"FOO{i}", "/scenes")
    text = client.get("/metrics").text
    for line in text.splitlines():
        assert line.startswith("#") or _SAMPLE.match(line), line
    assert "injected" not in text and text.count("\ndepthview_ready 0") == 0
    assert [line for line in text.splitlines() if line.startswith("depthview_ready ")] == ["depthview_ready 1"]
    assert routes() == before  # the redirects and unknown methods added no route
    assert "FOO" not in text and 'method="other"' in text


def test_frame_errors_count_unknown_scenes_and_loader_errors(client, cornell_id):
    """A valid frame body for a scene that is not stored is a 404 from the store (not an
    HTTPException): counted among the frame errors like the 422s and 5xx."""
    def count(status: int) -> float:
        for line in client.get("/metrics").text.splitlines():
            if line.startswith(f'depthview_frame_errors_total{{status="{status}"}} '):
                return float(line.rsplit(" ", 1)[1])
        return 0.0

    before = count(404)
    body = {"camera": frame_camera(FRAME_SCENE), "width": W, "height": H}
    assert client.post(f"/scenes/{'0' * 64}/frames", json=body).status_code == 404
    assert client.post("/scenes/not-an-id/frames", json=body).status_code == 404
    assert count(404) == before + 2


# --- persistence ---------------------------------------------------------------------------------
def test_store_survives_restart_and_skips_corrupt_meta(tmp_path):
    data = obj_text(3)
    with service(tmp_path) as c:
        up = c.post("/scenes", files={"file": ("strip.obj", data)}).json()["id"]
        bi = c.post("/scenes", json={"builtin": "nest", "params": {"detail": 0.02, "seed": 3}}).json()["id"]
        doomed = c.post("/scenes", files={"file": ("doomed.obj", obj_text(4))}).json()["id"]
    (tmp_path / "scenes" / doomed / "meta.json").write_text("{corrupt")
    with service(tmp_path) as c:
        r = c.get("/scenes")
        assert r.status_code == 200
        ids = {s["id"] for s in r.json()["scenes"]}
        assert {up, bi} <= ids and doomed not in ids
        assert c.get(f"/scenes/{doomed}").status_code == 404
        assert c.get(f"/scenes/{up}").json()["name"] == "strip"
        r = frame(c, up, {"eye": [1.5, 0.5, 3], "target": [1.5, 0.5, 0]})
        assert r.status_code == 200
        assert frame(c, bi, {"eye": [0, 1.5, 2.5], "target": [0, 0.1, 0]}).status_code == 200


# --- the worker on its own ------------------------------------------------------------------------
def test_worker_delivers_exceptions_skips_expired_jobs_and_releases_gl(monkeypatch):
    import service.worker as worker_mod

    released = []

    class SpyGPU(SceneGPU):
        def release(self) -> None:
            released.append(self.scene.name)
            super().release()

    monkeypatch.setattr(worker_mod, "SceneGPU", SpyGPU)
    w = RenderWorker(queue_size=4, job_timeout_s=5.0, gpu_cache_size=1)
    try:
        w.start()
        assert w.wait_ready(10) and w.ready
        with pytest.raises(ZeroDivisionError):
            w.submit(lambda st: 1 / 0).result(10)
        assert w.submit(lambda st: threading.get_ident()).result(10) == w.thread_id
        state = w.submit(lambda st: st).result(10)
        with pytest.raises(RuntimeError):
            state.gl.check_thread()  # not the GL thread
        # Deadline passed while queued → skipped, never run.
        gate, ran = threading.Event(), []
        blocker = w.submit(lambda st: gate.wait(10))
        late = w.submit(lambda st: ran.append(1), timeout=0.05)
        time.sleep(0.2)
        gate.set()
        blocker.result(10)
        with pytest.raises(JobExpired):
            late.result(10)
        assert ran == []
        # GPU uploads: LRU of one, the evicted upload is released on the GL thread.
        a, b = make_builtin("nest", 0.01), make_builtin("grass", 0.01)
        w.submit(lambda st: st.scene_gpu("a", a)).result(10)
        w.submit(lambda st: st.scene_gpu("b", b)).result(10)
        assert released == ["nest"]
        assert w.stats()["jobs_failed"] == 1 and w.stats()["jobs_expired"] == 1
    finally:
        w.stop()
    assert released == ["nest", "grass"]  # shutdown released the rest
    assert not w.alive and not w.ready
    with pytest.raises(WorkerUnavailable):
        w.submit(lambda st: None)


def test_worker_keeps_reconstructions_and_maps_within_their_byte_budget(gl):
    """GLState.kept: a job with the same scene and key reuses the meshes;
    the least recently used are released once the kept bytes would pass the budget
    (before the build when its size is expected); meshes larger than the budget are
    released when their job ends; forgetting a scene releases its own."""
    from service.worker import GLState

    built, released = [], []

    class Mesh:
        def __init__(self, name: str, nbytes: int) -> None:
            self.name, self.nbytes = name, nbytes

        def release(self) -> None:
            released.append(self.name)

    def build(name: str, nbytes: int):
        return lambda: built.append(name) or [Mesh(name, nbytes)]

    st = GLState(gl=gl, gbuffer=None, reconstruction_cache_bytes=100)
    with st.kept("s", "a", build("a", 60)) as meshes:
        assert meshes[0].name == "a"
    with st.kept("s", "a", build("a again", 60)) as meshes:
        assert meshes[0].name == "a"
    with st.kept("t", "a", build("t's a", 30)):
        pass
    assert built == ["a", "t's a"] and released == []
    with st.kept("s", "c", build("c", 40)):
        pass
    assert released == ["a"]  # 60 + 30 + 40 > 100: the least recently used goes
    with st.kept("s", "big", build("big", 101)):
        assert released == ["a"]
    assert released == ["a", "big"] and st.kept_count == 2
    st.forget("s")
    assert released == ["a", "big", "c"] and st.kept_count == 1

    def after_room() -> list[Mesh]:
        assert released[-1] == "t's a"  # 30 + 90 > 100: room made before the build
        return [Mesh("x", 90)]

    with st.kept("u", "x", after_room, expected=90) as meshes:
        assert meshes[0].name == "x"
    assert st.kept_count == 1


def test_worker_resources_hold_one_object_per_name(gl):
    """GLState.resource: the same name and variant give the same object; another
    variant (a pass's settings) releases the held one before making the next, so
    requests that vary it (a soft-shadow pass per sample count) never pile up; all
    are released with the state's objects."""
    from service.worker import GLState

    made, released = [], []

    class Pass:
        def __init__(self, k: int) -> None:
            self.k = k
            made.append(k)

        def release(self) -> None:
            released.append(self.k)

    st = GLState(gl=gl, gbuffer=None)
    a = st.resource("pass", lambda _: Pass(4), 4)
    assert st.resource("pass", lambda _: Pass(-1), 4) is a and made == [4]
    for k in (8, 16, 8):
        assert st.resource("pass", lambda _, k=k: Pass(k), k).k == k
    assert made == [4, 8, 16, 8] and released == [4, 8, 16]
    st.resource("other", lambda _: Pass(0))
    released.clear()
    st.release_objects()
    assert sorted(released) == [0, 8]


def test_worker_releases_passes_sized_over_keep_pixels_after_the_job(gl):
    """GLState.end_job: a pass a job used for images over keep_pixels, and a G-buffer
    target over it, are released after the job (an idle worker does not hold its
    largest frame's memory); smaller ones stay for the next job; keep_pixels None
    keeps all. The next job makes them again."""
    from gl_passes.gbuffer import GBufferPass
    from gl_passes.upload import SceneGPU
    from scenes.camera import Camera
    from service.worker import GLState

    released = []

    class Pass:
        def __init__(self, name: str) -> None:
            self.name = name

        def release(self) -> None:
            released.append(self.name)

    with GBufferPass(gl) as gbuffer, SceneGPU(gl, sphere_on_slab()) as gpu:
        st = GLState(gl=gl, gbuffer=gbuffer, keep_pixels=64 * 64)
        small = st.resource("small", lambda _: Pass("small"), pixels=64 * 64)
        big = st.resource("big", lambda _: Pass("big"), pixels=16)
        gbuffer.draw(gpu, Camera(eye=(0, 1, 3), target=(0, 0, 0), width=64, height=64))
        assert st.end_job() is False and released == [] and gbuffer.target is not None
        # the largest use within the job counts
        assert st.resource("big", lambda _: Pass("new"), pixels=16) is big
        assert st.resource("big", lambda _: Pass("new"), pixels=64 * 65) is big
        gbuffer.draw(gpu, Camera(eye=(0, 1, 3), target=(0, 0, 0), width=65, height=64))
        assert st.end_job() is True and released == ["big"] and gbuffer.target is None
        assert st.resource("small", lambda _: Pass("new"), pixels=1) is small
        assert st.resource("big", lambda _: Pass("new"), pixels=1).name == "new"
        assert gbuffer.render(gpu, Camera(eye=(0, 1, 3), target=(0, 0, 0), width=32, height=32)).tri_id.any()

        keep_all = GLState(gl=gl, gbuffer=gbuffer)
        keep_all.resource("huge", lambda _: Pass("huge"), pixels=1 << 30)
        assert keep_all.end_job() is False and released == ["big"]


def test_worker_resources_forget_a_released_upload_first(gl):
    """Before GLState releases a scene's upload (evicted, or forgotten when the scene
    is deleted), each resource with forget_scene drops what it cached of it."""
    from service.worker import GLState

    forgotten = []

    class Cache:
        def forget_scene(self, gpu) -> None:
            assert gpu.vbo.glo > 0  # still alive
            forgotten.append(gpu.scene)

        def release(self) -> None:
            pass

    a, b = make_builtin("cornell"), make_builtin("mirror")
    st = GLState(gl=gl, gbuffer=None, gpu_cache_size=1)
    st.resource("cache", lambda _: Cache())
    st.scene_gpu("a", a)
    st.scene_gpu("b", b)  # evicts a
    assert forgotten == [a]
    st.forget("b")
    assert forgotten == [a, b]
    st.release_objects()


# --- CLI -------------------------------------------------------------------------------------------
def test_cli_scenes_lists_builtins(capsys):
    from service.cli import main

    assert main(["scenes", "--detail", "0.5"]) == 0
    out = capsys.readouterr().out
    for name in BUILTIN_NAMES:
        assert name in out


def test_cli_render_writes_png_and_rejects_bad_camera(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = tmp_path / "frame.png"
    cmd = [sys.executable, "-m", "service", "render", "--scene", FRAME_SCENE, "--width", "40", "--height", "24"]
    p = subprocess.run([*cmd, str(out)], cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    img = image_io.decode_png(out.read_bytes())
    assert img.shape == (24, 40, 3) and img.std() > 5
    p = subprocess.run([*cmd, "--eye", "1", "1", "1", "--target", "1", "1", "1", str(tmp_path / "x.png")],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "coincide" in p.stderr


def test_cli_render_orbits_the_target_and_names_its_limits(tmp_path, capsys):
    """Without --eye the orbit centres on --target (it was ignored); sizes over the
    service's limits and an orbit that looks along --up are errors (exit 2) naming them."""
    from service.cli import main

    env = dict(os.environ, PYTHONPATH=str(ROOT))
    cmd = [sys.executable, "-m", "service", "render", "--scene", FRAME_SCENE, "--width", "40", "--height", "24"]
    images = []
    for extra in ([], ["--target", "5", "0", "0"]):
        out = tmp_path / f"orbit{len(images)}.png"
        p = subprocess.run([*cmd, *extra, str(out)], cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
        assert p.returncode == 0, p.stderr
        images.append(image_io.decode_png(out.read_bytes()).astype(int))
    assert np.abs(images[0] - images[1]).mean() > 5
    away = subprocess.run([*cmd, "--eye", "0", "1", "30", "--target", "0", "1", "60", str(tmp_path / "a.png")],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
    assert away.returncode == 0 and "warning: no pixel shows the scene" in away.stderr and "--no-cull" in away.stderr
    assert main(["render", "--scene", FRAME_SCENE, "--width", "20000", "--height", "2", str(tmp_path / "w.png")]) == 2
    assert "frame width 20000 exceeds the limit 4096" in capsys.readouterr().err
    assert main(["render", "--scene", FRAME_SCENE, "--elevation", "90", str(tmp_path / "p.png")]) == 2
    assert "at --elevation 90 the orbit looks along --up" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        main(["serve", "--port", "99999"])
    assert exit_info.value.code == 2 and "port 99999 is not in 0-65535" in capsys.readouterr().err
    (tmp_path / "afile").write_text("x")
    assert main(["serve", "--data-dir", str(tmp_path / "afile")]) == 2
    assert "is a file, not a directory" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0 and capsys.readouterr().out.startswith("depthview ")


def test_upload_a_real_model(client):
    path = shared_scene("teapot/teapot.obj")
    data = path.read_bytes()
    r = client.post("/scenes", files={"file": (path.name, data)})
    assert r.status_code == 201, r.text  # a new upload (200: the same content was stored before)
    assert r.headers["location"] == f"/scenes/{r.json()['id']}"
    info = r.json()
    assert info["id"] == hashlib.sha256(b"obj\n" + data).hexdigest() and info["triangles"] > 1000
    lo, hi = np.array(info["bounds"])
    c = (lo + hi) / 2
    eye = c + np.array([0.0, 0.3, 1.0]) * np.linalg.norm(hi - lo) * 1.2
    r = frame(client, info["id"], {"eye": eye.tolist(), "target": c.tolist()}, format="exr", width=32, height=32)
    assert r.status_code == 200
    assert (image_io.decode_exr(r.content)["id"] > 0).mean() > 0.1


def test_settings_from_env():
    env = {"DEPTHVIEW_DATA_DIR": "/tmp/dv", "DEPTHVIEW_MAX_UPLOAD_BYTES": "1_048_576", "DEPTHVIEW_PORT": "9000",
           "DEPTHVIEW_JOB_TIMEOUT_S": "2.5", "DEPTHVIEW_QUEUE_SIZE": "3", "DEPTHVIEW_GL_BACKEND": "osmesa"}
    s = Settings.from_env(env, port=9100)
    assert s.data_dir == Path("/tmp/dv") and s.max_upload_bytes == 1 << 20 and s.port == 9100
    assert s.job_timeout_s == 2.5 and s.queue_size == 3 and s.gl_backend == "osmesa"
    d = Settings.from_env({})
    assert (d.max_upload_bytes, d.max_triangles, d.max_width, d.max_height, d.queue_size, d.job_timeout_s) == (
        64 << 20, 5_000_000, 4096, 4096, 32, 120.0)
    with pytest.raises(ValueError, match="DEPTHVIEW_QUEUE_SIZE"):
        Settings.from_env({"DEPTHVIEW_QUEUE_SIZE": "many"})
    with pytest.raises(ValueError, match="queue_size"):
        Settings(queue_size=0)

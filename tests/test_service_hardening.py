"""Issue 15, item 5: the service's hardening — settings from the environment, body
limits, the memory budget, strict types, error messages, uniform statuses, slow
clients, the bearer token, CORS and the metrics. Frames here are tiny (≤ 32²)."""

from __future__ import annotations

import json
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from service.config import Settings
from service.deps import presented_token, token_ok
from service.store import builtin_id
from tests.helpers import frame_camera, live_server, obj_text, service, service_client, wait_until

CORNELL = builtin_id("cornell")
UNKNOWN = "0" * 64
CAMERA = frame_camera("cornell")
RENDER_PATHS = ("frames", "depth-images", "reconstruction")


client = service_client()


def post_text(client: TestClient, url: str, text: str | bytes, **headers: str):
    body = text.encode() if isinstance(text, str) else text
    return client.post(url, content=body, headers={"content-type": "application/json", **headers})


def frame_body(**extra) -> dict:
    return {"camera": CAMERA, "width": 32, "height": 32, **extra}


# --- depthview serve and the environment ---------------------------------------------------
def test_serve_honours_the_environment_and_options_win(tmp_path, monkeypatch):
    import uvicorn

    from service import cli

    seen = []
    monkeypatch.setattr(uvicorn.Server, "run", lambda self: seen.append(self.config))
    env = {"DEPTHVIEW_DATA_DIR": str(tmp_path / "store"), "DEPTHVIEW_HOST": "127.0.0.9",
           "DEPTHVIEW_PORT": "9123", "DEPTHVIEW_GL": "osmesa", "DEPTHVIEW_HEADER_TIMEOUT_S": "3"}
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    assert cli.main(["serve"]) == 0
    config = seen[-1]
    settings = config.app.state.settings
    assert (config.host, config.port) == ("127.0.0.9", 9123)
    assert settings.data_dir == tmp_path / "store" and settings.gl_backend == "osmesa"
    assert settings.header_timeout_s == 3.0 and config.timeout_keep_alive == cli.KEEP_ALIVE_S
    assert config.timeout_graceful_shutdown == cli.GRACEFUL_SHUTDOWN_S < 10  # before docker stop's SIGKILL
    # Options given on the command line win over the environment.
    assert cli.main(["serve", "--port", "9124", "--host", "127.0.0.10", "--data-dir", str(tmp_path / "o"),
                     "--gl-backend", "egl"]) == 0
    settings = seen[-1].app.state.settings
    assert (seen[-1].host, seen[-1].port, settings.data_dir, settings.gl_backend) == (
        "127.0.0.10", 9124, tmp_path / "o", "egl")


def test_settings_from_env_new_settings_and_none_overrides():
    env = {"DEPTHVIEW_PORT": "9000", "DEPTHVIEW_GL": "OSMesa", "DEPTHVIEW_GL_BACKEND": "egl",
           "DEPTHVIEW_TOKEN": "t0k", "DEPTHVIEW_CORS_ORIGINS": "https://a.example, https://b.example/",
           "DEPTHVIEW_MAX_JSON_BYTES": "4096", "DEPTHVIEW_MAX_JOB_BYTES": "1_000_000",
           "DEPTHVIEW_BODY_TIMEOUT_S": "2.5"}
    s = Settings.from_env(env, port=None, host=None, data_dir=None, gl_backend=None)
    assert s.port == 9000 and s.gl_backend == "osmesa"  # DEPTHVIEW_GL wins over DEPTHVIEW_GL_BACKEND
    assert s.token == "t0k" and s.cors_origins == ("https://a.example", "https://b.example")
    assert (s.max_json_bytes, s.max_job_bytes, s.body_timeout_s) == (4096, 1_000_000, 2.5)
    d = Settings.from_env({})
    assert (d.token, d.cors_origins, d.max_json_bytes, d.max_job_bytes) == (None, (), 1 << 20, 7 << 30)
    assert (d.header_timeout_s, d.body_timeout_s) == (10.0, 30.0)
    with pytest.raises(ValueError, match="DEPTHVIEW_MAX_JOB_BYTES"):
        Settings.from_env({"DEPTHVIEW_MAX_JOB_BYTES": "lots"})
    with pytest.raises(ValueError, match="gl_backend"):
        Settings.from_env({"DEPTHVIEW_GL": "vulkan"})
    with pytest.raises(ValueError, match="body_timeout_s"):
        Settings(body_timeout_s=0)


@pytest.mark.parametrize(("env", "message"), [
    ({"DEPTHVIEW_PORT": "70000"}, r"port \(DEPTHVIEW_PORT\) must be within 0..65535"),
    ({"DEPTHVIEW_PORT": "-1"}, r"DEPTHVIEW_PORT\) must be within"),
    ({"DEPTHVIEW_TOKEN": "  "}, "DEPTHVIEW_TOKEN is set but blank"),  # "$SECRET" unset: not an open service
    ({"DEPTHVIEW_RETRY_AFTER_S": "-1"}, r"DEPTHVIEW_RETRY_AFTER_S\) must be >= 0"),
    ({"DEPTHVIEW_MAX_WIDTH": "100000"}, r"DEPTHVIEW_MAX_WIDTH\) must be <= 16384"),
    ({"DEPTHVIEW_MAX_HEIGHT": "16385"}, r"DEPTHVIEW_MAX_HEIGHT\) must be <= 16384"),
    ({"DEPTHVIEW_QUEUE_SIZE": "0"}, r"queue_size \(DEPTHVIEW_QUEUE_SIZE\) must be >= 1"),
    ({"DEPTHVIEW_GL": "vulkan"}, r"gl_backend \(DEPTHVIEW_GL\)"),
    ({"DEPTHVIEW_PARSE_TIMEOUT_S": "0"}, r"DEPTHVIEW_PARSE_TIMEOUT_S\) must be > 0"),
    ({"DEPTHVIEW_PARSE_TIMEOUT_S": "inf"}, r"DEPTHVIEW_PARSE_TIMEOUT_S\) must be > 0 and at most 86400 s"),
    ({"DEPTHVIEW_JOB_TIMEOUT_S": "1e12"}, r"DEPTHVIEW_JOB_TIMEOUT_S\) must be > 0 and at most"),
    ({"DEPTHVIEW_STREAM_REUSE_BYTES": "0"}, r"DEPTHVIEW_STREAM_REUSE_BYTES\) must be >= 1"),
])
def test_settings_out_of_range_are_refused_naming_the_variable(env, message):
    with pytest.raises(ValueError, match=message):
        Settings.from_env(env)


def test_settings_at_their_bounds_are_accepted():
    s = Settings.from_env({"DEPTHVIEW_PORT": "65535", "DEPTHVIEW_RETRY_AFTER_S": "0", "DEPTHVIEW_MAX_WIDTH": "16384",
                           "DEPTHVIEW_DATA_DIR": " "})  # blank: unset, as for every variable but the token
    assert (s.port, s.retry_after_s, s.max_width, s.data_dir) == (65535, 0, 16384, Path("./data"))


# --- body size limits and short error messages -----------------------------------------------
@pytest.mark.parametrize("path", RENDER_PATHS)
def test_json_body_over_the_limit_is_413_without_an_echo(tmp_path_factory, path):
    with service(tmp_path_factory.mktemp("d"), ready=False, max_json_bytes=4096) as c:
        big = json.dumps({**frame_body(), "pad": "x" * 20_000})
        r = post_text(c, f"/scenes/{CORNELL}/{path}", big)
        assert r.status_code == 413 and "4096 bytes (DEPTHVIEW_MAX_JSON_BYTES)" in r.json()["detail"]
        assert len(r.content) < 300
        # Streamed without Content-Length: counted while it arrives.
        chunks = (big[i:i + 1000].encode() for i in range(0, len(big), 1000))
        r = c.post(f"/scenes/{CORNELL}/{path}", content=chunks, headers={"content-type": "application/json"})
        assert r.status_code == 413 and "exceeds the limit of 4096 bytes" in r.json()["detail"]
        # Any content type: the limit is the endpoint's, not the JSON parser's.
        r = c.post(f"/scenes/{CORNELL}/{path}", content=b"x" * 5000, headers={"content-type": "text/plain"})
        assert r.status_code == 413


def test_builtin_scene_json_body_over_the_limit_is_413(tmp_path):
    with service(tmp_path, ready=False, max_json_bytes=1024) as c:
        r = post_text(c, "/scenes", json.dumps({"builtin": "nest", "pad": "y" * 4000}))
        assert r.status_code == 413 and len(r.content) < 300 and "DEPTHVIEW_MAX_JSON_BYTES" in r.json()["detail"]


def test_validation_errors_repeat_only_an_excerpt_of_the_input(client):
    huge = "7" * 200_000
    r = post_text(client, f"/scenes/{CORNELL}/frames", json.dumps(frame_body(width=huge, cull_back_faces=huge)))
    assert r.status_code == 422
    assert len(r.content) < 2000, len(r.content)
    errs = r.json()["detail"]
    assert {tuple(e["loc"]) for e in errs} == {("body", "width"), ("body", "cull_back_faces")}
    assert all(e["input"].endswith("(200,002 characters)") and len(e["input"]) < 120 for e in errs)
    r = post_text(client, f"/scenes/{CORNELL}/frames", json.dumps(frame_body(width="x")))
    assert r.status_code == 422 and r.json()["detail"][0]["input"] == "x"  # short inputs in full


LONG_KEY = "k" * 5000


@pytest.mark.parametrize("path, body, where", [
    ("frames", frame_body(**{LONG_KEY: 1}), ["body"]),
    ("frames", frame_body(camera={**CAMERA, LONG_KEY: 1}), ["body", "camera"]),
    ("frames", frame_body(effects={LONG_KEY: 1}), ["body", "effects"]),
    ("frames", frame_body(effects={"soft_shadows": {LONG_KEY: 1}}), ["body", "effects", "soft_shadows"]),
    ("reconstruction", {LONG_KEY: 1}, ["body"]),
    ("depth-images", {LONG_KEY: 1}, ["body"]),
    ("/scenes", {"builtin": "cornell", LONG_KEY: 1}, ["body"]),
    ("/scenes", {"builtin": "cornell", "params": {LONG_KEY: 1}}, ["body", "params"]),
])
def test_a_long_unknown_key_is_named_by_an_excerpt(client, path, body, where):
    """The key of an unknown field is the client's text: its location quotes an excerpt."""
    r = post_text(client, path if path.startswith("/") else f"/scenes/{CORNELL}/{path}", json.dumps(body))
    assert r.status_code == 422, r.text
    assert "k" * 81 not in r.text and len(r.content) < 2000, len(r.content)
    locs = [e["loc"] for e in r.json()["detail"] if e["type"] == "extra_forbidden"]
    assert locs and locs[0][:len(where)] == where and locs[0][-1].endswith("(5,000 characters)"), locs


def test_many_invalid_fields_are_counted_not_listed(client):
    """60,000 unknown keys (a 0.8 MB body, under the 1 MiB JSON limit): the first 20 issues and their count."""
    body = frame_body(**{f"x{i}": 0 for i in range(60_000)})
    r = post_text(client, f"/scenes/{CORNELL}/frames", json.dumps(body))
    assert r.status_code == 422 and len(r.content) < 5000, len(r.content)
    errs = r.json()["detail"]
    assert [e["loc"] for e in errs[:2]] == [["body", "x0"], ["body", "x1"]] and len(errs) == 21
    assert errs[-1]["type"] == "too_many_errors" and errs[-1]["msg"] == "and 59,980 more invalid fields, not listed"


@pytest.mark.parametrize("path, body", [
    ("frames", {"effects": {"reflections": "y" * 5000}}),  # a validator's own message
    ("/scenes", {"builtin": "z" * 5000}),  # the store's
])
def test_error_messages_quote_only_an_excerpt_of_the_input(client, path, body):
    url = path if path.startswith("/") else f"/scenes/{CORNELL}/{path}"
    r = client.post(url, json=body if path.startswith("/") else frame_body(**body))
    assert r.status_code == 422, r.text
    assert "(5,002 characters)" in r.text
    assert "y" * 81 not in r.text and "z" * 81 not in r.text


# --- the memory budget -----------------------------------------------------------------------------
def test_memory_budget_refuses_large_requests_up_front(client):
    """16 layers at 2048² (17 GiB estimated) is over the default 7 GiB; the scene is not
    even looked up (an unknown id still gets 422, not 404). A 4096² frame, the largest,
    is within it."""
    r = client.post(f"/scenes/{UNKNOWN}/depth-images",
                    json={"method": "peeling", "layers": 16, "width": 2048, "height": 2048})
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert "memory budget of 7.00 GiB" in detail and "16 images of 2048×2048" in detail
    assert "DEPTHVIEW_MAX_JOB_BYTES" in detail
    r = client.post(f"/scenes/{UNKNOWN}/reconstruction",
                    json={"cameras": [CAMERA] * 16, "resolution": 2048})
    assert r.status_code == 422 and "16 reconstructed images of 2048²" in r.json()["detail"]
    r = client.post(f"/scenes/{UNKNOWN}/frames", json=frame_body(width=4096, height=4096,
                                                                  effects={"reflections": "cluster"}))
    assert r.status_code == 422 and "reflections" in r.json()["detail"]
    # Within the budget the same endpoints go on (404: the unknown scene is looked up).
    r = client.post(f"/scenes/{UNKNOWN}/frames", json=frame_body(width=4096, height=4096))
    assert r.status_code == 404
    r = client.post(f"/scenes/{UNKNOWN}/depth-images", json={"method": "peeling", "layers": 4, "width": 512,
                                                              "height": 512})
    assert r.status_code == 404


def test_memory_budget_is_configurable_and_covers_soft_shadows(tmp_path):
    with service(tmp_path, max_job_bytes=8 * 2**20) as c:
        r = c.post(f"/scenes/{CORNELL}/frames", json=frame_body(width=256, height=256))  # 10 MiB
        assert r.status_code == 422 and "over the memory budget of 8.0 MiB" in r.json()["detail"]
        assert c.post(f"/scenes/{CORNELL}/frames", json=frame_body()).status_code == 200
        shadows = {"soft_shadows": {"samples": 2, "resolution": 256}}  # 4 × 256² × 368 B = 92 MiB
        r = c.post(f"/scenes/{CORNELL}/frames", json=frame_body(width=8, height=8, effects=shadows))
        assert r.status_code == 422 and "4 reconstructed images of 256²" in r.json()["detail"]
        r = c.post(f"/scenes/{CORNELL}/depth-images", json={"width": 128, "height": 128, "metrics": True})
        assert r.status_code == 422 and "conventional images for metrics" in r.json()["detail"]


def test_memory_budget_counts_the_splat_depth_image_of_shadow_maps():
    """Shadow maps hold the depth atlas and an image of its size (the reconstructions'
    splats' integer depths, gl_passes.quad_splats.SplatRaster, which the worker's
    pass keeps once made, also for geometry frames after it); raytrace neither."""
    from service.budget import frame_bytes
    from service.config import RECONSTRUCTION_BYTES_PER_SAMPLE, SHADOW_MAP_RESOLUTION, SHADOW_MAPS_PER_DRAW
    from service.schemas import FrameRequest

    def estimate(method: str, samples: int) -> int:
        shadows = {"soft_shadows": {"samples": samples, "method": method, "resolution": 256}}
        return frame_bytes(FrameRequest.model_validate(frame_body(effects=shadows)))[0]

    for k in (2, 16):
        atlas = SHADOW_MAP_RESOLUTION**2 * min(k * k, SHADOW_MAPS_PER_DRAW) * 4
        images = 4 * 256**2 * RECONSTRUCTION_BYTES_PER_SAMPLE
        assert estimate("non_redundant", k) - estimate("geometry", k) == images
        assert estimate("geometry", k) - estimate("raytrace", k) == 2 * atlas


# --- strict types and messages that name the real problem ------------------------------------------
@pytest.mark.parametrize("extra, loc", [
    ({"width": True}, "width"),
    ({"width": "64"}, "width"),
    ({"height": 32.0}, "height"),
    ({"cull_back_faces": "no"}, "cull_back_faces"),
    ({"cull_back_faces": 0}, "cull_back_faces"),
    ({"camera": {**CAMERA, "fov": "45"}}, "fov"),
    ({"camera": {**CAMERA, "eye": ["1", 1, 3]}}, "eye"),
    ({"effects": {"reflections": "cluster", "glossy_rays": "8"}}, "glossy_rays"),
    ({"effects": {"soft_shadows": {"samples": True}}}, "samples"),
])
def test_strict_types_are_422_not_coerced(client, extra, loc):
    r = client.post(f"/scenes/{CORNELL}/frames", json=frame_body(**extra))
    assert r.status_code == 422, r.text
    assert any(e["loc"][-1] == loc or loc in e["loc"] for e in r.json()["detail"]), r.json()


@pytest.mark.parametrize("path, body, loc", [
    ("depth-images", {"metrics": "yes"}, "metrics"),
    ("depth-images", {"layers": "3", "method": "peeling"}, "layers"),
    ("reconstruction", {"resolution": "512"}, "resolution"),
])
def test_strict_types_on_the_other_render_endpoints(client, path, body, loc):
    r = client.post(f"/scenes/{CORNELL}/{path}", json=body)
    assert r.status_code == 422 and r.json()["detail"][0]["loc"][-1] == loc


def test_strict_builtin_params_and_integers_where_floats_go(client):
    for params in ({"seed": "1"}, {"detail": True}, {"detail": "1.0"}):
        r = client.post("/scenes", json={"builtin": "nest", "params": params})
        assert r.status_code == 422, (params, r.text)
    # An integer is a number: eye [0, 1, 3] and detail 1 are fine.
    assert client.post("/scenes", json={"builtin": "cornell", "params": {"detail": 1}}).status_code == 200
    r = client.post(f"/scenes/{CORNELL}/frames", json=frame_body(camera={"eye": [0, 1, 3], "target": [0, 1, 0]}))
    assert r.status_code == 200


def test_tiny_fov_and_huge_coordinates_name_the_real_problem(client):
    r = client.post(f"/scenes/{CORNELL}/frames", json=frame_body(camera={**CAMERA, "fov": 1e-9}))
    assert r.status_code == 422 and "greater than or equal to 0.01" in json.dumps(r.json())
    r = client.post(f"/scenes/{CORNELL}/frames", json=frame_body(camera={**CAMERA, "fov": 0.01}))
    assert r.status_code == 200  # the smallest fov renders
    r = client.post(f"/scenes/{CORNELL}/frames", json=frame_body(camera={"eye": [1e308, 1, 3], "target": [0, 1, 0]}))
    text = json.dumps(r.json())
    assert r.status_code == 422 and "coordinate 1e+308 is out of range" in text and "coincide" not in text
    light = {"center": [0, 1e300, 0], "u": [1, 0, 0], "v": [0, 0, 1]}
    r = client.post(f"/scenes/{CORNELL}/frames", json=frame_body(effects={"soft_shadows": {"light": light}}))
    assert r.status_code == 422 and "light center coordinate" in json.dumps(r.json())


@pytest.mark.parametrize(("body", "says"), [
    ('{"camera": {"eye": [%s, 1, 3], "target": [0, 1, 0]}, "width": 32, "height": 32}', "camera eye coordinate"),
    ('{"camera": {"eye": [0, 1, 3], "target": [0, 1, 0], "up": [0, -%s, 0]}, "width": 32, "height": 32}',
     "camera up coordinate"),
    ('{"camera": {"eye": [0, 1, 3], "target": [0, 1, 0]}, "width": 32, "height": 32, "effects": {"soft_shadows": '
     '{"light": {"center": [0, 1, 0], "u": [%s, 0, 0], "v": [0, 0, 1]}}}}', "light u coordinate"),
])
def test_an_integer_too_large_for_a_float_is_an_out_of_range_coordinate(client, body, says):
    """An integer coordinate of hundreds of digits is valid JSON, but no float holds it:
    422 naming the vector, not a 500 (OverflowError converting it)."""
    r = post_text(client, f"/scenes/{CORNELL}/frames", body % ("1" + "0" * 400))
    text = json.dumps(r.json())
    assert r.status_code == 422 and says in text and "out of range" in text, r.text
    assert len(r.content) < 2000


@pytest.mark.parametrize(("path", "body", "says"), [
    ("frames", '{"camera": %s, "width": %s, "height": 32}', "DEPTHVIEW_MAX_WIDTH"),
    ("frames", '{"camera": %s, "width": 32, "height": %s}', "DEPTHVIEW_MAX_HEIGHT"),
    ("depth-images", '{"cameras": [%s], "width": %s}', "DEPTHVIEW_MAX_WIDTH"),
])
def test_a_huge_size_is_named_by_an_excerpt_and_its_limit(client, path, body, says):
    """A width of thousands of digits (an int to JSON and pydantic) is over the limit:
    the 422 names the limit's variable and repeats only an excerpt of the number (the
    whole of it filled the message, cut before the limit was named)."""
    r = post_text(client, f"/scenes/{CORNELL}/{path}", body % (json.dumps(CAMERA), "9" * 4000))
    detail = r.json()["detail"]
    assert r.status_code == 422 and says in detail and len(detail) < 300, r.text


def test_a_long_format_name_is_not_echoed(client):
    r = client.post("/scenes?format=" + "q" * 5000, content=b"v 0 0 0\n",
                    headers={"content-type": "application/octet-stream"})
    assert r.status_code == 415 and len(r.content) < 300 and "q" * 16 in r.json()["detail"]


def test_a_long_store_or_loader_message_is_cut(tmp_path, monkeypatch):
    from scenes.loaders import SceneLoadError

    with service(tmp_path, ready=False) as c:
        def quoting(scene_id):  # a library message quoting a long piece of its input
            raise SceneLoadError("malformed OBJ: could not convert " + "9" * 5000)

        monkeypatch.setattr(c.app.state.store, "get_meta", quoting)
        r = c.get(f"/scenes/{CORNELL}")
        assert r.status_code == 422 and r.json()["detail"].endswith("… (message cut)")
        assert len(r.json()["detail"]) < 520


def test_ply_declaring_more_vertices_than_it_holds_is_422_saying_so(client):
    ply = (b"ply\nformat ascii 1.0\nelement vertex 5000000\nproperty float x\nproperty float y\n"
           b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
           b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    r = client.post("/scenes", files={"file": ("liar.ply", ply)})
    assert r.status_code == 422 and "declares 5,000,000 'vertex'" in r.json()["detail"]


# --- uniform statuses, Allow, OpenAPI ----------------------------------------------------------------
@pytest.mark.parametrize("url", ["/scenes", f"/scenes/{CORNELL}/frames", f"/scenes/{CORNELL}/depth-images",
                                 f"/scenes/{CORNELL}/reconstruction"])
@pytest.mark.parametrize("body, says", [
    (b'{"camera": ', ("line 1 column 11", "line 1 column 12")),  # cut short
    (b'{"camera": ' + b"[" * 5000 + b"]" * 5000 + b"}", ("recursion limit", "nested too deeply")),
    (b'{"camera": "\xff\xfe"}', ("line 1 column 13", "byte offset 12")),  # not UTF-8
    (b'{"name": "' + b"1" * 5000 + b'",\n "width": ' + b"9" * 5000 + b"}",  # past 4300 digits (not in a string)
     ("number out of range at line 2 column 11",
                                                      "number out of range at line 2 column 4312")),  # /scenes: its end
])
def test_malformed_json_is_400_on_every_endpoint_saying_what_and_where(client, url, body, says):
    """The render routes' JSONBodyRoute names the problem like /scenes's pydantic
    parser does (FastAPI alone answers a bare 'There was an error parsing the body' on
    deep nesting and invalid UTF-8)."""
    r = post_text(client, url, body)
    detail = r.json()["detail"]
    assert r.status_code == 400 and detail.startswith("request body is not valid JSON: "), r.text
    assert any(s in detail for s in says), detail


@pytest.mark.parametrize("url", [f"/scenes/{CORNELL}/frames", f"/scenes/{CORNELL}/depth-images",
                                 f"/scenes/{CORNELL}/reconstruction"])
@pytest.mark.parametrize("ctype", ["application/x-www-form-urlencoded", "text/plain", "text/json", None])
def test_json_without_a_json_content_type_is_415_saying_so(client, url, ctype):
    """curl -d sends form encoding: the answer names the header to send, not the body."""
    body = json.dumps(frame_body()).encode()
    r = client.post(url, content=body, headers={} if ctype is None else {"content-type": ctype})
    assert r.status_code == 415, r.text
    assert r.json()["detail"] == ("the request body is JSON: send Content-Type: application/json (got "
                                  f"{ctype and repr(ctype) or 'none'})")
    r = client.post(url, content=b"[1, 2]", headers={"content-type": "application/json"})
    assert r.status_code == 422  # JSON, but not an object: still a validation error


@pytest.mark.parametrize("method, url, allow", [
    ("POST", f"/scenes/{CORNELL}", "DELETE, GET, HEAD"),
    ("PUT", f"/scenes/{CORNELL}", "DELETE, GET, HEAD"),
    ("DELETE", "/scenes", "GET, HEAD, POST"),
    ("GET", f"/scenes/{CORNELL}/frames", "POST"),
    ("POST", "/healthz", "GET, HEAD"),
])
def test_405_lists_every_allowed_method(client, method, url, allow):
    r = client.request(method, url)
    assert r.status_code == 405 and r.headers["allow"] == allow
    if method != "HEAD":
        assert r.json()["detail"] == "Method Not Allowed"


def test_every_documented_status_has_a_schema(client):
    spec = client.get("/openapi.json").json()
    assert spec["components"]["securitySchemes"]["bearer"] == {
        "type": "http", "scheme": "bearer", "description": spec["components"]["securitySchemes"]["bearer"][
            "description"]}
    checked = 0
    for path, item in spec["paths"].items():
        for method, op in item.items():
            for status, resp in op["responses"].items():
                if status.startswith("2") and status != "200":
                    continue
                content = resp.get("content") or {}
                assert content, (method, path, status)
                if not status.startswith("2"):
                    assert content["application/json"]["schema"], (method, path, status)
                    checked += 1
    assert checked >= 40
    frames = spec["paths"]["/scenes/{scene_id}/frames"]["post"]["responses"]
    assert {"400", "401", "404", "408", "413", "422", "500", "503", "504"} <= set(frames)
    for name in ("ErrorResponse", "ValidationErrorResponse", "ValidationIssue"):
        assert name in spec["components"]["schemas"]


def test_the_document_describes_what_the_routes_accept_and_answer(client):
    """Media type objects hold only OpenAPI's fields (a description there made the
    document invalid); every raw upload type is listed; a string path parameter cannot
    fail validation, so no 422 is promised for it; the built-in detail range is the one
    enforced; the response headers of uploads and renders are named."""
    from service.routes.scenes import RAW_CONTENT_TYPES

    spec = client.get("/openapi.json").json()
    media_fields = {"schema", "example", "examples", "encoding"}
    for path, item in spec["paths"].items():
        for method, op in item.items():
            bodies = [op.get("requestBody", {}), *op["responses"].values()]
            for body in bodies:
                for media, obj in (body.get("content") or {}).items():
                    assert set(obj) <= media_fields, (method, path, media, set(obj) - media_fields)
    upload = spec["paths"]["/scenes"]["post"]
    assert set(RAW_CONTENT_TYPES) | {"multipart/form-data", "application/json"} == set(upload["requestBody"]["content"])
    assert {"200", "201"} <= set(upload["responses"]) and "Location" in upload["responses"]["201"]["headers"]
    for method in ("get", "delete"):
        assert "422" not in spec["paths"]["/scenes/{scene_id}"][method]["responses"], method
    detail = spec["components"]["schemas"]["BuiltinParams"]["properties"]["detail"]
    assert (detail["minimum"], detail["maximum"]) == (0.01, 60.0)
    r = client.post("/scenes", json={"builtin": "nest", "params": {"detail": 61}})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "params", "detail"]
    frames = spec["paths"]["/scenes/{scene_id}/frames"]["post"]["responses"]["200"]["headers"]
    assert {"X-Render-Seconds", "Server-Timing"} == set(frames)
    sets = spec["paths"]["/scenes/{scene_id}/depth-images"]["post"]["responses"]["200"]["content"]
    assert sets["application/json"]["schema"]["required"] == ["metrics", "media_type", "images_b64"]


def test_scenes_take_json_under_any_json_media_type_as_the_render_routes_do(client):
    body = json.dumps({"builtin": "cornell"}).encode()
    r = client.post("/scenes", content=body, headers={"content-type": "application/vnd.example+json"})
    assert r.status_code == 200 and r.json()["id"] == CORNELL, r.text


def test_the_document_states_the_limits_the_service_enforces(tmp_path):
    """Sizes up to this service's limits, coordinates within ±1e12, the reflection methods:
    what the service refuses with 422 the OpenAPI document says it does not accept."""
    with service(tmp_path, ready=False, max_width=200, max_height=100) as c:
        comps = c.get("/openapi.json").json()["components"]["schemas"]
    for name in ("FrameRequest", "DepthImagesRequest"):
        assert comps[name]["properties"]["width"]["maximum"] == 200
        assert comps[name]["properties"]["height"]["maximum"] == 100
    eye = comps["CameraSpec"]["properties"]["eye"]["prefixItems"]
    assert all(item["minimum"] == -1e12 and item["maximum"] == 1e12 for item in eye)
    assert comps["Effects"]["properties"]["reflections"]["enum"] == ["none", "cluster", "raytrace", "envmap"]


def test_an_unexpected_error_is_a_json_500(tmp_path, monkeypatch):
    """Anything unexpected answers the documented ErrorResponse, not Starlette's plain text."""
    from service.store import SceneStore

    def broken(self):
        raise RuntimeError("the disk is on fire")

    from service.app import create_app

    monkeypatch.setattr(SceneStore, "list", broken)
    # raise_server_exceptions=False: the server logs the exception; the client sees the answer
    with TestClient(create_app(Settings(data_dir=tmp_path, workers=0)), raise_server_exceptions=False) as c:
        r = c.get("/scenes")
    assert r.status_code == 500 and r.headers["content-type"] == "application/json"
    assert r.json() == {"detail": "internal error (RuntimeError); the service log has the details"}


# --- slow clients -------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def live(tmp_path_factory) -> Iterator[tuple[str, int]]:
    """The real uvicorn server of `depthview serve` on a loopback port, short timeouts."""
    with live_server(tmp_path_factory.mktemp("live"), header_timeout_s=0.5, body_timeout_s=0.5) as address:
        yield address


#: Seconds a test reads before it gives up on the server closing: a hang guard only.
HANG_S = 30.0
#: 10 × the live server's 0.5 s header timeout and half the 10 s default
#: (Settings().header_timeout_s): a connection closed within it was closed by the
#: configured timer.
OWN_TIMER_S = 5.0


def _read_until_closed(sock: socket.socket, limit_s: float = HANG_S) -> tuple[bytes, float]:
    t0 = time.monotonic()
    sock.settimeout(limit_s)
    data = b""
    while True:
        chunk = sock.recv(65536)
        if not chunk:
            return data, time.monotonic() - t0
        data += chunk


def test_stalled_headers_close_the_connection(live):
    # Nothing is answered, so only the time tells the timer that closed it: not at once
    # (> 0.3 s), and the configured 0.5 s rather than a default (< OWN_TIMER_S).
    with socket.create_connection(live, timeout=5) as s:
        s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")  # no blank line: the head never ends
        data, waited = _read_until_closed(s)
    assert data == b"" and 0.3 < waited < OWN_TIMER_S
    with socket.create_connection(live, timeout=5) as s:  # connected, silent
        data, waited = _read_until_closed(s)
    assert data == b"" and 0.3 < waited < OWN_TIMER_S


def test_stalled_body_is_408_and_closed(live):
    head = (f"POST /scenes/{CORNELL}/frames HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
            "Content-Length: 400\r\n\r\n").encode()
    with socket.create_connection(live, timeout=5) as s:
        s.sendall(head + b'{"camera": ')
        data, waited = _read_until_closed(s)
    assert data.startswith(b"HTTP/1.1 408 "), data[:200]
    assert b"connection: close" in data.lower() and b"DEPTHVIEW_BODY_TIMEOUT_S" in data
    assert b"no data for 0.5 s" in data  # the configured body timeout, not the 30 s default
    assert waited > 0.3  # it waited for the body before giving up


def test_an_announced_large_body_is_refused_before_it_is_sent(live):
    head = (f"POST /scenes/{CORNELL}/depth-images HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
            f"Content-Length: {200 * 2**20}\r\n\r\n").encode()
    with socket.create_connection(live, timeout=5) as s:
        s.sendall(head + b"{")  # 200 MiB announced, one byte sent
        data, _ = _read_until_closed(s)
    # 413, not the 408 of the 0.5 s body timeout: refused on the announcement alone.
    assert data.startswith(b"HTTP/1.1 413 ") and b"DEPTHVIEW_MAX_JSON_BYTES" in data
    assert len(data) < 1000


def test_a_prompt_client_is_served_and_kept_alive(live):
    with socket.create_connection(live, timeout=5) as s:
        for _ in range(2):  # two requests on one connection, well within the timeouts
            s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
            data = b""
            while b'"ok"' not in data:
                data += s.recv(65536)
            assert data.startswith(b"HTTP/1.1 200 ")


# --- bearer token and CORS ------------------------------------------------------------------------------
def test_bearer_token(tmp_path):
    with service(tmp_path, token="s3cret") as c:
        assert c.get("/healthz").status_code == 200 and c.get("/readyz").status_code == 200
        assert c.get("/openapi.json").status_code == 200
        assert c.get("/docs").status_code == 200 and c.get("/docs/static/swagger-ui.css").status_code == 200
        for method, url in (("GET", "/scenes"), ("GET", f"/scenes/{CORNELL}"), ("GET", "/metrics"),
                            ("POST", f"/scenes/{CORNELL}/frames"), ("DELETE", f"/scenes/{UNKNOWN}")):
            r = c.request(method, url, json=frame_body() if method == "POST" else None)
            assert r.status_code == 401, (url, r.status_code)
            assert r.headers["www-authenticate"].startswith("Bearer")
            r = c.request(method, url, headers={"Authorization": "Bearer wrong"},
                          json=frame_body() if method == "POST" else None)
            assert r.status_code == 401
        ok = {"Authorization": "Bearer s3cret"}
        assert c.get("/scenes", headers=ok).status_code == 200
        r = c.post(f"/scenes/{CORNELL}/frames", json=frame_body(), headers=ok)
        assert r.status_code == 200 and r.headers["content-type"] == "image/png"
        assert c.get("/metrics", headers=ok).status_code == 200
    # The reusable check (the stream and the page take the token from the query).
    s = Settings(token="s3cret")
    assert token_ok(s, "s3cret") and not token_ok(s, "s3cre") and not token_ok(s, None)
    assert token_ok(Settings(), None)
    assert presented_token({"authorization": "Bearer abc"}) == "abc"
    assert presented_token({}, {"token": "abc"}) == "abc" and presented_token({}) is None


def test_cors_is_off_by_default_and_configurable(client, tmp_path):
    r = client.get("/scenes", headers={"Origin": "https://a.example"})
    assert r.status_code == 200 and "access-control-allow-origin" not in r.headers
    with service(tmp_path, ready=False, cors_origins=("https://a.example",), token="t") as c:
        pre = c.options("/scenes", headers={"Origin": "https://a.example", "Access-Control-Request-Method": "GET",
                                            "Access-Control-Request-Headers": "authorization"})
        assert pre.status_code == 200 and pre.headers["access-control-allow-origin"] == "https://a.example"
        r = c.get("/scenes", headers={"Origin": "https://a.example"})  # a refusal carries CORS headers too
        assert r.status_code == 401 and r.headers["access-control-allow-origin"] == "https://a.example"
        r = c.get("/scenes", headers={"Origin": "https://evil.example", "Authorization": "Bearer t"})
        assert r.status_code == 200 and "access-control-allow-origin" not in r.headers


# --- metrics --------------------------------------------------------------------------------------------
def _values(text: str) -> dict[str, float]:
    out = {}
    for line in text.splitlines():
        if line and not line.startswith("#"):
            name, value = line.rsplit(" ", 1)
            out[name] = float(value)
    return out


def test_metrics_cover_routes_steps_workers_and_every_error(tmp_path):
    with service(tmp_path) as c:
        route = "/scenes/{scene_id}/frames"
        before = _values(c.get("/metrics").text)
        assert c.post(f"/scenes/{CORNELL}/frames", json=frame_body()).status_code == 200
        assert c.post(f"/scenes/{CORNELL}/frames", json=frame_body(width=True)).status_code == 422
        assert post_text(c, f"/scenes/{CORNELL}/frames", "{").status_code == 400
        assert c.post(f"/scenes/{CORNELL}/frames", json=frame_body(width=5000)).status_code == 422
        assert c.get(f"/scenes/{UNKNOWN}").status_code == 404
        assert c.get("/nowhere").status_code == 404
        assert c.post(f"/scenes/{CORNELL}").status_code == 405  # no route matched: labelled by template
        assert c.head("/scenes").status_code == 200
        assert c.get("/openapi.json").status_code == 200
        text = c.get("/metrics").text
    v = _values(text)

    def delta(key: str) -> float:
        return v.get(key, 0.0) - before.get(key, 0.0)

    assert delta(f'depthview_responses_total{{method="POST",route="{route}",status="200"}}') == 1
    assert delta(f'depthview_responses_total{{method="POST",route="{route}",status="422"}}') == 2
    assert delta(f'depthview_responses_total{{method="POST",route="{route}",status="400"}}') == 1
    assert delta('depthview_responses_total{method="GET",route="/scenes/{scene_id}",status="404"}') == 1
    assert delta('depthview_responses_total{method="GET",route="(unmatched)",status="404"}') == 1
    assert delta('depthview_responses_total{method="POST",route="/scenes/{scene_id}",status="405"}') == 1
    assert delta('depthview_responses_total{method="HEAD",route="/scenes",status="200"}') == 1
    assert delta('depthview_responses_total{method="GET",route="/openapi.json",status="200"}') == 1
    assert not [k for k in v if CORNELL in k or UNKNOWN in k]  # ids never become label values
    assert delta('depthview_http_errors_total{class="4xx"}') == 6
    assert delta('depthview_http_errors_total{class="5xx"}') == 0
    assert delta(f'depthview_request_seconds_count{{method="POST",route="{route}"}}') == 4
    assert v[f'depthview_request_seconds_bucket{{method="POST",route="{route}",le="+Inf"}}'] == 4
    buckets = [k for k in v if k.startswith(f'depthview_request_seconds_bucket{{method="POST",route="{route}"')]
    counts = [v[k] for k in buckets]
    assert len(buckets) >= 10 and counts == sorted(counts)  # cumulative
    assert "# TYPE depthview_request_seconds histogram" in text
    for step in ("scene_load", "job", "encode"):
        assert delta(f'depthview_step_seconds_count{{step="{step}"}}') == 1, step
    assert v["depthview_workers_alive"] == 1 and v["depthview_queue_depth"] == 0
    assert v["depthview_frames_streamed_total"] == 0 and delta("depthview_queue_wait_seconds_count") == 1


def test_head_is_answered_wherever_get_is(client):
    r = client.head("/scenes")
    assert r.status_code == 200 and r.content == b"" and r.headers["content-type"] == "application/json"
    assert client.head("/healthz").status_code == 200
    r = client.head(f"/scenes/{CORNELL}/frames")
    assert r.status_code == 405 and r.headers["allow"] == "POST"


def test_request_guard_leaves_uploads_to_their_own_limit(tmp_path):
    """The JSON limit does not apply to scene uploads (their own limit does)."""
    with service(tmp_path, ready=False, max_json_bytes=1024) as c:
        data = obj_text(60)
        assert len(data) > 1024
        r = c.post("/scenes", files={"file": ("strip.obj", data)})
        assert r.status_code == 201, r.text


# --- a client that leaves ----------------------------------------------------------------------
def test_a_job_whose_client_left_is_dropped_from_the_queue(tmp_path):
    """The worker is busy; a frame's client disconnects while its job waits: the job
    never runs (the worker does only the busy job) and the request is logged as 499."""
    import threading

    import anyio

    with service(tmp_path) as c:
        worker = c.app.state.worker
        gate = threading.Event()
        worker.submit(lambda state: gate.wait(10))
        done = worker.stats()["jobs_done"]
        body = json.dumps(frame_body()).encode()
        messages = [{"type": "http.request", "body": body, "more_body": False}]
        sent: list[dict] = []

        async def receive() -> dict:
            if messages:
                return messages.pop(0)
            await anyio.sleep(0.3)  # the client leaves while its job waits for the worker
            return {"type": "http.disconnect"}

        async def send(message: dict) -> None:
            sent.append(message)

        scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1", "method": "POST",
                 "scheme": "http", "path": f"/scenes/{CORNELL}/frames", "raw_path": b"", "query_string": b"",
                 "root_path": "", "headers": [(b"content-type", b"application/json"),
                                              (b"content-length", str(len(body)).encode())],
                 "client": ("127.0.0.1", 1), "server": ("testserver", 80)}
        c.portal.call(c.app, scope, receive, send)
        gate.set()
        assert sent[0]["type"] == "http.response.start" and sent[0]["status"] == 499
        wait_until(lambda: worker.stats()["jobs_done"] - done >= 1, what="the busy job done")
        time.sleep(0.3)  # time for a wrongly run frame job to be counted too
        assert worker.stats()["jobs_done"] - done == 1
        assert 'status="499"' in c.get("/metrics").text

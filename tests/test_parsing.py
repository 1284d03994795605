"""Uploads are parsed in a child process under a time and a memory limit (service.parsing)."""

from __future__ import annotations

import functools
import pickle

import numpy as np
import pytest
import trimesh

from scenes import loaders
from service.parsing import ParseLimits, ParseMemoryLimit, ParseTimeLimit, parse_scene
from service.store import SceneStore
from tests.helpers import service

GIB = 1 << 30


@functools.cache
def sphere_glb(subdivisions: int) -> bytes:
    """An icosphere as GLB: 20 · 4^subdivisions triangles."""
    return trimesh.creation.icosphere(subdivisions=subdivisions).export(file_type="glb")


def test_child_parse_equals_the_loader() -> None:
    data = sphere_glb(3)
    here = loaders.load_scene_bytes(data, "glb", name="ball")
    there = parse_scene(data, "glb", "ball", None, ParseLimits(60.0, GIB))
    assert there.name == here.name and len(there.objects) == len(here.objects)
    for a, b in zip(there.objects, here.objects, strict=True):
        assert a.name == b.name and a.material == b.material
        for field in ("vertices", "faces", "normals"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))


def test_the_loaders_errors_come_back_whole() -> None:
    with pytest.raises(loaders.TriangleLimitError) as info:
        parse_scene(sphere_glb(3), "glb", "ball", 100, ParseLimits(60.0, GIB))
    assert (info.value.n_triangles, info.value.limit) == (1280, 100)
    with pytest.raises(loaders.SceneLoadError, match="shorter than the 20-byte header"):
        parse_scene(b"garbage", "glb", "x", None, ParseLimits(60.0, GIB))
    err = pickle.loads(pickle.dumps(loaders.TriangleLimitError("too many", 7, 3)))
    assert (str(err), err.n_triangles, err.limit) == ("too many", 7, 3)


def test_a_parse_past_the_time_limit_is_stopped() -> None:
    # 327,680 triangles take ~1 s to parse here; 0.05 s is far below that
    with pytest.raises(ParseTimeLimit, match=r"longer than 0\.05 s.*PARSE_TIMEOUT_S"):
        parse_scene(sphere_glb(7), "glb", "ball", None, ParseLimits(0.05, GIB))


def test_a_parse_past_the_memory_limit_is_stopped() -> None:
    # its vertex arrays alone are 4 MiB each, and trimesh keeps several copies
    with pytest.raises(ParseMemoryLimit, match=r"more than 16777216 bytes.*MAX_JOB_BYTES"):
        parse_scene(sphere_glb(7), "glb", "ball", None, ParseLimits(60.0, 16 << 20))
    # the same file within a sufficient limit
    assert parse_scene(sphere_glb(7), "glb", "ball", None, ParseLimits(60.0, GIB)).n_triangles == 327_680


def test_a_stored_upload_reloaded_past_the_limit_names_the_limit(tmp_path) -> None:
    store = SceneStore(tmp_path, parse=functools.partial(parse_scene, limits=ParseLimits(60.0, GIB)))
    meta, _ = store.put_upload(sphere_glb(7), "glb", "ball")
    reader = SceneStore(tmp_path, cleanup=False, parse=functools.partial(parse_scene, limits=ParseLimits(0.05, GIB)))
    with pytest.raises(ParseTimeLimit):  # the limit, not "stored source no longer loads" (500)
        reader.get_scene(meta.id)
    assert store.get_scene(meta.id).n_triangles == 327_680


def test_service_refuses_uploads_past_the_parse_limits_and_keeps_serving(tmp_path) -> None:
    with service(tmp_path, parse_timeout_s=0.05) as client:
        before = client.get("/scenes").json()
        r = client.post("/scenes?format=glb", content=sphere_glb(7), headers={"content-type": "model/gltf-binary"})
        assert r.status_code == 422, r.text
        assert "PARSE_TIMEOUT_S" in r.json()["detail"]
        assert client.get("/scenes").json() == before  # nothing stored
        small = client.post("/scenes?format=glb", content=sphere_glb(1), headers={"content-type": "model/gltf-binary"})
        assert small.status_code == 201, small.text
    with service(tmp_path, max_job_bytes=16 << 20) as client:
        r = client.post("/scenes", files={"file": ("ball.glb", sphere_glb(7))})
        assert r.status_code == 422, r.text
        assert "MAX_JOB_BYTES" in r.json()["detail"]
        r = client.post("/scenes", files={"file": ("ball.glb", sphere_glb(3))})
        assert r.status_code == 201 and r.json()["triangles"] == 1280


def test_without_a_fork_server_uploads_are_parsed_here_and_the_log_says_so(monkeypatch, caplog):
    """A read-only container without a writable temporary directory cannot start the
    fork server (its socket lives there): the service still takes uploads."""
    import service.parsing as parsing

    class NoServer:
        def Pipe(self, duplex: bool):  # noqa: N802 - multiprocessing's name
            return parsing.mp.Pipe(duplex)

        def Process(self, **kw):  # noqa: N802
            class P:
                def start(self) -> None:
                    raise FileNotFoundError("No usable temporary directory found")
            return P()

    monkeypatch.setattr(parsing, "_fork_context", lambda: NoServer())
    monkeypatch.setattr(parsing, "_warned", [])
    for _ in range(2):
        assert parse_scene(sphere_glb(1), "glb", "ball", None, ParseLimits(60.0, GIB)).n_triangles == 80
    logged = [r for r in caplog.records if "fork server" in r.getMessage()]
    assert len(logged) == 1 and "without PARSE_TIMEOUT_S" in logged[0].getMessage()

"""Uploads are parsed in a child process under a time and a memory limit (service.parsing)."""

from __future__ import annotations

import functools
import pickle
import time

import numpy as np
import pytest
import trimesh

from scenes import loaders
from service.parsing import ParseLimits, ParseMemoryLimit, ParseTimeLimit, parse_scene
from service.store import SceneStore
from tests.helpers import ROOT, service, wait_until

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
    # 1.3 M triangles take ~4 s to parse here, 80 take ~0.05 s: both ten times from 0.5 s
    with service(tmp_path, parse_timeout_s=0.5) as client:
        before = client.get("/scenes").json()
        r = client.post("/scenes?format=glb", content=sphere_glb(8), headers={"content-type": "model/gltf-binary"})
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
    fork server (its socket lives there): the service still takes uploads. With a usable
    one, a server that keeps refusing makes the upload 503 instead (ParseUnavailable)."""
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
    monkeypatch.setattr(parsing, "_temp_dir_usable", lambda: False)
    monkeypatch.setattr(parsing, "_warned", [])
    for _ in range(2):
        assert parse_scene(sphere_glb(1), "glb", "ball", None, ParseLimits(60.0, GIB)).n_triangles == 80
    logged = [r for r in caplog.records if "fork server" in r.getMessage()]
    assert len(logged) == 1 and "without PARSE_TIMEOUT_S" in logged[0].getMessage()
    monkeypatch.setattr(parsing, "_temp_dir_usable", lambda: True)
    with pytest.raises(parsing.ParseUnavailable, match="cannot start a process to parse the upload"):
        parse_scene(sphere_glb(1), "glb", "ball", None, ParseLimits(60.0, GIB))


def test_a_fork_server_whose_socket_is_gone_is_restarted_and_the_limits_hold() -> None:
    """A /tmp cleaner may remove the fork server's socket: the next parse restarts the
    server instead of parsing without limits."""
    import os
    from multiprocessing import forkserver

    parse_scene(sphere_glb(1), "glb", "ball", None, ParseLimits(60.0, GIB))  # the server runs
    os.unlink(forkserver._forkserver._forkserver_address)
    with pytest.raises(ParseTimeLimit):
        parse_scene(sphere_glb(7), "glb", "ball", None, ParseLimits(0.05, GIB))
    assert parse_scene(sphere_glb(1), "glb", "ball", None, ParseLimits(60.0, GIB)).n_triangles == 80


def test_a_timed_out_child_is_killed_even_when_its_fork_server_died() -> None:
    """The server's death makes the child look finished (its exit code comes through the
    server); it must be killed by pid all the same."""
    import os
    import signal
    import threading
    from multiprocessing import forkserver
    from pathlib import Path

    def forked() -> set[int]:
        """Live (not zombie) processes running the fork server's code: it and its children."""
        pids = set()
        for proc in Path("/proc").glob("[0-9]*"):
            try:
                if b"multiprocessing.forkserver" in (proc / "cmdline").read_bytes() and \
                        (proc / "stat").read_text().rsplit(")", 1)[1].split()[0] != "Z":
                    pids.add(int(proc.name))
            except OSError:
                continue
        return pids

    parse_scene(sphere_glb(1), "glb", "ball", None, ParseLimits(60.0, GIB))
    server = forkserver._forkserver._forkserver_pid
    before = forked()
    assert server in before
    threading.Timer(0.3, os.kill, (server, signal.SIGKILL)).start()
    with pytest.raises(ParseTimeLimit):
        parse_scene(sphere_glb(8), "glb", "ball", None, ParseLimits(0.8, GIB))
    time.sleep(0.2)
    assert forked() - before == set()  # the child was killed, not left running
    assert parse_scene(sphere_glb(1), "glb", "ball", None, ParseLimits(60.0, GIB)).n_triangles == 80  # a new server


def test_a_hard_address_space_limit_below_the_budget_caps_the_childs() -> None:
    """Under ``ulimit -v`` (LimitAS=) lower than the server's size plus MAX_JOB_BYTES the
    child cannot raise its limit to that: it keeps the hard one, and parses."""
    import subprocess
    import sys

    code = ("import resource, trimesh, sys\n"
            "from service.parsing import ParseLimits, parse_scene\n"
            "def main():\n"
            "    data = trimesh.creation.icosphere(subdivisions=1).export(file_type='glb')\n"
            "    limit = 6 << 30\n"
            "    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))\n"
            "    print(parse_scene(data, 'glb', 'b', None, ParseLimits(60.0, 7 << 30)).n_triangles)\n"
            "if __name__ == '__main__':\n"
            "    main()\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          cwd=str(ROOT), env={**__import__("os").environ, "PYTHONPATH": str(ROOT)})
    assert done.returncode == 0 and done.stdout.strip() == "80", done.stderr[-2000:]


def test_parses_wait_for_a_turn_at_most_the_time_limit() -> None:
    """As many parses at once as render workers (each may grow to MAX_JOB_BYTES); an
    upload that cannot get a turn within PARSE_TIMEOUT_S is 503 (ParseUnavailable)."""
    from service.parsing import ParseUnavailable, UploadParser

    parser = UploadParser(ParseLimits(0.3, GIB), concurrent=1)
    assert parser._slots.acquire(timeout=1)  # a parse in progress
    t0 = time.monotonic()
    with pytest.raises(ParseUnavailable, match=r"1 upload\(s\) are being parsed.*0.3 s \(PARSE_TIMEOUT_S\)"):
        parser(sphere_glb(1), "glb", "ball", None)
    assert 0.25 < time.monotonic() - t0 < 5
    parser._slots.release()
    assert parser(sphere_glb(1), "glb", "ball", None).n_triangles == 80


def test_uploads_waiting_for_a_parse_hold_no_thread_other_routes_need(tmp_path) -> None:
    """Uploads queued behind a parse wait without a thread of the pool every route
    shares: with 45 of them waiting (more than the pool's 40 threads) the scene list
    still answers at once, and each upload is stored once the parse slot frees."""
    from concurrent.futures import ThreadPoolExecutor

    # a parse turn each, one after another: PARSE_TIMEOUT_S far above 45 parses on a slow host
    with service(tmp_path, ready=False, parse_timeout_s=300) as c, ThreadPoolExecutor(46) as pool:
        slots = c.app.state.store.parse._slots
        assert slots.acquire(timeout=1)  # a parse in progress (one render worker: one at a time)
        try:
            uploads = [pool.submit(c.post, "/scenes", content=f"v 0 0 0\nv 1 0 0\nv 0 1 {k + 1}\nf 1 2 3\n".encode(),
                                   headers={"content-type": "model/obj"}) for k in range(45)]
            time.sleep(1.0)
            listed = pool.submit(c.get, "/scenes")
            try:
                status = listed.result(timeout=5).status_code
            except TimeoutError:
                status = None
        finally:
            slots.release()
        assert status == 200, "GET /scenes waited behind the queued uploads"
        assert sorted(u.result(timeout=120).status_code for u in uploads) == [201] * 45


def test_uploads_past_the_pending_bytes_are_503_before_their_body_is_read(tmp_path) -> None:
    """The bytes uploads in progress hold (received, waiting for a parse, parsed) are
    capped: with one 200-byte upload waiting for its parse, a second that would take the
    total past 300 bytes is 503 at once, naming the limit; once the first is stored the
    second goes through, and an upload alone is admitted whatever its size. An upload
    stored before is answered at once, without waiting for the parse turn."""
    from concurrent.futures import ThreadPoolExecutor

    def obj(k: int, size: int) -> bytes:
        body = f"v 0 0 0\nv 1 0 0\nv 0 1 {k + 1}\nf 1 2 3\n".encode()
        return body + b"#" * (size - len(body) - 1) + b"\n"

    def upload(c, body: bytes):
        return c.post("/scenes", content=body, headers={"content-type": "model/obj"})

    with service(tmp_path, ready=False, max_pending_upload_bytes=300, parse_timeout_s=10) as c, \
            ThreadPoolExecutor(2) as pool:
        assert upload(c, obj(0, 400)).status_code == 201  # alone: admitted past the budget
        assert upload(c, obj(5, 90)).status_code == 201
        slots = c.app.state.store.parse._slots
        assert slots.acquire(timeout=1)  # a parse in progress: the next upload waits for its turn
        try:
            first = pool.submit(upload, c, obj(1, 200))
            wait_until(lambda: c.app.state.pending_uploads.count == 1, 10)
            t0 = time.monotonic()
            second = upload(c, obj(2, 200))
            assert second.status_code == 503 and time.monotonic() - t0 < 5, second.text
            assert "DEPTHVIEW_MAX_PENDING_UPLOAD_BYTES" in second.json()["detail"] and "Retry-After" in second.headers
        finally:
            slots.release()
            # content stored before is answered at once, without waiting for a parse turn
            t0 = time.monotonic()
            again = upload(c, obj(5, 90))
            assert again.status_code == 200 and time.monotonic() - t0 < 5, again.text
        assert first.result(timeout=60).status_code == 201
        assert c.app.state.pending_uploads.bytes == 0 and c.app.state.pending_uploads.count == 0
        assert upload(c, obj(2, 200)).status_code == 201

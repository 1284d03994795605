"""Render worker processes (DEPTHVIEW_WORKERS ≥ 1, ``service.process_worker``): jobs
run in child processes with their own GL context; a killed or stuck worker is replaced
and the next request succeeds; a stream's reuser stays on one worker."""

from __future__ import annotations

import os
import signal
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import pytest

from service import image_io
from service.config import Settings, default_workers
from service.process_worker import ProcessWorkerPool
from service.store import builtin_id
from service.worker import JobExpired, WorkerDied
from tests.helpers import (
    MIRROR_CAMERA,
    MIRROR_CAMERA_MOVED,
    frame_camera,
    obj_text,
    service,
    service_client,
    wait_until,
)

CORNELL = builtin_id("cornell")


@dataclass(frozen=True)
class Sleep:
    """A picklable job that sleeps (in the worker process) and returns its pid."""

    seconds: float

    def __call__(self, state) -> int:
        time.sleep(self.seconds)
        return os.getpid()


def frame(c, **extra):
    return c.post(f"/scenes/{CORNELL}/frames",
                  json={"camera": frame_camera(), "width": 32, "height": 24, **extra})


client = service_client(workers=1, job_timeout_s=20.0)


def test_workers_setting():
    assert Settings().workers == default_workers() >= 1  # worker processes by default
    assert Settings.from_env({"DEPTHVIEW_WORKERS": "0"}).workers == 0  # the in-process worker thread
    assert Settings.from_env({"DEPTHVIEW_WORKERS": "3"}).workers == 3
    assert Settings.from_env({"DEPTHVIEW_WORKERS": "auto"}).workers == default_workers() >= 1
    for bad in ("-1", "many"):
        with pytest.raises(ValueError):
            Settings.from_env({"DEPTHVIEW_WORKERS": bad})


def test_default_workers_obey_a_cgroup_cpu_quota(tmp_path, monkeypatch):
    from service import config

    cpu_max = tmp_path / "cpu.max"
    monkeypatch.setattr(config, "CGROUP_CPU_MAX", cpu_max)
    monkeypatch.setattr(config, "CGROUP_V1_CPU", tmp_path / "no-v1")
    monkeypatch.setattr(config, "nvidia_gpus", lambda: 0)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(64)), raising=False)
    assert config.cgroup_cpu_limit() is None and config.default_workers() == 32  # no file: no quota
    for text, cores, workers in (("max 100000\n", None, 32), ("200000 100000\n", 2, 1),
                                 ("150000 100000\n", 2, 1), ("800000 100000\n", 8, 4),
                                 ("50000 100000\n", 1, 1), ("12800000 100000\n", 128, 32)):
        cpu_max.write_text(text)
        assert config.cgroup_cpu_limit() == cores, text
        assert config.default_workers() == workers, text
    # cgroup v1 (no cpu.max): cpu.cfs_quota_us / cpu.cfs_period_us, -1 = no quota
    cpu_max.unlink()
    v1 = tmp_path / "v1"
    v1.mkdir()
    (v1 / "cpu.cfs_period_us").write_text("100000\n")
    for quota, cores in (("-1", None), ("300000", 3)):
        (v1 / "cpu.cfs_quota_us").write_text(quota + "\n")
        assert config.cgroup_cpu_limit(v1_dir=v1) == cores, quota
    monkeypatch.setattr(config, "nvidia_gpus", lambda: 4)
    assert config.default_workers() == 4  # one per GPU, whatever the CPU quota


def test_worker_processes_spread_over_the_nvidia_gpus(monkeypatch):
    from service import process_worker
    from service.process_worker import WorkerConfig

    def pool(workers, gpus, device=None):
        monkeypatch.setattr(process_worker, "nvidia_gpus", lambda: gpus)
        p = ProcessWorkerPool(workers, WorkerConfig("data", 1, None, 1, None, device))
        return [p.device(i) for i in range(p.workers)]

    assert pool(4, 4) == [0, 1, 2, 3]  # DEPTHVIEW_WORKERS=auto: one per GPU, each on its own
    assert pool(5, 2) == [0, 1, 0, 1, 0]  # more workers than GPUs: round robin
    assert pool(2, 1) == [None, None]  # one GPU (or none): the default device
    assert pool(2, 0) == [None, None]
    assert pool(3, 4, device=2) == [2, 2, 2]  # DEPTHVIEW_GL_DEVICE pins them all

    # the worker process is started with its slot's device
    started = []

    class FakeProcess:
        exitcode = 1

        def __init__(self, target, args, name, daemon):
            started.append((name, args[1].device))

        def start(self):
            pass

        def is_alive(self):
            return False

    monkeypatch.setattr(process_worker, "nvidia_gpus", lambda: 2)
    p = ProcessWorkerPool(3, WorkerConfig("data", 1, None, 1, None, None))
    p._ctx = SimpleNamespace(Pipe=p._ctx.Pipe, Process=FakeProcess)  # not the shared spawn context
    for slot in p._slots:
        p._spawn(slot)
    assert started == [("depthview-gl-0", 0), ("depthview-gl-1", 1), ("depthview-gl-2", 0)]
    assert p.config.device is None


def test_frames_render_in_a_worker_process(client, tmp_path):
    pool = client.app.state.worker
    assert isinstance(pool, ProcessWorkerPool) and pool.alive == 1
    assert pool.pids[0] != os.getpid()
    r = frame(client)
    assert r.status_code == 200, r.text
    with service(tmp_path) as thread_client:  # the same frame from the worker thread
        ref = frame(thread_client)
    np.testing.assert_array_equal(image_io.decode_png(r.content), image_io.decode_png(ref.content))
    assert frame(client, effects={"reflections": "raytrace", "glossy_rays": 1}).status_code == 200
    assert "depthview_workers_alive 1" in client.get("/metrics").text


def test_a_killed_worker_fails_its_job_naming_it_and_is_replaced(client):
    pool: ProcessWorkerPool = client.app.state.worker
    replaced = pool.workers_replaced
    pid = pool.pids[0]
    fut = pool.submit(Sleep(30), label="sleepy job")
    wait_until(lambda: pool.busy, 10)
    os.kill(pid, signal.SIGKILL)
    with pytest.raises(WorkerDied, match=f"process {pid} died .*sleepy job"):
        fut.result(30)
    r = frame(client)  # the next request succeeds on the replacement
    assert r.status_code == 200, r.text
    assert pool.pids[0] not in (None, pid) and pool.workers_replaced == replaced + 1
    idle = pool.pids[0]
    os.kill(idle, signal.SIGKILL)  # killed while idle: replaced without waiting for a request
    ready_while_dead = []  # /readyz must not say ready while no worker process is alive
    deadline = time.monotonic() + 30
    while pool.workers_replaced < replaced + 2 and time.monotonic() < deadline:
        if pool.alive == 0:
            ready_while_dead.append(pool.ready)
    assert ready_while_dead and not any(ready_while_dead)
    wait_until(lambda: pool.workers_replaced == replaced + 2 and pool.ready, 30)
    text = client.get("/metrics").text
    assert pool.pids[0] != idle and "depthview_workers_alive 1" in text
    assert f"depthview_workers_replaced_total {replaced + 2}" in text
    assert "depthview_gpu_scenes_cached" not in text  # in the processes: not reported as 0
    assert frame(client).status_code == 200


def test_a_worker_stuck_past_the_time_limit_is_killed_and_replaced(client):
    pool: ProcessWorkerPool = client.app.state.worker
    pid = pool.pids[0]
    t0 = time.monotonic()
    with pytest.raises(JobExpired, match=f"process {pid} was killed"):
        pool.submit(Sleep(60), timeout=1.0, label="stuck").result(30)
    assert time.monotonic() - t0 < 10
    assert frame(client).status_code == 200 and pool.pids[0] != pid


def test_an_unpicklable_job_is_refused_and_the_worker_lives_on(client):
    pool: ProcessWorkerPool = client.app.state.worker
    pid = pool.pids[0]
    with pytest.raises(TypeError, match="cannot be sent to a worker process"):
        pool.submit(lambda state: 1, label="closure").result(30)
    assert pool.submit(Sleep(0)).result(30) == pid


def stream_frame(ws, msg: dict, id_: int) -> dict:
    ws.send_json({**msg, "id": id_})
    while True:
        m = ws.receive_json()
        assert m.get("type") != "error", m
        ws.receive_bytes()
        if m.get("id") == id_ and not m.get("rest"):
            return m


MIRROR_VIEW = {"camera": MIRROR_CAMERA, "width": 64, "height": 48,
               "effects": {"reflections": "cluster"}}
MIRROR_MOVED = {**MIRROR_VIEW, "camera": MIRROR_CAMERA_MOVED}


def test_a_stream_is_pinned_to_one_worker_and_reuses_there(client):
    pool: ProcessWorkerPool = client.app.state.worker
    with client.websocket_connect(f"/scenes/{builtin_id('mirror')}/stream") as ws:
        ws.receive_json()
        metas = [stream_frame(ws, MIRROR_VIEW, 1), stream_frame(ws, MIRROR_MOVED, 2)]
        assert len(pool._pins) == 1
    assert metas[0]["keyframe"] is True and metas[1]["keyframe"] is False and metas[1]["reused_ratio"] > 0.5
    wait_until(lambda: not pool._pins, 10)  # the socket closed: the pin (and the reuser) is released


def test_a_stream_whose_worker_dies_starts_over_on_the_replacement(client):
    pool: ProcessWorkerPool = client.app.state.worker
    with client.websocket_connect(f"/scenes/{builtin_id('mirror')}/stream") as ws:
        ws.receive_json()
        assert stream_frame(ws, MIRROR_VIEW, 1)["keyframe"] is True
        replaced, pid = pool.workers_replaced, pool.pids[0]
        os.kill(pid, signal.SIGKILL)
        wait_until(lambda: pool.workers_replaced == replaced + 1 and pool.ready, 30)
        assert not pool._pins  # the reuser died with its worker
        m = stream_frame(ws, MIRROR_MOVED, 2)  # the stream goes on: a new reuser, a keyframe
        assert m["keyframe"] is True and pool.pids[0] != pid


def test_queue_full_is_503_and_stop_ends_a_busy_worker_at_once(tmp_path):
    with service(tmp_path, workers=1, queue_size=1, retry_after_s=4) as c:
        pool: ProcessWorkerPool = c.app.state.worker
        busy = pool.submit(Sleep(60), label="long")
        wait_until(lambda: pool.busy, 10)
        queued = pool.submit(Sleep(0))
        r = frame(c)
        assert r.status_code == 503 and r.headers["retry-after"] == "4" and "queue is full" in r.json()["detail"]
        pid = pool.pids[0]
        t0 = time.monotonic()
    assert time.monotonic() - t0 < 10  # the lifespan's stop did not wait for the 60 s job
    with pytest.raises(Exception, match="shutting down"):
        busy.result(5)
    with pytest.raises(Exception, match="shutting down"):
        queued.result(5)
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)


@dataclass(frozen=True)
class LoseContext:
    """A picklable job that releases the worker's GL context under it and fails."""

    def __call__(self, state) -> None:
        state.gl.ctx.release()
        raise RuntimeError("context released")


def test_a_worker_whose_context_fails_is_replaced(client):
    pool: ProcessWorkerPool = client.app.state.worker
    pid, replaced = pool.pids[0], pool.workers_replaced
    with pytest.raises(RuntimeError, match="context released"):
        pool.submit(LoseContext()).result(30)
    assert frame(client).status_code == 200  # on the replacement
    assert pool.pids[0] != pid and pool.workers_replaced == replaced + 1


def test_the_handler_answers_503_naming_the_dead_worker(client):
    """Through the routes' Render.job: the in-flight request of a killed worker."""
    import asyncio

    from fastapi import HTTPException

    from service.deps import get_render

    pool: ProcessWorkerPool = client.app.state.worker
    pid = pool.pids[0]
    r = get_render(type("Req", (), {"app": client.app})())

    async def run():
        task = asyncio.ensure_future(r.job(Sleep(30), "sleepy frame"))
        while not pool.busy:
            await asyncio.sleep(0.02)
        os.kill(pid, signal.SIGKILL)
        return await task

    with pytest.raises(HTTPException) as info:
        asyncio.run(run())
    assert info.value.status_code == 503 and info.value.headers["Retry-After"]
    assert f"process {pid} died (exit code -9)" in info.value.detail and "sleepy frame" in info.value.detail
    assert frame(client).status_code == 200


def test_uploaded_scenes_load_in_the_worker_by_id(client):
    r = client.post("/scenes", files={"file": ("quad.obj", obj_text(2), "text/plain")})
    assert r.status_code == 201, r.text  # a new upload (200: the same content was stored before)
    sid = r.json()["id"]
    cam = {"eye": [0.5, 0.5, 3.0], "target": [0.5, 0.5, 0.0]}
    r = client.post(f"/scenes/{sid}/frames", json={"camera": cam, "width": 16, "height": 16})
    assert r.status_code == 200, r.text
    r = client.delete(f"/scenes/{sid}")
    assert r.status_code == 204 and r.content == b"", r.text
    r = client.post(f"/scenes/{sid}/frames", json={"camera": cam, "width": 16, "height": 16})
    assert r.status_code == 404


def test_a_scene_deleted_while_its_frame_waits_is_404(client):
    """The worker process loads a job's scene by id when the job starts: a scene
    deleted while its frame waits in the queue answers that frame 404, not 500."""
    pool: ProcessWorkerPool = client.app.state.worker
    r = client.post("/scenes", files={"file": ("quad3.obj", obj_text(3), "text/plain")})
    assert r.status_code == 201, r.text
    sid = r.json()["id"]
    blocker = pool.submit(Sleep(2.0), label="blocker")
    wait_until(lambda: pool.busy, 10)
    with ThreadPoolExecutor(1) as ex:
        waiting = ex.submit(client.post, f"/scenes/{sid}/frames",
                            json={"camera": {"eye": [0.5, 0.5, 3.0], "target": [0.5, 0.5, 0.0]},
                                  "width": 16, "height": 16})
        wait_until(lambda: pool.queue_depth == 1, 10)  # the frame waits behind the blocker
        assert client.delete(f"/scenes/{sid}").status_code == 204
        r = waiting.result(60)
    blocker.result(30)
    assert r.status_code == 404, r.text
    assert sid[:12] in r.json()["detail"]


def test_two_workers_share_the_queue_and_pin_streams_apart(tmp_path):
    with service(tmp_path, workers=2) as c:
        pool: ProcessWorkerPool = c.app.state.worker
        wait_until(lambda: all(s.ready for s in pool._slots), 60)
        assert len(set(pool.pids)) == 2 and "depthview_workers_alive 2" in c.get("/metrics").text
        futures = [pool.submit(Sleep(0.3)) for _ in range(4)]
        assert {f.result(30) for f in futures} == set(pool.pids)  # both took jobs
        a = [pool.submit(Sleep(0), pin="stream-a").result(30) for _ in range(3)]
        b = [pool.submit(Sleep(0), pin="stream-b").result(30) for _ in range(3)]
        assert len(set(a)) == 1 and len(set(b)) == 1 and a[0] != b[0]
        pool.run_before_next_job(Sleep(0), pin="stream-a")
        assert "stream-a" not in pool._pins and "stream-b" in pool._pins


def test_a_request_cancelled_while_its_job_waits_drops_the_job_and_logs_nothing(caplog):
    """A stopping service cancels requests still in flight after its grace period: the
    job's future is cancelled with it (a queued job never runs), and a worker failing it
    later (shutting down) leaves no 'Future exception was never retrieved' error."""
    import asyncio
    import gc
    from concurrent.futures import Future

    from service.deps import Render
    from service.worker import WorkerUnavailable

    class StillConnected:
        async def receive(self) -> dict:
            await asyncio.sleep(3600)
            return {"type": "http.disconnect"}

    async def scenario() -> Future:
        fut: Future = Future()
        render = Render(settings=None, store=None, worker=None, metrics=None, request=StillConnected())
        task = asyncio.ensure_future(render._result(fut, 60.0))
        await asyncio.sleep(0.05)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        if not fut.cancelled():
            fut.set_exception(WorkerUnavailable("render worker is shutting down"))
        await asyncio.sleep(0.05)
        return fut

    with caplog.at_level("ERROR"):
        fut = asyncio.run(scenario())
        gc.collect()
    assert fut.cancelled()
    assert not [r for r in caplog.records if "never retrieved" in r.getMessage()]

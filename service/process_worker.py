"""Render worker processes (issue 15, item 4): ``DEPTHVIEW_WORKERS`` ≥ 1.

``ProcessWorkerPool`` has the ``RenderWorker`` interface (``submit`` → Future,
``forget``, ``run_before_next_job``, ``stats``, ``ready``, ``stop`` …) but runs jobs in
N child processes (multiprocessing "spawn"), each with its own GL context, Embree
devices, scene store reader (content-addressed: any worker loads any id) and GPU
upload cache. Jobs must be picklable (``service.jobs``: specs naming the scene by its
address); results (numpy arrays, bytes) come back over a pipe.

The main process keeps the bounded queue (full → ``QueueFull``, HTTP 503) and the
deadlines: one dispatcher thread per worker process takes the next job (its pinned
jobs first, then the shared ones), skips it when its deadline passed or its future was
cancelled (``JobExpired``), sends it and waits at most until the deadline. A worker
still busy at the deadline is killed and replaced (the job gets ``JobExpired``, 504); a
worker that dies gets ``WorkerDied`` for its job (503 naming the process; nothing is
retried silently) and is replaced, so the next request succeeds; so is a worker whose
GL context stops working (checked after a job fails: the job gets its own error).

``submit(..., pin=key)`` sends every job with that key to the same worker (a stream's
stateful ReflectionReuser lives in one process); ``run_before_next_job(fn, pin=key)``
runs a chore there and drops the pin.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field, replace
from multiprocessing.reduction import ForkingPickler
from typing import Any

from service.config import nvidia_gpus
from service.worker import (
    GLState,
    Job,
    JobExpired,
    QueueFull,
    WorkerDied,
    WorkerUnavailable,
    _Job,
    count_job,
    end_job,
)

log = logging.getLogger("depthview.worker")

#: Seconds a new worker process may take to import, create its GL context and report.
STARTUP_TIMEOUT_S = 120.0
#: How long to wait for a worker process whose pipe broke to be reaped (its exit code).
DEATH_REAP_S = 2.0
#: How often an idle dispatcher checks that its worker process is still alive.
IDLE_CHECK_S = 0.5


@dataclass(frozen=True)
class WorkerConfig:
    """What a worker process needs to start (picklable)."""

    data_dir: str
    scene_cache_size: int
    max_triangles: int | None
    gpu_cache_size: int
    backend: str | None
    device: int | None
    reconstruction_cache_bytes: int = 0
    keep_pixels: int | None = None


def _child_main(conn: Any, cfg: WorkerConfig) -> None:
    """A worker process: create the GL state, then run what the pipe sends."""
    from gl_passes.context import create_gl_context
    from gl_passes.gbuffer import GBufferPass
    from service.store import SceneStore

    try:
        store = SceneStore(cfg.data_dir, cfg.scene_cache_size, cfg.max_triangles, cleanup=False)
        gl = create_gl_context(cfg.backend, cfg.device)
        state = GLState(gl=gl, gbuffer=GBufferPass(gl), gpu_cache_size=cfg.gpu_cache_size,
                        reconstruction_cache_bytes=cfg.reconstruction_cache_bytes, keep_pixels=cfg.keep_pixels,
                        scene_loader=store.get_scene)
    except BaseException as exc:  # noqa: BLE001 - reported to the parent
        conn.send(("failed", f"{type(exc).__name__}: {exc}"))
        return
    conn.send(("ready", {"renderer": gl.renderer, "backend": gl.backend, "gl_version": getattr(gl, "version", None),
                         "is_software": bool(gl.is_software)}))
    try:
        while True:
            try:
                kind, payload = conn.recv()
            except (EOFError, OSError):
                break
            if kind == "stop":
                break
            if kind == "forget":
                state.forget(payload)
                end_job(state)
            elif kind == "chore":
                try:
                    payload(state)
                except Exception:  # noqa: BLE001 - a failed chore must not end the worker
                    log.exception("worker chore failed")
                end_job(state)
            elif kind == "job":
                lost = None
                try:
                    reply: tuple = ("ok", payload(state), None)
                except BaseException as exc:  # noqa: BLE001 - delivered to the future
                    lost = _context_lost(state)
                    reply = ("err", exc, lost)
                try:
                    conn.send(reply)
                except Exception as exc:  # noqa: BLE001 - an unpicklable result or exception
                    conn.send(("err", RuntimeError(f"job result could not be sent: {type(exc).__name__}: {exc}"),
                               lost))
                if lost is not None:  # the parent replaces this worker; a broken context is not released
                    log.error("render worker process %d: GL context failed (%s), exiting", os.getpid(), lost)
                    os._exit(3)
                end_job(state)
    finally:
        state.release()


def _context_lost(state: GLState) -> str | None:
    """Why the GL context no longer works (after a job failed), or None when it does."""
    try:
        state.gl.ctx.finish()
    except Exception as exc:  # noqa: BLE001 - any failure means the context is unusable
        return f"{type(exc).__name__}: {exc}"
    return None


@dataclass
class _Slot:
    """One worker process and what the main process knows of it."""

    index: int
    pinned: deque = field(default_factory=deque)
    chores: list = field(default_factory=list)
    process: Any = None
    conn: Any = None
    ready: bool = False
    busy: bool = False
    restarts: int = 0

    @property
    def alive(self) -> bool:
        """Its process exists and runs."""
        return self.process is not None and self.process.is_alive()


class ProcessWorkerPool:
    """N render worker processes behind one bounded queue (see the module docstring)."""

    def __init__(self, workers: int, config: WorkerConfig, queue_size: int = 32, job_timeout_s: float = 120.0) -> None:
        self.workers = max(1, int(workers))
        self.config = config
        self.queue_size = int(queue_size)
        self.job_timeout_s = float(job_timeout_s)
        self._ctx = mp.get_context("spawn")
        self._cv = threading.Condition()
        self._shared: deque[_Job] = deque()
        self._slots = [_Slot(i) for i in range(self.workers)]
        self._gpus = nvidia_gpus()
        self._pins: dict[str, int] = {}
        self._threads = [threading.Thread(target=self._dispatch, args=(s,), name=f"depthview-dispatch-{s.index}",
                                          daemon=True) for s in self._slots]
        self._started = threading.Event()
        self._stopping = False
        self.startup_error: str | None = None
        self.renderer: str | None = None
        self.backend: str | None = None
        self.gl_version: str | None = None
        self.is_software: bool | None = None
        self.jobs_submitted = self.jobs_done = self.jobs_failed = self.jobs_expired = self.jobs_rejected = 0
        self.workers_replaced = 0
        self.job_seconds_sum = self.queue_wait_seconds_sum = self.last_job_seconds = 0.0
        self.job_seconds_count = 0

    # --- lifecycle -----------------------------------------------------------------
    def start(self) -> ProcessWorkerPool:
        for t in self._threads:
            t.start()
        return self

    def wait_ready(self, timeout: float | None = None) -> bool:
        self._started.wait(timeout)
        return self.ready

    @property
    def ready(self) -> bool:
        return not self._stopping and any(s.ready and s.alive for s in self._slots)

    @property
    def alive(self) -> int:
        """Worker processes alive."""
        return sum(1 for s in self._slots if s.alive)

    @property
    def busy(self) -> bool:
        return any(s.busy for s in self._slots)

    @property
    def pids(self) -> list[int | None]:
        return [s.process.pid if s.process is not None else None for s in self._slots]

    def stop(self, timeout: float = 30.0) -> None:
        with self._cv:
            if self._stopping:
                return
            self._stopping = True
            queued = list(self._shared) + [j for s in self._slots for j in s.pinned]
            self._shared.clear()
            for s in self._slots:
                s.pinned.clear()
            self._cv.notify_all()
        for job in queued:
            if job.future.set_running_or_notify_cancel():
                job.future.set_exception(WorkerUnavailable("render worker is shutting down"))
        for t in self._threads:
            t.join(timeout)

    # --- submitting ------------------------------------------------------------------
    def submit(self, fn: Job, timeout: float | None = None, label: str = "", pin: str | None = None) -> Future:
        """Queue the picklable job `fn` (on the pinned worker when `pin` is given)."""
        if self.startup_error is not None and not self.ready:
            raise WorkerUnavailable(f"no GL context: {self.startup_error}")
        now = time.monotonic()
        job = _Job(fn=fn, future=Future(), deadline=now + (self.job_timeout_s if timeout is None else timeout),
                   submitted=now, label=label)
        with self._cv:
            if self._stopping:
                raise WorkerUnavailable("render worker is not running")
            if self._queued() >= self.queue_size:
                self.jobs_rejected += 1
                raise QueueFull(f"render queue is full ({self.queue_size} jobs waiting)")
            if pin is None:
                self._shared.append(job)
            else:
                self._slots[self._pin_slot(pin)].pinned.append(job)
            self.jobs_submitted += 1
            self._cv.notify_all()
        return job.future

    def _queued(self) -> int:
        return len(self._shared) + sum(len(s.pinned) for s in self._slots)

    def _pin_slot(self, pin: str) -> int:
        if pin not in self._pins:  # the worker with the fewest pins
            counts = [0] * self.workers
            for i in self._pins.values():
                counts[i] += 1
            self._pins[pin] = counts.index(min(counts))
        return self._pins[pin]

    def forget(self, key: str) -> None:
        """Every worker releases the GPU upload cached under `key` before its next job."""
        with self._cv:
            for s in self._slots:
                s.chores.append(("forget", key))
            self._cv.notify_all()

    def run_before_next_job(self, fn: Callable[[GLState], Any], pin: str | None = None) -> None:
        """Run the picklable `fn(state)` before the next job of the worker `pin` is pinned
        to (every worker when None), outside the queue; drops the pin."""
        with self._cv:
            index = self._pins.pop(pin, None) if pin is not None else None
            for s in self._slots:
                if index is None or s.index == index:
                    s.chores.append(("chore", fn))
            self._cv.notify_all()

    # --- introspection -------------------------------------------------------------------
    @property
    def queue_depth(self) -> int:
        with self._cv:
            return self._queued()

    def stats(self) -> dict[str, Any]:
        with self._cv:
            return {
                "ready": self.ready, "alive": self.alive, "workers": self.workers,
                "workers_replaced": self.workers_replaced,
                "jobs_submitted": self.jobs_submitted, "jobs_done": self.jobs_done,
                "jobs_failed": self.jobs_failed, "jobs_expired": self.jobs_expired,
                "jobs_rejected": self.jobs_rejected, "job_seconds_sum": self.job_seconds_sum,
                "job_seconds_count": self.job_seconds_count, "queue_wait_seconds_sum": self.queue_wait_seconds_sum,
                "last_job_seconds": self.last_job_seconds, "queue_depth": self._queued(),
                "queue_capacity": self.queue_size, "busy": self.busy,
                "gpu_scenes_cached": None,  # each process keeps its own upload cache
            }

    # --- the worker processes ---------------------------------------------------------------
    def device(self, index: int) -> int | None:
        """The EGL device of worker process index: the configured one, else with several
        NVIDIA GPUs device index mod their count (the NVIDIA EGL vendor's devices come
        first: glvnd loads it before Mesa's), else None (the default device)."""
        if self.config.device is not None:
            return self.config.device
        return index % self._gpus if self._gpus > 1 else None

    def _spawn(self, slot: _Slot) -> None:
        """Start slot's process and wait for its GL context (sets ready / startup_error)."""
        parent, child = self._ctx.Pipe()
        cfg = replace(self.config, device=self.device(slot.index))
        proc = self._ctx.Process(target=_child_main, args=(child, cfg), name=f"depthview-gl-{slot.index}",
                                 daemon=True)
        proc.start()
        child.close()
        slot.process, slot.conn, slot.ready = proc, parent, False
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        while time.monotonic() < deadline and not self._stopping:
            if parent.poll(0.1):
                try:
                    kind, info = parent.recv()
                except (EOFError, OSError):
                    kind, info = "failed", f"worker process exited with code {proc.exitcode}"
                break
            if not proc.is_alive():
                kind, info = "failed", f"worker process exited with code {proc.exitcode}"
                break
        else:
            kind, info = "failed", "stopping" if self._stopping else "worker process did not start in time"
        if self._stopping:
            self._kill(slot)
            return
        if kind == "ready":
            slot.ready = True
            self.renderer, self.backend = info["renderer"], info["backend"]
            self.gl_version, self.is_software = info["gl_version"], info["is_software"]
            self.startup_error = None
            log.info("render worker process %d (pid %d) ready: %s", slot.index, proc.pid, self.renderer)
        else:
            self.startup_error = str(info)
            log.error("render worker process %d could not start: %s", slot.index, info)
            self._kill(slot)

    def _kill(self, slot: _Slot) -> None:
        slot.ready = False
        if slot.alive:
            slot.process.kill()
            slot.process.join(5)
        if slot.conn is not None:
            slot.conn.close()

    def _replace(self, slot: _Slot, why: str) -> None:
        log.warning("replacing render worker process %d: %s", slot.index, why)
        self._kill(slot)
        with self._cv:
            self.workers_replaced += 1
            slot.restarts += 1
            for pin in [p for p, i in self._pins.items() if i == slot.index]:
                del self._pins[pin]  # its per-stream state died with the process
            slot.chores = [c for c in slot.chores if c[0] == "forget"]
        self._spawn(slot)

    def _dispatch(self, slot: _Slot) -> None:
        self._spawn(slot)
        self._started.set()
        try:
            while True:
                with self._cv:
                    while not self._stopping and not slot.pinned and not self._shared and not slot.chores:
                        self._cv.wait(IDLE_CHECK_S)
                        if slot.ready and not slot.process.is_alive():
                            break  # died while idle: replaced at once, not when the next job comes
                    if self._stopping:
                        return
                    chores, slot.chores = slot.chores, []
                    job = slot.pinned.popleft() if slot.pinned else (self._shared.popleft() if self._shared else None)
                try:
                    if not slot.ready:
                        self._spawn(slot)
                    elif not slot.process.is_alive():  # died while idle: replace it before the next job
                        self._replace(slot, f"process {slot.process.pid} died (exit code {slot.process.exitcode})")
                    for chore in chores:
                        self._send(slot, chore)
                    if job is not None:
                        self._execute(slot, job)
                except Exception as exc:  # noqa: BLE001 - the dispatcher must outlive any failure
                    log.exception("render worker dispatcher %d failed", slot.index)
                    if job is not None and not job.future.done():
                        job.future.set_exception(exc)
        finally:
            if slot.conn is not None and slot.alive:
                self._send(slot, ("stop", None))
                slot.process.join(10)
            self._kill(slot)

    def _send(self, slot: _Slot, message: tuple) -> bool:
        try:
            slot.conn.send(message)
            return True
        except (OSError, ValueError, AttributeError):  # a dead worker: the next job replaces it
            return False
        except Exception:  # noqa: BLE001 - a chore that does not pickle
            log.exception("could not send %s to render worker process %d", message[0], slot.index)
            return False

    def _execute(self, slot: _Slot, job: _Job) -> None:
        fut = job.future
        if not fut.set_running_or_notify_cancel() or time.monotonic() > job.deadline:
            if fut.running():
                fut.set_exception(JobExpired("render job expired in the queue before it started"))
            with self._cv:
                self.jobs_expired += 1
            return
        if not slot.ready:
            fut.set_exception(WorkerUnavailable(f"no GL context: {self.startup_error}"))
            with self._cv:
                self.jobs_failed += 1
            return
        waited = time.monotonic() - job.submitted
        t0 = time.perf_counter()
        slot.busy = True
        pid = slot.process.pid
        try:
            try:
                data = ForkingPickler.dumps(("job", job.fn))
            except Exception as exc:  # noqa: BLE001 - the job does not pickle
                outcome: tuple = ("err", TypeError(f"{job.label or 'render job'} cannot be sent to a worker "
                                                   f"process: {type(exc).__name__}: {exc}"))
            else:
                try:
                    slot.conn.send_bytes(data)
                except (OSError, ValueError):
                    outcome = ("died", None)
                else:
                    outcome = self._wait(slot, job)
        finally:
            slot.busy = False
        kind, value = outcome
        with self._cv:  # counted before it is delivered: whoever sees the result sees the job counted
            count_job(self, {"ok": "done", "timeout": "expired"}.get(kind, "failed"), time.perf_counter() - t0, waited)
        if kind == "ok":
            fut.set_result(value)
        elif kind == "err":
            fut.set_exception(value)
        elif kind == "lost":  # the job failed and took the context along: replace the worker
            fut.set_exception(value[0])
            self._replace(slot, f"process {pid}: GL context failed ({value[1]})")
        elif kind == "timeout":
            fut.set_exception(JobExpired(f"{job.label or 'render job'} ran past its time limit; "
                                         f"render worker process {pid} was killed and is being replaced"))
            self._replace(slot, f"job {job.label!r} ran past its time limit")
        else:
            slot.process.join(DEATH_REAP_S)  # the pipe broke first: reap it for its exit code (-9: SIGKILL)
            code = slot.process.exitcode
            fut.set_exception(WorkerDied(f"render worker process {pid} died (exit code {code}) while running "
                                         f"{job.label or 'a render job'}; it is being replaced"))
            self._replace(slot, f"process {pid} died (exit code {code})")

    def _wait(self, slot: _Slot, job: _Job) -> tuple:
        """("ok", result) | ("err", exc) | ("lost", (exc, why the context failed)) |
        ("timeout", None) | ("died", None); an error too when the pool stops meanwhile."""
        while True:
            left = job.deadline - time.monotonic()
            if left <= 0:
                return ("timeout", None)
            if self._stopping:  # shutting down: do not wait for the job
                self._kill(slot)
                return ("err", WorkerUnavailable("render worker is shutting down"))
            try:
                if slot.conn.poll(min(left, 0.2)):
                    kind, value, lost = slot.conn.recv()
                    return (kind, value) if lost is None else ("lost", (value, lost))
            except (EOFError, OSError):
                return ("died", None)
            except Exception as exc:  # noqa: BLE001 - a result that does not unpickle
                return ("err", RuntimeError(f"job result could not be received: {type(exc).__name__}: {exc}"))
            if not slot.process.is_alive() and not slot.conn.poll():
                return ("died", None)

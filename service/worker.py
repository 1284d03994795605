"""The render worker: one thread that owns a GL context and every GL object.

DESIGN.md ("Service shape"): one GL context per render worker thread; request
handlers never touch GL. Handlers ``submit()`` a job — a callable taking the
worker's ``GLState`` — to a bounded queue and get a ``concurrent.futures.Future``
back (an asyncio handler awaits it with ``asyncio.wrap_future``):

* a full queue raises ``QueueFull`` (HTTP 503 + Retry-After);
* each job has a deadline (``job_timeout_s``); the awaiting handler stops waiting at
  the deadline (HTTP 504) and the worker skips jobs whose deadline passed (or whose
  future was cancelled) before they start (``JobExpired``);
* an exception raised by a job is delivered to its future and never ends the thread;
* if the GL context cannot be created, ``ready`` stays False, ``startup_error``
  says why and jobs fail with ``WorkerUnavailable`` (HTTP 503).

The worker keeps a ``GBufferPass``, an LRU of ``SceneGPU`` uploads keyed by
scene id (content address) and an LRU of reconstructions and shadow maps (soft
shadows' occluders and their maps, bounded in GPU bytes), released on eviction,
when their scene is forgotten and at shutdown, all on the worker thread.
"""

from __future__ import annotations

import ctypes
import logging
import queue
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterator, Sequence
from concurrent.futures import Future
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from gl_passes.context import GLContext, create_gl_context
from gl_passes.gbuffer import GBuffer, GBufferPass
from gl_passes.releasable import settle
from gl_passes.upload import SceneGPU
from scenes.model import Scene
from service import image_io
from service.excerpts import quoted

log = logging.getLogger("depthview.worker")


class WorkerError(RuntimeError):
    """Base class of render worker errors."""


class QueueFull(WorkerError):
    """The job queue is full (HTTP 503 with Retry-After)."""


class WorkerUnavailable(WorkerError):
    """The worker has no GL context (start-up failed) or is shutting down (HTTP 503)."""


class WorkerDied(WorkerUnavailable):
    """A worker process died while running the job; it is replaced (HTTP 503)."""


class JobExpired(WorkerError, TimeoutError):
    """The job's deadline passed before the worker got to it (HTTP 504)."""


Job = Callable[["GLState"], Any]


@dataclass
class _Job:
    fn: Job
    future: Future
    deadline: float
    submitted: float
    label: str = ""


_STOP = object()
_WAKE = object()  # wakes an idle worker to run its chores


@dataclass
class GLState:
    """Everything a job may use. Only valid on the worker thread."""

    gl: GLContext
    gbuffer: GBufferPass
    gpu_cache_size: int = 4
    #: GPU bytes of reconstructions and shadow maps kept between jobs (`kept`); 0: none.
    reconstruction_cache_bytes: int = 0
    #: Loads a stored scene by its content address (jobs that arrive without their scene).
    scene_loader: Callable[[str], Scene] | None = None
    _gpu: OrderedDict[str, SceneGPU] = field(default_factory=OrderedDict)
    _kept: OrderedDict[tuple[str, Hashable], tuple[Sequence[Any], int]] = field(default_factory=OrderedDict)
    _resources: dict[str, tuple[Hashable, Any]] = field(default_factory=dict)
    #: Per-client state on this worker (a stream's ReflectionReuser), by client key.
    clients: dict[str, Any] = field(default_factory=dict)
    #: Frame pixels above which `end_job` releases the passes a job used and the
    #: G-buffer target (sized to the job's images); None: keep them all.
    keep_pixels: int | None = None
    _job_pixels: dict[str, int] = field(default_factory=dict)
    _freed: bool = False

    def scene_gpu(self, key: str, scene: Scene) -> SceneGPU:
        """The GPU upload of `scene`, cached under `key` (a content address: the same
        key must always mean the same geometry). Evicted uploads are released."""
        self.gl.check_thread()
        if key in self._gpu:
            self._gpu.move_to_end(key)
            return self._gpu[key]
        gpu = SceneGPU(self.gl, scene)
        self._gpu[key] = gpu
        while len(self._gpu) > self.gpu_cache_size:
            old_key, old = self._gpu.popitem(last=False)
            log.debug("releasing GPU upload of scene %s", old_key)
            self._release_upload(old)
        return gpu

    def _release_upload(self, gpu: SceneGPU) -> None:
        """Release a scene's upload, after the resources that cache something of it
        (those with `forget_scene`, e.g. the reflection renderer's per-scene records)."""
        for _, obj in self._resources.values():
            if hasattr(obj, "forget_scene"):
                obj.forget_scene(gpu)
        gpu.release()

    def has_scene(self, key: str) -> bool:
        """Whether the GPU upload of the scene under `key` is cached."""
        return key in self._gpu

    def scene(self, key: str) -> Scene:
        """The scene stored under the content address `key` (from the scene loader)."""
        if self.scene_loader is None:
            raise LookupError(f"no scene loader to load scene {key}")
        return self.scene_loader(key)

    def forget(self, key: str) -> None:
        """Release the GPU upload cached under `key` and what is kept of it (`kept`), if any."""
        self.gl.check_thread()
        gpu = self._gpu.pop(key, None)
        if gpu is not None:
            self._release_upload(gpu)
            self._freed = True
        for k in [k for k in self._kept if k[0] == key]:
            _release_all(self._kept.pop(k)[0])
            self._freed = True

    @contextmanager
    def kept(self, scene_key: str, what: Hashable, build: Callable[[], Sequence[Any]],
             expected: int | None = None) -> Iterator[Sequence[Any]]:
        """The GPU objects (reconstructed meshes, shadow maps: anything with `nbytes`
        and `release()`) that `build()` makes of the scene under the content address
        `scene_key` for `what` (method, light, cameras…: whatever else decides them),
        for the duration of the ``with`` block. Kept for the next job with the same
        key (LRU) while the kept objects' GPU bytes fit `reconstruction_cache_bytes`;
        otherwise released when the block ends. Callers never release them.
        `expected`: their bytes when known before `build()`, which then makes room
        first (the least recently used go before the new ones are made)."""
        self.gl.check_thread()
        key = (scene_key, what)
        if key in self._kept:
            self._kept.move_to_end(key)
            yield self._kept[key][0]
            return
        if expected is not None and expected <= self.reconstruction_cache_bytes:
            self._make_room(self.reconstruction_cache_bytes - expected)
        made = build()
        size = sum(int(m.nbytes) for m in made)
        if size > self.reconstruction_cache_bytes:
            try:
                yield made
            finally:
                _release_all(made)
            return
        self._make_room(self.reconstruction_cache_bytes - size)
        self._kept[key] = (made, size)
        yield made

    def _make_room(self, budget: int) -> None:
        """Release the least recently used kept objects until at most `budget` bytes are kept."""
        while self._kept and sum(n for _, n in self._kept.values()) > budget:
            _, (old, _) = self._kept.popitem(last=False)
            _release_all(old)

    @property
    def kept_count(self) -> int:
        """How many `kept` entries are held."""
        return len(self._kept)

    def resource(self, name: str, factory: Callable[[GLContext], Any], variant: Hashable = None,
                 pixels: int = 0) -> Any:
        """A long-lived GL object (e.g. another pass) created on first use with
        `factory(gl)` and released (``.release()``) at shutdown. One per name:
        asked for with another `variant` (the settings it was made with), the held
        one is released and a new one made, so that what requests vary (a pass per
        sample count) never piles up. `pixels`: the largest image this job draws
        with it (its targets and buffers grow to it; see `end_job`)."""
        self.gl.check_thread()
        self._job_pixels[name] = max(self._job_pixels.get(name, 0), int(pixels))
        held = self._resources.get(name)
        if held is not None and held[0] != variant:
            del self._resources[name]
            held[1].release()
        if name not in self._resources:
            self._resources[name] = (variant, factory(self.gl))
        return self._resources[name][1]

    def freed(self) -> None:
        """Note that a job or chore released GL objects (a stream's reuser): `end_job`
        hands their memory back."""
        self._freed = True

    def end_job(self) -> bool:
        """After each job and chore: release the passes it used for images over
        `keep_pixels` and a G-buffer target over it; then, when anything was released
        (here or noted by `freed`), let the driver free it (`settle`) and hand the
        freed heap back to the system (`trim_heap`), so that an idle worker does not
        keep the memory of its largest frame or of closed streams (passes are made
        again at the next job's size). True when something was released."""
        self.gl.check_thread()
        used, self._job_pixels = self._job_pixels, {}
        big: list[str] = []
        big_target = False
        if self.keep_pixels is not None:
            big = [name for name, px in used.items() if px > self.keep_pixels and name in self._resources]
            for name in big:
                self._resources.pop(name)[1].release()
            target = getattr(self.gbuffer, "target", None)
            big_target = target is not None and target.size[0] * target.size[1] > self.keep_pixels
            if big_target:
                self.gbuffer.release_target()
        released = bool(big or big_target or self._freed)
        self._freed = False
        if released:
            settle(self.gl)
            trim_heap()
        return released

    @property
    def resource_names(self) -> set[str]:
        """The names of the `resource` objects held now."""
        return set(self._resources)

    @property
    def gpu_cached(self) -> int:
        return len(self._gpu)

    def release(self) -> None:
        """Release every GL object, then the context (worker thread only)."""
        self.release_objects()
        self.gl.release()

    def release_objects(self) -> None:
        """Release every GL object this state made, not the context (worker thread only)."""
        self.gl.check_thread()
        for key, client in list(self.clients.items()):
            try:
                client.release(self)
            except Exception:  # noqa: BLE001 - release the rest anyway
                log.exception("releasing client state %s failed", key)
        self.clients.clear()
        for key, gpu in list(self._gpu.items()):
            try:
                gpu.release()
            except Exception:  # noqa: BLE001 - release the rest anyway
                log.exception("releasing GPU upload of %s failed", key)
        self._gpu.clear()
        for meshes, _ in self._kept.values():
            try:
                _release_all(meshes)
            except Exception:  # noqa: BLE001 - release the rest anyway
                log.exception("releasing a kept reconstruction or shadow maps failed")
        self._kept.clear()
        for name, (_, obj) in list(self._resources.items()):
            try:
                obj.release()
            except Exception:  # noqa: BLE001
                log.exception("releasing GL resource %s failed", name)
        self._resources.clear()
        try:
            self.gbuffer.release()
        except Exception:  # noqa: BLE001
            log.exception("releasing the G-buffer pass failed")


def _release_all(meshes: Sequence[Any]) -> None:
    for m in meshes:
        m.release()


class RenderWorker:
    """A daemon thread owning one GL context; jobs arrive through a bounded queue."""

    def __init__(self, queue_size: int = 32, job_timeout_s: float = 120.0, gpu_cache_size: int = 4,
                 backend: str | None = None, device: int | None = None, reconstruction_cache_bytes: int = 0,
                 keep_pixels: int | None = None,
                 context_factory: Callable[[], GLContext] | None = None,
                 gbuffer_factory: Callable[[GLContext], GBufferPass] | None = None, name: str = "depthview-gl",
                 scene_loader: Callable[[str], Scene] | None = None) -> None:
        self.queue_size = int(queue_size)
        self.job_timeout_s = float(job_timeout_s)
        self.gpu_cache_size = int(gpu_cache_size)
        self.reconstruction_cache_bytes = int(reconstruction_cache_bytes)
        self.keep_pixels = keep_pixels
        self._scene_loader = scene_loader
        self._context_factory = context_factory or (lambda: create_gl_context(backend, device))
        self._gbuffer_factory = gbuffer_factory or GBufferPass
        self._q: queue.Queue[Any] = queue.Queue(maxsize=self.queue_size)
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._ready = threading.Event()
        self._started = threading.Event()  # start-up finished, successfully or not
        self._submit_lock = threading.Lock()
        self._stats_lock = threading.Lock()
        self._evict_lock = threading.Lock()
        self._evictions: set[str] = set()
        self._chores: list[Callable[[GLState], Any]] = []
        self._stopping = False
        self._state: GLState | None = None
        #: Why the GL context could not be created (None when fine).
        self.startup_error: str | None = None
        self.renderer: str | None = None
        self.backend: str | None = None
        self.gl_version: str | None = None
        self.is_software: bool | None = None
        #: Thread id of the worker thread (set when it starts).
        self.thread_id: int | None = None
        #: Every thread id a job ran on (instrumentation: must be {thread_id}).
        self.job_thread_ids: set[int] = set()
        # counters
        self.jobs_submitted = 0
        self.jobs_done = 0
        self.jobs_failed = 0
        self.jobs_expired = 0
        self.jobs_rejected = 0
        self.job_seconds_sum = 0.0
        self.job_seconds_count = 0
        self.queue_wait_seconds_sum = 0.0
        self.last_job_seconds = 0.0
        self.busy = False

    # --- lifecycle -----------------------------------------------------------------
    def start(self) -> RenderWorker:
        self._thread.start()
        return self

    def wait_ready(self, timeout: float | None = None) -> bool:
        """Block until start-up finished; True when the GL context is alive."""
        self._started.wait(timeout)
        return self._ready.is_set()

    @property
    def ready(self) -> bool:
        """True while the GL context is alive and the worker accepts jobs."""
        return self._ready.is_set() and not self._stopping and self._thread.is_alive()

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def stop(self, timeout: float = 30.0) -> None:
        """Refuse new jobs, fail the queued ones, finish the running one, release
        every GL object and the context, and join the thread."""
        with self._submit_lock:
            if self._stopping:
                return
            self._stopping = True
        while True:
            try:
                job = self._q.get_nowait()
            except queue.Empty:
                break
            if isinstance(job, _Job) and job.future.set_running_or_notify_cancel():
                job.future.set_exception(WorkerUnavailable("render worker is shutting down"))
        if self._thread.is_alive():
            self._q.put(_STOP, timeout=timeout)
            self._thread.join(timeout)
            if self._thread.is_alive():
                log.warning("render worker did not stop within %.1f s", timeout)

    # --- submitting ------------------------------------------------------------------
    def submit(self, fn: Job, timeout: float | None = None, label: str = "", pin: str | None = None) -> Future:
        """Queue `fn(state)` for the GL thread; returns its Future. Raises QueueFull
        when `queue_size` jobs are already waiting, WorkerUnavailable when the worker
        failed to start or is stopping. `timeout` (default job_timeout_s) sets the
        deadline after which the job is skipped if it has not started. `pin` (jobs that
        must share a worker) changes nothing here: there is one thread."""
        if self.startup_error is not None:
            raise WorkerUnavailable(f"no GL context: {self.startup_error}")
        now = time.monotonic()
        job = _Job(fn=fn, future=Future(), deadline=now + (self.job_timeout_s if timeout is None else timeout),
                   submitted=now, label=label)
        with self._submit_lock:
            if self._stopping or not self._thread.is_alive():
                raise WorkerUnavailable("render worker is not running")
            try:
                self._q.put_nowait(job)
            except queue.Full:
                with self._stats_lock:
                    self.jobs_rejected += 1
                raise QueueFull(f"render queue is full ({self.queue_size} jobs waiting)") from None
            with self._stats_lock:
                self.jobs_submitted += 1
        return job.future

    def forget(self, key: str) -> None:
        """Ask the worker to release the GPU upload cached under `key` (done on the
        worker thread before its next job). Safe from any thread."""
        with self._evict_lock:
            self._evictions.add(key)

    def run_before_next_job(self, fn: Callable[[GLState], Any], pin: str | None = None) -> None:
        """Run `fn(state)` on the worker thread before its next job, outside the queue
        (never refused, never behind a full queue): releasing a client's GL objects, e.g.
        a stream's ReflectionReuser. An idle worker runs it at once; chores still pending
        at shutdown run before the context is released. Safe from any thread."""
        with self._evict_lock:
            self._chores.append(fn)
        try:
            self._q.put_nowait(_WAKE)
        except queue.Full:  # busy: it runs the chore before its next job
            pass

    # --- introspection -------------------------------------------------------------------
    @property
    def queue_depth(self) -> int:
        return self._q.qsize()

    def stats(self) -> dict[str, Any]:
        """Counters for /metrics."""
        with self._stats_lock:
            return {
                "ready": self.ready,
                "alive": self.alive,
                "jobs_submitted": self.jobs_submitted,
                "jobs_done": self.jobs_done,
                "jobs_failed": self.jobs_failed,
                "jobs_expired": self.jobs_expired,
                "jobs_rejected": self.jobs_rejected,
                "job_seconds_sum": self.job_seconds_sum,
                "job_seconds_count": self.job_seconds_count,
                "queue_wait_seconds_sum": self.queue_wait_seconds_sum,
                "last_job_seconds": self.last_job_seconds,
                "queue_depth": self.queue_depth,
                "queue_capacity": self.queue_size,
                "busy": self.busy,
                "gpu_scenes_cached": self._state.gpu_cached if self._state is not None else 0,
            }

    # --- the thread ------------------------------------------------------------------------
    def _startup(self) -> None:
        gl = self._context_factory()
        try:
            gbuffer = self._gbuffer_factory(gl)
        except BaseException:
            gl.release()
            raise
        self._state = GLState(gl=gl, gbuffer=gbuffer, gpu_cache_size=self.gpu_cache_size,
                              reconstruction_cache_bytes=self.reconstruction_cache_bytes,
                              keep_pixels=self.keep_pixels, scene_loader=self._scene_loader)
        self.renderer, self.backend = gl.renderer, gl.backend
        self.gl_version = getattr(gl, "version", None)
        self.is_software = bool(gl.is_software)

    def _run(self) -> None:
        self.thread_id = threading.get_ident()
        try:
            self._startup()
            self._ready.set()
        except BaseException as exc:  # noqa: BLE001 - report, keep draining jobs with an error
            self.startup_error = f"{type(exc).__name__}: {exc}"
            log.error("render worker could not create its GL context: %s", self.startup_error)
        finally:
            self._started.set()
        try:
            while True:
                item = self._q.get()
                if item is _STOP:
                    break
                self._process_evictions()
                if item is not _WAKE:
                    self._execute(item)
        finally:
            self._ready.clear()
            self._process_evictions()
            if self._state is not None:
                try:
                    self._state.release()
                except Exception:  # noqa: BLE001
                    log.exception("releasing the GL state failed")
                self._state = None

    def _process_evictions(self) -> None:
        with self._evict_lock:
            keys, self._evictions = self._evictions, set()
            chores, self._chores = self._chores, []
        if self._state is not None:
            for key in keys:
                self._state.forget(key)
            for fn in chores:
                try:
                    fn(self._state)
                except Exception:  # noqa: BLE001 - a failed release must not end the thread
                    log.exception("worker chore failed")
            if keys or chores:
                end_job(self._state)

    def _execute(self, job: _Job) -> None:
        fut = job.future
        if not fut.set_running_or_notify_cancel():  # the handler gave up already
            with self._stats_lock:
                self.jobs_expired += 1
            return
        if time.monotonic() > job.deadline:
            fut.set_exception(JobExpired("render job expired in the queue before it started"))
            with self._stats_lock:
                self.jobs_expired += 1
            return
        if self._state is None:
            fut.set_exception(WorkerUnavailable(f"no GL context: {self.startup_error}"))
            with self._stats_lock:
                self.jobs_failed += 1
            return
        self.job_thread_ids.add(threading.get_ident())
        self.busy = True
        waited = time.monotonic() - job.submitted
        t0 = time.perf_counter()
        result: Any = None
        error: BaseException | None = None
        try:
            result = job.fn(self._state)
        except BaseException as exc:  # noqa: BLE001 - delivered to the future, the thread lives on
            error = exc
        finally:
            self.busy = False
        # counted before it is delivered: whoever sees the result sees the job counted
        with self._stats_lock:
            count_job(self, "done" if error is None else "failed", time.perf_counter() - t0, waited)
        if error is None:
            fut.set_result(result)
        else:
            fut.set_exception(error)
        end_job(self._state)


#: The symbols this process has loaded, the C library's among them.
_LIBC = ctypes.CDLL(None)


def trim_heap() -> None:
    """Hand the heap's free memory back to the system (glibc ``malloc_trim(0)``; a
    no-op elsewhere). Freed frame buffers otherwise stay in the process's resident
    memory: bench/results/stream_memory.md."""
    trim = getattr(_LIBC, "malloc_trim", None)
    if trim is not None:
        trim(0)


def end_job(state: GLState) -> None:
    """`state.end_job()` after a job's result is delivered; a failure is logged (the
    next job's own GL calls meet a broken context and report it)."""
    try:
        state.end_job()
    except Exception:  # noqa: BLE001 - releasing must not end the worker
        log.exception("releasing a finished job's large passes failed")


def count_job(worker: Any, outcome: str, seconds: float, waited: float) -> None:
    """Add a finished job to `worker`'s counters (jobs_<outcome>, job seconds, queue
    wait); the caller holds the lock guarding them."""
    name = f"jobs_{outcome}"
    setattr(worker, name, getattr(worker, name) + 1)
    worker.job_seconds_sum += seconds
    worker.job_seconds_count += 1
    worker.queue_wait_seconds_sum += waited
    worker.last_job_seconds = seconds


def encode_frame(gbuf: GBuffer, fmt: str) -> bytes:
    """Encode a G-buffer as PNG (sRGB colour) or EXR (linear RGB, Z, N, id, object).
    Pure numpy/CPU: call it off the GL thread."""
    if fmt == "png":
        return image_io.encode_png(gbuf.color)
    if fmt == "exr":
        return image_io.encode_exr({"RGB": gbuf.color, "Z": gbuf.depth, "N": gbuf.normal,
                                    "id": gbuf.tri_id, "object": gbuf.obj_id})
    raise ValueError(f"unknown frame format {quoted(fmt)}")

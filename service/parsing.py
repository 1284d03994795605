"""Uploads parsed in a child process under a time and memory limit.

A scene file is parsed (``scenes.loaders.load_scene_bytes``) by a process forked for
it from a ``multiprocessing`` fork server that has the loaders imported, so a parse
starts in milliseconds. The child's address space may grow by at most
``ParseLimits.max_bytes`` past what the fork server had (``RLIMIT_AS``); the parent
waits at most ``ParseLimits.timeout_s`` and then kills it. Whatever ends a parse —
the time limit, the memory limit, the loader's own error, a crash of the process — comes
back as a :class:`scenes.loaders.SceneLoadError` (422) naming what happened; the service
process and its worker threads are never held past the limit. Where no fork server
can start (its socket needs a writable temporary directory: a read-only container
without one), uploads are parsed in the calling thread, without the limits, and the
log says so once.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging
import multiprocessing as mp
import os
import resource
import shutil
import signal
import tempfile
import threading
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing import forkserver
from typing import Any

from scenes import loaders
from scenes.model import Scene

log = logging.getLogger("depthview.parsing")

#: Modules the fork server imports once, so each parse forks with them loaded.
_PRELOAD = ["__main__", "scenes.loaders", "trimesh.exchange.gltf", "trimesh.exchange.obj", "trimesh.exchange.ply"]
#: Seconds a killed child may take to be reaped.
_REAP_S = 5.0

class ParseTimeLimit(loaders.SceneLoadError):
    """The parse ran past its time limit and was stopped."""


class ParseMemoryLimit(loaders.SceneLoadError):
    """The parse needed more memory than its limit."""


@dataclass(frozen=True)
class ParseLimits:
    """Limits of one parse: wall-clock seconds and bytes of address space the child
    may add (``Settings.parse_timeout_s``, ``Settings.max_job_bytes``)."""

    timeout_s: float
    max_bytes: int


@functools.cache
def _fork_context() -> Any:
    """The fork-server context, with the loaders preloaded (made once per process)."""
    ctx = mp.get_context("forkserver")
    ctx.set_forkserver_preload(_PRELOAD)
    return ctx


def _address_space() -> int:
    """This process's virtual memory size in bytes (``VmSize``)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    raise OSError("no VmSize in /proc/self/status")


def _memory_error(exc: BaseException) -> bool:
    """Whether a MemoryError caused `exc` (the loaders wrap what they catch)."""
    seen: set[int] = set()
    cur: BaseException | None = exc
    while cur is not None and id(cur) not in seen:
        if isinstance(cur, MemoryError):
            return True
        seen.add(id(cur))
        cur = cur.__cause__ or cur.__context__
    return False


def _child(conn: Any, data: bytes, fmt: str, name: str, max_triangles: int | None, max_bytes: int) -> None:
    """The parse process: limit the address space, parse, send ("ok", scene), ("load",
    the loader's SceneLoadError), or ("memory" | "crash", message)."""
    try:
        limit = _address_space() + max_bytes
        hard = resource.getrlimit(resource.RLIMIT_AS)[1]
        if hard != resource.RLIM_INFINITY:  # a limit set outside (ulimit -v, LimitAS=) cannot be raised
            limit = min(limit, hard)
        resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
        scene = loaders.load_scene_bytes(data, fmt, name=name, max_triangles=max_triangles)
        # a fresh Scene: the loader's cached concatenations would travel twice
        conn.send(("ok", dataclasses.replace(scene)))
    except BaseException as exc:  # noqa: BLE001 - everything goes back to the parent
        try:
            if _memory_error(exc):
                conn.send(("memory", str(exc)))
            elif isinstance(exc, loaders.SceneLoadError):
                conn.send(("load", exc))
            else:
                conn.send(("crash", f"{type(exc).__name__}: {exc}"))
        except BaseException:  # noqa: BLE001 - out of memory again: the exit code says it
            pass
    finally:
        conn.close()


class ParseUnavailable(Exception):
    """No parse process could be started (HTTP 503; the upload may be sent again)."""


def no_turn(concurrent: float, timeout_s: float) -> ParseUnavailable:
    """An upload waited `timeout_s` (PARSE_TIMEOUT_S) for one of `concurrent` parse turns."""
    return ParseUnavailable(f"{concurrent:g} upload(s) are being parsed, as many as at once; waited "
                            f"{timeout_s:g} s (PARSE_TIMEOUT_S): try again")


_warned: list[str] = []


def _warn_unlimited(exc: OSError) -> None:
    """Log once that uploads are parsed in this process, without the limits."""
    if not _warned:
        _warned.append(str(exc))
        log.error("cannot start the upload parser's fork server, no usable temporary directory for its socket "
                  "(%s): uploads are parsed in the service process, without PARSE_TIMEOUT_S and the memory "
                  "limit", exc)


def _temp_dir_usable() -> bool:
    try:
        shutil.rmtree(tempfile.mkdtemp(prefix="depthview-probe-"))
        return True
    except OSError:
        return False


def _started(make: Callable[[], Any], retry: bool = True) -> Any:
    """A parse process made by `make` and started; None where no fork server can run
    (no usable temporary directory). A fork server that refuses (its socket removed,
    say) is stopped and started again once (`retry`); ParseUnavailable if that fails too."""
    proc = make()
    try:
        proc.start()
        return proc
    except OSError as exc:
        if not _temp_dir_usable():
            _warn_unlimited(exc)
            return None
        if not retry:
            log.warning("starting a parse process failed again (%s); giving up", exc)
            raise ParseUnavailable(f"cannot start a process to parse the upload ({exc}); try again") from None
        log.warning("starting a parse process failed (%s); restarting the fork server", exc)
    with contextlib.suppress(OSError):  # its socket file may be gone already
        forkserver._forkserver._stop()
    return _started(make, retry=False)


def _stop(proc: Any, running: bool) -> None:
    """Kill the parse process when it may still run (`running`: no result came; by pid:
    a dead fork server makes ``is_alive`` false while its child runs on), then reap it."""
    if running:
        with contextlib.suppress(ProcessLookupError):
            os.kill(proc.pid, signal.SIGKILL)
    elif proc.is_alive():
        proc.kill()
    proc.join(_REAP_S)


def parse_scene(data: bytes, fmt: str, name: str, max_triangles: int | None, limits: ParseLimits) -> Scene:
    """Parse an uploaded file as ``loaders.load_scene_bytes`` would, in a child process
    held to `limits`. Raises SceneLoadError (ParseTimeLimit, ParseMemoryLimit, or the
    loader's own, e.g. TriangleLimitError), or ParseUnavailable."""
    ctx = _fork_context()
    recv, send = ctx.Pipe(duplex=False)
    try:
        proc = _started(lambda: ctx.Process(
            target=_child, args=(send, data, fmt, name, max_triangles, limits.max_bytes),
            name="depthview-parse", daemon=True))
    except BaseException:
        recv.close()
        raise
    finally:
        send.close()
    if proc is None:
        recv.close()
        return loaders.load_scene_bytes(data, fmt, name=name, max_triangles=max_triangles)
    running = True
    try:
        if not recv.poll(limits.timeout_s):
            raise ParseTimeLimit(f"parsing the {fmt} file took longer than {limits.timeout_s:g} s, "
                                 "the limit (PARSE_TIMEOUT_S)")
        try:
            message = recv.recv()
            running = False
        except EOFError:
            running = False
            proc.join(_REAP_S)
            raise loaders.SceneLoadError(
                f"the process parsing the {fmt} file died (exit code {proc.exitcode})") from None
    finally:
        recv.close()
        _stop(proc, running)
    kind, payload = message
    if kind == "ok":
        return payload
    if kind == "load":
        raise payload
    if kind == "memory":
        log.info("parsing a %s upload ran out of memory: %s", fmt, payload)
        raise ParseMemoryLimit(f"parsing the {fmt} file needed more than {limits.max_bytes} bytes of memory, "
                               "the limit (MAX_JOB_BYTES)")
    log.error("parsing a %s upload failed: %s", fmt, payload)
    raise loaders.SceneLoadError(f"the {fmt} file could not be parsed: {payload}")


class UploadParser:
    """The service's parser (``SceneStore.parse``): `parse_scene` under `limits`, at
    most `concurrent` parses at once (one per render worker: each may grow to
    ``max_bytes``, like a render job); an upload that waits longer than the time limit
    for its turn is ParseUnavailable (503)."""

    def __init__(self, limits: ParseLimits, concurrent: int) -> None:
        self.limits, self.concurrent = limits, max(1, int(concurrent))
        self._slots = threading.BoundedSemaphore(self.concurrent)

    def __call__(self, data: bytes, fmt: str, name: str, max_triangles: int | None) -> Scene:
        if not self._slots.acquire(timeout=self.limits.timeout_s):
            raise no_turn(self.concurrent, self.limits.timeout_s)
        try:
            return parse_scene(data, fmt, name, max_triangles, self.limits)
        finally:
            self._slots.release()

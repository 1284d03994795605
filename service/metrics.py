"""Prometheus metrics of the service (text exposition format 0.0.4).

Recorded by ``service.middleware.RequestGuard`` for every request (validation errors,
413s and 401s included): latency histograms per route and method, responses by route
and status, 4xx/5xx totals (/readyz's 503 left out). Recorded by the routes: per-step times (scene load, queue
wait and GL job, CPU work, encoding), frames by format. Read from the worker at
scrape time: queue depth, workers alive, job outcomes. ``frames_streamed`` is counted
by the stream (``Metrics.streamed()``, one per frame sent on /scenes/{id}/stream).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

#: Upper bounds (seconds) of the latency histogram buckets.
LATENCY_BUCKETS = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 120.0)
#: Steps of a render request whose time is recorded.
STEPS = ("scene_load", "job", "cpu", "encode")


class Histogram:
    """Cumulative-bucket histogram (not thread-safe: Metrics holds the lock)."""

    def __init__(self, buckets: tuple[float, ...] = LATENCY_BUCKETS) -> None:
        self.buckets = buckets
        self.counts = [0] * len(buckets)
        self.sum = 0.0
        self.count = 0

    def observe(self, value: float) -> None:
        for i, b in enumerate(self.buckets):
            if value <= b:
                self.counts[i] += 1
        self.sum += value
        self.count += 1

    def samples(self, labels: str) -> list[tuple[str, float]]:
        sep = "," if labels else ""
        out = [(f'_bucket{{{labels}{sep}le="{b:g}"}}', c) for b, c in zip(self.buckets, self.counts, strict=True)]
        out.append((f'_bucket{{{labels}{sep}le="+Inf"}}', self.count))
        out.append((f"_sum{{{labels}}}" if labels else "_sum", self.sum))
        out.append((f"_count{{{labels}}}" if labels else "_count", self.count))
        return out


#: Request methods counted under their own name; any other is counted as "other".
METHODS = frozenset({"GET", "HEAD", "POST", "PUT", "DELETE", "PATCH", "OPTIONS"})
#: Responses left out of the 4xx/5xx totals: /readyz's 503 answers the probe (not ready).
PROBE_ANSWERS = frozenset({("/readyz", 503)})


def label(value: object) -> str:
    """A label value as the exposition format writes it (backslash, quote and newline escaped)."""
    return str(value).replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")


class Metrics:
    """Service-level counters (the worker keeps its own)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.latency: dict[tuple[str, str], Histogram] = {}
        self.responses: dict[tuple[str, str, int], int] = {}
        self.steps: dict[str, Histogram] = {}
        self.frames: dict[str, int] = {}
        self.frame_errors: dict[int, int] = {}
        self.frames_streamed = 0
        self.uploads = 0
        self.started = time.time()

    def request(self, method: str, route: str, status: int, seconds: float) -> None:
        """Count a response: `route` must come from a bounded set (route templates), a
        method outside METHODS counts as "other"."""
        method = method if method in METHODS else "other"
        with self._lock:
            self.latency.setdefault((method, route), Histogram()).observe(seconds)
            key = (method, route, status)
            self.responses[key] = self.responses.get(key, 0) + 1

    @contextmanager
    def step(self, name: str) -> Iterator[None]:
        """Time one step of a render request."""
        t0 = time.perf_counter()
        try:
            yield
        finally:
            dt = time.perf_counter() - t0
            with self._lock:
                self.steps.setdefault(name, Histogram()).observe(dt)

    def frame(self, fmt: str) -> None:
        with self._lock:
            self.frames[fmt] = self.frames.get(fmt, 0) + 1

    def frame_error(self, status: int) -> None:
        with self._lock:
            self.frame_errors[status] = self.frame_errors.get(status, 0) + 1

    def streamed(self, n: int = 1) -> None:
        with self._lock:
            self.frames_streamed += n

    def upload(self) -> None:
        with self._lock:
            self.uploads += 1

    def render(self, worker_stats: dict[str, Any], scenes_cached: int) -> str:
        """The exposition text."""
        w = worker_stats
        out: list[str] = []

        def metric(name: str, typ: str, help_: str, samples: list[tuple[str, float]]) -> None:
            out.append(f"# HELP {name} {help_}")
            out.append(f"# TYPE {name} {typ}")
            out.extend(f"{name}{labels} {value}" for labels, value in samples)

        with self._lock:
            latency = {k: list(h.samples(f'method="{label(k[0])}",route="{label(k[1])}"'))
                       for k, h in sorted(self.latency.items())}
            responses = sorted(self.responses.items())
            steps = {k: h.samples(f'step="{label(k)}"') for k, h in sorted(self.steps.items())}
            frames, errors = sorted(self.frames.items()), sorted(self.frame_errors.items())
            streamed, uploads = self.frames_streamed, self.uploads
        by_class = {"4xx": 0, "5xx": 0}
        for (_, route, status), n in responses:
            if status >= 400 and (route, status) not in PROBE_ANSWERS:
                by_class[f"{status // 100}xx"] = by_class.get(f"{status // 100}xx", 0) + n

        metric("depthview_request_seconds", "histogram", "Request latency by route (template) and method.",
               [s for samples in latency.values() for s in samples])
        metric("depthview_responses_total", "counter", "Responses by route, method and status (validation "
               "errors, limits and auth refusals included).",
               [(f'{{method="{label(m)}",route="{label(r)}",status="{s}"}}', n) for (m, r, s), n in responses])
        metric("depthview_http_errors_total", "counter", "Error responses by class (not /readyz's 503, which "
               "answers the probe: not ready).",
               [(f'{{class="{k}"}}', v) for k, v in sorted(by_class.items())])
        metric("depthview_step_seconds", "histogram", "Time per step of render requests: scene_load (parse or "
               "cache), job (queue wait + GL and Embree on the worker), cpu (shading), encode.",
               [s for samples in steps.values() for s in samples])
        metric("depthview_ready", "gauge", "1 when the render worker's GL context is alive.", [("", int(w["ready"]))])
        metric("depthview_workers_alive", "gauge", "Render workers alive (the thread, or processes "
               "with DEPTHVIEW_WORKERS).", [("", int(w["alive"]))])
        metric("depthview_workers_replaced_total", "counter", "Worker processes replaced (died, lost their GL "
               "context or ran a job past its time limit).", [("", int(w.get("workers_replaced", 0)))])
        metric("depthview_jobs_total", "counter", "Render jobs by outcome.", [
            ('{outcome="done"}', w["jobs_done"]), ('{outcome="failed"}', w["jobs_failed"]),
            ('{outcome="expired"}', w["jobs_expired"]), ('{outcome="rejected"}', w["jobs_rejected"])])
        metric("depthview_queue_depth", "gauge", "Render jobs waiting in the queue.", [("", w["queue_depth"])])
        metric("depthview_queue_capacity", "gauge", "Size of the render job queue.", [("", w["queue_capacity"])])
        metric("depthview_worker_busy", "gauge", "1 while the worker runs a job.", [("", int(w["busy"]))])
        metric("depthview_job_seconds", "summary", "Time the GL thread spent per job.",
               [("_sum", float(w["job_seconds_sum"])), ("_count", w["job_seconds_count"])])
        metric("depthview_queue_wait_seconds", "summary", "Time jobs waited in the queue before they started.",
               [("_sum", float(w["queue_wait_seconds_sum"])), ("_count", w["job_seconds_count"])])
        metric("depthview_last_job_seconds", "gauge", "Duration of the latest job.",
               [("", float(w["last_job_seconds"]))])
        metric("depthview_frames_total", "counter", "Frames served by format.",
               [(f'{{format="{label(k)}"}}', v) for k, v in frames] or [('{format="png"}', 0)])
        metric("depthview_frame_errors_total", "counter",
               "Frame requests that passed validation and then failed, by status (all: depthview_responses_total).",
               [(f'{{status="{k}"}}', v) for k, v in errors])
        metric("depthview_frames_streamed_total", "counter", "Frames sent over the stream.", [("", streamed)])
        metric("depthview_uploads_total", "counter", "Scene upload requests accepted.", [("", uploads)])
        if w.get("gpu_scenes_cached") is not None:  # the worker thread's; each worker process keeps its own
            metric("depthview_gpu_scenes_cached", "gauge", "Scenes uploaded to the GPU (worker thread only).",
                   [("", w["gpu_scenes_cached"])])
        metric("depthview_scenes_cached", "gauge", "Parsed scenes in memory.", [("", scenes_cached)])
        return "\n".join(out) + "\n"

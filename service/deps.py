"""FastAPI dependencies of the routers: the settings, the scene store, the render
worker (``RenderWorker`` thread or ``ProcessWorkerPool``: the same interface) and
the metrics (all on ``app.state``, set by ``create_app`` and its
lifespan), the bearer-token check, and the helpers routes share to load a scene and
run a job.

The token check is reusable beyond the HTTP routes: ``token_ok(settings, presented)``
compares in constant time and ``presented_token(headers, query)`` reads the token from
an ``Authorization: Bearer`` header or, where a client cannot set headers (a browser's
WebSocket, a page opened from a link), from a ``token`` query parameter — the stream
and the page take it that way.
"""

from __future__ import annotations

import asyncio
import hmac
import logging
from collections.abc import Callable, Mapping
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Annotated, Any, TypeVar

from fastapi import Depends, HTTPException, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.concurrency import run_in_threadpool

from scenes.model import Scene
from service.config import Settings
from service.errors import short
from service.jobs import Job
from service.metrics import Metrics
from service.process_worker import ProcessWorkerPool
from service.store import SceneNotFound, SceneStore
from service.worker import JobExpired, QueueFull, RenderWorker, WorkerUnavailable

log = logging.getLogger("depthview.service")
T = TypeVar("T")
#: The render worker: the in-process thread (workers=0) or the worker processes.
Worker = RenderWorker | ProcessWorkerPool


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_store(request: Request) -> SceneStore:
    return request.app.state.store


def get_worker(request: Request) -> Worker:
    return request.app.state.worker


def get_metrics(request: Request) -> Metrics:
    return request.app.state.metrics


SettingsDep = Annotated[Settings, Depends(get_settings)]
StoreDep = Annotated[SceneStore, Depends(get_store)]
WorkerDep = Annotated[Worker, Depends(get_worker)]
MetricsDep = Annotated[Metrics, Depends(get_metrics)]

# --- authentication --------------------------------------------------------------------
bearer_scheme = HTTPBearer(auto_error=False, scheme_name="bearer",
                           description="DEPTHVIEW_TOKEN, when the service sets one: `Authorization: Bearer <token>`")


def token_ok(settings: Settings, presented: str | None) -> bool:
    """True when the service needs no token, or `presented` is it (constant time)."""
    if settings.token is None:
        return True
    return presented is not None and hmac.compare_digest(presented.encode(), settings.token.encode())


def presented_token(headers: Mapping[str, str], query: Mapping[str, str] | None = None) -> str | None:
    """The bearer token of a request: ``Authorization: Bearer <token>``, else (when
    `query` is given: WebSocket and page clients) the ``token`` query parameter."""
    scheme, _, value = headers.get("authorization", "").partition(" ")
    if scheme.lower() == "bearer" and value.strip():
        return value.strip()
    return None if query is None else query.get("token")


def unauthorized() -> HTTPException:
    return HTTPException(401, "missing or wrong bearer token (Authorization: Bearer <DEPTHVIEW_TOKEN>)",
                         headers={"WWW-Authenticate": 'Bearer realm="depthview"'})


async def require_token(settings: SettingsDep,
                        credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer_scheme)]) -> None:
    """Router dependency: 401 unless the request carries the service's token."""
    if not token_ok(settings, credentials.credentials if credentials is not None else None):
        raise unauthorized()


# --- shared route helpers --------------------------------------------------------------
def unavailable(detail: str, settings: Settings) -> HTTPException:
    return HTTPException(503, detail, headers={"Retry-After": str(settings.retry_after_s)})


def check_size(settings: Settings, width: int, height: int, what: str = "frame") -> None:
    """422 when width, height or their product exceed the service limits."""
    problem = settings.size_problem(width, height, what)
    if problem is not None:
        raise HTTPException(422, problem)


@dataclass
class Render:
    """What a render route uses: the settings, the store, the worker and the metrics,
    with the steps of a render request (each timed in the metrics)."""

    settings: Settings
    store: SceneStore
    worker: Worker
    metrics: Metrics
    #: The HTTP request rendered for: a job still queued when its client disconnects is
    #: dropped (None: the stream, which drops its own).
    request: Request | None = None

    async def scene(self, scene_id: str) -> Scene:
        """The stored scene, parsed off the event loop (store errors reach their handler)."""
        with self.metrics.step("scene_load"):
            return await run_in_threadpool(self.store.get_scene, scene_id)

    async def job(self, job: Job[T], label: str, pin: str | None = None) -> T:
        """Submit a job (GL or Embree) to the worker and await its result: 503 (+ Retry-After)
        when the queue is full, there is no context or the worker process died running
        it, 504 past the job timeout, 404 when its scene was deleted before it ran,
        422 when the job rejects its parameters (ValueError), 500 when it raised
        anything else. Jobs with the same `pin` run on
        the same worker (a stream's stateful reuser)."""
        settings = self.settings
        try:
            fut = self.worker.submit(job, timeout=settings.job_timeout_s, label=label, pin=pin)
        except (QueueFull, WorkerUnavailable) as exc:
            raise unavailable(str(exc), settings) from None
        try:
            with self.metrics.step("job"):
                return await self._result(fut, settings.job_timeout_s)
        except (asyncio.TimeoutError, JobExpired):
            fut.cancel()
            raise HTTPException(504, f"{label} did not finish within {settings.job_timeout_s:g} s") from None
        except ClientGone:
            fut.cancel()  # still queued: never runs (a running job ends on its own)
            raise HTTPException(CLIENT_CLOSED, f"the client closed the connection before {label} was done"
                                ) from None
        except WorkerUnavailable as exc:
            raise unavailable(str(exc), settings) from None
        except HTTPException:
            raise
        except SceneNotFound as exc:  # deleted while its job waited (the worker loads scenes by id)
            raise HTTPException(404, short(str(exc))) from None
        except ValueError as exc:  # a job rejecting its parameters
            raise HTTPException(422, str(exc)[:500]) from None
        except Exception as exc:  # noqa: BLE001
            log.exception("render job failed", exc_info=exc)
            raise HTTPException(500, f"{label} failed: {type(exc).__name__}: {str(exc)[:300]}") from None

    async def _result(self, fut: Future[T], timeout: float) -> T:
        """The job's result; asyncio.TimeoutError past `timeout`, ClientGone when the
        request's client disconnects first."""
        result = asyncio.ensure_future(asyncio.wrap_future(fut))
        if self.request is None:
            return await asyncio.wait_for(result, timeout)
        deadline = asyncio.get_running_loop().time() + timeout
        gone = asyncio.ensure_future(_disconnect(self.request))
        try:
            done, _ = await asyncio.wait({result, gone}, timeout=timeout, return_when=asyncio.FIRST_COMPLETED)
        except asyncio.CancelledError:  # the request itself was cancelled (a shutdown's grace ran out):
            result.cancel()  # drop the job if still queued; its later failure is no one's to log
            raise
        finally:
            gone.cancel()
        if result in done:
            return result.result()
        if gone in done and gone.exception() is not None:  # no way to watch the client: wait for the job alone
            return await asyncio.wait_for(result, max(0.0, deadline - asyncio.get_running_loop().time()))
        result.cancel()
        raise ClientGone if gone in done else asyncio.TimeoutError

    async def cpu(self, fn: Callable[..., T], *args: Any) -> T:
        """`fn(*args)` in the thread pool, timed as cpu: CPU work that is no render
        (shading). Embree work is a job (``service.jobs``): queued and timed."""
        with self.metrics.step("cpu"):
            return await run_in_threadpool(fn, *args)

    async def encode(self, fn: Callable[..., T], *args: Any) -> T:
        """`fn(*args)` in the thread pool, timed as encode."""
        with self.metrics.step("encode"):
            return await run_in_threadpool(fn, *args)


def get_render(request: Request) -> Render:
    state = request.app.state
    return Render(state.settings, state.store, state.worker, state.metrics, request)


#: Status logged for a request whose client left before its job was done (nginx's 499:
#: no one reads the answer).
CLIENT_CLOSED = 499


class ClientGone(Exception):
    """The HTTP client disconnected while its job waited or ran."""


async def _disconnect(request: Request) -> None:
    """Returns when the client disconnects (the body is read by then: ASGI's receive
    has nothing else to give)."""
    while (await request.receive())["type"] != "http.disconnect":
        pass


RenderDep = Annotated[Render, Depends(get_render)]

"""Liveness, readiness (open to probes even with a token) and metrics."""

from __future__ import annotations

from fastapi import APIRouter, Depends
from fastapi.responses import JSONResponse, PlainTextResponse

from service.deps import MetricsDep, StoreDep, WorkerDep, require_token
from service.errors import responses
from service.schemas import Readiness

probes = APIRouter(tags=["service"])
metrics_router = APIRouter(tags=["service"], dependencies=[Depends(require_token)])


#: Why /readyz is 503 while no worker failed to start: it is starting, or one is being replaced.
NOT_READY = "no render worker is ready yet: starting, or replacing one that died or ran past its time limit"


@probes.get("/healthz", summary="Liveness: the process is up")
async def healthz() -> dict[str, str]:
    return {"status": "ok"}


@probes.get("/readyz", response_model=Readiness, summary="Readiness: the render worker's GL context is alive",
            responses={503: {"model": Readiness, "description": "GL context not (yet) alive"}})
async def readyz(worker: WorkerDep) -> JSONResponse:
    body = Readiness(ready=worker.ready, renderer=worker.renderer, backend=worker.backend,
                     software=worker.is_software, gl_version=worker.gl_version,
                     error=worker.startup_error or (None if worker.ready else NOT_READY))
    return JSONResponse(body.model_dump(), status_code=200 if worker.ready else 503)


@metrics_router.get("/metrics", response_class=PlainTextResponse, summary="Prometheus text-format metrics",
                    responses=responses({401: "missing or wrong bearer token"}))
async def metrics(worker: WorkerDep, store: StoreDep, metrics_: MetricsDep) -> PlainTextResponse:
    return PlainTextResponse(metrics_.render(worker.stats(), store.cached), media_type="text/plain; version=0.0.4")

"""The HTTP service (FastAPI): ``create_app`` assembles the routers, the middleware
and the error handlers; the lifespan opens the scene store and starts the render
worker.

Routes (OpenAPI at /docs), one ``APIRouter`` per resource in ``service.routes``:

=========================  =====================================================================
GET  /healthz              200 while the process is alive (no token needed)
GET  /readyz               200 when the GL worker's context is alive, else 503 (no token needed)
GET  /metrics              Prometheus text format: latency per route, steps, queue, workers, errors
GET  /scenes               every scene: built-in defaults first, then stored scenes
POST /scenes               multipart upload (field ``file``; format from the file name suffix or a
                           ``format`` field), a raw body (``?format=obj``), or JSON
                           ``{"builtin": name, "params": {...}}``; 201 new / 200 already stored
GET  /scenes/{id}          one scene's metadata
DELETE /scenes/{id}        204; built-in defaults → 409
POST /scenes/{id}/frames   a frame: image/png (sRGB) or image/x-exr (RGB, Z, N, id, object)
POST /scenes/{id}/reconstruction  the reconstruction of a depth-image set as GLB
POST /scenes/{id}/depth-images  a depth-image set (conventional | non_redundant | peeling): multi-part
                           EXR or npz; metrics=true → JSON with the §2.3.2 metrics and the set (base64)
WS   /scenes/{id}/stream   camera messages in, JPEG/PNG frames and per-frame stats out (service.stream)
GET  /client               the thin-client page (stream or local mode); /client/static/*, /client/three/*
=========================  =====================================================================

Status codes (every one with its schema in OpenAPI): 400 a body that is not JSON (on
every endpoint) or a malformed multipart body; 401 missing or wrong bearer token (when
``DEPTHVIEW_TOKEN`` is set); 404 unknown or malformed scene id, unknown path; 405 with
``Allow``; 408 a request body that stalled; 409 deleting a built-in default; 413 a body
over its limit; 415 unknown/unsupported scene format; 422 invalid request fields (strict
types, camera with NaN/inf or out-of-range coordinates, eye == target, zero or parallel
up, fov under the minimum, frame size over the limits, over the memory budget, unknown
effect method), malformed scene file (the loader's message), scene over
``max_triangles``, unknown built-in or bad params; 503 render queue full or no GL
context (with ``Retry-After``); 504 the render job did not finish within
``job_timeout_s``; 500 anything unexpected.

Request handlers never touch GL: parsing runs in the thread pool; GPU upload and
rendering run as jobs (``service.jobs``) on the ``RenderWorker`` thread.
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import anyio
from fastapi import FastAPI
from fastapi.middleware.cors import CORSMiddleware
from fastapi.openapi.utils import get_openapi
from starlette.concurrency import run_in_threadpool

from service import errors
from service.config import Settings
from service.metrics import Metrics
from service.middleware import RequestGuard
from service.parsing import ParseLimits, UploadParser
from service.process_worker import ProcessWorkerPool, WorkerConfig
from service.routes import client, docs, renders, scenes, stream
from service.routes import service as service_routes
from service.schemas import BuiltinParams, BuiltinSceneRequest, ErrorResponse, ValidationErrorResponse
from service.store import SceneStore
from service.stream import ReuseFrameSource, StreamSlots
from service.worker import RenderWorker

log = logging.getLogger("depthview.service")


def create_app(settings: Settings | None = None) -> FastAPI:
    """The FastAPI application; its lifespan opens the scene store and starts
    (then stops) the render worker."""
    settings = settings or Settings.from_env()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        parse = UploadParser(ParseLimits(settings.parse_timeout_s, settings.max_job_bytes), max(1, settings.workers))
        app.state.upload_turns = anyio.CapacityLimiter(parse.concurrent)  # routes.scenes: uploads wait without a thread
        app.state.store = await run_in_threadpool(
            SceneStore, settings.data_dir, settings.scene_cache_size, settings.max_triangles, parse=parse)
        worker: Any
        if settings.workers >= 1:
            worker = ProcessWorkerPool(settings.workers, WorkerConfig(
                str(settings.data_dir), settings.scene_cache_size, settings.max_triangles, settings.gpu_cache_size,
                settings.gl_backend, settings.gl_device, settings.reconstruction_cache_bytes, settings.keep_pixels),
                queue_size=settings.queue_size,
                job_timeout_s=settings.job_timeout_s)
        else:
            worker = RenderWorker(queue_size=settings.queue_size, job_timeout_s=settings.job_timeout_s,
                                  gpu_cache_size=settings.gpu_cache_size, backend=settings.gl_backend,
                                  device=settings.gl_device, scene_loader=app.state.store.get_scene,
                                  reconstruction_cache_bytes=settings.reconstruction_cache_bytes,
                                  keep_pixels=settings.keep_pixels)
        app.state.worker = worker.start()
        try:
            yield
        finally:
            await run_in_threadpool(worker.stop)

    app = FastAPI(title="depthview", version="0.1.0", lifespan=lifespan, docs_url=None, redoc_url=None,
                  description="Headless rendering service approximating scenes with depth images.")
    app.state.settings = settings
    app.state.metrics = Metrics()
    app.state.stream_slots = StreamSlots(settings)
    app.state.pending_uploads = scenes.PendingUploads()  # routes.scenes: the bytes uploads in progress hold
    #: Makes each stream's FrameSource (cluster reflections through a per-stream ReflectionReuser).
    app.state.frame_source = ReuseFrameSource
    errors.install(app)
    for router in (service_routes.probes, service_routes.metrics_router, scenes.router, renders.frames,
                   renders.reconstructions, renders.depth_images, stream.router, client.router, docs.router):
        app.include_router(router)
    app.add_middleware(RequestGuard, settings=settings, metrics=app.state.metrics,
                       templates=lambda: list(app.openapi()["paths"]))
    if settings.cors_origins:  # outermost, so refusals (401, 413) carry the CORS headers too
        app.add_middleware(CORSMiddleware, allow_origins=list(settings.cors_origins), allow_methods=["*"],
                           allow_headers=["Authorization", "Content-Type"],
                           expose_headers=["X-Render-Seconds", "Retry-After", "Location"])

    def custom_openapi() -> dict[str, Any]:
        if app.openapi_schema:
            return app.openapi_schema
        schema = get_openapi(title=app.title, version=app.version, description=app.description, routes=app.routes)
        comps = schema.setdefault("components", {}).setdefault("schemas", {})
        for model in (BuiltinSceneRequest, BuiltinParams, ErrorResponse, ValidationErrorResponse):
            s = model.model_json_schema(ref_template="#/components/schemas/{model}")
            for name, sub in s.pop("$defs", {}).items():
                comps.setdefault(name, sub)
            comps.setdefault(model.__name__, s)
        for ops in schema["paths"].values():  # a string path parameter cannot fail validation
            for op in ops.values():
                params = op.get("parameters", [])
                if "requestBody" not in op and all(p["in"] == "path" and p["schema"].get("type") == "string"
                                                   for p in params):
                    op["responses"].pop("422", None)
        for name in ("FrameRequest", "DepthImagesRequest"):  # the size limits of this service's settings
            props = comps[name]["properties"]
            props["width"]["maximum"], props["height"]["maximum"] = settings.max_width, settings.max_height
        app.openapi_schema = schema
        return schema

    app.openapi = custom_openapi  # type: ignore[method-assign]
    return app

"""The HTTP service (FastAPI): scenes, frames, health, readiness and metrics.

Routes (OpenAPI at /docs):

=========================  =====================================================================
GET  /healthz              200 while the process is alive
GET  /readyz               200 when the GL worker's context is alive, else 503 (JSON says why)
GET  /metrics              Prometheus text format counters
GET  /scenes               every scene: built-in defaults first, then stored scenes
POST /scenes               multipart upload (field ``file``; format from the file name suffix or a
                           ``format`` field), a raw body (``?format=obj``), or JSON
                           ``{"builtin": name, "params": {...}}``; 201 new / 200 already stored
GET  /scenes/{id}          one scene's metadata
DELETE /scenes/{id}        204; built-in defaults → 409
POST /scenes/{id}/frames   a frame: image/png (sRGB) or image/x-exr (RGB, Z, N, id, object)
POST /scenes/{id}/depth-images  a depth-image set (conventional | non_redundant | peeling): multi-part
                           EXR or npz; metrics=true → JSON with the §2.3.2 metrics and the set (base64)
=========================  =====================================================================

Status codes: 400 malformed request body (bad JSON/multipart); 404 unknown or
malformed scene id; 409 deleting a built-in default; 413 upload over
``max_upload_bytes``; 415 unknown/unsupported scene format; 422 invalid request
fields (camera with NaN/inf, eye == target, zero or parallel up, frame size over
the limits, unknown effect method), malformed scene file (the loader's message),
scene over ``max_triangles``, unknown built-in or bad params; 503 render queue full
or no GL context (with ``Retry-After``); 504 the render job did not finish within
``job_timeout_s``; 500 anything unexpected.

Request handlers never touch GL: parsing runs in the thread pool; GPU upload and
rendering run as jobs on the ``RenderWorker`` thread.
"""

from __future__ import annotations

import asyncio
import base64
import logging
import math
import threading
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import PurePath
from typing import Any

from fastapi import FastAPI, HTTPException, Request, Response
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.utils import get_openapi
from fastapi.responses import JSONResponse, PlainTextResponse
from pydantic import ValidationError
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import UploadFile
from starlette.formparsers import MultiPartException, MultiPartParser

from gl_passes.reconstruction import glb_bytes
from scenes.loaders import SceneLoadError
from scenes.model import AreaLight, Scene
from service.config import Settings
from service.depth_sets import embree_set, encode_set, needs_gl, plan_set, set_job, set_metrics
from service.effects import encode_reflections, raytrace, reflection_job
from service.schemas import (
    BuiltinParams,
    BuiltinSceneRequest,
    DepthImagesRequest,
    FrameRequest,
    Readiness,
    ReconstructionRequest,
    SceneInfo,
    SceneList,
)
from service.soft_shadows import (
    SoftShadowRequest,
    encode_shadowed,
    raytrace_counts,
    reconstruction_job,
    reference_cameras,
    resolve_light,
    shade,
    soft_shadow_job,
)
from service.store import (
    InvalidBuiltin,
    InvalidSceneId,
    SceneMeta,
    SceneNotFound,
    SceneProtected,
    SceneStore,
    StoreCorrupted,
    TriangleLimitExceeded,
    UnsupportedFormat,
)
from service.worker import JobExpired, QueueFull, RenderWorker, WorkerUnavailable, encode_frame, frame_job

log = logging.getLogger("depthview.service")

#: Allowance for multipart boundaries and small form fields on top of max_upload_bytes.
MULTIPART_OVERHEAD = 64 * 1024
#: Largest JSON body accepted by POST /scenes.
MAX_JSON_BYTES = 1024 * 1024
#: Content types accepted as a raw scene upload body, and the format they imply.
RAW_CONTENT_TYPES = {"application/octet-stream": None, "model/gltf-binary": "glb", "model/gltf+json": "gltf",
                     "model/obj": "obj", "model/ply": "ply", "application/ply": "ply"}
MEDIA_TYPES = {"png": "image/png", "exr": "image/x-exr"}


class _BodyTooLarge(Exception):
    def __init__(self, seen: int, limit: int) -> None:
        super().__init__(f"request body exceeds {limit} bytes")
        self.seen, self.limit = seen, limit


class Metrics:
    """Service-level counters (the worker keeps its own)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.frames: dict[str, int] = {}
        self.frame_seconds_sum = 0.0
        self.frame_seconds_count = 0
        self.frame_errors: dict[int, int] = {}
        self.uploads = 0
        self.started = time.time()

    def frame(self, fmt: str, seconds: float) -> None:
        with self._lock:
            self.frames[fmt] = self.frames.get(fmt, 0) + 1
            self.frame_seconds_sum += seconds
            self.frame_seconds_count += 1

    def frame_error(self, status: int) -> None:
        with self._lock:
            self.frame_errors[status] = self.frame_errors.get(status, 0) + 1

    def upload(self) -> None:
        with self._lock:
            self.uploads += 1

    def snapshot(self) -> tuple[list[tuple[str, int]], list[tuple[int, int]], float, int, int]:
        """(frames by format, errors by status, frame seconds sum, count, uploads)."""
        with self._lock:
            return (sorted(self.frames.items()), sorted(self.frame_errors.items()), self.frame_seconds_sum,
                    self.frame_seconds_count, self.uploads)


# --- helpers ------------------------------------------------------------------------------
def _info(meta: SceneMeta) -> SceneInfo:
    d = meta.to_dict()
    d.pop("extra", None)
    return SceneInfo(**d)


def _http_error(exc: Exception) -> HTTPException:
    """Map store/loader errors to HTTP errors."""
    if isinstance(exc, (InvalidSceneId, SceneNotFound)):
        return HTTPException(404, str(exc))
    if isinstance(exc, SceneProtected):
        return HTTPException(409, str(exc))
    if isinstance(exc, UnsupportedFormat):
        return HTTPException(415, str(exc))
    if isinstance(exc, (TriangleLimitExceeded, InvalidBuiltin, SceneLoadError)):
        return HTTPException(422, str(exc))
    if isinstance(exc, StoreCorrupted):
        log.error("%s", exc)
        return HTTPException(500, str(exc))
    if isinstance(exc, ValueError):  # e.g. make_builtin rejecting parameters
        return HTTPException(422, str(exc))
    log.exception("unexpected error", exc_info=exc)
    return HTTPException(500, f"internal error: {type(exc).__name__}")


async def _limited(stream: AsyncIterator[bytes], limit: int) -> AsyncIterator[bytes]:
    """Pass the body through, raising _BodyTooLarge as soon as it exceeds `limit`."""
    seen = 0
    async for chunk in stream:
        seen += len(chunk)
        if seen > limit:
            raise _BodyTooLarge(seen, limit)
        yield chunk


def _check_content_length(request: Request, limit: int, what: str) -> None:
    cl = request.headers.get("content-length")
    if cl is None:
        return
    try:
        n = int(cl)
    except ValueError:
        raise HTTPException(400, "invalid Content-Length header") from None
    if n > limit:
        raise HTTPException(413, f"{what} is {n} bytes; the limit is {limit} bytes")


async def _read_limited(request: Request, limit: int, what: str) -> bytes:
    _check_content_length(request, limit, what)
    buf = bytearray()
    try:
        async for chunk in _limited(request.stream(), limit):
            buf.extend(chunk)
    except _BodyTooLarge as exc:
        raise HTTPException(413, f"{what} exceeds the limit of {exc.limit} bytes") from None
    return bytes(buf)


def _format_from(fmt: str | None, filename: str | None) -> str:
    if fmt:
        return fmt.strip().lower().lstrip(".")
    suffix = PurePath(filename or "").suffix.lower().lstrip(".")
    if not suffix:
        raise HTTPException(415, "cannot tell the scene format: upload a file whose name ends in .glb, .gltf, "
                                 ".obj or .ply, or give a 'format' field")
    return suffix


def _json_safe(obj: Any) -> Any:
    """Replace NaN/inf floats (JSON has none) by their names, recursively."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return str(obj)
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


async def _validation_error(request: Request, exc: Exception) -> JSONResponse:
    """422 with pydantic's error list (location + message). Unlike FastAPI's default
    handler it survives NaN/inf in the echoed input (Python's JSON parser accepts them)."""
    assert isinstance(exc, RequestValidationError)
    errors = [{k: v for k, v in e.items() if k != "ctx"} for e in exc.errors()]
    return JSONResponse({"detail": _json_safe(jsonable_encoder(errors))}, status_code=422)


def _unavailable(detail: str, settings: Settings) -> HTTPException:
    return HTTPException(503, detail, headers={"Retry-After": str(settings.retry_after_s)})


def check_size(settings: Settings, width: int, height: int, what: str = "frame") -> None:
    """422 when width, height or their product exceed the service limits."""
    for name, value, limit in ((f"{what} width", width, settings.max_width),
                               (f"{what} height", height, settings.max_height),
                               (f"{what} width × height", width * height, settings.max_pixels)):
        if value > limit:
            raise HTTPException(422, f"{name} {value} exceeds the limit {limit}")


async def load_scene(app: FastAPI, scene_id: str) -> Scene:
    """The stored scene (parsed off the event loop); 404/422 on store errors."""
    try:
        return await run_in_threadpool(app.state.store.get_scene, scene_id)
    except Exception as exc:  # noqa: BLE001
        raise _http_error(exc) from None


async def run_job(app: FastAPI, job: Any, label: str) -> Any:
    """Submit a job to the GL worker and await its result: 503 (+ Retry-After) when
    the queue is full or there is no context, 504 past the job timeout, 500 when
    the job raised."""
    settings: Settings = app.state.settings
    worker: RenderWorker = app.state.worker
    try:
        fut = worker.submit(job, timeout=settings.job_timeout_s, label=label)
    except (QueueFull, WorkerUnavailable) as exc:
        raise _unavailable(str(exc), settings) from None
    try:
        return await asyncio.wait_for(asyncio.wrap_future(fut), timeout=settings.job_timeout_s)
    except (asyncio.TimeoutError, JobExpired):
        fut.cancel()
        raise HTTPException(504, f"{label} did not finish within {settings.job_timeout_s:g} s") from None
    except WorkerUnavailable as exc:
        raise _unavailable(str(exc), settings) from None
    except HTTPException:
        raise
    except ValueError as exc:  # a job rejecting its parameters
        raise HTTPException(422, str(exc)) from None
    except Exception as exc:  # noqa: BLE001
        log.exception("render job failed", exc_info=exc)
        raise HTTPException(500, f"{label} failed: {type(exc).__name__}: {exc}") from None


# --- the app --------------------------------------------------------------------------
def create_app(settings: Settings | None = None) -> FastAPI:
    """The FastAPI application; its lifespan opens the scene store and starts
    (then stops) the render worker."""
    settings = settings or Settings.from_env()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        app.state.store = await run_in_threadpool(
            SceneStore, settings.data_dir, settings.scene_cache_size, settings.max_triangles)
        worker = RenderWorker(queue_size=settings.queue_size, job_timeout_s=settings.job_timeout_s,
                              gpu_cache_size=settings.gpu_cache_size, backend=settings.gl_backend,
                              device=settings.gl_device)
        app.state.worker = worker.start()
        try:
            yield
        finally:
            await run_in_threadpool(worker.stop)

    app = FastAPI(title="depthview", version="0.1.0", lifespan=lifespan,
                  description="Headless rendering service approximating scenes with depth images.")
    app.state.settings = settings
    app.state.metrics = Metrics()
    app.add_exception_handler(RequestValidationError, _validation_error)

    # --- health ------------------------------------------------------------------------
    @app.get("/healthz", tags=["service"], summary="Liveness: the process is up")
    async def healthz() -> dict[str, str]:
        return {"status": "ok"}

    @app.get("/readyz", tags=["service"], response_model=Readiness,
             responses={503: {"model": Readiness, "description": "GL context not (yet) alive"}},
             summary="Readiness: the render worker's GL context is alive")
    async def readyz(request: Request) -> JSONResponse:
        w: RenderWorker = request.app.state.worker
        body = Readiness(ready=w.ready, renderer=w.renderer, backend=w.backend, software=w.is_software,
                         gl_version=w.gl_version, error=w.startup_error)
        return JSONResponse(body.model_dump(), status_code=200 if w.ready else 503)

    @app.get("/metrics", tags=["service"], response_class=PlainTextResponse,
             summary="Prometheus text-format metrics")
    async def metrics(request: Request) -> PlainTextResponse:
        return PlainTextResponse(_metrics_text(request.app), media_type="text/plain; version=0.0.4")

    # --- scenes ------------------------------------------------------------------------
    @app.get("/scenes", tags=["scenes"], response_model=SceneList, summary="List scenes")
    async def list_scenes(request: Request) -> SceneList:
        metas = await run_in_threadpool(request.app.state.store.list)
        return SceneList(scenes=[_info(m) for m in metas])

    @app.post(
        "/scenes", tags=["scenes"], response_model=SceneInfo, status_code=201,
        summary="Upload a scene file or register a built-in scene",
        responses={200: {"model": SceneInfo, "description": "already stored (same content ⇒ same id)"},
                   400: {"description": "malformed body"}, 413: {"description": "upload too large"},
                   415: {"description": "unsupported format"},
                   422: {"description": "malformed scene file, too many triangles, unknown built-in"}},
        openapi_extra={"requestBody": {"required": True, "content": {
            "multipart/form-data": {"schema": {"type": "object", "required": ["file"], "properties": {
                "file": {"type": "string", "format": "binary", "description": "a .glb, .gltf, .obj or .ply file"},
                "format": {"type": "string", "enum": ["glb", "gltf", "obj", "ply"],
                           "description": "overrides the file name suffix"},
                "name": {"type": "string", "description": "display name (default: the file name stem)"}}}},
            "application/json": {"schema": {"$ref": "#/components/schemas/BuiltinSceneRequest"}},
            "application/octet-stream": {"schema": {"type": "string", "format": "binary"},
                                         "description": "raw file; give ?format="}}}})
    async def create_scene(request: Request, format: str | None = None, name: str | None = None) -> JSONResponse:
        ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
        store: SceneStore = request.app.state.store
        if ctype == "application/json":
            body = await _read_limited(request, MAX_JSON_BYTES, "JSON body")
            try:
                req = BuiltinSceneRequest.model_validate_json(body)
            except ValidationError as exc:
                errors = exc.errors(include_url=False)
                if any(e["type"] == "json_invalid" for e in errors):
                    raise HTTPException(400, "request body is not valid JSON") from None
                raise RequestValidationError([{**e, "loc": ("body", *e["loc"])} for e in errors]) from None
            try:
                meta, created = await run_in_threadpool(store.put_builtin, req.builtin, req.params.model_dump())
            except Exception as exc:  # noqa: BLE001 - mapped to a status code
                raise _http_error(exc) from None
        else:
            if ctype == "multipart/form-data":
                data, fmt, display = await _read_multipart(request, settings, format, name)
            elif ctype in RAW_CONTENT_TYPES:
                implied = format or RAW_CONTENT_TYPES[ctype]
                if not implied:
                    raise HTTPException(415, "a raw upload needs its format: add ?format=glb|gltf|obj|ply")
                data = await _read_limited(request, settings.max_upload_bytes, "upload")
                fmt = _format_from(implied, None)
                display = name or "upload"
            else:
                raise HTTPException(415, f"unsupported content type {ctype or '(none)'!r}: send multipart/form-data "
                                         "with a 'file' field, a raw body with ?format=, or JSON "
                                         "{\"builtin\": ...}")
            try:
                meta, created = await run_in_threadpool(store.put_upload, data, fmt, display)
            except Exception as exc:  # noqa: BLE001
                raise _http_error(exc) from None
            request.app.state.metrics.upload()
        return JSONResponse(jsonable_encoder(_info(meta)), status_code=201 if created else 200,
                            headers={"Location": f"/scenes/{meta.id}"})

    @app.get("/scenes/{scene_id}", tags=["scenes"], response_model=SceneInfo, summary="One scene's metadata",
             responses={404: {"description": "unknown or malformed id"}})
    async def get_scene(scene_id: str, request: Request) -> SceneInfo:
        try:
            meta = await run_in_threadpool(request.app.state.store.get_meta, scene_id)
        except Exception as exc:  # noqa: BLE001
            raise _http_error(exc) from None
        return _info(meta)

    @app.delete("/scenes/{scene_id}", tags=["scenes"], status_code=204, summary="Delete a stored scene",
                responses={404: {"description": "unknown or malformed id"},
                           409: {"description": "built-in default scenes cannot be deleted"}})
    async def delete_scene(scene_id: str, request: Request) -> Response:
        try:
            await run_in_threadpool(request.app.state.store.delete, scene_id)
        except Exception as exc:  # noqa: BLE001
            raise _http_error(exc) from None
        request.app.state.worker.forget(scene_id)
        return Response(status_code=204)

    # --- frames -------------------------------------------------------------------------
    @app.post(
        "/scenes/{scene_id}/frames", tags=["frames"], summary="Render a frame",
        response_class=Response,
        responses={200: {"content": {"image/png": {}, "image/x-exr": {}},
                         "description": "PNG (sRGB colour) or EXR (linear RGB, Z, N, id, object)"},
                   404: {"description": "unknown scene"}, 422: {"description": "invalid camera or size"},
                   503: {"description": "render queue full or no GL context (Retry-After)"},
                   504: {"description": "render timed out"}})
    async def render_frame(scene_id: str, req: FrameRequest, request: Request) -> Response:
        t0 = time.perf_counter()
        metrics_: Metrics = request.app.state.metrics
        try:
            body, media = await _render(request.app, scene_id, req)
        except HTTPException as exc:
            metrics_.frame_error(exc.status_code)
            raise
        dt = time.perf_counter() - t0
        metrics_.frame(req.format, dt)
        return Response(body, media_type=media, headers={
            "X-Render-Seconds": f"{dt:.4f}", "Content-Disposition": f'inline; filename="frame.{req.format}"'})

    async def _render(app_: FastAPI, scene_id: str, req: FrameRequest) -> tuple[bytes, str]:
        check_size(settings, req.width, req.height)
        scene = await load_scene(app_, scene_id)
        camera = req.to_camera().fit_clip(scene.bounds)
        label = f"frame {scene_id[:12]}"
        method, rays = req.effects.reflections, req.effects.glossy_rays
        if req.effects.soft_shadows is not None:
            return await _soft_shadow_frame(app_, scene_id, scene, camera, req, label)
        if method == "none":
            gbuf = await run_job(app_, frame_job(scene_id, scene, camera, req.cull_back_faces), label)
            body = await run_in_threadpool(encode_frame, gbuf, req.format)
        else:
            if method == "raytrace":
                result = await run_in_threadpool(raytrace, scene, camera, rays)
            else:
                result = await run_job(app_, reflection_job(scene_id, scene, camera, method, rays), label)
            body = await run_in_threadpool(encode_reflections, result, req.format)
        return body, MEDIA_TYPES[req.format]


    async def _soft_shadow_frame(app_: FastAPI, scene_id: str, scene: Scene, camera: Any, req: FrameRequest,
                                 label: str) -> tuple[bytes, str]:
        spec = req.effects.soft_shadows
        light = resolve_light(scene, None if spec.light is None else
                              AreaLight(spec.light.center, spec.light.u, spec.light.v))
        ss = SoftShadowRequest(light, spec.samples, spec.method, spec.reconstruction, spec.resolution)
        try:  # the light must see the whole scene from its corners (422 otherwise)
            reference_cameras(scene, light, "conventional", 16)
        except ValueError as exc:
            raise HTTPException(422, f"soft_shadows light: {exc}") from None
        gbuf, counts = await run_job(app_, soft_shadow_job(scene_id, scene, camera, ss), label)
        if counts is None:
            counts = await run_in_threadpool(raytrace_counts, scene, gbuf, ss)
        color = await run_in_threadpool(shade, scene, gbuf, counts, ss)
        body = await run_in_threadpool(encode_shadowed, color, gbuf, counts, req.format)
        return body, MEDIA_TYPES[req.format]

    # --- reconstructions (thesis Ch. 3) -----------------------------------------------------
    @app.post(
        "/scenes/{scene_id}/reconstruction", tags=["reconstruction"], summary="Reconstruct a depth-image set (GLB)",
        response_class=Response,
        responses={200: {"content": {"model/gltf-binary": {}},
                         "description": "binary glTF, one node per source image, vertex colours"},
                   404: {"description": "unknown scene"}, 422: {"description": "invalid cameras, light or size"},
                   503: {"description": "render queue full"}, 504: {"description": "timed out"}})
    async def reconstruct(scene_id: str, req: ReconstructionRequest, request: Request) -> Response:
        scene = await load_scene(request.app, scene_id)
        cams = req.to_cameras()
        try:
            if cams is None:
                spec = req.light
                light = resolve_light(scene, None if spec is None else AreaLight(spec.center, spec.u, spec.v))
                cams = reference_cameras(scene, light, req.method, req.resolution)
            else:
                cams = [c.fit_clip(scene.bounds) for c in cams]
        except ValueError as exc:
            raise HTTPException(422, f"reconstruction viewpoints: {exc}") from None
        if req.method == "peeling":
            cams = cams[:1]
        job = reconstruction_job(scene_id, scene, cams, req.method, req.reconstruction, req.layers)
        parts = await run_job(request.app, job, f"reconstruction {scene_id[:12]}")
        names = [f"{req.method}_{k}" for k in range(len(parts))]
        body = await run_in_threadpool(glb_bytes, parts, names)
        return Response(body, media_type="model/gltf-binary",
                        headers={"Content-Disposition": 'attachment; filename="reconstruction.glb"'})

    # --- depth-image sets (thesis Ch. 2) ---------------------------------------------------
    @app.post(
        "/scenes/{scene_id}/depth-images", tags=["depth images"], summary="Render a depth-image set",
        response_class=Response,
        responses={200: {"content": {"image/x-exr": {}, "application/x-npz": {}, "application/json": {}},
                         "description": "multi-part EXR (one part per image) or npz; with metrics=true JSON "
                                        "{metrics, media_type, images_b64}"},
                   404: {"description": "unknown scene"}, 422: {"description": "invalid cameras or size"},
                   503: {"description": "render queue full"}, 504: {"description": "timed out"}})
    async def render_depth_images(scene_id: str, req: DepthImagesRequest, request: Request) -> Response:
        check_size(settings, req.width, req.height, "depth image")
        scene = await load_scene(request.app, scene_id)
        plan = plan_set(scene, req.method, req.redundancy, req.to_cameras(), req.width, req.height, req.layers)
        images, conv = None, None
        if needs_gl(plan, req.metrics):
            images, conv = await run_job(request.app, set_job(scene_id, scene, plan, req.metrics),
                                         f"depth images {scene_id[:12]}")
        if images is None:
            images = await run_in_threadpool(embree_set, scene, plan)
        body = await run_in_threadpool(encode_set, images, req.format)
        media = {"exr": "image/x-exr", "npz": "application/x-npz"}[req.format]
        if not req.metrics:
            return Response(body, media_type=media)
        metrics = await run_in_threadpool(set_metrics, scene, plan, images, conv, req.intermediate_views, req.seed)
        return JSONResponse({"metrics": _json_safe(metrics), "media_type": media,
                             "images_b64": base64.b64encode(body).decode("ascii")})

    def custom_openapi() -> dict[str, Any]:
        if app.openapi_schema:
            return app.openapi_schema
        schema = get_openapi(title=app.title, version=app.version, description=app.description, routes=app.routes)
        comps = schema.setdefault("components", {}).setdefault("schemas", {})
        for model in (BuiltinSceneRequest, BuiltinParams):
            s = model.model_json_schema(ref_template="#/components/schemas/{model}")
            s.pop("$defs", None)
            comps.setdefault(model.__name__, s)
        app.openapi_schema = schema
        return schema

    app.openapi = custom_openapi  # type: ignore[method-assign]
    return app


async def _read_multipart(request: Request, settings: Settings, fmt: str | None,
                          name: str | None) -> tuple[bytes, str, str]:
    """Parse a multipart upload while counting bytes (413 past the limit); returns
    (file bytes, format, display name)."""
    limit = settings.max_upload_bytes
    _check_content_length(request, limit + MULTIPART_OVERHEAD, "upload")
    parser = MultiPartParser(request.headers, _limited(request.stream(), limit + MULTIPART_OVERHEAD),
                             max_files=1, max_fields=8)
    try:
        form = await parser.parse()
    except _BodyTooLarge as exc:
        raise HTTPException(413, f"upload exceeds the limit of {limit} bytes (body passed {exc.limit} "
                                 "bytes including multipart overhead)") from None
    except MultiPartException as exc:
        raise HTTPException(400, f"malformed multipart body: {exc.message}") from None
    try:
        upload = form.get("file")
        if not isinstance(upload, UploadFile):
            raise HTTPException(422, "multipart upload needs a file field named 'file'")
        data = await upload.read(limit + 1)
        if len(data) > limit:
            raise HTTPException(413, f"upload is larger than the limit of {limit} bytes")
        form_fmt = form.get("format")
        form_name = form.get("name")
        fmt_ = _format_from(fmt or (form_fmt if isinstance(form_fmt, str) else None), upload.filename)
        display = name or (form_name if isinstance(form_name, str) else None) or PurePath(upload.filename or "").stem
        return data, fmt_, display or "upload"
    finally:
        await form.close()


def _metrics_text(app: FastAPI) -> str:
    """Prometheus exposition format (text 0.0.4)."""
    w = app.state.worker.stats()
    m: Metrics = app.state.metrics
    store: SceneStore = app.state.store
    out: list[str] = []

    def metric(name: str, typ: str, help_: str, samples: list[tuple[str, float]]) -> None:
        out.append(f"# HELP {name} {help_}")
        out.append(f"# TYPE {name} {typ}")
        for labels, value in samples:
            out.append(f"{name}{labels} {value}")

    metric("depthview_ready", "gauge", "1 when the render worker's GL context is alive.", [("", int(w["ready"]))])
    metric("depthview_jobs_total", "counter", "Render jobs by outcome.", [
        ('{outcome="done"}', w["jobs_done"]), ('{outcome="failed"}', w["jobs_failed"]),
        ('{outcome="expired"}', w["jobs_expired"]), ('{outcome="rejected"}', w["jobs_rejected"])])
    metric("depthview_queue_depth", "gauge", "Render jobs waiting in the queue.", [("", w["queue_depth"])])
    metric("depthview_queue_capacity", "gauge", "Size of the render job queue.", [("", w["queue_capacity"])])
    metric("depthview_worker_busy", "gauge", "1 while the worker runs a job.", [("", int(w["busy"]))])
    metric("depthview_job_seconds", "summary", "Time the GL thread spent per job.",
           [("_sum", float(w["job_seconds_sum"])), ("_count", w["job_seconds_count"])])
    metric("depthview_last_job_seconds", "gauge", "Duration of the latest job.", [("", float(w["last_job_seconds"]))])
    frames, errors, fsum, fcount, uploads = m.snapshot()
    metric("depthview_frames_total", "counter", "Frames served by format.",
           [(f'{{format="{k}"}}', v) for k, v in frames] or [('{format="png"}', 0)])
    metric("depthview_frame_errors_total", "counter", "Failed frame requests by status.",
           [(f'{{status="{k}"}}', v) for k, v in errors])
    metric("depthview_frame_seconds", "summary", "End-to-end frame request time.",
           [("_sum", float(fsum)), ("_count", fcount)])
    metric("depthview_uploads_total", "counter", "Scene upload requests accepted.", [("", uploads)])
    metric("depthview_gpu_scenes_cached", "gauge", "Scenes uploaded to the GPU.", [("", w["gpu_scenes_cached"])])
    metric("depthview_scenes_cached", "gauge", "Parsed scenes in memory.", [("", store.cached)])
    return "\n".join(out) + "\n"

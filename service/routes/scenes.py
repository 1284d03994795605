"""``/scenes``: list, upload (multipart, raw body, or a built-in by JSON), metadata,
delete. Store and loader errors reach the one handler in ``service.errors``."""

from __future__ import annotations

from collections.abc import AsyncIterator, Iterator
from contextlib import contextmanager
from pathlib import PurePath

import anyio
from fastapi import APIRouter, Depends, HTTPException, Request, Response
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import ValidationError
from python_multipart.multipart import DEFAULT_MAX_HEADER_SIZE as MULTIPART_HEADER_BYTES
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import UploadFile
from starlette.formparsers import MultiPartException, MultiPartParser

from service.config import Settings
from service.deps import MetricsDep, SettingsDep, StoreDep, WorkerDep, require_token, unavailable
from service.errors import json_media_type, responses
from service.middleware import MULTIPART_OVERHEAD, body_limit
from service.parsing import no_turn
from service.schemas import BuiltinSceneRequest, SceneInfo, SceneList
from service.store import SceneMeta, SceneStore

router = APIRouter(prefix="/scenes", tags=["scenes"], dependencies=[Depends(require_token)],
                   responses=responses({401: "missing or wrong bearer token"}))

#: Content types accepted as a raw scene upload body, and the format they imply.
RAW_CONTENT_TYPES = {"application/octet-stream": None, "model/gltf-binary": "glb", "model/gltf+json": "gltf",
                     "model/obj": "obj", "model/ply": "ply", "application/ply": "ply"}


class _BodyTooLarge(Exception):
    def __init__(self, seen: int, limit: int) -> None:
        super().__init__(f"request body exceeds {limit} bytes")
        self.seen, self.limit = seen, limit


def _info(meta: SceneMeta) -> SceneInfo:
    d = meta.to_dict()
    d.pop("extra", None)
    return SceneInfo(**d)


async def _limited(stream: AsyncIterator[bytes], limit: int) -> AsyncIterator[bytes]:
    """Pass the body through, raising _BodyTooLarge as soon as it exceeds `limit`."""
    seen = 0
    async for chunk in stream:
        seen += len(chunk)
        if seen > limit:
            raise _BodyTooLarge(seen, limit)
        yield chunk


#: The variable of each body limit, named in its 413.
_LIMIT_VARS = {"upload": "DEPTHVIEW_MAX_UPLOAD_BYTES", "JSON body": "DEPTHVIEW_MAX_JSON_BYTES"}


def _check_content_length(request: Request, limit: int, what: str) -> None:
    cl = request.headers.get("content-length")
    if cl is None:
        return
    try:
        n = int(cl)
    except ValueError:
        raise HTTPException(400, "invalid Content-Length header") from None
    if n > limit:
        raise HTTPException(413, f"{what} is {n} bytes; the limit is {limit} bytes ({_LIMIT_VARS[what]})")


async def _read_limited(request: Request, limit: int, what: str) -> bytes:
    _check_content_length(request, limit, what)
    buf = bytearray()
    try:
        async for chunk in _limited(request.stream(), limit):
            buf.extend(chunk)
    except _BodyTooLarge as exc:
        raise HTTPException(413, f"{what} exceeds the limit of {exc.limit} bytes ({_LIMIT_VARS[what]})") from None
    return bytes(buf)


#: Longest format name repeated in an error (the store names an unsupported format).
FORMAT_EXCERPT = 16


def _format_from(fmt: str | None, filename: str | None) -> str:
    if fmt:
        return fmt.strip().lower().lstrip(".")[:FORMAT_EXCERPT]
    suffix = PurePath(filename or "").suffix.lower().lstrip(".")[:FORMAT_EXCERPT]
    if not suffix:
        raise HTTPException(415, "cannot tell the scene format: upload a file whose name ends in .glb, .gltf, "
                                 ".obj or .ply, or give a 'format' field")
    return suffix


def _multipart_problem(exc: MultiPartException) -> str:
    """What python-multipart found wrong (Starlette says only "Invalid multipart data.")."""
    why = str(exc.__cause__ or "") or exc.message
    if "header size" in why:
        why += (f" (a part's header line, its file name included, may be at most "
                f"{MULTIPART_HEADER_BYTES:,} bytes)")
    return why[:240]


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
        raise HTTPException(413, f"upload exceeds the limit of {limit} bytes, DEPTHVIEW_MAX_UPLOAD_BYTES (body "
                                 f"passed {exc.limit} bytes including multipart overhead)") from None
    except MultiPartException as exc:
        raise HTTPException(400, f"malformed multipart body: {_multipart_problem(exc)}") from None
    try:
        upload = form.get("file")
        if not isinstance(upload, UploadFile):
            raise HTTPException(422, "multipart upload needs a file field named 'file'")
        data = await upload.read(limit + 1)
        if len(data) > limit:
            raise HTTPException(413, f"upload is larger than the limit of {limit} bytes (DEPTHVIEW_MAX_UPLOAD_BYTES)")
        form_fmt = form.get("format")
        form_name = form.get("name")
        fmt_ = _format_from(fmt or (form_fmt if isinstance(form_fmt, str) else None), upload.filename)
        display = name or (form_name if isinstance(form_name, str) else None) or PurePath(upload.filename or "").stem
        return data, fmt_, display or "upload"
    finally:
        await form.close()


class PendingUploads:
    """Bytes held by the uploads in progress (``Settings.max_pending_upload_bytes``):
    each is counted from before its body is read until it is stored or refused, by its
    Content-Length, else as the largest upload the body limit lets through
    (``middleware.body_limit``). Used on the event loop only."""

    def __init__(self) -> None:
        self.bytes = 0
        self.count = 0

    @contextmanager
    def hold(self, request: Request, settings: Settings) -> Iterator[None]:
        """Count this upload while it is received, waits and is parsed; 503 (+ Retry-After)
        when it would take the bytes held past the budget, unless it is the only one."""
        try:
            size = int(request.headers.get("content-length", ""))
        except ValueError:  # none, or malformed (413/400 come from the body's own checks)
            size = -1
        if size < 0:
            size = body_limit(settings, request.scope)[0]
        budget = settings.max_pending_upload_bytes
        if self.count and self.bytes + size > budget:
            raise unavailable(f"{self.count} upload(s) of {self.bytes} bytes are being received or parsed; this one "
                              f"({size} bytes) would pass the limit of {budget} bytes "
                              "(DEPTHVIEW_MAX_PENDING_UPLOAD_BYTES): try again", settings)
        self.bytes += size
        self.count += 1
        try:
            yield
        finally:
            self.bytes -= size
            self.count -= 1


async def _put_upload(request: Request, settings: Settings, store: SceneStore, data: bytes, fmt: str,
                      display: str) -> tuple[SceneMeta, bool]:
    """``store.put_upload`` once the upload has its turn (as many at once as are parsed at
    once): a waiting upload holds no thread of the pool every route shares (a burst of
    uploads stalled the scene list, scene loads and encoding), and after PARSE_TIMEOUT_S
    of waiting it is 503; then the parser's own wait (a render's reparse of a stored
    upload may hold it) may add as long again. Content stored before is answered at
    once; the data is hashed once."""
    sid, known = await run_in_threadpool(store.stored_upload, data, fmt)
    if known is not None:  # stored before: no parse, so no turn to wait for
        return known, False
    turns = request.app.state.upload_turns
    with anyio.move_on_after(settings.parse_timeout_s) as waited:
        await turns.acquire()
    if waited.cancelled_caught:
        raise no_turn(turns.total_tokens, settings.parse_timeout_s)
    try:
        return await run_in_threadpool(store.put_upload, data, fmt, display, sid)
    finally:
        turns.release()


@router.get("", response_model=SceneList, summary="List scenes")
async def list_scenes(store: StoreDep) -> SceneList:
    metas = await run_in_threadpool(store.list)
    return SceneList(scenes=[_info(m) for m in metas])


#: The Location header of a stored scene (OpenAPI).
LOCATION = {"Location": {"description": "the scene's URL, /scenes/{id}", "schema": {"type": "string"}}}


@router.post(
    "", response_model=SceneInfo, status_code=201, summary="Upload a scene file or register a built-in scene",
    responses={200: {"model": SceneInfo, "description": "already stored (same content ⇒ same id)",
                     "headers": LOCATION},
               201: {"description": "stored", "headers": LOCATION},
               **responses({400: "malformed body (not JSON, bad multipart)",
                            408: "the body stalled (DEPTHVIEW_BODY_TIMEOUT_S)",
                            413: "upload or JSON body too large", 415: "unsupported format or content type",
                            422: "malformed scene file, too many triangles, unknown built-in, parse over its "
                                 "time or memory limit",
                            500: "the store is corrupted",
                            503: "no process to parse the upload could start, or the uploads in progress hold "
                                 "DEPTHVIEW_MAX_PENDING_UPLOAD_BYTES"})},
    openapi_extra={"requestBody": {"required": True, "content": {
        "multipart/form-data": {"schema": {"type": "object", "required": ["file"], "properties": {
            "file": {"type": "string", "format": "binary", "description": "a .glb, .gltf, .obj or .ply file"},
            "format": {"type": "string", "enum": ["glb", "gltf", "obj", "ply"],
                       "description": "overrides the file name suffix"},
            "name": {"type": "string", "description": "display name (default: the file name stem)"}}}},
        "application/json": {"schema": {"$ref": "#/components/schemas/BuiltinSceneRequest"}},
        **{ctype: {"schema": {"type": "string", "format": "binary"}} for ctype in RAW_CONTENT_TYPES}},
        "description": "a scene file as multipart/form-data (field 'file'), a raw file body (its format from "
                       "its content type, else from ?format=), or JSON naming a built-in scene"}})
async def create_scene(request: Request, settings: SettingsDep, store: StoreDep, metrics: MetricsDep,
                       format: str | None = None, name: str | None = None) -> JSONResponse:
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if json_media_type(ctype):
        body = await _read_limited(request, settings.max_json_bytes, "JSON body")
        try:
            req = BuiltinSceneRequest.model_validate_json(body)
        except ValidationError as exc:
            errors = exc.errors(include_url=False)
            raise RequestValidationError([{**e, "loc": ("body", *e["loc"])} for e in errors]) from None
        meta, created = await run_in_threadpool(store.put_builtin, req.builtin, req.params.model_dump())
    else:
        raw = ctype != "multipart/form-data"
        if raw and ctype not in RAW_CONTENT_TYPES:
            raise HTTPException(415, f"unsupported content type {ctype[:60] or '(none)'!r}: send "
                                     "multipart/form-data with a 'file' field, a raw body with ?format=, or JSON "
                                     "{\"builtin\": ...}")
        implied = format or RAW_CONTENT_TYPES.get(ctype)
        if raw:
            if not implied:
                raise HTTPException(415, "a raw upload needs its format: add ?format=glb|gltf|obj|ply")
            _check_content_length(request, settings.max_upload_bytes, "upload")  # 413 before a 503 below
        with request.app.state.pending_uploads.hold(request, settings):
            if raw:
                data = await _read_limited(request, settings.max_upload_bytes, "upload")
                fmt, display = _format_from(implied, None), name or "upload"
            else:
                data, fmt, display = await _read_multipart(request, settings, format, name)
            meta, created = await _put_upload(request, settings, store, data, fmt, display)
        metrics.upload()
    return JSONResponse(jsonable_encoder(_info(meta)), status_code=201 if created else 200,
                        headers={"Location": f"/scenes/{meta.id}"})


@router.get("/{scene_id}", response_model=SceneInfo, summary="One scene's metadata",
            responses=responses({404: "unknown or malformed id"}))
async def get_scene(scene_id: str, store: StoreDep) -> SceneInfo:
    return _info(await run_in_threadpool(store.get_meta, scene_id))


@router.delete("/{scene_id}", status_code=204, summary="Delete a stored scene",
               responses=responses({404: "unknown or malformed id", 409: "built-in default scenes cannot be deleted"}))
async def delete_scene(scene_id: str, store: StoreDep, worker: WorkerDep) -> Response:
    await run_in_threadpool(store.delete, scene_id)
    worker.forget(scene_id)
    return Response(status_code=204)

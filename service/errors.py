"""Error answers of the service: one handler per kind of error, every body an
``ErrorResponse`` (``{"detail": "..."}``) or, for invalid fields, a
``ValidationErrorResponse``, and never more than a short excerpt of the input.

* store and loader errors (``StoreError``, ``SceneLoadError``): one handler mapping
  each to its status (404, 409, 415, 422, 500);
* request validation: malformed JSON is 400 on every endpoint, a body sent without a
  JSON content type 415; invalid fields 422 with their location, message and an
  excerpt of the offending value;
* 405 carries ``Allow`` listing every method the path answers (Starlette lists only
  the first route's when one path has several routes);
* anything unexpected is a 500 ``ErrorResponse`` too (not Starlette's plain text).
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Mapping, Sequence
from typing import Any

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match

from scenes.loaders import SceneLoadError
from service.excerpts import EXCERPT_CHARS, cut
from service.parsing import ParseUnavailable
from service.store import (
    InvalidBuiltin,
    InvalidSceneId,
    SceneNotFound,
    SceneProtected,
    StoreCorrupted,
    StoreError,
    TriangleLimitExceeded,
    UnsupportedFormat,
)

log = logging.getLogger("depthview.service")

#: Longest error message (a loader's or a library's message may quote its input).
DETAIL_CHARS = 500

#: Most invalid fields a 422 lists (a body of 100,000 unknown keys is answered with
#: these and their count, not 100,000 issues).
MAX_ISSUES = 20

#: Store/loader error → status (first match wins).
STORE_STATUS: tuple[tuple[type[Exception] | tuple[type[Exception], ...], int], ...] = (
    ((InvalidSceneId, SceneNotFound), 404),
    (SceneProtected, 409),
    (UnsupportedFormat, 415),
    ((TriangleLimitExceeded, InvalidBuiltin, SceneLoadError), 422),
    (StoreCorrupted, 500),
    (ParseUnavailable, 503),
)
#: Every error `store_error` answers (by STORE_STATUS).
STORE_ERRORS = (StoreError, SceneLoadError, ParseUnavailable)


def excerpt(value: Any, limit: int = EXCERPT_CHARS) -> Any:
    """`value` itself when its JSON form is short, else the start of that form and
    how long it was (so a 200 MiB body is never echoed back)."""
    try:
        text = json.dumps(jsonable_encoder(value), allow_nan=True, default=str)
    except (TypeError, ValueError):
        text = repr(value)
    if len(text) <= limit:
        return _json_safe(jsonable_encoder(value)) if not isinstance(value, (bytes, bytearray)) else text
    return cut(text, limit)


def _json_safe(obj: Any) -> Any:
    """Replace NaN/inf floats (JSON has none) by their names, recursively."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return str(obj)
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


json_safe = _json_safe


def short(detail: str) -> str:
    """`detail`, cut to DETAIL_CHARS."""
    return detail if len(detail) <= DETAIL_CHARS else f"{detail[:DETAIL_CHARS]}… (message cut)"


def store_status(exc: Exception) -> int:
    for types, status in STORE_STATUS:
        if isinstance(exc, types):
            return status
    return 500


async def store_error(request: Request, exc: Exception) -> JSONResponse:
    """The one handler of store and loader errors."""
    status = store_status(exc)
    if status >= 500:
        log.error("%s", exc)
    return JSONResponse({"detail": short(str(exc))}, status_code=status)


async def validation_error(request: Request, exc: Exception) -> JSONResponse:
    """400 for a body that is not JSON (every endpoint alike), 415 for a JSON body's
    endpoint sent another content type, else 422 with the invalid fields, each with an
    excerpt of its input."""
    assert isinstance(exc, RequestValidationError)
    errors = exc.errors()
    bad_json = [e for e in errors if e.get("type") == "json_invalid"]
    if bad_json:
        where = str((bad_json[0].get("ctx") or {}).get("error", ""))[:EXCERPT_CHARS]
        return JSONResponse({"detail": "request body is not valid JSON" + (f": {where}" if where else "")},
                            status_code=400)
    ctype = request.headers.get("content-type", "")
    if not json_media_type(ctype) and any(e.get("type") == "model_attributes_type" and tuple(e.get("loc", ())) ==
                                           ("body",) for e in errors):  # e.g. curl -d without -H
        return JSONResponse({"detail": "the request body is JSON: send Content-Type: application/json (got "
                                       + (repr(cut(ctype)) if ctype else "none") + ")"}, status_code=415)
    return JSONResponse({"detail": validation_details(errors)}, status_code=422)


def json_media_type(content_type: str) -> bool:
    """Whether FastAPI parses a body of this Content-Type as JSON: application/json or
    application/*+json (``text/json`` is not: such a body reaches validation as a string)."""
    media = content_type.split(";", 1)[0].strip().lower()
    return media == "application/json" or (media.startswith("application/") and media.endswith("+json"))


def validation_details(errors: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """pydantic's errors as ValidationIssue dicts (JSON-safe), each with an excerpt of
    its input and of each key of its location, the first MAX_ISSUES of them and then
    one ``too_many_errors`` issue counting the rest (the 422 body; the stream sends the
    same in its error messages)."""
    out = [{"loc": [loc_part(p) for p in e.get("loc", ())], "msg": str(e.get("msg", ""))[:300],
            "type": e.get("type", ""), "input": excerpt(e.get("input"))} for e in errors[:MAX_ISSUES]]
    if len(errors) > MAX_ISSUES:
        out.append({"loc": [], "msg": f"and {len(errors) - MAX_ISSUES:,} more invalid fields, not listed",
                    "type": "too_many_errors", "input": None})
    return _json_safe(jsonable_encoder(out))


def loc_part(part: Any) -> str | int:
    """One key of an error location: an index, or a field name cut to an excerpt
    (an unknown key is the client's own text, of any length)."""
    return part if isinstance(part, int) and not isinstance(part, bool) else cut(str(part))


async def http_error(request: Request, exc: Exception) -> JSONResponse:
    """HTTPException → ErrorResponse; a 405 lists every method of the path in Allow."""
    assert isinstance(exc, StarletteHTTPException)
    headers = dict(exc.headers or {})
    if exc.status_code == 405:
        headers["Allow"] = ", ".join(allowed_methods(request.app, request.scope))
    detail = short(exc.detail) if isinstance(exc.detail, str) else exc.detail
    return JSONResponse({"detail": detail}, status_code=exc.status_code, headers=headers or None)


async def internal_error(request: Request, exc: Exception) -> JSONResponse:
    """Anything unexpected: 500 as an ErrorResponse like every other error (the server
    logs the traceback: Starlette raises the exception on after this answer)."""
    return JSONResponse({"detail": f"internal error ({type(exc).__name__}); the service log has the details"},
                        status_code=500)


#: Methods a 405 may list in Allow.
HTTP_METHODS = ("DELETE", "GET", "HEAD", "OPTIONS", "PATCH", "POST", "PUT")


def allowed_methods(app: FastAPI, scope: dict) -> list[str]:
    """Every method some route of the app answers fully at this path (asked route by
    route, method by method, so it holds for included routers too); HEAD wherever GET
    (``RequestGuard`` answers HEAD as GET)."""
    methods = {m for m in HTTP_METHODS
               if any(route.matches({**scope, "method": m})[0] == Match.FULL for route in app.router.routes)}
    if "GET" in methods:
        methods.add("HEAD")
    return sorted(methods)


def install(app: FastAPI) -> None:
    """Register the handlers on `app`."""
    for error in STORE_ERRORS:
        app.add_exception_handler(error, store_error)
    app.add_exception_handler(RequestValidationError, validation_error)
    app.add_exception_handler(StarletteHTTPException, http_error)
    app.add_exception_handler(Exception, internal_error)


def responses(statuses: dict[int, str]) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses`` for the statuses a route documents: each with its
    description and schema — ErrorResponse, or for 422 ValidationErrorResponse or
    ErrorResponse (a limit, the budget or a job refusing its parameters); a 503 with
    its Retry-After header."""
    out: dict[int | str, dict[str, Any]] = {}
    for code, description in statuses.items():
        if code == 422:
            out[code] = {"description": description, "content": {"application/json": {"schema": {"anyOf": [
                {"$ref": "#/components/schemas/ValidationErrorResponse"},
                {"$ref": "#/components/schemas/ErrorResponse"}]}}}}
        else:
            out[code] = {"description": description, "content": {"application/json": {"schema": {
                "$ref": "#/components/schemas/ErrorResponse"}}}}
        if code == 503:
            out[code]["headers"] = {"Retry-After": {
                "description": "seconds to wait before retrying (DEPTHVIEW_RETRY_AFTER_S)",
                "schema": {"type": "integer"}}}
    return out

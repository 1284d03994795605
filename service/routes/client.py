"""``/client``: the thin-client page (thesis scenario: a host renders, a thin client
shows streamed frames and orbits a downloaded reconstruction locally).

* ``GET /client`` — the page; takes the bearer token as a header or ``?token=`` (the page
  passes it on to its API calls and to the stream);
* ``GET /client/static/{name}`` — its script and style sheet (``service/static``);
* ``GET /client/three/{path}`` — three.js from npm (``node_modules/three``: ``build/`` and
  ``examples/jsm/``, JavaScript only; ``npm ci`` installs it, ``make setup`` runs that;
  ``DEPTHVIEW_NODE_MODULES`` points elsewhere).

The script, style sheet and three.js hold no data and need no token (a module script's
imports cannot carry one)."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import FileResponse, HTMLResponse

from service.config import Settings
from service.deps import SettingsDep, presented_token, token_ok, unauthorized
from service.errors import responses

STATIC = Path(__file__).resolve().parents[1] / "static"
#: Parts of the three package the page may import.
THREE_DIRS = ("build", "examples/jsm")
MEDIA = {".js": "text/javascript", ".css": "text/css", ".html": "text/html"}

router = APIRouter(prefix="/client", tags=["client"])


def _is_file(path: Path) -> bool:
    """Whether `path` is a file; False for a name the file system refuses (too long:
    ``Path.is_file`` raises ENAMETOOLONG rather than answering False)."""
    try:
        return path.is_file()
    except (OSError, ValueError):
        return False


def not_installed(what: str, settings: Settings) -> HTTPException:
    """404 naming the npm package missing from the node_modules the service uses."""
    return HTTPException(404, f"{what} is not installed in {settings.node_modules}: run `npm ci` at the "
                              "repository root (make setup does) or set DEPTHVIEW_NODE_MODULES")


@router.get("", response_class=HTMLResponse, summary="The thin-client page",
            responses=responses({401: "missing or wrong bearer token (header or ?token=)"}))
async def page(request: Request) -> HTMLResponse:
    if not token_ok(request.app.state.settings, presented_token(request.headers, request.query_params)):
        raise unauthorized()
    return HTMLResponse((STATIC / "client.html").read_text(encoding="utf-8"),
                        headers={"Cache-Control": "no-cache"})


@router.get("/static/{name}", summary="The page's script and style sheet", include_in_schema=False)
async def static(name: str) -> FileResponse:
    path = STATIC / name
    if "/" in name or path.suffix not in (".js", ".css") or not _is_file(path):
        raise HTTPException(404, "no such client file")
    return FileResponse(path, media_type=MEDIA[path.suffix], headers={"Cache-Control": "no-cache"})


@router.get("/three/{path:path}", summary="three.js (npm package, build/ and examples/jsm/)",
            include_in_schema=False)
async def three(path: str, settings: SettingsDep) -> FileResponse:
    root = settings.node_modules / "three"
    if not root.is_dir():
        raise not_installed("three.js", settings)
    try:
        target = (root / path).resolve()
    except (OSError, ValueError):  # a NUL byte, a name too long: no such module
        raise HTTPException(404, "not a three.js module") from None
    allowed = [(root / d).resolve() for d in THREE_DIRS]
    if target.suffix != ".js" or not any(target.is_relative_to(a) for a in allowed) or not _is_file(target):
        raise HTTPException(404, "not a three.js module")
    return FileResponse(target, media_type="text/javascript", headers={"Cache-Control": "max-age=3600"})

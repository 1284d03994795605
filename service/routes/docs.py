"""``/docs``: Swagger UI for the OpenAPI document, served from this host.

FastAPI's own ``/docs`` loads Swagger UI from a CDN, so the page is blank on a machine
without internet access. Here the page's script and style sheet come from the npm
package ``swagger-ui-dist`` (``npm ci`` installs it beside three.js; ``make setup`` runs
that) under ``/docs/static/``. The docs need no token, like ``/openapi.json``."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Request
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse

from service.deps import SettingsDep
from service.routes.client import not_installed

#: The files of swagger-ui-dist the page loads, with their media types.
SWAGGER_FILES = {"swagger-ui-bundle.js": "text/javascript", "swagger-ui.css": "text/css",
                 "favicon-32x32.png": "image/png"}

router = APIRouter(tags=["docs"])


@router.get("/docs", include_in_schema=False)
async def docs(request: Request) -> HTMLResponse:
    return get_swagger_ui_html(openapi_url=request.app.openapi_url, title=f"{request.app.title} — API",
                               swagger_js_url="/docs/static/swagger-ui-bundle.js",
                               swagger_css_url="/docs/static/swagger-ui.css",
                               swagger_favicon_url="/docs/static/favicon-32x32.png")


@router.get("/docs/static/{name}", include_in_schema=False)
async def docs_static(name: str, settings: SettingsDep) -> FileResponse:
    path = settings.node_modules / "swagger-ui-dist" / name
    if name not in SWAGGER_FILES:
        raise HTTPException(404, "not a Swagger UI file")
    if not path.is_file():
        raise not_installed("Swagger UI", settings)
    return FileResponse(path, media_type=SWAGGER_FILES[name], headers={"Cache-Control": "max-age=3600"})

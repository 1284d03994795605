"""ASGI middleware of the service and the uvicorn protocol that times out headers.

``RequestGuard`` wraps every HTTP request:

* body size: a request whose ``Content-Length`` exceeds its limit is answered 413
  before its body is read; a body without one is counted while it streams in and cut
  off with 413 at the limit. The limit is ``max_json_bytes`` for every endpoint but a
  scene upload (``POST /scenes`` with a non-JSON body: ``max_upload_bytes`` plus the
  multipart allowance twice, a backstop: the route checks the file itself exactly);
* body read timeout: waiting more than ``body_timeout_s`` for the next chunk of a body
  answers 408 and closes the connection;
* HEAD: answered as GET (uvicorn sends the headers without the body), so every GET
  endpoint answers HEAD and a 405's ``Allow`` lists it;
* metrics: latency and status of every request by route template, whatever answered
  it (validation, limits, authentication included).

Header read timeout: uvicorn has none (a client that sends half a request line and
stalls holds the connection forever), so ``depthview serve`` runs uvicorn with
``header_timeout_protocol(seconds)``: an h11 protocol that closes a connection which has
not delivered a complete request head within ``header_timeout_s`` of connecting or of
its previous response.
"""

from __future__ import annotations

import asyncio
import json
import re
import time
from collections.abc import Callable
from typing import Any

import h11
from fastapi import HTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send
from uvicorn.protocols.http.h11_impl import H11Protocol

from service.config import Settings
from service.errors import json_media_type
from service.metrics import Metrics

#: Allowance for multipart boundaries and small form fields on top of max_upload_bytes.
MULTIPART_OVERHEAD = 64 * 1024


def body_limit(settings: Settings, scope: Scope) -> tuple[int, str]:
    """(byte limit, the limit in words) for the body of this request."""
    headers = dict(scope.get("headers") or [])
    ctype = headers.get(b"content-type", b"").decode("latin-1")
    if scope["method"] == "POST" and scope["path"].rstrip("/") == "/scenes" and not json_media_type(ctype):
        # a backstop above the route's own exact checks of the file
        return (settings.max_upload_bytes + 2 * MULTIPART_OVERHEAD,
                f"an upload's limit of {settings.max_upload_bytes} bytes (DEPTHVIEW_MAX_UPLOAD_BYTES) "
                f"plus {2 * MULTIPART_OVERHEAD} bytes of multipart overhead")
    return settings.max_json_bytes, f"the limit of {settings.max_json_bytes} bytes (DEPTHVIEW_MAX_JSON_BYTES)"


class RequestGuard:
    """Body size limit, body read timeout and request metrics (see the module doc)."""

    def __init__(self, app: ASGIApp, settings: Settings, metrics: Metrics,
                 templates: Callable[[], list[str]] = list) -> None:
        self.app, self.settings, self.metrics = app, settings, metrics
        self._templates = templates
        self._patterns: list[tuple[re.Pattern[str], str]] | None = None

    def route_label(self, scope: Scope, status: int) -> str:
        """The route template of a request for the metrics: the matched route's, else
        the template its path fits (a 405 matched no route), else the path of a
        successful answer (docs' static files), else "(unmatched)" — never an
        unbounded set of ids (a redirect, e.g. of a trailing slash, is "(unmatched)")."""
        route = getattr(scope.get("route"), "path", None)
        if route is not None:
            return route
        if self._patterns is None:
            self._patterns = [(re.compile("^" + re.sub(r"\\\{[^/]+?\\\}", "[^/]+", re.escape(t)) + "$"), t)
                              for t in self._templates()]
        for pattern, template in self._patterns:
            if pattern.match(scope["path"]):
                return template
        return scope["path"] if 200 <= status < 300 else "(unmatched)"

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        t0 = time.perf_counter()
        state: dict[str, Any] = {"status": 500, "close": False, "seen": 0, "done": False,
                                 "head": scope["method"] == "HEAD"}
        limit, limit_words = body_limit(self.settings, scope)

        async def send_wrapper(message: Message) -> None:
            if message["type"] == "http.response.start":
                state["status"] = message["status"]
                if state["close"]:  # the body was not read to its end: do not reuse the connection
                    message = {**message, "headers": [*message.get("headers", []), (b"connection", b"close")]}
            await send(message)

        async def receive_wrapper() -> Message:
            if state["done"]:
                return await receive()
            try:
                message = await asyncio.wait_for(receive(), self.settings.body_timeout_s)
            except asyncio.TimeoutError:
                state["close"] = True
                raise HTTPException(408, f"request body stalled: no data for {self.settings.body_timeout_s:g} s "
                                         "(DEPTHVIEW_BODY_TIMEOUT_S)") from None
            if message["type"] == "http.request":
                state["seen"] += len(message.get("body", b""))
                if state["seen"] > limit:
                    state["close"] = True
                    raise HTTPException(413, f"request body exceeds {limit_words}")
                state["done"] = not message.get("more_body", False)
            else:
                state["done"] = True
            return message

        try:
            refusal = self._content_length_refusal(scope, limit, limit_words)
            if refusal is not None:
                state["close"] = True
                await self._answer(send_wrapper, *refusal)
            else:
                if scope["method"] == "HEAD":
                    scope = {**scope, "method": "GET"}
                await self.app(scope, receive_wrapper, send_wrapper)
        finally:
            method = "HEAD" if state["head"] else scope["method"]
            self.metrics.request(method, self.route_label(scope, state["status"]), state["status"],
                                 time.perf_counter() - t0)

    @staticmethod
    def _content_length_refusal(scope: Scope, limit: int, limit_words: str) -> tuple[int, str] | None:
        for key, value in scope.get("headers") or []:
            if key == b"content-length":
                try:
                    n = int(value)
                except ValueError:
                    return 400, "invalid Content-Length header"
                if n > limit:
                    return 413, f"request body is {n} bytes, over {limit_words}"
        return None

    @staticmethod
    async def _answer(send: Send, status: int, detail: str) -> None:
        body = json.dumps({"detail": detail}, separators=(",", ":")).encode()  # as JSONResponse writes it
        await send({"type": "http.response.start", "status": status, "headers": [
            (b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]})
        await send({"type": "http.response.body", "body": body})


def header_timeout_protocol(seconds: float) -> type[H11Protocol]:
    """uvicorn's h11 protocol, closing a connection that has not delivered a complete
    request head within `seconds` of connecting or of its previous response."""

    class HeaderTimeoutH11Protocol(H11Protocol):
        _header_timer: asyncio.TimerHandle | None = None

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            super().connection_made(transport)
            self._arm_header_timer()

        def on_response_complete(self) -> None:
            super().on_response_complete()
            if not self.transport.is_closing():
                self._arm_header_timer()

        def connection_lost(self, exc: Exception | None) -> None:
            self._cancel_header_timer()
            super().connection_lost(exc)

        def _arm_header_timer(self) -> None:
            self._cancel_header_timer()
            self._header_timer = self.loop.call_later(seconds, self._header_timeout)

        def _cancel_header_timer(self) -> None:
            if self._header_timer is not None:
                self._header_timer.cancel()
                self._header_timer = None

        def _header_timeout(self) -> None:
            self._header_timer = None
            # IDLE: no complete request head since the timer was armed (a request in
            # progress has moved the client's side on; its body has its own timeout).
            if self.conn.their_state is h11.IDLE and not self.transport.is_closing():
                self.logger.info("closing a connection that sent no complete request head in %g s", seconds)
                self.transport.close()

    return HeaderTimeoutH11Protocol

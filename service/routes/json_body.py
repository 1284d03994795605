"""The route class of the JSON-body routes: every way ``json.loads`` can fail on a
body becomes a JSON decode error naming what is wrong and where, which FastAPI
answers as ``json_invalid`` and ``service.errors`` as 400 "request body is not valid
JSON: ..." (FastAPI's own handling turns anything but ``JSONDecodeError`` (invalid
UTF-8, nesting past Python's recursion limit) into a bare "There was an error
parsing the body")."""

from __future__ import annotations

import json
from collections.abc import Callable, Coroutine
from typing import Any

from fastapi import Request, Response
from fastapi.routing import APIRoute


class JSONBodyRequest(Request):
    """A request whose ``json()`` raises only ``json.JSONDecodeError``, its message
    naming the problem and its line and column (or byte offset)."""

    async def json(self) -> Any:
        if not hasattr(self, "_json"):
            body = await self.body()
            try:
                self._json = json.loads(body)
            except json.JSONDecodeError as exc:
                raise json.JSONDecodeError(f"{exc.msg} at line {exc.lineno} column {exc.colno}",
                                           exc.doc, exc.pos) from None
            except UnicodeDecodeError as exc:
                raise json.JSONDecodeError(f"invalid {exc.encoding.upper()} at byte offset {exc.start}",
                                           "", 0) from None
            except RecursionError:
                raise json.JSONDecodeError("nested too deeply", "", 0) from None
        return self._json


class JSONBodyRoute(APIRoute):
    """``APIRoute`` handing its endpoint a ``JSONBodyRequest``."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()

        async def route_handler(request: Request) -> Response:
            return await handler(JSONBodyRequest(request.scope, request.receive))

        return route_handler

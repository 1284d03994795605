"""The route class of the JSON-body routes: every way ``json.loads`` can fail on a
body becomes a JSON decode error naming what is wrong and where, which FastAPI
answers as ``json_invalid`` and ``service.errors`` as 400 "request body is not valid
JSON: ..." (FastAPI's own handling turns anything but ``JSONDecodeError`` (invalid
UTF-8, nesting past Python's recursion limit, an integer past Python's digit limit)
into a bare "There was an error parsing the body")."""

from __future__ import annotations

import json
import re
import sys
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
            except ValueError:  # an integer longer than sys.get_int_max_str_digits()
                raise json.JSONDecodeError(f"number out of range{_where_long_number(body)}", "", 0) from None
        return self._json


def _where_long_number(body: bytes) -> str:
    """" at line L column C" (1-based) of the first number value in `body` with more
    digits than Python converts, or "" where none is found."""
    digits = sys.get_int_max_str_digits()
    if digits == 0:
        return ""
    match = re.search(rb"[:\[,]\s*(-?\d{%d,})" % (digits + 1), body)
    if match is None:
        return ""
    pos, newline = match.start(1), b"\n"
    return f" at line {body.count(newline, 0, pos) + 1} column {pos - body.rfind(newline, 0, pos)}"


class JSONBodyRoute(APIRoute):
    """``APIRoute`` handing its endpoint a ``JSONBodyRequest``."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()

        async def route_handler(request: Request) -> Response:
            return await handler(JSONBodyRequest(request.scope, request.receive))

        return route_handler

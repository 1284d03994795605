"""``/scenes/{id}/stream``: the WebSocket frame stream (protocol in ``service.stream``).

The bearer token, when the service has one, comes as ``Authorization: Bearer`` or, since
a browser's WebSocket cannot set headers, as ``?token=``; without it the handshake is
refused (HTTP 403, close code 1008) before anything is rendered."""

from __future__ import annotations

from fastapi import APIRouter, WebSocket

from service.deps import Render, presented_token, token_ok
from service.stream import serve_stream

router = APIRouter(tags=["stream"])


@router.websocket("/scenes/{scene_id}/stream")
async def stream(ws: WebSocket, scene_id: str) -> None:
    state = ws.app.state
    if not token_ok(state.settings, presented_token(ws.headers, ws.query_params)):
        await ws.close(code=1008, reason="missing or wrong bearer token")
        return
    render = Render(state.settings, state.store, state.worker, state.metrics)
    await serve_stream(ws, render, scene_id, state.stream_slots, state.frame_source)

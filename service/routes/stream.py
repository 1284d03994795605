"""``/scenes/{id}/stream``: the WebSocket frame stream (protocol in ``service.stream``).

The bearer token, when the service has one, comes as ``Authorization: Bearer`` or, since
a browser's WebSocket cannot set headers, as ``?token=``; without it the handshake is
refused (HTTP 403, close code 1008) before anything is rendered. A plain HTTP GET of the
path is 426 Upgrade Required (``Upgrade: websocket``), not 404."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, WebSocket

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


@router.get("/scenes/{scene_id}/stream", include_in_schema=False)
async def stream_without_upgrade(scene_id: str) -> None:
    raise HTTPException(426, "the stream is a WebSocket: open ws://…/scenes/{id}/stream with an Upgrade: "
                             "websocket handshake (README, Streaming and the thin client)",
                        headers={"Upgrade": "websocket", "Connection": "Upgrade"})

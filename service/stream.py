"""The frame stream of ``/scenes/{id}/stream`` (a WebSocket; the route is
``service.routes.stream``).

Protocol. The client sends camera messages, JSON text (``StreamRequest``: the frames
endpoint's ``camera``, ``width``, ``height``, ``effects``, ``cull_back_faces`` and an
optional integer ``id``). The server sends, as JSON text:

* ``{"type": "hello", "scene", "bounds", "view", "limits"}`` once, after accepting: the
  scene's bounding box, a starting view that frames it, and the stream's limits;
* per frame ``{"type": "frame", "seq", "id", "format": "jpeg"|"png", "width", "height",
  "bytes", "render_ms", "encode_ms", "queue_wait_ms", "reused_ratio", "keyframe",
  "superseded", "rest"}`` immediately followed by the frame itself as one binary
  message (``id``: the camera message it answers; ``superseded``: camera messages
  replaced by later ones since the previous frame; ``rest``: the PNG re-send);
* ``{"type": "error", "status", "detail", "id"}`` for a bad message (not JSON, invalid
  fields, over a limit) or a frame that failed (503 queue full, 504, ...): the socket
  stays open (after a 503 a client may send its camera again after the hello's
  ``limits.retry_after_s``, as the thin client does).

Latest wins: a reader task validates messages as they arrive and keeps only the newest
one; the render loop takes it when the previous frame is sent, so messages that arrive
while a frame renders replace each other and the latency stays bounded by about two
frame times however fast the client sends. Frames are JPEG
(``stream_jpeg_quality``) while the camera moves; once no message came for
``stream_rest_s`` the latest view is sent again as PNG (lossless, re-encoded, not
re-rendered).

Each stream owns a ``FrameSource`` (made by ``app.state.frame_source(render,
scene_id)``, closed with the socket). The service's is ``ReuseFrameSource``: frames with
``reflections: "cluster"`` or ``"raytrace"`` go through one ``ReflectionReuser`` per stream
(thesis Ch. 5, issue 14; the cluster method of Ch. 4, or Embree's sparse rays over the
worker's cached BVH, traces the pixels it recomputes), whose stats give
``reused_ratio`` (reused / reflective pixels; 0 on keyframes) and ``keyframe``; every
other frame renders from scratch with the frames endpoint's jobs (``JobFrameSource``,
``service.frames.render``: a keyframe, 0 reused). Either way frames are jobs in the
worker's bounded queue; the reuser lives on the worker thread and is released there
(``RenderWorker.run_before_next_job``) when the socket closes.
"""

from __future__ import annotations

import asyncio
import json
import logging
import threading
import time
import uuid
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

import anyio
import numpy as np
from fastapi import HTTPException
from pydantic import ValidationError
from starlette.concurrency import run_in_threadpool
from starlette.websockets import WebSocket, WebSocketDisconnect

from gl_passes.cluster_tracer import ClusterTracer
from gl_passes.reprojection import ReflectionReuser, ReuseSettings
from reference.reflection_tracer import EmbreeTracer
from scenes.camera import Camera, camera_step, framing_distance, look_at_scene
from scenes.model import Scene
from service import errors, image_io
from service.budget import check_budget, frame_bytes, stream_reuser_bytes
from service.config import Settings
from service.deps import Render, check_size
from service.effects import CASTERS
from service.frames import render
from service.jobs import Job, SceneJob
from service.schemas import MAX_MESSAGE_ID, StreamRequest
from service.worker import GLState


@dataclass(frozen=True)
class JumpLimits:
    """How far a stream's camera may step between reflective frames before the next one
    is a keyframe (`camera_jump`): turn_deg, the turn of the view direction (degrees);
    move, the eye's displacement over its distance to the target; zoom, the factor on
    tan(fov/2), either way. A roll about the view direction does not count: near the
    vertical a look-at camera spins on smooth paths, and with a roll the reuse's error
    does not rise (its cost stays under a keyframe's for raytrace; cluster's reused frames
    cost about a keyframe at every step: bench/results/stream_jumps.md)."""

    turn_deg: float
    move: float
    zoom: float


#: JumpLimits per reused method, as bench/results/stream_jumps.md recommends them (its
#: reading says how; the limits let the benchmarked fly-throughs' steps through:
#: tests/test_service_stream.py). "raytrace": the largest tested steps at which Embree's
#: sparse reuse errs on the pixels it reuses no more than clearly above its error on the
#: paths and costs at most 0.8 of a keyframe. "cluster": the cluster tracer renders whole
#: frames, so its reused frame costs about a keyframe and a forced keyframe costs nothing
#: more: the smallest tested steps clear of the fly-throughs'.
JUMP_LIMITS: dict[str, JumpLimits] = {"raytrace": JumpLimits(turn_deg=30.0, move=0.15, zoom=1.5),
                                      "cluster": JumpLimits(turn_deg=15.0, move=0.15, zoom=1.05)}
#: Reflection methods whose stream frames go through the stream's ReflectionReuser.
REUSED_METHODS = tuple(JUMP_LIMITS)

log = logging.getLogger("depthview.stream")
T = TypeVar("T")

#: Close codes: too many streams or no parse process now (try again later); a stored
#: scene that does not load (the thin client does not reconnect); unknown scene.
CLOSE_TRY_LATER = 1013
CLOSE_SERVER_ERROR = 1011
CLOSE_NO_SCENE = 4404


def close_reason(detail: Any) -> str:
    """A close frame's reason: the error's detail within the protocol's 123 bytes (a
    browser's close event shows it; the error message before it has the whole detail)."""
    return str(detail).encode("utf-8")[:123].decode("utf-8", "ignore")


@dataclass(frozen=True)
class SourceFrame:
    """A rendered frame of a stream: linear colour (H,W,3) and how it was made
    (render_s: scene load, jobs and shading, not the queue_wait_s before its jobs ran)."""

    color: np.ndarray
    render_s: float
    queue_wait_s: float
    reused_ratio: float = 0.0
    keyframe: bool = True


class FrameSource(Protocol):
    """Renders a stream's frames; holds its per-stream state (issue 14: the
    ReflectionReuser) and frees it in ``close()``."""

    async def render(self, req: StreamRequest) -> SourceFrame: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class _Started:
    """A job that also returns when it started (time.monotonic: one clock for every
    process on the machine); picklable when the job is."""

    job: Any

    def __call__(self, state: Any) -> tuple[float, Any]:
        return time.monotonic(), self.job(state)


@dataclass
class _TimedRender(Render):
    """A Render that adds up how long its jobs waited in the worker's queue."""

    queue_wait_s: float = 0.0

    async def job(self, job: Job[T], label: str, pin: str | None = None) -> T:
        submitted, started = time.monotonic(), None
        try:
            started, result = await super().job(_Started(job), label, pin)
            return result
        finally:
            self.queue_wait_s += (started if started is not None else time.monotonic()) - submitted

    def render_s(self, t0: float) -> float:
        """Seconds since ``time.perf_counter()`` was `t0`, less the queue waits (the
        frame's ``render_ms``; its ``queue_wait_ms`` counts those)."""
        return max(0.0, time.perf_counter() - t0 - self.queue_wait_s)


class JobFrameSource:
    """Every frame rendered from scratch as ``POST /frames`` renders it (no reuse yet:
    reused_ratio 0, every frame a keyframe)."""

    def __init__(self, r: Render, scene_id: str) -> None:
        self.r, self.scene_id = r, scene_id

    async def render(self, req: StreamRequest) -> SourceFrame:
        timed = _TimedRender(self.r.settings, self.r.store, self.r.worker, self.r.metrics)
        t0 = time.perf_counter()
        rendered = await render(timed, self.scene_id, req)
        return SourceFrame(np.asarray(rendered.color, np.float32), timed.render_s(t0), timed.queue_wait_s)

    def close(self) -> None:
        pass


class _CachedEmbreeTracer(EmbreeTracer):
    """The Embree tracer over the worker's cached BVH of the scene (service.effects.CASTERS),
    holding the caster's lock while it traces."""

    def __init__(self, scene_key: str, scene: Scene, glossy_rays: int) -> None:
        caster, self._lock, _, _ = CASTERS.get(scene_key, scene)
        super().__init__(scene, glossy_rays, caster=caster)

    def trace(self, camera: Camera, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        with self._lock:
            return super().trace(camera, pixels)


def camera_jump(prev: Camera | None, cam: Camera, limits: JumpLimits) -> bool:
    """Whether `cam` jumped from `prev` (None: no reused frame before) past `limits`
    (JUMP_LIMITS of the stream's method): beyond the thesis, whose keyframe policy
    (§5.4.4) looks only at the share of pixels recomputed, so a jump was answered from
    the old keyframe, smeared, before the policy reacted."""
    if prev is None:
        return True
    step = camera_step(prev, cam)
    return bool(step.turn_deg > limits.turn_deg or step.move > limits.move
                or not 1 / limits.zoom <= step.zoom <= limits.zoom)


class _Reuse:
    """A stream's ReflectionReuser and its tracer (the cluster method for reflections
    "cluster", Embree's sparse rays for "raytrace"); touched only on the worker thread
    (in ``GLState.clients`` under the stream's key, on the worker the stream is pinned to)."""

    def __init__(self) -> None:
        self.reuser: ReflectionReuser | None = None
        self.tracer: ClusterTracer | _CachedEmbreeTracer | None = None
        self.key: tuple[Any, ...] | None = None
        self.nbytes = 0  # estimated bytes of the reuser at the stream's latest frame size

    def get(self, state: GLState, scene_key: str, scene: Scene, method: str, glossy_rays: int,
            mode: str = "reuse") -> ReflectionReuser:
        gpu = state.scene_gpu(scene_key, scene)
        key = (id(gpu), method, glossy_rays, mode)  # a new upload (the GPU cache evicted the old one), method, ...
        if self.reuser is None or key != self.key:
            self.release(state)
            self.tracer = (ClusterTracer(state.gl, gpu, glossy_rays=glossy_rays)  # the service's ClusterSettings
                           if method == "cluster" else _CachedEmbreeTracer(scene_key, scene, glossy_rays))
            self.reuser = ReflectionReuser(state.gl, gpu, self.tracer,
                                           ReuseSettings(mode=mode, sync_timings=False, search_stats=False))
            self.key = key
        return self.reuser

    def release(self, state: GLState | None = None) -> None:
        for obj in (self.reuser, self.tracer):
            if obj is not None:
                obj.release()
        self.reuser = self.tracer = self.key = None


@dataclass(frozen=True)
class StreamReflectionJob(SceneJob):
    """The next reflective frame (`method` "cluster" or "raytrace") of stream `stream`
    through its ReflectionReuser (created on first use in the worker's ``GLState.clients``)."""

    scene_key: str
    scene: Scene | None
    camera: Camera
    method: str
    glossy_rays: int
    stream: str
    #: ReuseSettings.mode: "reuse", or the baselines "full" and "direct" (stream_reflection_mode).
    mode: str = "reuse"
    #: Start a keyframe whatever the policy says (the camera jumped, or frames without
    #: reuse came between: the keyframe no longer fits).
    keyframe: bool = False
    #: Estimated bytes of this stream's reuser (`budget.stream_reuser_bytes`) and the
    #: most the worker's reusers may hold together (Settings.stream_reuse_bytes; None: no limit).
    reuse_bytes: int = 0
    reuse_budget: int | None = None

    def __call__(self, state: GLState) -> Any:
        reuse = state.clients.pop(self.stream, None) or _Reuse()
        state.clients[self.stream] = reuse  # the most recently used last
        reuse.nbytes = self.reuse_bytes
        if self.reuse_budget is not None:
            evict_reusers(state, self.reuse_budget)
        reuser = reuse.get(state, self.scene_key, self.load(state), self.method, self.glossy_rays, self.mode)
        return reuser.next_frame(self.camera, keyframe=self.keyframe)


def evict_reusers(state: GLState, budget: int) -> list[str]:
    """Release the least recently used streams' reusers on this worker until the
    estimated bytes of those held, the latest stream's included (it is kept), fit
    `budget`; an evicted stream's next frame makes a new reuser, a keyframe. Returns
    the evicted streams' keys."""
    held = [(key, c) for key, c in state.clients.items() if isinstance(c, _Reuse)]
    total = sum(c.nbytes for _, c in held[:-1] if c.reuser is not None) + (held[-1][1].nbytes if held else 0)
    evicted = []
    for key, c in held[:-1]:
        if total <= budget:
            break
        if c.reuser is not None:
            total -= c.nbytes
            c.release(state)
            evicted.append(key)
    if evicted:
        log.info("released the reflection reusers of %d stream(s) to keep them within %d bytes "
                 "(STREAM_REUSE_BYTES); their next frames are keyframes", len(evicted), budget)
        state.freed()
    return evicted


@dataclass(frozen=True)
class ReleaseStream:
    """Chore: release stream `stream`'s ReflectionReuser on its worker."""

    stream: str

    def __call__(self, state: GLState) -> None:
        reuse = state.clients.pop(self.stream, None)
        if reuse is not None:
            reuse.release(state)
            state.freed()


class ReuseFrameSource(JobFrameSource):
    """The stream's frame source: frames with ``reflections: "cluster"`` go through one
    ``ReflectionReuser`` per stream (thesis Ch. 5, Alg. 8), and so do frames with
    ``reflections: "raytrace"``; the tracer for the recomputed pixels is the cluster
    method (Ch. 4) or Embree's sparse rays over the worker's cached BVH, at one sample
    per pixel (the frames endpoint supersamples 2×2); its stats give the reused-pixel ratio (reused / reflective
    pixels, 0 on keyframes) and the keyframe flag. Every other frame renders as
    ``JobFrameSource`` renders it. The reuser lives on one worker (its jobs are pinned to
    it: the stream's key) and ``close()`` frees it there; a worker process that dies
    takes it along (the next frame is a keyframe on its replacement). The setting
    ``stream_reflection_mode`` swaps the reuse for a baseline: ``full`` traces every
    reflective pixel of every frame with the same tracer (every frame a keyframe)."""

    def __init__(self, r: Render, scene_id: str) -> None:
        super().__init__(r, scene_id)
        self._key = f"stream-{uuid.uuid4().hex}"
        self._used = False
        self._last: Camera | None = None  # the camera of the last reflective frame, None after other frames

    async def render(self, req: StreamRequest) -> SourceFrame:
        if req.effects.reflections not in REUSED_METHODS:
            self._last = None  # the views in between left the keyframe behind
            return await super().render(req)
        timed = _TimedRender(self.r.settings, self.r.store, self.r.worker, self.r.metrics)
        t0 = time.perf_counter()
        scene = await timed.scene(self.scene_id)
        camera = req.to_camera().fit_clip(scene.bounds)
        self._used = True
        settings = self.r.settings
        method = req.effects.reflections
        job = StreamReflectionJob(self.scene_id, scene, camera, method, req.effects.glossy_rays, self._key,
                                  settings.stream_reflection_mode,
                                  camera_jump(self._last, camera, JUMP_LIMITS[method]),
                                  stream_reuser_bytes(method, camera.width, camera.height),
                                  settings.stream_reuse_bytes)
        self._last = None  # until this frame is answered: a failed one leaves no keyframe to trust
        frame = await timed.job(job, f"stream frame {self.scene_id[:12]}", pin=self._key)
        self._last = camera
        st = frame.stats
        ratio = 0.0 if st.keyframe or not st.reflective else 1.0 - st.recomputed_fraction
        return SourceFrame(np.asarray(frame.color, np.float32), timed.render_s(t0), timed.queue_wait_s,
                           float(ratio), bool(st.keyframe))

    def close(self) -> None:
        if self._used:
            self.r.worker.run_before_next_job(ReleaseStream(self._key), pin=self._key)


SourceFactory = Callable[[Render, str], FrameSource]


class StreamSlots:
    """Open streams per client address and in total, against the settings' limits."""

    def __init__(self, settings: Settings) -> None:
        self.per_client, self.total = settings.stream_max_per_client, settings.stream_max_total
        self._open: dict[str, int] = {}
        self._lock = threading.Lock()

    def acquire(self, client: str) -> str | None:
        """Take a slot for `client`; None when granted, else why not."""
        with self._lock:
            if sum(self._open.values()) >= self.total:
                return f"too many streams open ({self.total} in total, DEPTHVIEW_STREAM_MAX_TOTAL)"
            if self._open.get(client, 0) >= self.per_client:
                return f"too many streams from this client ({self.per_client}, DEPTHVIEW_STREAM_MAX_PER_CLIENT)"
            self._open[client] = self._open.get(client, 0) + 1
            return None

    def release(self, client: str) -> None:
        with self._lock:
            n = self._open.get(client, 0) - 1
            if n > 0:
                self._open[client] = n
            else:
                self._open.pop(client, None)

    @property
    def open(self) -> int:
        with self._lock:
            return sum(self._open.values())


class BadMessage(Exception):
    def __init__(self, status: int, detail: Any, msg_id: int | None = None) -> None:
        super().__init__(str(detail))
        self.status, self.detail, self.msg_id = status, detail, msg_id


def parse_message(settings: Settings, text: str | None) -> StreamRequest:
    """A camera message, validated and checked against the limits (BadMessage otherwise)."""
    if text is None:
        raise BadMessage(400, "send camera messages as JSON text, not binary")
    size = len(text.encode("utf-8", "replace"))
    if size > settings.stream_max_message_bytes:
        raise BadMessage(413, f"message is {size} bytes, over the limit of {settings.stream_max_message_bytes} "
                              "(DEPTHVIEW_STREAM_MAX_MESSAGE_BYTES)")
    try:
        req = StreamRequest.model_validate_json(text)
    except ValidationError as exc:
        issues = exc.errors(include_url=False)
        if any(e.get("type") == "json_invalid" for e in issues):
            raise BadMessage(400, "message is not valid JSON") from None
        raise BadMessage(422, errors.validation_details(issues), _message_id(text)) from None
    try:
        check_size(settings, req.width, req.height, "stream frame")
        if req.width * req.height > settings.stream_max_pixels:
            raise HTTPException(422, f"stream frame width × height {req.width * req.height} exceeds the limit "
                                     f"{settings.stream_max_pixels} (DEPTHVIEW_STREAM_MAX_PIXELS)")
        check_budget(settings, frame_bytes(req))
    except HTTPException as exc:
        raise BadMessage(exc.status_code, exc.detail, req.id) from None
    return req


def _message_id(text: str) -> int | None:
    try:
        value = json.loads(text).get("id")
    except (ValueError, AttributeError):
        return None
    # only an id the schema accepts is echoed (one of thousands of digits is input to excerpt, not repeat)
    return value if isinstance(value, int) and not isinstance(value, bool) and 0 <= value < MAX_MESSAGE_ID else None


#: The hello view: direction and vertical field of view (degrees), and its distance
#: beyond the one at which the scene's box just fits (`framing_distance`).
HELLO_AZIMUTH, HELLO_ELEVATION, HELLO_FOV = 20.0, 15.0, 50.0
HELLO_MARGIN = 1.05


def hello(scene_id: str, bounds: Any, settings: Settings) -> dict[str, Any]:
    lo, hi = (np.asarray(b, np.float64) for b in bounds)
    distance = HELLO_MARGIN * framing_distance((lo, hi), HELLO_AZIMUTH, HELLO_ELEVATION, HELLO_FOV)
    cam = look_at_scene((lo, hi), HELLO_AZIMUTH, HELLO_ELEVATION, distance, HELLO_FOV)
    return {"type": "hello", "scene": scene_id, "bounds": [lo.tolist(), hi.tolist()],
            "view": {"eye": list(cam.eye), "target": list(cam.target), "up": [0.0, 1.0, 0.0], "fov": HELLO_FOV},
            "limits": {"max_pixels": settings.stream_max_pixels, "max_width": settings.max_width,
                       "max_height": settings.max_height, "max_message_bytes": settings.stream_max_message_bytes,
                       "jpeg_quality": settings.stream_jpeg_quality, "rest_s": settings.stream_rest_s,
                       "retry_after_s": settings.retry_after_s}}


class StreamSession:
    """One open stream: the reader keeps the latest camera message, the render loop
    renders it and sends the frame (see the module doc)."""

    def __init__(self, ws: WebSocket, r: Render, source: FrameSource) -> None:
        self.ws, self.r, self.source = ws, r, source
        self.settings = r.settings
        self._send_lock = asyncio.Lock()
        self._latest: StreamRequest | None = None
        self._superseded = 0
        self._wake = asyncio.Event()
        self.seq = 0

    async def send_json(self, obj: dict[str, Any]) -> None:
        async with self._send_lock:
            await self.ws.send_text(json.dumps(obj))

    async def error(self, status: int, detail: Any, msg_id: int | None = None) -> None:
        detail = errors.short(detail) if isinstance(detail, str) else detail
        await self.send_json({"type": "error", "status": status, "detail": detail, "id": msg_id})

    async def run(self) -> None:
        """Read and render until the socket closes (either task ending ends both)."""
        async with anyio.create_task_group() as tg:

            async def until_closed(loop: Callable[[], Awaitable[None]]) -> None:
                try:
                    await loop()
                except (WebSocketDisconnect, OSError):  # the client went away
                    pass
                except Exception:  # noqa: BLE001 - ends this stream only
                    log.exception("stream task failed")
                finally:
                    tg.cancel_scope.cancel()

            tg.start_soon(until_closed, self._read)
            tg.start_soon(until_closed, self._render_loop)

    async def _read(self) -> None:
        while True:
            msg = await self.ws.receive()
            if msg["type"] == "websocket.disconnect":
                return
            try:
                req = parse_message(self.settings, msg.get("text"))
            except BadMessage as exc:
                await self.error(exc.status, exc.detail, exc.msg_id)
                continue
            if self._latest is not None:
                self._superseded += 1
            self._latest = req
            self._wake.set()

    async def _render_loop(self) -> None:
        last: tuple[SourceFrame, StreamRequest] | None = None
        while True:
            with anyio.move_on_after(None if last is None else self.settings.stream_rest_s) as waited:
                await self._wake.wait()
            if waited.cancelled_caught:  # the camera rested: the same view, lossless
                assert last is not None
                f, req = last  # re-sent: no render, the reuse stats of the frame it repeats
                await self._send(SourceFrame(f.color, 0.0, 0.0, f.reused_ratio, f.keyframe), req, "png",
                                 superseded=0, rest=True)
                last = None
                continue
            self._wake.clear()
            req, superseded = self._latest, self._superseded
            self._latest, self._superseded = None, 0
            assert req is not None
            try:
                frame = await self.source.render(req)
            except Exception as exc:  # noqa: BLE001 - reported on the socket, the stream goes on
                if isinstance(exc, HTTPException):
                    status, detail = exc.status_code, exc.detail
                else:
                    status, detail = errors.store_status(exc), f"{type(exc).__name__}: {str(exc)[:300]}"
                    if status >= 500:
                        log.exception("stream frame failed", exc_info=exc)
                await self.error(status, detail, req.id)
                if status == 404:  # the scene was deleted while streaming: as for an unknown one, final
                    await self.ws.close(CLOSE_NO_SCENE, close_reason(detail))
                    return
                continue
            await self._send(frame, req, "jpeg", superseded=superseded, rest=False)
            last = (frame, req)

    async def _send(self, frame: SourceFrame, req: StreamRequest, fmt: str, superseded: int, rest: bool) -> None:
        t0 = time.perf_counter()
        with self.r.metrics.step("encode"):
            if fmt == "jpeg":
                body = await run_in_threadpool(image_io.encode_jpeg, frame.color,
                                               quality=self.settings.stream_jpeg_quality)
            else:
                body = await run_in_threadpool(image_io.encode_png, frame.color, compress_level=1)
        encode_s = time.perf_counter() - t0
        self.seq += 1
        h, w = frame.color.shape[:2]
        stats = {"type": "frame", "seq": self.seq, "id": req.id, "format": fmt, "width": w, "height": h,
                 "bytes": len(body), "render_ms": round(frame.render_s * 1e3, 2),
                 "encode_ms": round(encode_s * 1e3, 2), "queue_wait_ms": round(frame.queue_wait_s * 1e3, 2),
                 "reused_ratio": frame.reused_ratio, "keyframe": frame.keyframe, "superseded": superseded,
                 "rest": rest}
        async with self._send_lock:
            await self.ws.send_text(json.dumps(stats))
            await self.ws.send_bytes(body)
        self.r.metrics.streamed()


async def _refuse(ws: WebSocket, status: int, detail: str, code: int) -> None:
    """End a stream before its hello: the error message, then the close `code` with the
    detail as its reason."""
    await ws.send_text(json.dumps({"type": "error", "status": status, "detail": detail, "id": None}))
    await ws.close(code, close_reason(detail))


async def serve_stream(ws: WebSocket, r: Render, scene_id: str, slots: StreamSlots, factory: SourceFactory) -> None:
    """Accept `ws` (the caller checked the token), enforce the stream limits, send the
    hello and run the session; the frame source is closed when the socket closes."""
    client = ws.client.host if ws.client is not None else "unknown"
    await ws.accept()
    refusal = slots.acquire(client)
    if refusal is not None:
        await _refuse(ws, 429, refusal, CLOSE_TRY_LATER)
        return
    source: FrameSource | None = None
    try:
        try:
            scene = await r.scene(scene_id)
        except Exception as exc:  # noqa: BLE001 - the store's errors (unknown id, malformed file)
            status = errors.store_status(exc)
            # 404: final; 503 (no parse process now): try again; else the stored scene does not load
            await _refuse(ws, status, errors.short(str(exc)),
                          {404: CLOSE_NO_SCENE, 503: CLOSE_TRY_LATER}.get(status, CLOSE_SERVER_ERROR))
            return
        await ws.send_text(json.dumps(hello(scene_id, scene.bounds, r.settings)))
        source = factory(r, scene_id)
        await StreamSession(ws, r, source).run()
    except WebSocketDisconnect:
        pass
    finally:
        if source is not None:
            source.close()
        slots.release(client)

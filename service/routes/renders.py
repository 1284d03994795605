"""The render resources of a scene: frames (G-buffer, reflections, soft shadows),
reconstructions (GLB) and depth-image sets. Each request is checked against the
size limits and the memory budget before its scene is loaded; GL and Embree work runs
as jobs (``service.jobs``) on the worker, encoding in the thread pool."""

from __future__ import annotations

import base64
import time

from fastapi import APIRouter, Depends, HTTPException, Response
from fastapi.responses import JSONResponse

from gl_passes.reconstruction import glb_bytes
from scenes.lights import reference_cameras
from scenes.model import AreaLight
from scenes.rig import peeling_camera
from service.budget import check_budget, frame_bytes, reconstruction_bytes, set_bytes
from service.deps import RenderDep, check_size, require_token
from service.depth_sets import encode_set, plan_set
from service.effects import server_timing
from service.errors import STORE_ERRORS, json_safe, responses, store_status
from service.frames import render
from service.jobs import ReconstructionJob, SetJob
from service.routes.json_body import JSONBodyRoute
from service.schemas import FRAME_EXR_CHANNELS, DepthImagesRequest, FrameRequest, ReconstructionRequest
from service.soft_shadows import resolve_light

MEDIA_TYPES = {"png": "image/png", "exr": "image/x-exr"}
SET_MEDIA_TYPES = {"exr": "image/x-exr", "npz": "application/x-npz"}
#: Statuses every render route documents.
RENDER_ERRORS = {400: "the body is not JSON", 401: "missing or wrong bearer token", 404: "unknown scene",
                 408: "the body stalled (DEPTHVIEW_BODY_TIMEOUT_S)", 413: "body over DEPTHVIEW_MAX_JSON_BYTES",
                 415: "the body was sent without a JSON Content-Type",
                 503: "render queue full or no GL context (Retry-After)", 504: "the job timed out",
                 500: "the job failed unexpectedly"}

frames = APIRouter(prefix="/scenes/{scene_id}", tags=["frames"], dependencies=[Depends(require_token)],
                  route_class=JSONBodyRoute)
reconstructions = APIRouter(prefix="/scenes/{scene_id}", tags=["reconstruction"],
                            dependencies=[Depends(require_token)], route_class=JSONBodyRoute)
depth_images = APIRouter(prefix="/scenes/{scene_id}", tags=["depth images"], dependencies=[Depends(require_token)],
                         route_class=JSONBodyRoute)


# --- frames ----------------------------------------------------------------------------
#: The headers of every render response (OpenAPI).
RENDER_HEADERS = {"X-Render-Seconds": {"description": "seconds in the service from the request's arrival to the "
                                                      "encoded body", "schema": {"type": "string"}}}
#: A frame's steps, on reflective and soft-shadow frames (OpenAPI).
SERVER_TIMING = {"Server-Timing": {"description": "each step's milliseconds (reflective and soft-shadow frames), "
                                                  "cached steps with desc=\"cache hit\" or \"cache miss\"",
                                   "schema": {"type": "string"}}}


@frames.post(
    "/frames", summary="Render a frame", response_class=Response,
    responses={200: {"content": {"image/png": {}, "image/x-exr": {}},
                     "description": f"PNG (sRGB colour) or EXR (linear {FRAME_EXR_CHANNELS})",
                     "headers": {**RENDER_HEADERS, **SERVER_TIMING}},
               **responses({**RENDER_ERRORS, 422: "invalid camera, effects or size, or over the memory budget"})})
async def render_frame(scene_id: str, req: FrameRequest, r: RenderDep) -> Response:
    t0 = time.perf_counter()
    timing: dict[str, str] = {}
    try:
        check_size(r.settings, req.width, req.height)
        check_budget(r.settings, frame_bytes(req))
        rendered = await render(r, scene_id, req)
        t1 = time.perf_counter()
        body = await r.encode(rendered.encode, req.format)
        if rendered.steps_ms:  # reflective and soft-shadow frames name each step (and their cache hits)
            steps = {**rendered.steps_ms, "encode": (time.perf_counter() - t1) * 1e3}
            timing["Server-Timing"] = server_timing(steps, rendered.cache_hits)
    except HTTPException as exc:
        r.metrics.frame_error(exc.status_code)
        raise
    except STORE_ERRORS as exc:  # answered by errors.store_error
        r.metrics.frame_error(store_status(exc))
        raise
    r.metrics.frame(req.format)
    return Response(body, media_type=MEDIA_TYPES[req.format], headers={
        **render_seconds(t0), "Content-Disposition": f'inline; filename="frame.{req.format}"', **timing})


def render_seconds(t0: float) -> dict[str, str]:
    """The X-Render-Seconds header of every render response: seconds since `t0`
    (the request's arrival in the route) to the encoded body."""
    return {"X-Render-Seconds": f"{time.perf_counter() - t0:.4f}"}


# --- reconstructions (thesis Ch. 3) -------------------------------------------------------
@reconstructions.post(
    "/reconstruction", summary="Reconstruct a depth-image set (GLB)", response_class=Response,
    responses={200: {"content": {"model/gltf-binary": {}},
                     "description": "binary glTF, one node per source image that holds samples: vertex colours "
                                    "under an unlit, two-sided, non-metal material; node extras: method, layer "
                                    "(peeling), camera", "headers": RENDER_HEADERS},
               **responses({**RENDER_ERRORS, 422: "invalid cameras, light or size, or over the memory budget"})})
async def reconstruct(scene_id: str, req: ReconstructionRequest, r: RenderDep) -> Response:
    t0 = time.perf_counter()
    check_budget(r.settings, reconstruction_bytes(req))
    scene = await r.scene(scene_id)
    cams = req.to_cameras()
    try:
        if cams is None:
            spec = req.light
            light = resolve_light(scene, None if spec is None else AreaLight(spec.center, spec.u, spec.v))
            cams = reference_cameras(light, scene.bounds, req.method, req.resolution)
        elif req.method == "peeling":
            cams = [peeling_camera(cams).fit_clip(scene.bounds)]
        else:
            cams = [c.fit_clip(scene.bounds) for c in cams]
    except ValueError as exc:
        raise HTTPException(422, f"reconstruction viewpoints: {exc}") from None
    job = ReconstructionJob(scene_id, scene, cams, req.method, req.reconstruction, req.layers, req.sides)
    parts = await r.job(job, f"reconstruction {scene_id[:12]}")
    names = [f"{req.method}_{k}" for k in range(len(parts))]
    extras = [{"method": req.method, **({"layer": k} if req.method == "peeling" else {}),
               "camera": cams[min(k, len(cams) - 1)].describe()} for k in range(len(parts))]
    body = await r.encode(glb_bytes, parts, names, extras)
    return Response(body, media_type="model/gltf-binary",
                    headers={"Content-Disposition": 'attachment; filename="reconstruction.glb"', **render_seconds(t0)})


# --- depth-image sets (thesis Ch. 2) ---------------------------------------------------------
@depth_images.post(
    "/depth-images", summary="Render a depth-image set", response_class=Response,
    responses={200: {"content": {"image/x-exr": {}, "application/x-npz": {}, "application/json": {"schema": {
                         "type": "object", "required": ["metrics", "media_type", "images_b64"], "properties": {
                             "metrics": {"type": "object", "description": "the four sampling metrics (§2.3.2)"},
                             "media_type": {"type": "string", "description": "of the encoded set"},
                             "images_b64": {"type": "string", "contentEncoding": "base64",
                                            "description": "the set, as the EXR or npz response's body"}}}}},
                     "description": "multi-part EXR (one part per image) or npz; with metrics=true JSON "
                                    "{metrics, media_type, images_b64}", "headers": RENDER_HEADERS},
               **responses({**RENDER_ERRORS, 422: "invalid cameras or size, or over the memory budget"})})
async def render_depth_images(scene_id: str, req: DepthImagesRequest, r: RenderDep) -> Response:
    t0 = time.perf_counter()
    check_size(r.settings, req.width, req.height, "depth image")
    check_budget(r.settings, set_bytes(req))
    scene = await r.scene(scene_id)
    try:
        plan = plan_set(scene, req.method, req.redundancy, req.to_cameras(), req.width, req.height, req.layers)
    except ValueError as exc:  # CameraError: e.g. a scene too small for the rig's cameras
        raise HTTPException(422, f"depth-image viewpoints: {exc}") from None
    job = SetJob(scene_id, scene, plan, req.intermediate_views if req.metrics else None, req.seed)
    images, metrics = await r.job(job, f"depth images {scene_id[:12]}")
    body = await r.encode(encode_set, images, req.format)
    media = SET_MEDIA_TYPES[req.format]
    seconds = render_seconds(t0)
    if metrics is None:
        return Response(body, media_type=media, headers={
            **seconds, "Content-Disposition": f'attachment; filename="depth_images.{req.format}"'})
    return JSONResponse({"metrics": json_safe(metrics), "media_type": media,
                         "images_b64": base64.b64encode(body).decode("ascii")}, headers=seconds)

"""Frames for users' test suites (the pytest plugin's fixtures, service.pytest_plugin).

`GLThread` is one headless GL context on its own thread — the service's
RenderWorker, so frames are rendered exactly as `POST /scenes/{id}/frames` renders
them; `render_frame` renders a frame with it and `reference_frame` computes the
Embree reference of the same frame on the calling thread (never on the GL thread).

Arguments, as the service takes them:

* scene: a `scenes.Scene`, a path to a model file (GLB/glTF/OBJ/PLY; loaded once
  per file version) or the name of a built-in scene;
* camera: a `scenes.Camera` (its width × height is the frame size) or a mapping of
  Camera's fields; near/far are fitted to the scene bounds when missing;
* effects: None or the service's `effects` object, e.g. {"reflections": "cluster",
  "glossy_rays": 8} (service.schemas.Effects validates it).

Without effects a frame is the G-buffer (`scenes.buffers.FrameBuffers`: colour
(H,W,3) float32 linear, depth (H,W) float32 eye-space z, +inf background, normal,
position, tri_id, obj_id, specular, glossiness); with reflections it is
`scenes.buffers.ReflectionBuffers` (colour (H,W,3) linear: the final image).
"""

from __future__ import annotations

import hashlib
import os
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from scenes.buffers import FrameBuffers, ReflectionBuffers
from scenes.builtin import BUILTIN_NAMES, make_builtin
from scenes.camera import Camera
from scenes.loaders import load_scene
from scenes.model import Scene
from service.effects import raytrace
from service.jobs import FrameJob, ReflectionJob
from service.schemas import Effects
from service.worker import GLState, RenderWorker

T = TypeVar("T")
SceneArg = Scene | str | os.PathLike
CameraArg = Camera | Mapping[str, Any]
Frame = FrameBuffers | ReflectionBuffers


class GLThread:
    """One headless GL context (EGL, OSMesa fallback; DEPTHVIEW_GL picks) owned by
    its own thread, as the service's render worker owns its context. `run(fn)`
    calls fn(state) on that thread (state: service.worker.GLState) and returns
    its result; GL objects never leave the thread. `close()` releases everything."""

    def __init__(self, backend: str | None = None, device: int | None = None, timeout_s: float = 600.0) -> None:
        self.worker = RenderWorker(queue_size=8, job_timeout_s=timeout_s, backend=backend, device=device,
                                   name="depthview-pytest-gl").start()
        if not self.worker.wait_ready(120.0):
            error = self.worker.startup_error or "start-up did not finish within 120 s"
            self.worker.stop()
            raise RuntimeError(f"depthview: no headless OpenGL 4.3 context ({error}); "
                               "install Mesa's EGL/OSMesa drivers (see the README) or set DEPTHVIEW_GL")

    @property
    def renderer(self) -> str | None:
        """GL_RENDERER of the context, e.g. 'llvmpipe (LLVM 15.0.6, 256 bits)'."""
        return self.worker.renderer

    @property
    def backend(self) -> str | None:
        """'egl' or 'osmesa'."""
        return self.worker.backend

    def run(self, fn: Callable[[GLState], T]) -> T:
        """fn(state) on the GL thread; its result or its exception."""
        return self.worker.submit(fn).result()

    def close(self) -> None:
        self.worker.stop()


def wait_ready(client: Any, timeout: float = 20.0, poll_s: float = 0.02) -> dict:
    """/readyz's JSON once the service's render worker is up (client: a TestClient
    or httpx client on the app); TimeoutError naming the last answer after `timeout` s."""
    t0 = time.monotonic()
    while True:
        r = client.get("/readyz")
        if r.status_code == 200:
            return r.json()
        if time.monotonic() - t0 >= timeout:
            raise TimeoutError(f"service not ready after {timeout:g} s: {r.text}")
        time.sleep(poll_s)


_LOADED: dict[tuple[str, int, int], Scene] = {}


def as_scene(scene: SceneArg) -> Scene:
    """A Scene from a Scene, a model file path or a built-in scene name."""
    if isinstance(scene, Scene):
        return scene
    if isinstance(scene, str) and scene in BUILTIN_NAMES:
        return make_builtin(scene)
    path = Path(scene).resolve()
    if not path.exists():
        raise FileNotFoundError(f"no model file {path} (and {str(scene)!r} is not a built-in scene: "
                                f"{', '.join(BUILTIN_NAMES)})")
    st = path.stat()
    key = (str(path), st.st_mtime_ns, st.st_size)  # a rewritten file is loaded again
    if key not in _LOADED:
        _LOADED[key] = load_scene(path)
    return _LOADED[key]


def as_camera(camera: CameraArg, scene: Scene) -> Camera:
    """A Camera from a Camera or a mapping of its fields, near/far fitted to the
    scene bounds when missing (as the service does)."""
    cam = camera if isinstance(camera, Camera) else Camera(**dict(camera))
    return cam if cam.near is not None else cam.fit_clip(scene.bounds)


def scene_key(scene: Scene) -> str:
    """A content address of the scene's geometry, materials and sun (the GPU
    upload cache key: the same key always means the same geometry)."""
    h = hashlib.sha256(repr(scene.sun_direction).encode())
    for o in scene.objects:
        h.update(repr((o.name, o.material, o.vertices.shape, o.faces.shape)).encode())
        for a in (o.vertices, o.faces, o.normals):
            h.update(np.ascontiguousarray(a).tobytes())
    return "pytest-" + h.hexdigest()


#: The effects these frames render (others are refused rather than silently left out).
SUPPORTED_EFFECTS = ("reflections", "glossy_rays")


def _effects(effects: Mapping[str, Any] | None) -> Effects:
    try:
        fx = Effects.model_validate(dict(effects or {}))
    except ValueError as exc:  # pydantic's ValidationError is a ValueError
        raise ValueError(f"invalid effects {effects!r}: {exc}") from None
    other = sorted(k for k, v in fx.model_dump().items() if k not in SUPPORTED_EFFECTS and v not in (None, "none"))
    if other:
        raise NotImplementedError(f"the test fixtures render {', '.join(SUPPORTED_EFFECTS)} only, not {other}")
    return fx


def render_frame(gl: GLThread, scene: SceneArg, camera: CameraArg, effects: Mapping[str, Any] | None = None
                 ) -> Frame:
    """The frame the service renders for (scene, camera, effects): FrameBuffers
    without effects, ReflectionBuffers with reflections ("raytrace" is Embree's,
    on the calling thread, as in the service)."""
    sc = as_scene(scene)
    cam = as_camera(camera, sc)
    fx = _effects(effects)
    if fx.reflections == "none":
        return gl.run(FrameJob(scene_key(sc), sc, cam))
    if fx.reflections == "raytrace":
        return raytrace(sc, cam, fx.glossy_rays)
    return gl.run(ReflectionJob(scene_key(sc), sc, cam, fx.reflections, fx.glossy_rays))


def reference_frame(scene: SceneArg, camera: CameraArg, effects: Mapping[str, Any] | None = None) -> Frame:
    """The Embree reference of the same frame (the truth the GL passes are tested
    against): primary rays → FrameBuffers; with reflections, ray-traced
    reflections (2×2 supersampled, the same glossy_rays) → ReflectionBuffers."""
    from reference.raycast import RayCaster

    sc = as_scene(scene)
    cam = as_camera(camera, sc)
    fx = _effects(effects)
    if fx.reflections == "none":
        return RayCaster(sc).gbuffer(cam)
    return raytrace(sc, cam, fx.glossy_rays)

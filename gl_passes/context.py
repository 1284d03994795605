"""Headless OpenGL 4.3+ core contexts (DESIGN.md: one context per render thread).

EGL (surfaceless / device platform) is the default; OSMesa is the fallback or is
chosen with DEPTHVIEW_GL=osmesa. DEPTHVIEW_GL_DEVICE picks the EGL device index
(GPU). The creating thread owns the context: every pass calls `check_thread()`
before touching GL, so a GL call from a request-handler thread fails loudly.
"""

from __future__ import annotations

import ctypes
import logging
import os
import threading
from dataclasses import dataclass, field

import moderngl

log = logging.getLogger(__name__)

REQUIRED_GL = 430
_SOFTWARE_MARKERS = ("llvmpipe", "softpipe", "swrast", "software", "lavapipe")


class GLContextError(RuntimeError):
    """No usable OpenGL 4.3 core context could be created."""


@dataclass
class GLContext:
    """A moderngl context bound to the thread that created it."""

    ctx: moderngl.Context
    backend: str
    renderer: str
    version: str
    owner_thread: int = field(default_factory=threading.get_ident)
    #: Compiled programs keyed by shader files and defines (gl_passes.shaders).
    programs: dict = field(default_factory=dict)
    _release_hook: object | None = None

    @property
    def is_software(self) -> bool:
        r = self.renderer.lower()
        return any(m in r for m in _SOFTWARE_MARKERS)

    def check_thread(self) -> None:
        """Raise if the caller is not the thread that owns this context."""
        if threading.get_ident() != self.owner_thread:
            raise RuntimeError(
                f"GL context used from thread {threading.get_ident()}, owned by {self.owner_thread}"
            )

    def release(self) -> None:
        self.check_thread()
        self.ctx.release()
        if callable(self._release_hook):
            self._release_hook()


def _create_egl(device: int | None) -> tuple[moderngl.Context, None]:
    kwargs: dict = {"standalone": True, "backend": "egl", "require": REQUIRED_GL}
    if device is not None:
        kwargs["device_index"] = device
    return moderngl.create_context(**kwargs), None


class _OSMesaLoader:
    """moderngl loader over an OSMesa core-profile context (Mesa's libOSMesa)."""

    _FORMAT, _RGBA, _DEPTH_BITS, _PROFILE, _CORE = 0x22, 0x1908, 0x30, 0x33, 0x34
    _MAJOR, _MINOR, _UNSIGNED_BYTE = 0x36, 0x37, 0x1401

    def __init__(self) -> None:
        lib = None
        for name in ("libOSMesa.so.8", "libOSMesa.so.6", "libOSMesa.so"):
            try:
                lib = ctypes.CDLL(name)
                break
            except OSError:
                continue
        if lib is None:
            raise GLContextError("libOSMesa not found (apt-get install libosmesa6)")
        lib.OSMesaCreateContextAttribs.restype = ctypes.c_void_p
        lib.OSMesaCreateContextAttribs.argtypes = [ctypes.POINTER(ctypes.c_int), ctypes.c_void_p]
        lib.OSMesaMakeCurrent.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int, ctypes.c_int, ctypes.c_int]
        lib.OSMesaGetProcAddress.restype = ctypes.c_void_p
        lib.OSMesaGetProcAddress.argtypes = [ctypes.c_char_p]
        lib.OSMesaDestroyContext.argtypes = [ctypes.c_void_p]
        attrs = [self._FORMAT, self._RGBA, self._DEPTH_BITS, 0, self._PROFILE, self._CORE,
                 self._MAJOR, REQUIRED_GL // 100, self._MINOR, (REQUIRED_GL // 10) % 10, 0]
        self._lib = lib
        self._handle = lib.OSMesaCreateContextAttribs((ctypes.c_int * len(attrs))(*attrs), None)
        if not self._handle:
            raise GLContextError("OSMesaCreateContextAttribs failed (no GL 4.3 core profile)")
        # All rendering goes to our own framebuffers; the default buffer is a 1x1 dummy.
        self._buffer = (ctypes.c_ubyte * 4)()
        if not lib.OSMesaMakeCurrent(self._handle, self._buffer, self._UNSIGNED_BYTE, 1, 1):
            raise GLContextError("OSMesaMakeCurrent failed")

    def load_opengl_function(self, name: str) -> int:
        return self._lib.OSMesaGetProcAddress(name.encode()) or 0

    def release(self) -> None:
        if self._handle:
            self._lib.OSMesaDestroyContext(self._handle)
            self._handle = None


def _create_osmesa() -> tuple[moderngl.Context, object]:
    loader = _OSMesaLoader()
    moderngl.init_context(loader)
    ctx = moderngl.get_context()
    # init_context registers a process-wide default; we keep one context per thread instead.
    moderngl._store.default_context = None
    return ctx, loader.release


def create_gl_context(backend: str | None = None, device: int | None = None) -> GLContext:
    """Create a GL ≥ 4.3 core context owned by the calling thread.

    backend: "egl" | "osmesa" | None (env DEPTHVIEW_GL, default "egl" with OSMesa
    fallback). device: EGL device index (env DEPTHVIEW_GL_DEVICE)."""
    choice = (backend or os.environ.get("DEPTHVIEW_GL") or "egl").lower()
    if choice not in ("egl", "osmesa"):
        raise GLContextError(f"DEPTHVIEW_GL must be 'egl' or 'osmesa', got {choice!r}")
    if device is None and os.environ.get("DEPTHVIEW_GL_DEVICE"):
        device = int(os.environ["DEPTHVIEW_GL_DEVICE"])
    errors = []
    order = ["egl", "osmesa"] if choice == "egl" and backend is None else [choice]
    for name in order:
        try:
            ctx, hook = _create_egl(device) if name == "egl" else _create_osmesa()
        except Exception as exc:  # noqa: BLE001 - report every backend's failure together
            errors.append(f"{name}: {exc}")
            log.warning("GL backend %s failed: %s", name, exc)
            continue
        if ctx.version_code < REQUIRED_GL:
            ctx.release()
            errors.append(f"{name}: GL {ctx.version_code} < {REQUIRED_GL}")
            continue
        info = ctx.info
        gl = GLContext(ctx=ctx, backend=name, renderer=str(info["GL_RENDERER"]),
                       version=str(info["GL_VERSION"]), _release_hook=hook)
        log.info("GL context: backend=%s renderer=%s version=%s", name, gl.renderer, gl.version)
        if gl.is_software:
            log.warning("GL renderer %r is a SOFTWARE rasteriser: expect CPU-bound rendering", gl.renderer)
        return gl
    raise GLContextError("no OpenGL 4.3 core context: " + "; ".join(errors))

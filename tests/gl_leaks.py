"""Leak check for GL passes: count live GL objects on a fresh context before and
after many frames (EGL/glvnd; object names are not reused by Mesa, so the count
of names that are still textures/buffers/framebuffers/VAOs/renderbuffers is the
number of live objects)."""

from __future__ import annotations

import ctypes
import threading
from collections.abc import Callable
from typing import Any

from gl_passes.context import GLContext, create_gl_context


def live_gl_objects(max_name: int) -> int:
    """Live textures, buffers, framebuffers, vertex arrays and renderbuffers with names ≤ max_name."""
    lib = ctypes.CDLL("libOpenGL.so.0")
    total = 0
    for fn in ("glIsTexture", "glIsBuffer", "glIsFramebuffer", "glIsVertexArray", "glIsRenderbuffer"):
        f = getattr(lib, fn)
        f.restype = ctypes.c_ubyte
        total += sum(f(i) for i in range(1, max_name + 1))
    return total


def _count(gl: GLContext) -> int:
    probe = gl.ctx.texture((1, 1), 1)  # its name bounds every name handed out so far
    n = live_gl_objects(probe.glo + 64)
    probe.release()
    return n


def gl_object_growth(setup: Callable[[GLContext], Any], frame: Callable[[Any, int], None], frames: int
                     ) -> tuple[int, int]:
    """On a fresh EGL context in its own thread: state = setup(gl) (which should
    render once, so lazily created objects exist), count live objects, call
    frame(state, i) `frames` times, count again; state.release() if it has one.
    Returns (before, after)."""
    result: dict[str, Any] = {}

    def run() -> None:
        gl = create_gl_context("egl")
        try:
            state = setup(gl)
            result["before"] = _count(gl)
            for i in range(frames):
                frame(state, i)
            result["after"] = _count(gl)
            if hasattr(state, "release"):
                state.release()
        except BaseException as exc:  # noqa: BLE001 - re-raised on the test thread
            result["error"] = exc
        finally:
            gl.release()

    t = threading.Thread(target=run)
    t.start()
    t.join()
    if "error" in result:
        raise result["error"]
    return result["before"], result["after"]

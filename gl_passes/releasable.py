"""`with` support for GL-owning objects (uploads, passes): leaving the block calls
`release()`, on the thread that owns the context, as every GL call must be; the
objects one step makes for itself (`Scratch`) or to hand over (`ReleasedOnError`),
so that no path, a raising one included, leaves one behind; and the grow-or-keep
rule for the storage buffers those objects own."""

from __future__ import annotations

from typing import Any, Protocol, TypeVar

import moderngl

from gl_passes.context import GLContext
from gl_passes.shaders import compute_program

_T = TypeVar("_T", bound="Releasable")


class _HasRelease(Protocol):
    def release(self) -> None: ...


_R = TypeVar("_R", bound=_HasRelease)
_S = TypeVar("_S", bound="Scratch")


class Releasable:
    """Mixin: `with SceneGPU(gl, scene) as sg: ...` releases `sg` on exit, also when
    the block raises (the subclass defines `release()`)."""

    def release(self) -> None:  # pragma: no cover - every subclass overrides it
        raise NotImplementedError

    def __enter__(self: _T) -> _T:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.release()


def release_framebuffer(fbo: moderngl.Framebuffer) -> None:
    """Release `fbo`, binding the default framebuffer first where `fbo` is moderngl's
    current one: moderngl binds its current framebuffer again after it makes a
    framebuffer or clears or reads another, and binding a deleted one is
    GL_INVALID_OPERATION."""
    if fbo.ctx.fbo is fbo:
        fbo.ctx.detect_framebuffer(0).use()
    fbo.release()


def release_gl(obj: _HasRelease) -> None:
    """obj.release(); a framebuffer through `release_framebuffer`."""
    if isinstance(obj, moderngl.Framebuffer):
        release_framebuffer(obj)
    else:
        obj.release()


class Scratch:
    """The GL objects one step makes for itself: `with Scratch() as temp: tex =
    temp(ctx.texture(...))` releases everything passed to `temp` (last first) when
    the block ends, also when it raises."""

    def __init__(self) -> None:
        self.objects: list[_HasRelease] = []

    def __call__(self, obj: _R) -> _R:
        self.objects.append(obj)
        return obj

    def __enter__(self: _S) -> _S:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: Any) -> None:
        self._release_all()

    def _release_all(self) -> None:
        while self.objects:
            release_gl(self.objects.pop())


class ReleasedOnError(Scratch):
    """The GL objects a step makes to hand over: `with ReleasedOnError() as made:
    vbo = made(ctx.buffer(...))` releases them (last first) only when the block
    raises; when it completes they belong to what the step returned."""

    def __exit__(self, exc_type: type[BaseException] | None, *exc: Any) -> None:
        if exc_type is not None:
            self._release_all()
        self.objects.clear()


def grown_buffer(ctx: moderngl.Context, buf: moderngl.Buffer | None, need: int,
                 reserve: int | None = None) -> moderngl.Buffer:
    """`buf` when it holds at least `need` bytes, else a new buffer of `reserve`
    bytes (default `need`; callers pass their headroom) with `buf` released: the
    storage buffers the passes keep across frames."""
    if buf is not None and buf.size >= need:
        return buf
    if buf is not None:
        buf.release()
    return ctx.buffer(reserve=need if reserve is None else reserve)


def settle(gl: GLContext) -> None:
    """Let the driver free what was just released: one empty compute dispatch
    (shaders/settle.comp), then wait. Mesa's llvmpipe holds the buffers and images
    last bound to the compute stage until the next dispatch rebinds it, so a pass's
    released storage stays resident until some later job runs without this."""
    gl.check_thread()
    compute_program(gl, "settle.comp").run(1)
    gl.ctx.finish()

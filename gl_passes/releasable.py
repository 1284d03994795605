"""`with` support for GL-owning objects (uploads, passes): leaving the block calls
`release()`, on the thread that owns the context, as every GL call must be; and
the grow-or-keep rule for the storage buffers those objects own."""

from __future__ import annotations

from typing import Any, TypeVar

import moderngl

_T = TypeVar("_T", bound="Releasable")


class Releasable:
    """Mixin: `with SceneGPU(gl, scene) as sg: ...` releases `sg` on exit, also when
    the block raises (the subclass defines `release()`)."""

    def release(self) -> None:  # pragma: no cover - every subclass overrides it
        raise NotImplementedError

    def __enter__(self: _T) -> _T:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.release()


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

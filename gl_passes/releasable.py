"""`with` support for GL-owning objects (uploads, passes): leaving the block calls
`release()`, on the thread that owns the context, as every GL call must be."""

from __future__ import annotations

from typing import Any, TypeVar

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

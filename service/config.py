"""Service settings and limits (read from ``DEPTHVIEW_*`` environment variables).

Every limit below is enforced by the HTTP service (``service.app``); the README
cites them. Environment variable = ``DEPTHVIEW_`` + the field name in upper case,
e.g. ``DEPTHVIEW_MAX_UPLOAD_BYTES=1048576``.

=====================  ===========================  ===============================================
field                  default                      meaning
=====================  ===========================  ===============================================
data_dir               ``./data``                   scene store root (``<data_dir>/scenes/<id>/``)
host / port            ``127.0.0.1`` / ``8000``     where ``depthview serve`` listens
max_upload_bytes       64 MiB (67108864)            largest accepted scene file; counted while the
                                                    request body is read → 413
max_triangles          5,000,000                    largest scene (uploads: parsed count; built-ins:
                                                    ``estimate_triangles``) → 422
max_width/max_height   4096 / 4096                  largest frame side in pixels → 422
max_pixels             16,777,216 (4096²)           largest width × height → 422
queue_size             32                           render jobs waiting for the GL worker; a full
                                                    queue → 503 with ``Retry-After``
job_timeout_s          120                          how long a handler waits for its job → 504
retry_after_s          1                            value of the ``Retry-After`` header on 503
scene_cache_size       8                            parsed Scene objects kept in memory (LRU)
gpu_cache_size         4                            scenes kept uploaded on the GPU (LRU, worker)
gl_backend             unset (EGL, OSMesa fallback) ``egl`` or ``osmesa``
gl_device              unset                        EGL device index
=====================  ===========================  ===============================================
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ENV_PREFIX = "DEPTHVIEW_"

MIB = 1024 * 1024


@dataclass(frozen=True)
class Settings:
    """Service configuration. Build with ``Settings.from_env(**overrides)`` to read
    ``DEPTHVIEW_*`` variables, or construct directly (tests)."""

    #: Root of the on-disk scene store.
    data_dir: Path = field(default_factory=lambda: Path("./data"))
    #: Interface ``depthview serve`` binds to.
    host: str = "127.0.0.1"
    #: Port ``depthview serve`` listens on.
    port: int = 8000
    #: Largest scene upload in bytes (the file part of a multipart body, or a raw body).
    #: Enforced while the body streams in: a larger request is cut off with 413.
    max_upload_bytes: int = 64 * MIB
    #: Largest scene in triangles. Uploads: the parsed count; built-ins: the estimate
    #: for the requested detail. Over the limit → 422 naming the count and the limit.
    max_triangles: int = 5_000_000
    #: Largest frame width in pixels (422 above it).
    max_width: int = 4096
    #: Largest frame height in pixels (422 above it).
    max_height: int = 4096
    #: Largest frame area width × height in pixels (422 above it).
    max_pixels: int = 4096 * 4096
    #: Render jobs that may wait for the GL worker; when full → 503 + Retry-After.
    queue_size: int = 32
    #: Seconds a request waits for its render job before 504; a job whose deadline
    #: passed while queued is skipped by the worker.
    job_timeout_s: float = 120.0
    #: Seconds advertised in the Retry-After header of a 503.
    retry_after_s: int = 1
    #: Parsed Scene objects kept in memory (LRU).
    scene_cache_size: int = 8
    #: Scenes kept uploaded on the GPU by the render worker (LRU; released on eviction).
    gpu_cache_size: int = 4
    #: GL backend: "egl" or "osmesa"; None = EGL with OSMesa fallback (DEPTHVIEW_GL).
    gl_backend: str | None = None
    #: EGL device index; None = default device (DEPTHVIEW_GL_DEVICE).
    gl_device: int | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "data_dir", Path(self.data_dir))
        for name in ("max_upload_bytes", "max_triangles", "max_width", "max_height", "max_pixels",
                     "queue_size", "scene_cache_size", "gpu_cache_size"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"setting {name} must be >= 1, got {getattr(self, name)!r}")
        if not self.job_timeout_s > 0:
            raise ValueError(f"setting job_timeout_s must be > 0, got {self.job_timeout_s!r}")
        if self.gl_backend is not None and self.gl_backend not in ("egl", "osmesa"):
            raise ValueError(f"setting gl_backend must be 'egl' or 'osmesa', got {self.gl_backend!r}")

    @classmethod
    def from_env(cls, environ: dict[str, str] | None = None, **overrides: Any) -> Settings:
        """Settings from ``DEPTHVIEW_<FIELD>`` variables; keyword overrides win.

        ``DEPTHVIEW_GL`` / ``DEPTHVIEW_GL_DEVICE`` (the GL core's own variables) are
        left to ``create_gl_context``; ``DEPTHVIEW_GL_BACKEND`` sets gl_backend here."""
        env = os.environ if environ is None else environ
        values: dict[str, Any] = {}
        for f in dataclasses.fields(cls):
            if f.name in overrides:
                continue
            raw = env.get(ENV_PREFIX + f.name.upper())
            if raw is None or raw == "":
                continue
            values[f.name] = _convert(f.name, raw)
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**values)


_INT_FIELDS = {"port", "max_upload_bytes", "max_triangles", "max_width", "max_height", "max_pixels",
               "queue_size", "retry_after_s", "scene_cache_size", "gpu_cache_size", "gl_device"}
_FLOAT_FIELDS = {"job_timeout_s"}


def _convert(name: str, raw: str) -> Any:
    try:
        if name in _INT_FIELDS:
            return int(raw.replace("_", ""))
        if name in _FLOAT_FIELDS:
            return float(raw)
    except ValueError as exc:
        raise ValueError(f"{ENV_PREFIX}{name.upper()}={raw!r} is not a number") from exc
    if name == "data_dir":
        return Path(raw)
    return raw

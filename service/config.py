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
                                                    ``estimate_triangles``) → 422; the built-ins at
                                                    their default parameters are exempt
max_width/max_height   4096 / 4096                  largest frame side in pixels → 422 (at most
                                                    16384, MAX_FRAME_SIDE)
max_pixels             16,777,216 (4096²)           largest width × height → 422
queue_size             32                           render jobs waiting for the GL worker; a full
                                                    queue → 503 with ``Retry-After``
job_timeout_s          120                          how long a handler waits for its job → 504
retry_after_s          1                            value of the ``Retry-After`` header on 503
parse_timeout_s        60                           seconds an upload may take to parse (in a child
                                                    process, which is then killed) → 422; its memory
                                                    is held to max_job_bytes (→ 422); as many parses
                                                    run at once as workers, and an upload waiting
                                                    longer than this for its turn → 503
max_pending_upload_     1 GiB (1073741824)           bytes of the uploads being received, waiting for
bytes                                               their parse or parsed at once (each holds its
                                                    body in memory): its Content-Length, else the
                                                    largest upload; an upload past it → 503 before
                                                    its body is read (one alone is always admitted)
scene_cache_size       8                            parsed Scene objects kept in memory (LRU)
gpu_cache_size         4                            scenes kept uploaded on the GPU (LRU, worker)
reconstruction_cache_  1.25 GiB (1342177280)        GPU bytes of reconstructions (soft shadows'
bytes                                               occluders, /reconstruction meshes) and of a
                                                    light's k² shadow maps (S²·16·4 B per 16 maps:
                                                    1 GiB for the default 16×16) each worker keeps
                                                    for the next request with the same scene, light
                                                    or cameras, method and resolution (LRU); 0 keeps
                                                    none
gl_backend             unset (EGL, OSMesa fallback) ``egl`` or ``osmesa`` (``DEPTHVIEW_GL``, or
                                                    ``DEPTHVIEW_GL_BACKEND``)
gl_device              unset                        EGL device index of every worker; unset with
                                                    several NVIDIA GPUs: worker process i uses
                                                    device i mod the GPU count, else the default
workers                ``auto``: one per NVIDIA     render worker processes, each with its own GL
                       GPU, else one per two cores  context and Embree devices; 0 = one worker
                       (at least 1; the cores the   thread in the service process instead (tests:
                       affinity mask and a cgroup   a timed-out job still runs to its end there)
                       CPU quota allow)
max_json_bytes         1 MiB (1048576)              largest request body of every endpoint but a
                                                    scene upload (Content-Length or counted) → 413
max_job_bytes          7 GiB (7516192768)           memory budget of one render request, estimated
                                                    up front by ``service.budget`` → 422 naming the
                                                    estimate and the budget (formulas below)
header_timeout_s       10                           seconds a connection may take to send a request's
                                                    headers (from connect or the previous response)
                                                    before it is closed
body_timeout_s         30                           seconds the service waits for the next chunk of a
                                                    request body → 408 and the connection is closed
token                  unset (no authentication)    bearer token every endpoint but /healthz, /readyz
                                                    and the docs requires (401 otherwise)
cors_origins           unset (no CORS headers)      comma-separated origins allowed cross-origin
                                                    requests (``*`` for any)
stream_max_per_client  4                            open ``/scenes/{id}/stream`` sockets per client
                                                    address; one more gets an error message and is
                                                    closed (code 1013)
stream_max_total       16                           open stream sockets in total (same refusal)
stream_max_message_    16 KiB (16384)               largest camera message on the stream (bytes);
bytes                                               a larger one gets an error message
stream_max_pixels      2,073,600 (1920×1080)        largest streamed frame width × height (error
                                                    message; max_width/max_height apply too)
stream_reuse_bytes     4 GiB (4294967296)           memory each worker keeps for the reusers of its
                                                    reflective streams, estimated per frame size
                                                    (STREAM_REUSER_BYTES_PER_PIXEL); past it the
                                                    least recently used stream's reuser is released
                                                    and its next frame is a keyframe
stream_jpeg_quality    80                           JPEG quality (1–95) of frames while the camera
                                                    moves
stream_rest_s          0.3                          seconds without a camera message after which
                                                    the latest view is sent again as lossless PNG
stream_reflection_mode ``reuse``                    how the stream renders reflective frames: reuse
                                                    (thesis Ch. 5), or the baselines full (every
                                                    reflective pixel traced each frame, same tracer)
                                                    and direct (depth reprojection)
node_modules           ``<repo>/node_modules``      where ``npm ci`` installed three.js for the
                                                    /client page (set it for a non-editable install)
=====================  ===========================  ===============================================

The memory budget (``max_job_bytes``) is checked against an estimate made from the
request alone, before the scene is loaded or a job queued (``service.budget``;
W×H the image size, n the number of images, r the reconstruction resolution, k the
light samples per side, S the shadow-map resolution 1024):

* frame: W·H·``FRAME_BYTES_PER_PIXEL`` (400 B: G-buffer readback, float copies, encoding);
  with reflections ×4 (2×2 supersampling; glossy lobes are traced in fixed-size chunks);
* soft shadows: the frame + W·H·2·(k²/8 + 8) B of visibility bits + n·r²·
  ``RECONSTRUCTION_BYTES_PER_SAMPLE`` (n = 4 images, none for ``geometry`` and ``raytrace``;
  368 B per sample: the sample and its offset image, its quad on CPU and GPU)
  + 2·S²·min(k², 16)·4 B of shadow-map atlas and the integer depth image of the
  same size that a reconstruction's small pieces are rasterised into (kept by the
  worker's pass once made) (not for ``raytrace``);
* reconstruction: n·r²·``RECONSTRUCTION_BYTES_PER_SAMPLE`` (the GLB included);
* depth-image set: n·W·H·``SET_BYTES_PER_PIXEL`` (272 B), doubled with ``metrics``
  (the conventional images beside the set).

The costs were measured (see the constants); 7 GiB admits every single-image limit
(a 4096² frame, 4 reconstructed images at 2048²) and refuses 16 images at 2048².
What a worker keeps between requests (reconstructions, a light's k² shadow maps,
drawn in place of the one atlas above when they fit) is bounded by
``reconstruction_cache_bytes`` apart from this per-request budget; the passes and
targets a job sized for images over ``stream_max_pixels`` are released after it
(``Settings.keep_pixels``), so an idle worker does not hold its largest frame's.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from scenes.excerpts import cut

ENV_PREFIX = "DEPTHVIEW_"
#: The repository (or, installed, site-packages) root: package.json and node_modules live here.
REPO_ROOT = Path(__file__).resolve().parents[1]

MIB = 1024 * 1024
#: Largest max_width / max_height: the framebuffer side GL 4.5 guarantees (MAX_TEXTURE_SIZE,
#: MAX_RENDERBUFFER_SIZE); a frame wider than the driver's limit fails in the framebuffer.
MAX_FRAME_SIDE = 16384
#: Longest time setting in seconds (a day): waits take finite timeouts (inf or 1e12 s overflowed).
MAX_SECONDS = 86400.0

# Per-unit costs of the memory-budget estimate (``max_job_bytes``; formulas in the
# module docstring, applied by ``service.budget``). Calibrated by the peak resident
# memory one request adds to a warm service on llvmpipe (GPU memory is host memory
# there), per request kind against this estimate, the larger of: the render worker a
# thread of the service (bench/results/memory_budget.md) and the default, a worker
# process, whose result the service process holds again to shade and encode it (the
# two processes' peaks summed: bench/results/memory_budget_workers1.md).
#: Bytes per frame pixel: G-buffer readback (RGB, depth, normal, position, ids, mask),
#: the float copies made while shading and the encoded image.
FRAME_BYTES_PER_PIXEL = 400
#: Bytes per pixel of one image of a depth-image set.
SET_BYTES_PER_PIXEL = 272
#: Bytes per reference-image sample of a reconstruction: the sample and its offset
#: image, its quad (vertices, colours, indices) on the CPU and the GPU, the readback.
RECONSTRUCTION_BYTES_PER_SAMPLE = 368
#: Side of each soft-shadow map (gl_passes.shadows.ShadowSettings) and the most maps
#: rendered at once into one atlas (maps_per_draw), float32 depth.
SHADOW_MAP_RESOLUTION = 1024
SHADOW_MAPS_PER_DRAW = 16
#: Bytes per frame pixel a reflective stream's reuser keeps on its worker between
#: frames, by reflection method (``stream_reuse_bytes``; bench/results/stream_memory.md,
#: rounded up from its largest row).
STREAM_REUSER_BYTES_PER_PIXEL = {"cluster": 448, "raytrace": 256}


#: cgroup v2's CPU limit of this process's group ("<quota> <period>" or "max <period>"), and
#: cgroup v1's quota and period files (quota -1: none): `docker run --cpus=N` writes them.
CGROUP_CPU_MAX = Path("/sys/fs/cgroup/cpu.max")
CGROUP_V1_CPU = Path("/sys/fs/cgroup/cpu")


def nvidia_gpus() -> int:
    """NVIDIA GPUs visible here: ``/dev/nvidia<N>`` device nodes (cheap, no driver call;
    in a container, the GPUs it was given)."""
    return len(list(Path("/dev").glob("nvidia[0-9]*")))


def cgroup_cpu_limit(cpu_max: Path | None = None, v1_dir: Path | None = None) -> int | None:
    """Whole cores the cgroup CPU quota allows (ceil(quota / period)), or None without a
    quota (or where the files cannot be read)."""
    try:
        quota, period = (cpu_max or CGROUP_CPU_MAX).read_text().split()[:2]
    except (OSError, ValueError):  # no cgroup v2 file: cgroup v1
        v1 = v1_dir or CGROUP_V1_CPU
        try:
            quota, period = ((v1 / f).read_text().strip() for f in ("cpu.cfs_quota_us", "cpu.cfs_period_us"))
        except (OSError, ValueError):
            return None
    try:
        q, p = int(quota), int(period)
    except ValueError:  # "max": no quota
        return None
    if q <= 0 or p <= 0:
        return None
    return max(1, -(-q // p))


def default_workers() -> int:
    """One render worker per NVIDIA GPU (`nvidia_gpus`), else one per two usable cores
    (the affinity mask, and the cgroup CPU quota where it allows fewer), at least one."""
    gpus = nvidia_gpus()
    if gpus:
        return gpus
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    quota = cgroup_cpu_limit()
    if quota is not None:
        cores = min(cores, quota)
    return max(1, cores // 2)


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
    #: Seconds an upload may take to parse (``service.parsing``: a child process, killed
    #: past it → 422); its memory is held to max_job_bytes.
    parse_timeout_s: float = 60.0
    #: Bytes the uploads in progress (received, waiting for their parse, parsed) may hold
    #: at once, each counted by its Content-Length or else as the largest upload; one past
    #: it → 503 + Retry-After before its body is read; one alone is always admitted.
    max_pending_upload_bytes: int = 1024 * MIB
    #: Parsed Scene objects kept in memory (LRU).
    scene_cache_size: int = 8
    #: Scenes kept uploaded on the GPU by the render worker (LRU; released on eviction).
    gpu_cache_size: int = 4
    #: GPU bytes of reconstructions and shadow maps each render worker keeps between requests (LRU; 0: none).
    reconstruction_cache_bytes: int = 1280 * MIB
    #: GL backend: "egl" or "osmesa"; None = EGL with OSMesa fallback (DEPTHVIEW_GL).
    gl_backend: str | None = None
    #: EGL device index of every worker (DEPTHVIEW_GL_DEVICE); None = the default device, or
    #: with several NVIDIA GPUs device i mod their count for worker process i.
    gl_device: int | None = None
    #: Render worker processes (``service.process_worker``); 0 = the in-process worker
    #: thread. Default (and ``DEPTHVIEW_WORKERS=auto``): one per NVIDIA GPU, else one per
    #: two cores (affinity mask, cgroup CPU quota), at least one.
    workers: int = field(default_factory=lambda: default_workers())
    #: Largest request body of every endpoint except scene uploads (413 above it).
    max_json_bytes: int = MIB
    #: Memory budget of one render request in bytes, estimated up front (422 above it).
    max_job_bytes: int = 7 * 1024 * MIB
    #: Seconds a connection may take to deliver a request's headers before it is closed.
    header_timeout_s: float = 10.0
    #: Seconds to wait for the next chunk of a request body (408 and close after it).
    body_timeout_s: float = 30.0
    #: Bearer token required by every endpoint but /healthz, /readyz and the docs; None = open.
    token: str | None = None
    #: Origins allowed cross-origin requests (CORS); empty = no CORS headers at all.
    cors_origins: tuple[str, ...] = ()
    #: Open stream sockets per client address (more → error message, close code 1013).
    stream_max_per_client: int = 4
    #: Open stream sockets in total (more → error message, close code 1013).
    stream_max_total: int = 16
    #: Largest camera message on the stream in bytes (larger → error message on the socket).
    stream_max_message_bytes: int = 16 * 1024
    #: Largest streamed frame width × height (larger → error message on the socket).
    stream_max_pixels: int = 1920 * 1080
    #: Bytes of reflective streams' reusers each worker keeps (estimated per frame size);
    #: past it the least recently used one is released (its next frame a keyframe).
    stream_reuse_bytes: int = 4 * 1024 * MIB
    #: JPEG quality of streamed frames while the camera moves (1–95).
    stream_jpeg_quality: int = 80
    #: Seconds the camera must rest before the latest view is sent again as PNG.
    stream_rest_s: float = 0.3
    #: Reflective stream frames: "reuse" (thesis Ch. 5), or the baselines "full" (every
    #: reflective pixel traced every frame by the same tracer) and "direct" (depth reprojection).
    stream_reflection_mode: str = "reuse"
    #: node_modules holding three.js for the /client page (``npm ci`` at the repository root).
    node_modules: Path = field(default_factory=lambda: REPO_ROOT / "node_modules")

    def __post_init__(self) -> None:
        object.__setattr__(self, "data_dir", Path(self.data_dir))
        object.__setattr__(self, "node_modules", Path(self.node_modules))
        if isinstance(self.cors_origins, str):
            object.__setattr__(self, "cors_origins", _origins(self.cors_origins))
        object.__setattr__(self, "cors_origins", tuple(self.cors_origins))
        if self.token is not None and not self.token.strip():
            raise ValueError(f"{_setting('token')} must not be blank (leave it unset for no authentication)")
        if not 0 <= int(self.port) <= 65535:
            raise ValueError(f"{_setting('port')} must be within 0..65535, got {self.port!r}")
        for name in ("max_width", "max_height"):
            if int(getattr(self, name)) > MAX_FRAME_SIDE:
                raise ValueError(f"{_setting(name)} must be <= {MAX_FRAME_SIDE} (the largest framebuffer GL 4.5 "
                                 f"guarantees), got {getattr(self, name)!r}")
        for name in ("max_upload_bytes", "max_pending_upload_bytes", "max_triangles", "max_width", "max_height",
                     "max_pixels",
                     "queue_size", "scene_cache_size", "gpu_cache_size", "max_json_bytes", "max_job_bytes",
                     "stream_max_per_client", "stream_max_total", "stream_max_message_bytes", "stream_max_pixels",
                     "stream_reuse_bytes"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{_setting(name)} must be >= 1, got {getattr(self, name)!r}")
        if not 1 <= int(self.stream_jpeg_quality) <= 95:
            raise ValueError(f"{_setting('stream_jpeg_quality')} must be within 1..95, "
                             f"got {self.stream_jpeg_quality!r}")
        for name, what in (("reconstruction_cache_bytes", "0 = none"), ("workers", "0 = the worker thread"),
                           ("retry_after_s", "seconds in Retry-After")):
            if int(getattr(self, name)) < 0:
                raise ValueError(f"{_setting(name)} must be >= 0 ({what}), got {getattr(self, name)!r}")
        for name in ("job_timeout_s", "parse_timeout_s", "header_timeout_s", "body_timeout_s", "stream_rest_s"):
            if not 0 < getattr(self, name) <= MAX_SECONDS:
                raise ValueError(f"{_setting(name)} must be > 0 and at most {MAX_SECONDS:g} s, "
                                 f"got {getattr(self, name)!r}")
        from gl_passes.reprojection import MODES  # ReuseSettings.mode (imported here: settings load without GL)

        if self.stream_reflection_mode not in MODES:
            raise ValueError(f"{_setting('stream_reflection_mode')} must be one of {', '.join(MODES)}, "
                             f"got {self.stream_reflection_mode!r}")
        if self.gl_backend is not None and self.gl_backend not in ("egl", "osmesa"):
            raise ValueError(f"{_setting('gl_backend')} must be 'egl' or 'osmesa', got {self.gl_backend!r}")

    @property
    def keep_pixels(self) -> int:
        """Image pixels a render worker keeps its passes and G-buffer target sized for
        between jobs: the largest streamed frame's, which a stream may ask for every
        frame. A larger job's are released after it (`GLState.end_job`)."""
        return self.stream_max_pixels

    def size_problem(self, width: int, height: int, what: str = "frame") -> str | None:
        """What is over the limits in a width × height image, or None."""
        for name, value, limit, field_ in ((f"{what} width", width, self.max_width, "max_width"),
                                           (f"{what} height", height, self.max_height, "max_height"),
                                           (f"{what} width × height", width * height, self.max_pixels, "max_pixels")):
            if value > limit:  # a value of thousands of digits is named by an excerpt
                return f"{name} {cut(str(value), 24)} exceeds the limit {limit} ({ENV_PREFIX}{field_.upper()})"
        return None

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None, **overrides: Any) -> Settings:
        """Settings from ``DEPTHVIEW_<FIELD>`` variables; keyword overrides that are
        not None win (a CLI option left unset leaves the variable in force).

        gl_backend also reads ``DEPTHVIEW_GL`` (the GL core's own variable, which wins
        over ``DEPTHVIEW_GL_BACKEND``); gl_device is ``DEPTHVIEW_GL_DEVICE``."""
        env = os.environ if environ is None else environ
        values: dict[str, Any] = {}
        for f in dataclasses.fields(cls):
            if overrides.get(f.name) is not None:
                values[f.name] = overrides[f.name]
                continue
            for var in _ENV_NAMES.get(f.name, (ENV_PREFIX + f.name.upper(),)):
                raw = env.get(var)
                if f.name == "token" and raw is not None and not raw.strip():
                    raise ValueError(f"{var} is set but blank: unset it for no authentication, or give a token")
                if raw is not None and raw.strip() != "":
                    values[f.name] = _convert(f.name, raw, var)
                    break
        unknown = set(overrides) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise TypeError(f"unknown settings {sorted(unknown)}")
        return cls(**values)


#: Fields read from other variables than DEPTHVIEW_<FIELD> (first one set wins).
_ENV_NAMES = {"gl_backend": (ENV_PREFIX + "GL", ENV_PREFIX + "GL_BACKEND")}


def _setting(name: str) -> str:
    """A setting in messages: its field and the variable it is read from."""
    return f"setting {name} ({_ENV_NAMES.get(name, (ENV_PREFIX + name.upper(),))[0]})"


def _origins(raw: str) -> tuple[str, ...]:
    return tuple(o.strip().rstrip("/") for o in raw.split(",") if o.strip())


_INT_FIELDS = {"port", "max_upload_bytes", "max_pending_upload_bytes", "max_triangles", "max_width", "max_height",
               "max_pixels", "queue_size", "retry_after_s", "scene_cache_size", "gpu_cache_size", "gl_device",
               "max_json_bytes", "max_job_bytes", "stream_max_per_client", "stream_max_total",
               "stream_max_message_bytes", "stream_max_pixels", "stream_jpeg_quality", "workers",
               "reconstruction_cache_bytes", "stream_reuse_bytes"}
_FLOAT_FIELDS = {"job_timeout_s", "parse_timeout_s", "header_timeout_s", "body_timeout_s", "stream_rest_s"}


def _convert(name: str, raw: str, var: str) -> Any:
    if name == "workers" and raw.strip().lower() == "auto":
        return default_workers()
    try:
        if name in _INT_FIELDS:
            return int(raw.replace("_", ""))
        if name in _FLOAT_FIELDS:
            return float(raw)
    except ValueError as exc:
        raise ValueError(f"{var}={raw[:40]!r} is not a number") from exc
    if name in ("data_dir", "node_modules"):
        return Path(raw)
    if name in ("gl_backend", "stream_reflection_mode"):
        return raw.strip().lower()
    if name == "cors_origins":
        return _origins(raw)
    return raw

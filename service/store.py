"""Content-addressed scene store (DESIGN.md, "Service shape").

Scene ids are sha256 hex digests of the canonical upload:

* uploaded files: ``sha256(<format> + "\\n" + <raw file bytes>)`` — the same file
  uploaded twice gets the same id (the display name is not part of the id);
* built-in scenes: ``sha256(canonical JSON of {"builtin": name, "params": params})``
  with params normalised (defaults filled in, ``detail`` a float, ``seed`` an int)
  and keys sorted, so ``{"builtin": "cornell"}`` and
  ``{"builtin": "cornell", "params": {"detail": 1, "seed": 0}}`` are the same scene.

On disk (under ``<data_dir>/scenes``)::

    <id>/meta.json        SceneMeta as JSON
    <id>/source.<fmt>     the uploaded bytes (uploads only)

A scene directory is built under a temporary name and renamed into place, and
every file is written to a temporary file and ``os.replace``-d, so a crash never
leaves a half-written scene visible. Ids are validated (64 lowercase hex digits)
before any path is built from them; users never choose paths.

Built-in scenes with default parameters are registered at start-up as metadata
only (nothing on disk, no geometry built until a frame needs it). They are always
listed and **cannot be deleted** (``SceneProtected`` → HTTP 409). Built-ins with
non-default parameters are stored like uploads (``meta.json`` only) and can be
deleted.

Parsed ``Scene`` objects are loaded lazily and kept in a small thread-safe LRU.
A corrupted ``meta.json`` is logged and skipped by ``list()``; ``get_meta`` treats
it as a missing scene. Re-uploading the same content repairs it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import json
import logging
import math
import os
import re
import shutil
import threading
import time
import uuid
from collections import OrderedDict
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from scenes import builtin as builtin_scenes
from scenes import loaders
from scenes.model import Scene
from service.excerpts import quoted
from service.parsing import ParseMemoryLimit, ParseTimeLimit

log = logging.getLogger("depthview.store")

#: A valid scene id: sha256 hex digest, lowercase.
ID_RE = re.compile(r"^[0-9a-f]{64}$")

#: Parameters a built-in scene accepts, with their defaults.
BUILTIN_PARAM_DEFAULTS: dict[str, Any] = {"detail": 1.0, "seed": 0}

_TMP_PREFIX = ".tmp-"
_DEL_PREFIX = ".del-"


# --- errors ------------------------------------------------------------------------
class StoreError(Exception):
    """Base class of store errors."""


class InvalidSceneId(StoreError, ValueError):
    """The id is not 64 lowercase hex digits (HTTP 404)."""


class SceneNotFound(StoreError, LookupError):
    """No scene with that id (HTTP 404)."""


class SceneProtected(StoreError):
    """A built-in default scene cannot be deleted (HTTP 409)."""


class UnsupportedFormat(StoreError, ValueError):
    """The upload's format is not one of the loaders' formats (HTTP 415)."""


class TriangleLimitExceeded(StoreError, ValueError):
    """The scene has more triangles than allowed (HTTP 422)."""


class InvalidBuiltin(StoreError, ValueError):
    """Unknown built-in name or bad parameters (HTTP 422)."""


class StoreCorrupted(StoreError):
    """Stored data no longer matches its id or cannot be read (HTTP 500)."""


def builtin_description(name: str) -> str | None:
    """The built-in's one-line description without building it (``builtin_info()``
    builds every scene to count triangles, so it is not used at start-up)."""
    if name not in builtin_scenes.BUILTIN_NAMES:
        return None
    try:
        return getattr(importlib.import_module(f"scenes.builtin.{name}"), "DESCRIPTION", None)
    except ImportError:
        return None


# --- ids -----------------------------------------------------------------------------
def validate_id(scene_id: str) -> str:
    """Return scene_id if it is 64 lowercase hex digits, else raise InvalidSceneId."""
    if not isinstance(scene_id, str) or not ID_RE.fullmatch(scene_id):
        raise InvalidSceneId("invalid scene id (expected 64 lowercase hex digits)")
    return scene_id


def upload_id(fmt: str, data: bytes) -> str:
    """Content address of an uploaded file: sha256(format + '\\n' + bytes)."""
    h = hashlib.sha256()
    h.update(fmt.encode("ascii") + b"\n")
    h.update(data)
    return h.hexdigest()


def normalise_builtin_params(params: Mapping[str, Any] | None) -> dict[str, Any]:
    """Fill in defaults and canonicalise types: detail → finite float > 0, seed → int."""
    params = dict(params or {})
    unknown = sorted(set(params) - set(BUILTIN_PARAM_DEFAULTS))
    if unknown:
        raise InvalidBuiltin(f"unknown built-in parameter(s) {unknown}; allowed: {sorted(BUILTIN_PARAM_DEFAULTS)}")
    out = dict(BUILTIN_PARAM_DEFAULTS)
    out.update({k: v for k, v in params.items() if v is not None})
    detail, seed = out["detail"], out["seed"]
    if isinstance(detail, bool) or not isinstance(detail, (int, float)) or not math.isfinite(detail) or detail <= 0:
        raise InvalidBuiltin(f"built-in parameter detail must be a finite number > 0, got {quoted(detail)}")
    if isinstance(seed, bool) or not isinstance(seed, (int, float)) or not float(seed).is_integer():
        raise InvalidBuiltin(f"built-in parameter seed must be an integer, got {quoted(seed)}")
    if seed < 0:
        raise InvalidBuiltin(f"built-in parameter seed must be >= 0, got {quoted(seed)}")
    return {"detail": float(detail), "seed": int(seed)}


def builtin_canonical(name: str, params: Mapping[str, Any] | None) -> str:
    """Canonical JSON text identifying a built-in scene (normalised params, sorted keys)."""
    return json.dumps({"builtin": name, "params": normalise_builtin_params(params)},
                      sort_keys=True, separators=(",", ":"), allow_nan=False)


def builtin_id(name: str, params: Mapping[str, Any] | None = None) -> str:
    """Content address of a built-in scene: sha256 of its canonical JSON."""
    return hashlib.sha256(builtin_canonical(name, params).encode("utf-8")).hexdigest()


# --- metadata ------------------------------------------------------------------------
@dataclass
class SceneMeta:
    """What the store knows about a scene without building or parsing it."""

    id: str
    kind: str  # "upload" | "builtin"
    name: str
    triangles: int
    created_at: float
    format: str | None = None
    size_bytes: int | None = None
    objects: int | None = None
    bounds: list[list[float]] | None = None
    builtin: str | None = None
    params: dict[str, Any] | None = None
    description: str | None = None
    #: True for the built-in default entries registered at start-up (not deletable).
    default: bool = False
    #: True when `triangles` is an estimate (built-ins, before being built).
    triangles_estimated: bool = False
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> SceneMeta:
        """Parse and sanity-check a meta dict; raises ValueError when malformed."""
        if not isinstance(d, Mapping):
            raise ValueError("meta is not a JSON object")
        known = {f for f in cls.__dataclass_fields__}
        m = cls(**{k: v for k, v in d.items() if k in known})
        validate_id(m.id)
        if m.kind not in ("upload", "builtin"):
            raise ValueError(f"bad kind {m.kind!r}")
        if not isinstance(m.triangles, int) or m.triangles < 0:
            raise ValueError(f"bad triangle count {m.triangles!r}")
        if m.kind == "upload" and not (isinstance(m.format, str) and m.format.isalnum()):
            raise ValueError(f"bad format {m.format!r}")
        if m.kind == "builtin" and not isinstance(m.builtin, str):
            raise ValueError("built-in meta without a name")
        return m


def _display_name(name: str | None, fallback: str) -> str:
    """A printable display name (never used for paths)."""
    name = "".join(ch for ch in (name or "") if ch.isprintable()).strip()[:200]
    return name or fallback


def _atomic_write(path: Path, data: bytes) -> None:
    """Write `data` to a temporary file next to `path`, fsync, then os.replace it."""
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex}.tmp")
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


#: Parses an uploaded file: (data, format, name, max_triangles) → Scene; raises SceneLoadError.
Parser = Callable[[bytes, str, str, "int | None"], Scene]


def _upload_format(fmt: str | None) -> str:
    """`fmt` as the loaders name it (lower case, no dot); UnsupportedFormat if they have none."""
    fmt = (fmt or "").lower().lstrip(".")
    if fmt not in loaders.SUPPORTED_FORMATS:
        raise UnsupportedFormat(
            f"unsupported scene format {quoted(fmt)}; supported: {', '.join(loaders.SUPPORTED_FORMATS)}")
    return fmt


def _parse_here(data: bytes, fmt: str, name: str, max_triangles: int | None) -> Scene:
    return loaders.load_scene_bytes(data, fmt, name=name, max_triangles=max_triangles)


# --- the store -----------------------------------------------------------------------
class SceneStore:
    """Content-addressed scenes under ``<data_dir>/scenes`` with a lazy LRU of parsed Scenes.

    Thread-safe: handlers call it from a thread pool. It never touches GL. Uploads are
    parsed by `parse` (the service's: a child process under limits, ``service.parsing``;
    default: in this thread)."""

    def __init__(self, data_dir: str | os.PathLike[str], cache_size: int = 8,
                 max_triangles: int | None = None, cleanup: bool = True, parse: Parser = _parse_here) -> None:
        self.root = Path(data_dir) / "scenes"
        self.parse = parse
        self.root.mkdir(parents=True, exist_ok=True)
        self.cache_size = max(1, int(cache_size))
        self.max_triangles = max_triangles
        self._lock = threading.Lock()
        self._cache: OrderedDict[str, Scene] = OrderedDict()
        self._load_locks: dict[str, threading.Lock] = {}
        self._defaults: dict[str, SceneMeta] = {}
        self.loads = 0  # number of Scene parses/builds (for tests and metrics)
        if cleanup:  # not in a reader (a worker process) beside the store that writes
            self._cleanup_temp()
        self._register_builtins()

    # --- start-up ----------------------------------------------------------------
    def _cleanup_temp(self) -> None:
        """Remove half-written or half-deleted directories left by a crash."""
        for p in self.root.iterdir():
            if p.name.startswith((_TMP_PREFIX, _DEL_PREFIX)):
                shutil.rmtree(p, ignore_errors=True)

    def _register_builtins(self) -> None:
        """Metadata for every built-in at default parameters. No geometry is built:
        the triangle count is ``estimate_triangles`` until the scene is first built."""
        now = time.time()
        for name in builtin_scenes.BUILTIN_NAMES:
            params = normalise_builtin_params(None)
            sid = builtin_id(name, params)
            estimate = int(builtin_scenes.estimate_triangles(name, params["detail"]))
            self._defaults[sid] = SceneMeta(
                id=sid, kind="builtin", name=name, triangles=estimate, created_at=now, builtin=name,
                params=params, description=builtin_description(name), default=True, triangles_estimated=True)

    # --- paths ---------------------------------------------------------------------
    def _dir(self, scene_id: str) -> Path:
        return self.root / validate_id(scene_id)

    def _read_meta(self, scene_id: str) -> SceneMeta:
        """Meta of a stored scene; SceneNotFound if absent, ValueError/OSError if corrupt."""
        path = self._dir(scene_id) / "meta.json"
        try:
            raw = path.read_bytes()
        except FileNotFoundError:
            raise SceneNotFound(f"scene {scene_id} not found") from None
        meta = SceneMeta.from_dict(json.loads(raw))
        if meta.id != scene_id:
            raise ValueError(f"meta.json id {meta.id} does not match its directory")
        return meta

    def _put(self, meta: SceneMeta, files: Mapping[str, bytes], tries: int = 3) -> tuple[SceneMeta, bool]:
        """Store a scene: (meta, True), or (the stored meta, False) when it was there
        already. A concurrent DELETE of the same id between the write and the read is
        retried (the answer was a 404 to the POST)."""
        for attempt in range(tries):
            try:
                if self._write_new(meta, files):
                    return meta, True
                return self._read_meta(meta.id), False
            except (SceneNotFound, FileNotFoundError):
                if attempt == tries - 1:
                    raise
        raise AssertionError("unreachable")

    def _write_new(self, meta: SceneMeta, files: Mapping[str, bytes]) -> bool:
        """Create the scene directory atomically. Returns False if it already
        existed with readable meta (content-addressed: nothing to do)."""
        final = self._dir(meta.id)
        tmp = self.root / f"{_TMP_PREFIX}{uuid.uuid4().hex}"
        tmp.mkdir()
        try:
            for fname, data in files.items():
                _atomic_write(tmp / fname, data)
            _atomic_write(tmp / "meta.json", json.dumps(meta.to_dict(), indent=1).encode())
            _fsync_dir(tmp)
            try:
                os.rename(tmp, final)
            except OSError:
                if not final.is_dir():
                    raise
                # Already there (a concurrent identical upload, or an earlier one):
                # keep it unless its meta is unreadable, in which case repair in place.
                try:
                    self._read_meta(meta.id)
                    return False
                except (SceneNotFound, ValueError, OSError):
                    log.warning("repairing scene %s (unreadable meta.json)", meta.id)
                    for fname, data in files.items():
                        _atomic_write(final / fname, data)
                    _atomic_write(final / "meta.json", json.dumps(meta.to_dict(), indent=1).encode())
            _fsync_dir(self.root)
            return True
        finally:
            if tmp.exists():
                shutil.rmtree(tmp, ignore_errors=True)

    # --- queries -----------------------------------------------------------------
    def list(self) -> list[SceneMeta]:
        """Built-in defaults (by name), then stored scenes (oldest first). Entries
        whose meta.json is unreadable are logged and skipped."""
        out = sorted(self._defaults.values(), key=lambda m: m.name)
        stored = []
        for p in self.root.iterdir():
            if not ID_RE.fullmatch(p.name) or not p.is_dir():
                continue
            try:
                stored.append(self._read_meta(p.name))
            except SceneNotFound:
                log.warning("skipping scene directory %s without meta.json", p.name)
            except Exception as exc:  # noqa: BLE001 - a bad entry must not break listing
                log.warning("skipping scene %s with unreadable meta.json: %s", p.name, exc)
        return out + sorted(stored, key=lambda m: (m.created_at, m.id))

    def get_meta(self, scene_id: str) -> SceneMeta:
        """Meta of one scene; InvalidSceneId / SceneNotFound otherwise."""
        validate_id(scene_id)
        if scene_id in self._defaults:
            return self._defaults[scene_id]
        try:
            return self._read_meta(scene_id)
        except SceneNotFound:
            raise
        except Exception as exc:  # noqa: BLE001
            log.warning("scene %s has an unreadable meta.json: %s", scene_id, exc)
            raise SceneNotFound(f"scene {scene_id} not found") from None

    def __contains__(self, scene_id: object) -> bool:
        try:
            self.get_meta(scene_id)  # type: ignore[arg-type]
            return True
        except (InvalidSceneId, SceneNotFound):
            return False

    def count(self) -> int:
        """Number of scenes a listing would return."""
        return len(self.list())

    @property
    def cached(self) -> int:
        with self._lock:
            return len(self._cache)

    # --- adding scenes ---------------------------------------------------------------
    def _check_triangles(self, n: int, what: str) -> None:
        if self.max_triangles is not None and n > self.max_triangles:
            raise TriangleLimitExceeded(f"{what} has {n:,} triangles, limit is {self.max_triangles:,}")

    def stored_upload(self, data: bytes, fmt: str) -> tuple[str, SceneMeta | None]:
        """(the id of `data` as a `fmt` upload, its meta when it is stored already
        (readable), else None): `put_upload` answers it without a parse, and given
        the id does not hash the data again. Raises UnsupportedFormat."""
        sid = upload_id(_upload_format(fmt), data)
        return sid, self._stored(sid)

    def _stored(self, sid: str) -> SceneMeta | None:
        """The meta of the upload `sid`, or None: not stored, or an unreadable entry
        (logged; `put_upload` re-creates it)."""
        try:
            return self._read_meta(sid)
        except SceneNotFound:
            return None
        except Exception as exc:  # noqa: BLE001 - corrupt entry: rebuilt by put_upload
            log.warning("scene %s: unreadable meta.json (%s); re-creating it", sid, exc)
            return None

    def put_upload(self, data: bytes, fmt: str, name: str | None = None,
                   sid: str | None = None) -> tuple[SceneMeta, bool]:
        """Parse and store an uploaded file. Returns (meta, created). sid: the id
        `stored_upload` gave for the same data and format (else it is hashed here).
        Raises UnsupportedFormat, SceneLoadError (from the loader) or TriangleLimitExceeded."""
        fmt = _upload_format(fmt)
        sid = sid or upload_id(fmt, data)
        known = self._stored(sid)
        if known is not None:
            return known, False
        display = _display_name(name, "upload")
        scene = self.parse(data, fmt, display, self.max_triangles)
        self._check_triangles(scene.n_triangles, "the uploaded scene")
        lo, hi = scene.bounds
        meta = SceneMeta(id=sid, kind="upload", name=display, triangles=scene.n_triangles, created_at=time.time(),
                         format=fmt, size_bytes=len(data), objects=len(scene.objects),
                         bounds=[[float(x) for x in lo], [float(x) for x in hi]])
        meta, created = self._put(meta, {f"source.{fmt}": data})
        self._cache_put(sid, scene)
        return meta, created

    def put_builtin(self, name: str, params: Mapping[str, Any] | None = None) -> tuple[SceneMeta, bool]:
        """Register a built-in scene with parameters (metadata only; geometry is built
        on first use). Returns (meta, created). Raises InvalidBuiltin or
        TriangleLimitExceeded (checked against the estimate; the always-available
        default entries are exempt)."""
        if name not in builtin_scenes.BUILTIN_NAMES:
            names = ", ".join(builtin_scenes.BUILTIN_NAMES)
            raise InvalidBuiltin(f"unknown built-in scene {quoted(name)}; available: {names}")
        p = normalise_builtin_params(params)
        try:
            estimate = int(builtin_scenes.estimate_triangles(name, p["detail"]))
        except ValueError as exc:
            raise InvalidBuiltin(str(exc)) from exc
        sid = builtin_id(name, p)
        if sid in self._defaults:  # always available; the limit applies to requested detail levels
            return self._defaults[sid], False
        self._check_triangles(estimate, f"built-in scene {name!r} at detail {p['detail']:g}")
        try:
            return self._read_meta(sid), False
        except SceneNotFound:
            pass
        except Exception as exc:  # noqa: BLE001
            log.warning("scene %s: unreadable meta.json (%s); re-creating it", sid, exc)
        description = builtin_description(name)
        meta = SceneMeta(id=sid, kind="builtin", name=name, triangles=estimate, created_at=time.time(),
                         builtin=name, params=p, description=description, triangles_estimated=True)
        return self._put(meta, {})

    # --- scenes ----------------------------------------------------------------------
    def _cache_put(self, scene_id: str, scene: Scene) -> None:
        with self._lock:
            self._cache[scene_id] = scene
            self._cache.move_to_end(scene_id)
            while len(self._cache) > self.cache_size:
                self._cache.popitem(last=False)

    def get_scene(self, scene_id: str) -> Scene:
        """The parsed/built Scene (lazy, LRU-cached). Raises InvalidSceneId,
        SceneNotFound, StoreCorrupted, or ValueError from a built-in's builder."""
        meta = self.get_meta(scene_id)
        with self._lock:
            if scene_id in self._cache:
                self._cache.move_to_end(scene_id)
                return self._cache[scene_id]
            load_lock = self._load_locks.setdefault(scene_id, threading.Lock())
        with load_lock:  # one parse per scene even under concurrent requests
            with self._lock:
                if scene_id in self._cache:
                    return self._cache[scene_id]
            try:
                scene = self._load(meta)
                self._cache_put(scene_id, scene)
                if meta.triangles_estimated:
                    self._record_exact(meta, scene)
            finally:
                with self._lock:
                    self._load_locks.pop(scene_id, None)
            return scene

    def _record_exact(self, meta: SceneMeta, scene: Scene) -> None:
        """Replace a built-in's estimated triangle count by the real one (and add
        object count and bounds) once it has been built."""
        lo, hi = scene.bounds
        exact = dataclasses.replace(meta, triangles=scene.n_triangles, objects=len(scene.objects),
                                    bounds=[[float(x) for x in lo], [float(x) for x in hi]],
                                    triangles_estimated=False)
        if meta.default:
            self._defaults[meta.id] = exact
            return
        try:
            _atomic_write(self._dir(meta.id) / "meta.json", json.dumps(exact.to_dict(), indent=1).encode())
        except OSError as exc:  # deleted meanwhile: nothing to update
            log.debug("could not update meta of %s: %s", meta.id, exc)

    def _load(self, meta: SceneMeta) -> Scene:
        self.loads += 1
        if meta.kind == "builtin":
            p = meta.params or {}
            return builtin_scenes.make_builtin(meta.builtin, detail=float(p.get("detail", 1.0)),
                                                  seed=int(p.get("seed", 0)))
        path = self._dir(meta.id) / f"source.{meta.format}"
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise StoreCorrupted(f"scene {meta.id}: cannot read its source file: {exc}") from exc
        if upload_id(meta.format, data) != meta.id:
            raise StoreCorrupted(f"scene {meta.id}: source file does not match its id")
        try:
            return self.parse(data, meta.format, meta.name, None)
        except (ParseTimeLimit, ParseMemoryLimit):  # the limit, not the stored file (422 naming it)
            raise
        except loaders.SceneLoadError as exc:
            raise StoreCorrupted(f"scene {meta.id}: stored source no longer loads: {exc}") from exc

    # --- deleting ----------------------------------------------------------------------
    def delete(self, scene_id: str) -> SceneMeta:
        """Delete a stored scene (atomic: renamed away, then removed). Built-in
        defaults raise SceneProtected. Returns the deleted scene's meta."""
        validate_id(scene_id)
        if scene_id in self._defaults:
            raise SceneProtected("built-in default scenes are always available and cannot be deleted")
        final = self._dir(scene_id)
        try:
            meta = self._read_meta(scene_id)
        except SceneNotFound:
            raise
        except Exception:  # noqa: BLE001 - a corrupt entry can still be deleted
            meta = None
        trash = self.root / f"{_DEL_PREFIX}{uuid.uuid4().hex}"
        try:
            os.rename(final, trash)
        except FileNotFoundError:
            raise SceneNotFound(f"scene {scene_id} not found") from None
        shutil.rmtree(trash, ignore_errors=True)
        with self._lock:
            self._cache.pop(scene_id, None)
        if meta is None:
            meta = SceneMeta(id=scene_id, kind="upload", name="(corrupt)", triangles=0, created_at=0.0)
        return meta

"""Scene loaders: glTF/GLB, OBJ(+MTL) and PLY files -> :class:`scenes.model.Scene`, through trimesh.

Units are whatever the file uses (glTF: metres; OBJ/PLY: arbitrary); nothing is rescaled.
Every loaded object is a triangle mesh in world space:

* vertices (V,3) float32, faces (F,3) uint32 counter-clockwise front faces,
  normals (V,3) float32 unit vertex normals (never NaN);
* glTF/GLB: one object per mesh-node instance (each primitive of a glTF mesh is its own
  object, as trimesh splits them), node world transform applied; normals transformed by the
  inverse transpose; winding flipped where the transform mirrors (det < 0). Primitives
  without NORMAL get flat normals, as the glTF spec requires.
* OBJ: one object per (object, material) split; MTL ``Kd`` -> albedo, ``Pm``/``Pr`` (PBR
  extension) -> specular / glossiness (else s = 0, g = 1). Missing normals are computed
  area-weighted over position-welded vertices (no shading seams at UV seams).
* PLY: a single object; mean vertex (or face) colour, taken as 8-bit sRGB -> linear albedo.

Materials follow DESIGN.md: albedo is linear RGB; from glTF PBR baseColorFactor -> albedo
(times the mean linear colour of a baseColorTexture), metallicFactor -> specular s,
roughnessFactor -> glossiness g, glTF spec defaults (1.0) when a factor is absent. A mesh with
no material at all gets albedo 0.8 grey, s = 0, g = 1.

glTF documents are checked and their node hierarchies flattened before trimesh reads them
(:mod:`scenes.gltf`); trimesh's random names for a mesh's primitives are made serial.

Malformed input of any kind raises :class:`SceneLoadError` (a ``ValueError``). trimesh is
never given a URL nor ``allow_remote``; bytes uploads get no resolver at all, so references
to external files (buffers, textures, MTL) fail or are skipped instead of being fetched.
"""

from __future__ import annotations

import io
import itertools
import json
import struct
import threading
from collections import Counter
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from scenes import gltf, obj, ply
from scenes.excerpts import cut, quoted
from scenes.model import Material, Scene, SceneObject

__all__ = ["SUPPORTED_FORMATS", "SceneLoadError", "TriangleLimitError", "load_scene", "load_scene_bytes"]

SUPPORTED_FORMATS = ("glb", "gltf", "obj", "ply")

#: Largest object count a scene may have (object ids are uint16, 0 = none).
_MAX_OBJECTS = 65534
#: Material for meshes the file gives no material (s = 0: not reflective).
_DEFAULT_MATERIAL = Material(albedo=(0.8, 0.8, 0.8), specular=0.0, glossiness=1.0)
#: Textures are shrunk to at most this many pixels per side before averaging.
_TEXTURE_AVERAGE_SIZE = 256
#: Most pixels of one texture (8192²): a larger one is refused, since its pixels, not
#: its compressed size, set the memory a load takes.
MAX_TEXTURE_PIXELS = 8192 * 8192
#: Most parts of an uploaded scene: glTF nodes, OBJ objects (``o`` statements). Parsing
#: time grows with them, not with the file's size (a 41 MB GLB of 800,000 nodes instancing
#: one triangle took 139 s to load, longer than a render job may take to reload it).
MAX_PARTS = 10_000
#: Largest |coordinate| of an uploaded scene (cameras framing it stay within the
#: service's ±1e12 camera coordinates).
MAX_COORDINATE = 1e11
#: Smallest bounding-box diagonal of an uploaded scene: GL depth images of a scene
#: 1e-8 across came back empty (1e-6 across rendered).
MIN_EXTENT = 1e-5
#: Smallest diagonal relative to the largest |coordinate| (float32 vertices resolve
#: 6e-8 of it: a millionth is about 17 steps across the whole scene).
MIN_RELATIVE_EXTENT = 1e-6
#: Where a texture's mean is kept in its PIL image's ``info`` (materials share images).
_MEAN_KEY = "depthview_mean_linear"


class SceneLoadError(ValueError):
    """The data cannot be turned into a Scene; the message says what is wrong."""


class TriangleLimitError(SceneLoadError):
    """The scene has more triangles than max_triangles (n_triangles is exact, or a lower
    bound when counted from a header). A SceneLoadError, so callers may ignore the difference."""

    def __init__(self, message: str, n_triangles: int, limit: int) -> None:
        super().__init__(message)
        self.n_triangles = n_triangles
        self.limit = limit

    def __reduce__(self) -> tuple:  # picklable: the upload parser sends it between processes
        return type(self), (str(self), self.n_triangles, self.limit)


# --------------------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------------------
def load_scene_bytes(data: bytes, fmt: str, name: str = "upload", max_triangles: int | None = None) -> Scene:
    """Load a scene from in-memory file contents.

    data: the whole file (GLB, glTF JSON with embedded ``data:`` buffers, OBJ or PLY).
    fmt: one of SUPPORTED_FORMATS (case-insensitive, a leading dot is ignored).
    max_triangles: reject scenes with more triangles (checked from headers before decoding
    where the format allows, and again exactly after loading).
    External references (an OBJ's MTL, a glTF's external buffers/images) are not resolved.
    """
    return _load(data, fmt, name=name, max_triangles=max_triangles, resolver=None)


def load_scene(path: str | Path, max_triangles: int | None = None) -> Scene:
    """Load a scene file; the format comes from the suffix. Files next to it (an OBJ's
    MTL and textures, a glTF's buffers and images) are read from the local file system only.
    The scene is named after the file stem. An unreadable file raises SceneLoadError."""
    path = Path(path)
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in SUPPORTED_FORMATS:
        raise SceneLoadError(
            f"unsupported format {path.suffix or '(no suffix)'!r} for {path.name}; "
            f"supported: {', '.join(SUPPORTED_FORMATS)}"
        )
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise SceneLoadError(f"cannot read {path}: {exc}") from exc
    from trimesh.resolvers import FilePathResolver

    return _load(data, fmt, name=path.stem, max_triangles=max_triangles, resolver=FilePathResolver(str(path)))


# --------------------------------------------------------------------------------------
# driver
# --------------------------------------------------------------------------------------
def _load(data: bytes, fmt: str, name: str, max_triangles: int | None, resolver: object | None) -> Scene:
    fmt = str(fmt).lower().lstrip(".")
    if fmt not in SUPPORTED_FORMATS:
        raise SceneLoadError(f"unsupported format {fmt!r}; supported: {', '.join(SUPPORTED_FORMATS)}")
    if max_triangles is not None and max_triangles < 1:
        raise SceneLoadError(f"max_triangles must be positive, got {max_triangles}")
    label = fmt.upper() if fmt != "gltf" else "glTF"
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise SceneLoadError(f"{label} data must be bytes, got {type(data).__name__}")
    data = bytes(data)
    if not data.strip():
        raise SceneLoadError(f"empty {label} data")

    # cheap header checks before trimesh decodes anything
    gltf_header = None
    if fmt in ("glb", "gltf"):
        gltf_header = _gltf_json(data, fmt)
        data = _gltf_prepared(data, gltf_header, label, max_triangles)
    elif fmt == "obj":
        try:
            data = obj.normalised(obj.text(data))
        except obj.ObjError as exc:
            raise SceneLoadError(f"malformed OBJ: {exc}") from None
        _check_limit(obj.triangle_count(data), max_triangles, estimate=False)
        parts = obj.part_count(data)
        if parts > MAX_PARTS:
            raise SceneLoadError(f"OBJ has {parts:,} parts (objects × materials, from its 'o' and 'usemtl' lines), "
                                 f"limit is {MAX_PARTS:,}")
    else:
        data = _ply_readable(data, max_triangles)

    tm_scene = _trimesh_load(data, fmt, label, resolver)
    try:
        objects, flattened_by = _convert(tm_scene, fmt, gltf_header, max_triangles)
    except SceneLoadError:
        raise
    except Exception as exc:  # trimesh visuals/graph on malformed data, numpy errors
        raise SceneLoadError(f"malformed {label}: {_library_text(exc)}") from exc

    if not objects:
        problem = obj.face_problem(data) if fmt == "obj" else None  # trimesh drops such faces silently
        if flattened_by:
            problem = (f"mesh instance{'s' if len(flattened_by) > 1 else ''} {quoted(', '.join(sorted(flattened_by)))} "
                       "had triangles, but a node transform that scales them flat (a zero scale)")
        raise SceneLoadError(f"{label} has no faces (no non-degenerate triangles)"
                             + (f": its {problem}" if problem else ""))
    total = sum(o.n_triangles for o in objects)
    _check_limit(total, max_triangles, estimate=False)
    if len(objects) > _MAX_OBJECTS:
        objects = _merge_by_material(objects)
    if len(objects) > _MAX_OBJECTS:
        raise SceneLoadError(f"scene has {len(objects):,} distinct materials, limit is {_MAX_OBJECTS:,}")
    try:
        scene = Scene(objects=objects, name=name)
    except ValueError as exc:
        raise SceneLoadError(f"invalid scene: {exc}") from exc
    _check_extent(scene)
    return scene


def _check_extent(scene: Scene) -> None:
    """SceneLoadError unless the scene's coordinates are within ±MAX_COORDINATE and its
    bounding-box diagonal is at least MIN_EXTENT and MIN_RELATIVE_EXTENT × its largest
    coordinate (float32 vertices)."""
    lo, hi = scene.bounds
    largest = float(max(np.abs(lo).max(), np.abs(hi).max()))
    diagonal = float(np.linalg.norm(hi - lo))
    if largest > MAX_COORDINATE:
        raise SceneLoadError(f"scene coordinates reach {largest:.3g}, beyond ±{MAX_COORDINATE:.0e}")
    if diagonal < MIN_EXTENT or diagonal < MIN_RELATIVE_EXTENT * largest:
        raise SceneLoadError(f"scene is {diagonal:.3g} across (its bounding box's diagonal) at coordinates up to "
                             f"{largest:.3g}: below {MIN_EXTENT:.0e} or a millionth of its distance from the "
                             "origin, too small to render; scale it up or move it to the origin")


def _check_limit(n_triangles: int | None, max_triangles: int | None, estimate: bool) -> None:
    if n_triangles is None or max_triangles is None or n_triangles <= max_triangles:
        return
    what = "at least " if estimate else ""
    raise TriangleLimitError(
        f"scene has {what}{n_triangles:,} triangles, limit is {max_triangles:,}", n_triangles, max_triangles
    )


_SERIAL = itertools.count()


def _serial_id(length: int = 12) -> str:
    """trimesh.util.unique_id without collisions (installed by `_trimesh_load`):
    trimesh names a glTF mesh's primitives f"{node}_{unique_id(length=6)}", and
    random 6-hex-digit names collide (about half the loads of 5,000 primitives), each
    collision dropping a primitive, different ones each load. Unique in the process."""
    return f"{next(_SERIAL):0{length}x}"


_NAMES = threading.local()  # .counts: this thread's load's unique_name counts, by collection
_TRIMESH_UNIQUE_NAME: Callable[..., str] | None = None


def _unique_name(start: str | None, contains, counts: dict | None = None) -> str:
    """trimesh.util.unique_name (installed by `_trimesh_load`) remembering, within one
    load, the last number it gave each name, as trimesh's own ``counts`` argument
    does: without it each repeated name scanned every number before (an OBJ whose
    parts share a name, e.g. no materials: 20,000 parts took 148 s)."""
    memo = getattr(_NAMES, "counts", None)
    if counts is None and memo is not None:
        counts = memo.setdefault(id(contains), {})
    assert _TRIMESH_UNIQUE_NAME is not None  # set when installed
    return _TRIMESH_UNIQUE_NAME(start, contains, counts)


_PATCH_LOCK = threading.Lock()


def _patch_trimesh(trimesh) -> None:
    """Install `_unique_name` and `_serial_id` in trimesh.util, once per process
    (under a lock: two first loads must not keep each other's patch as the original)."""
    global _TRIMESH_UNIQUE_NAME
    with _PATCH_LOCK:
        if _TRIMESH_UNIQUE_NAME is None:
            _TRIMESH_UNIQUE_NAME = trimesh.util.unique_name
            trimesh.util.unique_name = _unique_name
            trimesh.util.unique_id = _serial_id


def _trimesh_load(data: bytes, fmt: str, label: str, resolver: object | None):
    """trimesh.Scene from bytes; every failure becomes SceneLoadError."""
    import trimesh

    _patch_trimesh(trimesh)
    kwargs: dict = {"process": False}
    if fmt == "obj":
        # one mesh per (object, material); keep faces as written
        kwargs.update(group_material=True, split_objects=True, split_groups=False)
    _NAMES.counts = {}
    try:
        scene = trimesh.load_scene(
            io.BytesIO(data), file_type=fmt, resolver=resolver, allow_remote=False, **kwargs
        )
    except SceneLoadError:
        raise
    except Exception as exc:  # trimesh raises anything from KeyError to struct.error
        msg = _library_text(exc)
        if isinstance(exc, TypeError) and "NoneType" in str(exc) and resolver is None:
            msg = "references an external file (not allowed for in-memory data)"
        elif fmt == "obj":
            msg = obj.face_problem(data) or msg
        elif fmt == "ply":
            msg = ply.ascii_value_problem(data) or msg
        raise SceneLoadError(f"malformed {label}: {msg}") from exc
    finally:
        _NAMES.counts = None
    if not isinstance(scene, trimesh.Scene):
        raise SceneLoadError(f"malformed {label}: trimesh returned {type(scene).__name__}")
    return scene


#: Longest part of a library's exception text an error repeats (it may quote the file).
LIBRARY_TEXT_CHARS = 80


def _library_text(exc: Exception) -> str:
    """'Type: message' of a library's exception, the message cut to LIBRARY_TEXT_CHARS."""
    return f"{type(exc).__name__}: {cut(str(exc), LIBRARY_TEXT_CHARS)}"


# --------------------------------------------------------------------------------------
# header checks (before decoding)
# --------------------------------------------------------------------------------------
def _gltf_json(data: bytes, fmt: str) -> dict:
    """The glTF JSON document of a GLB container or a .gltf file."""
    if fmt == "glb" or data[:4] == b"glTF":
        if len(data) < 20:
            raise SceneLoadError(f"malformed GLB: {len(data)} bytes is shorter than the 20-byte header")
        magic, version, length = struct.unpack_from("<4sII", data, 0)
        if magic != b"glTF":
            raise SceneLoadError(f"malformed GLB: bad magic {magic!r} (expected b'glTF')")
        if version != 2:
            raise SceneLoadError(f"malformed GLB: container version {version}, only glTF 2 is supported")
        if length > len(data):
            raise SceneLoadError(f"malformed GLB: header says {length:,} bytes, got {len(data):,} (truncated?)")
        chunk_len, chunk_type = struct.unpack_from("<II", data, 12)
        if chunk_type != 0x4E4F534A:  # 'JSON'
            raise SceneLoadError("malformed GLB: first chunk is not JSON")
        if 20 + chunk_len > len(data):
            raise SceneLoadError("malformed GLB: JSON chunk runs past the end of the data")
        raw = data[20 : 20 + chunk_len]
        label = "GLB"
    else:
        raw = data
        label = "glTF"
    try:
        header = json.loads(raw.decode("utf-8-sig"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SceneLoadError(f"malformed {label}: JSON header does not parse: {exc}") from exc
    if not isinstance(header, dict):
        raise SceneLoadError(f"malformed {label}: JSON header is not an object")
    version = str(header.get("asset", {}).get("version", "")) if isinstance(header.get("asset"), dict) else ""
    if not version.startswith("2"):
        raise SceneLoadError(f"malformed {label}: asset.version is {quoted(version) if version else 'missing'}, "
                             "only glTF 2 is supported")
    return header


def _gltf_prepared(data: bytes, header: dict, label: str, max_triangles: int | None) -> bytes:
    """The glTF's bytes for trimesh, once its buffers, accessors, limits and features
    pass (scenes.gltf), its hierarchy flattened. Any failure is a SceneLoadError: the
    document's values may be of any JSON type."""
    try:
        problem = gltf.buffer_problem(header, label) or gltf.accessor_problem(header, label)
        if problem:
            raise SceneLoadError(f"malformed {problem}")
        _check_gltf_header(header, label, max_triangles)
        problem = gltf.unsupported_features(header, label)
        if problem:
            raise SceneLoadError(problem)
        flat = gltf.flattened(header)
    except SceneLoadError:
        raise
    except gltf.GltfError as exc:
        raise SceneLoadError(f"malformed {label}: {exc}") from None
    except (TypeError, ValueError, KeyError, AttributeError, IndexError) as exc:
        raise SceneLoadError(f"malformed {label}: {_library_text(exc)}") from None
    return data if flat is None else gltf.repacked(data, flat)


def _check_gltf_header(header: dict, label: str, max_triangles: int | None) -> None:
    nodes = header.get("nodes", [])
    if isinstance(nodes, list) and len(nodes) > MAX_PARTS:
        raise SceneLoadError(f"{label} has {len(nodes):,} nodes, limit is {MAX_PARTS:,}")
    meshes = header.get("meshes", [])
    n_meshes = len(meshes) if isinstance(meshes, list) else 0
    for i, node in enumerate(nodes if isinstance(nodes, list) else []):
        mesh = node.get("mesh") if isinstance(node, dict) else None
        if mesh is not None and not (isinstance(mesh, int) and 0 <= mesh < n_meshes):
            raise SceneLoadError(f"{label} node {i} refers to mesh {str(mesh)[:20]}; the file has {n_meshes} "
                                 f"mesh{'es' if n_meshes != 1 else ''}")
    if max_triangles is not None:
        try:
            count, complete = gltf.triangle_count(header, stop_above=max_triangles)
        except Exception:  # malformed structure: trimesh will report it
            count, complete = None, True
        _check_limit(count, max_triangles, estimate=not complete)


def _ply_readable(data: bytes, max_triangles: int | None) -> bytes:
    """The PLY header's face count against the limit (a lower bound on its triangles),
    then its body row by row against its header (:mod:`scenes.ply`); the bytes trimesh
    is to read."""
    try:
        header = ply.read_header(data)
        faces = header.element("face")
        _check_limit(faces.count if faces else None, max_triangles, estimate=True)
        return ply.readable(data, header, lambda n: _check_limit(n, max_triangles, estimate=False))
    except ply.PlyError as exc:
        raise SceneLoadError(f"malformed PLY: {exc}") from None


# --------------------------------------------------------------------------------------
# trimesh.Scene -> SceneObjects
# --------------------------------------------------------------------------------------
def _convert(tm_scene, fmt: str, gltf_header: dict | None,
             max_triangles: int | None) -> tuple[list[SceneObject], list[str]]:
    """The scene's objects, and the names of the mesh instances a singular node
    transform (a zero scale) left without area."""
    import trimesh

    header_materials: dict[str, dict] = {}
    header_node_names: set[str] = set()
    if gltf_header is not None:
        mats = [m for m in gltf_header.get("materials", []) if isinstance(m, dict)]
        names = Counter(m.get("name") for m in mats)
        header_materials = {m["name"]: m for m in mats if m.get("name") and names[m["name"]] == 1}
        header_node_names = {n.get("name") for n in gltf_header.get("nodes", []) if isinstance(n, dict)}

    geometry = tm_scene.geometry
    instances = tm_scene.graph.nodes_geometry
    if len(instances) > MAX_PARTS:
        raise SceneLoadError(f"scene has {len(instances):,} mesh instances, limit is {MAX_PARTS:,}")
    uses: dict[str, int] = {}
    for node in instances:
        uses[tm_scene.graph[node][1]] = uses.get(tm_scene.graph[node][1], 0) + 1

    # the limit again, instance by instance, before any per-object work
    _check_limit(sum(len(getattr(geometry.get(tm_scene.graph[n][1]), "faces", ())) for n in instances),
                 max_triangles, estimate=False)

    objects: list[SceneObject] = []
    flattened_by: list[str] = []  # instances left without area by a singular transform (a zero scale)
    used_names: set[str] = set()
    material_cache: dict[int, Material] = {}
    for node in instances:
        transform, geom_name = tm_scene.graph[node]
        mesh = geometry.get(geom_name)
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            continue  # points, lines, empty meshes
        if node in header_node_names and node != geom_name:
            obj_name = str(node)
        elif uses[geom_name] > 1:
            obj_name = f"{geom_name}@{node}"
        else:
            obj_name = str(geom_name)
        obj_name = _unique(obj_name, used_names)

        key = id(mesh.visual)
        if key not in material_cache:
            material_cache[key] = _material(mesh, fmt, header_materials)
        matrix = np.asarray(transform, dtype=np.float64)
        obj = _mesh_object(mesh, matrix, fmt, obj_name, material_cache[key])
        if obj is not None:
            objects.append(obj)
        elif np.linalg.matrix_rank(matrix[:3, :3]) < 3:
            flattened_by.append(obj_name)
    return objects, flattened_by


def _unique(name: str, used: set[str]) -> str:
    out, k = name, 1
    while out in used:
        out, k = f"{name}_{k}", k + 1
    used.add(out)
    return out


def _provided_normals(mesh) -> np.ndarray | None:
    """Vertex normals the file gave (trimesh keeps them in its cache), else None."""
    cache = getattr(mesh, "_cache", None)
    store = getattr(cache, "cache", None)
    if isinstance(store, dict) and "vertex_normals" in store:
        normals = np.asarray(store["vertex_normals"], dtype=np.float64)
        if normals.shape == np.shape(mesh.vertices):
            return normals
    return None


def _mesh_object(mesh, transform: np.ndarray, fmt: str, name: str, material: Material) -> SceneObject | None:
    """One world-space SceneObject from a trimesh mesh instance; None if nothing is left
    after dropping degenerate faces."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
    if len(vertices) == 0 or faces.min() < 0 or faces.max() >= len(vertices):
        raise SceneLoadError(f"malformed {fmt.upper()}: object {quoted(name)} has face indices out of range")
    normals = _provided_normals(mesh)

    if transform.shape != (4, 4) or not np.all(np.isfinite(transform)):
        raise SceneLoadError(f"object {quoted(name)}: non-finite node transform")
    linear = transform[:3, :3]
    if not np.allclose(transform, np.eye(4)):
        vertices = vertices @ linear.T + transform[:3, 3]
        if normals is not None:
            try:
                normals = normals @ np.linalg.inv(linear)  # (M^-T n)^T = n^T M^-1
            except np.linalg.LinAlgError:
                normals = None  # singular transform: recompute below
        if np.linalg.det(linear) < 0:
            faces = faces[:, [0, 2, 1]]  # a mirroring transform turns CCW into CW

    # referenced vertices only, finite as float32
    used = np.unique(faces)
    remap = np.full(len(vertices), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    vertices = vertices[used].astype(np.float32)
    faces = remap[faces]
    if normals is not None:
        normals = normals[used]
    if not np.all(np.isfinite(vertices)):
        raise SceneLoadError(f"object {quoted(name)} has non-finite vertex coordinates")

    # drop degenerate faces (repeated index or zero area in float32)
    v64 = vertices.astype(np.float64)
    cross = np.cross(v64[faces[:, 1]] - v64[faces[:, 0]], v64[faces[:, 2]] - v64[faces[:, 0]])
    area2 = np.linalg.norm(cross, axis=1)
    keep = (
        (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
        & np.isfinite(area2) & (area2 > 0)
    )
    if not keep.any():
        return None
    if not keep.all():
        faces, cross = faces[keep], cross[keep]
        used = np.unique(faces)
        remap = np.full(len(vertices), -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        vertices, faces = vertices[used], remap[faces]
        if normals is not None:
            normals = normals[used]

    if normals is None and fmt in ("glb", "gltf"):
        # glTF spec: no NORMAL attribute -> flat shading
        vertices = vertices[faces.reshape(-1)]
        faces = np.arange(len(faces) * 3, dtype=np.int64).reshape(-1, 3)
        unit = cross / np.linalg.norm(cross, axis=1, keepdims=True)
        normals = np.repeat(unit, 3, axis=0)
    elif normals is None:
        normals = _smooth_normals(vertices, faces, cross)
    else:
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        ok = np.isfinite(length[:, 0]) & (length[:, 0] > 1e-12)
        normals = normals / np.where(ok[:, None], length, 1.0)
        if not ok.all():  # zero / NaN normals in the file: replace by computed ones
            normals[~ok] = _smooth_normals(vertices, faces, cross)[~ok]

    try:
        return SceneObject(
            name=name,
            vertices=vertices,
            faces=faces.astype(np.uint32),
            normals=normals.astype(np.float32),
            material=material,
        )
    except ValueError as exc:
        raise SceneLoadError(f"object {quoted(name)}: {exc}") from exc


def _smooth_normals(vertices: np.ndarray, faces: np.ndarray, cross: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (V,3) float64, accumulated over vertices welded by
    exact position (so split UV/normal seams shade smoothly). A vertex whose incident face
    normals cancel (e.g. back-to-back double-sided faces) gets one incident face's normal."""
    _, weld = np.unique(vertices, axis=0, return_inverse=True)
    weld = weld.reshape(-1)
    n_welded = int(weld.max()) + 1
    acc = np.zeros((n_welded, 3))
    welded_faces = weld[faces]
    for k in range(3):
        np.add.at(acc, welded_faces[:, k], cross)
    normals = acc[weld]
    length = np.linalg.norm(normals, axis=1)
    bad = ~(length > 1e-12 * max(1.0, float(np.abs(cross).max(initial=0.0))))
    normals = normals / np.where(bad, 1.0, length)[:, None]
    if bad.any():
        face_unit = cross / np.linalg.norm(cross, axis=1, keepdims=True)
        fallback = np.zeros_like(normals)
        for k in range(3):
            fallback[faces[:, k]] = face_unit
        normals[bad] = fallback[bad]
    return normals


# --------------------------------------------------------------------------------------
# materials
# --------------------------------------------------------------------------------------
def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _texture_mean_linear(image) -> np.ndarray | None:
    """Mean linear RGB (3,) of an sRGB texture (PIL image): texels are decoded to linear
    first, then averaged. None if the image cannot be read; SceneLoadError if it has
    more than MAX_TEXTURE_PIXELS. The image is shrunk in its own mode before any
    conversion and closed after (trimesh keeps it in its material: 40 decoded 8000²
    textures held 2 GiB), its mean kept in its ``info`` for other materials using it."""
    info = getattr(image, "info", None)
    if isinstance(info, dict) and _MEAN_KEY in info:
        return info[_MEAN_KEY]
    try:
        width, height = image.size
    except Exception:
        return None
    if width * height > MAX_TEXTURE_PIXELS:
        raise SceneLoadError(f"a texture is {width}×{height} pixels, over the limit of {MAX_TEXTURE_PIXELS:,} "
                             "pixels")
    try:
        img = image if image.mode in ("RGB", "RGBA", "L", "LA") else image.convert("RGBA")
        img.thumbnail((_TEXTURE_AVERAGE_SIZE, _TEXTURE_AVERAGE_SIZE))  # JPEG: decoded at a reduced scale
        texels = np.asarray(img.convert("RGB"), dtype=np.float64).reshape(-1, 3) / 255.0
        mean = _srgb_to_linear(texels).mean(axis=0) if texels.size else None
    except Exception:
        mean = None
    finally:
        image.close()
    if isinstance(info, dict):
        info[_MEAN_KEY] = mean
    return mean


def _unit(x: object, default: float) -> float:
    try:
        v = float(x[0] if isinstance(x, (list, tuple)) else x)  # MTL values arrive as ['0.5']
    except (TypeError, ValueError, IndexError):
        return default
    return float(np.clip(v, 0.0, 1.0)) if np.isfinite(v) else default


def _rgb(x: Iterable | None, scale: float = 1.0) -> np.ndarray | None:
    if x is None:
        return None
    try:
        arr = np.asarray(x, dtype=np.float64).reshape(-1)[:3] / scale
    except (TypeError, ValueError):
        return None
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        return None
    return arr


def _make_material(albedo: np.ndarray, specular: float, glossiness: float) -> Material:
    albedo = np.clip(np.nan_to_num(albedo, nan=0.8), 0.0, 1.0)
    return Material(albedo=tuple(float(a) for a in albedo), specular=specular, glossiness=glossiness)


def _material(mesh, fmt: str, header_materials: dict[str, dict]) -> Material:
    """Material for a trimesh mesh (see the module docstring for the mapping)."""
    from trimesh.visual.color import ColorVisuals
    from trimesh.visual.material import PBRMaterial, SimpleMaterial

    visual = mesh.visual
    if isinstance(visual, ColorVisuals):
        kind = visual.kind
        if kind not in ("vertex", "face"):
            return _DEFAULT_MATERIAL
        colors = visual.vertex_colors if kind == "vertex" else visual.face_colors
        rgb = np.asarray(colors, dtype=np.float64)[:, :3] / 255.0
        # 8-bit PLY/OBJ colours are sRGB-encoded; glTF COLOR_0 is linear already
        linear = rgb if fmt in ("glb", "gltf") else _srgb_to_linear(rgb)
        return _make_material(linear.mean(axis=0), 0.0, 1.0)

    mat = getattr(visual, "material", None)
    if isinstance(mat, PBRMaterial):
        pbr = header_materials.get(mat.name or "", {}).get("pbrMetallicRoughness")
        if isinstance(pbr, dict):  # exact floats from the file (trimesh rounds colours to 8 bit)
            base = _rgb(pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0]))
            metallic = _unit(pbr.get("metallicFactor", 1.0), 1.0)
            roughness = _unit(pbr.get("roughnessFactor", 1.0), 1.0)
        else:
            base = _rgb(mat.baseColorFactor, 255.0) if mat.baseColorFactor is not None else np.ones(3)
            metallic = _unit(mat.metallicFactor if mat.metallicFactor is not None else 1.0, 1.0)
            roughness = _unit(mat.roughnessFactor if mat.roughnessFactor is not None else 1.0, 1.0)
        if base is None:
            base = np.ones(3)
        if mat.baseColorTexture is not None:
            tex = _texture_mean_linear(mat.baseColorTexture)
            if tex is not None:
                base = base * tex
        colors = getattr(visual, "vertex_attributes", {}).get("color")  # COLOR_0 beside a material
        if colors is not None and len(colors):
            c = np.asarray(colors)
            rgb = (c[:, :3] / float(np.iinfo(c.dtype).max) if np.issubdtype(c.dtype, np.integer)  # normalized
                   else c[:, :3].astype(np.float64))
            base = base * np.clip(rgb, 0.0, 1.0).mean(axis=0)  # glTF: base colour = factor × texture × COLOR_0
        return _make_material(base, metallic, roughness)

    if isinstance(mat, SimpleMaterial):
        extra = getattr(mat, "kwargs", {}) or {}
        kd = _rgb(extra.get("kd"))
        image = getattr(mat, "image", None)
        if not extra and (image is None or max(image.size) <= 2):
            return _DEFAULT_MATERIAL  # trimesh's placeholder (e.g. an OBJ with UVs but no MTL)
        if kd is None:
            kd = _rgb(mat.diffuse, 255.0)
            if kd is None:
                kd = np.asarray(_DEFAULT_MATERIAL.albedo)
        if image is not None:
            tex = _texture_mean_linear(image)
            if tex is not None:
                kd = kd * tex
        return _make_material(kd, _unit(extra.get("pm", 0.0), 0.0), _unit(extra.get("pr", 1.0), 1.0))

    if mat is not None:  # some other trimesh material: its main colour
        main = getattr(mat, "main_color", None)
        rgb = _rgb(main, 255.0) if main is not None else None
        if rgb is not None:
            return _make_material(rgb, 0.0, 1.0)
    return _DEFAULT_MATERIAL


def _merge_by_material(objects: list[SceneObject]) -> list[SceneObject]:
    """Concatenate objects that share a material (used when there are too many for uint16
    object ids). Order of first appearance is kept."""
    groups: dict[Material, list[SceneObject]] = {}
    for part in objects:
        groups.setdefault(part.material, []).append(part)
    merged = []
    for material, objs in groups.items():
        offsets = np.cumsum([0] + [len(o.vertices) for o in objs[:-1]])
        merged.append(
            SceneObject(
                name=objs[0].name if len(objs) == 1 else f"{objs[0].name}+{len(objs) - 1}",
                vertices=np.concatenate([o.vertices for o in objs]),
                faces=np.concatenate([o.faces.astype(np.int64) + off for o, off in zip(objs, offsets, strict=True)]),
                normals=np.concatenate([o.normals for o in objs]),
                material=material,
            )
        )
    return merged

"""glTF documents before trimesh decodes them: the features trimesh would get wrong
silently are refused by name (`unsupported_features`), and the node hierarchy is
flattened (`flattened`), since trimesh's scene graph composes each node's transform
along its whole path with ``np.linalg.multi_dot``, whose chain-order search is cubic
in the path's length, once per node: a 13 KB chain of 200 nested mesh nodes took
60 s to load, 500 did not load in 10 minutes.

Both work on the JSON document only (`header`, as `scenes.loaders` parsed it); no
buffer is read. `repacked` writes a changed document back into the file's bytes.
"""

from __future__ import annotations

import base64
import binascii
import json
import struct
from collections.abc import Iterator

import numpy as np

#: Extensions a file may require (``extensionsRequired``) that the loader handles,
#: or that change nothing of the geometry and average colour it reads.
SUPPORTED_REQUIRED_EXTENSIONS = frozenset({
    "KHR_materials_unlit", "KHR_materials_emissive_strength", "KHR_materials_ior", "KHR_materials_specular",
    "KHR_materials_transmission", "KHR_materials_volume", "KHR_materials_clearcoat", "KHR_materials_sheen",
    "KHR_materials_iridescence", "KHR_materials_anisotropy", "KHR_materials_dispersion",
    "KHR_materials_pbrSpecularGlossiness", "KHR_texture_transform", "KHR_materials_variants",
    "KHR_mesh_quantization",
})
#: Compressed geometry: named in its own message (decompress first).
COMPRESSION_EXTENSIONS = ("KHR_draco_mesh_compression", "EXT_meshopt_compression", "KHR_meshopt_compression")
#: Primitive modes: triangles and triangle strips load; points and lines are skipped
#: (nothing to rasterise); triangle fans are refused (trimesh drops them silently).
TRIANGLES, TRIANGLE_STRIP, TRIANGLE_FAN = 4, 5, 6
#: Bytes of an accessor component type; components of an accessor type.
_COMPONENT_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
_TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
#: A node's fields that place it (replaced by one world matrix when flattened).
_PLACEMENT = ("children", "matrix", "translation", "rotation", "scale")


class GltfError(ValueError):
    """The document uses a feature the loader cannot read faithfully, or is malformed."""


def _items(header: dict, key: str) -> list:
    value = header.get(key, [])
    return value if isinstance(value, list) else []


def _primitives(header: dict) -> Iterator[tuple[int, int, dict]]:
    """(mesh index, primitive index, primitive) of every mesh."""
    for m, mesh in enumerate(_items(header, "meshes")):
        prims = mesh.get("primitives", []) if isinstance(mesh, dict) else []
        for p, prim in enumerate(prims if isinstance(prims, list) else []):
            if isinstance(prim, dict):
                yield m, p, prim


def _read_accessors(prim: dict) -> tuple[tuple[str, object], tuple[str, object]]:
    """(what, accessor index) of the two accessors a primitive's triangles are read
    from: its POSITION attribute and its indices (None where absent)."""
    attributes = prim.get("attributes") if isinstance(prim.get("attributes"), dict) else {}
    return ("POSITION", attributes.get("POSITION")), ("indices", prim.get("indices"))


def unsupported_features(header: dict, label: str) -> str | None:
    """Why the loader cannot read this document faithfully, naming the feature and
    where it is used; None when it can. Checked: required extensions (the glTF spec:
    a loader must fail on one it does not support), compressed geometry, triangle
    fans, sparse positions or indices, normalized (quantized) positions, and morph
    targets with non-zero default weights (trimesh gets all of these wrong silently)."""
    required = [str(e) for e in _items(header, "extensionsRequired")]
    compressed = [e for e in required if e in COMPRESSION_EXTENSIONS]
    if compressed:
        return f"{label} needs unsupported extension(s) {', '.join(compressed)}; decompress it first"
    unknown = [e for e in required if e not in SUPPORTED_REQUIRED_EXTENSIONS]
    if unknown:
        names = ", ".join(repr(e[:40]) for e in unknown[:3]) + (f" and {len(unknown) - 3} more" if len(unknown) > 3
                                                                  else "")
        return f"{label} requires extension(s) {names}, which this loader does not support"
    accessors = _items(header, "accessors")
    for m, p, prim in _primitives(header):
        where = f"{label} mesh {m} primitive {p}"
        mode = prim.get("mode", TRIANGLES)
        if mode == TRIANGLE_FAN:
            return f"{where} is a triangle fan (mode 6), which this loader does not read; export triangles"
        if mode not in (TRIANGLES, TRIANGLE_STRIP):
            continue  # points and lines: skipped, nothing to rasterise
        for what, index in _read_accessors(prim):
            acc = accessors[index] if _whole(index) and index < len(accessors) else None
            if not isinstance(acc, dict):
                continue
            if "sparse" in acc:
                return f"{where}: its {what} accessor {index} is sparse, which this loader does not read"
            if what == "POSITION" and acc.get("normalized"):
                return (f"{where}: its POSITION accessor {index} is normalized (KHR_mesh_quantization), which this "
                        "loader does not read; export float or integer positions")
    meshes = _items(header, "meshes")
    for i, node in enumerate(_items(header, "nodes")):
        m = node.get("mesh") if isinstance(node, dict) else None
        mesh = meshes[m] if _whole(m) and m < len(meshes) and isinstance(meshes[m], dict) else {}
        prims = mesh.get("primitives") if isinstance(mesh.get("primitives"), list) else []
        if not any(isinstance(p, dict) and p.get("targets") for p in prims):
            continue
        weights = node.get("weights", mesh.get("weights"))  # the node's override the mesh's (the spec)
        if isinstance(weights, list) and any(w != 0 for w in weights):
            return (f"{label} node {i} shows mesh {m}'s morph targets with non-zero weights, which this loader does "
                    "not apply; bake the morph into the mesh")
    return None


def accessor_problem(header: dict, label: str) -> str | None:
    """What is wrong with the accessors the primitives' positions and indices read,
    in words naming the accessor, its buffer view or buffer; None when they fit. Each
    must have a known type, a count, and lie within its buffer view, the view within
    its buffer (trimesh failed on these with numpy's reshape or index errors, or the
    triangle limit counted a count no buffer holds)."""
    accessors, views, buffers = (_items(header, k) for k in ("accessors", "bufferViews", "buffers"))
    checked = set()
    for m, p, prim in _primitives(header):
        for what, index in _read_accessors(prim):
            if index is None and what == "indices":
                continue
            where = f"{label} mesh {m} primitive {p}: its {what} accessor {str(index)[:20]}"
            if not (_whole(index) and index < len(accessors) and isinstance(accessors[index], dict)):
                return f"{where} is not one of the file's {len(accessors)} accessors"
            if index in checked:
                continue
            checked.add(index)
            problem = _accessor_fit(accessors[index], views, buffers)
            if problem:
                return f"{where} {problem}"
    return None


def buffer_problem(header: dict, label: str) -> str | None:
    """What is wrong with a buffer embedded as a data URI (not base64, or shorter than
    its byteLength), naming the buffer; None when they decode (trimesh failed on
    these with an empty AssertionError)."""
    for i, buf in enumerate(_items(header, "buffers")):
        uri = buf.get("uri") if isinstance(buf, dict) else None
        if not isinstance(uri, str) or not uri.startswith("data:"):
            continue
        head, sep, payload = uri.partition(",")
        if not sep or not head.endswith(";base64"):
            return f"{label} buffer {i} is a data URI without ';base64,' ({head[:40]!r})"
        try:
            size = len(base64.b64decode(payload, validate=True))
        except (binascii.Error, ValueError):
            return f"{label} buffer {i} is a data URI whose base64 does not decode"
        length = buf.get("byteLength")
        if not isinstance(length, int) or size < length:
            return f"{label} buffer {i} holds {size:,} bytes, but its byteLength is {str(length)[:20]}"
    return None


def _whole(value: object) -> bool:
    """Whether `value` is a JSON whole number ≥ 0 (an index, count or byte offset)."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _accessor_fit(acc: dict, views: list, buffers: list) -> str | None:
    """Why accessor `acc` does not fit its buffer view and buffer, or None."""
    kind, shape = acc.get("componentType"), acc.get("type")
    component = _COMPONENT_BYTES.get(kind) if isinstance(kind, int) else None
    size = _TYPE_SIZES.get(shape) if isinstance(shape, str) else None
    count = acc.get("count")
    if component is None or size is None:
        return f"has componentType {str(acc.get('componentType'))[:20]} and type {str(acc.get('type'))[:20]}"
    if not _whole(count):
        return f"has count {str(count)[:20]}, not a count"
    view_index = acc.get("bufferView")
    if view_index is None:  # all zeros (the spec; sparse accessors are refused apart)
        return "has no buffer view: all its values would be zero"
    if not (_whole(view_index) and view_index < len(views) and isinstance(views[view_index], dict)):
        return f"refers to buffer view {str(view_index)[:20]}; the file has {len(views)}"
    view = views[view_index]
    element = component * size
    stride, offset = view.get("byteStride", element), acc.get("byteOffset", 0)
    if not (_whole(stride) and stride >= element) or not _whole(offset):
        return (f"has byteOffset {str(offset)[:20]} in buffer view {view_index} of byteStride {str(stride)[:20]}, "
                f"not byte counts fitting its {element}-byte elements")
    need = offset + (stride * (count - 1) + element if count else 0)
    length = view.get("byteLength")
    if not _whole(length) or need > length:
        return (f"needs {need:,} bytes ({count:,} × {acc.get('type')} of {component}-byte components), but its "
                f"buffer view {view_index} holds {str(length)[:20]}")
    buffer_index = view.get("buffer")
    if not (_whole(buffer_index) and buffer_index < len(buffers) and isinstance(buffers[buffer_index], dict)):
        return f"is in buffer view {view_index}, whose buffer {str(buffer_index)[:20]} is not one of the file's " \
               f"{len(buffers)}"
    start = view.get("byteOffset", 0)
    if not _whole(start):
        return f"is in buffer view {view_index}, whose byteOffset {str(start)[:20]} is not a byte count"
    end = start + length
    held = buffers[buffer_index].get("byteLength")
    if not _whole(held) or end > held:
        return f"is in buffer view {view_index}, which ends at byte {end:,} of buffer {buffer_index}, which holds " \
               f"{str(held)[:20]}"
    return None


def _local_matrix(node: dict, index: int) -> np.ndarray:
    """(4,4) transform of a node: its matrix (column-major) times T·R·S, as trimesh
    composes a node that has both (the spec allows one or the other)."""
    try:
        matrix = np.asarray(node.get("matrix", np.eye(4).reshape(-1)), dtype=np.float64)
        if matrix.shape != (16,):
            raise ValueError(f"matrix has {matrix.size} values, not 16")
        out = np.eye(4)
        t = np.asarray(node.get("translation", (0.0, 0.0, 0.0)), dtype=np.float64)
        x, y, z, w = np.asarray(node.get("rotation", (0.0, 0.0, 0.0, 1.0)), dtype=np.float64)
        s = np.asarray(node.get("scale", (1.0, 1.0, 1.0)), dtype=np.float64)
        if t.shape != (3,) or s.shape != (3,):
            raise ValueError("translation and scale need 3 values")
    except (TypeError, ValueError) as exc:
        raise GltfError(f"node {index} has a malformed transform: {str(exc)[:80]}") from None
    n = x * x + y * y + z * z + w * w
    q = 2.0 / n if n > 0 else 0.0
    rot = np.array([
        [1 - q * (y * y + z * z), q * (x * y - z * w), q * (x * z + y * w)],
        [q * (x * y + z * w), 1 - q * (x * x + z * z), q * (y * z - x * w)],
        [q * (x * z - y * w), q * (y * z + x * w), 1 - q * (x * x + y * y)],
    ])
    out[:3, :3] = rot * s
    out[:3, 3] = t
    return matrix.reshape(4, 4).T @ out


def _list(owner: dict, key: str, what: str) -> list:
    """owner[key] (default []), which must be a list."""
    value = owner.get(key, [])
    if not isinstance(value, list):
        raise GltfError(f"{what}'s {key} is {str(value)[:20]}, not a list")
    return value


def scene_roots(header: dict) -> list:
    """The root nodes of the default scene (``scene``, else scene 0); a file without
    scenes: the nodes no node lists as a child. GltfError when the default scene is
    not one of the file's, or a node or scene list is not a list."""
    nodes, scenes = _items(header, "nodes"), _items(header, "scenes")
    if not scenes:
        children = {c for n in nodes if isinstance(n, dict) for c in _list(n, "children", "node") if _whole(c)}
        return [i for i in range(len(nodes)) if i not in children]
    index = header.get("scene", 0)
    if not (_whole(index) and index < len(scenes) and isinstance(scenes[index], dict)):
        raise GltfError(f"its scene {str(index)[:20]} is not one of its {len(scenes)} scenes")
    return _list(scenes[index], "nodes", f"scene {index}")


def flattened(header: dict) -> dict | None:
    """A copy of `header` whose default scene (`scene_roots`; one made of them for a
    file without scenes) lists every node it reaches as a root, each with its world
    transform as its matrix and no children (node indices, names and meshes
    unchanged, so trimesh names the instances as before); None when the hierarchy is
    already flat. A node reached twice (two parents, a root that is also a child, a
    cycle: the spec makes the nodes a tree), a child list that is not a list, raise
    GltfError naming it."""
    nodes, scenes = _items(header, "nodes"), _items(header, "scenes")
    roots = scene_roots(header)
    if scenes and not any(isinstance(n, dict) and n.get("children") for n in nodes):
        return None
    world: dict[int, np.ndarray] = {}
    stack = [(r, np.eye(4)) for r in reversed(roots)]
    order = []
    while stack:
        i, parent = stack.pop()
        if not (_whole(i) and i < len(nodes)):
            raise GltfError(f"the node hierarchy refers to node {str(i)[:20]}; the file has {len(nodes)} nodes")
        if i in world:
            raise GltfError(f"node {i} is reached twice (two parents, a root that is also a child, or a cycle); "
                            "glTF nodes form trees")
        node = nodes[i] if isinstance(nodes[i], dict) else {}
        world[i] = parent @ _local_matrix(node, i)
        order.append(i)
        stack.extend((c, world[i]) for c in reversed(_list(node, "children", f"node {i}")))
    out = dict(header)
    new_nodes = list(nodes)
    for i in order:
        node = {k: v for k, v in (nodes[i] if isinstance(nodes[i], dict) else {}).items() if k not in _PLACEMENT}
        node["matrix"] = world[i].T.reshape(-1).tolist()
        new_nodes[i] = node
    out["nodes"] = new_nodes
    index = header.get("scene", 0) if scenes else 0
    out["scenes"] = [dict(s) if isinstance(s, dict) else s for s in scenes] or [{}]
    out["scenes"][index]["nodes"] = order
    out["scene"] = index
    return out


def repacked(data: bytes, header: dict) -> bytes:
    """The file's bytes with `header` as its JSON document (GLB: the JSON chunk
    replaced, the binary chunk kept; .gltf: the document itself)."""
    text = json.dumps(header, separators=(",", ":")).encode()
    if data[:4] != b"glTF":
        return text
    (json_len,) = struct.unpack_from("<I", data, 12)
    rest = data[20 + json_len:]
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + rest
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def triangle_count(header: dict, stop_above: int) -> tuple[int, bool]:
    """(triangles, complete): triangles of all mesh instances reachable from the default
    scene, from accessor counts only (no buffer is read). Counting stops (complete = False)
    once the running total passes 100 * stop_above, so deep instancing cannot stall it."""
    accessors = header.get("accessors", [])
    per_mesh = []
    for mesh in header.get("meshes", []):
        n = 0
        for prim in mesh.get("primitives", []):
            mode = prim.get("mode", 4)
            if "indices" in prim:
                count = int(accessors[prim["indices"]]["count"])
            else:
                count = int(accessors[prim["attributes"]["POSITION"]]["count"])
            n += count // 3 if mode == 4 else max(count - 2, 0) if mode in (5, 6) else 0
        per_mesh.append(n)
    nodes = header.get("nodes", [])
    total = 0
    stack = [(r, 0) for r in scene_roots(header)]
    while stack:
        idx, depth = stack.pop()
        if depth > 256:  # a cycle; the flattening refuses it
            break
        node = nodes[idx]
        if "mesh" in node:
            total += per_mesh[node["mesh"]]
            if total > 100 * stop_above:
                return total, False
        stack.extend((c, depth + 1) for c in node.get("children", []))
    return total, True

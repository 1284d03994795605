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
        attributes = prim.get("attributes") if isinstance(prim.get("attributes"), dict) else {}
        for what, index in (("POSITION", attributes.get("POSITION")), ("indices", prim.get("indices"))):
            acc = accessors[index] if isinstance(index, int) and 0 <= index < len(accessors) else None
            if not isinstance(acc, dict):
                continue
            if "sparse" in acc:
                return f"{where}: its {what} accessor {index} is sparse, which this loader does not read"
            if what == "POSITION" and acc.get("normalized"):
                return (f"{where}: its POSITION accessor {index} is normalized (KHR_mesh_quantization), which this "
                        "loader does not read; export float or integer positions")
        targets = prim.get("targets")
        weights = header["meshes"][m].get("weights")
        if targets and isinstance(weights, list) and any(w != 0 for w in weights):
            return (f"{where} has morph targets with non-zero default weights, which this loader does not apply; "
                    "bake the morph into the mesh")
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
        attributes = prim.get("attributes") if isinstance(prim.get("attributes"), dict) else {}
        for what, index in (("POSITION", attributes.get("POSITION")), ("indices", prim.get("indices"))):
            if index is None and what == "indices" or index in checked:
                continue
            where = f"{label} mesh {m} primitive {p}: its {what} accessor {str(index)[:20]}"
            if not (isinstance(index, int) and 0 <= index < len(accessors) and isinstance(accessors[index], dict)):
                return f"{where} is not one of the file's {len(accessors)} accessors"
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


def _accessor_fit(acc: dict, views: list, buffers: list) -> str | None:
    """Why accessor `acc` does not fit its buffer view and buffer, or None."""
    component = _COMPONENT_BYTES.get(acc.get("componentType"))
    size = _TYPE_SIZES.get(acc.get("type"))
    count = acc.get("count")
    if component is None or size is None:
        return f"has componentType {str(acc.get('componentType'))[:20]} and type {str(acc.get('type'))[:20]}"
    if not isinstance(count, int) or count < 0:
        return f"has count {str(count)[:20]}, not a count"
    view_index = acc.get("bufferView")
    if view_index is None:
        return None  # all zeros (the spec), or sparse: refused apart
    if not (isinstance(view_index, int) and 0 <= view_index < len(views) and isinstance(views[view_index], dict)):
        return f"refers to buffer view {str(view_index)[:20]}; the file has {len(views)}"
    view = views[view_index]
    element = component * size
    stride = view.get("byteStride") or element
    need = int(acc.get("byteOffset", 0) or 0) + (stride * (count - 1) + element if count else 0)
    length = view.get("byteLength")
    if not isinstance(length, int) or need > length:
        return (f"needs {need:,} bytes ({count:,} × {acc.get('type')} of {component}-byte components), but its "
                f"buffer view {view_index} holds {str(length)[:20]}")
    buffer_index = view.get("buffer")
    if not (isinstance(buffer_index, int) and 0 <= buffer_index < len(buffers) and isinstance(buffers[buffer_index],
                                                                                               dict)):
        return f"is in buffer view {view_index}, whose buffer {str(buffer_index)[:20]} is not one of the file's " \
               f"{len(buffers)}"
    end = int(view.get("byteOffset", 0) or 0) + length
    held = buffers[buffer_index].get("byteLength")
    if not isinstance(held, int) or end > held:
        return f"is in buffer view {view_index}, which ends at byte {end:,} of buffer {buffer_index}, which holds " \
               f"{str(held)[:20]}"
    return None


def _local_matrix(node: dict, index: int) -> np.ndarray:
    """(4,4) transform of a node from its matrix (column-major) or T·R·S."""
    try:
        if "matrix" in node:
            m = np.asarray(node["matrix"], dtype=np.float64)
            if m.shape != (16,):
                raise ValueError(f"matrix has {m.size} values, not 16")
            return m.reshape(4, 4).T
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
    return out


def flattened(header: dict) -> dict | None:
    """A copy of `header` whose default scene lists every node it reaches as a root,
    each with its world transform as its matrix and no children (node indices, names
    and meshes unchanged, so trimesh names the instances as before); None when the
    hierarchy is already flat. A file without scenes gets one of its root nodes (the
    nodes no node lists as a child), as the triangle limit counts them. A node reached
    twice (the spec forbids it) keeps its first path's transform; cycles end where
    they close."""
    nodes = _items(header, "nodes")
    scenes = _items(header, "scenes")
    index = header.get("scene", 0)
    if not scenes and nodes:
        children = {c for n in nodes if isinstance(n, dict) for c in n.get("children", [])
                    if isinstance(c, int)}
        scenes, index = [{"nodes": [i for i in range(len(nodes)) if i not in children]}], 0
    elif not scenes:
        return None
    if not isinstance(index, int) or not 0 <= index < len(scenes) or not isinstance(scenes[index], dict):
        raise GltfError(f"its scene {str(index)[:20]} is not one of its {len(scenes)} scenes")
    if "scenes" in header and not any(isinstance(n, dict) and n.get("children") for n in nodes):
        return None
    world: dict[int, np.ndarray] = {}
    stack = [(r, np.eye(4)) for r in reversed(scenes[index].get("nodes", []))]
    order = []
    while stack:
        i, parent = stack.pop()
        if not (isinstance(i, int) and 0 <= i < len(nodes)):
            raise GltfError(f"the node hierarchy refers to node {str(i)[:20]}; the file has {len(nodes)} nodes")
        if i in world:
            continue
        node = nodes[i] if isinstance(nodes[i], dict) else {}
        world[i] = parent @ _local_matrix(node, i)
        order.append(i)
        children = node.get("children", [])
        stack.extend((c, world[i]) for c in reversed(children if isinstance(children, list) else []))
    out = dict(header)
    new_nodes = list(nodes)
    for i in order:
        node = {k: v for k, v in (nodes[i] if isinstance(nodes[i], dict) else {}).items() if k not in _PLACEMENT}
        node["matrix"] = world[i].T.reshape(-1).tolist()
        new_nodes[i] = node
    out["nodes"] = new_nodes
    out["scenes"] = [dict(s) if isinstance(s, dict) else s for s in scenes]
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

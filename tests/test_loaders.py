"""scenes.loaders on the real models in ../shared/scenes and on small synthetic files."""

from __future__ import annotations

import io
import json
import re
import struct

import numpy as np
import pytest

from scenes.loaders import SUPPORTED_FORMATS, SceneLoadError, TriangleLimitError, load_scene, load_scene_bytes
from scenes.model import Scene
from tests.helpers import shared_scene


def srgb_to_linear(c):
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def check_geometry(scene: Scene) -> None:
    """Invariants every loaded scene must satisfy."""
    assert isinstance(scene, Scene) and scene.objects
    for o in scene.objects:
        assert o.vertices.dtype == np.float32 and o.faces.dtype == np.uint32 and o.normals.dtype == np.float32
        assert o.normals.shape == o.vertices.shape
        assert np.isfinite(o.vertices).all() and np.isfinite(o.normals).all()
        np.testing.assert_allclose(np.linalg.norm(o.normals, axis=1), 1.0, atol=1e-5)
        assert o.n_triangles > 0 and int(o.faces.max()) < len(o.vertices)
        assert all(0.0 <= a <= 1.0 for a in o.material.albedo)
        # no degenerate triangles survive
        v = o.vertices.astype(np.float64)
        f = o.faces.astype(np.int64)
        area2 = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
        assert (area2 > 0).all()


def outward_fraction(o) -> tuple[float, float]:
    """Fraction of faces whose CCW normal, and of vertices whose normal, points away from
    the object's centroid (for closed, roughly convex shapes)."""
    v = o.vertices.astype(np.float64)
    f = o.faces.astype(np.int64)
    c = v.mean(axis=0)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    faces_out = np.mean(np.einsum("ij,ij->i", fn, v[f].mean(axis=1) - c) > 0)
    verts_out = np.mean(np.einsum("ij,ij->i", o.normals, v - c) > 0)
    return float(faces_out), float(verts_out)


# --------------------------------------------------------------------------------------
# real models
# --------------------------------------------------------------------------------------
def test_diorama_glb_objects_and_materials():
    scene = load_scene(shared_scene("macross_diorama/scene.glb"))
    check_geometry(scene)
    assert scene.name == "scene"
    assert len(scene.objects) >= 5  # one mesh with 24 primitives -> 24 objects
    assert scene.n_triangles == 102_822
    albedos = {o.material.albedo for o in scene.objects}
    assert len(albedos) >= 10  # many distinct coloured materials
    # exact glTF floats (not trimesh's 8-bit rounding): material "mat1" baseColorFactor
    mat1 = (0.610000014, 0.150000006, 0.689999998)
    assert any(np.allclose(o.material.albedo, mat1, atol=1e-7) for o in scene.objects)
    assert all(o.material.specular == 0.0 for o in scene.objects)  # metallicFactor 0 everywhere
    assert any(abs(o.material.glossiness - 0.583820879) < 1e-6 for o in scene.objects)  # roughnessFactor of mat24
    lo, hi = scene.bounds
    assert np.all(hi > lo)


def test_glb_bytes_equals_path_load():
    path = shared_scene("macross_diorama/scene.glb")
    a = load_scene(path)
    b = load_scene_bytes(path.read_bytes(), "glb", name="diorama")
    assert b.name == "diorama"
    assert [o.name for o in a.objects] == [o.name for o in b.objects]
    np.testing.assert_array_equal(a.faces, b.faces)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    assert [o.material for o in a.objects] == [o.material for o in b.objects]


def test_quaternius_trees_materials_split():
    for stem in ("Birch_8", "Pine_1", "Tree_3"):
        scene = load_scene(shared_scene(f"quaternius_trees/{stem}.obj"))
        check_geometry(scene)
        assert len(scene.objects) == 2, stem  # bark + leaves, one usemtl each
        names = " ".join(o.name for o in scene.objects)
        assert "Bark" in names and "Leaves" in names, names
        for o in scene.objects:
            # the MTL's Kd (both materials are 0.64 grey in these files); no Pm/Pr -> s=0, g=1
            assert o.material.albedo == (0.64, 0.64, 0.64)
            assert (o.material.specular, o.material.glossiness) == (0.0, 1.0)
    # the Pine's 329 OBJ faces (quads and a 10-gon) fan-triangulate to 664 triangles
    assert load_scene(shared_scene("quaternius_trees/Pine_1.obj")).n_triangles == 664


@pytest.mark.parametrize(
    "relpath,n_tri",
    [("teapot/teapot.obj", 6320), ("spot/spot.obj", 5856), ("stanford_bunny/stanford-bunny.obj", 69451)],
)
def test_obj_without_normals_gets_computed_normals(relpath, n_tri):
    scene = load_scene(shared_scene(relpath))
    check_geometry(scene)
    assert len(scene.objects) == 1
    assert scene.n_triangles <= n_tri and scene.n_triangles >= n_tri - 50  # a few degenerate faces may go
    o = scene.objects[0]
    # computed normals agree with the faces around them: mean cosine to adjacent face normals
    v = o.vertices.astype(np.float64)
    f = o.faces.astype(np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    cos = np.einsum("ij,ij->i", o.normals[f[:, 0]].astype(np.float64), fn)
    assert np.median(cos) > 0.9
    # positions that trimesh split (UV seams on spot) share one normal
    _, inv = np.unique(o.vertices, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    first = np.full(inv.max() + 1, -1)
    first[inv[::-1]] = np.arange(len(inv))[::-1]
    np.testing.assert_allclose(o.normals, o.normals[first[inv]], atol=1e-6)


def test_too_many_objects_merge_by_material(monkeypatch):
    import scenes.loaders as loaders

    path = shared_scene("quaternius_trees/Birch_8.obj")
    full = load_scene(path)
    monkeypatch.setattr(loaders, "_MAX_OBJECTS", 1)
    merged = load_scene(path)  # both objects share Kd 0.64 -> one object
    assert len(merged.objects) == 1 and merged.n_triangles == full.n_triangles
    check_geometry(merged)
    np.testing.assert_array_equal(np.sort(merged.vertices, axis=0), np.sort(full.vertices, axis=0))
    np.testing.assert_array_equal(merged.vertices[merged.faces], full.vertices[full.faces])
    with pytest.raises(SceneLoadError, match="distinct materials"):
        load_scene(shared_scene("macross_diorama/scene.glb"))


def test_obj_mtl_kd_and_pbr_keys(tmp_path):
    (tmp_path / "two.mtl").write_text(
        "newmtl red\nKd 0.8 0.1 0.05\n\nnewmtl chrome\nKd 0.5 0.5 0.6\nPm 0.9\nPr 0.25\n"
    )
    (tmp_path / "two.obj").write_text(
        "mtllib two.mtl\n"
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 2 1 0\nv 3 3 3\n"
        "o quad\nusemtl red\nf 1 2 3 4\n"
        "o strip\nusemtl chrome\nf 2 5 6\nf 2 6 3\nf 2 2 5\n"  # last face is degenerate
    )
    scene = load_scene(tmp_path / "two.obj")
    check_geometry(scene)
    mats = {o.material.albedo: o.material for o in scene.objects}
    assert len(scene.objects) == 2 and len(mats) == 2
    red, chrome = mats[(0.8, 0.1, 0.05)], mats[(0.5, 0.5, 0.6)]
    assert (red.specular, red.glossiness) == (0.0, 1.0)
    assert (chrome.specular, chrome.glossiness) == (0.9, 0.25)
    assert scene.n_triangles == 4  # 2 from the quad + 2 (degenerate one dropped)
    for o in scene.objects:
        assert len(o.vertices) == int(o.faces.max()) + 1  # unreferenced vertex (3,3,3) gone
        np.testing.assert_allclose(o.normals, np.tile([0, 0, 1], (len(o.vertices), 1)), atol=1e-6)
    # the same OBJ as bytes: the MTL is not resolved -> default material, still loads
    plain = load_scene_bytes((tmp_path / "two.obj").read_bytes(), "obj")
    assert all(o.material.albedo == (0.8, 0.8, 0.8) for o in plain.objects)


# --------------------------------------------------------------------------------------
# synthetic GLB / PLY
# --------------------------------------------------------------------------------------
def _box_glb(include_normals: bool = True) -> bytes:
    import trimesh
    from trimesh.visual.material import PBRMaterial

    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    box.visual = trimesh.visual.TextureVisuals(
        material=PBRMaterial(name="paint", baseColorFactor=[0.25, 0.5, 0.75, 1.0], metallicFactor=0.3,
                             roughnessFactor=1.7)  # out of range on purpose: clamped to 1
    )
    sc = trimesh.Scene()
    sc.add_geometry(box, node_name="plain", geom_name="box")
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0])
    mirror[:3, 3] = [5.0, 0.0, 0.0]
    sc.add_geometry(box, node_name="mirrored", geom_name="box", transform=mirror)
    return sc.export(file_type="glb", include_normals=include_normals)


@pytest.mark.parametrize("include_normals", [True, False])
def test_glb_node_transforms_and_mirroring(include_normals):
    scene = load_scene_bytes(_box_glb(include_normals), "glb")
    check_geometry(scene)
    assert len(scene.objects) == 2
    by_name = {o.name: o for o in scene.objects}
    assert set(by_name) == {"plain", "mirrored"}
    np.testing.assert_allclose(by_name["mirrored"].vertices.mean(axis=0), [5.0, 0.0, 0.0], atol=1e-6)
    for o in scene.objects:
        faces_out, verts_out = outward_fraction(o)
        assert faces_out == 1.0 and verts_out == 1.0, o.name  # winding and normals survive the mirror
        # trimesh writes its 8-bit copy of the colour; exact floats are checked on the diorama
        assert o.material.albedo == pytest.approx((0.25, 0.5, 0.75), abs=1 / 255)
        assert (o.material.specular, o.material.glossiness) == pytest.approx((0.3, 1.0))
    if not include_normals:  # glTF without NORMAL -> flat normals, 3 vertices per triangle
        o = scene.objects[0]
        assert len(o.vertices) == 3 * o.n_triangles


def test_gltf_json_with_external_and_embedded_buffers(tmp_path):
    import trimesh

    tm = trimesh.load_scene(io.BytesIO(_box_glb()), file_type="glb")
    for name, blob in tm.export(file_type="gltf").items():  # model.gltf + external .bin buffers
        (tmp_path / name).write_bytes(blob)
    scene = load_scene(tmp_path / "model.gltf")
    check_geometry(scene)
    assert sorted(o.name for o in scene.objects) == ["mirrored", "plain"] and scene.n_triangles == 24
    # in-memory glTF may not reference files: rejected, nothing fetched
    with pytest.raises(SceneLoadError, match="external file"):
        load_scene_bytes((tmp_path / "model.gltf").read_bytes(), "gltf")
    embedded = tm.export(file_type="gltf", embed_buffers=True)["model.gltf"]
    assert load_scene_bytes(embedded, "gltf").n_triangles == 24


def test_glb_base_color_texture_mean():
    import trimesh
    from PIL import Image
    from trimesh.visual.material import PBRMaterial

    tex = np.zeros((8, 8, 3), dtype=np.uint8)
    tex[:, :4] = (255, 128, 0)
    tex[:, 4:] = (0, 128, 255)
    mesh = trimesh.creation.box()
    uv = np.random.default_rng(1).random((len(mesh.vertices), 2))
    mesh.visual = trimesh.visual.TextureVisuals(
        uv=uv, material=PBRMaterial(baseColorFactor=[0.5, 1.0, 1.0, 1.0], baseColorTexture=Image.fromarray(tex))
    )
    scene = load_scene_bytes(trimesh.Scene(mesh).export(file_type="glb"), "glb")
    expected = np.array([0.5, 1.0, 1.0]) * srgb_to_linear(tex.reshape(-1, 3) / 255.0).mean(axis=0)
    # the factor goes through trimesh's 8-bit copy when trimesh writes the GLB
    np.testing.assert_allclose(scene.objects[0].material.albedo, expected, atol=1 / 255)
    assert scene.objects[0].material.specular == 1.0  # metallicFactor absent -> glTF default 1


def _textured_boxes_glb(image, n: int = 2) -> bytes:
    """n boxes whose PBR materials share one base-colour texture `image`."""
    import trimesh
    from trimesh.visual.material import PBRMaterial

    material = PBRMaterial(baseColorTexture=image)
    boxes = []
    for i in range(n):
        box = trimesh.creation.box()
        box.apply_translation((2.0 * i, 0, 0))
        box.visual = trimesh.visual.TextureVisuals(uv=np.full((len(box.vertices), 2), 0.5), material=material)
        boxes.append(box)
    return trimesh.Scene(boxes).export(file_type="glb")


def test_a_texture_shared_by_materials_is_averaged_once_and_released():
    """A palette texture shared by two materials: both get its mean; the loader shrinks
    and closes each decoded image (trimesh keeps it in its material)."""
    from PIL import Image

    from scenes.loaders import _texture_mean_linear

    tex = np.zeros((64, 64), dtype=np.uint8)
    tex[:, 32:] = 1
    image = Image.fromarray(tex, mode="P")
    image.putpalette([255, 0, 0, 0, 0, 255] + [0] * 762)  # index 0 red, 1 blue
    scene = load_scene_bytes(_textured_boxes_glb(image), "glb")
    expected = srgb_to_linear(np.array([[1.0, 0, 0], [0, 0, 1.0]])).mean(axis=0)
    assert len(scene.objects) >= 1
    for obj in scene.objects:
        np.testing.assert_allclose(obj.material.albedo, expected, atol=1 / 255)
    big = Image.new("L", (1024, 1024), 128)
    np.testing.assert_allclose(_texture_mean_linear(big), srgb_to_linear(np.full(3, 128 / 255)), atol=1e-6)
    with pytest.raises(ValueError):  # closed: its pixels are not held
        big.getpixel((0, 0))
    np.testing.assert_allclose(_texture_mean_linear(big), srgb_to_linear(np.full(3, 128 / 255)), atol=1e-6)


def test_a_texture_over_the_pixel_limit_is_refused(monkeypatch):
    from PIL import Image

    import scenes.loaders

    monkeypatch.setattr(scenes.loaders, "MAX_TEXTURE_PIXELS", 63)
    with pytest.raises(SceneLoadError, match=r"a texture is 8×8 pixels, over the limit of 63 pixels"):
        load_scene_bytes(_textured_boxes_glb(Image.new("RGB", (8, 8)), n=1), "glb")


def test_ply_round_trip_with_vertex_colours():
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=2, radius=2.0)
    colours = np.zeros((len(mesh.vertices), 4), dtype=np.uint8)
    colours[:] = (200, 100, 50, 255)
    colours[::2, :3] = (20, 40, 250)
    mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=colours)
    for encoding in ("binary", "ascii"):
        data = mesh.export(file_type="ply", encoding=encoding)
        scene = load_scene_bytes(data, "ply", name="ico")
        check_geometry(scene)
        assert len(scene.objects) == 1
        o = scene.objects[0]
        assert o.n_triangles == len(mesh.faces) == 320
        np.testing.assert_allclose(np.sort(o.vertices, axis=0), np.sort(mesh.vertices, axis=0), atol=1e-6)
        np.testing.assert_allclose(np.linalg.norm(o.vertices, axis=1), 2.0, atol=1e-5)
        expected = srgb_to_linear(colours[:, :3] / 255.0).mean(axis=0)
        np.testing.assert_allclose(o.material.albedo, expected, atol=1e-9)
        assert outward_fraction(o) == (1.0, 1.0)


def test_load_scene_ply_file(tmp_path):
    import trimesh

    p = tmp_path / "tet.ply"
    p.write_bytes(trimesh.creation.box().export(file_type="ply"))
    scene = load_scene(p)
    assert scene.name == "tet" and scene.n_triangles == 12
    assert scene.objects[0].material.albedo == (0.8, 0.8, 0.8)  # no colours -> default


# --------------------------------------------------------------------------------------
# malformed input
# --------------------------------------------------------------------------------------
def test_supported_formats():
    assert SUPPORTED_FORMATS == ("glb", "gltf", "obj", "ply")


@pytest.mark.parametrize("fmt", SUPPORTED_FORMATS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_bytes_rejected(fmt, seed):
    data = np.random.default_rng(seed).bytes(4096)
    with pytest.raises(SceneLoadError, match=r"(?i)malformed|no faces"):
        load_scene_bytes(data, fmt)


@pytest.mark.parametrize("fmt", SUPPORTED_FORMATS)
def test_empty_rejected(fmt):
    with pytest.raises(SceneLoadError, match="empty"):
        load_scene_bytes(b"", fmt)


def test_structurally_broken_inputs():
    cases = [
        ("obj", "no faces", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n"),
        ("obj", "no faces", b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n"),  # collinear: only a degenerate face
        ("obj", "non-finite", b"v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n"),
        ("obj", "binary", b"\x00\x01\x02" * 100),
        ("ply", "malformed PLY", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n2\n3\n"),
        ("glb", "truncated", _box_glb()[:200]),
        ("glb", "magic", b"GLTF" + bytes(40)),
        ("gltf", "malformed glTF", b'{"asset": {"version": "2.0"}, "meshes": [{"primitives": [{"attributes":'
         b' {"POSITION": 7}}]}], "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}]}'),
        ("gltf", "does not parse", b"{not json"),
        ("gltf", "version", b'{"asset": {"version": "1.0"}}'),
    ]
    for fmt, needle, data in cases:
        with pytest.raises(SceneLoadError, match=needle):
            load_scene_bytes(data, fmt)


def _triangle_gltf(nodes: int, **accessor) -> bytes:
    """A glTF (embedded buffer) of one triangle placed by `nodes` nodes."""
    import base64

    data = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32).tobytes()
    doc = {
        "asset": {"version": "2.0"},
        "buffers": [{"uri": "data:application/octet-stream;base64," + base64.b64encode(data).decode(),
                     "byteLength": 36}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0, 0, 0], "max": [1, 1, 0], **accessor}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "nodes": [{"mesh": 0, "translation": [2.0 * i, 0, 0]} for i in range(nodes)],
        "scenes": [{"nodes": list(range(nodes))}],
    }
    return json.dumps(doc).encode()


def test_parts_limit_counts_gltf_nodes_and_obj_objects(monkeypatch):
    """Load time grows with parts, not bytes: MAX_PARTS is checked before trimesh parses."""
    import scenes.loaders

    monkeypatch.setattr(scenes.loaders, "MAX_PARTS", 2)
    assert load_scene_bytes(_triangle_gltf(2), "gltf").n_triangles == 2
    with pytest.raises(SceneLoadError, match="glTF has 3 nodes, limit is 2"):
        load_scene_bytes(_triangle_gltf(3), "gltf")
    obj = "".join(f"o part{i}\nv {i} 0 0\nv {i + 1} 0 0\nv {i} 1 0\nf {3 * i + 1} {3 * i + 2} {3 * i + 3}\n"
                  for i in range(3)).encode()
    with pytest.raises(SceneLoadError, match=r"OBJ has 3 parts \(objects × materials.*limit is 2"):
        load_scene_bytes(obj, "obj")
    assert load_scene_bytes(obj.replace(b"o part2\n", b""), "obj").n_triangles == 3
    # material switches split parts too: 3 (object, material) pairs, though one object
    mtl = obj.replace(b"o part1\n", b"usemtl b\n").replace(b"o part2\n", b"usemtl a\n")
    with pytest.raises(SceneLoadError, match="OBJ has 3 parts"):
        load_scene_bytes(mtl, "obj")
    assert load_scene_bytes(mtl.replace(b"usemtl a", b"usemtl b"), "obj").n_triangles == 3  # (part0, b) twice


@pytest.mark.parametrize("scale, offset, message", [
    (1e-6, 0.0, "scene is 1.41e-06 across"),  # too small to render (depth images of 1e-8 came back empty)
    (1.0, 1e7, "a millionth of its distance"),  # 1 across at 1e7: float32 steps of 1
    (2e11, 0.0, "scene coordinates reach 2e+11, beyond ±1e+11"),
])
def test_scene_extent_out_of_range_is_refused(scale, offset, message):
    obj = f"v {offset} 0 0\nv {offset + scale} 0 0\nv {offset} {scale} 0\nf 1 2 3\n".encode()
    with pytest.raises(SceneLoadError, match=re.escape(message)):
        load_scene_bytes(obj, "obj")
    ok = f"v 0 0 0\nv {scale / 10 if scale > 1 else 1e-4} 0 0\nv 0 1e-4 0\nf 1 2 3\n".encode()
    assert load_scene_bytes(ok, "obj").n_triangles == 1


def test_faces_and_nodes_naming_what_is_not_there_say_so():
    obj = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n"  # OBJ indices start at 1: trimesh drops the face
    with pytest.raises(SceneLoadError, match="no faces .*: its face on line 4 refers to vertex 0; the file "
                                             "defines 3 vertices"):
        load_scene_bytes(obj, "obj")
    with pytest.raises(SceneLoadError, match="does not start with the 'ply' magic"):
        load_scene_bytes(b"PLY\nend_header\n", "ply")
    long_header = b"ply\nformat ascii 1.0\n" + b"comment " + b"x" * 70_000 + b"\nend_header\n"
    with pytest.raises(SceneLoadError, match="no 'end_header' in its first 64 KiB"):
        load_scene_bytes(long_header, "ply")
    doc = json.loads(_triangle_gltf(1))
    doc["nodes"][0]["mesh"] = 5
    with pytest.raises(SceneLoadError, match="glTF node 0 refers to mesh 5; the file has 1 mesh$"):
        load_scene_bytes(json.dumps(doc).encode(), "gltf")


def test_a_library_message_quoting_the_file_is_cut():
    """A library's exception text (trimesh's KeyError quoting a value of the file) is
    repeated up to LIBRARY_TEXT_CHARS, with its length."""
    from scenes.loaders import LIBRARY_TEXT_CHARS, _library_text

    message = _library_text(KeyError("Q" * 10_000))
    assert message.startswith("KeyError: ") and "Q" * 40 in message, message
    assert message.count("Q") <= LIBRARY_TEXT_CHARS and "(10,002 characters)" in message, message


@pytest.mark.parametrize(("accessor", "view", "message"), [
    ({"type": "Q" * 10_000}, {}, "has componentType 5126 and type Q{20}$"),
    ({"count": 10**9}, {}, r"needs 12,000,000,000 bytes \(1,000,000,000 × VEC3 of 4-byte "
                           r"components\), but its buffer view 0 holds 36"),
    ({"count": 4}, {}, "needs 48 bytes"),
    ({"byteOffset": 4}, {}, "needs 40 bytes"),
    ({"bufferView": 3}, {}, "refers to buffer view 3; the file has 1"),
    ({}, {"byteOffset": 8}, "buffer view 0, which ends at byte 44 of buffer 0, which holds 36"),
    ({}, {"buffer": 2}, "whose buffer 2 is not one of the file's 1"),
    ({"bufferView": None, "count": 10**7}, {}, "has no buffer view: all its values would be zero"),
    ({"count": 2 * 10**8}, {"byteStride": "1"}, "byteStride 1, not byte counts fitting its 12-byte elements"),
    ({"componentType": [5126]}, {}, r"has componentType \[5126\] and type VEC3"),
])
def test_accessors_that_do_not_fit_their_buffers_are_named(accessor, view, message):
    """Checked before trimesh (scenes.gltf.accessor_problem): numpy's reshape and
    index errors named nothing, and a count no buffer holds met the triangle limit."""
    doc = json.loads(_triangle_gltf(1, **accessor))
    doc["accessors"][0] = {k: v for k, v in doc["accessors"][0].items() if v is not None}
    doc["bufferViews"][0].update(view)
    with pytest.raises(SceneLoadError, match="^malformed glTF mesh 0 primitive 0: its POSITION accessor 0 .*"
                       + message):
        load_scene_bytes(json.dumps(doc).encode(), "gltf")


def test_gltf_external_buffer_not_fetched():
    doc = {
        "asset": {"version": "2.0"},
        "buffers": [{"uri": "https://example.invalid/geometry.bin", "byteLength": 36}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0, 0, 0], "max": [1, 1, 0]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
    }
    with pytest.raises(SceneLoadError, match="external file"):
        load_scene_bytes(json.dumps(doc).encode(), "gltf")


def test_compressed_glb_rejected():
    doc = json.dumps({"asset": {"version": "2.0"}, "extensionsRequired": ["KHR_draco_mesh_compression"]}).encode()
    doc += b" " * (-len(doc) % 4)
    glb = struct.pack("<4sII", b"glTF", 2, 20 + len(doc)) + struct.pack("<II", len(doc), 0x4E4F534A) + doc
    with pytest.raises(SceneLoadError, match="KHR_draco_mesh_compression"):
        load_scene_bytes(glb, "glb")


def test_unsupported_format():
    with pytest.raises(SceneLoadError, match="unsupported format 'fbx'"):
        load_scene_bytes(b"abc", "fbx")
    with pytest.raises(SceneLoadError, match="unsupported format"):
        load_scene("model.stl")
    with pytest.raises(SceneLoadError, match="cannot read"):
        load_scene("/nonexistent/model.obj")


def test_max_triangles():
    glb = shared_scene("macross_diorama/scene.glb")
    with pytest.raises(SceneLoadError, match=r"102,822 triangles, limit is 100,000") as info:
        load_scene(glb, max_triangles=100_000)
    assert isinstance(info.value, TriangleLimitError)
    assert (info.value.n_triangles, info.value.limit) == (102_822, 100_000)
    assert load_scene(glb, max_triangles=102_822).n_triangles == 102_822
    bunny = shared_scene("stanford_bunny/stanford-bunny.obj")
    with pytest.raises(SceneLoadError, match=r"69,451 triangles, limit is 1,000"):
        load_scene(bunny, max_triangles=1_000)


def test_max_triangles_checked_before_decoding(monkeypatch):
    """Over-limit files are rejected from their headers, before trimesh parses them."""
    import trimesh

    def boom(*args, **kwargs):
        raise AssertionError("trimesh should not be called")

    monkeypatch.setattr(trimesh, "load_scene", boom)
    big_obj = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n" + b"f 1 2 4 3\n" * 600
    with pytest.raises(SceneLoadError, match=r"1,200 triangles, limit is 1,000"):
        load_scene_bytes(big_obj, "obj", max_triangles=1_000)
    ply = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nelement face 5000\nend_header\n"
    with pytest.raises(SceneLoadError, match=r"at least 5,000 triangles"):
        load_scene_bytes(ply, "ply", max_triangles=1_000)
    with pytest.raises(SceneLoadError, match=r"24 triangles, limit is 10"):
        load_scene_bytes(_box_glb(), "glb", max_triangles=10)


def test_only_scene_load_error_escapes_fuzzed_glb():
    """Bit flips in a valid GLB give a Scene or a SceneLoadError, nothing else."""
    good = bytearray(_box_glb())
    rng = np.random.default_rng(7)
    for _ in range(40):
        data = bytearray(good)
        for pos in rng.integers(0, len(data), size=4):
            data[pos] = int(rng.integers(0, 256))
        try:
            load_scene_bytes(bytes(data), "glb")
        except SceneLoadError:
            pass


def test_ply_declaring_more_vertices_than_its_body_holds_says_so():
    """The header's counts against the body, before trimesh allocates them (issue 15)."""
    head = ("ply\nformat {fmt} 1.0\nelement vertex 1000000\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 1\nproperty list uchar int vertex_indices\nend_header\n")
    ascii_body = b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    with pytest.raises(SceneLoadError, match=r"declares 1,000,000 'vertex' and 1 'face' elements .* body has 4 lines"):
        load_scene_bytes(head.format(fmt="ascii").encode() + ascii_body, "ply")
    with pytest.raises(SceneLoadError, match=r"at least 12,000,001 bytes, but the body has 40 bytes"):
        load_scene_bytes(head.format(fmt="binary_little_endian").encode() + bytes(40), "ply")
    exact = head.replace("1000000", "3").format(fmt="ascii").encode() + ascii_body
    assert load_scene_bytes(exact, "ply").n_triangles == 1


@pytest.mark.parametrize("face, message", [
    ("f 1 2 4", "face on line 5 refers to vertex 4; the file defines 3 vertices"),
    ("f 1/1 -4 3", "face on line 5 refers to vertex -4 (relative), but only 3 vertices come before it"),
    ("f 1 2 x", "face on line 5 refers to 'x', not a vertex number; the file defines 3 vertices"),
])
def test_obj_face_naming_a_missing_vertex_says_which(face, message):
    """Not the library's IndexError: the face's line, its reference and the vertex count."""
    text = f"v 0 0 0\nv 1 0 0\n# a comment\nv 0 1 0\n{face}\n"
    with pytest.raises(SceneLoadError) as info:
        load_scene_bytes(text.encode(), "obj")
    assert str(info.value) == f"malformed OBJ: {message}"
    assert load_scene_bytes(text.replace(face, "f 1 2 -1").encode(), "obj").n_triangles == 1


def test_gltf_vertex_colours_beside_a_material_tint_it():
    """glTF's base colour is factor × texture × COLOR_0: a reconstruction GLB (white,
    non-metal sample material with vertex colours) loads with the colours' mean."""
    from gl_passes.reconstruction import glb_bytes

    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32)
    rgba = np.array([[255, 0, 0, 255], [255, 0, 0, 255], [0, 0, 255, 255], [0, 0, 255, 255]], np.uint8)
    tri = np.array([[0, 1, 2], [1, 3, 2]], np.uint32)
    scene = load_scene_bytes(glb_bytes([(pos, rgba, tri)]), "glb")
    m = scene.objects[0].material
    np.testing.assert_allclose(m.albedo, (0.5, 0.0, 0.5), atol=1e-6)  # COLOR_0 is linear: no sRGB decoding
    assert m.specular == 0.0


def test_gltf_vertex_colours_of_every_normalized_type():
    """COLOR_0 may be float, normalized uint8 or normalized uint16: 0.5 grey is 0.5 in each."""
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    for dtype, component, grey in ((np.float32, 5126, 0.5), (np.uint8, 5121, 128), (np.uint16, 5123, 32768)):
        colours = np.full((3, 4), grey, dtype)
        colours[:, 3] = 1 if dtype == np.float32 else np.iinfo(dtype).max
        blob = pos.tobytes() + colours.tobytes()
        doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
               "materials": [{"pbrMetallicRoughness": {"metallicFactor": 0.0}}],
               "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "COLOR_0": 1}, "material": 0}]}],
               "buffers": [{"byteLength": len(blob)}],
               "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": pos.nbytes},
                               {"buffer": 0, "byteOffset": pos.nbytes, "byteLength": colours.nbytes}],
               "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                              "min": [0, 0, 0], "max": [1, 1, 0]},
                             {"bufferView": 1, "componentType": component, "count": 3, "type": "VEC4",
                              "normalized": dtype != np.float32}]}
        text = json.dumps(doc).encode()
        text += b" " * (-len(text) % 4)
        blob += b"\0" * (-len(blob) % 4)
        glb = (struct.pack("<4sII", b"glTF", 2, 28 + len(text) + len(blob)) + struct.pack("<I4s", len(text), b"JSON")
               + text + struct.pack("<I4s", len(blob), b"BIN\0") + blob)
        albedo = load_scene_bytes(glb, "glb").objects[0].material.albedo
        np.testing.assert_allclose(albedo, [grey / (1 if dtype == np.float32 else np.iinfo(dtype).max)] * 3,
                                   rtol=1e-6, err_msg=str(dtype))


# --------------------------------------------------------------------------------------
# glTF documents before trimesh (scenes.gltf)
# --------------------------------------------------------------------------------------
_TRIANGLE = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)


def _gltf(meshes: list[dict], nodes: list[dict], roots: list[int], **extra) -> bytes:
    """A .gltf (embedded buffer; accessor 0: _TRIANGLE's positions) of `meshes`
    placed by `nodes`, the default scene's roots `roots`."""
    import base64

    doc = {
        "asset": {"version": "2.0"},
        "buffers": [{"uri": "data:application/octet-stream;base64," + base64.b64encode(_TRIANGLE.tobytes()).decode(),
                     "byteLength": 36}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0, 0, 0], "max": [1, 1, 0]}],
        "meshes": meshes, "nodes": nodes, "scenes": [{"nodes": roots}], **extra,
    }
    return json.dumps(doc).encode()


_ONE_TRIANGLE = {"primitives": [{"attributes": {"POSITION": 0}}]}


def test_a_flattened_hierarchy_places_every_instance_as_trimesh_composes_it(monkeypatch):
    """scenes.gltf.flattened: a tree of nodes placed by matrices and by T·R·S (rotations,
    non-uniform and mirroring scales) loads with every instance where trimesh's own
    composition along the paths puts it (the flattening switched off), names included."""
    import scenes.gltf

    rng = np.random.default_rng(5)
    nodes = []
    for i in range(24):
        node: dict = {"mesh": 0, "name": f"n{i}"} if i % 3 else {}
        if i % 4 == 1:
            m = np.eye(4)
            m[:3, :3] = rng.normal(size=(3, 3))
            m[:3, 3] = rng.normal(size=3)
            node["matrix"] = m.T.reshape(-1).tolist()
            if i % 8 == 1:  # both (the spec allows one): composed as trimesh does, matrix first
                node["translation"] = rng.normal(size=3).tolist()
        else:
            q = rng.normal(size=4)
            node.update(translation=rng.normal(size=3).tolist(), rotation=(q / np.linalg.norm(q)).tolist(),
                        scale=(rng.uniform(0.5, 2, 3) * rng.choice([-1, 1], 3)).tolist())
        nodes.append(node)
    for i in range(1, 24):
        nodes[(i - 1) // 2].setdefault("children", []).append(i)
    data = _gltf([_ONE_TRIANGLE], nodes, [0])
    ours = load_scene_bytes(data, "gltf")
    monkeypatch.setattr(scenes.gltf, "flattened", lambda header: None)
    theirs = load_scene_bytes(data, "gltf")
    assert len(ours.objects) == len(theirs.objects) == 16
    by_name = {o.name: o for o in theirs.objects}
    for o in ours.objects:
        np.testing.assert_allclose(o.vertices, by_name[o.name].vertices, rtol=1e-5, atol=1e-5)
        np.testing.assert_array_equal(o.faces, by_name[o.name].faces)


def test_a_deep_node_chain_loads_with_each_level_applied():
    """300 nested mesh nodes, each 1 cm along x of its parent. trimesh composes each
    node's transform along its path with np.linalg.multi_dot, cubic in the depth per
    node: 200 levels took 60 s and 500 did not finish in 10 minutes before the loader
    flattened the hierarchy itself."""
    n = 300
    nodes = [{"mesh": 0, "name": f"level{i}", "translation": [0.01, 0, 0], **({"children": [i + 1]} if i < n - 1
                                                                              else {})} for i in range(n)]
    scene = load_scene_bytes(_gltf([_ONE_TRIANGLE], nodes, [0]), "gltf")
    assert len(scene.objects) == n
    by_name = {o.name: o for o in scene.objects}
    assert by_name[f"level{n - 1}"].vertices[:, 0].min() == pytest.approx(0.01 * n, rel=1e-5)


def test_every_primitive_of_a_mesh_loads():
    """9,000 primitives in one mesh: all load, every time. trimesh names a mesh's
    primitives with random 6-hex-digit suffixes; two alike dropped a primitive (2.4
    pairs expected at this count: nine loads in ten lost some), until the loader gave
    it serial ones."""
    mesh = {"primitives": [{"attributes": {"POSITION": 0}}] * 9000}
    scene = load_scene_bytes(_gltf([mesh], [{"mesh": 0}], [0]), "gltf")
    assert scene.n_triangles == 9000


@pytest.mark.parametrize(("change", "message"), [
    ({"extensionsRequired": ["KHR_meshopt_compression"]}, "KHR_meshopt_compression.*decompress"),
    ({"extensionsRequired": ["EXT_made_up"]}, "requires extension.*EXT_made_up"),
    ({"mode": 6}, "mesh 0 primitive 0 is a triangle fan"),
    ({"sparse": {"count": 1, "indices": {"bufferView": 0, "componentType": 5125},
                 "values": {"bufferView": 0}}}, "POSITION accessor 0 is sparse"),
    ({"normalized": True}, "POSITION accessor 0 is normalized"),
    ({"targets": [{"POSITION": 0}], "weights": [0.5]}, "node 0 shows mesh 0.s morph targets with non-zero weights"),
    ({"children": [7]}, "refers to node 7; the file has 2 nodes"),
    ({"children": [1]}, "node 1 is reached twice"),  # a root and node 0's child
    ({"children": 5}, "node 0's children is 5, not a list"),
    ({"targets": [{"POSITION": 0}], "node weights": [1.0]}, "node 0 shows mesh 0.s morph targets"),
])
def test_gltf_features_read_wrongly_are_refused_by_name(change, message):
    """trimesh reads each of these wrongly without a word (ignores it, drops the
    primitive, or scales positions by 32767): the loader names the feature instead."""
    prim: dict = {"attributes": {"POSITION": 0}}
    mesh: dict = {"primitives": [prim]}
    nodes: list[dict] = [{"mesh": 0}, {"mesh": 0, "translation": [2, 0, 0]}]
    extra: dict = {}
    doc = json.loads(_gltf([mesh], nodes, [0, 1]))
    if "mode" in change or "targets" in change:
        prim.update({k: v for k, v in change.items() if "weights" not in k})
        mesh.update({k: v for k, v in change.items() if k == "weights"})
        if "node weights" in change:
            nodes[0]["weights"] = change["node weights"]
    elif "sparse" in change or "normalized" in change:
        doc["accessors"][0].update(change)
    elif "children" in change:
        nodes[0].update(change)
    else:
        extra = change
    doc.update(meshes=[mesh], nodes=nodes, **extra)
    with pytest.raises(SceneLoadError, match=message):
        load_scene_bytes(json.dumps(doc).encode(), "gltf")


def test_required_extensions_the_loader_handles_load():
    """A required extension that changes nothing the loader reads (unlit materials,
    texture transforms) or that it reads (integer positions) does not stop a load."""
    data = _gltf([_ONE_TRIANGLE], [{"mesh": 0}], [0],
                 extensionsRequired=["KHR_materials_unlit", "KHR_texture_transform", "KHR_mesh_quantization"])
    assert load_scene_bytes(data, "gltf").n_triangles == 1


# --------------------------------------------------------------------------------------
# OBJ text before trimesh (scenes.obj)
# --------------------------------------------------------------------------------------
def test_obj_relative_indices_count_back_from_their_line():
    """`f -3 -2 -1` names the three vertices defined last above the line (the OBJ
    spec), not the file's last three: trimesh resolved them against the end of the
    file, moving the first object's face onto the second's vertices."""
    obj = (b"o a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\n"
           b"o b\nvt 0 0\nvn 0 0 1\nv 0 0 5\nv 1 0 5\nv 0 1 5\nf -3/-1/-1 -2/-1/-1 -1/-1/-1\nvn 0 0 1\n")
    scene = load_scene_bytes(obj, "obj")
    by_name = {o.name: o for o in scene.objects}
    assert sorted(by_name) == ["a", "b"]
    assert by_name["a"].vertices[:, 2].max() == 0 and by_name["b"].vertices[:, 2].min() == 5
    with pytest.raises(SceneLoadError, match="face on line 5 refers to vertex -4 .relative., but only 3 vertices"):
        load_scene_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf -4 -2 -1\n", "obj")


@pytest.mark.parametrize("text", [
    b"v\t0 0 0\nv\t1 0 0\nv\t0 1 0\nf\t1 2 3\n",  # a tab after the keyword
    b"  v 0 0 0\n\tv 1 0 0\n v 0 1 0\n   f 1 2 3\n",  # indented lines
    b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3 # a comment after the face\n",
])
def test_obj_lines_that_are_valid_but_unusual_load(text):
    """trimesh took keywords only at the line's start and followed by a space, and
    failed on a comment after numbers: these valid files were refused."""
    scene = load_scene_bytes(text, "obj")
    assert scene.n_triangles == 1
    np.testing.assert_array_equal(np.asarray(scene.bounds), [[0, 0, 0], [1, 1, 0]])


def test_names_and_values_from_the_file_are_cut_in_messages():
    """An object name or asset.version of 20,000 characters: the message quotes 80
    of them and says how long it was (it repeated about 480)."""
    long = "N" * 20_000
    obj = f"o {long}\nv 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n".encode()
    ply_elements = f"ply\nformat ascii 1.0\nelement {long} 3\nend_header\n".encode()  # no vertices: named
    ply_rows = (f"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nelement {long} 2\n"
                "property float a\nend_header\n1\n2\n").encode()  # its rows run short: named
    for data, fmt in ((obj, "obj"), (json.dumps({"asset": {"version": long}}).encode(), "gltf"),
                      (ply_elements, "ply"), (ply_rows, "ply")):
        with pytest.raises(SceneLoadError) as info:
            load_scene_bytes(data, fmt)
        message = str(info.value)
        assert "N" * 81 not in message and len(message) < 300, (fmt, message[:600])
        assert "(20,002 characters)" in message or ("N" * 60 in message and "…" in message), message[:300]


@pytest.mark.parametrize(("change", "message"), [
    ({"uri": "data:application/octet-stream,AAAA"},
     "buffer 0 is a data URI without ';base64,' ('data:application/octet-stream')"),
    ({"uri": "data:application/octet-stream;base64,@@@@"}, "buffer 0 is a data URI whose base64 does not decode"),
    ({"byteLength": 48}, "buffer 0 holds 36 bytes, but its byteLength is 48"),
])
def test_embedded_buffers_that_do_not_decode_are_named(change, message):
    """trimesh failed on these with an empty AssertionError."""
    doc = json.loads(_triangle_gltf(1))
    doc["buffers"][0].update(change)
    doc["bufferViews"][0]["byteLength"] = min(36, doc["buffers"][0]["byteLength"])
    with pytest.raises(SceneLoadError, match=f"^malformed glTF {re.escape(message)}$"):
        load_scene_bytes(json.dumps(doc).encode(), "gltf")


def test_the_default_scene_out_of_range_is_named_and_no_scenes_means_the_root_nodes():
    """A `scene` index no scene has was trimesh's IndexError; a file without `scenes`
    loaded nothing ('no faces') while the triangle limit counted its root nodes."""
    doc = json.loads(_triangle_gltf(2))
    with pytest.raises(SceneLoadError, match="^malformed glTF: its scene 3 is not one of its 1 scenes$"):
        load_scene_bytes(json.dumps({**doc, "scene": 3}).encode(), "gltf")
    doc["nodes"][0]["children"] = [1]
    del doc["scenes"]
    scene = load_scene_bytes(json.dumps(doc).encode(), "gltf")
    assert scene.n_triangles == 2 and scene.bounds[1][0] == pytest.approx(3.0)  # node 1 at x 2 under node 0's 0


def test_obj_continued_lines_comments_in_names_and_polylines():
    """A face continued on the next line ('\\') counts back from its own line as
    trimesh joins it; a comment after a material name is not part of the name (trimesh
    read it as one, so parts the limit counted as one split apart); a polyline corner
    that names nothing does not refuse the file (polylines are not drawn)."""
    import scenes.loaders

    obj = b"o a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 \\\n-1\no b\nv 5 0 0\nv 6 0 0\nv 5 1 0\nf -3 -2 -1\n"
    by_name = {o.name: o for o in load_scene_bytes(obj, "obj").objects}
    assert by_name["a"].vertices[:, 0].max() == 1 and by_name["b"].vertices[:, 0].min() == 5
    tri = b"v 0 0 0\nv 1 0 0\nv 0 1 0\n"
    switches = tri + b"".join(b"usemtl m #%d\nf 1 2 3\n" % i for i in range(3))
    original = scenes.loaders.MAX_PARTS
    try:
        scenes.loaders.MAX_PARTS = 2
        assert len(load_scene_bytes(switches, "obj").objects) == 1  # one material "m", as counted
    finally:
        scenes.loaders.MAX_PARTS = original
    assert load_scene_bytes(tri + b"l -1/-1 -2/-2\nf 1 2 3\n", "obj").n_triangles == 1


def test_trimesh_is_patched_once_keeping_its_own_functions():
    """Two first loads at once must not keep each other's patch as trimesh's original
    (every later OBJ load would then recurse)."""
    import trimesh

    import scenes.loaders as loaders

    load_scene_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "obj")
    loaders._patch_trimesh(trimesh)
    assert loaders._TRIMESH_UNIQUE_NAME is not loaders._unique_name
    assert trimesh.util.unique_name is loaders._unique_name and trimesh.util.unique_id is loaders._serial_id


def test_instances_scaled_flat_are_named_when_nothing_else_is_left():
    """A zero scale is valid glTF (it hides a node): such instances are dropped, and a
    file of nothing else says so instead of only 'no faces'."""
    nodes = [{"mesh": 0, "name": "hidden", "scale": [1, 0, 1]}, {"mesh": 0, "name": "gone", "matrix": [0] * 16}]
    with pytest.raises(SceneLoadError, match=r"no faces.*instances 'gone, hidden' had triangles, but a node "
                                             r"transform that scales them flat \(a zero scale\)"):
        load_scene_bytes(_gltf([_ONE_TRIANGLE], nodes, [0, 1]), "gltf")
    shown = load_scene_bytes(_gltf([_ONE_TRIANGLE], [*nodes, {"mesh": 0, "name": "shown"}], [0, 1, 2]), "gltf")
    assert [o.name for o in shown.objects] == ["shown"]
    with pytest.raises(SceneLoadError) as info:  # degenerate, not flattened: no such words
        load_scene_bytes(b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", "obj")
    assert "zero scale" not in str(info.value)

"""PLY bodies against their headers (scenes.ply): faces of mixed sizes, rows cut short or
with values to spare, trailing bytes; hand-made files whose triangles are known."""

from __future__ import annotations

import re
import struct

import numpy as np
import pytest

from scenes.loaders import SceneLoadError, TriangleLimitError, load_scene_bytes

#: A unit square's corners and a pentagon's, z = 0 (x, y).
SQUARE = [(0, 0), (1, 0), (1, 1), (0, 1)]
PENTAGON = [(3 + np.cos(a), np.sin(a)) for a in np.linspace(0, 2 * np.pi, 6)[:-1]]
VERTICES = [(x, y, 0.0) for x, y in SQUARE + PENTAGON] + [(5.0, 0.0, 0.0), (6.0, 0.0, 0.0), (5.0, 1.0, 0.0)]
#: A quad, a pentagon and a triangle: 2 + 3 + 1 triangles by fans.
FACES = [(0, 1, 2, 3), (4, 5, 6, 7, 8), (9, 10, 11)]
FACE_COLOURS = [(255, 0, 0), (0, 255, 0), (0, 0, 255)]


def _header(fmt: str, faces: int, face_props: str = "property list uchar int vertex_indices\n",
            extra: str = "") -> bytes:
    return (f"ply\nformat {fmt} 1.0\ncomment made by hand\nelement vertex {len(VERTICES)}\nproperty float x\n"
            f"property float y\nproperty float z\nelement face {faces}\n{face_props}{extra}end_header\n").encode()


def _binary(order: str = "<", colours: bool = False, faces=FACES) -> bytes:
    fmt = "binary_little_endian" if order == "<" else "binary_big_endian"
    props = "property list uchar int vertex_indices\n"
    if colours:  # one scalar before the list, three after: the fan copies both sides
        props = "property uchar flags\n" + props + "property uchar red\nproperty uchar green\nproperty uchar blue\n"
    body = b"".join(struct.pack(order + "3f", *v) for v in VERTICES)
    for f, rgb in zip(faces, FACE_COLOURS, strict=False):
        row = struct.pack(order + "B", len(f)) + struct.pack(f"{order}{len(f)}i", *f)
        body += (struct.pack("B", 7) + row + struct.pack("3B", *rgb)) if colours else row
    return _header(fmt, len(faces), props) + body


def _ascii(faces=FACES, tail: str = "") -> bytes:
    body = "".join(f"{x} {y} {z}\n" for x, y, z in VERTICES)
    body += "".join(f"{len(f)} {' '.join(map(str, f))}\n" for f in faces)
    return _header("ascii", len(faces)) + (body + tail).encode()


def _triangles(scene) -> set[tuple]:
    """Each triangle as its sorted corner coordinates (independent of vertex order)."""
    o = scene.objects[0]
    return {tuple(sorted(_key(o.vertices[i]) for i in tri)) for tri in o.faces}


def _key(vertex) -> tuple[float, ...]:
    return tuple(round(float(c), 4) + 0.0 for c in vertex)


def _area(scene) -> float:
    o = scene.objects[0]
    a, b, c = (o.vertices[o.faces[:, i]].astype(np.float64) for i in range(3))
    return float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())


def _fans() -> set[tuple]:
    want = set()
    for f in FACES:
        for j in range(1, len(f) - 1):
            want.add(tuple(sorted(_key(VERTICES[i]) for i in (f[0], f[j], f[j + 1]))))
    return want


@pytest.mark.parametrize("order", ["<", ">"])
def test_binary_faces_of_mixed_sizes_load_as_fans(order):
    """trimesh alone refuses this file ('PLY is unexpected length!'): a quad, a pentagon
    and a triangle are 6 fan triangles covering 1 + pentagon + 0.5 of area."""
    scene = load_scene_bytes(_binary(order), "ply")
    assert scene.n_triangles == 6
    assert _triangles(scene) == _fans()
    pentagon = 5 / 2 * np.sin(2 * np.pi / 5)
    assert _area(scene) == pytest.approx(1 + pentagon + 0.5, rel=1e-5)


def test_binary_fans_keep_each_faces_other_properties():
    """A scalar before the list and three after it (face colours) go with every triangle
    of the face: the mean face colour counts the pentagon's green three times."""
    scene = load_scene_bytes(_binary(colours=True), "ply")
    assert _triangles(scene) == _fans()
    # triangles: 2 red, 3 green, 1 blue (sRGB 255 is linear 1)
    np.testing.assert_allclose(scene.objects[0].material.albedo, (2 / 6, 3 / 6, 1 / 6), atol=1e-9)


def test_ascii_and_binary_of_mixed_sizes_agree():
    """trimesh reads ASCII faces of mixed sizes itself; our binary fans match it."""
    assert _triangles(load_scene_bytes(_ascii(), "ply")) == _triangles(load_scene_bytes(_binary(), "ply"))


@pytest.mark.parametrize("row, line, message", [
    ("3 9 10", 25, "has 3 values, its header and list lengths call for 4"),      # cut short: was 1 triangle fewer
    ("3 9 10 11 4", 25, "has 5 values, its header and list lengths call for 4"),  # a value to spare: was ignored
    ("4 9 10 11", 25, "has 4 values, its header and list lengths call for 5"),    # too long: was a wrong triangle
    ("x 9 10 11", 25, "list 'vertex_indices' has length 'x', not a whole number"),
])
def test_ascii_face_rows_must_match_their_lengths(row, line, message):
    data = _ascii(faces=FACES[:2]).decode() + row + "\n"
    data = data.replace(f"element face {len(FACES) - 1}", f"element face {len(FACES)}")
    with pytest.raises(SceneLoadError, match=rf"malformed PLY: line {line} \(face 2\): .*{message}|"
                                             rf"malformed PLY: line {line} \(face 2\) {message}"):
        load_scene_bytes(data.encode(), "ply")


def test_ascii_vertex_rows_and_extra_lines():
    text = _ascii().decode()
    with pytest.raises(SceneLoadError, match=r"line 12 \(vertex 1\) has 2 values, its header calls for 3"):
        load_scene_bytes(text.replace("1 0 0.0\n", "1 0\n", 1).encode(), "ply")
    with pytest.raises(SceneLoadError, match=r"the body has 1 lines after the 15 rows the header declares"):
        load_scene_bytes(_ascii(tail="3 0 1 2\n"), "ply")
    assert load_scene_bytes(_ascii(tail="\n\n"), "ply").n_triangles == 6  # trailing blank lines are fine
    with pytest.raises(SceneLoadError, match=r"line 24 \(face 1\) has 0 values, too few for its header"):
        load_scene_bytes(text.replace("\n5 4 5", "\n\n5 4 5").encode(), "ply")  # a blank line among the faces


def test_binary_rows_cut_short_or_with_bytes_to_spare():
    data = _binary()
    with pytest.raises(SceneLoadError, match=r"face 2 runs past the end of the body \(its list 'vertex_indices' "
                                             r"says 3 entries\)"):
        load_scene_bytes(data[:-4], "ply")
    with pytest.raises(SceneLoadError, match=r"the body has 5 bytes after the rows the header declares"):
        load_scene_bytes(data + bytes(5), "ply")


def test_other_elements_with_mixed_lists_are_dropped_and_bad_headers_named():
    """An element trimesh does not use (here per-material names as lists of chars) with lists
    of mixed lengths is left out; the mesh loads. Unknown types and bad lines are named."""
    extra = "element material 2\nproperty list uchar uchar name\n"
    data = _binary().replace(b"end_header\n", extra.encode() + b"end_header\n")
    data += struct.pack("B", 3) + b"red" + struct.pack("B", 5) + b"green"
    assert _triangles(load_scene_bytes(data, "ply")) == _fans()
    with pytest.raises(SceneLoadError, match=r"header line 5 has unknown type 'real'"):
        load_scene_bytes(_binary().replace(b"property float x", b"property real x"), "ply")
    with pytest.raises(SceneLoadError, match=r"format 'binary' is not ascii"):
        load_scene_bytes(_binary().replace(b"binary_little_endian", b"binary"), "ply")


def test_header_oddities_are_named():
    """A list whose length is a float type (it crashed the walk: 500), a comment holding
    bytes that str.splitlines() would split on (trimesh splits the header on newlines
    only), and a header cut short by 'end_header' inside a comment."""
    data = _binary().replace(b"property list uchar int", b"property list float int")
    with pytest.raises(SceneLoadError, match=r"list 'vertex_indices' has its length as 'float'; a length is an "
                                             r"integer type"):
        load_scene_bytes(data, "ply")
    odd = _binary().replace(b"comment made by hand", b"comment caf\xc3\xa9 \xc2\x85 property int bad\x0c element x 5")
    assert _triangles(load_scene_bytes(odd, "ply")) == _fans()
    cut = _binary().replace(b"comment made by hand", b"comment before end_header x")
    with pytest.raises(SceneLoadError, match=r"\(no elements, 0 bytes\)"):
        load_scene_bytes(cut, "ply")


def test_the_triangle_limit_sees_the_fans_before_they_are_built():
    """A 255-gon is 253 fan triangles: over a limit of 100 it is refused by count, before the rewrite."""
    data = _binary(faces=[tuple(range(12)) * 21 + (0, 1, 2)])  # 255 indices into the 12 vertices
    with pytest.raises(TriangleLimitError, match=r"scene has 253 triangles, limit is 100"):
        load_scene_bytes(data, "ply", max_triangles=100)


@pytest.mark.parametrize(("body", "message"), [
    (b"0 0 0\n1 0 abc\n0 1 0\n3 0 1 2\n", "line 11 (vertex 1) has 'abc', not a number"),
    (b"0 0 0\n1 0 0\n0 1 0\n3 0 1 x\n", "line 13 (face 0) has 'x', not a number"),
])
def test_an_ascii_value_that_is_not_a_number_is_named(body, message):
    """The parser's own message ('string or file could not be read to its end')
    named no line: the loader finds the value once the parse failed."""
    head = (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            b"element face 1\nproperty list uchar int vertex_indices\nend_header\n")
    with pytest.raises(SceneLoadError, match=f"^malformed PLY: {re.escape(message)}$"):
        load_scene_bytes(head + body, "ply")

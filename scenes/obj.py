"""OBJ text before trimesh reads it: text, not binary (`text`); lines trimesh would
misread rewritten as it reads them (`normalised`); the parts it will split the file into
and the triangles its faces make counted (`part_count`, `triangle_count`); and the first
face corner that names no vertex (`face_problem`), which trimesh drops silently.

trimesh's OBJ reader takes a line's keyword only at the line's start and followed by a
space, so indented lines and a tab after the keyword (both valid OBJ) were lost, a
comment after a line's numbers failed the whole file, and
it resolves relative (negative) indices against the end of the file instead of the
line they are on, which silently moved faces of files written object by object.
"""

from __future__ import annotations

import re

#: Keywords whose lines define an element that relative indices count back over.
_ELEMENTS = {b"v": 0, b"vt": 1, b"vn": 2}
#: Lines that need rewriting: indented, a tab after the keyword, a negative index on a
#: face or line element, a comment after a line's content, or continued on the next.
_NEEDS_REWRITE = re.compile(rb"^[ \t]+\S|^\S+\t|^[ \t]*[fl][ \t][^\n#]*-|^[ \t]*[^#\s][^\n#]*#|\\\r?$",
                            re.MULTILINE)
#: Keywords whose comments after the content are cut (trimesh reads a name to the
#: line's end, comment included; the part count reads it up to the comment).
_NAMED = (b"o", b"g", b"usemtl", b"s")
_PART_LINE = re.compile(rb"^[ \t]*(o|usemtl)[ \t]+([^\r\n#]*)", re.MULTILINE)
_FACE_LINE = re.compile(rb"^[ \t]*f[ \t]+([^\r\n#]*)", re.MULTILINE)
_VERTEX_LINE = re.compile(rb"^[ \t]*v[ \t]", re.MULTILINE)


class ObjError(ValueError):
    """Binary data, or a face refers to an element before the first one (relative index
    too large)."""


def text(data: bytes) -> bytes:
    """OBJ data as UTF-8 bytes; binary data raises ObjError, other 8-bit text is read as Latin-1."""
    sample = data[:65536]
    if b"\x00" in sample or sum(b < 9 or 13 < b < 32 for b in sample) > len(sample) // 100:
        raise ObjError("binary data, not an OBJ text file")
    try:
        data.decode("utf-8")
        return data
    except UnicodeDecodeError:
        return data.decode("latin-1").encode("utf-8")


def triangle_count(data: bytes) -> int:
    """Triangles the face lines fan-triangulate into (a polygon with k corners: k - 2)."""
    return sum(max(len(match.group(1).split()) - 2, 0) for match in _FACE_LINE.finditer(data))


def face_problem(data: bytes) -> str | None:
    """The first face corner of `normalised` data that names no vertex (not an integer,
    or outside 1..the file's vertex count), in words with its line; None if none."""
    n = len(_VERTEX_LINE.findall(data))
    for match in _FACE_LINE.finditer(data):
        for token in match.group(1).split():
            ref = token.split(b"/")[0]
            try:
                index = int(ref)
            except ValueError:
                index = None
            if index is None or not 1 <= index <= n:
                line = data.count(b"\n", 0, match.start()) + 1
                what = (f"vertex {index}" if index is not None
                        else f"{ref[:20].decode('utf-8', 'replace')!r}, not a vertex number")
                return f"face on line {line:,} refers to {what}; the file defines {n:,} vertices"
    return None


def normalised(data: bytes) -> bytes:
    """`data` with every line's keyword at its start followed by single spaces, and
    relative indices of faces and lines (``f -3 -2 -1``: the last three vertices
    defined above the line) made absolute; `data` itself when nothing needs it.
    One output line per input line, so line numbers in later messages still hold."""
    if not _NEEDS_REWRITE.search(data):
        return data
    seen = [0, 0, 0]  # v, vt, vn defined so far
    out = []
    for number, line in _joined(data.split(b"\n")):
        words = line.split()
        if not words:
            out.append(line)
            continue
        key = words[0]
        if key in _ELEMENTS:
            seen[_ELEMENTS[key]] += 1
            words = _before_comment(words)
        elif key == b"f":
            words = [key, *(_absolute(w, seen, number) for w in _before_comment(words[1:]))]
        elif key == b"l":  # polylines are not drawn: a corner that names nothing stays as it is
            words = [key, *(_absolute(w, seen, number, strict=False) for w in _before_comment(words[1:]))]
        elif key in _NAMED:
            words = _before_comment(words)
        out.append(b" ".join(words))
    return b"\n".join(out)


def _joined(lines: list[bytes]) -> list[tuple[int, bytes]]:
    """(1-based line number, line) with each line ending in a backslash joined to the
    next (OBJ's continuation, which trimesh joins too), an empty line put after the
    joined one for each line it took, so that the line count stays the same."""
    out: list[tuple[int, bytes]] = []
    i = 0
    while i < len(lines):
        number, line, taken = i + 1, lines[i], 0
        while line.rstrip(b"\r").endswith(b"\\") and i + 1 < len(lines):
            i += 1
            taken += 1
            line = line.rstrip(b"\r")[:-1] + b" " + lines[i]
        out.append((number, line))
        out.extend((number + k, b"") for k in range(1, taken + 1))
        i += 1
    return out


def _before_comment(words: list[bytes]) -> list[bytes]:
    for i, w in enumerate(words):
        if w.startswith(b"#"):
            return words[:i]
    return words


def _absolute(corner: bytes, seen: list[int], line: int, strict: bool = True) -> bytes:
    """A face corner (``v``, ``v/vt``, ``v//vn``, ``v/vt/vn``) with negative indices
    replaced by the absolute ones they name at this line; one that names nothing
    raises ObjError (`strict`) or is left as it is."""
    if b"-" not in corner:
        return corner
    refs = corner.split(b"/")
    for k, ref in enumerate(refs[:3]):
        if ref.startswith(b"-"):
            try:
                rel = int(ref)
            except ValueError:
                continue  # not a number: the face check names it
            absolute = seen[k] + 1 + rel
            if absolute < 1 and not strict:
                return corner
            if absolute < 1:
                what, whats = (("vertex", "vertices"), ("texture coordinate", "texture coordinates"),
                               ("normal", "normals"))[k]
                raise ObjError(f"face on line {line:,} refers to {what} {rel} (relative), but only {seen[k]:,} "
                               f"{whats} come before it")
            refs[k] = str(absolute).encode()
    return b"/".join(refs)


def part_count(data: bytes) -> int:
    """The meshes trimesh splits the OBJ into at most: its distinct (object, material)
    pairs, from the ``o`` and ``usemtl`` lines (at least 1)."""
    pairs = set()
    obj, material = b"", b""
    for match in _PART_LINE.finditer(data):
        if match.group(1) == b"o":
            obj = match.group(2).strip()
        else:
            material = match.group(2).strip()
        pairs.add((obj, material))
    return max(len(pairs), 1)

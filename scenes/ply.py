"""PLY bodies checked row by row against their headers, before trimesh reads them.

trimesh, our PLY reader, reads a binary ``face`` element only when every face has as
many vertices as the first ("PLY is unexpected length!" for a mesh of triangles and
quads, as Blender writes them), and reads ASCII rows loosely: a face line cut short or
with values to spare loads without a word, one triangle short or with a wrong one.
:func:`readable` walks the body as the header describes it (Bourke's PLY format: ASCII
rows one per line; binary rows packed, a list as its length then its entries), names
the first row that disagrees, and returns bytes trimesh reads as the file means: a
binary face element of mixed sizes rewritten as triangle fans (each face's other
properties copied to its triangles), another element of mixed-length lists dropped
(trimesh uses only ``vertex`` and ``face``).
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from scenes.excerpts import cut, quoted

__all__ = ["HEADER_BYTES", "Element", "Header", "PlyError", "Property", "read_header", "readable"]

#: A header longer than this is refused (bytes).
HEADER_BYTES = 1 << 16

#: PLY scalar type names -> numpy type codes (without byte order).
_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
          "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
          "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}

_STRUCT = {"i1": "b", "u1": "B", "i2": "h", "u2": "H", "i4": "i", "u4": "I", "f4": "f", "f8": "d"}


class PlyError(ValueError):
    """The file disagrees with the PLY format or with its own header (the message names where)."""


@dataclass(frozen=True)
class Property:
    """One property of an element: a scalar of type ``kind``, or a list (``count_kind`` set:
    the type of its length field) of ``kind`` entries. Types are numpy codes ('f4', 'u1', ...)."""

    name: str
    kind: str
    count_kind: str | None = None

    @property
    def is_list(self) -> bool:
        return self.count_kind is not None


@dataclass(frozen=True)
class Element:
    """An element of the header: ``count`` rows of ``properties``; ``lines``: the indices of
    its ``element`` line and its property lines among the header's lines."""

    name: str
    count: int
    properties: tuple[Property, ...]
    lines: tuple[int, ...]


@dataclass(frozen=True)
class Header:
    """A parsed PLY header. ``format``: 'ascii', 'binary_little_endian' or
    'binary_big_endian'; ``lines``: the header's lines up to ``end_header``;
    ``body_start``: byte offset of the first body byte."""

    format: str
    elements: tuple[Element, ...]
    lines: tuple[str, ...]
    body_start: int

    @property
    def order(self) -> str:
        return ">" if self.format == "binary_big_endian" else "<"

    def element(self, name: str) -> Element | None:
        return next((e for e in self.elements if e.name == name), None)

    def declared(self) -> str:
        if not self.elements:
            return "no elements"
        return " and ".join(f"{e.count:,} {quoted(e.name)}" for e in self.elements) + " elements"


def read_header(data: bytes) -> Header:
    """Parse the header of ``data``; :class:`PlyError` names what is wrong with it."""
    if not data.startswith(b"ply"):
        raise PlyError("it does not start with the 'ply' magic")
    end = data.find(b"end_header", 0, HEADER_BYTES)
    if end < 0:
        raise PlyError(f"no 'end_header' in its first {HEADER_BYTES // 1024} KiB (a header is at most that long)")
    newline = data.find(b"\n", end)
    body_start = newline + 1 if newline >= 0 else len(data)
    lines = tuple(line.removesuffix("\r") for line in data[:end].decode("latin-1").split("\n"))
    if lines and not lines[-1]:
        lines = lines[:-1]  # the newline before end_header
    fmt = ""
    elements: list[Element] = []
    properties: list[Property] = []
    owned: list[int] = []

    def close() -> None:
        if elements:
            last = elements[-1]
            elements[-1] = Element(last.name, last.count, tuple(properties), (*last.lines, *owned))

    for i, line in enumerate(lines):
        words = line.split()
        if not words:
            continue
        if words[0] == "format" and len(words) >= 2:
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise PlyError(f"header line {i + 1} {line[:60]!r} is not 'element <name> <count>'")
            close()
            elements.append(Element(words[1], int(words[2]), (), (i,)))
            properties, owned = [], []
        elif words[0] == "property":
            if not elements:
                raise PlyError(f"header line {i + 1} declares a property before any element")
            properties.append(_property(words, i, line))
            owned.append(i)
    close()
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise PlyError(f"format {fmt[:30]!r} is not ascii, binary_little_endian or binary_big_endian")
    return Header(fmt, tuple(elements), lines, body_start)


def _property(words: list[str], i: int, line: str) -> Property:
    try:
        if words[1] == "list" and len(words) == 5:
            count_kind = _TYPES[words[2]]
            if count_kind[0] == "f":
                raise PlyError(f"header line {i + 1}: list {words[4][:30]!r} has its length as {quoted(words[2])}; "
                               "a length is an integer type")
            return Property(words[4], _TYPES[words[3]], count_kind)
        if words[1] != "list" and len(words) == 3:
            return Property(words[2], _TYPES[words[1]])
    except KeyError as exc:
        raise PlyError(f"header line {i + 1} has unknown type {exc.args[0][:20]!r}; "
                       f"known: {', '.join(sorted(_TYPES))}") from None
    raise PlyError(f"header line {i + 1} {line[:60]!r} is not 'property <type> <name>' "
                   "or 'property list <count type> <type> <name>'")


def readable(data: bytes, header: Header, check_triangles: Callable[[int], None] | None = None) -> bytes:
    """``data`` checked row by row against ``header``; returned as is, or (binary with
    lists of mixed lengths) rewritten as described in the module docstring, after
    ``check_triangles(n)`` (e.g. a limit; it raises) has seen the n fan triangles."""
    body = memoryview(data)[header.body_start:]
    if header.format == "ascii":
        _check_ascii(header, bytes(body))
        return data
    return _binary(data, header, body, check_triangles)


# --------------------------------------------------------------------------------------
# ASCII
# --------------------------------------------------------------------------------------
def _check_ascii(header: Header, body: bytes) -> None:
    lines = body.split(b"\n")
    while lines and not lines[-1].strip():
        lines.pop()
    rows = sum(e.count for e in header.elements)
    if len(lines) < rows:
        filled = sum(1 for ln in lines if ln.strip())
        raise PlyError(f"the header declares {header.declared()} ({rows:,} rows) but the body has {filled:,} lines")
    for element, chunk, first in _element_lines(header, lines):
        if any(p.is_list for p in element.properties):
            for r, text in enumerate(chunk):
                _check_ascii_row(element, r, text.split(), first + r)
        else:
            widths = [len(text.split()) for text in chunk]
            want = len(element.properties)
            bad = next((r for r, w in enumerate(widths) if w != want), None)
            if bad is not None:
                raise PlyError(f"line {first + bad:,} ({cut(element.name)} {bad:,}) has {widths[bad]} values, "
                               f"its header calls for {want}")
    if len(lines) > rows:
        raise PlyError(f"the body has {len(lines) - rows:,} lines after the {rows:,} rows the header declares "
                       f"({header.declared()})")


def ascii_value_problem(data: bytes) -> str | None:
    """The first value of an ASCII PLY body that is not a number, in words with its
    line and row; None when every value is one (or the file is not ASCII PLY). Asked
    after a parse failed: the parser's message names no line."""
    try:
        header = read_header(data)
    except PlyError:
        return None
    if header.format != "ascii":
        return None
    for element, chunk, first in _element_lines(header, data[header.body_start:].split(b"\n")):
        for r, text in enumerate(chunk):
            for token in text.split():
                try:
                    float(token)
                except ValueError:
                    return (f"line {first + r:,} ({cut(element.name)} {r:,}) has {token[:20].decode('latin-1')!r}, "
                            "not a number")
    return None


def _element_lines(header: Header, lines: list[bytes]) -> Iterator[tuple[Element, list[bytes], int]]:
    """Each element of an ASCII body with the lines of its rows and the 1-based file
    line of its first row."""
    first_line = len(header.lines) + 2  # 1-based file line of the body's first line
    row = 0
    for element in header.elements:
        yield element, lines[row:row + element.count], first_line + row
        row += element.count


def _check_ascii_row(element: Element, r: int, tokens: list[bytes], line: int) -> None:
    """One ASCII row of an element with list properties: each list's length, then exactly
    that many entries, and nothing to spare."""
    at = 0
    for p in element.properties:
        if not p.is_list:
            at += 1
            continue
        if at >= len(tokens):
            raise PlyError(f"line {line:,} ({cut(element.name)} {r:,}) has {len(tokens)} values, too few for its "
                           f"header (list {quoted(p.name)} has no length)")
        try:
            n = int(tokens[at])
        except ValueError:
            raise PlyError(f"line {line:,} ({cut(element.name)} {r:,}): list {quoted(p.name)} has length "
                           f"{tokens[at][:20].decode('latin-1')!r}, not a whole number") from None
        if n < 0:
            raise PlyError(f"line {line:,} ({cut(element.name)} {r:,}): list {quoted(p.name)} has negative length {n}")
        at += 1 + n
    if at != len(tokens):
        raise PlyError(f"line {line:,} ({cut(element.name)} {r:,}) has {len(tokens)} values, its header and list "
                       f"lengths call for {at}")


# --------------------------------------------------------------------------------------
# binary
# --------------------------------------------------------------------------------------
@dataclass
class _Rows:
    """Where one element's rows lie in the body: [start, end) and, for an element whose
    lists vary in length, each row's offset and its lists' lengths (R,) / (R, L)."""

    start: int
    end: int
    offsets: np.ndarray | None = None
    lengths: np.ndarray | None = None


def _binary(data: bytes, header: Header, body: memoryview, check_triangles: Callable[[int], None] | None) -> bytes:
    order = header.order
    minimum = sum(e.count * sum(np.dtype(p.count_kind or p.kind).itemsize for p in e.properties)
                  for e in header.elements)
    if len(body) < minimum:
        raise PlyError(f"the header declares {header.declared()}, at least {minimum:,} bytes, "
                       f"but the body has {len(body):,} bytes")
    layout: list[_Rows] = []
    at = 0
    for element in header.elements:
        rows = _binary_rows(element, body, at, order)
        layout.append(rows)
        at = rows.end
    if at != len(body):
        raise PlyError(f"the body has {len(body) - at:,} bytes after the rows the header declares "
                       f"({header.declared()}, {at:,} bytes)")
    if all(rows.offsets is None for rows in layout):
        return data

    lines: list[str | None] = list(header.lines)
    parts: list[bytes] = []
    for element, rows in zip(header.elements, layout, strict=True):
        if rows.offsets is None:
            parts.append(bytes(body[rows.start:rows.end]))
        elif element.name == "face":
            if check_triangles is not None:
                check_triangles(int(_fan_sizes(rows).sum()))
            fan, triangles = _fan(element, rows, body, order)
            parts.append(fan)
            lines[element.lines[0]] = f"element face {triangles}"
        elif element.name == "vertex":
            raise PlyError("the vertex element has lists of mixed lengths, which no reader here understands")
        else:  # trimesh ignores it; the rest of the file stays readable without it
            for i in element.lines:
                lines[i] = None
    head = "\n".join(ln for ln in lines if ln is not None) + "\nend_header\n"
    return head.encode("latin-1") + b"".join(parts)


def _binary_rows(element: Element, body: memoryview, start: int, order: str) -> _Rows:
    """Rows of one element from ``start``: fixed-size rows (lists of one length each, the
    first row's, checked on every row at once) or, failing that, a walk row by row."""
    if element.count == 0:
        return _Rows(start, start)
    first_end, first_lengths = _walk_row(element, body, start, order, 0)
    size = first_end - start
    end = start + element.count * size
    if not first_lengths:
        if end > len(body):
            raise PlyError(f"the {cut(element.name)} rows run past the end of the body")
        return _Rows(start, end)
    if end <= len(body) and _uniform(element, body[start:end], size, first_lengths, order):
        return _Rows(start, end)
    if sum(p.is_list for p in element.properties) == 1:
        return _walk_one_list(element, body, start, order)
    offsets, lengths = [], []
    at = start
    for r in range(element.count):
        offsets.append(at)
        at, row_lengths = _walk_row(element, body, at, order, r)
        lengths.append(row_lengths)
    return _Rows(start, at, np.array(offsets, np.int64), np.array(lengths, np.int64))


def _one_list(element: Element) -> tuple[Property, int, int]:
    """An element's only list property and the bytes of the scalars before and after it."""
    k = next(i for i, p in enumerate(element.properties) if p.is_list)
    prefix = sum(np.dtype(p.kind).itemsize for p in element.properties[:k])
    suffix = sum(np.dtype(p.kind).itemsize for p in element.properties[k + 1:])
    return element.properties[k], prefix, suffix


def _fan_sizes(rows: _Rows) -> np.ndarray:
    """(F,) triangles of each face's fan (n − 2; none under 3 vertices)."""
    return np.maximum(rows.lengths[:, 0] - 2, 0)


def _walk_one_list(element: Element, body: memoryview, start: int, order: str) -> _Rows:
    """The rows of an element with one list property, walked in a tight loop (faces);
    a row that does not fit is handed to :func:`_walk_row` for its message."""
    lst, prefix, suffix = _one_list(element)
    count = struct.Struct(order + _STRUCT[lst.count_kind])
    entry = np.dtype(lst.kind).itemsize
    fixed = prefix + count.size + suffix
    unpack, end = count.unpack_from, len(body)
    offsets: list[int] = []
    lengths: list[int] = []
    at = start
    for r in range(element.count):
        try:
            (n,) = unpack(body, at + prefix)
        except struct.error:
            n = -1
        offsets.append(at)
        lengths.append(n)
        at += fixed + n * entry
        if n < 0 or at > end:
            _walk_row(element, body, offsets[-1], order, r)  # raises, naming the row and its list
            raise PlyError(f"{cut(element.name)} {r:,} runs past the end of the body")
    return _Rows(start, at, np.array(offsets, np.int64), np.array(lengths, np.int64)[:, None])


def _uniform(element: Element, rows: memoryview, size: int, lengths: list[int], order: str) -> bool:
    """Whether every row of ``rows`` (``size`` bytes each) has the first row's list lengths."""
    table = np.frombuffer(rows, np.uint8).reshape(element.count, size)
    at, lists = 0, iter(lengths)
    for p in element.properties:
        width = np.dtype(p.count_kind or p.kind).itemsize
        if p.is_list:
            n = next(lists)
            column = np.ascontiguousarray(table[:, at:at + width]).view(order + p.count_kind)
            if not (column == n).all():
                return False
            width += n * np.dtype(p.kind).itemsize
        at += width
    return True


def _walk_row(element: Element, body: memoryview, at: int, order: str, r: int) -> tuple[int, list[int]]:
    """Row ``r`` of ``element`` at byte ``at``: (the byte after it, its lists' lengths)."""
    lengths = []
    for p in element.properties:
        if p.is_list:
            width = np.dtype(p.count_kind).itemsize
            if at + width > len(body):
                raise PlyError(f"{cut(element.name)} {r:,} runs past the end of the body")
            (n,) = struct.unpack_from(order + _STRUCT[p.count_kind], body, at)
            if n < 0:
                raise PlyError(f"{cut(element.name)} {r:,}: list {quoted(p.name)} has negative length {n}")
            lengths.append(n)
            at += width + n * np.dtype(p.kind).itemsize
        else:
            at += np.dtype(p.kind).itemsize
        if at > len(body):
            raise PlyError(f"{cut(element.name)} {r:,} runs past the end of the body"
                           + (f" (its list {quoted(p.name)} says {lengths[-1]:,} entries)" if p.is_list else ""))
    return at, lengths


def _fan(element: Element, rows: _Rows, body: memoryview, order: str) -> tuple[bytes, int]:
    """A face element of mixed sizes as triangle fans (v0, vj, vj+1): the same row layout
    with every list of length 3; faces under 3 vertices are dropped. Returns the rows and
    their count."""
    lists = [p for p in element.properties if p.is_list]
    if len(lists) != 1:
        raise PlyError(f"faces of mixed sizes with {len(lists)} list properties "
                       f"({', '.join(p.name for p in lists)}) are not supported; triangulate before uploading")
    lst, prefix, suffix = _one_list(element)
    count_width, entry = np.dtype(lst.count_kind).itemsize, np.dtype(lst.kind).itemsize
    n = rows.lengths[:, 0]
    per_face = _fan_sizes(rows)
    triangles = int(per_face.sum())
    face = np.repeat(np.arange(len(n)), per_face)
    j = np.arange(triangles) - np.repeat(np.cumsum(per_face) - per_face, per_face) + 1
    base = rows.offsets[face]
    raw = np.frombuffer(body, np.uint8)
    entries = base + prefix + count_width

    def take(first: np.ndarray, width: int) -> np.ndarray:
        return raw[first[:, None] + np.arange(width)]

    three = np.broadcast_to(np.array([3], order + lst.count_kind).view(np.uint8), (triangles, count_width))
    table = np.concatenate([take(base, prefix), three, take(entries, entry), take(entries + j * entry, entry),
                            take(entries + (j + 1) * entry, entry), take(entries + n[face] * entry, suffix)], axis=1)
    return table.tobytes(), triangles


"""Image encoding for the service: sRGB PNG, linear float OpenEXR (single- and multi-part), npz.

Array convention (DESIGN.md): images are numpy arrays H×W[×C], row 0 = top. EXR stores
y increasing downward from the data window's top (line order INCREASING_Y), so row 0 of an
array is the first scanline of the file; no flip happens here.

PNG is 8-bit sRGB: float linear input is encoded with the exact piecewise sRGB curve.
EXR is linear float (no sRGB): float channels are FLOAT (32-bit), integer channels UINT
(32-bit). Channel naming (encode_exr / decode_exr):

=============  ====================  =============================================
key            array                 EXR channels
=============  ====================  =============================================
``"RGB"``      (H,W,3) float         R, G, B (FLOAT)
``"Z"``        (H,W) float           Z (FLOAT); +inf (background depth) round-trips
``"N"``        (H,W,3) float         N.x, N.y, N.z (FLOAT)
``"P"``        (H,W,3) float         P.x, P.y, P.z (FLOAT)
``"id"``       (H,W) unsigned int    id (UINT, full uint32 range)
``"object"``   (H,W) unsigned int    object (UINT)
other          (H,W) float           <name> (FLOAT)
other          (H,W) unsigned int    <name> (UINT)
``"diffuse"``,  (H,W,3) float         <name>.R, .G, .B (FLOAT): colour layers, as EXR
``"reflected"``                      tools (exrheader, Blender, Nuke) group them
other          (H,W,C) float, C 2-4  <name>.x, .y, .z, .w (FLOAT)
=============  ====================  =============================================

decode_exr inverts this: R, G, B -> "RGB"; <name>.R/.G/.B and <name>.x/.y[/.z[/.w]] ->
<name> (H,W,C); UINT
channels come back as uint32, FLOAT (and HALF) as float32. Invalid input raises ValueError.
"""

from __future__ import annotations

import io
import re

import numpy as np

__all__ = [
    "decode_exr",
    "decode_exr_multipart",
    "decode_npz",
    "decode_png",
    "encode_exr",
    "encode_exr_multipart",
    "encode_jpeg",
    "encode_npz",
    "encode_png",
    "linear_to_srgb",
    "srgb_to_linear",
]

_EXR_MAGIC = b"\x76\x2f\x31\x01"
_VECTOR_SUFFIXES = ("x", "y", "z", "w")
#: (H,W,3) float keys written as colour layers <name>.R/.G/.B (not vectors).
_COLOUR_KEYS = frozenset({"diffuse", "reflected"})
_FLOAT_KEYS = {"RGB": 3, "Z": None, "N": 3, "P": 3}  # name -> required C (None: (H,W))
_UINT_KEYS = ("id", "object")
_MAX_UINT32 = np.iinfo(np.uint32).max


# --------------------------------------------------------------------------------------
# sRGB transfer functions
# --------------------------------------------------------------------------------------
def _as_float(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x)
    if x.dtype.kind == "f":
        return x
    if x.dtype.kind in "biu":
        return x.astype(np.float64)
    raise ValueError(f"expected a numeric array, got dtype {x.dtype}")


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """Encode linear values in [0, 1] with the sRGB curve (IEC 61966-2-1):
    12.92·x for x ≤ 0.0031308, else 1.055·x^(1/2.4) − 0.055. Input is clipped to [0, 1]
    (NaN → 0); any shape; float input keeps its dtype, integer input becomes float64."""
    x = _as_float(x)
    x = np.clip(np.nan_to_num(x, nan=0.0), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055).astype(x.dtype, copy=False)


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """Decode sRGB values in [0, 1] to linear: x/12.92 for x ≤ 0.04045, else
    ((x + 0.055)/1.055)^2.4. Input is clipped to [0, 1] (NaN → 0); any shape; float input
    keeps its dtype, integer input becomes float64 (so pass uint8 data divided by 255)."""
    x = _as_float(x)
    x = np.clip(np.nan_to_num(x, nan=0.0), 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, np.power((x + 0.055) / 1.055, 2.4)).astype(x.dtype, copy=False)


# --------------------------------------------------------------------------------------
# PNG
# --------------------------------------------------------------------------------------
def encode_png(rgb: np.ndarray, *, compress_level: int = 6) -> bytes:
    """8-bit sRGB PNG from a linear float image.

    rgb: (H,W,3) colour or (H,W) grey, any float dtype, linear; values are clipped to
    [0, 1] (NaN → 0), sRGB-encoded and rounded to the nearest 8-bit level (linear 0.5 → 188).
    Grey input is written as an RGB image with equal channels. compress_level: zlib level 0–9.
    """
    return _save_srgb8(rgb, "encode_png", format="PNG", compress_level=compress_level)


def encode_jpeg(rgb: np.ndarray, *, quality: int = 80) -> bytes:
    """8-bit sRGB JPEG (baseline, 4:2:0) of a linear float image, levels as ``encode_png``
    makes them (the stream's frames while the camera moves). quality: 1–95."""
    return _save_srgb8(rgb, "encode_jpeg", _fast_levels, format="JPEG", quality=int(quality))


def _exact_levels(arr: np.ndarray) -> np.ndarray:
    return np.rint(linear_to_srgb(arr.astype(np.float64)) * 255.0).astype(np.uint8)


_SRGB_LUT: np.ndarray | None = None


def _fast_levels(arr: np.ndarray) -> np.ndarray:
    """8-bit sRGB levels through a 65536-entry table of the exact transfer function:
    faster than ``_exact_levels`` (no float64 transfer curve per pixel), at most one
    level off (tested); for the stream's lossy JPEG frames."""
    global _SRGB_LUT
    if _SRGB_LUT is None:
        _SRGB_LUT = _exact_levels(np.arange(65536) / 65535.0)
    x = np.nan_to_num(np.clip(arr.astype(np.float32, copy=False), 0.0, 1.0), nan=0.0) * 65535.0
    return _SRGB_LUT[np.rint(x).astype(np.uint16)]


def _save_srgb8(rgb: np.ndarray, where: str, levels_of=_exact_levels, **save: object) -> bytes:
    arr = np.asarray(rgb)
    if arr.dtype.kind != "f":
        raise ValueError(f"{where} expects linear float data, got dtype {arr.dtype}")
    if arr.ndim == 2:
        arr = arr[:, :, None].repeat(3, axis=2)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ValueError(f"{where} expects an (H,W,3) or (H,W) array, got shape {arr.shape}")
    if arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ValueError(f"{where}: empty image of shape {arr.shape}")
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(levels_of(arr)), mode="RGB").save(out, **save)
    return out.getvalue()


def decode_png(data: bytes) -> np.ndarray:
    """(H,W,3) uint8 sRGB levels of a PNG (grey, palette and alpha images are converted to
    RGB; alpha is dropped). Invalid data raises ValueError."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(io.BytesIO(bytes(data))) as img:
            if img.format != "PNG":
                raise ValueError(f"not a PNG image (format {img.format})")
            return np.asarray(img.convert("RGB"), dtype=np.uint8).copy()
    except (UnidentifiedImageError, Image.DecompressionBombError, OSError, SyntaxError) as exc:
        raise ValueError(f"invalid PNG data: {exc}") from exc


# --------------------------------------------------------------------------------------
# EXR
# --------------------------------------------------------------------------------------
def _exr_channels(channels: dict[str, np.ndarray], where: str) -> tuple[dict[str, np.ndarray], tuple[int, int]]:
    """Flat {exr channel name: contiguous (H,W) float32/uint32 array} and (H, W)."""
    if not isinstance(channels, dict) or not channels:
        raise ValueError(f"{where}: expected a non-empty dict of arrays")
    flat: dict[str, np.ndarray] = {}
    size: tuple[int, int] | None = None

    def put(name: str, arr: np.ndarray) -> None:
        if name in flat:
            raise ValueError(f"{where}: channel {name!r} given twice")
        flat[name] = np.ascontiguousarray(arr)  # OpenEXR misreads non-contiguous arrays

    for key, value in channels.items():
        if not isinstance(key, str) or not key or not re.fullmatch(r"[^\x00-\x1f]{1,255}", key):
            raise ValueError(f"{where}: invalid channel name {key!r}")
        arr = np.asarray(value)
        if arr.ndim not in (2, 3):
            raise ValueError(f"{where}: {key!r} must be (H,W) or (H,W,C), got shape {arr.shape}")
        hw = (int(arr.shape[0]), int(arr.shape[1]))
        if hw[0] < 1 or hw[1] < 1:
            raise ValueError(f"{where}: {key!r} is empty, shape {arr.shape}")
        if size is None:
            size = hw
        elif hw != size:
            raise ValueError(f"{where}: {key!r} is {hw[0]}x{hw[1]} (HxW) but other channels are {size[0]}x{size[1]}")

        kind = arr.dtype.kind
        if key in _UINT_KEYS or (key not in _FLOAT_KEYS and kind in "iu"):
            if kind not in "iu":
                raise ValueError(f"{where}: {key!r} must be an unsigned integer array, got dtype {arr.dtype}")
            if arr.ndim != 2:
                raise ValueError(f"{where}: {key!r} must be (H,W), got shape {arr.shape}")
            if arr.dtype.itemsize > 4 or kind == "i":
                lo, hi = int(arr.min()), int(arr.max())
                if lo < 0 or hi > _MAX_UINT32:
                    raise ValueError(f"{where}: {key!r} values [{lo}, {hi}] do not fit in uint32")
            put(key, arr.astype(np.uint32, copy=False))
            continue

        if kind != "f":
            raise ValueError(f"{where}: {key!r} must be a float array, got dtype {arr.dtype}")
        arr = arr.astype(np.float32, copy=False)
        want_c = _FLOAT_KEYS.get(key, "any")
        if want_c is None or (want_c == "any" and arr.ndim == 2):
            if arr.ndim != 2:
                raise ValueError(f"{where}: {key!r} must be (H,W), got shape {arr.shape}")
            put(key, arr)
        elif key == "RGB":
            if arr.ndim != 3 or arr.shape[2] != 3:
                raise ValueError(f"{where}: 'RGB' must be (H,W,3), got shape {arr.shape}")
            for i, c in enumerate("RGB"):
                put(c, arr[:, :, i])
        else:
            n = arr.shape[2] if arr.ndim == 3 else 0
            if (want_c != "any" and (arr.ndim != 3 or n != want_c)) or not 2 <= n <= 4:
                need = f"(H,W,{want_c})" if want_c != "any" else "(H,W) or (H,W,C) with C in 2..4"
                raise ValueError(f"{where}: {key!r} must be {need}, got shape {arr.shape}")
            suffixes = "RGB" if key in _COLOUR_KEYS and n == 3 else _VECTOR_SUFFIXES
            for i in range(n):
                put(f"{key}.{suffixes[i]}", arr[:, :, i])
    assert size is not None
    return flat, size


def _group_channels(flat: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Inverse of _exr_channels: R,G,B -> "RGB"; name.R/.G/.B and name.x/.y[/.z[/.w]] -> name (H,W,C)."""
    out: dict[str, np.ndarray] = {}
    used: set[str] = set()

    def same_float(names: list[str]) -> bool:
        arrays = [flat[n] for n in names]
        return all(a.dtype == np.float32 and a.shape == arrays[0].shape for a in arrays)

    if all(c in flat for c in "RGB") and same_float(list("RGB")):
        out["RGB"] = np.stack([flat["R"], flat["G"], flat["B"]], axis=-1)
        used.update("RGB")
    bases = sorted({(n.rsplit(".", 1)[0], n[-1]) for n in flat if n.endswith((".x", ".R"))})
    for base, first in bases:
        names = []
        for s in ("RGB" if first == "R" else _VECTOR_SUFFIXES):
            if f"{base}.{s}" not in flat:
                break
            names.append(f"{base}.{s}")
        if len(names) >= 2 and base not in flat and base not in out and same_float(names):
            out[base] = np.stack([flat[n] for n in names], axis=-1)
            used.update(names)
    for name, arr in flat.items():
        if name not in used:
            out[name] = arr
    return out


def _exr_header(size: tuple[int, int], display: tuple[int, int] | None = None) -> dict:
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    if display is not None:  # every part of a multi-part file must share the display window
        header["displayWindow"] = (np.array([0, 0], np.int32), np.array([display[1] - 1, display[0] - 1], np.int32))
    return header


def _write(exr_file) -> bytes:
    out = io.BytesIO()
    exr_file.write(out)
    return out.getvalue()


def encode_exr(channels: dict[str, np.ndarray]) -> bytes:
    """Single-part scanline EXR (ZIP compressed, lossless) from named arrays, all H×W.

    See the module docstring for the naming convention: e.g.
    ``{"RGB": (H,W,3) float, "Z": (H,W) float, "N": (H,W,3) float, "id": (H,W) uint32,
    "object": (H,W) uint16}``. Float data is stored as 32-bit float, integers as uint32.
    Raises ValueError on empty input, mismatched sizes, wrong shapes or dtypes.
    """
    import OpenEXR

    flat, size = _exr_channels(channels, "encode_exr")
    try:
        return _write(OpenEXR.File(_exr_header(size), flat))
    except (RuntimeError, TypeError) as exc:  # pragma: no cover - validated above
        raise ValueError(f"encode_exr: {exc}") from exc


def encode_exr_multipart(parts: list[tuple[str, dict[str, np.ndarray]]]
                         | list[tuple[str, dict[str, np.ndarray], dict]]) -> bytes:
    """Multi-part EXR: one part per (name, channels) pair, e.g. one part per depth image
    of a set. Parts may differ in size and channels; names must be unique, non-empty
    strings. Each part follows encode_exr's naming convention. A third item holds header
    attributes of the part (str, float, or a (4,4) float32 array as an M44f, e.g.
    OpenEXR's standard worldToCamera / worldToNDC). Raises ValueError."""
    import OpenEXR

    if not isinstance(parts, (list, tuple)) or not parts:
        raise ValueError("encode_exr_multipart: expected a non-empty list of (name, channels)")
    prepared = []
    seen: set[str] = set()
    for i, item in enumerate(parts):
        if not isinstance(item, (list, tuple)) or len(item) not in (2, 3):
            raise ValueError(f"encode_exr_multipart: part {i} is not a (name, channels[, attributes]) tuple")
        name, channels, attributes = (*item, {}) if len(item) == 2 else item
        if not isinstance(name, str) or not name or name in seen:
            raise ValueError(f"encode_exr_multipart: part {i} name {name!r} is empty, not a string or repeated")
        seen.add(name)
        flat, size = _exr_channels(channels, f"encode_exr_multipart part {name!r}")
        prepared.append((name, flat, size, dict(attributes)))
    display = (max(p[2][0] for p in prepared), max(p[2][1] for p in prepared))
    try:
        exr_parts = [OpenEXR.Part({**attributes, **_exr_header(size, display)}, flat, name)
                     for name, flat, size, attributes in prepared]
        return _write(OpenEXR.File(exr_parts))
    except (RuntimeError, TypeError) as exc:  # pragma: no cover - validated above
        raise ValueError(f"encode_exr_multipart: {exc}") from exc


def _read_exr(data: bytes):
    import OpenEXR

    data = bytes(data)
    if data[:4] != _EXR_MAGIC:
        raise ValueError("not an OpenEXR file (bad magic number)")
    try:
        return OpenEXR.File(io.BytesIO(data), separate_channels=True)
    except Exception as exc:  # the binding raises RuntimeError, sometimes others
        raise ValueError(f"invalid EXR data: {exc}") from exc


def _part_arrays(part) -> dict[str, np.ndarray]:
    flat: dict[str, np.ndarray] = {}
    for name, channel in part.channels.items():
        pixels = np.asarray(channel.pixels)
        flat[name] = pixels.astype(np.uint32 if pixels.dtype.kind in "iu" else np.float32, copy=False)
    return _group_channels(flat)


def decode_exr(data: bytes) -> dict[str, np.ndarray]:
    """Arrays of a single-part EXR, named as encode_exr names them (module docstring).
    A multi-part file raises ValueError (use decode_exr_multipart)."""
    exr = _read_exr(data)
    if len(exr.parts) != 1:
        raise ValueError(f"decode_exr: the file has {len(exr.parts)} parts; use decode_exr_multipart")
    try:
        return _part_arrays(exr.parts[0])
    except Exception as exc:
        raise ValueError(f"invalid EXR data: {exc}") from exc


def decode_exr_multipart(data: bytes) -> list[tuple[str, dict[str, np.ndarray]]]:
    """[(part name, arrays)] in file order; a single-part file gives one entry (named
    "part0" when it has no name). Arrays are named as in decode_exr."""
    exr = _read_exr(data)
    out = []
    try:
        for i, part in enumerate(exr.parts):
            out.append((part.name() or f"part{i}", _part_arrays(part)))
    except Exception as exc:
        raise ValueError(f"invalid EXR data: {exc}") from exc
    return out


# --------------------------------------------------------------------------------------
# npz
# --------------------------------------------------------------------------------------
def encode_npz(arrays: dict[str, np.ndarray]) -> bytes:
    """Compressed ``.npz`` of named numeric/bool arrays (any shapes), readable with
    ``np.load(io.BytesIO(data))`` without pickle. Raises ValueError for object dtypes or
    names that are not valid non-empty strings."""
    if not isinstance(arrays, dict) or not arrays:
        raise ValueError("encode_npz: expected a non-empty dict of arrays")
    clean = {}
    for key, value in arrays.items():
        if not isinstance(key, str) or not key or "/" in key:
            raise ValueError(f"encode_npz: invalid array name {key!r}")
        arr = np.asarray(value)
        if arr.dtype.kind not in "biuf":
            raise ValueError(f"encode_npz: {key!r} has unsupported dtype {arr.dtype}")
        clean[key] = arr
    out = io.BytesIO()
    np.savez_compressed(out, **clean)
    return out.getvalue()


def decode_npz(data: bytes) -> dict[str, np.ndarray]:
    """Inverse of encode_npz (no pickle). Invalid data raises ValueError."""
    try:
        with np.load(io.BytesIO(bytes(data)), allow_pickle=False) as npz:
            return {k: npz[k] for k in npz.files}
    except Exception as exc:
        raise ValueError(f"invalid npz data: {exc}") from exc

"""The one place where GL images are read back and flipped to row 0 = top, where
storage buffers of top-down planes are read into arrays, and where storage buffers
that shaders write with atomics are read back through a staging copy."""

from __future__ import annotations

from collections.abc import Sequence

import moderngl
import numpy as np

from gl_passes.releasable import grown_buffer

_DTYPES = {"f1": np.uint8, "f2": np.float16, "f4": np.float32, "u1": np.uint8, "u2": np.uint16,
           "u4": np.uint32, "i1": np.int8, "i2": np.int16, "i4": np.int32}


def read_texture(tex: moderngl.Texture, viewport: tuple[int, int, int, int] | None = None,
                 gl_rows: bool = False) -> np.ndarray:
    """Texture (or a viewport x, y, w, h of it, GL bottom-left origin) → numpy
    array (H,W) or (H,W,C), row 0 = top of the image; gl_rows=True keeps GL's
    order (row 0 = bottom), for callers that index texels as the shaders do."""
    w, h = tex.size
    dtype = _DTYPES[tex.dtype]
    arr = np.frombuffer(tex.read(), dtype=dtype).reshape(h, w, tex.components)  # row 0 = GL bottom
    if viewport:  # moderngl's Texture.read takes no viewport: crop the GL-oriented rows, then flip
        x, y, vw, vh = (int(v) for v in viewport)
        arr = arr[y:y + vh, x:x + vw]
    if not gl_rows:
        arr = arr[::-1]
    return np.ascontiguousarray(arr[..., 0] if tex.components == 1 else arr)


def read_planes(buf: moderngl.Buffer, shapes: Sequence[tuple[int, ...]], dtype: type = np.float32) -> list[np.ndarray]:
    """Consecutive planes of a storage buffer, each read straight into a fresh array
    of its shape: for buffers whose shader wrote their rows top-down (row 0 = top), so
    that a frame-sized output costs one copy and no flip (the caller issues the memory
    barrier)."""
    out, offset = [], 0
    for shape in shapes:
        arr = np.empty(shape, dtype)
        buf.read_into(arr, size=arr.nbytes, offset=offset)
        offset += arr.nbytes
        out.append(arr)
    return out


def read_buffer(buf: moderngl.Buffer, dtype: type, count: int, offset: int = 0) -> np.ndarray:
    """`count` elements of `dtype` of a buffer from byte `offset`, read straight into
    a fresh (count,) array (for buffers the shaders write without atomics; the
    caller issues the memory barrier and reshapes)."""
    arr = np.empty(int(count), dtype)
    if arr.nbytes:
        buf.read_into(arr, size=arr.nbytes, offset=offset)
    return arr


def read_texture_layer(arr_tex: moderngl.TextureArray, layer: int) -> np.ndarray:
    """One layer of a texture array, flipped like `read_texture`."""
    w, h, _ = arr_tex.size
    dtype = _DTYPES[arr_tex.dtype]
    full = np.frombuffer(arr_tex.read(), dtype=dtype).reshape(-1, h, w, arr_tex.components)[layer, ::-1]
    return np.ascontiguousarray(full[..., 0] if arr_tex.components == 1 else full)


def write_texture(tex: moderngl.Texture, image: np.ndarray) -> None:
    """Numpy image (H,W[,C]), row 0 = top, into `tex` (same size and components,
    its dtype), flipped to GL's bottom-up rows: the inverse of `read_texture`."""
    w, h = tex.size
    arr = np.asarray(image, dtype=_DTYPES[tex.dtype]).reshape(h, w, tex.components)
    tex.write(np.ascontiguousarray(arr[::-1]))


class StagingBuffer:
    """Reads storage buffers back through a copy into a buffer of its own, so that
    the buffers the shaders write (atomics above all) are never read by the CPU:
    a driver may move a buffer the CPU reads back every frame into host memory
    (NVIDIA's does), after which each of the GPU's atomics on it crosses the bus."""

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx
        self.buf: moderngl.Buffer | None = None

    def read(self, src: moderngl.Buffer, size: int, offset: int = 0) -> bytes:
        """`size` bytes of `src` from `offset` (waits for the GPU's writes before it,
        as Buffer.read does; the caller issues the memory barrier)."""
        if size <= 0:
            return b""
        self.buf = grown_buffer(self.ctx, self.buf, size, max(size, 64) * 2)
        self.ctx.copy_buffer(self.buf, src, size, read_offset=offset)
        return self.buf.read(size=size)

    def release(self) -> None:
        if self.buf is not None:
            self.buf.release()
            self.buf = None

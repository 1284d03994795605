"""The one place where GL images are read back and flipped to row 0 = top, and where
storage buffers that shaders write are read back through a staging copy."""

from __future__ import annotations

from collections.abc import Sequence

import moderngl
import numpy as np

from gl_passes.releasable import grown_buffer

_DTYPES = {"f1": np.uint8, "f2": np.float16, "f4": np.float32, "u1": np.uint8, "u2": np.uint16,
           "u4": np.uint32, "i1": np.int8, "i2": np.int16, "i4": np.int32}


def read_texture(tex: moderngl.Texture, viewport: tuple[int, int, int, int] | None = None) -> np.ndarray:
    """Texture (or a viewport x, y, w, h of it, GL bottom-left origin) → numpy
    array (H,W) or (H,W,C), row 0 = top of the image."""
    w, h = tex.size
    dtype = _DTYPES[tex.dtype]
    arr = np.frombuffer(tex.read(), dtype=dtype).reshape(h, w, tex.components)  # row 0 = GL bottom
    if viewport:  # moderngl's Texture.read takes no viewport: crop the GL-oriented rows, then flip
        x, y, vw, vh = (int(v) for v in viewport)
        arr = arr[y:y + vh, x:x + vw]
    arr = arr[::-1]
    return np.ascontiguousarray(arr[..., 0] if tex.components == 1 else arr)


class TextureReader:
    """Reads textures back into one reused scratch buffer and copies out the channel
    groups asked for, flipped to row 0 = top: one fresh array per part instead of a
    fresh read, a flipped copy and the parts (frame-sized images: each fresh
    allocation is paid again in page faults). The scratch keeps the largest size
    read until release()."""

    def __init__(self) -> None:
        self._scratch = np.empty(0, np.uint8)

    def read(self, tex: moderngl.Texture, parts: Sequence[int | slice]) -> list[np.ndarray]:
        """One (H,W) array per int part (a channel) and one (H,W,C) per slice part."""
        w, h = tex.size
        dtype = np.dtype(_DTYPES[tex.dtype])
        n = w * h * tex.components * dtype.itemsize
        if self._scratch.nbytes < n:
            self._scratch = np.empty(n, np.uint8)
        tex.read_into(self._scratch)
        arr = self._scratch[:n].view(dtype).reshape(h, w, tex.components)[::-1]  # row 0 = GL bottom → top
        return [np.array(arr[..., part], order="C", copy=True) for part in parts]

    def release(self) -> None:
        self._scratch = np.empty(0, np.uint8)


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

"""The list of a frame's reflective samples (technique 3, thesis Ch. 4): built on
the GPU tile by tile by the clustering's first pass (cluster_count.comp, §4.3), so
that the passes working per reflective sample — the clustering's assign and
accumulate passes, the cluster cameras' extent passes (§4.4) and the intersection
(Alg. 7) — dispatch over it (glDispatchComputeIndirect, the count never read
back) instead of over every G-buffer sample. On a CPU rasteriser an invocation
whose lanes are all non-reflective still runs its code under an empty lane mask;
most samples of a view are not reflective."""

from __future__ import annotations

import struct

import moderngl

from gl_passes.cluster_units import UNITS
from gl_passes.context import GLContext
from gl_passes.releasable import Releasable

HEADER_BYTES = 32  # n_samples, dispatch64[3], dispatch256[3], pad (reflective_list.glsl)
DISPATCH_OFFSET = {64: 4, 256: 16}  # byte offset of the indirect dispatch triple per group size


class ReflectiveSampleList(Releasable):
    """The list's storage buffer: emptied per frame (reset) and filled by
    cluster_count.comp; dispatches a per-sample pass over it (dispatch)."""

    def __init__(self, gl: GLContext) -> None:
        gl.check_thread()
        self.gl = gl
        self.buf: moderngl.Buffer | None = None

    def reset(self, size: tuple[int, int]) -> None:
        """Empty the list, with room for every sample of a (W, H) G-buffer, and bind
        it to UNITS' SampleList for the pass that fills it."""
        need = HEADER_BYTES + 4 * size[0] * size[1]
        if self.buf is None or self.buf.size < need:
            if self.buf is not None:
                self.buf.release()
            self.buf = self.gl.ctx.buffer(reserve=need)
        self.buf.write(struct.pack("8I", 0, 0, 1, 1, 0, 1, 1, 0))
        UNITS.bind_storage("SampleList", self.buf)

    def dispatch(self, prog: moderngl.ComputeShader, group_size: int) -> None:
        """Run `prog` (1D work groups of `group_size` = 64 or 256 invocations, each
        reading its sample with list_sample) once per listed sample, rounded up to
        whole groups (invocations past n_samples return)."""
        UNITS.bind_storage("SampleList", self.buf)
        prog.run_indirect(self.buf, DISPATCH_OFFSET[group_size])

    def release(self) -> None:
        if self.buf is not None:
            self.buf.release()
            self.buf = None

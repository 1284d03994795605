"""The list of a frame's reflective samples (technique 3, thesis Ch. 4): the
samples with a bin after the clustering (§4.3), built on the GPU tile by tile
(reflective_list.comp) so that the passes working per reflective sample — the
cluster cameras' extent passes (§4.4) and the intersection (Alg. 7) — dispatch
over it (glDispatchComputeIndirect, the count never read back) instead of over
every G-buffer sample. On a CPU rasteriser an invocation whose lanes are all
non-reflective still runs its code under an empty lane mask; most samples of a
view are not reflective."""

from __future__ import annotations

import struct

import moderngl

from gl_passes.cluster_units import UNITS
from gl_passes.context import GLContext
from gl_passes.releasable import Releasable
from gl_passes.shaders import compute_program

HEADER_BYTES = 32  # n_samples, dispatch64[3], dispatch256[3], pad (reflective_list.glsl)
DISPATCH_OFFSET = {64: 4, 256: 16}  # byte offset of the indirect dispatch triple per group size
GROUP = 16  # the list pass's work group side


class ReflectiveSampleList(Releasable):
    """Builds the list (build) and dispatches a per-sample pass over it (dispatch);
    the list's storage buffer stays bound to UNITS' SampleList after build."""

    def __init__(self, gl: GLContext) -> None:
        gl.check_thread()
        self.gl = gl
        self.prog = compute_program(gl, "reflective_list.comp", UNITS.defines())
        self.buf: moderngl.Buffer | None = None

    def build(self, bins: moderngl.Texture) -> None:
        """List the samples of `bins` (R32UI, 0 = not reflective) with a bin."""
        w, h = bins.size
        need = HEADER_BYTES + 4 * w * h
        if self.buf is None or self.buf.size < need:
            if self.buf is not None:
                self.buf.release()
            self.buf = self.gl.ctx.buffer(reserve=need)
        self.buf.write(struct.pack("8I", 0, 0, 1, 1, 0, 1, 1, 0))
        UNITS.bind_storage("SampleList", self.buf)
        UNITS.bind_texture("u_bins", bins)
        self.prog.run(-(-w // GROUP), -(-h // GROUP), 1)
        self.gl.ctx.memory_barrier()

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

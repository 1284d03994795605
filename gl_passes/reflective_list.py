"""The list of a frame's reflective samples, and of the 16×16 tiles holding any
(technique 3, thesis Ch. 4): built on the GPU tile by tile by the clustering's
first pass (cluster_count.comp, §4.3), so that the passes working per reflective
sample or tile — the clustering's passes after it, the cluster cameras' extent
passes (§4.4) and the intersection (Alg. 7) — dispatch over them
(glDispatchComputeIndirect, the counts never read back) instead of over every
G-buffer sample. On a CPU rasteriser an invocation
whose lanes are all non-reflective still runs its code under an empty lane mask;
most samples of a view are not reflective."""

from __future__ import annotations

import struct

import moderngl

from gl_passes.cluster_units import UNITS
from gl_passes.context import GLContext
from gl_passes.releasable import Releasable, grown_buffer
from gl_passes.shaders import compute_program

HEADER_BYTES = 32  # n_samples, dispatch64[3], dispatch256[3], pad (reflective_list.glsl)
TILE_HEADER_BYTES = 16  # n_tiles, dispatch_tiles[3]
DISPATCH_OFFSET = {64: 4, 256: 16}  # byte offset of the indirect dispatch triple per group size
TILE_DISPATCH_OFFSET = 4  # byte offset of dispatch_tiles
TILE = 16  # the lists' tile side (the clustering's work groups)
#: On a CPU rasteriser, consecutive listed samples per invocation of the passes that
#: reduce runs of them in registers (the clustering's accumulate pass, the cluster
#: cameras' extent passes); at most 255, so that a run's 2^24 fixed-point sums fit 32 bits.
LIST_RUN = 32


def run_defines(run: int, name: str = "run") -> dict[str, str]:
    """SAMPLE_RUN and RUN_GROUP (its invocations per work group) of a pass taking `run`
    consecutive listed samples per invocation, dispatched with dispatch(prog, 256);
    name: the caller's name for `run`, in the error."""
    if run < 1 or 256 % run:
        raise ValueError(f"{name} must divide 256, got {run}")
    return {"SAMPLE_RUN": str(run), "RUN_GROUP": str(256 // run)}


class ReflectiveSampleList(Releasable):
    """The lists' storage buffers (samples and tiles): emptied per frame (reset) and
    filled by cluster_count.comp, or built from a bin image (build); dispatches a
    pass over the samples (dispatch) or the tiles (dispatch_tiles)."""

    def __init__(self, gl: GLContext) -> None:
        gl.check_thread()
        self.gl = gl
        self.buf: moderngl.Buffer | None = None
        self.tiles: moderngl.Buffer | None = None

    def reset(self, size: tuple[int, int]) -> None:
        """Empty the lists, with room for every sample and tile of a (W, H)
        G-buffer, and bind them to UNITS' SampleList and TileList for the pass that
        fills them."""
        n_tiles = -(-size[0] // TILE) * -(-size[1] // TILE)
        self.buf = grown_buffer(self.gl.ctx, self.buf, HEADER_BYTES + 4 * size[0] * size[1])
        self.tiles = grown_buffer(self.gl.ctx, self.tiles, TILE_HEADER_BYTES + 4 * n_tiles)
        self.buf.write(struct.pack("8I", 0, 0, 1, 1, 0, 1, 1, 0))
        self.tiles.write(struct.pack("4I", 0, 0, 1, 1))
        self._bind()

    def build(self, bins: moderngl.Texture) -> None:
        """List the samples of `bins` (R32UI, 0 = not reflective) with a bin, and
        their tiles (reflective_list.comp; compiled on first use, since a frame's
        lists come from the clustering's count pass)."""
        self.reset(bins.size)
        UNITS.bind_texture("u_bins", bins)
        prog = compute_program(self.gl, "reflective_list.comp", UNITS.defines())
        prog.run(-(-bins.size[0] // TILE), -(-bins.size[1] // TILE), 1)
        self.gl.ctx.memory_barrier()

    def _bind(self) -> None:
        UNITS.bind_storage("SampleList", self.buf)
        UNITS.bind_storage("TileList", self.tiles)

    def dispatch(self, prog: moderngl.ComputeShader, group_size: int) -> None:
        """Run `prog` (1D work groups of `group_size` = 64 or 256 invocations, each
        reading its sample with list_sample) once per listed sample, rounded up to
        whole groups (invocations past n_samples return)."""
        self._bind()
        prog.run_indirect(self.buf, DISPATCH_OFFSET[group_size])

    def dispatch_tiles(self, prog: moderngl.ComputeShader) -> None:
        """Run `prog` with one work group per listed tile (list_tile)."""
        self._bind()
        prog.run_indirect(self.tiles, TILE_DISPATCH_OFFSET)

    def release(self) -> None:
        for attr in ("buf", "tiles"):
            buf = getattr(self, attr)
            if buf is not None:
                buf.release()
                setattr(self, attr, None)

"""Reflective-pixel clustering on the GPU (thesis §4.3; Alg. 6 step 2).

Reflective samples (s > 0) of the supersampled G-buffer are binned by
(normal θ bin, normal φ bin, reflector id). Per reflector R (object id), with
a_R = R's share of the reflective samples and n_v = the number of reflectors on
screen (§4.3 steps 2–3), the bin resolution is

    n_θ(R) = max(1, ceil(MAXTHETABINS · s_R)),  n_φ(R) = max(1, ceil(MAXPHIBINS · s_R))

and a sample with normal azimuth θ ∈ [0°, 360°) (atan2(n.z, n.x)) and polar
angle φ ∈ [0°, 180°] (acos n.y) goes to bin (⌊n_θ·θ/360°⌋, ⌊n_φ·φ/180°⌋, R).

The normal is the sample's mirror normal, the one its mirror ray is reflected about
(reflect_common.glsl mirror_normal): the interpolated shading normal, or the
geometric normal where the project's below-surface rule reflects about it
(reference.reflections.mirror_directions), turned toward the viewer. The thesis
bins "by the pixel's normal rather than by the reflected ray" (§4.3); with the
below-surface rule the two normals differ, and binning by the shading normal puts
such a sample's ray, far from its bin's others, into a cluster whose camera must
then widen to hold it: on a small curved reflector (a tap) the frustums grew to
near-hemispheres of coarse texels and most rays lost their hits
(bench/results/reflections_issue17_quality.md).
`bin_normal="shading"` keeps the shading normal (for comparison).

The scale s_R: the printed formula multiplies by a_R / n_v ("literal" rule). Taken
literally it gives every reflector a single bin as soon as a few reflectors are on
screen (25 reflectors: a_R / n_v ≈ 1/625), i.e. at most n_v clusters, which
contradicts the thesis's own cluster counts (Table 19: 120–195 clusters for 15–25
reflectors). The default "relative" rule reads a_R relative to the mean share 1/n_v:
s_R = min(1, a_R · n_v) — a reflector with an average or larger share gets the full
13 × 8 bins, smaller ones proportionally fewer (more pixels → finer, smaller share
among more reflectors → coarser). Both rules give a lone reflector 13 × 8 bins (a
sphere: at most 13·8/2 visible clusters, as §4.3 says). `bin_scale` multiplies s_R.

Two compute passes: `cluster_count.comp` counts reflective samples per object
(a tiny readback gives a_R and n_v), `cluster_assign.comp` writes each sample's
raw bin into an r32ui image and accumulates per-bin statistics with atomics into
an SSBO (count; position and normal sums in 64-bit fixed point). Only the
per-bin statistics are read back (13 uints per bin); empty bins are dropped and
the rest numbered 0..n−1 (the remap SSBO used by later passes).
"""

from __future__ import annotations

from dataclasses import dataclass

import moderngl
import numpy as np

from gl_passes.cluster_units import UNITS
from gl_passes.context import GLContext
from gl_passes.readback import read_texture
from gl_passes.shaders import compute_program
from gl_passes.uniforms import set_uniform

MAX_THETA_BINS = 13
MAX_PHI_BINS = 8
STATS_STRIDE = 13
FIXED = float(1 << 24)
GROUP = 16


@dataclass
class ClusterStats:
    """Per-cluster statistics (n clusters). object_id (n,) int 1-based reflector;
    bin (n,) raw bin index; count (n,) samples; mean_position (n,3) float64 P_c;
    normal_sum_length (n,) |mean of unit normals| (1 for a planar cluster);
    mean_normal (n,3) float64 unit n_c; bins_per_object (n_objects+1, 2) (n_θ, n_φ)."""

    object_id: np.ndarray
    bin: np.ndarray
    count: np.ndarray
    mean_position: np.ndarray
    mean_normal: np.ndarray
    normal_sum_length: np.ndarray
    bins_per_object: np.ndarray
    object_samples: np.ndarray

    @property
    def n(self) -> int:
        return len(self.count)


def bins_per_reflector(object_samples: np.ndarray, bin_scale: float = 1.0, rule: str = "relative") -> np.ndarray:
    """(n_objects+1, 2) int (n_θ, n_φ) per object id from reflective sample counts
    (index = object id; 0 and objects without reflective samples get (0, 0)).
    rule: "relative" (default, s_R = min(1, a_R·n_v)) or "literal" (s_R = a_R / n_v)."""
    if rule not in ("relative", "literal"):
        raise ValueError(f"bin rule must be 'relative' or 'literal', got {rule!r}")
    counts = np.asarray(object_samples, np.float64)
    total = counts.sum()
    out = np.zeros((len(counts), 2), np.int64)
    if total <= 0:
        return out
    vis = counts > 0
    n_v = int(vis.sum())
    a = counts[vis] / total
    factor = (np.minimum(1.0, a * n_v) if rule == "relative" else a / n_v) * bin_scale
    out[vis, 0] = np.maximum(1, np.ceil(MAX_THETA_BINS * factor - 1e-9)).astype(np.int64)
    out[vis, 1] = np.maximum(1, np.ceil(MAX_PHI_BINS * factor - 1e-9)).astype(np.int64)
    return out


def decode64(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return hi.astype(np.float64) * 4294967296.0 + lo.astype(np.float64)


class ClusteringPass:
    """Owns the count/assign programs, the raw-bin image and the stats SSBO."""

    def __init__(self, gl: GLContext, bin_normal: str = "mirror") -> None:
        gl.check_thread()
        if bin_normal not in ("mirror", "shading"):
            raise ValueError(f"bin_normal must be 'mirror' or 'shading', got {bin_normal!r}")
        self.gl = gl
        self.count_prog = compute_program(gl, "cluster_count.comp", UNITS.defines())
        self.assign_prog = compute_program(gl, "cluster_assign.comp", {
            **UNITS.defines(), **({"SHADING_NORMAL_BINS": "1"} if bin_normal == "shading" else {})})
        self.bins_tex: moderngl.Texture | None = None
        self._remap = np.full(1, -1, np.int32)  # raw bin → cluster index of the last run (−1: empty bin)
        self._buffers: dict[str, moderngl.Buffer] = {}

    def buffer(self, name: str, data: bytes) -> moderngl.Buffer:
        """A named SSBO holding `data` (grown when needed, reused across frames)."""
        buf = self._buffers.get(name)
        if buf is None or buf.size < len(data):
            if buf is not None:
                buf.release()
            buf = self.gl.ctx.buffer(reserve=max(len(data), 16) * 2)
            self._buffers[name] = buf
        buf.write(data)
        return buf

    def run(self, textures: dict[str, moderngl.Texture], bounds: tuple[np.ndarray, np.ndarray],
            n_objects: int, eye: np.ndarray, bin_scale: float = 1.0, rule: str = "relative") -> ClusterStats:
        """Cluster the reflective samples of a G-buffer (its textures on the GPU) seen
        from `eye`; the scene's mesh storage buffers (MeshVerts, MeshFaces) must be
        bound by the caller."""
        self.gl.check_thread()
        ctx = self.gl.ctx
        size = textures["obj_id"].size
        if self.bins_tex is None or self.bins_tex.size != size:
            if self.bins_tex is not None:
                self.bins_tex.release()
            self.bins_tex = ctx.texture(size, 1, dtype="u4")
            self.bins_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        groups = ((size[0] + GROUP - 1) // GROUP, (size[1] + GROUP - 1) // GROUP, 1)
        for name, key in (("u_obj", "obj_id"), ("u_material", "material"), ("u_normal", "normal"),
                          ("u_position", "position"), ("u_tri", "tri_id")):
            UNITS.bind_texture(name, textures[key])

        # Pass 1: reflective samples per object.
        counts_buf = self.buffer("obj_count", np.zeros(n_objects + 1, np.uint32).tobytes())
        UNITS.bind_storage("ObjCount", counts_buf)
        self.count_prog.run(*groups)
        ctx.memory_barrier()
        obj_samples = np.frombuffer(counts_buf.read(size=4 * (n_objects + 1)), np.uint32).copy()

        bins = bins_per_reflector(obj_samples, bin_scale, rule)
        per_obj = bins[:, 0] * bins[:, 1]
        base = np.concatenate([[0], np.cumsum(per_obj)[:-1]])
        n_bins = int(per_obj.sum())
        table = np.zeros((n_objects + 1, 4), np.uint32)
        table[:, 0], table[:, 1], table[:, 2] = base, np.maximum(bins[:, 0], 1), np.maximum(bins[:, 1], 1)
        UNITS.bind_storage("BinTable", self.buffer("bin_table", table.tobytes()))
        stats_buf = self.buffer("bin_stats", np.zeros(max(n_bins, 1) * STATS_STRIDE, np.uint32).tobytes())
        UNITS.bind_storage("BinStats", stats_buf)
        UNITS.bind_image("u_bin_image", self.bins_tex, read=False, write=True)
        lo, hi = (np.asarray(b, np.float64) for b in bounds)
        pad = 1e-3 * max(float(np.linalg.norm(hi - lo)), 1e-6)
        lo, hi = lo - pad, hi + pad
        prog = self.assign_prog
        set_uniform(prog, "u_lo", lo)
        set_uniform(prog, "u_eye", np.asarray(eye, np.float64))
        self._lo, self._ext = lo, hi - lo
        set_uniform(prog, "u_inv_ext", 1.0 / (hi - lo))
        prog.run(*groups)
        ctx.memory_barrier()
        raw = np.frombuffer(stats_buf.read(size=4 * max(n_bins, 1) * STATS_STRIDE), np.uint32)
        raw = raw[: n_bins * STATS_STRIDE].reshape(n_bins, STATS_STRIDE)
        nonempty = np.nonzero(raw[:, 0] > 0)[0]
        st = raw[nonempty]
        count = st[:, 0].astype(np.int64)
        pos = np.stack([decode64(st[:, 1 + 2 * k], st[:, 2 + 2 * k]) for k in range(3)], axis=1)
        nrm = np.stack([decode64(st[:, 7 + 2 * k], st[:, 8 + 2 * k]) for k in range(3)], axis=1)
        mean_pos = lo + pos / FIXED / np.maximum(count, 1)[:, None] * (hi - lo)
        mean_n = (nrm / FIXED / np.maximum(count, 1)[:, None]) * 2.0 - 1.0
        length = np.linalg.norm(mean_n, axis=1)
        unit_n = mean_n / np.maximum(length, 1e-12)[:, None]
        objs = np.nonzero(per_obj > 0)[0]
        owner = objs[np.searchsorted(base[objs], nonempty, side="right") - 1] if len(nonempty) else objs[:0]
        remap = np.full(max(n_bins, 1), -1, np.int32)
        remap[nonempty] = np.arange(len(nonempty), dtype=np.int32)
        self._remap = remap
        UNITS.bind_storage("Remap", self.buffer("remap", remap.tobytes()))
        return ClusterStats(object_id=owner, bin=nonempty, count=count, mean_position=mean_pos,
                            mean_normal=unit_n, normal_sum_length=length, bins_per_object=bins,
                            object_samples=obj_samples)

    def cluster_of_samples(self) -> np.ndarray:
        """(H,W) int32 cluster index (into the last run's ClusterStats) of each
        G-buffer sample, −1 for non-reflective samples (a read-back: diagnostics only)."""
        raw = read_texture(self.bins_tex).astype(np.int64)  # raw bin + 1, 0 = not reflective
        return np.where(raw > 0, self._remap[np.maximum(raw - 1, 0)], -1).astype(np.int32)

    def release(self) -> None:
        self.gl.check_thread()
        for b in self._buffers.values():
            b.release()
        self._buffers.clear()
        if self.bins_tex is not None:
            self.bins_tex.release()
            self.bins_tex = None

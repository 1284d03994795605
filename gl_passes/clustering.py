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

Components (issue 17, beyond the thesis's bins). §4.3 wants each cluster's camera
compact (design rule b) and adds the reflector id to the bin because "clustering by
the normal's orientation alone puts far-apart pixels of similar orientation into one
cluster", whose camera then covers too much; within one reflector the same holds
for pieces of a bin that do not touch on screen, and a bin also spans breaks of the
normal field (a planar face and its bevel), where one fitted plane and camera serve
neither side: a 20° bevel inside its face's bin made the face's cluster non-planar
and its camera shifted off the mirrored eye e0 (§4.4: a pinhole camera models a
planar reflector exactly, only from e0). With normal_break > 0 every bin is split
into the connected components of its samples, neighbours (4-connected) joined when
their mirror normals differ by at most normal_break degrees. A component of at
least min_samples samples is a segment of its own; the smaller ones stay with their
bin's remaining samples. Then (group_segments): a planar segment (its normals agree
and its plane offsets n·P span ≤ PLANAR_SPAN × the scene diagonal) is a cluster,
shared with the planar segments of its bin in the same plane (a plane seen in
pieces keeps one exact camera); a curved component is a cluster of its own
(split_curved; else it goes back to its bin's cluster). Planarity is thus judged
per cluster from its own normals, so a flat mirror inside a larger reflector
object keeps the exact e0 camera (cluster_camera.place_centers).

Passes (cluster_*.comp): `count` counts reflective samples per object (a tiny
readback gives a_R and n_v) and lists them (gl_passes.reflective_list: `assign`,
`accumulate` and the later steps' per-sample passes run over the list); `assign`
writes each reflective sample's raw bin (r32ui image) and mirror normal (rgba32f
image) and, for components, initialises the union-find labels; then a block
union-find (cluster_labels.glsl): `merge` unites each sample with its left and
upper neighbour when connected inside its 16×16 tile, in shared memory, and
labels it with its tile-local root; `border` unites the local
roots' sets across tile borders; `roots` points every local root at its
component's root (the least sample index); `compress` does the same for every
sample and counts the component; `split` lists the components of at least
min_samples samples (a readback of their number, root, bin and count);
`accumulate` writes each sample's segment (raw bin, or n_bins + its component's
list index) into the bin image and accumulates the per-segment statistics with
atomics into an SSBO (count; position and normal sums in 64-bit fixed point; the
plane-offset range), on a GPU summed per work group in shared memory first, on a
CPU rasteriser over runs of reflective_list.LIST_RUN listed samples in registers. Only
the per-segment statistics are read back (STATS_STRIDE uints each); empty
segments are dropped and the clusters numbered 0..n−1 (the remap SSBO, segment →
cluster, used by later passes).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import moderngl
import numpy as np

from gl_passes.cluster_units import UNITS
from gl_passes.context import GLContext
from gl_passes.laps import LapClock
from gl_passes.readback import StagingBuffer, read_texture
from gl_passes.reflective_list import LIST_RUN, ReflectiveSampleList, run_defines
from gl_passes.releasable import grown_buffer
from gl_passes.shaders import compute_program
from gl_passes.uniforms import set_uniform

MAX_THETA_BINS = 13
MAX_PHI_BINS = 8
STATS_STRIDE = 15
#: A component is planar when its mean unit normal is this long (its normals agree)
#: and its plane offsets n·P span at most PLANAR_SPAN × the scene diagonal.
PLANAR_LENGTH = 1.0 - 1e-6
PLANAR_SPAN = 1e-5
FIXED = float(1 << 24)
GROUP = 16  # work-group side of the passes, and the union-find's tile (TILE in the shaders)
LIST_GROUP = 256  # work group of the passes over the listed reflective samples (assign, accumulate)


@dataclass
class ClusterStats:
    """Per-cluster statistics (n clusters). object_id (n,) int 1-based reflector;
    bin (n,) raw bin index; component (n,) the root sample (linear index) of the
    first component of a cluster split off its bin (group_segments), −1 for a
    bin's cluster; count (n,) samples; mean_position (n,3) float64 P_c;
    normal_sum_length (n,) |mean of unit normals| (1 for a planar cluster);
    mean_normal (n,3) float64 unit n_c; bins_per_object (n_objects+1, 2) (n_θ, n_φ)."""

    object_id: np.ndarray
    bin: np.ndarray
    component: np.ndarray
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


def decode_ordered(u: np.ndarray) -> np.ndarray:
    """Inverse of f2o in reflect_common.glsl (order-preserving float ↔ uint)."""
    u = np.asarray(u, np.uint32)
    bits = np.where(u & np.uint32(0x80000000), u & np.uint32(0x7FFFFFFF), ~u).astype(np.uint32)
    return bits.view(np.float32).astype(np.float64)


def group_segments(seg_bin: np.ndarray, seg_root: np.ndarray, count: np.ndarray, normal_sum: np.ndarray,
                   offsets: np.ndarray, span: float, curved: bool = False) -> np.ndarray:
    """(n_seg,) int cluster of each segment (−1: empty), from the segments' raw bin,
    component root (−1: a bin's remaining samples), sample count, fixed-point
    mirror-normal sums and plane-offset range (min, max). A segment is planar when
    its normals agree (mean length ≥ PLANAR_LENGTH) and its offsets span at most
    `span`. The planar segments of a bin that lie in one plane (normals and offsets
    within those tolerances: pieces of one plane seen apart, or a bin's remaining
    samples in the plane of a component) share a cluster; a curved component is a
    cluster of its own when `curved`, else goes back to its bin's cluster (with the
    bin's remaining samples). Clusters are numbered in (raw bin, first component
    root) order, a bin's own cluster first."""
    n_seg = len(count)
    mean = normal_sum / FIXED / np.maximum(count, 1)[:, None] * 2.0 - 1.0
    length = np.linalg.norm(mean, axis=1)
    unit = mean / np.maximum(length, 1e-12)[:, None]
    planar = (count > 0) & (length >= PLANAR_LENGTH) & (offsets[:, 1] - offsets[:, 0] <= span)
    home = np.arange(n_seg)  # the segment whose cluster each segment joins
    bin_seg = {int(b): i for i, (b, r) in enumerate(zip(seg_bin, seg_root, strict=True)) if r < 0}
    if not curved:  # curved components back to their bin, which is then curved too
        back = np.nonzero((seg_root >= 0) & (count > 0) & ~planar)[0]
        home[back] = [bin_seg[int(b)] for b in seg_bin[back]]
        planar[home[back]] = False
    planes: dict[int, list[int]] = {}  # per bin: the first segment of each plane
    for i in np.lexsort((seg_root, seg_bin)):  # a bin's own segment first, then its components by root
        if not planar[i] or home[i] != i:
            continue
        b = int(seg_bin[i])
        for j in planes.setdefault(b, []):
            if np.dot(unit[i], unit[j]) >= PLANAR_LENGTH and abs(offsets[i].mean() - offsets[j].mean()) <= span:
                home[i] = j
                break
        else:
            planes[b].append(int(i))
    total = np.zeros(n_seg, np.int64)
    np.add.at(total, home, count)
    order = [i for i in np.lexsort((seg_root, seg_bin)) if home[i] == i and total[i] > 0]
    number = np.full(n_seg, -1, np.int64)
    number[order] = np.arange(len(order))
    return number[home]


class ClusteringPass:
    """Owns the clustering programs, the bin (segment) image, the mirror-normal image
    and the label, count and statistics SSBOs."""

    def __init__(self, gl: GLContext, bin_normal: str = "mirror", tile_sums: bool | None = None) -> None:
        """tile_sums: the statistics summed per work group in shared memory first
        (cluster_accumulate.comp), else over runs of LIST_RUN samples in
        registers; None: on a hardware renderer only (same sums)."""
        gl.check_thread()
        if bin_normal not in ("mirror", "shading"):
            raise ValueError(f"bin_normal must be 'mirror' or 'shading', got {bin_normal!r}")
        self.gl = gl
        units = {**UNITS.defines(), "STATS_STRIDE": str(STATS_STRIDE),
                 "TILE": str(GROUP), "TILE_SIDES": str(2 * GROUP), "TILE_HALF": str(GROUP // 2),
                 **({"SHADING_NORMAL_BINS": "1"} if bin_normal == "shading" else {})}
        self.tile_sums = not gl.is_software if tile_sums is None else bool(tile_sums)
        self.count_prog = compute_program(gl, "cluster_count.comp", units)
        self.assign_prog = compute_program(gl, "cluster_assign.comp", units)
        self.merge_prog = compute_program(gl, "cluster_merge.comp", units)
        self.border_prog = compute_program(gl, "cluster_border.comp", units)
        self.roots_prog = compute_program(gl, "cluster_roots.comp", units)
        self.compress_prog = compute_program(gl, "cluster_compress.comp", units)
        self.split_prog = compute_program(gl, "cluster_split.comp", units)
        self.accumulate_prog = compute_program(gl, "cluster_accumulate.comp", {
            **units, **({"TILE_SUMS": "1"} if self.tile_sums else run_defines(LIST_RUN))})
        self.samples = ReflectiveSampleList(gl)  # this frame's reflective samples, listed by the count pass
        self.pass_ms: dict[str, float] = {}  # run(timed=True): milliseconds per pass
        self.bins_tex: moderngl.Texture | None = None
        self.mnormal_tex: moderngl.Texture | None = None
        self._remap = np.full(1, -1, np.int32)  # segment → cluster index of the last run (−1: empty segment)
        self._buffers: dict[str, moderngl.Buffer] = {}
        self.staging = StagingBuffer(gl.ctx)  # reads the counts, split list and statistics back

    def buffer(self, name: str, data: bytes | None = None, size: int = 0) -> moderngl.Buffer:
        """A named SSBO holding `data` (or at least `size` bytes left as they are;
        grown when needed, reused across frames)."""
        need = len(data) if data is not None else size
        buf = self._buffers[name] = grown_buffer(self.gl.ctx, self._buffers.get(name), need, max(need, 16) * 2)
        if data is not None:
            buf.write(data)
        return buf

    def _images(self, size: tuple[int, int]) -> None:
        if self.bins_tex is not None and self.bins_tex.size == size:
            return
        for t in (self.bins_tex, self.mnormal_tex):
            if t is not None:
                t.release()
        self.bins_tex = self.gl.ctx.texture(size, 1, dtype="u4")
        self.mnormal_tex = self.gl.ctx.texture(size, 4, dtype="f4")
        for t in (self.bins_tex, self.mnormal_tex):
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)

    def run(self, textures: dict[str, moderngl.Texture], bounds: tuple[np.ndarray, np.ndarray],
            n_objects: int, eye: np.ndarray, bin_scale: float = 1.0, rule: str = "relative",
            normal_break: float = 0.0, min_samples: int = 1, curved: bool = False,
            timed: bool = False) -> ClusterStats:
        """Cluster the reflective samples of a G-buffer (its textures on the GPU) seen
        from `eye`; the scene's face normals (storage buffer FaceNormals) must be
        bound by the caller. normal_break > 0 (degrees) splits every raw bin into the
        connected components of its samples whose mirror normals differ by at most
        that much between neighbours; components of at least `min_samples` samples
        become clusters of their own (module docstring). timed: wait for each pass
        and keep its milliseconds in `pass_ms` (count, assign, merge, border,
        roots, compress, split, accumulate; "grouping": the CPU's part after them)."""
        self.gl.check_thread()
        ctx = self.gl.ctx
        clock = LapClock(ctx, sync=True, record=timed)
        self.pass_ms = clock.ms
        mark = clock.lap
        size = textures["obj_id"].size
        n_samples = size[0] * size[1]
        self._images(size)
        groups = ((size[0] + GROUP - 1) // GROUP, (size[1] + GROUP - 1) // GROUP, 1)
        for name, key in (("u_obj", "obj_id"), ("u_material", "material"), ("u_normal", "normal"),
                          ("u_position", "position"), ("u_tri", "tri_id")):
            UNITS.bind_texture(name, textures[key])

        # Pass 1: reflective samples per object; the list of reflective samples; the
        # non-reflective samples' bins (0) and union-find records.
        components = normal_break > 0
        counts_buf = self.buffer("obj_count", np.zeros(n_objects + 1, np.uint32).tobytes())
        UNITS.bind_storage("ObjCount", counts_buf)
        UNITS.bind_storage("Labels", self.buffer("labels", size=4 * n_samples))
        UNITS.bind_storage("CompCount", self.buffer("comp_count", size=4 * n_samples))
        UNITS.bind_image("u_bin_image", self.bins_tex, read=False, write=True)
        self.samples.reset(size)
        set_uniform(self.count_prog, "u_components", components)
        self.count_prog.run(*groups)
        ctx.memory_barrier()
        obj_samples = np.frombuffer(self.staging.read(counts_buf, 4 * (n_objects + 1)), np.uint32).copy()
        mark("count")

        bins = bins_per_reflector(obj_samples, bin_scale, rule)
        per_obj = bins[:, 0] * bins[:, 1]
        base = np.concatenate([[0], np.cumsum(per_obj)[:-1]])
        n_bins = int(per_obj.sum())
        table = np.zeros((n_objects + 1, 4), np.uint32)
        table[:, 0], table[:, 1], table[:, 2] = base, np.maximum(bins[:, 0], 1), np.maximum(bins[:, 1], 1)
        eye = np.asarray(eye, np.float64)

        # Pass 2: raw bins, mirror normals, labels of the listed reflective samples.
        UNITS.bind_storage("BinTable", self.buffer("bin_table", table.tobytes()))
        UNITS.bind_image("u_bin_image", self.bins_tex, read=False, write=True)
        UNITS.bind_image("u_mnormal_image", self.mnormal_tex, read=False, write=True)
        set_uniform(self.assign_prog, "u_eye", eye)
        set_uniform(self.assign_prog, "u_components", components)
        self.samples.dispatch(self.assign_prog, LIST_GROUP)
        ctx.memory_barrier()
        mark("assign")

        # Passes 3-5: components of continuous normal field, the large ones split off.
        n_reflective = int(obj_samples[1:].sum())
        min_samples = max(int(min_samples), 1)
        capacity = n_reflective // min_samples + 1 if components else 0
        split_buf = self.buffer("split", size=4 * (1 + 3 * capacity))
        split_buf.write(np.zeros(1, np.uint32).tobytes())
        UNITS.bind_storage("SplitList", split_buf)
        UNITS.bind_texture("u_mnormal", self.mnormal_tex)
        if components and n_reflective:
            self.label_components(self.bins_tex, self.mnormal_tex, normal_break, mark)
            set_uniform(self.split_prog, "u_min_samples", min_samples)
            set_uniform(self.split_prog, "u_capacity", capacity)
            self.samples.dispatch(self.split_prog, LIST_GROUP)
            ctx.memory_barrier()
            n_split = min(int(np.frombuffer(self.staging.read(split_buf, 4), np.uint32)[0]), capacity)
            mark("split")
        else:  # every sample stays in its raw bin (cluster_assign.comp marked no component)
            n_split = 0
        split = np.frombuffer(self.staging.read(split_buf, 4 * 3 * n_split, 4), np.uint32).reshape(n_split, 3) \
            if n_split else np.zeros((0, 3), np.uint32)

        # Pass 6: segments (raw bins, then the split components) and their statistics.
        n_seg = n_bins + n_split
        init = np.zeros((max(n_seg, 1), STATS_STRIDE), np.uint32)
        init[:, 13] = 0xFFFFFFFF  # offset minimum
        stats_buf = self.buffer("bin_stats", init.tobytes())
        UNITS.bind_storage("BinStats", stats_buf)
        UNITS.bind_image("u_bin_image", self.bins_tex, read=True, write=True)
        lo, hi = (np.asarray(b, np.float64) for b in bounds)
        diagonal = max(float(np.linalg.norm(hi - lo)), 1e-6)
        lo, hi = lo - 1e-3 * diagonal, hi + 1e-3 * diagonal
        prog = self.accumulate_prog
        set_uniform(prog, "u_lo", lo)
        set_uniform(prog, "u_inv_ext", 1.0 / (hi - lo))
        set_uniform(prog, "u_n_bins", n_bins)
        set_uniform(prog, "u_components", components)
        self.samples.dispatch(prog, LIST_GROUP)
        ctx.memory_barrier()
        raw = np.frombuffer(self.staging.read(stats_buf, 4 * max(n_seg, 1) * STATS_STRIDE), np.uint32)
        mark("accumulate")
        raw = raw[: n_seg * STATS_STRIDE].reshape(n_seg, STATS_STRIDE)
        seg_bin = np.concatenate([np.arange(n_bins), split[:, 1].astype(np.int64)])
        seg_root = np.concatenate([np.full(n_bins, -1), split[:, 0].astype(np.int64)])
        count = raw[:, 0].astype(np.int64)
        if int(count.sum()) != n_reflective:  # a sample went to no segment: every later pass would be wrong
            raise RuntimeError(f"clustering lost reflective samples: {int(count.sum())} of {n_reflective} are in "
                               f"its {n_seg} segments (GL renderer {self.gl.renderer})")
        pos = np.stack([decode64(raw[:, 1 + 2 * k], raw[:, 2 + 2 * k]) for k in range(3)], axis=1)
        nrm = np.stack([decode64(raw[:, 7 + 2 * k], raw[:, 8 + 2 * k]) for k in range(3)], axis=1)
        offsets = decode_ordered(raw[:, 13:15])
        cluster = group_segments(seg_bin, seg_root, count, nrm, offsets, PLANAR_SPAN * diagonal, curved)
        n = int(cluster.max()) + 1 if len(cluster) else 0
        sums = np.zeros((n, 7))
        live = cluster >= 0
        np.add.at(sums, cluster[live], np.concatenate([count[:, None], pos, nrm], axis=1)[live])
        count_c = sums[:, 0].astype(np.int64)
        mean_pos = lo + sums[:, 1:4] / FIXED / np.maximum(count_c, 1)[:, None] * (hi - lo)
        mean_n = (sums[:, 4:7] / FIXED / np.maximum(count_c, 1)[:, None]) * 2.0 - 1.0
        length = np.linalg.norm(mean_n, axis=1)
        unit_n = mean_n / np.maximum(length, 1e-12)[:, None]
        first = np.full(n, n_seg, np.int64)  # each cluster's first segment (its bin and component)
        np.minimum.at(first, cluster[live], np.nonzero(live)[0])
        objs = np.nonzero(per_obj > 0)[0]
        owner = objs[np.searchsorted(base[objs], seg_bin[first], side="right") - 1] if n else objs[:0]
        remap = cluster.astype(np.int32) if n_seg else np.full(1, -1, np.int32)
        self._remap = remap
        UNITS.bind_storage("Remap", self.buffer("remap", remap.tobytes()))
        mark("grouping")
        return ClusterStats(object_id=owner, bin=seg_bin[first], component=seg_root[first], count=count_c,
                            mean_position=mean_pos, mean_normal=unit_n, normal_sum_length=length,
                            bins_per_object=bins, object_samples=obj_samples)

    def label_components(self, bins: moderngl.Texture, mnormal: moderngl.Texture, normal_break: float,
                         mark: Callable[[str], None] = lambda name: None) -> None:
        """The block union-find (module docstring): passes merge, border, roots and
        compress over a raw-bin image (r32ui, bin + 1, 0 = not reflective) and a
        mirror-normal image of the same size. On entry self.samples lists the
        reflective samples and tiles of `bins` (the count pass, or
        self.samples.build(bins)), the "labels" SSBO holds each sample's own linear
        index (NONE where not reflective) and "comp_count" zeros at the reflective
        samples (cluster_count.comp's and cluster_assign.comp's initialisation); on
        return every reflective sample's label is its component's root (the least
        linear index in it) and comp_count at a root the component's size. mark(name) is called after each pass."""
        ctx = self.gl.ctx
        size = bins.size
        UNITS.bind_storage("Labels", self.buffer("labels", size=4 * size[0] * size[1]))
        UNITS.bind_storage("CompCount", self.buffer("comp_count", size=4 * size[0] * size[1]))
        UNITS.bind_texture("u_bins", bins)
        UNITS.bind_texture("u_mnormal", mnormal)
        for prog in (self.merge_prog, self.border_prog):
            set_uniform(prog, "u_cos_break", float(np.cos(np.radians(normal_break))))
        for prog in (self.roots_prog, self.compress_prog):
            set_uniform(prog, "u_size", tuple(int(x) for x in size))
        for name, prog in (("merge", self.merge_prog), ("border", self.border_prog)):
            self.samples.dispatch_tiles(prog)
            ctx.memory_barrier()
            mark(name)
        for name, prog in (("roots", self.roots_prog), ("compress", self.compress_prog)):
            self.samples.dispatch(prog, LIST_GROUP)
            ctx.memory_barrier()
            mark(name)

    def cluster_of_samples(self) -> np.ndarray:
        """(H,W) int32 cluster index (into the last run's ClusterStats) of each
        G-buffer sample, −1 for non-reflective samples (a read-back: diagnostics only)."""
        raw = read_texture(self.bins_tex).astype(np.int64)  # segment + 1, 0 = not reflective
        return np.where(raw > 0, self._remap[np.maximum(raw - 1, 0)], -1).astype(np.int32)

    def release(self) -> None:
        self.gl.check_thread()
        for b in self._buffers.values():
            b.release()
        self._buffers.clear()
        self.staging.release()
        self.samples.release()
        for t in (self.bins_tex, self.mnormal_tex):
            if t is not None:
                t.release()
        self.bins_tex = self.mnormal_tex = None

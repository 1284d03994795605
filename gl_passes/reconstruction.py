"""Scene reconstruction from depth images (thesis Ch. 3, §3.2, Alg. 4).

* Offset image H (Alg. 4, first line): the image I's camera with its image
  window grown by half a pixel on every side and one more pixel column and row,
  so H's (W+1)×(H+1) pixel centres are exactly I's pixel corners (the thesis's H
  has I's resolution and misses the last row and column of corners; ours
  covers them all). H is rendered by I's method: for a non-redundant image I_i
  with the same previous images I_0..I_{i−1} bound, so it samples the same
  surfaces; for a peeling layer, as that layer of the offset camera's peeling.
* Hybrid reconstruction (Alg. 4): every sample of I becomes two triangles over
  its pixel. Corner c comes from H where H's sample at c lies on the sample's
  surface (same triangle id, or within `plane_tolerance` pixel footprints of the
  sample's tangent plane and — the depth gate — its depth within 2 ·
  `max_corner_extent` footprints per half pixel between them of the sample's,
  unless both lie on one smooth surface: same_surface in reconstruct_common.glsl),
  as a vertex shared by every sample taking it (indexed mesh: a continuous surface
  gives a watertight mesh, a sphere included; tests/test_reconstruction.py);
  otherwise it is the intersection
  of c's camera ray with the sample's tangent plane, with its depth clamped to ±
  `max_corner_extent` pixel footprints of the sample's (grazing planes; Alg. 4
  states no clamp). The clamp defaults to 2 footprints: a corner stays on the
  tangent plane where the plane's depth changes by at most that much over the
  half pixel (0.5 px, or 0.71 px diagonally) to the corner, i.e. for planes up to
  76° (70.5° in the worst direction) from facing the camera; steeper planes are
  flattened toward the image plane. Without a tight clamp, a tangent plane seen
  at a grazing angle (a silhouette, a blade or twig seen edge-on) becomes a fin
  along the view ray, which light samples away from the capturing eye see
  broadside (bench/results/soft_shadows.md, "Reference cameras and the corner
  clamp"); the depth gate keeps H from bringing the same fin back: near a grazing
  tangent plane every point along the corner ray is near the plane. A smooth
  surface passes the gate (`smooth_surfaces`): where the neighbour's normal is
  within 18° of the sample's (cosine 0.95) and each lies within `plane_tolerance`
  footprints of the other's tangent plane, as on a sphere turning grazing near its
  outline, whose true depth runs past the clamp (with the gate alone such a corner
  splits into two vertices on one camera ray: the mesh is not watertight there);
  the far surface behind a grazing sample faces another way. A surface in the
  sample's plane but apart from it passes too, as it passes Alg. 4's plane test
  without the gate (the gap tables measure the rule's effect). Every corner
  lies on its pixel corner's camera ray, so each quad covers exactly its pixel as
  seen from I's camera.
  Beyond Alg. 4 (each a `ReconstructionSettings` flag, on by default; their
  effects are measured in the soft-shadow report's gap tables):
  - joined corners: neighbours on one surface (edge-adjacent, same_surface both
    ways) that both lack H at a corner share one tangent-plane vertex there (the
    mean of their intersections), so a surface narrower than a pixel (a blade, a
    twig) is one connected strip, watertight along its length, instead of a row
    of separate quads; an isolated sample still gives one quad of its own.
  - evidence (`reconstruct_set`): image i of a set is reconstructed knowing
    images 0..i−1. Each image rounds a surface's outline to its own pixel grid,
    which is unbiased for one image but not for a union: NR image i keeps exactly
    the samples beyond the earlier images' rounded outlines, and its own whole
    pixels then reach past the true edge. Where an earlier image saw past a
    tangent-plane corner (its texel there holds nothing, or something farther)
    and none holds a sample at the corner's depth, the edge lies between the
    sample and that image's missing ray: the corner moves to their middle
    (shaders/reconstruct_evidence.glsl).
  Three compute passes (shaders/reconstruct_hybrid_*.comp).
* Grid reconstruction (the baseline of §3.2): neighbouring pixel centres joined
  into two triangles unless a depth discontinuity separates them
  (shaders/reconstruct_grid.comp); isolated samples give nothing.
* Compact reconstruction (beyond the thesis): each image's hybrid mesh
  simplified by meshoptimizer with an absolute error bound of `compact_error`
  measured in the capturing image (`image_space`: pixels across it, and in depth
  one footprint at the median sample depth, the nearer the tighter); borders
  and discontinuities stay where they are up to that bound (edge collapses keep
  the mesh's topology, so no surface is joined across a discontinuity). The
  bound is the simplifier's quadric error, not a distance: a piece narrower than
  it would collapse to nothing, so a piece the simplifier drops whole is kept as
  it was (`keep_pieces`).

Meshes are `MeshGPU`s (positions in world units, linear vertex colours
quantised to RGBA8), triangles counter-clockwise as seen from the capturing
camera, vertices in first-use order (`fetch_order`: the compute passes append
in whatever order their invocations run; its effect on a vertex-bound
rasteriser's shadow maps is measured in Fig. 20). `export_glb` writes one node
per source image.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Literal

import meshoptimizer
import moderngl
import numpy as np

from gl_passes.bindings import Units
from gl_passes.context import GLContext
from gl_passes.depth_images import DepthImageRenderer, prepare_cameras
from gl_passes.mesh_gpu import VERTEX_BYTES, MeshGPU, pack_colors
from gl_passes.quad_splats import splats_last, triangle_pieces
from gl_passes.readback import StagingBuffer, read_buffer
from gl_passes.releasable import Releasable, ReleasedOnError, Scratch
from gl_passes.shaders import compute_program
from gl_passes.uniforms import set_uniform
from gl_passes.upload import SceneGPU
from scenes.camera import Camera
from scenes.depth_image import DepthImage

Reconstruction = Literal["hybrid", "grid", "compact"]
SamplingMethod = Literal["non_redundant", "conventional", "peeling"]
RECONSTRUCTIONS: tuple[str, ...] = ("hybrid", "grid", "compact")
SAMPLING_METHODS: tuple[str, ...] = ("non_redundant", "conventional", "peeling")
CompactMeasure = Literal["image", "world"]
COMPACT_MEASURES: tuple[str, ...] = ("image", "world")

#: Most earlier images a hybrid reconstruction takes as evidence (reconstruct_evidence.glsl).
MAX_EVIDENCE = 15
_GROUP = 8  # local size of the reconstruction compute shaders (x and y)
#: Units of every reconstruction shader (shared, so one binding serves all passes).
_UNITS = Units(images=("u_i_a", "u_i_b", "u_h_a", "u_h_b", "u_flags", "u_sample_corner", "u_evidence"),
               storage=("Vertices", "Indices", "Counters"))


@dataclass(frozen=True)
class ReconstructionSettings:
    """How depth images become meshes (Alg. 4 and its baselines).

    kind: "hybrid" (Alg. 4), "grid" (baseline) or "compact" (hybrid, simplified).
    plane_tolerance: same-surface test, in pixel footprints (the world size of one
    pixel at the sample's depth): a neighbour within this distance of the sample's
    tangent plane is on its surface. max_corner_extent: grazing clamp of a
    tangent-plane corner's depth, in pixel footprints (see the module docstring).
    depth_gate: a neighbour of another triangle is on the surface only within
    2 · max_corner_extent footprints per half pixel of separation of the sample's
    depth as well (reconstruct_common.glsl, same_surface). smooth_surfaces: ...
    unless both lie on one smooth surface (normals within 18°, each within
    plane_tolerance of the other's tangent plane; see the module docstring).
    join_corners:
    same-surface neighbours share their tangent-plane corners. evidence: corners
    are pulled in where an earlier image of the set saw past them, judged with
    evidence_tolerance of that image's pixel footprints (see the module docstring).
    compact_error: the compact mesh's absolute error bound, in pixels of the image
    across it and footprints at the median depth along it (`image_space`).
    compact_measure: "image" (that) or "world" (a diagnostic, the measure before:
    world units, compact_error footprints at the median depth in every direction).
    fetch_order: vertices in first-use order (`fetch_order`; the same mesh; its
    speed: Fig. 20). quad_splats: the triangles of the mesh's small pieces (at most
    `quad_splats.SPLAT_PIECE` triangles, each splat at most `SPLAT_PIXELS` across)
    are put last and drawn as splats in shadow maps (`gl_passes.quad_splats`: the
    same texels and depths, one compute invocation per quad or lone triangle and
    map, where `ShadowSettings.splat_raster_min` says it pays; the mesh, its export
    and its triangle count are the same). evidence_pull: the
    share of the evidence rule's move a corner makes (1: to the expected edge, 0:
    none; a diagnostic, the gap tables). offset_quads:
    a diagnostic (tried, not kept; the soft-shadow report's gap tables): > 0, an H
    sample that no sample of I takes as a corner becomes a quad of its own,
    ± offset_quads pixels around its pixel corner.
    offset_evidence: a diagnostic (tried, not kept; the gap tables): the share of
    the move a tangent-plane corner makes toward the middle of its samples and
    itself where H's own ray at that corner saw past it (0: none; 1: to the middle,
    the expected edge); `reconstruct_set` leaves peeling layers after the first
    without it (their H holds the corner ray's j-th surface, not its first past the
    sample)."""

    kind: Reconstruction = "hybrid"
    plane_tolerance: float = 1.0
    max_corner_extent: float = 2.0
    depth_gate: bool = True
    smooth_surfaces: bool = True
    join_corners: bool = True
    evidence: bool = True
    evidence_tolerance: float = 2.0
    compact_error: float = 0.4
    compact_measure: CompactMeasure = "image"
    fetch_order: bool = True
    quad_splats: bool = True
    evidence_pull: float = 1.0
    offset_quads: float = 0.0
    offset_evidence: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in RECONSTRUCTIONS:
            raise ValueError(f"reconstruction must be one of {RECONSTRUCTIONS}, got {self.kind!r}")
        for name in ("plane_tolerance", "max_corner_extent", "compact_error", "evidence_tolerance"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        if not 0.0 <= self.evidence_pull <= 1.0:
            raise ValueError(f"evidence_pull must be within [0, 1], got {self.evidence_pull!r}")
        if not 0.0 <= self.offset_evidence <= 1.0:
            raise ValueError(f"offset_evidence must be within [0, 1], got {self.offset_evidence!r}")
        if self.compact_measure not in COMPACT_MEASURES:
            raise ValueError(f"compact_measure must be one of {COMPACT_MEASURES}, got {self.compact_measure!r}")
        if not 0.0 <= self.offset_quads <= 0.5:
            raise ValueError(f"offset_quads must be within [0, 0.5] pixels, got {self.offset_quads!r}")


def offset_camera(camera: Camera) -> Camera:
    """Camera of the offset image H of an image taken with `camera` (Alg. 4): the
    same eye, orientation and clip planes, (W+1)×(H+1) pixels and a window grown by
    half a pixel per side, so H's pixel (i, j) centre is I's pixel corner (i, j)."""
    w, h = camera.width, camera.height
    t = np.tan(np.radians(camera.fov) / 2) * (h + 1) / h
    return replace(camera, width=w + 1, height=h + 1, fov=float(np.degrees(2 * np.arctan(t))))


def _position_words(img: DepthImage) -> np.ndarray:
    """(H, W, 4) uint32: the first rgba32ui texture of a depth image (position bits,
    triangle id; see reconstruct_common.glsl), all that an evidence image needs."""
    h, w = img.depth.shape
    a = np.empty((h, w, 4), np.uint32)
    a[..., :3] = np.ascontiguousarray(img.position, np.float32).view(np.uint32)
    a[..., 3] = img.tri_id
    return a


def _image_words(img: DepthImage) -> tuple[np.ndarray, np.ndarray]:
    """The two rgba32ui textures' contents of a depth image (see reconstruct_common.glsl)."""
    h, w = img.depth.shape
    b = np.empty((h, w, 4), np.uint32)
    b[..., :3] = np.ascontiguousarray(img.normal, np.float32).view(np.uint32)
    b[..., 3] = pack_colors(img.color)
    return _position_words(img), b


class Reconstructor(Releasable):
    """Compute programs for reconstructions on `gl`'s thread (cached on the
    context), and the staging buffer the atomic counters are read through; each
    reconstruction makes and frees its own scratch images. `release()` frees the
    staging buffer."""

    def __init__(self, gl: GLContext) -> None:
        gl.check_thread()
        self.gl = gl
        defines = _UNITS.defines()
        self.hybrid_passes = [compute_program(gl, f"reconstruct_hybrid_{name}.comp", defines)
                              for name in ("flags", "corners", "quads")]
        self.grid_prog = compute_program(gl, "reconstruct_grid.comp", defines)
        self.staging = StagingBuffer(gl.ctx)

    def release(self) -> None:
        self.gl.check_thread()
        self.staging.release()

    # --- helpers -----------------------------------------------------------------
    def _upload(self, img: DepthImage, temp: Scratch) -> tuple[moderngl.Texture, moderngl.Texture]:
        """The image's two word textures, made as `temp`'s."""
        a, b = _image_words(img)
        size = (a.shape[1], a.shape[0])
        return (temp(self.gl.ctx.texture(size, 4, a, dtype="u4")),
                temp(self.gl.ctx.texture(size, 4, b, dtype="u4")))

    def _set_camera(self, prog: moderngl.ComputeShader, camera: Camera, settings: ReconstructionSettings) -> None:
        r, u, f = camera.basis()
        t = np.tan(np.radians(camera.fov) / 2)
        set_uniform(prog, "u_size", (camera.width, camera.height))
        set_uniform(prog, "u_eye", np.asarray(camera.eye))
        set_uniform(prog, "u_forward", f)
        set_uniform(prog, "u_right", r * t * camera.aspect)
        set_uniform(prog, "u_up", u * t)
        set_uniform(prog, "u_footprint", camera.pixel_footprint)
        set_uniform(prog, "u_plane_tol", float(settings.plane_tolerance))
        set_uniform(prog, "u_max_extent", float(settings.max_corner_extent))
        set_uniform(prog, "u_depth_gate", bool(settings.depth_gate))
        set_uniform(prog, "u_smooth", bool(settings.smooth_surfaces))
        set_uniform(prog, "u_join", bool(settings.join_corners))
        set_uniform(prog, "u_offset_quads", float(settings.offset_quads))
        set_uniform(prog, "u_offset_evidence", float(settings.offset_evidence))
        set_uniform(prog, "u_e_tol", float(settings.evidence_tolerance))  # both evidence rules' depth test

    def _mesh(self, vbo: moderngl.Buffer, ibo: moderngl.Buffer, counters: moderngl.Buffer,
              settings: ReconstructionSettings, camera: Camera, n_vertices: int | None = None) -> MeshGPU:
        """A MeshGPU from the output buffers, trimmed to the counted size; read back
        and made again by `_upload_mesh` where settings.fetch_order or settings.quad_splats."""
        nv, ni = (int(x) for x in np.frombuffer(self.staging.read(counters, 8), np.uint32))
        counters.release()
        nv = nv if n_vertices is None else n_vertices
        ctx = self.gl.ctx
        if (settings.fetch_order or settings.quad_splats) and ni:
            records = read_buffer(vbo, np.float32, 4 * nv).reshape(-1, 4)
            indices = read_buffer(ibo, np.uint32, ni)
            vbo.release()
            ibo.release()
            return self._upload_mesh(records, indices, camera, settings)
        out = []
        with ReleasedOnError() as made:
            for buf, used in ((vbo, nv * VERTEX_BYTES), (ibo, ni * 4)):
                if used == buf.size:
                    out.append(buf)
                    continue
                trimmed = made(ctx.buffer(reserve=max(used, 16)))
                if used:
                    ctx.copy_buffer(trimmed, buf, size=used)
                buf.release()
                out.append(trimmed)
            return MeshGPU(self.gl, out[0], out[1], nv, ni // 3)

    def _upload_mesh(self, records: np.ndarray, indices: np.ndarray, camera: Camera,
                     settings: ReconstructionSettings) -> MeshGPU:
        """The MeshGPU of (N,4) vertex records and their triangles' indices (any
        shape): with settings.quad_splats its small pieces' triangles last, drawn as
        splats in shadow maps (`gl_passes.quad_splats.split_splats`); with
        settings.fetch_order its vertices in first-use order (`fetch_order`), else in
        their order, unused ones dropped."""
        tri = np.asarray(indices, np.uint32).reshape(-1, 3)
        quads = singles = 0
        if settings.quad_splats and len(tri):
            px, _ = camera.project(np.asarray(records[:, :3], np.float64))
            tri, quads, singles = splats_last(tri, px)
        if settings.fetch_order:
            records, tri = fetch_order(records, tri)
        else:
            used, tri = np.unique(tri, return_inverse=True)
            records = records[used]
        return MeshGPU.from_records(self.gl, records, tri.reshape(-1, 3), quads=quads, singles=singles)

    @staticmethod
    def _bind_outputs(vbo: moderngl.Buffer, ibo: moderngl.Buffer, counters: moderngl.Buffer) -> None:
        for name, buf in (("Vertices", vbo), ("Indices", ibo), ("Counters", counters)):
            _UNITS.bind_storage(name, buf)

    @staticmethod
    def _groups(w: int, h: int) -> tuple[int, int, int]:
        return (w + _GROUP - 1) // _GROUP, (h + _GROUP - 1) // _GROUP, 1

    # --- reconstructions -----------------------------------------------------------
    def hybrid(self, image: DepthImage, offset: DepthImage, settings: ReconstructionSettings,
               evidence: Sequence[DepthImage] = (), complete: Sequence[bool] = ()) -> MeshGPU:
        """Alg. 4: the mesh of `image` (W×H) with corners from its offset image
        ((W+1)×(H+1), see `offset_camera`). 2 triangles per sample. `evidence`: the
        earlier images of its set (I's size), `complete[j]` where an empty texel of
        evidence[j] is a miss (see reconstruct_evidence.glsl)."""
        self.gl.check_thread()
        h, w = image.depth.shape
        if offset.depth.shape != (h + 1, w + 1):
            raise ValueError(f"offset image must be {(h + 1, w + 1)}, got {offset.depth.shape}")
        if len(evidence) > MAX_EVIDENCE or len(complete) != len(evidence):
            raise ValueError(f"at most {MAX_EVIDENCE} evidence images, each with its completeness flag")
        if any(e.depth.shape != (h, w) for e in evidence):
            raise ValueError(f"evidence images must be {(h, w)}, as the image")
        ctx = self.gl.ctx
        n = image.n_samples
        quads = n + (offset.n_samples if settings.offset_quads else 0)  # samples' quads, H samples' own
        with ReleasedOnError() as made, Scratch() as temp:
            ia, ib = self._upload(image, temp)
            ha, hb = self._upload(offset, temp)
            flags = temp(ctx.texture((w, h), 1, dtype="u4"))  # 32-bit: llvmpipe's 8-bit image stores race
            sample_corner = temp(ctx.texture((2 * w, 2 * h), 1, dtype="u4"))
            if evidence:
                words = np.stack([_position_words(e) for e in evidence])
                ev = temp(ctx.texture_array((w, h, len(evidence)), 4, words, dtype="u4"))
            else:
                ev = temp(ctx.texture_array((1, 1, 1), 4, dtype="u4"))
            vbo = made(ctx.buffer(reserve=max(4 * quads * VERTEX_BYTES, 16)))  # ≤ 4 distinct corners per quad
            ibo = made(ctx.buffer(reserve=max(6 * quads * 4, 16)))
            counters = made(ctx.buffer(np.zeros(2, np.uint32).tobytes()))
            for name, tex in (("u_i_a", ia), ("u_i_b", ib), ("u_h_a", ha), ("u_h_b", hb), ("u_flags", flags),
                              ("u_sample_corner", sample_corner), ("u_evidence", ev)):
                _UNITS.bind_image(name, tex, read=True, write=name in ("u_flags", "u_sample_corner"))
            self._bind_outputs(vbo, ibo, counters)
            self._set_evidence(self.hybrid_passes[1], evidence, complete, settings)
            for prog, grid in zip(self.hybrid_passes, ((w, h), (w + 1, h + 1), (w, h)), strict=True):
                self._set_camera(prog, image.camera, settings)
                prog.run(*self._groups(*grid))
                ctx.memory_barrier()
            return self._mesh(vbo, ibo, counters, settings, image.camera)

    @staticmethod
    def _set_evidence(prog: moderngl.ComputeShader, evidence: Sequence[DepthImage], complete: Sequence[bool],
                      settings: ReconstructionSettings) -> None:
        set_uniform(prog, "u_n_evidence", len(evidence))
        if not evidence:
            return
        set_uniform(prog, "u_e_pull", float(settings.evidence_pull))
        arrays = {name: np.zeros((MAX_EVIDENCE, 3), np.float32) for name in ("u_e_eye", "u_e_forward",
                                                                                "u_e_right", "u_e_up")}
        footprint = np.zeros(MAX_EVIDENCE, np.float32)
        flag = np.zeros(MAX_EVIDENCE, np.int32)
        for j, (img, full) in enumerate(zip(evidence, complete, strict=True)):
            cam = img.camera
            r, u, f = cam.basis()
            t = np.tan(np.radians(cam.fov) / 2)
            arrays["u_e_eye"][j] = cam.eye
            arrays["u_e_forward"][j] = f
            arrays["u_e_right"][j] = r * t * cam.aspect
            arrays["u_e_up"][j] = u * t
            footprint[j] = cam.pixel_footprint
            flag[j] = int(full)
        for name, values in (*arrays.items(), ("u_e_footprint", footprint), ("u_e_complete", flag)):
            prog[name].write(values.tobytes())

    def grid(self, image: DepthImage, settings: ReconstructionSettings) -> MeshGPU:
        """The grid baseline: vertex y·W + x per sample, ≤ 2 triangles per 2×2 block."""
        self.gl.check_thread()
        h, w = image.depth.shape
        m = image.mask
        blocks = int((m[:-1, :-1].astype(np.int8) + m[1:, :-1] + m[:-1, 1:] + m[1:, 1:] >= 3).sum())
        ctx = self.gl.ctx
        with ReleasedOnError() as made, Scratch() as temp:
            ia, ib = self._upload(image, temp)
            vbo = made(ctx.buffer(reserve=max(w * h * VERTEX_BYTES, 16)))
            ibo = made(ctx.buffer(reserve=max(6 * blocks * 4, 16)))
            counters = made(ctx.buffer(np.zeros(2, np.uint32).tobytes()))
            prog = self.grid_prog
            _UNITS.bind_image("u_i_a", ia)
            _UNITS.bind_image("u_i_b", ib)
            self._bind_outputs(vbo, ibo, counters)
            self._set_camera(prog, image.camera, settings)
            prog.run(*self._groups(w, h))
            ctx.memory_barrier()
            return self._mesh(vbo, ibo, counters, settings, image.camera, n_vertices=w * h)

    def compact(self, mesh: MeshGPU, image: DepthImage, settings: ReconstructionSettings) -> MeshGPU:
        """`mesh` (a hybrid reconstruction of `image`) simplified with an error ≤
        compact_error in the image's own measure (`image_space`): pixels across
        the image, and the matching depth error."""
        self.gl.check_thread()
        records, tri = mesh.read_records()
        if len(tri) == 0:
            return MeshGPU.from_records(self.gl, records, tri)
        cam = image.camera
        records, tri = canonical_order(records, tri, cam)  # the same mesh gives the same simplification
        median = float(np.median(image.depth[image.mask]))
        if settings.compact_measure == "image":
            simplified = simplify(image_space(records[:, :3], cam, median), tri, settings.compact_error)
        else:
            simplified = simplify(records[:, :3], tri, settings.compact_error * cam.pixel_footprint * median)
        return self._upload_mesh(records, keep_pieces(tri, simplified), cam, settings)

    def reconstruct(self, image: DepthImage, offset: DepthImage | None, settings: ReconstructionSettings,
                    evidence: Sequence[DepthImage] = (), complete: Sequence[bool] = ()) -> MeshGPU:
        """One image's mesh by settings.kind (hybrid and compact need `offset`)."""
        if settings.kind == "grid":
            return self.grid(image, settings)
        if offset is None:
            raise ValueError(f"the {settings.kind} reconstruction needs the offset image")
        if settings.kind == "hybrid":
            return self.hybrid(image, offset, settings, evidence, complete)
        # compact: its input's vertex order is replaced by canonical_order and its quads
        # are found after simplifying, so neither is made here
        mesh = self.hybrid(image, offset, replace(settings, fetch_order=False, quad_splats=False), evidence, complete)
        try:
            return self.compact(mesh, image, settings)
        finally:
            mesh.release()


def fetch_order(records: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertex records (N,4) float32 and triangle indices (any shape, uint32) with the
    vertices put in first-use order and unused ones dropped (meshoptimizer's
    vertex-fetch optimisation): (N',4) records and the remapped indices, flat.
    The compute passes append vertices and triangles in whatever order their
    invocations run, and llvmpipe shades an indexed draw's vertices in batches of
    nearby indices (the effect on shadow maps: bench/results/soft_shadows.md, Fig. 20)."""
    idx = np.array(indices, np.uint32).ravel()  # a copy: remapped in place
    src = np.ascontiguousarray(records, np.float32)
    out = np.empty_like(src)
    n = meshoptimizer.optimize_vertex_fetch(out, idx, src, vertex_count=len(src), vertex_size=VERTEX_BYTES)
    return out[:n], idx


def _morton(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Z-order codes (uint64) of non-negative integer coordinates below 2^16."""
    def spread(v: np.ndarray) -> np.ndarray:
        v = v.astype(np.uint64) & np.uint64(0xFFFF)
        for shift, mask in ((8, 0x00FF00FF), (4, 0x0F0F0F0F), (2, 0x33333333), (1, 0x55555555)):
            v = (v | (v << np.uint64(shift))) & np.uint64(mask)
        return v
    return spread(x) | (spread(y) << np.uint64(1))


def canonical_order(records: np.ndarray, triangles: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Vertex records (N,4) sorted along a Z-order curve over `camera`'s image (¼ px
    cells; within one, by a hash of the record; identical records welded), and
    triangles (F,3) renumbered, each rotated to start at its least vertex (winding
    kept) and sorted: an order that depends on
    the mesh alone, not on the order the compute passes' atomics appended it in (the
    simplifier's collapses depend on its input's order), and keeps neighbours on the
    image together as those passes' tiles did (a rasteriser pays for scattered ones)."""
    px, _ = camera.project(records[:, :3].astype(np.float64))
    cell = np.clip(np.floor(np.nan_to_num(px) * 4), 0, 0xFFFF)
    # within a cell (vertices meet at pixel corners) by a hash of the record's bits
    bits = np.ascontiguousarray(records, np.float32).view(np.uint32).astype(np.uint64)
    mixed = np.zeros(len(bits), np.uint64)
    for k, prime in enumerate((0x9E3779B97F4A7C15, 0xC2B2AE3D27D4EB4F, 0x165667B19E3779F9, 0xD6E8FEB86659FD93)):
        mixed ^= (bits[:, k] + np.uint64(k)) * np.uint64(prime)
    order = np.argsort((_morton(cell[:, 0], cell[:, 1]) << np.uint64(32)) | (mixed >> np.uint64(32)))
    n = len(order)
    # identical records (the hybrid emits a few) sort side by side in an order the input sets:
    # every copy takes the first one's number, so the triangles weld them and no order remains
    ordered = records[order]
    same = np.concatenate([[False], np.all(ordered[1:] == ordered[:-1], axis=1)])
    first_of_run = np.maximum.accumulate(np.where(same, 0, np.arange(n)))
    rank = np.empty(n, np.int64)
    rank[order] = first_of_run
    t = rank[np.asarray(triangles, np.int64).reshape(-1, 3)]
    first = np.argmin(t, axis=1)
    t = np.take_along_axis(t, (first[:, None] + np.arange(3)) % 3, axis=1)
    if n < 2_000_000:  # (t0·n + t1)·n + t2 fits in int64
        t = t[np.argsort((t[:, 0] * n + t[:, 1]) * n + t[:, 2])]
    else:
        t = t[np.lexsort(t.T[::-1])]
    return ordered, t.astype(np.uint32)


def image_space(positions: np.ndarray, camera: Camera, median_depth: float) -> np.ndarray:
    """(N,3) float32 coordinates of world `positions` (N,3) in which the compact
    reconstruction's error is measured: pixel x, y of `camera`'s image and
    median_depth / (f·d), d the eye depth and f·d the pixel footprint at d
    (f = camera.pixel_footprint). The map is projective, so a plane stays a plane
    and a triangle's error is measured on the triangle drawn; a unit is one pixel
    across the image at any depth and, in depth, one footprint at the median depth
    (Δd ≤ e·(f·d)·d/median_depth at d)."""
    px, d = camera.project(np.asarray(positions, np.float64))
    return np.column_stack([px, median_depth / (camera.pixel_footprint * d)]).astype(np.float32)


def keep_pieces(triangles: np.ndarray, simplified: np.ndarray) -> np.ndarray:
    """(M'',3) uint32: `simplified` (the simplifier's output for `triangles` (M,3), on
    the same vertices) with every piece of `triangles` (connected through shared
    vertices) that it lost whole put back as it was. The simplifier's bound is a
    quadric error, not a distance: it collapses a piece narrower than the bound (a
    lone quad 1 × 0.3 px, a blade seen edge-on) to nothing."""
    tri = np.asarray(triangles, np.uint32).reshape(-1, 3)
    out = np.asarray(simplified, np.uint32).reshape(-1, 3)
    if len(tri) == 0:
        return out
    piece = triangle_pieces(tri)
    label = np.full(int(max(tri.max(), out.max(initial=0))) + 1, -1, np.int64)
    label[tri.ravel()] = np.repeat(piece, 3)
    alive = np.zeros(int(piece.max()) + 1, bool)
    kept = label[out[:, 0]]
    if (kept < 0).any():
        raise ValueError("the simplified triangles use a vertex no input triangle does")
    alive[kept] = True
    return np.concatenate([out, tri[~alive[piece]]])


def simplify(positions: np.ndarray, triangles: np.ndarray, max_error: float) -> np.ndarray:
    """(M',3) uint32 triangles of the mesh simplified by meshoptimizer with an
    absolute error ≤ max_error (in the units of `positions`), as few triangles as that allows."""
    idx = np.ascontiguousarray(triangles, np.uint32).ravel()
    pos = np.ascontiguousarray(positions, np.float32)
    out = np.empty_like(idx)
    n = meshoptimizer.simplify(out, idx, pos, target_index_count=0, target_error=float(max_error),
                               options=meshoptimizer.SIMPLIFY_ERROR_ABSOLUTE)
    return out[:n].reshape(-1, 3)


# --- depth-image sets with their offset images ---------------------------------------

@dataclass
class SampledSet:
    """A depth-image set and, per image, its offset image (None for the grid)."""

    method: str
    images: list[DepthImage]
    offsets: list[DepthImage] | None


def render_set(gl: GLContext, scene_gpu: SceneGPU, method: SamplingMethod, cameras: Sequence[Camera],
               layers: int = 4, offsets: bool = True, renderer: DepthImageRenderer | None = None,
               cull_back_faces: bool = True) -> SampledSet:
    """The depth images of `method` and (offsets=True) their offset images H.

    non_redundant / conventional: one image per camera (pixel redundancy, Alg. 3);
    peeling: `layers` layers from cameras[0]. Cameras get near/far from the scene.
    Without `renderer`, one made here with `cull_back_faces` (False: both sides of
    every surface, see `DepthImageRenderer`)."""
    if method not in SAMPLING_METHODS:
        raise ValueError(f"method must be one of {SAMPLING_METHODS}, got {method!r}")
    gl.check_thread()
    cams = prepare_cameras(scene_gpu, cameras)
    own = renderer is None
    r = DepthImageRenderer(gl, cull_back_faces=cull_back_faces) if own else renderer
    try:
        offs = [offset_camera(c) for c in cams] if offsets else None
        if method == "non_redundant":
            images, h = (r.non_redundant_with_offsets(scene_gpu, cams, offs) if offs
                         else (r.non_redundant(scene_gpu, cams), None))
        elif method == "conventional":
            images = r.conventional(scene_gpu, cams)
            h = r.conventional(scene_gpu, offs) if offs else None
        else:
            images = r.depth_peeling(scene_gpu, cams[0], layers)
            h = r.depth_peeling(scene_gpu, offs[0], layers) if offs else None
        return SampledSet(method, images, h)
    finally:
        if own:
            r.release()


def reconstruct_set(gl: GLContext, sampled: SampledSet, settings: ReconstructionSettings,
                    reconstructor: Reconstructor | None = None) -> list[MeshGPU]:
    """One mesh per image of `sampled` (the caller releases them); with
    settings.evidence, image i's hybrid mesh takes images 0..i−1 as evidence (all of
    them complete but a non-redundant set's later images, whose empty texels may be
    redundant samples rather than misses)."""
    own = reconstructor is None
    rec = Reconstructor(gl) if own else reconstructor
    try:
        images = sampled.images
        offs = sampled.offsets or [None] * len(images)
        with ReleasedOnError() as made:  # the meshes made so far, when a later one fails
            out = []
            for i, (img, off) in enumerate(zip(images, offs, strict=True)):
                earlier = images[max(0, i - MAX_EVIDENCE):i] if settings.evidence else []
                first = i - len(earlier)
                complete = [first + j == 0 or sampled.method != "non_redundant" for j in range(len(earlier))]
                mine = replace(settings, offset_evidence=0.0) if sampled.method == "peeling" and i > 0 else settings
                out.append(made(rec.reconstruct(img, off, mine, earlier, complete)))
            return out
    finally:
        if own:
            rec.release()


def export_glb(meshes: Sequence[MeshGPU], names: Sequence[str] | None = None) -> bytes:
    """`glb_bytes` of GPU meshes (reads them back on the GL thread)."""
    return glb_bytes([m.read() for m in meshes], names)


def glb_bytes(parts: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]], names: Sequence[str] | None = None,
              extras: Sequence[dict] | None = None) -> bytes:
    """A binary glTF with one node (and mesh) per source image with triangles, from (positions
    (N,3), RGBA8 colours (N,4), triangles (M,3)) as `MeshGPU.read` returns them:
    COLOR_0 vertex colours (linear), triangles counter-clockwise from the capturing
    camera; vertices no triangle uses are dropped. Every primitive has `SAMPLE_MATERIAL`;
    node k carries ``extras[k]`` (e.g. its camera) where given. No GL (call off the GL thread)."""
    import trimesh

    scene = trimesh.Scene()
    node_extras = {}
    for k, (pos, rgba, tri) in enumerate(parts):
        if len(tri) == 0:
            continue
        used, remap = np.unique(tri, return_inverse=True)
        tm = trimesh.Trimesh(pos[used], remap.reshape(-1, 3), vertex_colors=rgba[used], process=False)
        name = names[k] if names else f"image_{k}"
        scene.add_geometry(tm, node_name=name, geom_name=name)
        if extras is not None:
            node_extras[name] = extras[k]
    if scene.is_empty:  # the images saw nothing: a valid glTF with one empty scene (trimesh exports none)
        return _empty_glb()
    return _with_material(scene.export(file_type="glb"), node_extras)


#: The material of every reconstruction primitive. Its vertex colours are the captured
#: samples' colours, already shaded, and a depth image's surface is seen from either
#: side: unlit (KHR_materials_unlit) and two-sided; a viewer without the extension
#: falls back to a rough dielectric (glTF's default material, used when a primitive
#: names none, is a one-sided metal, which renders the colours nearly black).
SAMPLE_MATERIAL = {"name": "depth_image_samples", "doubleSided": True,
                   "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0,
                                            "roughnessFactor": 1.0},
                   "extensions": {"KHR_materials_unlit": {}}}


def _with_material(glb: bytes, node_extras: dict[str, dict]) -> bytes:
    """The GLB with `SAMPLE_MATERIAL` on every primitive and ``extras`` on the nodes named."""
    (json_len,) = struct.unpack_from("<I", glb, 12)
    doc = json.loads(glb[20:20 + json_len])
    doc["materials"] = [SAMPLE_MATERIAL]
    for mesh in doc.get("meshes", []):
        for primitive in mesh.get("primitives", []):
            primitive["material"] = 0
    doc["extensionsUsed"] = sorted({*doc.get("extensionsUsed", []), "KHR_materials_unlit"})
    for node in doc.get("nodes", []):
        if node.get("name") in node_extras:
            node["extras"] = node_extras[node["name"]]
    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)  # chunks are 4-byte aligned, JSON padded with spaces
    rest = glb[20 + json_len:]  # the BIN chunk, unchanged
    return struct.pack("<4sII", b"glTF", 2, 20 + len(text) + len(rest)) + struct.pack("<I4s", len(text), b"JSON") \
        + text + rest


def _empty_glb() -> bytes:
    """A binary glTF 2.0 holding one scene without nodes."""
    doc = json.dumps({"asset": {"version": "2.0", "generator": "depthview"}, "scene": 0, "scenes": [{}]}).encode()
    doc += b" " * (-len(doc) % 4)  # chunks are 4-byte aligned, JSON padded with spaces
    return struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(doc)) + struct.pack("<I4s", len(doc), b"JSON") + doc


def mesh_arrays(mesh: MeshGPU) -> tuple[np.ndarray, np.ndarray]:
    """(positions (N,3) float32, triangles (M,3) uint32) of a MeshGPU (for tests)."""
    pos, _, tri = mesh.read()
    return pos, tri


__all__ = ["ReconstructionSettings", "Reconstructor", "SampledSet", "export_glb", "glb_bytes", "offset_camera",
           "reconstruct_set", "render_set", "simplify"]

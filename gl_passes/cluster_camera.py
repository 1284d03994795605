"""Cluster cameras (thesis §4.4; Alg. 6 step 3.a) and their GPU extent passes.

Per cluster (P_c mean position, n_c mean normal from gl_passes.clustering):

1. fitting plane (P_c, n_c); e0 = the eye mirrored in it;
2. ray length (far distance along the reflected rays): the scene diagonal for
   mirrors, scenes.glossy.glossy_far for glossy reflectors (§4.6);
3. centre of projection e_c = e0 + (P_c − e0)·(1 − f), f = d_n / d_f (DESIGN.md's
   note: the printed e0 + (P_c − e0)·f would put a planar mirror's camera on the
   mirror). d_n, d_f are the diagonals of the AABBs of the ray start and end points
   centrally projected from e0 onto the fitting plane (GPU pass, stage 0: the mirror
   rays, of one sub-sample per output pixel in a cluster of at least
   ClusterSettings.stage0_dense samples, of every sample otherwise; stage 1 adds a
   glossy lobe's rim). The shift
   1 − f is clamped to [0, MAX_SHIFT]; a planar cluster (all start points on the
   plane, all normals equal) gets exactly e_c = e0;
4. image rectangle: the AABB of the clipped ray start and end points (glossy: the
   lobe-boundary end points too) projected from e_c (GPU pass, stage 1), in the
   frame of the primary camera mirrored in the fitting plane; near/far: the range of
   those points' depths. The fitting plane, shifted to the lowest start point (curved
   clusters: CLIP_DROP·d_n lower still), is the near CLIP plane of the depth image
   (gl_ClipDistance) and of every ray;
5. resolution: rectangle / (mean projected spacing of neighbouring samples of the
   cluster) × resolution_scale, capped at max_resolution; the rectangle is snapped
   to that spacing's grid anchored like the primary camera's sample grid, so that a
   planar mirror's cluster image has its texel centres exactly on the mirrored
   primary rays (texel size = sample size) and its intersections are exact.

Why the mirrored primary frame (not an image plane parallel to the fitting plane):
for a planar mirror it makes the cluster camera the primary camera mirrored, hence
one texel per reflected ray. Both frames give the same frustum family (off-axis,
centre e_c), only the image plane's orientation differs.
"""

from __future__ import annotations

from dataclasses import dataclass

import moderngl
import numpy as np

from gl_passes.chunks import box_corners, boxes_in_frustum, facing_away
from gl_passes.cluster_units import UNITS
from gl_passes.clustering import ClusterStats, decode_ordered
from gl_passes.context import GLContext
from gl_passes.readback import StagingBuffer
from gl_passes.reflective_list import LIST_RUN, TILE, ReflectiveSampleList, run_defines
from gl_passes.releasable import grown_buffer
from gl_passes.shaders import compute_program
from gl_passes.uniforms import set_uniform
from scenes.camera import Camera
from scenes.glossy import glossy_far, lobe_half_angle

EXT_STRIDE = 16
FRAME_FLOATS = 32  # 8 vec4, layout of ClusterFrame in reflect_common.glsl
MISC_SPARSE = 29  # misc.y of a stage-0 frame: the cluster's every sample read (stage0_frames)
MAX_SHIFT = 0.5
CLIP_DROP = 0.5  # curved clusters: clip plane lowered by CLIP_DROP·d_n below the lowest ray start
SPACING_FIXED = float(1 << 28)
EXTENT_GROUP = 256  # listed samples per stage-1 work group of cluster_extent.comp


@dataclass
class ClusterCamera:
    """One cluster's pinhole camera. Vectors are float64 (3,) world space."""

    index: int
    object_id: int
    samples: int
    glossiness: float
    plane_point: np.ndarray       # P_c
    plane_normal: np.ndarray      # n_c
    mirrored_eye: np.ndarray      # e0
    center: np.ndarray            # e_c
    f: float                      # d_n / d_f (eq. 6)
    shift: float                  # clamped 1 − f actually applied
    planar: bool
    d_n: float
    d_f: float
    right: np.ndarray
    up: np.ndarray
    forward: np.ndarray
    clip_offset: float            # keep dot(plane_normal, X) >= clip_offset
    ray_length: float             # far distance along the reflected rays
    rect: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # u0, v0, u1, v1 (tangent units)
    near: float = 1e-3
    far: float = 1.0
    spacing: float = 0.0          # tangent units per texel
    resolution: tuple[int, int] = (1, 1)
    atlas: tuple[int, int, int, int] = (0, 0, 1, 1)
    valid: bool = True

    def view_matrix(self) -> np.ndarray:
        m = np.eye(4)
        m[0, :3], m[1, :3], m[2, :3] = self.right, self.up, -self.forward
        m[:3, 3] = -m[:3, :3] @ self.center
        return m

    def projection_matrix(self) -> np.ndarray:
        u0, v0, u1, v1 = self.rect
        n, f = self.near, self.far
        m = np.zeros((4, 4))
        m[0, 0], m[0, 2] = 2.0 / (u1 - u0), (u1 + u0) / (u1 - u0)
        m[1, 1], m[1, 2] = 2.0 / (v1 - v0), (v1 + v0) / (v1 - v0)
        m[2, 2], m[2, 3] = -(f + n) / (f - n), -2.0 * f * n / (f - n)
        m[3, 2] = -1.0
        return m

    def view_projection(self) -> np.ndarray:
        return self.projection_matrix() @ self.view_matrix()

    def frame(self) -> np.ndarray:
        """(32,) float32 GPU record (ClusterFrame in reflect_common.glsl)."""
        half = float(lobe_half_angle(self.glossiness))
        return np.array([*self.center, self.near, *self.right, self.far, *self.up, self.ray_length,
                         *self.forward, half, *self.plane_normal, self.clip_offset, *self.rect,
                         *self.atlas, self.glossiness, 0, 0, 0], np.float32)


def mirror_point(e: np.ndarray, p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """e mirrored in the plane through p with unit normal n."""
    return e - 2.0 * np.dot(e - p, n) * n


def reflect(v: np.ndarray, n: np.ndarray) -> np.ndarray:
    return v - 2.0 * np.dot(v, n) * n


def plane_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal (t1, t2) ⟂ n (Duff et al. frame, as scenes.glossy)."""
    sign = 1.0 if n[2] >= 0 else -1.0
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    t1 = np.array([1 + sign * n[0] ** 2 * a, sign * b, -sign * n[0]])
    t2 = np.array([b, sign + n[1] ** 2 * a, -n[1]])
    return t1, t2


def camera_frame(camera: Camera, n: np.ndarray, p_c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(right, up, forward) of the primary camera mirrored in the plane (right-handed
    again: right = −reflect(r)). Falls back to the reflected central ray when the
    mirrored axis would look along the plane or behind it."""
    r, u, f = camera.basis()
    fwd = reflect(f, n)
    if np.dot(fwd, n) >= 0.1:
        return -reflect(r, n), reflect(u, n), fwd
    v = p_c - np.asarray(camera.eye)
    fwd = reflect(v / np.linalg.norm(v), n)
    up = reflect(u, n)
    up = up - np.dot(up, fwd) * fwd
    if np.linalg.norm(up) < 1e-6:
        up = plane_basis(fwd)[0]
    up /= np.linalg.norm(up)
    return np.cross(fwd, up), up, fwd


def ext_init(n: int) -> np.ndarray:
    e = np.zeros((max(n, 1), EXT_STRIDE), np.uint32)
    e[:, [0, 1, 4, 5, 8, 10]] = 0xFFFFFFFF
    return e


def initial_cameras(stats: ClusterStats, camera: Camera, materials: np.ndarray, diagonal: float) -> list[ClusterCamera]:
    """Steps 1–2 and e0 (before the stage-0 pass)."""
    eye = np.asarray(camera.eye, np.float64)
    cams = []
    for k in range(stats.n):
        p, n = stats.mean_position[k], stats.mean_normal[k]
        if np.dot(eye - p, n) < 0:  # keep the eye on the +n side (n_c faces the viewer)
            n = -n
        e0 = mirror_point(eye, p, n)
        g = float(materials[stats.object_id[k], 4])
        right, up, fwd = camera_frame(camera, n, p)
        cams.append(ClusterCamera(
            index=k, object_id=int(stats.object_id[k]), samples=int(stats.count[k]), glossiness=g,
            plane_point=p, plane_normal=n, mirrored_eye=e0, center=e0.copy(), f=1.0, shift=0.0, planar=False,
            d_n=0.0, d_f=0.0, right=right, up=up, forward=fwd, clip_offset=-1e30,
            ray_length=float(glossy_far(diagonal, g))))
    return cams


def stage0_frames(cams: list[ClusterCamera], dense_samples: int | None = None) -> np.ndarray:
    """Frames for stage 0: centre e0, plane basis, no clip plane; misc.y = 1 for a
    sparse cluster (fewer than dense_samples G-buffer samples, every cluster when
    None), whose every sample the extent pass reads (a dense one: one per output
    pixel, cluster_extent.comp)."""
    rows = []
    for c in cams:
        t1, t2 = plane_basis(c.plane_normal)
        d0 = float(np.dot(c.plane_point - c.mirrored_eye, c.plane_normal))
        tmp = ClusterCamera(**{**c.__dict__, "center": c.mirrored_eye, "right": t1, "up": t2,
                               "forward": c.plane_normal, "near": 1e-4 * max(d0, 1e-9), "clip_offset": -1e30})
        rows.append(tmp.frame())
    frames = np.asarray(rows, np.float32).reshape(-1, FRAME_FLOATS)
    frames[:, MISC_SPARSE] = [dense_samples is None or c.samples < dense_samples for c in cams]
    return frames


def place_centers(cams: list[ClusterCamera], ext: np.ndarray, stats: ClusterStats, diagonal: float,
                  max_shift: float = MAX_SHIFT) -> None:
    """Step 3 from the stage-0 extents: f, e_c, clip plane."""
    for c, e in zip(cams, ext, strict=True):
        start = decode_ordered(e[0:4])
        end = decode_ordered(e[4:8])
        zmin, zmax = decode_ordered(e[8:10])
        d0 = float(np.dot(c.plane_point - c.mirrored_eye, c.plane_normal))
        ok_s = np.all(np.isfinite(start)) and start[2] >= start[0]
        ok_e = np.all(np.isfinite(end)) and end[2] >= end[0]
        c.d_n = float(np.hypot(start[2] - start[0], start[3] - start[1])) * d0 if ok_s else 0.0
        c.d_f = float(np.hypot(end[2] - end[0], end[3] - end[1])) * d0 if ok_e else 0.0
        flat = (zmax - zmin) <= 1e-5 * diagonal and stats.normal_sum_length[c.index] >= 1.0 - 1e-6
        c.planar = bool(flat)
        c.f = c.d_n / c.d_f if c.d_f > 0 else 1.0
        c.shift = 0.0 if c.planar else float(np.clip(1.0 - c.f, 0.0, max_shift))
        c.center = c.mirrored_eye + (c.plane_point - c.mirrored_eye) * c.shift
        # Clip plane: the fitting plane moved down to the lowest ray start, and for a
        # curved cluster by a further CLIP_DROP·d_n, so that rays from its rim that
        # dip below the fitting plane still meet the geometry next to the reflector.
        c.clip_offset = float(np.dot(c.mirrored_eye, c.plane_normal) + (min(zmin, d0) if np.isfinite(zmin) else d0)
                              - 1e-6 * diagonal - (0.0 if c.planar else CLIP_DROP * c.d_n))


def stage1_frames(cams: list[ClusterCamera]) -> np.ndarray:
    rows = []
    for c in cams:
        dc = max(float(np.dot(c.plane_point - c.center, c.plane_normal)), 1e-9)
        c.near = 1e-3 * dc
        rows.append(c.frame())
    return np.asarray(rows, np.float32).reshape(-1, FRAME_FLOATS)


def finish_cameras(cams: list[ClusterCamera], ext: np.ndarray, camera: Camera, ss: int,
                   resolution_scale: float, max_resolution: int) -> None:
    """Steps 4–5 from the stage-1 extents: rectangle, near/far, spacing, resolution."""
    t = np.tan(np.radians(camera.fov) / 2)
    sample = 2.0 * t / (ss * camera.height)  # tangent size of one G-buffer sample (square pixels)
    anchor = np.array([-t * camera.aspect, -t])
    for c, e in zip(cams, ext, strict=True):
        s = decode_ordered(e[0:4])
        en = decode_ordered(e[4:8])
        zmin, zmax = decode_ordered(e[10:12])
        boxes = [b for b in (s, en) if np.all(np.isfinite(b)) and b[2] >= b[0] and b[3] >= b[1]]
        if not boxes or not (np.isfinite(zmin) and np.isfinite(zmax)) or zmax <= 0:
            c.valid = False
            c.rect, c.near, c.far, c.resolution = (-1.0, -1.0, 1.0, 1.0), 1e-3, 1.0, (1, 1)
            continue
        lo = np.min([b[:2] for b in boxes], axis=0)
        hi = np.max([b[2:] for b in boxes], axis=0)
        cnt = int(e[14])
        spacing = (float(e[13]) * 4294967296.0 + float(e[12])) / SPACING_FIXED / cnt if cnt else 0.0
        ext_uv = hi - lo
        if c.planar and (spacing == 0 or abs(spacing / sample - 1) < 0.02):
            spacing = sample
        if spacing <= 0:
            spacing = max(float(ext_uv.max()), 1e-9) / max(4.0, 2.0 * np.sqrt(c.samples))
        p = spacing / resolution_scale
        need = max(float(ext_uv.max()) / p, 1.0)
        if need > max_resolution:
            p *= need / max_resolution
        lo = anchor + np.floor((lo - anchor) / p - 1e-6) * p
        hi = anchor + np.ceil((hi - anchor) / p + 1e-6) * p
        res = np.maximum(np.rint((hi - lo) / p).astype(int), 1)
        c.spacing = p
        c.rect = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
        c.resolution = (int(res[0]), int(res[1]))
        c.near = max(0.98 * zmin, 1e-6 * zmax, 1e-9)
        c.far = max(1.02 * zmax, c.near * 1.01)


def pack_atlas(cams: list[ClusterCamera], max_size: int = 8192, budget: float | None = None) -> tuple[int, int]:
    """Shelf-pack the cluster images (tallest first). When their total area exceeds
    `budget` texels the images shrink uniformly, except planar mirrors' (glossiness
    0), which keep their texel = sample grid (exact intersections, one texel per
    sample, so they cost little) unless they alone exceed the budget; a planar
    glossy cluster shrinks with the others (its lobe rays spread its image far past
    its samples, and land between texel centres anyway). All shrink uniformly when
    the atlas would exceed max_size² (reported via each camera's resolution and
    spacing). Returns the atlas (width, height)."""
    live = [c for c in cams if c.valid]
    for c in cams:
        if not c.valid:
            c.atlas = (0, 0, 0, 0)  # the trace treats an empty viewport as a miss
    if not live:
        return 1, 1
    exact = {c.index for c in live if c.planar and c.glossiness <= 0}
    total = float(sum(c.resolution[0] * c.resolution[1] for c in live))
    fixed = float(sum(c.resolution[0] * c.resolution[1] for c in live if c.index in exact))
    scale = fscale = 1.0
    if budget and total > budget:
        if fixed < 0.5 * budget and total > fixed:
            scale = float(np.sqrt((budget - fixed) / (total - fixed)))
        else:
            scale = fscale = float(np.sqrt(budget / total))
    for _ in range(20):
        res = {c.index: tuple(max(1, int(np.ceil(r * (fscale if c.index in exact else scale)))) for r in c.resolution)
               for c in live}
        area = sum(w * h for w, h in res.values())
        width = int(min(max_size, max(max(w for w, _ in res.values()), np.ceil(np.sqrt(area * 1.15)))))
        x = y = shelf = 0
        place = {}
        for c in sorted(live, key=lambda c: -res[c.index][1]):
            w, h = res[c.index]
            if x + w > width:
                x, y, shelf = 0, y + shelf, 0
            place[c.index] = (x, y, w, h)
            x, shelf = x + w, max(shelf, h)
        height = y + shelf
        if height <= max_size and width <= max_size:
            break
        shrink = 0.9 * np.sqrt(max_size * max_size / (width * max(height, 1)))
        scale, fscale = scale * shrink, fscale * shrink
    for c in live:
        x, y, w, h = place[c.index]
        if (w, h) != c.resolution:  # shrunk to fit: widen the texel spacing accordingly
            c.spacing *= c.resolution[0] / w
            c.resolution = (w, h)
        c.atlas = (x, y, w, h)
    return width, height


def visible_boxes(cam: ClusterCamera, bounds: np.ndarray, corners: np.ndarray | None = None) -> np.ndarray:
    """(n,) bool: boxes (n, 2, 3) (min, max) that may intersect the cluster frustum
    (culled when all 8 corners are outside one clip-space plane or below the
    fitting-plane clip); corners: their box_corners when at hand (ChunkTable.corners)."""
    corners = box_corners(bounds) if corners is None else corners
    below = np.all(corners @ cam.plane_normal < cam.clip_offset, axis=1)
    return boxes_in_frustum(cam.view_projection(), bounds, corners) & ~below


def backfacing_chunks(cam: ClusterCamera, cones: np.ndarray) -> np.ndarray:
    """(n,) bool: triangle chunks (chunks.chunk_cones) all of whose triangles face
    away from the cluster camera's centre e_c (chunks.facing_away)."""
    return facing_away(np.asarray(cam.center, np.float64), cones)


def visible_objects(cam: ClusterCamera, object_bounds: np.ndarray) -> list[int]:
    """0-based objects whose AABB may intersect the cluster frustum."""
    return [int(k) for k in np.nonzero(visible_boxes(cam, object_bounds))[0]]


class ClusterExtentPass:
    """Runs cluster_extent.comp (both stages) and reads back the (n, 16) extents."""

    def __init__(self, gl: GLContext, sample_run: int | None = None) -> None:
        """sample_run: listed samples per invocation of either stage, reduced in
        registers (cluster_extent.comp; 1: stage 1 one sample, stage 0 one output
        pixel per invocation, into a shared record per work group); None:
        reflective_list.LIST_RUN on a software renderer, 1 otherwise (the same
        extents either way)."""
        self.gl = gl
        run = (LIST_RUN if gl.is_software else 1) if sample_run is None else int(sample_run)
        self._run_defines = run_defines(run, "sample_run")  # a stage-1 work group: EXTENT_GROUP samples
        self.sample_run = run
        self.ext_buf: moderngl.Buffer | None = None
        self.frame_buf: moderngl.Buffer | None = None
        self.staging = StagingBuffer(gl.ctx)  # reads the extents back (ext_buf stays the GPU's)

    def _buffer(self, attr: str, data: bytes) -> moderngl.Buffer:
        buf = grown_buffer(self.gl.ctx, getattr(self, attr), len(data), max(len(data), 64) * 2)
        setattr(self, attr, buf)
        buf.write(data)
        return buf

    def upload_frames(self, frames: np.ndarray) -> moderngl.Buffer:
        buf = self._buffer("frame_buf", np.ascontiguousarray(frames, np.float32).tobytes())
        UNITS.bind_storage("Frames", buf)
        return buf

    def run(self, stage: int, frames: np.ndarray, samples: ReflectiveSampleList, eye: np.ndarray,
            ss: int) -> np.ndarray:
        """Stage 1: per reflective sample of `samples` (built from the bins bound as
        u_bins); stage 0: per output pixel of `samples`' tiles, its first sub-sample
        (G-buffer supersampled ss×ss) when reflective, its others too where the first
        is in no dense cluster (with sample_run > 1: runs of listed samples).
        Textures (u_bins, u_tri, u_normal, u_position) and SSBOs (Remap, FaceNormals)
        of cluster_units.UNITS must be bound by the caller."""
        n = len(frames)
        self.upload_frames(frames)
        ext = self._buffer("ext_buf", ext_init(n).tobytes())
        UNITS.bind_storage("Ext", ext)
        tiles = stage == 0 and self.sample_run == 1  # stage 0 on a GPU: per listed tile
        defines = {**UNITS.defines(), "EXTENT_STAGE": str(stage), "SS": str(ss), **self._run_defines}
        if tiles:
            defines.update(TILE=str(TILE), TILE_PIXELS=str(max(-(-TILE // ss), 4)))
        p = compute_program(self.gl, "cluster_extent.comp", defines)  # cached per stage and ss
        set_uniform(p, "u_eye", np.asarray(eye, np.float64))
        if tiles:
            samples.dispatch_tiles(p)
        else:
            samples.dispatch(p, EXTENT_GROUP)
        self.gl.ctx.memory_barrier()
        raw = self.staging.read(ext, 4 * EXT_STRIDE * max(n, 1))
        return np.frombuffer(raw, np.uint32).reshape(-1, EXT_STRIDE)[:n].copy()

    def release(self) -> None:
        for b in (self.ext_buf, self.frame_buf):
            if b is not None:
                b.release()
        self.ext_buf = self.frame_buf = None
        self.staging.release()

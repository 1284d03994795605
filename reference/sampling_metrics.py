"""Sampling-quality metrics of a depth-image set (thesis §2.3.2), by Embree only.

Given a scene S and a set of depth images I_0..I_{n-1} of reference views
V_0..V_{n-1} (conventional, non-redundant or peeling layers), §2.3.2 defines
three view-independent metrics and one view-dependent metric. Every one of them
rests on a redundancy test "sample x is redundant with image I" (§2.2.1):

* ``pixel`` (Alg. 3): project x into I; the texel containing the projection
  (inside the image, depth in (near, far)) holds the same triangle id as x.
* ``visibility`` (Alg. 2): x is visible from I's viewpoint inside I's frustum,
  front-facing and unoccluded with back-face culling (`reference.visibility`).

The metrics (per image and for the whole set):

1. **Redundant samples** (§2.3.2 item 1): samples of I_i redundant with some
   *earlier image of the same set* I_j, j < i. Counted per image, as a fraction
   of I_i's samples. Zero by construction for non-redundant images of the same
   definition and for depth-peeling layers. Pixel definition: the samples
   counted there whose projection lies within ``EDGE_TIE`` texels of a texel
   edge of every image they are redundant with are also counted apart
   (``redundant_edge_ties``): GL decides Alg. 3 with float32 positions and
   matrices, this module with float64, and on a texel edge the two may fall on
   different texels (a GL non-redundant image then shows a handful of
   "redundant" samples in hundreds of thousands).
2. **Occluded samples** (item 2): samples that the *conventional* images C_0..
   C_{n-1} of V_0..V_{n-1} do not capture. "Captured by C_j" is the same
   redundancy test against C_j: pixel — the sample's projection into C_j lands on
   a texel of the same triangle; visibility — the sample is visible from V_j in
   C_j's frustum. Two readings are computed side by side:

   * ``occluded`` ("all" reading, the issue's wording "not captured by the
     conventional images of V_0..V_{n-1}"): every image of every set is tested
     against all n conventional images.
   * ``occluded_earlier`` (the thesis's item 2 read literally): an image taken
     from reference viewpoint V_i, i ≥ 1 (an NR image I_i) is tested against
     C_0..C_{i-1} only; an image from V_0 against C_0 (a set's first image is
     conventional); an image from any other viewpoint (a peeling layer)
     against all n; a conventional image is tested against itself too (0 by
     definition, as the thesis states). Every sample of a pixel-NR I_i is then occluded by
     construction, so the thesis's 62-88 % for NR I_1/I_2 cannot be fractions
     of I_i's own samples; they fit fractions of the view's scene samples
     (C_i's sample count): e.g. its tree row, conventional I_1 23 % redundant
     but NR I_1 84 % occluded, is impossible under the "all" reading, where
     NR I_1's first-layer samples (≥ 77 % of C_1's pixels) are captured by C_1.

   Zero by construction for the conventional images themselves. Fractions in
   `occluded_frac` are of I_i's samples.
3. **Useful samples** (item 3): occluded samples (either reading:
   ``useful`` / ``useful_earlier``) needed by at least one
   intermediate output frame, i.e. redundant with that frame under the same
   definition: pixel — projected into the frame's Embree-cast triangle-id buffer
   the texel holds the sample's triangle; visibility — the sample is visible from
   the frame's viewpoint. Fraction of the occluded samples. Evaluated frame by
   frame with a per-sample boolean "needed" mask (memory O(samples + one frame)).
4. **Available samples** (item 4, view-dependent): per intermediate frame, the
   fraction of its samples (pixels whose Embree primary ray hits a front face, at
   the frame's own resolution) that are redundant with at least one image of the
   set; average and minimum over the frames. Pixel — the frame sample's
   projection into I_i lands on a texel holding the same triangle (Alg. 3 with
   the frame as the sample's source). Visibility — the thesis compares with what
   each image *stores*, so "visible from V_i" is generalised by layers: the
   *layer* of a stored sample is the number of front-facing surfaces its pixel
   ray crosses before it (0 for conventional images, k for peeling layer k, any
   for NR images); the frame sample x is represented by I_i when x is inside
   I_i's frustum, faces V_i, and the segment V_i → x crosses exactly k
   front-facing surfaces where k is the layer of a sample I_i stores within one
   texel of x's projection (3×3 texels: the visibility definition ignores the
   image resolution, so a surface seen through a one-texel gap still counts).
   For a conventional image this is "x visible from V_i" wherever I_i has a
   sample next to x's projection.

How the metrics treat the methods (checked for bias between NR and peeling):

* Every set is measured against the same conventional images C_0..C_{n-1}
  (metric 2) and the same intermediate frames, whatever viewpoints the set
  uses; evaluating sets together or one by one gives the same numbers.
* Useful (metric 3) counts *samples of the set*: the benchmark compares the
  totals over the set's images (the number of useful occluded samples, as
  §2.3.3 compares NR and peeling), not fractions.
* Image borders: a frame sample outside I_i's frustum is not available from
  I_i, and a set sample outside C_j's frustum is not captured by C_j. The
  benchmark's rig (`scenes.rig.fit_distance`) keeps the framed content inside
  every reference, peeling and intermediate view, so neither decides a
  comparison there.
* Pixel definition, inherent to Alg. 3 and kept: a first-layer sample of NR
  image I_i lies on C_i's own pixel ray and is always captured by C_i, whereas
  peeling samples come from the centroid and are reprojected into C_j; on
  triangles of about a pixel or less the reprojected texel often holds a
  neighbouring triangle, so the pixel definition counts some peeling samples
  that V_j does see as occluded (the visibility definition does not). Likewise
  an NR image drops C_i's sample at texel q when C_0's texel at its projection
  holds the same triangle, but a frame sample on that triangle near q can
  project to a C_0 texel of another triangle (thin occluders' silhouettes):
  pixel-definition availability of NR can then fall below conventional's.
  Both effects shrink as the resolution grows (pixel redundancy converges to
  visibility redundancy, §2.3.3).

Intermediate frames are Embree primary-ray casts (back faces culled) of the
given cameras; they are shared by every set evaluated in one call
(`evaluate_sets`), so comparing methods costs one cast per frame.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import maximum_filter

from reference.raycast import RayCaster
from reference.visibility import (
    MAX_LAYERS,
    REDUNDANCY,
    any_redundant,
    clipped,
    count_front_hits,
    front_facing,
    pixel_redundant,
    project_texels,
    visible_from,
)
from scenes.camera import Camera
from scenes.depth_image import DepthImage
from scenes.model import Scene


@dataclass
class SamplingMetrics:
    """§2.3.2 metrics of one depth-image set under one redundancy definition.

    Per image lists (index i = image I_i): ``samples`` (pixels holding a sample),
    ``redundant`` (metric 1), ``occluded`` (metric 2), ``useful`` (metric 3,
    subset of occluded). ``available`` holds metric 4 per intermediate frame
    (fraction in [0, 1]; frames with no visible pixel are skipped). Masks (H,W)
    bool per image are kept only when asked (`keep_masks`)."""

    redundancy: str
    samples: list[int]
    redundant: list[int]
    occluded: list[int]
    useful: list[int]
    available: list[float]
    n_views: int
    redundant_edge_ties: list[int] | None = None
    occluded_earlier: list[int] = field(default_factory=list)
    useful_earlier: list[int] = field(default_factory=list)
    occluded_masks: list[np.ndarray] | None = field(default=None, repr=False, compare=False)
    useful_masks: list[np.ndarray] | None = field(default=None, repr=False, compare=False)

    @staticmethod
    def _frac(a: Sequence[int], b: Sequence[int]) -> list[float]:
        return [float(x) / y if y else 0.0 for x, y in zip(a, b, strict=True)]

    @property
    def redundant_frac(self) -> list[float]:
        """Redundant samples / samples, per image."""
        return self._frac(self.redundant, self.samples)

    @property
    def occluded_frac(self) -> list[float]:
        """Occluded samples / samples, per image."""
        return self._frac(self.occluded, self.samples)

    @property
    def useful_frac(self) -> list[float]:
        """Useful samples / occluded samples, per image (0 when none occluded)."""
        return self._frac(self.useful, self.occluded)

    @property
    def total_samples(self) -> int:
        return int(sum(self.samples))

    @property
    def total_redundant(self) -> int:
        return int(sum(self.redundant))

    @property
    def total_occluded(self) -> int:
        return int(sum(self.occluded))

    @property
    def total_useful(self) -> int:
        return int(sum(self.useful))

    @property
    def available_avg(self) -> float:
        return float(np.mean(self.available)) if self.available else float("nan")

    @property
    def available_min(self) -> float:
        return float(np.min(self.available)) if self.available else float("nan")

    def to_dict(self) -> dict:
        """JSON-ready numbers (no masks)."""
        tot = self.total_samples
        return {
            "redundancy": self.redundancy,
            "samples": list(self.samples),
            "redundant": list(self.redundant),
            "redundant_edge_ties": None if self.redundant_edge_ties is None else list(self.redundant_edge_ties),
            "occluded": list(self.occluded),
            "useful": list(self.useful),
            "occluded_earlier": list(self.occluded_earlier),
            "useful_earlier": list(self.useful_earlier),
            "redundant_frac": self.redundant_frac,
            "occluded_frac": self.occluded_frac,
            "useful_frac_of_occluded": self.useful_frac,
            "total": {
                "samples": tot,
                "redundant": self.total_redundant,
                "occluded": self.total_occluded,
                "useful": self.total_useful,
                "occluded_earlier": int(sum(self.occluded_earlier)),
                "useful_earlier": int(sum(self.useful_earlier)),
                "redundant_frac": self.total_redundant / tot if tot else 0.0,
                "occluded_frac": self.total_occluded / tot if tot else 0.0,
                "useful_frac_of_occluded": self.total_useful / self.total_occluded if self.total_occluded else 0.0,
            },
            "available_avg": self.available_avg,
            "available_min": self.available_min,
            "n_views": self.n_views,
        }


# --- sample sets ------------------------------------------------------------------


@dataclass
class _Samples:
    """The samples of an image list, flattened: image index, flat pixel index,
    world position (float64) and triangle id per sample."""

    image: np.ndarray
    pixel: np.ndarray
    position: np.ndarray
    tri: np.ndarray
    counts: list[int]

    @classmethod
    def of(cls, images: Sequence[DepthImage]) -> _Samples:
        imgs, pixs, pos, tri, counts = [], [], [], [], []
        for i, im in enumerate(images):
            flat = np.flatnonzero(im.tri_id.reshape(-1) > 0)
            imgs.append(np.full(len(flat), i, np.int64))
            pixs.append(flat)
            pos.append(im.position.reshape(-1, 3)[flat].astype(np.float64))
            tri.append(im.tri_id.reshape(-1)[flat].astype(np.uint32))
            counts.append(len(flat))
        return cls(np.concatenate(imgs), np.concatenate(pixs), np.concatenate(pos).reshape(-1, 3),
                   np.concatenate(tri), counts)

    def per_image(self, mask: np.ndarray, n: int) -> list[int]:
        return [int(x) for x in np.bincount(self.image[mask], minlength=n)[:n]]

    def to_masks(self, mask: np.ndarray, images: Sequence[DepthImage]) -> list[np.ndarray]:
        out = []
        for i, im in enumerate(images):
            m = np.zeros(im.tri_id.size, bool)
            sel = self.image == i
            m[self.pixel[sel]] = mask[sel]
            out.append(m.reshape(im.tri_id.shape))
        return out


#: Pixel definition: a projection closer than this (texels) to a texel edge is a float tie.
EDGE_TIE = 1e-3


def texel_edge_distance(camera: Camera, points: np.ndarray) -> np.ndarray:
    """(N,) distance, in texels, from each point's projection into `camera` to
    the nearest texel edge (0.5 at a texel centre)."""
    xy, _ = camera.project(np.asarray(points, np.float64).reshape(-1, 3))
    frac = xy - np.floor(xy)
    return np.minimum(frac, 1.0 - frac).min(axis=1)


def pixel_edge_ties(images: Sequence[DepthImage], samples: _Samples, redundant: np.ndarray) -> np.ndarray:
    """(N,) bool: the pixel-redundant samples (mask `redundant` over `samples`)
    whose projection is within EDGE_TIE texels of a texel edge in every earlier
    image they are pixel-redundant with (float rounding ties, see metric 1)."""
    out = np.zeros(len(samples.tri), bool)
    for i in range(1, len(images)):
        idx = np.flatnonzero(redundant & (samples.image == i))
        if len(idx) == 0:
            continue
        robust = np.zeros(len(idx), bool)
        for im in images[:i]:
            r = pixel_redundant(im.tri_id, im.camera, samples.position[idx], samples.tri[idx])
            robust |= r & (texel_edge_distance(im.camera, samples.position[idx]) >= EDGE_TIE)
        out[idx] = ~robust
    return out


def redundant_samples(caster: RayCaster, images: Sequence[DepthImage], redundancy: str) -> np.ndarray:
    """Metric 1 per sample of `_Samples.of(images)`: redundant with an earlier image."""
    s = _Samples.of(images)
    out = np.zeros(len(s.tri), bool)
    for i in range(1, len(images)):
        sel = np.flatnonzero(s.image == i)
        out[sel] = any_redundant(caster, images[:i], s.position[sel], s.tri[sel], redundancy)
    return out


def layer_map(caster: RayCaster, image: DepthImage) -> np.ndarray:
    """(H,W) int64: number of front-facing surfaces the pixel ray crosses before
    the stored sample (-1 where no sample); 0 everywhere for conventional images."""
    out = np.full(image.tri_id.shape, -1, np.int64).reshape(-1)
    flat = np.flatnonzero(image.tri_id.reshape(-1) > 0)
    pos = image.position.reshape(-1, 3)[flat].astype(np.float64)
    out[flat] = count_front_hits(caster, np.asarray(image.camera.eye, np.float64), pos,
                                 image.tri_id.reshape(-1)[flat], MAX_LAYERS)
    return out.reshape(image.tri_id.shape)


def _layer_match(layers: np.ndarray, camera: Camera, points: np.ndarray, k: np.ndarray) -> np.ndarray:
    """(N,) bool: points (inside camera's frustum) whose layer counts k equal the
    layer of some stored sample in the 3×3 texels around their projection."""
    ix, iy, inside = project_texels(camera, points)
    h, w = layers.shape
    out = np.zeros(len(points), bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            x, y = ix + dx, iy + dy
            ok = inside & (x >= 0) & (x < w) & (y >= 0) & (y < h)
            kr = np.where(ok, layers[np.clip(y, 0, h - 1), np.clip(x, 0, w - 1)], -1)
            out |= ok & (kr >= 0) & (kr == k)
    return out


def earlier_conventional(image: DepthImage, conventional_images: Sequence[DepthImage]) -> list[DepthImage]:
    """The conventional images an image is tested against under the thesis's
    literal item 2 (module docstring, ``occluded_earlier``): C_0..C_{i-1} for an
    image from V_i's viewpoint, all of them for an image from another viewpoint
    (peeling). C_0 for an image from V_0: the first image of a set is a
    conventional image (Alg. 1 has no earlier image to test against there), and
    C_i itself is included when the image is C_i (0 by definition)."""
    eye = np.asarray(image.camera.eye, np.float64)
    for i, c in enumerate(conventional_images):
        if np.array_equal(np.asarray(c.camera.eye, np.float64), eye):
            same = i == 0 or c is image or np.array_equal(c.tri_id, image.tri_id)
            return list(conventional_images[: i + 1 if same else i])
    return list(conventional_images)


@dataclass
class _View:
    """One intermediate frame: camera, triangle-id buffer (H,W), and its hit
    pixels as points (M,3) + triangle ids (M,)."""

    camera: Camera
    tri_buffer: np.ndarray
    points: np.ndarray
    tri: np.ndarray


def cast_view(caster: RayCaster, camera: Camera) -> _View:
    """Embree primary-ray cast of an intermediate frame (back faces culled)."""
    d = camera.pixel_directions().reshape(-1, 3)
    eye = np.asarray(camera.eye, np.float64)
    # Per-ray culling (RayCaster.intersect): no per-viewpoint BVH for each of many frames.
    h = caster.intersect(np.broadcast_to(eye, d.shape), d, cull_back_faces=True)
    hit = h.hit
    pts = eye + d[hit] * h.t[hit, None]
    return _View(camera, h.tri_id.reshape(camera.height, camera.width), pts, h.tri_id[hit])


@dataclass
class _Job:
    name: str
    images: list[DepthImage]
    redundancy: str
    samples: _Samples
    redundant: np.ndarray
    occluded: np.ndarray
    occluded_earlier: np.ndarray
    needed: np.ndarray
    available: list[float]
    layers: list[np.ndarray] | None


def evaluate_sets(scene: Scene, sets: Mapping[str, tuple[Sequence[DepthImage], str]],
                  conventional_images: Sequence[DepthImage], intermediate_cameras: Sequence[Camera],
                  caster: RayCaster | None = None, progress: bool = False,
                  keep_masks: bool = False) -> dict[str, SamplingMetrics]:
    """§2.3.2 metrics of several sets at once: sets maps a name to (images,
    redundancy); every intermediate frame is cast once and shared. See the module
    docstring for the definitions; conventional_images are the conventional depth
    images of the reference viewpoints (metric 2)."""
    rc = caster or RayCaster(scene)
    views = [clipped(c, scene) for c in intermediate_cameras]
    jobs: list[_Job] = []
    for name, (images, redundancy) in sets.items():
        if redundancy not in REDUNDANCY:
            raise ValueError(f"redundancy must be one of {REDUNDANCY}, got {redundancy!r}")
        images = list(images)
        s = _Samples.of(images)
        red = redundant_samples(rc, images, redundancy)
        captured = any_redundant(rc, conventional_images, s.position, s.tri, redundancy)
        earlier = ~captured  # images tested against all conventional images (peeling) share the answer
        for i, im in enumerate(images):
            refs = earlier_conventional(im, conventional_images)
            if len(refs) < len(conventional_images):
                sel = np.flatnonzero(s.image == i)
                earlier[sel] = ~any_redundant(rc, refs, s.position[sel], s.tri[sel], redundancy)
        layers = [layer_map(rc, im) for im in images] if redundancy == "visibility" else None
        jobs.append(_Job(name, images, redundancy, s, red, ~captured, earlier, np.zeros(len(s.tri), bool), [],
                         layers))

    # Reference cameras of the visibility jobs, each with the 3×3-max of its
    # images' layer maps (how deep a frame sample's walk along it must go).
    vis_cams: dict[Camera, np.ndarray] = {}
    for job in jobs:
        if job.layers is not None:
            for im, lay in zip(job.images, job.layers, strict=True):
                grown = maximum_filter(lay, size=3, mode="constant", cval=-1)
                prev = vis_cams.get(im.camera)
                vis_cams[im.camera] = grown if prev is None else np.maximum(prev, grown)

    it = views
    if progress:
        from tqdm import tqdm

        it = tqdm(views, desc="intermediate views", unit="view", leave=False)
    for cam in it:
        view = cast_view(rc, cam)
        m = len(view.tri)
        # Layer counts of the frame's samples along each reference camera
        # (visibility), computed lazily for the samples some set still needs and
        # walked only as deep as some image of that camera needs (-2: no match
        # possible, -3: not computed yet).
        counts = {ref: np.full(m, -3, np.int64) for ref in vis_cams}

        def layer_counts(ref: Camera, idx: np.ndarray, view: _View = view, counts: dict = counts) -> np.ndarray:
            k = counts[ref]
            todo = idx[k[idx] == -3]
            if len(todo):
                ix, iy, inside = project_texels(ref, view.points[todo])
                cap = vis_cams[ref][iy, ix]
                eye = np.asarray(ref.eye, np.float64)
                ok = inside & (cap >= 0)
                ok[ok] = front_facing(rc, eye, view.points[todo[ok]], view.tri[todo[ok]])
                k[todo] = -2
                c = todo[ok]
                k[c] = count_front_hits(rc, eye, view.points[c], view.tri[c], cap[ok])
            return k[idx]

        for job in jobs:
            s = job.samples
            # Metric 3: occluded samples (either reading) needed by this frame.
            todo = np.flatnonzero((job.occluded | job.occluded_earlier) & ~job.needed)
            if len(todo):
                if job.redundancy == "pixel":
                    need = pixel_redundant(view.tri_buffer, cam, s.position[todo], s.tri[todo])
                else:
                    need = visible_from(rc, cam, s.position[todo], s.tri[todo])
                job.needed[todo[need]] = True
            # Metric 4: frame samples represented by the set.
            if m == 0:
                continue
            avail = np.zeros(m, bool)
            for i, im in enumerate(job.images):
                idx = np.flatnonzero(~avail)
                if len(idx) == 0:
                    break
                if job.redundancy == "pixel":
                    avail[idx] = pixel_redundant(im.tri_id, im.camera, view.points[idx], view.tri[idx])
                else:
                    avail[idx] = _layer_match(job.layers[i], im.camera, view.points[idx],
                                              layer_counts(im.camera, idx))
            job.available.append(float(avail.mean()))

    out: dict[str, SamplingMetrics] = {}
    for job in jobs:
        n = len(job.images)
        s = job.samples
        useful = job.occluded & job.needed
        useful_earlier = job.occluded_earlier & job.needed
        out[job.name] = SamplingMetrics(
            redundancy=job.redundancy,
            samples=list(s.counts),
            redundant=s.per_image(job.redundant, n),
            redundant_edge_ties=(s.per_image(pixel_edge_ties(job.images, s, job.redundant), n)
                                 if job.redundancy == "pixel" else None),
            occluded=s.per_image(job.occluded, n),
            useful=s.per_image(useful, n),
            occluded_earlier=s.per_image(job.occluded_earlier, n),
            useful_earlier=s.per_image(useful_earlier, n),
            available=job.available,
            n_views=len(views),
            occluded_masks=s.to_masks(job.occluded, job.images) if keep_masks else None,
            useful_masks=s.to_masks(useful, job.images) if keep_masks else None,
        )
    return out


def sampling_metrics(scene: Scene, images: Sequence[DepthImage], conventional_images: Sequence[DepthImage],
                     intermediate_cameras: Sequence[Camera], redundancy: str = "pixel", progress: bool = False,
                     caster: RayCaster | None = None, keep_masks: bool = False) -> SamplingMetrics:
    """§2.3.2 metrics of one depth-image set (module docstring). images: the set
    I_0..I_{n-1}; conventional_images: conventional images of the same reference
    viewpoints (for metric 2); intermediate_cameras: output frames for metrics 3
    and 4 (e.g. `scenes.rig.intermediate_views`); redundancy: "pixel" or
    "visibility"; progress: tqdm bar over the intermediate frames."""
    return evaluate_sets(scene, {"set": (images, redundancy)}, conventional_images, intermediate_cameras,
                         caster=caster, progress=progress, keep_masks=keep_masks)["set"]

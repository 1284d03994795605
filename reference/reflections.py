"""Ray-traced reflection ground truth (Ch. 4, technique 3) and the environment-map
baseline, both with Embree (via reference.raycast.RayCaster). Never imports gl_passes.

Definitions (the GL cluster-depth-image pass must follow the same ones):

Sampling. Output pixel (x, y) of `camera` is covered by supersample² primary rays
through the centres of an ss×ss grid of cells inside the pixel, i.e. image-plane
points (x + (i + ½)/ss, y + (j + ½)/ss). These are exactly the pixel centres of
the same camera rendered at ss·W × ss·H, which is what the GL G-buffer does for
ss = 2 (points x + 0.25, x + 0.75). Every primary and reflected ray culls back faces;
primary rays, which all start at the eye, use the exact per-viewpoint culling of
RayCaster.cast_from (a back face coplanar with a front face, e.g. a wall behind a
tile seen from outside the room, cannot hide that front face; restarting past
back faces would skip it).

Per sample (primary hit with material albedo, s, g):
  * diffuse  = local shading of the hit (scenes.shading.local_shade with the
    interpolated shading normal); sky(d) for a primary miss.
  * reflective = the sample hits a surface with s > 0.
  * mirror direction r = d − 2(d·n)n about the INTERPOLATED shading normal n.
    Below-surface rule: if r·n_geom < 0 (r points into the surface, possible
    because n differs from the geometric normal n_geom of the hit triangle) the
    direction is replaced by the reflection about n_geom, r = d − 2(d·n_geom)n_geom,
    which leaves the surface since the hit is front-facing (d·n_geom < 0).
  * reflected rays start at the hit point moved ORIGIN_OFFSET·diagonal along
    n_geom; the originating triangle is back-facing for them, so culling alone
    already rules out self-hits.
  * mirror (g = 0): one ray along r, limited to glossy_far(diagonal, 0) = the
    scene diagonal (the cluster camera's far plane, §4.4 step 2); a hit gives the
    LOCAL shading of the hit point (single bounce, no recursion, even if that
    surface is itself reflective); a miss reads sky(r).
  * glossy (g > 0): `glossy_rays` directions scenes.glossy.lobe_directions(r, g, n)
    (lobe around the clamped r); a lobe direction with dir·n_geom < 0 is mirrored
    about the geometric tangent plane (dir − 2(dir·n_geom)n_geom). Each ray is
    limited to far = glossy_far(diagonal, g); a hit at distance t contributes
    w·hit_colour + (1 − w)·diffuse with w = fade_weight(t, far, g); a miss within
    far contributes the DIFFUSE colour (not the sky). The reflected colour is the
    mean over the lobe.
  * colour = mix(diffuse, reflected, s) = diffuse·(1 − s) + reflected·s (GLSL mix);
    colour = diffuse for non-reflective samples.
  * ray length: distance along r (the lobe axis for glossy samples, limited to the
    same far) from the offset origin to the first front-facing hit, +inf on a miss;
    NaN for non-reflective samples. (The offset changes it by at most
    ORIGIN_OFFSET·diagonal / (r·n_geom), far below any comparison tolerance.)

Averaging to output resolution (ss×ss blocks; sums in float64, then float32):
  color, diffuse: mean over all samples of the block; specular: mean of s over the
  block (0 for non-reflective samples and background); reflective: ANY sample of the
  block is reflective; reflected: mean over the block's reflective samples (0 where
  none); ray_length: mean over the block's reflective samples, +inf if any of them
  missed, NaN where none is reflective (`aggregate_ray_length`, reusable on GL
  buffers rendered at ss·W × ss·H). The sample-resolution ray lengths and reflective
  mask are kept in the result too, with each mirror ray's hit point and hit-triangle
  normal (for the thesis's occlusion-error test, reference.occlusion).

Environment-map baseline: identical, except that no reflected ray is intersected:
reflected = sky(r) for mirrors, the lobe mean of sky(dir) for glossy samples (the
environment is at infinity, so there is no far limit and no fade), ray length +inf.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from reference.raycast import Hits, RayCaster
from scenes.buffers import ReflectionBuffers
from scenes.camera import Camera
from scenes.glossy import fade_weight, glossy_far, lobe_directions
from scenes.model import Scene
from scenes.shading import sky

#: Reflected-ray origins move this fraction of the scene diagonal along n_geom.
ORIGIN_OFFSET = 1e-5
#: Primary samples per chunk (a chunk casts at most chunk·(glossy_rays + 1) rays).
DEFAULT_CHUNK = 1 << 15


@dataclass
class ReflectionResult(ReflectionBuffers):
    """ReflectionBuffers (after the ss×ss averaging described in the module
    docstring) plus ray_length_samples and reflective_samples, the same at sample
    resolution (ss·H, ss·W); hit_points_samples (ss·H, ss·W, 3) float64 world-space
    point where the mirror ray (the lobe axis for glossy samples, within the same far
    limit as ray_length) first hits, NaN where the sample is not reflective or the ray
    missed, and hit_normals_samples (ss·H, ss·W, 3) float32 the unit geometric normal
    of the hit triangle there (NaN likewise); both are for the thesis's occlusion-error
    test (reference.occlusion, §4.7.1). The environment-map baseline leaves them NaN."""

    supersample: int = 1
    ray_length_samples: np.ndarray | None = None
    reflective_samples: np.ndarray | None = None
    hit_points_samples: np.ndarray | None = None
    hit_normals_samples: np.ndarray | None = None


def reflect(d: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Mirror unit directions d (...,3) about unit normals n (...,3), renormalised."""
    r = d - 2.0 * np.sum(d * n, axis=-1, keepdims=True) * n
    return r / np.maximum(np.linalg.norm(r, axis=-1, keepdims=True), 1e-30)


def mirror_directions(d: np.ndarray, n_shading: np.ndarray, n_geom: np.ndarray) -> np.ndarray:
    """Mirror directions (N,3) of view directions d about the interpolated shading
    normals, with the below-surface rule: where the result points into the surface
    (r·n_geom < 0) reflect about the geometric normal instead."""
    r = reflect(d, n_shading)
    below = np.sum(r * n_geom, axis=-1) < 0
    if np.any(below):
        r[below] = reflect(d[below], n_geom[below])
    return r


def lift_above(dirs: np.ndarray, n_geom: np.ndarray) -> np.ndarray:
    """Glossy lobe directions (M,k,3) that point below the geometric tangent plane
    (dir·n_geom < 0, n_geom (M,3)) are mirrored about that plane."""
    dn = np.einsum("mkc,mc->mk", dirs, n_geom)
    return np.where((dn < 0)[..., None], dirs - 2.0 * dn[..., None] * n_geom[:, None, :], dirs)


def _block_mean(x: np.ndarray, ss: int) -> np.ndarray:
    """Mean over ss×ss blocks of (ss·H, ss·W[, C]) in float64."""
    h, w = x.shape[0] // ss, x.shape[1] // ss
    return x.reshape(h, ss, w, ss, *x.shape[2:]).astype(np.float64).sum(axis=(1, 3)) / (ss * ss)


def aggregate_ray_length(lengths: np.ndarray, reflective: np.ndarray, ss: int) -> np.ndarray:
    """Output-resolution mirror-ray lengths from sample-resolution ones (ss·H, ss·W):
    mean over the reflective samples of each ss×ss block, +inf if any of them is
    +inf (missed), NaN where the block has no reflective sample."""
    h, w = lengths.shape[0] // ss, lengths.shape[1] // ss
    refl = reflective.reshape(h, ss, w, ss)
    lng = np.where(refl, lengths.reshape(h, ss, w, ss).astype(np.float64), 0.0)
    count = refl.sum(axis=(1, 3))
    with np.errstate(invalid="ignore"):
        total = lng.sum(axis=(1, 3))
        out = total / np.maximum(count, 1)
    return np.where(count > 0, out, np.nan)


@dataclass
class SampleShading:
    """Per-sample results of `_shade_samples` (N primary rays): color, diffuse,
    reflected (N,3) float32; specular (N,) float32; reflective (N,) bool; length
    (N,) float64 mirror-ray length (+inf miss, NaN non-reflective); hit_points (N,3)
    float64 and hit_normals (N,3) float32 (NaN where no mirror hit)."""

    color: np.ndarray
    diffuse: np.ndarray
    reflected: np.ndarray
    specular: np.ndarray
    reflective: np.ndarray
    length: np.ndarray
    hit_points: np.ndarray
    hit_normals: np.ndarray


def _shade_samples(caster: RayCaster, eye: np.ndarray, dirs: np.ndarray, glossy_rays: int, trace: bool,
                   chunk: int, per_viewpoint: bool = True) -> SampleShading:
    """Every rule of the module docstring for primary rays from `eye` along unit
    `dirs` (N,3), before any ss×ss averaging. per_viewpoint=False casts the primary
    rays in the scene's one BVH, restarting past back faces (no per-viewpoint BVH
    build, a fixed cost per eye that sparse rays cannot amortise; differs from the
    exact culling only where a back face is coplanar with a front face)."""
    scene = caster.scene
    n_samples = len(dirs)
    sun = np.asarray(scene.sun_direction, np.float64)
    diag = scene.diagonal
    offset = ORIGIN_OFFSET * max(diag, 1e-6)
    face_n = caster.face_normals / np.maximum(np.linalg.norm(caster.face_normals, axis=1, keepdims=True), 1e-30)

    color = np.empty((n_samples, 3), np.float32)
    diffuse = np.empty((n_samples, 3), np.float32)
    reflected = np.zeros((n_samples, 3), np.float32)
    spec = np.zeros(n_samples, np.float32)
    reflective = np.zeros(n_samples, bool)
    length = np.full(n_samples, np.nan)
    hit_points = np.full((n_samples, 3), np.nan)
    hit_normals = np.full((n_samples, 3), np.nan, np.float32)

    for start in range(0, n_samples, chunk):
        sl = slice(start, min(start + chunk, n_samples))
        d = dirs[sl]
        # Primary rays all start at the eye: exact back-face culling with the
        # per-viewpoint BVH (as the G-buffer's rasteriser; restarting past back faces
        # would let a coplanar back face hide a front face, e.g. tiles on a wall).
        hits = caster.cast_from(eye, d) if per_viewpoint else caster.intersect(np.broadcast_to(eye, d.shape), d)
        diff, n_shade = caster.shade_hits(hits, d)
        diffuse[sl] = diff
        color[sl] = diff
        tri = hits.tri_id.astype(np.int64)
        obj = np.zeros(len(d), np.int64)
        obj[hits.hit] = scene.face_object[tri[hits.hit] - 1]
        s = scene.materials[obj, 3]
        g = scene.materials[obj, 4]
        refl = hits.hit & (s > 0)
        idx = np.nonzero(refl)[0]
        if len(idx) == 0:
            continue
        gi = start + idx
        spec[gi] = s[idx]
        reflective[gi] = True
        dr = d[idx]
        ng = face_n[tri[idx] - 1]
        r = mirror_directions(dr, n_shade[idx], ng)
        origin = eye + dr * hits.t[idx, None] + ng * offset
        gs = g[idx].astype(np.float64)
        dif = diff[idx]
        out = np.empty((len(idx), 3), np.float32)
        glossy = gs > 0
        mir = ~glossy

        if trace:
            far = glossy_far(diag, gs)
            axis = caster.intersect(origin, r, far)
            length[gi] = axis.t
            ok = axis.hit
            hit_points[gi[ok]] = origin[ok] + r[ok] * axis.t[ok, None]
            hit_normals[gi[ok]] = face_n[axis.tri_id[ok].astype(np.int64) - 1]
            if np.any(mir):
                col, _ = caster.shade_hits(_subset(axis, mir), r[mir])  # local shade on hit, sky on miss
                out[mir] = col
        else:
            length[gi] = np.inf
            out[mir] = sky(r[mir], sun)

        if np.any(glossy):
            k = glossy_rays
            gsel = np.nonzero(glossy)[0]
            lob = lift_above(lobe_directions(r[gsel], gs[gsel], k), ng[gsel])  # (M,k,3)
            m = len(gsel)
            if trace:
                o_l = np.repeat(origin[gsel], k, axis=0)
                d_l = lob.reshape(-1, 3)
                far_l = np.repeat(glossy_far(diag, gs[gsel]), k)
                lh = caster.intersect(o_l, d_l, far_l)
                hit_col, _ = caster.shade_hits(lh, d_l)
                w = fade_weight(lh.t, far_l, np.repeat(gs[gsel], k))
                w = np.where(lh.hit, w, 0.0)  # a miss within far contributes the diffuse colour
                base = np.repeat(dif[gsel].astype(np.float64), k, axis=0)
                samp = w[:, None] * hit_col + (1.0 - w[:, None]) * base
                out[gsel] = samp.reshape(m, k, 3).mean(axis=1)
            else:
                out[gsel] = sky(lob.reshape(-1, 3), sun).reshape(m, k, 3).astype(np.float64).mean(axis=1)

        reflected[gi] = out
        sf = s[idx].astype(np.float32)[:, None]
        color[gi] = dif * (1.0 - sf) + out * sf

    return SampleShading(color, diffuse, reflected, spec, reflective, length, hit_points, hit_normals)


def _render(scene: Scene, camera: Camera, supersample: int, glossy_rays: int, trace: bool,
            chunk: int, caster: RayCaster | None) -> ReflectionResult:
    ss = int(supersample)
    if ss < 1:
        raise ValueError("supersample must be >= 1")
    if glossy_rays < 1:
        raise ValueError("glossy_rays must be >= 1")
    caster = caster if caster is not None else RayCaster(scene)
    if caster.scene is not scene:
        raise ValueError("caster was built for another scene")
    H, W = camera.height, camera.width
    cam = camera.with_size(W * ss, H * ss)
    dirs = cam.pixel_directions().reshape(-1, 3)
    sh = _shade_samples(caster, np.asarray(camera.eye, np.float64), dirs, glossy_rays, trace, chunk)
    color, diffuse, reflected, spec = sh.color, sh.diffuse, sh.reflected, sh.specular
    reflective, length, hit_points, hit_normals = sh.reflective, sh.length, sh.hit_points, sh.hit_normals

    shape2 = (H * ss, W * ss)
    refl_img = reflective.reshape(shape2)
    len_img = length.reshape(shape2)
    refl3 = refl_img[..., None]
    count = refl_img.reshape(H, ss, W, ss).sum(axis=(1, 3))
    refl_sum = np.where(refl3, reflected.reshape(*shape2, 3), 0).reshape(H, ss, W, ss, 3)
    refl_mean = refl_sum.astype(np.float64).sum(axis=(1, 3)) / np.maximum(count, 1)[..., None]
    return ReflectionResult(
        color=_block_mean(color.reshape(*shape2, 3), ss).astype(np.float32),
        reflected=refl_mean.astype(np.float32),
        diffuse=_block_mean(diffuse.reshape(*shape2, 3), ss).astype(np.float32),
        specular=_block_mean(spec.reshape(shape2), ss).astype(np.float32),
        reflective=count > 0,
        ray_length=aggregate_ray_length(len_img, refl_img, ss),
        supersample=ss,
        ray_length_samples=len_img,
        reflective_samples=refl_img,
        hit_points_samples=hit_points.reshape(*shape2, 3),
        hit_normals_samples=hit_normals.reshape(*shape2, 3),
    )


def _subset(hits: Hits, mask: np.ndarray) -> Hits:
    return Hits(t=hits.t[mask], tri_id=hits.tri_id[mask], u=hits.u[mask], v=hits.v[mask], front=hits.front[mask])


def raytrace_reflections(scene: Scene, camera: Camera, supersample: int = 2, glossy_rays: int = 8,
                         max_bounces: int = 1, chunk: int = DEFAULT_CHUNK,
                         caster: RayCaster | None = None) -> ReflectionResult:
    """Ray-traced single-bounce reflections (ground truth for technique 3); see the
    module docstring for every rule. `caster` may pass a prebuilt RayCaster of
    `scene` (saves the BVH build across calls)."""
    if max_bounces != 1:
        raise NotImplementedError("only single-bounce reflections (max_bounces=1) are defined (§4.1)")
    return _render(scene, camera, supersample, glossy_rays, True, chunk, caster)


def envmap_reflections(scene: Scene, camera: Camera, supersample: int = 2, glossy_rays: int = 8,
                       chunk: int = DEFAULT_CHUNK, caster: RayCaster | None = None) -> ReflectionResult:
    """Environment-map baseline: reflected = sky(reflected direction) (lobe mean for
    glossy samples), no reflected-ray intersection; ray_length +inf on every
    reflective pixel."""
    return _render(scene, camera, supersample, glossy_rays, False, chunk, caster)

"""The thesis's occlusion-error test for cluster depth images (§4.4, §4.7.1, "误差来源之二").

The thesis defines an occlusion error as a reflected ray meeting a reflected object
that the cluster's depth image did not sample ("遮挡误差是在反射光线相交到深度图像没有
采样到的被反射物体时产生", §4.4), and reports the share of reflective pixels with one
(§4.7.1: max/mean 1.3 %/0.62 % living room, 3.5 %/2.75 % bathroom). This module
implements that definition, pure numpy (never imports gl_passes); the method's side
(which cluster each sample belongs to, the cluster cameras and the stored depth
layers) comes from the GL pass's diagnostics, the truth (where each mirror ray
really hits) from Embree (reference.reflections, hit_points_samples).

It differs from reference.image_metrics.occlusion_error_mask (the "strict" metric:
the method's mirror-ray length disagrees with Embree's by > 5 %), which also counts
every failure of the intersection march (Alg. 7) on a surface the image DOES hold,
and glossy axis rays near the far plane; the thesis's test does not depend on the
march at all.

Captured. A true mirror-ray hit point X of a sample in cluster k is held by the
cluster's depth image when

1. X projects inside the image: clip = VP_k·(X, 1) has w > 0 and NDC x, y, z in
   [−1, 1] (inside the viewport, between the near and far planes), and, when the
   image has a clip plane (the fitting plane, §4.4), X lies on its kept side;
2. some stored sample within ±`radius` texels of X's texel (the stored samples sit
   at texel centres, X anywhere inside its texel, so the sample of X's own surface
   may be a neighbour's), in any of the L stored layers, lies on X's surface: with
   S the stored sample (the texel-centre ray at the stored depth D) and D* the depth
   at which that ray meets X's tangent plane (the plane of the hit triangle, normal
   `hit_normals`),

       |D − D*| ≤ rel_tol·D*   or   |n·(S − X)| ≤ plane_tol·(X's texel footprint).

Depth is the clip-space w of VP_k (for a perspective camera: linear depth along its
viewing axis, what cluster_depth.frag stores). Predicting D* from the tangent plane
makes the test independent of the surface's slope: it is exact (float32
rasterisation error, ~1e-6 relative) when S lies on X's triangle, and off by the
surface's curvature only (≈ l²/(2ρ) for a lateral offset l of ≤ 1.5·√2 texel
footprints f = D·p and curvature radius ρ) on a neighbouring triangle. Seen head-on,
rel_tol = 1 % covers that for ρ ≳ 200·f·p, i.e. for the bench's texel spacing
p ≈ 0.003 any surface curved less sharply than about a texel footprint, while an
occluder counts as "the same surface" only when it lies within 1 % of X's depth in
front of it. The second, plane-distance form covers surfaces the cluster camera sees
at a grazing angle θ, where the lateral offset grows as 1/cos θ and a depth offset is
the plane offset / cos θ, so a curvature (or tessellation) offset far below the
image's resolution becomes a large depth difference: a stored sample within half a texel
footprint (plane_tol = 0.5; the footprint = the spacing of neighbouring texel rays
at X's depth) of X's tangent plane is as close as the image can resolve. Without
normals the test falls back to D* = X's own depth (a fronto-parallel surface) and
the depth form only.

How far each tolerance moves the error on the bench's Table 12 views:
bench/results/reflections_notes.json, "occlusion_metric_sensitivity" (the depth
form alone misses grazing surfaces; radius 0 is X's own texel only).

Pixels. An output pixel is an occlusion-error pixel when one of its ss×ss reflective
samples has a true hit (finite Embree hit within the mirror ray's far limit) that its
cluster's image does not hold — the same block aggregation as the strict metric
(reference.reflections.aggregate_ray_length: a pixel is wrong when any of its
reflective samples is). A mirror ray that escapes to the environment map is never an
occlusion error under this definition. The percentage is over the reflective pixels
(reference.image_metrics.occlusion_error_percentage).
"""

from __future__ import annotations

import numpy as np

from scenes.buffers import ClusterDiagnostics

#: Relative depth tolerance of the captured test (module docstring).
CAPTURE_REL_TOL = 0.01
#: Distance from the tangent plane, in texel footprints at the point (module docstring).
CAPTURE_PLANE_TOL = 0.5
#: Stored depths at or above this are empty texels (the GL pass clears to 1e30).
EMPTY_DEPTH = 1e29
#: Points per vectorised chunk (bounds the temporary arrays).
CHUNK = 1 << 16


def _texel_rays(inv_vp: np.ndarray, vp: np.ndarray, ndc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rays through the image points `ndc` (M,2): (origin (M,3), step (M,3)) such
    that origin + t·step is the world point at depth (clip w) t."""
    m = len(ndc)
    ends = []
    for z in (-1.0, 1.0):  # the ray's points on the near and far planes
        h = np.einsum("mij,mj->mi", inv_vp, np.concatenate([ndc, np.full((m, 1), z), np.ones((m, 1))], axis=1))
        ends.append(h[:, :3] / h[:, 3:4])
    a, b = ends
    wa = np.einsum("mj,mj->m", vp[:, 3, :3], a) + vp[:, 3, 3]
    wb = np.einsum("mj,mj->m", vp[:, 3, :3], b) + vp[:, 3, 3]
    step = (b - a) / (wb - wa)[:, None]  # depth is affine along a world line
    return a - wa[:, None] * step, step


def captured_mask(hit_points: np.ndarray, cluster_of_sample: np.ndarray, view_proj: np.ndarray,
                  viewports: np.ndarray, layer_depths: np.ndarray, hit_normals: np.ndarray | None = None,
                  clip_planes: np.ndarray | None = None, rel_tol: float = CAPTURE_REL_TOL,
                  plane_tol: float = CAPTURE_PLANE_TOL, radius: int = 1) -> np.ndarray:
    """(...) bool: the true hit point of each sample is held by its cluster's depth
    image (module docstring, thesis §4.4 / §4.7.1).

    hit_points (...,3) world space (NaN = no hit; never captured); cluster_of_sample
    (...) int, index into the K cameras (< 0 = none; never captured); view_proj
    (K,4,4) each cluster camera's projection·view (clip w = stored depth);
    viewports (K,4) int (x, y, w, h) of each image in layer_depths, y = its TOP row
    (row 0 = top, NDC y = +1 at the top; w or h = 0: no image); layer_depths (L,Ha,Wa)
    the stored depths of the L layers (≥ EMPTY_DEPTH or non-finite = empty texel);
    hit_normals (...,3) unit normals of the hit surfaces (None: fronto-parallel
    prediction); clip_planes (K,4) (n, c): only points with n·X ≥ c are rendered;
    rel_tol (relative depth), plane_tol (texel footprints from the tangent plane;
    with normals only) and radius (texels): the tolerances of the module docstring."""
    pts = np.asarray(hit_points, np.float64)
    cl = np.asarray(cluster_of_sample)
    if pts.shape != (*cl.shape, 3):
        raise ValueError(f"hit_points {pts.shape} does not match cluster_of_sample {cl.shape} + (3,)")
    vp_all = np.asarray(view_proj, np.float64).reshape(-1, 4, 4)
    vps = np.asarray(viewports, np.int64).reshape(-1, 4)
    layers = np.asarray(layer_depths)
    if layers.ndim == 2:
        layers = layers[None]
    if len(vps) != len(vp_all):
        raise ValueError(f"{len(vp_all)} cameras but {len(vps)} viewports")
    nrm_all = None if hit_normals is None else np.asarray(hit_normals, np.float64).reshape(-1, 3)
    flat_pts, flat_cl = pts.reshape(-1, 3), cl.reshape(-1).astype(np.int64)
    out = np.zeros(len(flat_cl), bool)
    ok = (flat_cl >= 0) & (flat_cl < len(vp_all)) & np.all(np.isfinite(flat_pts), axis=1)
    if nrm_all is not None:
        ok &= np.all(np.isfinite(nrm_all), axis=1)
    if not len(vp_all) or not ok.any():
        return out.reshape(cl.shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        inv_all = np.linalg.inv(vp_all)
    _, ha, wa = layers.shape
    offsets = [(dx, dy) for dy in range(-radius, radius + 1) for dx in range(-radius, radius + 1)]
    for start in range(0, len(flat_cl), CHUNK):
        sel = np.nonzero(ok[start:start + CHUNK])[0] + start
        if not len(sel):
            continue
        k, x = flat_cl[sel], flat_pts[sel]
        vp, inv = vp_all[k], inv_all[k]
        clip = np.einsum("mij,mj->mi", vp, np.concatenate([x, np.ones((len(x), 1))], axis=1))
        w = clip[:, 3]
        with np.errstate(invalid="ignore", divide="ignore"):
            ndc = clip[:, :3] / w[:, None]
        vx, vy, vw, vh = (vps[k, i] for i in range(4))
        inside = (w > 0) & np.all(np.abs(ndc) <= 1.0, axis=1) & (vw > 0) & (vh > 0)
        if clip_planes is not None:
            cp = np.asarray(clip_planes, np.float64).reshape(-1, 4)[k]
            inside &= np.sum(cp[:, :3] * x, axis=1) >= cp[:, 3]
        fx = np.where(inside, (ndc[:, 0] + 1.0) * 0.5 * vw, 0.0)  # texel units from the image's left / top edge
        fy = np.where(inside, (1.0 - ndc[:, 1]) * 0.5 * vh, 0.0)
        col = np.clip(np.floor(fx), 0, np.maximum(vw - 1, 0)).astype(np.int64)
        row = np.clip(np.floor(fy), 0, np.maximum(vh - 1, 0)).astype(np.int64)
        nrm = None if nrm_all is None else nrm_all[sel]
        if nrm is not None:  # X's texel footprint: spacing of neighbouring texel rays at X's depth
            o0, s0 = _texel_rays(inv, vp, ndc[:, :2])
            o1, s1 = _texel_rays(inv, vp, ndc[:, :2] + np.stack([2.0 / np.maximum(vw, 1), 0.0 * vw], axis=1))
            with np.errstate(invalid="ignore"):
                footprint = np.linalg.norm((o1 + w[:, None] * s1) - (o0 + w[:, None] * s0), axis=1)
        hit = np.zeros(len(sel), bool)
        for dx, dy in offsets:
            c, r = col + dx, row + dy
            live = inside & ~hit & (c >= 0) & (c < vw) & (r >= 0) & (r < vh)
            gx, gy = vx + c, vy + r
            live &= (gx >= 0) & (gx < wa) & (gy >= 0) & (gy < ha)
            if not live.any():
                continue
            idx = np.nonzero(live)[0]
            centre = np.stack([(c[idx] + 0.5) / vw[idx] * 2.0 - 1.0, 1.0 - (r[idx] + 0.5) / vh[idx] * 2.0], axis=1)
            stored = layers[:, gy[idx], gx[idx]].astype(np.float64)  # (L, M)
            filled = stored < EMPTY_DEPTH
            if nrm is None:  # fronto-parallel: the point's own depth
                with np.errstate(invalid="ignore"):
                    match = filled & (np.abs(stored - w[idx][None]) <= rel_tol * w[idx][None])
            else:
                org, step = _texel_rays(inv[idx], vp[idx], centre)
                n, xi = nrm[idx], x[idx]
                with np.errstate(invalid="ignore", divide="ignore"):
                    # D*: where the texel ray meets X's tangent plane (ray depth t: org + t·step)
                    pred = np.sum(n * (xi - org), axis=1) / np.sum(n * step, axis=1)
                    pred = np.where(np.isfinite(pred) & (pred > 0), pred, np.nan)
                    # the stored samples' distances from that plane
                    s_pts = org[None] + stored[..., None] * step[None]  # (L, M, 3)
                    off_plane = np.abs(np.sum(n[None] * (s_pts - xi[None]), axis=-1))
                    match = filled & ((np.abs(stored - pred[None]) <= rel_tol * pred[None])
                                      | (off_plane <= plane_tol * footprint[idx][None]))
            hit[idx] |= match.any(axis=0)
        out[sel] = hit
    return out.reshape(cl.shape)


def captured_by_clusters(diagnostics: ClusterDiagnostics, hit_points: np.ndarray,
                         hit_normals: np.ndarray | None = None, **tolerances: float) -> np.ndarray:
    """`captured_mask` of a reflection frame's cluster images, as the GL pass records
    them (scenes.buffers.ClusterDiagnostics): hit_points, hit_normals (ss·H, ss·W, 3)
    the true (Embree) mirror-ray hits per sample; tolerances: rel_tol, plane_tol,
    radius. Returns (ss·H, ss·W) bool."""
    d = diagnostics
    return captured_mask(hit_points, d.cluster_of_sample, d.view_proj, d.viewports, d.layer_depths, hit_normals,
                         d.clip_planes, **tolerances)


def uncaptured_error_mask(reflective_samples: np.ndarray, hit_points_samples: np.ndarray, captured: np.ndarray,
                          ss: int) -> np.ndarray:
    """(H,W) bool occlusion-error pixels of the thesis's definition from sample
    resolution (ss·H, ss·W) inputs: a pixel is one when a reflective sample of its
    ss×ss block has a true hit (finite hit point) that is not `captured`."""
    bad = uncaptured_sample_mask(reflective_samples, hit_points_samples, captured)
    if bad.shape[0] % ss or bad.shape[1] % ss:
        raise ValueError(f"sample image {bad.shape} is not a multiple of ss = {ss}")
    h, w = bad.shape[0] // ss, bad.shape[1] // ss
    return bad.reshape(h, ss, w, ss).any(axis=(1, 3))


def uncaptured_sample_mask(reflective_samples: np.ndarray, hit_points_samples: np.ndarray,
                           captured: np.ndarray) -> np.ndarray:
    """(ss·H, ss·W) bool: reflective samples whose mirror ray has a true hit
    (finite hit point) that its cluster image does not hold."""
    refl = np.asarray(reflective_samples, bool)
    pts = np.asarray(hit_points_samples)
    cap = np.asarray(captured, bool)
    if not (refl.shape == cap.shape == pts.shape[:-1]):
        raise ValueError(f"shapes differ: {refl.shape}, {pts.shape}, {cap.shape}")
    return refl & np.all(np.isfinite(pts), axis=-1) & ~cap


def uncaptured_ray_percentage(reflective_samples: np.ndarray, hit_points_samples: np.ndarray,
                              captured: np.ndarray) -> float:
    """The thesis's occlusion error per reflected ray: 100 · (uncaptured reflective
    samples) / (reflective samples); 0 without reflective samples. The thesis's
    "reflective pixels" are those of its first pass (§4.7: "generates the
    reflective pixels in the first rendering pass"), which runs at the 2×2
    supersampled resolution (512² output = 1024² first-pass pixels, §4.7.1), each
    with one mirror ray ("the reflected ray of each reflective pixel of the
    cluster", §4.2) — i.e. our samples. `uncaptured_error_mask` counts an output
    pixel instead, when any of its ss×ss rays is an error (the stricter count)."""
    refl = np.asarray(reflective_samples, bool)
    n = int(refl.sum())
    if n == 0:
        return 0.0
    return 100.0 * float(uncaptured_sample_mask(refl, hit_points_samples, captured).sum()) / n

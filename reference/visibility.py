"""Redundancy tests (thesis §2.2.1, Alg. 2 and 3) and Alg. 1 with Embree — never with GL.

Definitions used here and by `reference.sampling_metrics` (culling semantics as
every depth image in the project, DESIGN.md "Back-face culling on"):

* A surface point x on triangle T is *inside the frustum* of camera V when it
  projects into the image rectangle [0, W) × [0, H) and its eye-space depth lies
  in (near, far) (near/far of the camera when set, else (0, inf)).
* x is *visible from* V when it is inside V's frustum, T is front-facing to V
  (n_T · (x − eye) < 0, back faces are culled) and the segment eye → x crosses no
  triangle that is front-facing to V (back-facing triangles are culled, so they
  never occlude). T and the triangles in T's plane are ignored along the segment
  (a line meets a plane once, so any hit on that plane is x's own surface, met
  early only by the float32 rounding of x and of the vertices) and the segment is
  shortened by a relative 1e-4 at x, as `RayCaster.occluded` does.
* Alg. 2 (visibility-redundancy test): a sample s of image I_i is redundant with
  I_j (j < i) iff the point s is visible from V_j in the sense above. The
  non-redundant image I_i stores, per pixel, the nearest front-facing hit of the
  pixel ray that is not visible from any earlier V_j (image 0: plain ray cast).
* Alg. 3 (pixel-redundancy test): s is redundant with I_j iff the texel of I_j
  that s projects to (inside I_j's frustum) stores s's triangle id. The
  reference non-redundant image of this definition stores, per pixel, the
  nearest front-facing hit not pixel-redundant with any earlier image as stored
  (`non_redundant_reference`; GL renders the same in the fragment shader).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from reference.raycast import Hits, RayCaster
from scenes.camera import Camera
from scenes.depth_image import DepthImage
from scenes.model import Scene

#: Relative shortening of a segment at its surface end (as RayCaster.occluded).
REL_EPS = 1e-4
#: Maximum number of surfaces a ray walks through before it gives up.
MAX_LAYERS = 64
#: The two redundancy definitions of §2.2.1.
REDUNDANCY = ("pixel", "visibility")


def clipped(camera: Camera, scene: Scene) -> Camera:
    """`camera` with near/far planes (fitted to the scene bounds when missing)."""
    if camera.near is None or camera.far is None:
        return camera.fit_clip(scene.bounds)
    return camera


def project_texels(camera: Camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (N,3) → (ix (N,) int64, iy (N,) int64, inside (N,) bool): the texel
    containing each point's projection (row 0 = top) and whether the point is
    inside the frustum (image rectangle and (near, far), see module docstring).
    ix/iy are clipped to the image so they can always index it."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    xy, z = camera.project(p)
    near = camera.near if camera.near is not None else 0.0
    far = camera.far if camera.far is not None else np.inf
    with np.errstate(invalid="ignore"):
        fx, fy = np.floor(xy[:, 0]), np.floor(xy[:, 1])
        inside = (z > near) & (z < far) & (fx >= 0) & (fx < camera.width) & (fy >= 0) & (fy < camera.height)
    inside &= np.isfinite(fx) & np.isfinite(fy)
    ix = np.where(inside, fx, 0).astype(np.int64)
    iy = np.where(inside, fy, 0).astype(np.int64)
    return ix, iy, inside


def front_facing(caster: RayCaster, eye: np.ndarray, points: np.ndarray, tri_id: np.ndarray) -> np.ndarray:
    """(N,) bool: triangle tri_id (1-based, > 0) at `points` faces `eye`."""
    n = caster.face_normals[np.asarray(tri_id, np.int64) - 1]
    return np.einsum("ij,ij->i", n, np.asarray(points, np.float64) - np.asarray(eye, np.float64)) < 0


def count_front_hits(caster: RayCaster, a: np.ndarray, b: np.ndarray, tri_b: np.ndarray,
                     max_count: int | np.ndarray = 0) -> np.ndarray:
    """Number of triangles front-facing to `a` that the segment a → b crosses
    before b, capped at max_count + 1 (so `== 0` means b is visible from a).

    a (3,) the eye; b (N,3) surface points on triangles tri_b (N,) (ignored along
    the segment, see module docstring); max_count scalar or (N,). Back faces are
    culled exactly, as the images are cast (`RayCaster.cast_from`: a back face met
    at the same t as a front face, at a silhouette edge, does not hide it)."""
    eye = np.asarray(a, np.float64).reshape(3)
    b = np.asarray(b, np.float64).reshape(-1, 3)
    a = np.broadcast_to(eye, b.shape)
    n = len(b)
    count = np.zeros(n, np.int64)
    if n == 0:
        return count
    seg = b - a
    length = np.linalg.norm(seg, axis=1)
    d = seg / np.maximum(length, 1e-30)[:, None]
    eps = caster.eps
    tmax = np.maximum(length * (1 - REL_EPS) - 2 * eps, 0.0)
    travelled = np.full(n, eps)
    last = np.zeros(n, np.uint32)
    tri_b = np.asarray(tri_b, np.uint32).reshape(-1)
    cap = np.broadcast_to(np.asarray(max_count, np.int64), (n,))
    active = np.flatnonzero(tmax > travelled)
    # Fast path: one any-hit query (no culling) over the same segment; a segment
    # that meets no triangle at all has count 0 and needs no walk.
    if len(active):
        blocked = caster.occluded(a[active], b[active], cull_back_faces=False, rel_eps=REL_EPS)
        active = active[blocked]
    for _ in range(MAX_LAYERS):
        if len(active) == 0:
            break
        h = caster.cast_from(eye, d[active], tmax[active], start=travelled[active])
        hit = h.hit
        idx = active[hit]
        th = h.t[hit]
        tri = h.tri_id[hit]
        # own surface (T or a triangle in T's plane: the segment meets it at b) /
        # re-hit of the last one
        real = (tri != tri_b[idx]) & (tri != last[idx])
        real[real] = ~caster.same_plane(tri[real], tri_b[idx][real])
        count[idx[real]] += 1
        travelled[idx] = th + eps
        last[idx] = tri
        cont = (count[idx] <= cap[idx]) & (travelled[idx] < tmax[idx])
        active = idx[cont]
    return count


def visible_from(caster: RayCaster, camera: Camera, points: np.ndarray, tri_id: np.ndarray) -> np.ndarray:
    """(N,) bool: surface points (N,3) on triangles tri_id (N,) are visible from
    `camera` (inside its frustum, front-facing, unoccluded; module docstring)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    tri_id = np.asarray(tri_id, np.uint32).reshape(-1)
    _, _, inside = project_texels(camera, p)
    cand = np.flatnonzero(inside & (tri_id > 0))
    eye = np.asarray(camera.eye, np.float64)
    cand = cand[front_facing(caster, eye, p[cand], tri_id[cand])]
    out = np.zeros(len(p), bool)
    out[cand] = count_front_hits(caster, eye, p[cand], tri_id[cand], 0) == 0
    return out


def pixel_redundant(image_tri: np.ndarray, camera: Camera, points: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """(N,) bool, Alg. 3: the texel of `image_tri` (H,W) that each point projects
    to (inside the frustum of `camera`) holds the point's triangle id."""
    ix, iy, inside = project_texels(camera, points)
    return inside & (image_tri[iy, ix] == np.asarray(tri, np.uint32))


def redundant_with(caster: RayCaster, image: DepthImage, points: np.ndarray, tri: np.ndarray,
                   redundancy: str) -> np.ndarray:
    """(N,) bool: surface points on triangles `tri` are redundant with `image`
    (module docstring; visibility ignores the stored content, as §2.2.1)."""
    if redundancy == "pixel":
        return pixel_redundant(image.tri_id, image.camera, points, tri)
    if redundancy == "visibility":
        return visible_from(caster, image.camera, points, tri)
    raise ValueError(f"redundancy must be one of {REDUNDANCY}, got {redundancy!r}")


def any_redundant(caster: RayCaster, images: Sequence[DepthImage], pts: np.ndarray, tri: np.ndarray,
                  redundancy: str, select: np.ndarray | None = None) -> np.ndarray:
    """(N,) bool: redundant with at least one of `images`; tests only where
    `select` (default all) and each point at most until it is found redundant."""
    out = np.zeros(len(pts), bool)
    todo = np.ones(len(pts), bool) if select is None else select.copy()
    for im in images:
        idx = np.flatnonzero(todo)
        if len(idx) == 0:
            break
        r = redundant_with(caster, im, pts[idx], tri[idx], redundancy)
        out[idx[r]] = True
        todo[idx[r]] = False
    return out


def depth_image_from_hits(caster: RayCaster, camera: Camera, hits: Hits, directions: np.ndarray) -> DepthImage:
    """DepthImage (row 0 = top) from per-pixel hits of `camera`'s pixel rays,
    shaded exactly like RayCaster.gbuffer; misses hold no sample (colour 0, as the GL
    depth images' background)."""
    h, w = camera.height, camera.width
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    col, n = caster.shade_hits(hits, d)
    _, _, fwd = camera.basis()
    hit = hits.hit
    t = np.where(hit, hits.t, 0.0)
    eye = np.asarray(camera.eye, np.float64)
    depth = np.where(hit, t * (d @ fwd), np.inf)
    pos = np.where(hit[:, None], eye + d * t[:, None], 0.0)
    return DepthImage(
        camera=camera,
        color=np.where(hit[:, None], col, 0.0).reshape(h, w, 3).astype(np.float32),
        depth=depth.reshape(h, w).astype(np.float32),
        normal=n.reshape(h, w, 3).astype(np.float32),
        position=pos.reshape(h, w, 3).astype(np.float32),
        tri_id=hits.tri_id.reshape(h, w).astype(np.uint32),
    )


def conventional_reference(scene: Scene, cameras: Sequence[Camera],
                           caster: RayCaster | None = None) -> list[DepthImage]:
    """Conventional depth images by Embree ray casting (front faces only)."""
    rc = caster or RayCaster(scene)
    out = []
    for cam in cameras:
        cam = clipped(cam, scene)
        d = cam.pixel_directions().reshape(-1, 3)
        out.append(depth_image_from_hits(rc, cam, rc.cast_from(np.asarray(cam.eye, np.float64), d), d))
    return out


def non_redundant_reference(scene: Scene, cameras: Sequence[Camera], redundancy: str = "visibility",
                            caster: RayCaster | None = None, max_layers: int = MAX_LAYERS) -> list[DepthImage]:
    """Alg. 1 by Embree with the redundancy test of Alg. 2 ("visibility") or
    Alg. 3 ("pixel", against the earlier images of this set as stored).

    For each pixel of image i the ray's front-facing hits are walked in depth
    order (restarting just past each hit) and the first hit that is not
    redundant with any earlier image I_j (j < i) is kept (module docstring for
    "visible"). Image 0 is a plain ray cast. Vectorised over pixels: one Embree
    batch per layer. Cameras without near/far get them fitted to the scene
    bounds. The pixel variant is the GL-independent reference of
    `gl_passes.depth_images.non_redundant`."""
    if redundancy not in REDUNDANCY:
        raise ValueError(f"redundancy must be one of {REDUNDANCY}, got {redundancy!r}")
    rc = caster or RayCaster(scene)
    cams = [clipped(c, scene) for c in cameras]
    images: list[DepthImage] = []
    for cam in cams:
        d = cam.pixel_directions().reshape(-1, 3)
        eye = np.asarray(cam.eye, np.float64)
        n = len(d)
        t = np.full(n, np.inf)
        tri = np.zeros(n, np.uint32)
        u = np.zeros(n)
        v = np.zeros(n)
        travelled = np.zeros(n)
        last = np.zeros(n, np.uint32)
        active = np.arange(n)
        for _ in range(max_layers):
            if len(active) == 0:
                break
            h = rc.cast_from(eye, d[active], start=travelled[active])
            hit = h.hit
            idx = active[hit]
            th = h.t[hit]
            ht = h.tri_id[hit]
            # Test the point the image will store (float32 positions, as
            # depth_image_from_hits writes them), so that re-testing the stored
            # samples (reference.sampling_metrics) gives the same answer even for
            # occlusion rays that graze an edge.
            pts = (eye + d[idx] * th[:, None]).astype(np.float32).astype(np.float64)
            stepped_past = ht == last[idx]  # re-hit of the surface we just stepped past
            redundant = stepped_past | any_redundant(rc, images, pts, ht, redundancy, select=~stepped_past)
            keep = ~redundant
            k = idx[keep]
            t[k], tri[k] = th[keep], ht[keep]
            u[k], v[k] = h.u[hit][keep], h.v[hit][keep]
            again = idx[redundant]
            travelled[again] = th[redundant] + rc.eps
            last[again] = ht[redundant]
            active = again
        hits = Hits(t=t, tri_id=tri, u=u, v=v, front=tri > 0)
        images.append(depth_image_from_hits(rc, cam, hits, d))
    return images


def non_redundant_visibility(scene: Scene, cameras: Sequence[Camera], caster: RayCaster | None = None,
                             max_layers: int = MAX_LAYERS) -> list[DepthImage]:
    """Alg. 1 with the visibility-redundancy test of Alg. 2, by Embree
    (`non_redundant_reference`): per pixel of image i, the nearest front-facing
    hit not visible from any earlier viewpoint V_j inside I_j's frustum."""
    return non_redundant_reference(scene, cameras, "visibility", caster, max_layers)

"""Embree (embreex) reference ray casting (DESIGN.md "Conventions").

Primary rays give the same buffers as the GL G-buffer (colour with the same
local shading, linear depth, normal, position, triangle and object ids,
material); batched point-to-point occlusion queries serve visibility tests and
shadow ground truth. Back-face culling is emulated by continuing rays past
back-facing hits, as Embree here is built without it.
"""

from __future__ import annotations

import os
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from embreex import mesh_construction, rtcore_scene

from scenes.buffers import FrameBuffers
from scenes.camera import Camera
from scenes.model import Scene
from scenes.shading import local_shade, sky

_MAX_LAYERS = 64  # back-face skips per ray before giving up (pathological scenes)


@dataclass
class Hits:
    """Per-ray results (N = number of rays). t (N,) float64 distance along the
    unit direction (+inf on a miss); tri_id (N,) uint32 (0 = miss); u, v (N,)
    float64 barycentrics of vertices 1 and 2; front (N,) bool front-facing."""

    t: np.ndarray
    tri_id: np.ndarray
    u: np.ndarray
    v: np.ndarray
    front: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return self.tri_id > 0


#: Reference primary-ray buffers: the same layout as the GL G-buffer.
RayBuffers = FrameBuffers


def _ray_limits(tmax: np.ndarray | float | None, n: int) -> np.ndarray:
    """(n,) float64 maximum ray distances: tmax broadcast (None = unbounded),
    capped at 1e30 so Embree's float32 tfar stays finite."""
    limit = np.inf if tmax is None else np.asarray(tmax, np.float64)
    return np.minimum(np.broadcast_to(limit, (n,)), 1e30)


#: Rays per Embree call below which the batch is not split across threads.
PARALLEL_MIN_RAYS = 65536


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity mask where the OS has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - non-Linux
        return os.cpu_count() or 1


_WORKERS = max(1, min(usable_cpus(), 16))
_pool: ThreadPoolExecutor | None = None


def _embree_run(emb: object, o: np.ndarray, d: np.ndarray, tmax: np.ndarray, **kw: object) -> dict | np.ndarray:
    """emb.run on float32 rays, split into one chunk per CPU for large batches:
    embreex releases the GIL while Embree traces, so the chunks run in parallel
    with identical per-ray results (tested)."""
    global _pool
    o32, d32, t32 = o.astype(np.float32), d.astype(np.float32), tmax.astype(np.float32)
    n = len(o32)
    if _WORKERS == 1 or n < PARALLEL_MIN_RAYS:
        return emb.run(o32, d32, dists=t32, **kw)
    if _pool is None:
        _pool = ThreadPoolExecutor(_WORKERS, thread_name_prefix="embree")
    cuts = np.linspace(0, n, _WORKERS + 1).astype(np.int64)
    parts = list(_pool.map(lambda ab: emb.run(o32[ab[0]:ab[1]], d32[ab[0]:ab[1]], dists=t32[ab[0]:ab[1]], **kw),
                           zip(cuts[:-1], cuts[1:], strict=True)))
    if isinstance(parts[0], dict):
        return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return np.concatenate([np.asarray(p) for p in parts])


def _embree_scene(vertices: np.ndarray, faces: np.ndarray) -> object:
    emb = rtcore_scene.EmbreeScene()
    mesh_construction.TriangleMesh(emb, np.ascontiguousarray(vertices, np.float32),
                                   np.ascontiguousarray(faces, np.int32))
    return emb


def _reversed_twins(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) int64: for each face the index of a coincident face with the opposite
    winding (same three positions), else −1. Two-sided thin geometry is often
    modelled this way; ray casting must then pick the copy that faces the ray."""
    _, pos_id = np.unique(vertices, axis=0, return_inverse=True)
    tri = pos_id.reshape(-1)[faces]  # (F,3) canonical position ids
    key = np.sort(tri, axis=1)
    _, group, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    group = group.reshape(-1)
    twin = np.full(len(faces), -1, np.int64)
    pairs = np.flatnonzero(counts[group] == 2)
    if len(pairs) == 0:
        return twin
    order = pairs[np.argsort(group[pairs], kind="stable")]
    a, b = order[0::2], order[1::2]
    # Opposite winding: b is an odd permutation of a's positions.
    ta, tb = tri[a], tri[b]
    same_cycle = np.zeros(len(a), bool)
    for shift in range(3):
        same_cycle |= (np.roll(tb, shift, axis=1) == ta).all(axis=1)
    a, b = a[~same_cycle], b[~same_cycle]
    twin[a], twin[b] = b, a
    return twin


class RayCaster:
    """Embree scene over a Scene's concatenated triangles (primID = id − 1)."""

    def __init__(self, scene: Scene) -> None:
        self.scene = scene
        self._v = scene.vertices.astype(np.float64)
        self._f = scene.faces.astype(np.int64)
        self._embree = _embree_scene(scene.vertices, self._f)
        self._viewpoint_cache: OrderedDict[tuple[float, ...], tuple[object | None, np.ndarray]] = OrderedDict()
        e1 = self._v[self._f[:, 1]] - self._v[self._f[:, 0]]
        e2 = self._v[self._f[:, 2]] - self._v[self._f[:, 0]]
        self.face_normals = np.cross(e1, e2)  # (F,3) unnormalised, CCW front
        self.twin = _reversed_twins(scene.vertices, self._f)
        # Offset for restarting rays past a surface: tiny against the scene size.
        self.eps = 1e-6 * max(scene.diagonal, 1e-6)
        length = np.linalg.norm(self.face_normals, axis=1, keepdims=True)
        self._unit_normals = self.face_normals / np.where(length > 0, length, 1.0)
        # float32 vertices are off their exact plane by up to ~half an ulp of the
        # largest coordinate: a plane offset within 16 such ulps is the same plane.
        self._plane_tol = 16 * 2.0**-24 * max(float(np.abs(self._v).max(initial=0.0)), 1e-30)

    def _viewpoint_scene(self, eye: np.ndarray) -> tuple[object | None, np.ndarray]:
        """Embree scene of the faces front-facing as seen from `eye`, and the map
        from its primIDs to global face indices. Rays from one point meet a
        triangle's front exactly when the point is on its positive side, so this is
        exact back-face culling (coplanar back faces cannot hide front faces)."""
        key = tuple(float(x) for x in eye)
        if key in self._viewpoint_cache:
            self._viewpoint_cache.move_to_end(key)
            return self._viewpoint_cache[key]
        a = self._v[self._f[:, 0]]
        front = np.flatnonzero(np.einsum("ij,ij->i", self.face_normals, np.asarray(eye) - a) > 0)
        entry = (_embree_scene(self.scene.vertices, self._f[front]) if len(front) else None, front)
        self._viewpoint_cache[key] = entry
        if len(self._viewpoint_cache) > 4:
            self._viewpoint_cache.popitem(last=False)
        return entry

    def cast_from(self, eye: np.ndarray, directions: np.ndarray, tmax: np.ndarray | float | None = None,
                  start: np.ndarray | None = None) -> Hits:
        """Closest front-facing hit of rays from the single point `eye` (3,) along
        unit `directions` (N,3), at distances t in (start, tmax) from `eye` (start
        (N,) default 0: a walk through a ray's surfaces restarts past each), with
        exact back-face culling: a per-viewpoint BVH of the faces front-facing from
        `eye`, cached for the last few viewpoints. So a back face never hides a
        front face it meets at the same t (a silhouette edge shared by a front and
        a back face), which culling hit by hit cannot promise."""
        eye = np.asarray(eye, np.float64)
        d = np.asarray(directions, np.float64).reshape(-1, 3)
        n = len(d)
        limit = _ray_limits(tmax, n)
        t0 = np.zeros(n) if start is None else np.asarray(start, np.float64).reshape(n)
        emb, faces = self._viewpoint_scene(eye)
        t = np.full(n, np.inf)
        tri = np.zeros(n, np.uint32)
        u = np.zeros(n)
        v = np.zeros(n)
        if emb is not None and n:
            r = _embree_run(emb, eye + d * t0[:, None], d, np.maximum(limit - t0, 0.0), output=1)
            hit = (r["primID"] >= 0) & (limit > t0)
            t[hit] = t0[hit] + r["tfar"][hit]
            tri[hit] = faces[r["primID"][hit]].astype(np.uint32) + 1
            u[hit], v[hit] = r["u"][hit], r["v"][hit]
        return Hits(t=t, tri_id=tri, u=u, v=v, front=tri > 0)

    def _run(self, o: np.ndarray, d: np.ndarray, tmax: np.ndarray) -> dict:
        return _embree_run(self._embree, o, d, tmax, output=1)

    def intersect(self, origins: np.ndarray, directions: np.ndarray, tmax: np.ndarray | float | None = None,
                  cull_back_faces: bool = True) -> Hits:
        """Closest hit of each ray. origins, directions (N,3) (directions unit);
        tmax scalar or (N,) maximum distance. With culling, back-facing hits are
        skipped (the ray continues past them)."""
        o = np.asarray(origins, np.float64).reshape(-1, 3)
        d = np.asarray(directions, np.float64).reshape(-1, 3)
        n = len(o)
        limit = _ray_limits(tmax, n)
        t = np.full(n, np.inf)
        tri = np.zeros(n, np.uint32)
        u = np.zeros(n)
        v = np.zeros(n)
        front = np.zeros(n, bool)
        travelled = np.zeros(n)
        active = np.arange(n)
        for _ in range(_MAX_LAYERS):
            if len(active) == 0:
                break
            start = o[active] + d[active] * travelled[active, None]
            r = self._run(start, d[active], limit[active] - travelled[active])
            prim = r["primID"]
            hit = prim >= 0
            idx, p = active[hit], prim[hit]
            th = travelled[idx] + r["tfar"][hit].astype(np.float64)
            is_front = np.einsum("ij,ij->i", self.face_normals[p], d[idx]) < 0
            hu, hv = r["u"][hit].astype(np.float64), r["v"][hit].astype(np.float64)
            if cull_back_faces:
                # A back face with a coincident reversed twin (two-sided thin geometry):
                # Embree returned either copy; the front-facing one is the real hit.
                swap = ~is_front & (self.twin[p] >= 0)
                if swap.any():
                    p = p.copy()
                    p[swap] = self.twin[p[swap]]
                    hu[swap], hv[swap] = self._barycentrics(p[swap], o[idx[swap]] + d[idx[swap]] * th[swap, None])
                    is_front = is_front | swap
            keep = is_front | (not cull_back_faces)
            k = idx[keep]
            t[k], tri[k] = th[keep], p[keep].astype(np.uint32) + 1
            u[k], v[k] = hu[keep], hv[keep]
            front[k] = is_front[keep]
            # Back faces under culling: restart just past them.
            again = idx[~keep]
            travelled[again] = th[~keep] + self.eps
            active = again
        return Hits(t=t, tri_id=tri, u=u, v=v, front=front)

    def same_plane(self, tri_a: np.ndarray, tri_b: np.ndarray) -> np.ndarray:
        """(N,) bool: triangles tri_a (N,) lie in the plane of triangles tri_b (N,)
        (1-based ids): the same orientation within 1e-6 and every vertex of tri_a
        within float32 rounding of tri_b's plane."""
        a = np.asarray(tri_a, np.int64).reshape(-1) - 1
        b = np.asarray(tri_b, np.int64).reshape(-1) - 1
        n = self._unit_normals[b]
        parallel = np.einsum("ij,ij->i", self._unit_normals[a], n) > 1 - 1e-6
        off = np.einsum("nkj,nj->nk", self._v[self._f[a]] - self._v[self._f[b, 0]][:, None], n)
        return parallel & (np.abs(off).max(axis=1, initial=0.0) <= self._plane_tol)

    def _barycentrics(self, faces: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Barycentrics (u, v) of vertices 1 and 2 for points (N,3) on faces (N,)."""
        f = self._f[faces]
        a, b, c = self._v[f[:, 0]], self._v[f[:, 1]], self._v[f[:, 2]]
        e1, e2, w = b - a, c - a, points - a
        d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
        w1, w2 = (w * e1).sum(1), (w * e2).sum(1)
        den = np.maximum(d11 * d22 - d12 * d12, 1e-300)
        return (d22 * w1 - d12 * w2) / den, (d11 * w2 - d12 * w1) / den

    def occluded(self, a: np.ndarray, b: np.ndarray, cull_back_faces: bool = False,
                 rel_eps: float = 1e-4) -> np.ndarray:
        """(N,) bool: is the open segment a→b blocked? a, b (N,3). The segment is
        shortened by rel_eps·|b−a| + eps at the b end (b usually lies on a surface)
        and started eps after a."""
        a = np.asarray(a, np.float64).reshape(-1, 3)
        b = np.asarray(b, np.float64).reshape(-1, 3)
        seg = b - a
        length = np.linalg.norm(seg, axis=1)
        d = seg / np.maximum(length, 1e-30)[:, None]
        start = a + d * self.eps
        tmax = np.maximum(length * (1 - rel_eps) - 2 * self.eps, 0.0)
        if not cull_back_faces:
            res = _embree_run(self._embree, start, d, tmax, query="OCCLUDED")
            return np.asarray(res) >= 0
        return self.intersect(start, d, tmax, cull_back_faces=True).hit

    def interpolate_normals(self, tri_id: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Unit shading normals (N,3) float64 at hits (barycentric interpolation of
        vertex normals); zeros where tri_id == 0."""
        n = np.zeros((len(tri_id), 3))
        hit = tri_id > 0
        f = self._f[tri_id[hit].astype(np.int64) - 1]
        vn = self.scene.normals.astype(np.float64)
        w0 = (1 - u[hit] - v[hit])[:, None]
        nn = w0 * vn[f[:, 0]] + u[hit, None] * vn[f[:, 1]] + v[hit, None] * vn[f[:, 2]]
        n[hit] = nn / np.maximum(np.linalg.norm(nn, axis=1, keepdims=True), 1e-30)
        return n

    def shade_hits(self, hits: Hits, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(colour (N,3) float32 with the local shading formula, shading normal
        (N,3) facing the ray for back-face hits); sky colour on misses."""
        d = np.asarray(directions, np.float64).reshape(-1, 3)
        n = self.interpolate_normals(hits.tri_id, hits.u, hits.v)
        n[hits.hit & ~hits.front] *= -1
        sun = np.asarray(self.scene.sun_direction)
        col = sky(d, sun)
        h = hits.hit
        obj = self.scene.face_object[hits.tri_id[h].astype(np.int64) - 1]
        col[h] = local_shade(self.scene.materials[obj, :3], n[h].astype(np.float32), sun)
        return col, n

    def gbuffer(self, camera: Camera, cull_back_faces: bool = True) -> RayBuffers:
        """Primary-ray buffers through every pixel centre of `camera`."""
        h, w = camera.height, camera.width
        d = camera.pixel_directions().reshape(-1, 3)
        o = np.broadcast_to(np.asarray(camera.eye, np.float64), d.shape)
        hits = self.cast_from(camera.eye, d) if cull_back_faces else self.intersect(o, d, cull_back_faces=False)
        col, n = self.shade_hits(hits, d)
        _, _, fwd = camera.basis()
        hit = hits.hit
        depth = np.where(hit, hits.t * (d @ fwd), np.inf)
        pos = np.where(hit[:, None], o + d * np.where(hit, hits.t, 0)[:, None], 0.0)
        obj = np.zeros(len(d), np.uint16)
        obj[hit] = self.scene.face_object[hits.tri_id[hit].astype(np.int64) - 1]
        mat = self.scene.materials[obj]
        return RayBuffers(
            color=col.reshape(h, w, 3).astype(np.float32),
            depth=depth.reshape(h, w).astype(np.float32),
            normal=n.reshape(h, w, 3).astype(np.float32),
            position=pos.reshape(h, w, 3).astype(np.float32),
            tri_id=hits.tri_id.reshape(h, w),
            obj_id=obj.reshape(h, w),
            specular=mat[:, 3].reshape(h, w).astype(np.float32),
            glossiness=mat[:, 4].reshape(h, w).astype(np.float32),
        )

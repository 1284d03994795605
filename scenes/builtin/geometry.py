"""Vectorised triangle-mesh primitives shared by the built-in procedural scenes.

Every generator returns a ``Mesh`` = ``(vertices, faces)``: vertices (V,3) float32 in
world units (metres, +Y up), faces (F,3) uint32 whose triangles are counter-clockwise
seen from their front side (DESIGN.md, "Conventions"). Depth-image sampling culls back
faces (thesis §2.2), so:

* solids (``box``, ``boxes``, ``tubes``/``cylinder``, ``lathe`` with poles or a closed
  profile, ``uv_sphere``/``ellipsoid``) are closed and face outward;
* open surfaces (``grid``/``quad``, ``ribbons``) face along ``u × v`` (or ``side × path``);
  wrap thin things (blades, leaves) in ``two_sided`` so they are visible from both sides.

Batch helpers (``instances``, ``boxes``, ``tubes``, ``ribbons``) build any number of
instances with array operations only, so millions of triangles take well under a second
of numpy time. ``*_triangles`` functions return exact triangle counts without building,
for the cheap estimates of ``scenes.builtin.estimate_triangles``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy import sparse

from scenes.model import AreaLight, Material, SceneObject

#: (vertices (V,3) float32, faces (F,3) uint32).
Mesh = tuple[np.ndarray, np.ndarray]

__all__ = [
    "Mesh", "as_mesh", "empty", "merge", "transform", "instances", "box", "boxes", "grid", "quad",
    "tubes", "cylinder", "lathe", "uv_sphere", "ellipsoid", "ribbons", "two_sided",
    "rotation_y", "rotation_axis_angle", "orthonormal_basis", "fast_vertex_normals",
    "make_object", "scaled_count", "scaled_res", "box_triangles", "grid_triangles",
    "tube_triangles", "lathe_triangles", "sphere_triangles", "ribbon_triangles", "smooth_curve",
    "solid_profile", "vessel_profile", "overhead_area_light", "scene_bounds", "resample_polyline",
    "room_walls", "room_wall_triangles",
]


def _mesh(vertices: np.ndarray, faces: np.ndarray) -> Mesh:
    return (np.ascontiguousarray(vertices, dtype=np.float32).reshape(-1, 3),
            np.ascontiguousarray(faces, dtype=np.uint32).reshape(-1, 3))


def as_mesh(vertices: np.ndarray, faces: np.ndarray) -> Mesh:
    """(vertices, faces) converted to contiguous float32 (V,3) / uint32 (F,3)."""
    return _mesh(np.asarray(vertices), np.asarray(faces))


def empty() -> Mesh:
    """A mesh without vertices or faces."""
    return _mesh(np.zeros((0, 3)), np.zeros((0, 3)))


def merge(meshes: Sequence[Mesh]) -> Mesh:
    """Concatenate meshes (faces re-indexed); order is preserved."""
    if not meshes:
        return empty()
    counts = np.array([len(v) for v, _ in meshes], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
    verts = np.concatenate([v for v, _ in meshes]) if len(meshes) > 1 else meshes[0][0]
    faces = np.concatenate([f.astype(np.int64) + o for (_, f), o in zip(meshes, offsets, strict=True)])
    return _mesh(verts, faces)


def transform(mesh: Mesh, rotation: np.ndarray | None = None, scale: float | Sequence[float] | None = None,
              translation: Sequence[float] | None = None) -> Mesh:
    """v' = R · (scale ⊙ v) + t. A mirroring transform (det < 0) reverses the
    winding so that faces keep their front side outward."""
    v = mesh[0].astype(np.float64)
    f = mesh[1]
    det = 1.0
    if scale is not None:
        s = np.broadcast_to(np.asarray(scale, dtype=np.float64), (3,))
        v = v * s
        det *= float(np.prod(s))
    if rotation is not None:
        r = np.asarray(rotation, dtype=np.float64)
        v = v @ r.T
        det *= float(np.linalg.det(r))
    if translation is not None:
        v = v + np.asarray(translation, dtype=np.float64)
    if det < 0:
        f = f[:, [0, 2, 1]]
    return _mesh(v, f)


def instances(template: Mesh, translations: np.ndarray, rotations: np.ndarray | None = None,
              scales: np.ndarray | None = None) -> Mesh:
    """N copies of ``template``: copy i is R_i · (s_i ⊙ v) + t_i.

    translations (N,3); rotations (N,3,3) proper rotations or None; scales (N,), (N,3)
    (positive) or None. One array expression for all copies (no per-instance loop).
    """
    tv = template[0].astype(np.float64)
    tf = template[1].astype(np.int64)
    t = np.asarray(translations, dtype=np.float64).reshape(-1, 3)
    n = len(t)
    v = np.broadcast_to(tv, (n, *tv.shape))
    if scales is not None:
        s = np.asarray(scales, dtype=np.float64)
        s = s.reshape(n, 1, 1) if s.ndim == 1 else s.reshape(n, 1, 3)
        v = v * s
    if rotations is not None:
        v = np.einsum("nij,nvj->nvi", np.asarray(rotations, dtype=np.float64).reshape(n, 3, 3), v)
    v = v + t[:, None, :]
    f = tf[None, :, :] + (np.arange(n, dtype=np.int64) * len(tv))[:, None, None]
    return _mesh(v, f)


# --- planar grids and boxes -----------------------------------------------------------


def _grid_faces(nu: int, nv: int) -> np.ndarray:
    """Faces of an (nu+1)×(nv+1) vertex grid indexed i*(nv+1)+j, front = u × v."""
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    a = (i * (nv + 1) + j).ravel()
    b = a + (nv + 1)  # i+1, j
    c = b + 1  # i+1, j+1
    d = a + 1  # i, j+1
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def grid_triangles(nu: int, nv: int) -> int:
    return 2 * nu * nv


def grid(origin: Sequence[float], u: Sequence[float], v: Sequence[float], nu: int = 1, nv: int = 1) -> Mesh:
    """Parallelogram origin + a·u + b·v (a, b in [0, 1]) split into nu×nv cells of
    two triangles; single-sided, front face along u × v."""
    o, uu, vv = (np.asarray(x, dtype=np.float64) for x in (origin, u, v))
    a = np.linspace(0.0, 1.0, nu + 1)
    b = np.linspace(0.0, 1.0, nv + 1)
    verts = o + a[:, None, None] * uu + b[None, :, None] * vv
    return _mesh(verts.reshape(-1, 3), _grid_faces(nu, nv))


def quad(origin: Sequence[float], u: Sequence[float], v: Sequence[float]) -> Mesh:
    """A flat single-sided quad (two triangles), front face along u × v."""
    return grid(origin, u, v, 1, 1)


def disc_triangles(segments: int) -> int:
    return segments


def disc(center: Sequence[float], radius: float, segments: int = 48) -> Mesh:
    """A flat horizontal disc (regular ``segments``-gon) at height center[1], a fan
    of ``segments`` triangles around its centre; single-sided, facing up (+Y)."""
    c = np.asarray(center, dtype=np.float64)
    a = 2.0 * np.pi * np.arange(segments) / segments
    rim = c + radius * np.stack([np.cos(a), np.zeros(segments), np.sin(a)], 1)
    k = np.arange(segments)
    # (centre, rim[k+1], rim[k]): counter-clockwise seen from above, so u × v points up
    faces = np.stack([np.zeros(segments, np.int64), 1 + (k + 1) % segments, 1 + k], 1)
    return _mesh(np.concatenate([c[None], rim]), faces)


def footprint_disc(meshes: Sequence[Mesh], scale: float = 1.4, segments: int = 48, y: float = 0.0) -> Mesh:
    """A modest ground under an object: `disc` at height y centred on the
    horizontal (x, z) bounding-box centre of `meshes`, its diameter ``scale`` × the
    larger horizontal extent of that box (the object's footprint)."""
    lo, hi = scene_bounds(meshes)
    c = (lo + hi) / 2
    ext = float(max(hi[0] - lo[0], hi[2] - lo[2]))
    return disc((float(c[0]), y, float(c[2])), 0.5 * scale * ext, segments)


def _axis_coords(lo: float, hi: float, n: int) -> np.ndarray:
    c = lo + (hi - lo) * np.linspace(0.0, 1.0, n + 1)
    c[0], c[-1] = lo, hi  # exact endpoints: shared box edges get identical coordinates
    return c


def box_triangles(divisions: int = 1) -> int:
    return 12 * divisions * divisions


def box(lo: Sequence[float], hi: Sequence[float], divisions: int = 1) -> Mesh:
    """Closed axis-aligned box, faces outward; each side split into divisions² cells.
    Every side has its own vertices (flat vertex normals); shared edges have
    bit-identical coordinates, so merging vertices by position gives a watertight mesh."""
    lo_, hi_ = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    if np.any(hi_ <= lo_):
        raise ValueError(f"box needs hi > lo, got lo={lo_}, hi={hi_}")
    n = int(divisions)
    coords = [_axis_coords(lo_[k], hi_[k], n) for k in range(3)]
    faces_f = _grid_faces(n, n)
    parts: list[Mesh] = []
    for k in range(3):  # fixed axis k; (a1, a2) with e_a1 × e_a2 = e_k
        a1, a2 = (k + 1) % 3, (k + 2) % 3
        for side, val in ((1, hi_[k]), (-1, lo_[k])):
            p, q = (a1, a2) if side > 0 else (a2, a1)
            g1, g2 = np.meshgrid(coords[p], coords[q], indexing="ij")
            verts = np.empty((n + 1, n + 1, 3))
            verts[..., p], verts[..., q], verts[..., k] = g1, g2, val
            parts.append((verts.reshape(-1, 3), faces_f))
    return merge(parts)


_UNIT_BOX = box((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5))


def boxes(centers: np.ndarray, sizes: np.ndarray, yaw: np.ndarray | None = None) -> Mesh:
    """N closed boxes (12 triangles each): centres (N,3), full sizes (N,3) > 0,
    optional rotation about +Y by yaw (N,) radians."""
    centers = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    rot = None if yaw is None else rotation_y(np.asarray(yaw, dtype=np.float64))
    return instances(_UNIT_BOX, centers, rot, np.asarray(sizes, dtype=np.float64).reshape(-1, 3))


# --- rotations ---------------------------------------------------------------------------


def rotation_y(angles: np.ndarray | float) -> np.ndarray:
    """Rotation matrices about +Y (N,3,3) (or (3,3) for a scalar), right-handed."""
    a = np.asarray(angles, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def rotation_axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues rotations (N,3,3) about unit-normalised axes (N,3) by angles (N,)."""
    k = np.asarray(axis, dtype=np.float64).reshape(-1, 3)
    k = k / np.linalg.norm(k, axis=1, keepdims=True)
    a = np.asarray(angle, dtype=np.float64).reshape(-1)
    c, s = np.cos(a)[:, None, None], np.sin(a)[:, None, None]
    kx = np.zeros((len(k), 3, 3))
    kx[:, 0, 1], kx[:, 0, 2] = -k[:, 2], k[:, 1]
    kx[:, 1, 0], kx[:, 1, 2] = k[:, 2], -k[:, 0]
    kx[:, 2, 0], kx[:, 2, 1] = -k[:, 1], k[:, 0]
    return np.eye(3) + s * kx + (1 - c) * (kx @ kx)


def orthonormal_basis(directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For unit directions t (...,3) return unit u, w with (u, w, t) right-handed
    (u × w = t). u is built from the world axis least aligned with t."""
    t = np.asarray(directions, dtype=np.float64)
    ref = np.zeros_like(t)
    idx = np.argmin(np.abs(t), axis=-1)
    np.put_along_axis(ref, idx[..., None], 1.0, axis=-1)
    u = ref - np.sum(ref * t, -1, keepdims=True) * t
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    return u, np.cross(t, u)


# --- tubes (twigs, trunks, branches, rails) --------------------------------------------


def tube_triangles(segments: int, sides: int, caps: bool = True) -> int:
    return 2 * segments * sides + (2 * (sides - 2) if caps else 0)


def _ring_faces(n_rings: int, sides: int) -> np.ndarray:
    """Side faces between consecutive rings of ``sides`` vertices (ring k, vertex j at
    k*sides + j, angle increasing from u toward w, u × w = path direction): outward."""
    k, j = np.meshgrid(np.arange(n_rings - 1), np.arange(sides), indexing="ij")
    a = (k * sides + j).ravel()
    d = (k * sides + (j + 1) % sides).ravel()
    b, c = a + sides, d + sides
    return np.concatenate([np.stack([a, c, b], 1), np.stack([a, d, c], 1)])


def tubes(paths: np.ndarray, radii: np.ndarray | float, sides: int = 6, caps: bool = True) -> Mesh:
    """N closed tubes (generalised prisms) along polylines, built in one batch.

    paths (N,K+1,3): K ≥ 1 segments per tube; radii scalar, (N,) or (N,K+1) (tapering);
    ``sides`` ≥ 3 sides per ring. With caps each tube is a closed, outward-facing solid
    of 2·K·sides + 2·(sides−2) triangles (``tube_triangles``); caps have their own
    vertices so their normals are flat, the sides are smooth. A two-point path is a
    capped cylinder (prism) between two points — the twig/branch primitive.
    """
    p = np.asarray(paths, dtype=np.float64)
    if p.ndim == 2:
        p = p[None]
    n, m, _ = p.shape
    if m < 2 or sides < 3:
        raise ValueError("tubes need at least 2 path points and 3 sides")
    r = np.broadcast_to(np.asarray(radii, dtype=np.float64).reshape(-1, 1) if np.ndim(radii) == 1
                        else np.asarray(radii, dtype=np.float64), (n, m))
    tang = np.empty_like(p)
    tang[:, 1:-1] = p[:, 2:] - p[:, :-2]
    tang[:, 0] = p[:, 1] - p[:, 0]
    tang[:, -1] = p[:, -1] - p[:, -2]
    tang /= np.maximum(np.linalg.norm(tang, axis=-1, keepdims=True), 1e-300)
    # one reference axis per tube (least aligned with its overall direction) keeps the
    # rings of a tube from twisting; fall back per point where it is parallel locally.
    overall = p[:, -1] - p[:, 0]
    ref = np.zeros((n, 3))
    ref[np.arange(n), np.argmin(np.abs(overall), axis=1)] = 1.0
    u = ref[:, None, :] - np.sum(ref[:, None, :] * tang, -1, keepdims=True) * tang
    un = np.linalg.norm(u, axis=-1, keepdims=True)
    bad = un[..., 0] < 1e-3
    if np.any(bad):
        u_alt, _ = orthonormal_basis(tang[bad])
        u[bad], un[bad] = u_alt, 1.0
    u /= un
    w = np.cross(tang, u)
    theta = 2.0 * np.pi * np.arange(sides) / sides
    ring = np.cos(theta)[:, None] * u[:, :, None, :] + np.sin(theta)[:, None] * w[:, :, None, :]
    side_v = p[:, :, None, :] + r[:, :, None, None] * ring  # (N, M, S, 3)
    per = m * sides
    f_side = _ring_faces(m, sides)
    if caps:
        verts = np.concatenate([side_v.reshape(n, per, 3), side_v[:, 0], side_v[:, -1]], axis=1)
        j = np.arange(1, sides - 1)
        start = np.stack([np.zeros_like(j), j + 1, j], 1) + per
        end = np.stack([np.zeros_like(j), j, j + 1], 1) + per + sides
        f_one = np.concatenate([f_side, start, end])
        per += 2 * sides
    else:
        verts = side_v.reshape(n, per, 3)
        f_one = f_side
    faces = f_one[None] + (np.arange(n, dtype=np.int64) * per)[:, None, None]
    return _mesh(verts, faces)


def cylinder(p0: Sequence[float], p1: Sequence[float], radius: float, sides: int = 12, caps: bool = True) -> Mesh:
    """A capped cylinder / prism with ``sides`` sides between two points."""
    return tubes(np.array([[p0, p1]], dtype=np.float64), radius, sides, caps)


# --- surfaces of revolution ------------------------------------------------------------------


def lathe_triangles(n_profile: int, segments: int, n_poles: int = 0, closed: bool = False) -> int:
    spans = n_profile if closed else n_profile - 1
    return 2 * spans * segments - n_poles * segments


def lathe(profile: np.ndarray, segments: int, closed: bool = False) -> Mesh:
    """Surface of revolution of a profile about the +Y axis.

    profile (P,2) rows (r, y) with r ≥ 0. Either the profile starts and/or ends on the
    axis (r = 0: a pole, one vertex) — from pole to pole it bounds a closed solid — or
    ``closed=True`` treats it as a closed polygon (a solid ring: table top, lamp shade
    with wall thickness). The orientation is fixed automatically (the profile, closed
    through the axis, is made counter-clockwise in the (r, y) half-plane) so faces point
    out of the solid. Vertex (r, y) at angle θ maps to (r cos θ, y, −r sin θ). Interior
    profile points must have r > 0 and consecutive points must differ.
    """
    prof = np.asarray(profile, dtype=np.float64).reshape(-1, 2).copy()
    prof[:, 0] = np.maximum(prof[:, 0], 0.0)
    if len(prof) < 2 or segments < 3:
        raise ValueError("lathe needs at least 2 profile points and 3 segments")
    poles = prof[:, 0] == 0.0
    if closed and np.any(poles):
        raise ValueError("a closed lathe profile must stay off the axis")
    if np.any(poles[1:-1]):
        raise ValueError("only the first and last profile points may lie on the axis")
    x, y = prof[:, 0], prof[:, 1]
    area2 = float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))  # closed through the axis
    if area2 < 0:
        prof, poles = prof[::-1].copy(), poles[::-1].copy()
    if closed:
        prof = np.concatenate([prof, prof[:1]])
        poles = np.concatenate([poles, poles[:1]])
    theta = 2.0 * np.pi * np.arange(segments) / segments
    cos, sin = np.cos(theta), -np.sin(theta)
    n_rings = len(prof)
    ring_v = np.stack([prof[:, :1] * cos, np.broadcast_to(prof[:, 1:2], (n_rings, segments)),
                       prof[:, :1] * sin], -1)  # (R, S, 3)
    faces = _ring_faces(n_rings, segments)
    verts = ring_v.reshape(-1, 3)
    if closed:  # last ring = first ring
        faces = np.where(faces >= (n_rings - 1) * segments, faces - (n_rings - 1) * segments, faces)
        verts = verts[: (n_rings - 1) * segments]
    else:  # collapse pole rings to one vertex and drop the triangles that degenerate
        keep = np.ones(len(verts), dtype=bool)
        remap = np.arange(len(verts))
        for k in (0, n_rings - 1):
            if poles[k]:
                remap[k * segments: (k + 1) * segments] = k * segments
                keep[k * segments + 1: (k + 1) * segments] = False
        faces = remap[faces]
        ok = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
        faces = faces[ok]
        new_index = np.cumsum(keep) - 1
        faces = new_index[faces]
        verts = verts[keep]
    return _mesh(verts, faces)


def sphere_triangles(n_lat: int, n_lon: int) -> int:
    return 2 * n_lon * (n_lat - 1)


def uv_sphere(center: Sequence[float] = (0.0, 0.0, 0.0), radius: float = 1.0, n_lat: int = 16,
              n_lon: int = 32) -> Mesh:
    """Closed UV sphere: n_lat latitude bands, n_lon longitudes; 2·n_lon·(n_lat−1)
    triangles, outward, single vertices at the poles."""
    return ellipsoid(center, (radius, radius, radius), n_lat, n_lon)


def ellipsoid(center: Sequence[float], radii: Sequence[float], n_lat: int = 16, n_lon: int = 32) -> Mesh:
    """Closed axis-aligned ellipsoid (a scaled ``uv_sphere``)."""
    phi = np.linspace(-np.pi / 2, np.pi / 2, n_lat + 1)
    prof = np.stack([np.cos(phi), np.sin(phi)], 1)
    prof[0, 0] = prof[-1, 0] = 0.0
    return transform(lathe(prof, n_lon), scale=radii, translation=center)


# --- thin surfaces ---------------------------------------------------------------------------


def ribbon_triangles(segments: int, pointed: bool) -> int:
    return 2 * segments - (1 if pointed else 0)


def ribbons(paths: np.ndarray, half_widths: np.ndarray, sides: np.ndarray) -> Mesh:
    """N single-sided strips along polylines (grass blades), built in one batch.

    paths (N,K+1,3); half_widths (N,K+1) or (K+1,); sides (N,3) or (N,K+1,3) unit
    vectors across the strip. The front face is along side × path direction. If every
    last half width is 0 the strip ends in a single tip vertex (one triangle there).
    Wrap in ``two_sided`` for blades seen from both sides.
    """
    p = np.asarray(paths, dtype=np.float64)
    n, m, _ = p.shape
    h = np.broadcast_to(np.asarray(half_widths, dtype=np.float64), (n, m))
    s = np.asarray(sides, dtype=np.float64)
    s = np.broadcast_to(s[:, None, :] if s.ndim == 2 else s, (n, m, 3))
    pointed = bool(np.all(h[:, -1] == 0.0))
    body = m - 1 if pointed else m  # rings with a left/right pair
    left = p[:, :body] - h[:, :body, None] * s[:, :body]
    right = p[:, :body] + h[:, :body, None] * s[:, :body]
    lr = np.stack([left, right], 2).reshape(n, 2 * body, 3)  # L_k = 2k, R_k = 2k+1
    k = np.arange(body - 1)
    a, b, c, d = 2 * k, 2 * k + 1, 2 * k + 3, 2 * k + 2
    f_one = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    if pointed:
        verts = np.concatenate([lr, p[:, -1:]], axis=1)
        tip = np.array([[2 * (body - 1), 2 * (body - 1) + 1, 2 * body]])
        f_one = np.concatenate([f_one, tip])
    else:
        verts = lr
    per = verts.shape[1]
    faces = f_one[None] + (np.arange(n, dtype=np.int64) * per)[:, None, None]
    return _mesh(verts, faces)


def two_sided(mesh: Mesh) -> Mesh:
    """Duplicate every triangle with reversed winding on its own copy of the vertices
    (so vertex normals of the two sides point opposite ways): visible from both sides
    under back-face culling. Doubles the triangle count."""
    v, f = _mesh(*mesh)
    nf, nv = len(f), len(v)
    if 2 * nv >= 2**32:
        raise ValueError("mesh too large for uint32 indices")
    faces = np.empty((2 * nf, 3), dtype=np.uint32)
    faces[:nf] = f
    faces[nf:, 0] = f[:, 0] + np.uint32(nv)
    faces[nf:, 1] = f[:, 2] + np.uint32(nv)
    faces[nf:, 2] = f[:, 1] + np.uint32(nv)
    return np.concatenate([v, v]), faces


# --- objects and detail scaling ---------------------------------------------------------------


def fast_vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals like ``scenes.model.vertex_normals`` (isolated
    vertices get +Y), accumulated with one sparse vertex × face incidence product —
    fast for millions of faces."""
    v = np.asarray(vertices, dtype=np.float32)
    f = np.asarray(faces).astype(np.intp, copy=False)
    nv, nf = len(v), len(f)
    a = v[f[:, 0]]
    e1 = v[f[:, 1]] - a
    e2 = v[f[:, 2]] - a
    fn = np.empty((nf, 3), dtype=np.float32)  # |fn| = 2 · area
    fn[:, 0] = e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1]
    fn[:, 1] = e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2]
    fn[:, 2] = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    # vertex × face incidence in CSC form: column j holds face j's three vertices (no sorting needed)
    incidence = sparse.csc_matrix((np.ones(3 * nf, dtype=np.float32), f.ravel(), np.arange(0, 3 * nf + 1, 3)),
                                  shape=(nv, nf))
    n = np.asarray(incidence @ fn, dtype=np.float32)
    length = np.sqrt(np.einsum("ij,ij->i", n, n))
    isolated = length <= 1e-30
    length[isolated] = 1.0
    n /= length[:, None]
    n[isolated] = (0.0, 1.0, 0.0)
    return n


def make_object(name: str, mesh: Mesh, material: Material, double_sided: bool = False) -> SceneObject:
    """SceneObject with fast area-weighted vertex normals. With ``double_sided`` the
    single-sided ``mesh`` is doubled as by ``two_sided`` (the back copy's normals are
    the negated front normals, computed once)."""
    v, f = mesh
    n = fast_vertex_normals(v, f)
    if double_sided:
        v, f = two_sided(mesh)
        n = np.concatenate([n, -n])
    return SceneObject(name=name, vertices=v, faces=f, normals=n, material=material)


def scaled_count(base: float, detail: float, minimum: int = 1) -> int:
    """Instance count proportional to detail: max(minimum, round(base · detail))."""
    return max(int(minimum), int(round(base * detail)))


def scaled_res(base: float, detail: float, minimum: int = 1) -> int:
    """Tessellation resolution along one direction of a surface, ∝ √detail, so that
    the surface's triangle count is ∝ detail: max(minimum, round(base · √detail))."""
    return max(int(minimum), int(round(base * math.sqrt(detail))))


# --- profiles and lights -------------------------------------------------------------------------


def smooth_curve(control: np.ndarray, n: int) -> np.ndarray:
    """n points on the uniform Catmull-Rom spline through control points (C,D), C ≥ 2;
    the first and last points are the first and last control points exactly."""
    c = np.asarray(control, dtype=np.float64)
    m = len(c)
    ext = np.concatenate([2 * c[:1] - c[1:2], c, 2 * c[-1:] - c[-2:-1]])
    t = np.linspace(0.0, m - 1.0, int(n))
    seg = np.minimum(t.astype(np.int64), m - 2)
    s = (t - seg)[:, None]
    p0, p1, p2, p3 = ext[seg], ext[seg + 1], ext[seg + 2], ext[seg + 3]
    out = 0.5 * ((2 * p1) + (-p0 + p2) * s + (2 * p0 - 5 * p1 + 4 * p2 - p3) * s**2
                 + (-p0 + 3 * p1 - 3 * p2 + p3) * s**3)
    out[0], out[-1] = c[0], c[-1]
    return out


def solid_profile(control: np.ndarray, n: int) -> np.ndarray:
    """Lathe profile (n,2) of a closed solid of revolution from pole to pole: a smooth
    curve through control points (r, y) whose first and last r are forced to 0 and
    whose interior radii stay positive; spline overshoot is clipped to the control
    points' height range (a solid standing on y = 0 does not dip below it)."""
    c = np.asarray(control, dtype=np.float64)
    p = smooth_curve(c, n)
    p[:, 1] = np.clip(p[:, 1], c[:, 1].min(), c[:, 1].max())
    p[1:-1, 0] = np.maximum(p[1:-1, 0], 1e-4)
    p[0, 0] = p[-1, 0] = 0.0
    return p


def vessel_profile(outer: np.ndarray, thickness: float, n: int) -> np.ndarray:
    """Lathe profile of a hollow vessel (vase, bowl, basin, tub) with wall ``thickness``.

    outer (C,2): control points (r, y) of the outside from the bottom pole (r = 0) up
    to the lip, counter-clockwise around the wall (bottom first). The profile is the
    smooth outside (≈ n/2 points), a half-circle lip and the inside (the outside offset
    inward by ``thickness``) back down to the inner bottom pole: a closed, watertight
    solid after ``lathe``. About n points in all.
    """
    n_side = max(3, (int(n) - 4) // 2)
    c = np.asarray(outer, dtype=np.float64)
    o = smooth_curve(c, n_side)
    o[0, 0] = 0.0
    o[:, 1] = np.maximum(o[:, 1], c[0, 1])  # no spline overshoot below the base
    tan = np.gradient(o, axis=0)
    tan /= np.maximum(np.linalg.norm(tan, axis=1, keepdims=True), 1e-12)
    left = np.stack([-tan[:, 1], tan[:, 0]], 1)  # into the wall (interior on the left)
    inner = o + thickness * left
    inner[0] = (0.0, o[0, 1] + thickness)
    c = (o[-1] + inner[-1]) / 2
    a0 = math.atan2(o[-1, 1] - c[1], o[-1, 0] - c[0])
    ang = a0 + np.pi * np.arange(1, 4) / 4
    lip = c + thickness / 2 * np.stack([np.cos(ang), np.sin(ang)], 1)
    prof = np.concatenate([o, lip, inner[::-1]])
    prof[1:-1, 0] = np.maximum(prof[1:-1, 0], 1e-4)
    return prof


def overhead_area_light(lo: Sequence[float], hi: Sequence[float], fraction: float = 0.25,
                        height: float | None = None) -> AreaLight:
    """Square area light facing down (u × v = −Y), centred above the box [lo, hi]:
    edge = ``fraction`` × the larger horizontal extent (thesis §3.3 sizes lights
    relative to the scene), at ``height`` (default: top + half the horizontal extent)."""
    lo_, hi_ = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    ext = float(max(hi_[0] - lo_[0], hi_[2] - lo_[2]))
    size = fraction * ext
    y = float(hi_[1] + 0.5 * ext) if height is None else float(height)
    return AreaLight(center=(float((lo_[0] + hi_[0]) / 2), y, float((lo_[2] + hi_[2]) / 2)),
                     u=(size, 0.0, 0.0), v=(0.0, 0.0, size))


def scene_bounds(meshes: Sequence[Mesh]) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounds (lo, hi) float64 of non-empty meshes."""
    v = np.concatenate([m[0] for m in meshes if len(m[0])])
    return v.min(0).astype(np.float64), v.max(0).astype(np.float64)


def resample_polyline(points: np.ndarray, n: int, closed: bool = False) -> np.ndarray:
    """About n points along a polyline (closed: a polygon) keeping every corner: each
    edge gets a share of the points proportional to its length (at least one)."""
    p = np.asarray(points, dtype=np.float64)
    q = np.concatenate([p, p[:1]]) if closed else p
    seg = np.linalg.norm(np.diff(q, axis=0), axis=1)
    k = np.maximum(1, np.round(seg / seg.sum() * max(int(n), len(seg))).astype(np.int64))
    parts = [q[i] + (q[i + 1] - q[i]) * (np.arange(k[i]) / k[i])[:, None] for i in range(len(seg))]
    if not closed:
        parts.append(q[-1:])
    return np.concatenate(parts)


# --- rooms -----------------------------------------------------------------------------------------

#: side name -> (origin corner selector (0 = lo, 1 = hi) per axis, u axis, v axis); u × v points into the room
_ROOM_SIDES = {
    "floor": ((0, 0, 0), 2, 0),
    "ceiling": ((0, 1, 0), 0, 2),
    "back": ((0, 0, 0), 0, 1),
    "front": ((0, 0, 1), 1, 0),
    "left": ((0, 0, 0), 1, 2),
    "right": ((1, 0, 0), 2, 1),
}


def _room_res(lo: np.ndarray, hi: np.ndarray, side: str, cell: float) -> tuple[int, int]:
    _, ua, va = _ROOM_SIDES[side]
    return max(1, int(round((hi[ua] - lo[ua]) / cell))), max(1, int(round((hi[va] - lo[va]) / cell)))


def room_walls(lo: Sequence[float], hi: Sequence[float], cell: float, sides: Sequence[str]) -> dict[str, Mesh]:
    """Inward-facing grids (cells ≈ ``cell`` metres) on the named sides of the box
    [lo, hi]: "floor" (y = lo), "ceiling", "back" (z = lo), "front" (z = hi), "left"
    (x = lo), "right" (x = hi). Seen from inside the room every side is front-facing;
    from outside it is culled, so a camera outside sees in (a "doll's house")."""
    lo_, hi_ = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    out: dict[str, Mesh] = {}
    for side in sides:
        corner, ua, va = _ROOM_SIDES[side]
        origin = np.where(np.asarray(corner) == 1, hi_, lo_)
        u, v = np.zeros(3), np.zeros(3)
        u[ua], v[va] = hi_[ua] - lo_[ua], hi_[va] - lo_[va]
        out[side] = grid(origin, u, v, *_room_res(lo_, hi_, side, cell))
    return out


def room_wall_triangles(lo: Sequence[float], hi: Sequence[float], cell: float, sides: Sequence[str]) -> int:
    lo_, hi_ = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    return sum(grid_triangles(*_room_res(lo_, hi_, s, cell)) for s in sides)

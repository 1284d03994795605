"""Reconstruction of depth images (thesis Ch. 3, §3.2, Alg. 4): the hybrid mesh is
watertight on continuous surfaces, covers exactly the sampled pixels, keeps
isolated samples as one quad, takes its corners as Fig. 17 shows, and NR meshes
do not cover a surface twice; the grid baseline and the compact mesh beside it."""

from __future__ import annotations

import io
from collections import Counter
from dataclasses import replace

import numpy as np
import pytest
import trimesh

from gl_passes import mesh_gpu
from gl_passes.mesh_gpu import pack_vertices
from gl_passes.reconstruction import (
    ReconstructionSettings,
    Reconstructor,
    canonical_order,
    export_glb,
    fetch_order,
    image_space,
    keep_pieces,
    mesh_arrays,
    offset_camera,
    reconstruct_set,
    render_set,
    simplify,
)
from gl_passes.upload import SceneGPU
from reference.raycast import RayCaster
from scenes import Camera, Material, Scene, SceneObject
from scenes.builtin.geometry import make_object, uv_sphere
from scenes.depth_image import DepthImage
from tests.gl_leaks import gl_object_growth
from tests.helpers import box, figure11_scene, triangle_rows

HYBRID = ReconstructionSettings()
W, H = 40, 30
EYE = np.array([0.0, 0.0, 5.0])
FRONT = Camera(tuple(EYE), (0.0, 0.0, 0.0), fov=40.0, width=W, height=H, near=1.0, far=20.0)


def pixel_point(u: float, v: float, depth: float, cam: Camera = FRONT) -> np.ndarray:
    """World point at continuous pixel coordinate (u, v) (row 0 = top) and eye depth."""
    r, up, f = cam.basis()
    t = np.tan(np.radians(cam.fov) / 2)
    x, y = (2 * u / cam.width - 1) * t * cam.aspect, (1 - 2 * v / cam.height) * t
    return np.asarray(cam.eye) + depth * (f + x * r + y * up)


def screen_rects(rects: list[tuple[float, float, float, float]], depth: float, name: str = "rects") -> SceneObject:
    """Rectangles [u0,u1]×[v0,v1] in FRONT's pixel coordinates, on the plane at
    eye depth `depth`, facing the camera."""
    verts, faces = [], []
    for u0, u1, v0, v1 in rects:
        b = len(verts)
        verts += [pixel_point(u, v, depth) for u, v in ((u0, v1), (u1, v1), (u1, v0), (u0, v0))]
        faces += [[b, b + 1, b + 2], [b, b + 2, b + 3]]
    return SceneObject(name, np.array(verts), np.array(faces), material=Material((0.5, 0.6, 0.7)))


def reconstruct(gl, scene: Scene, cams: list[Camera], method: str = "conventional",
                settings: ReconstructionSettings = HYBRID):
    with SceneGPU(gl, scene) as sg:
        ss = render_set(gl, sg, method, cams)
    meshes = reconstruct_set(gl, ss, settings)
    try:
        return ss, [mesh_arrays(m) for m in meshes]
    finally:
        for m in meshes:
            m.release()


def edge_counts(tri: np.ndarray) -> Counter:
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    e.sort(axis=1)
    return Counter(map(tuple, e))


def perimeter(mask: np.ndarray) -> int:
    """Pixel edges between a sampled pixel and an unsampled one (or the border)."""
    m = np.pad(mask, 1)
    return int((m[1:, :] != m[:-1, :]).sum() + (m[:, 1:] != m[:, :-1]).sum())


def quad_pixels(pos: np.ndarray, tri: np.ndarray, cam: Camera) -> np.ndarray:
    """(n_quads, 2) pixel (x, y) covered by each quad (triangles 2q, 2q+1) seen from cam."""
    px, _ = cam.project(pos[tri[0::2]].reshape(-1, 3).astype(np.float64))
    return np.floor(px.reshape(-1, 3, 2).mean(axis=1)).astype(int)


# --- offset image --------------------------------------------------------------------

def test_offset_camera_centres_are_pixel_corners():
    off = offset_camera(FRONT)
    assert (off.width, off.height) == (W + 1, H + 1)
    corners = np.array([pixel_point(u, v, 3.0) for u, v in ((0, 0), (W, 0), (7, 11), (W, H))])
    px, _ = off.project(corners)  # I's corner (u, v) is H's pixel centre (u + 0.5, v + 0.5)
    np.testing.assert_allclose(px, [[0.5, 0.5], [W + 0.5, 0.5], [7.5, 11.5], [W + 0.5, H + 0.5]], atol=1e-9)


# --- watertight, covering, exact on planes -----------------------------------------------

def test_hybrid_plane_is_watertight_and_covers_the_samples(gl):
    # A tilted plane (not facing the camera) over part of the image.
    plane = SceneObject("plane", np.array([[-3, -1.2, -4], [3, -1.2, -4], [3, 1.0, 1], [-3, 1.0, 1]], float),
                        np.array([[0, 1, 2], [0, 2, 3]]), material=Material((0.6, 0.6, 0.6)))
    ss, [(pos, tri)] = reconstruct(gl, Scene([plane]), [FRONT])
    img = ss.images[0]
    assert 0 < img.n_samples < W * H and len(tri) == 2 * img.n_samples
    counts = edge_counts(tri)
    assert max(counts.values()) == 2
    assert sum(1 for c in counts.values() if c == 1) == perimeter(img.mask)
    n = np.cross([6, 0, 0], [0, 2.2, 5.0])
    assert np.abs((pos - [-3, -1.2, -4]) @ (n / np.linalg.norm(n))).max() < 1e-5
    pix = quad_pixels(pos, tri, FRONT)
    assert len(np.unique(pix, axis=0)) == len(pix)  # one quad per pixel, no overlap
    assert img.mask[pix[:, 1], pix[:, 0]].all()
    px = FRONT.project(pos.astype(np.float64))[0]
    assert np.abs(px - np.rint(px)).max() < 1e-3  # every corner on a pixel corner: each quad spans its pixel
    a, b, c = (px[tri[:, k]] for k in range(3))
    u, v = b - a, c - a
    area = 0.5 * np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]).sum()
    assert area == pytest.approx(img.n_samples, abs=1e-2)  # square pixels, covered once


def assert_watertight(pos: np.ndarray, tri: np.ndarray, img, cam: Camera) -> None:
    """Every edge used at most twice, the once-used ones exactly the outline of the
    sampled pixels, one quad on each sampled pixel."""
    counts = edge_counts(tri)
    assert len(tri) == 2 * img.n_samples and max(counts.values()) == 2
    assert sum(1 for c in counts.values() if c == 1) == perimeter(img.mask)
    pix = quad_pixels(pos, tri, cam)
    assert len(np.unique(pix, axis=0)) == len(pix) == img.n_samples and img.mask[pix[:, 1], pix[:, 0]].all()


def test_hybrid_sphere_is_watertight(gl):
    """Alg. 4's shared H corners and the joined tangent-plane corners (where H misses
    the sphere past its outline) make the sphere's mesh watertight: its once-used
    edges exactly the outline of the sampled pixels, one quad on each, at the
    defaults and without the depth gate alike. With the depth gate alone (no
    smooth-surface rule) a neighbour of another triangle joins a corner only within 2 ·
    max_corner_extent footprints per half pixel of the sample's depth, so where the
    sphere turns grazing corners split into two vertices on one camera ray (measured:
    56 corners, at most 2.42 footprints apart), all on the rim (pixels within one
    pixel of an unsampled one); every other edge is shared by exactly two triangles."""
    sphere = make_object("sphere", uv_sphere((0, 0, 0), 1.2, 32, 64), Material((0.8, 0.2, 0.2)))
    cam = FRONT.with_size(64, 64)
    for settings in (replace(HYBRID, depth_gate=False), HYBRID):  # the defaults last: checked further below
        ss, [(pos, tri)] = reconstruct(gl, Scene([sphere]), [cam], settings=settings)
        assert ss.images[0].n_samples > 1400  # measured 1484
        assert_watertight(pos, tri, ss.images[0], cam)
    # Every vertex is close to the sphere (corners off the rim are H's samples on it).
    pad = np.pad(ss.images[0].mask, 1)
    rim = np.zeros_like(ss.images[0].mask)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            rim |= ~pad[1 + dy:1 + dy + 64, 1 + dx:1 + dx + 64]
    assert (~rim & ss.images[0].mask).sum() > 1000  # a real interior
    pix = quad_pixels(pos, tri, cam)
    interior_vertices = np.unique(tri[np.repeat(~rim[pix[:, 1], pix[:, 0]], 2)])
    np.testing.assert_allclose(np.linalg.norm(pos[interior_vertices], axis=1), 1.2, atol=5e-3)
    assert np.linalg.norm(pos[np.unique(tri)], axis=1).max() < 1.4

    ss, [(pos, tri)] = reconstruct(gl, Scene([sphere]), [cam], settings=replace(HYBRID, smooth_surfaces=False))
    img = ss.images[0]
    assert len(tri) == 2 * img.n_samples
    counts = edge_counts(tri)
    assert max(counts.values()) == 2
    once = np.array([e for e, c in counts.items() if c == 1])
    assert len(once) > perimeter(img.mask)  # not watertight
    near = np.floor(cam.project(pos[once].mean(axis=1).astype(np.float64))[0]).astype(int).clip(0, 63)
    assert rim[near[:, 1], near[:, 0]].all()
    # the split corners: two vertices at one pixel corner (one camera ray), apart in depth
    px, z = cam.project(pos.astype(np.float64))
    used = np.unique(tri)
    at, corner, n_at = np.unique(np.round(px[used], 3), axis=0, return_inverse=True, return_counts=True)
    corner = corner.ravel()
    assert n_at.max() <= 2 and 0 < (n_at == 2).sum() <= 64
    rim_around = np.pad(rim, 1, constant_values=True)  # pixel corner (x, y) touches rows y..y+1, columns x..x+1
    for c in np.flatnonzero(n_at == 2):
        depths = z[used[corner == c]]
        assert np.ptp(depths) <= 3 * cam.pixel_footprint * depths.mean()  # footprints (measured ≤ 2.42)
        x, y = np.rint(at[c]).astype(int)
        assert rim_around[y:y + 2, x:x + 2].any()  # a corner of a rim pixel


def test_isolated_sample_gives_exactly_one_quad(gl):
    # A patch smaller than a pixel, around pixel (10, 12)'s centre: H sees none of it.
    patch = screen_rects([(10.3, 10.7, 12.3, 12.7)], 4.0)
    ss, [(pos, tri)] = reconstruct(gl, Scene([patch]), [FRONT])
    assert ss.images[0].n_samples == 1 and ss.offsets[0].n_samples == 0
    assert len(tri) == 2 and len(np.unique(tri)) == 4
    assert quad_pixels(pos, tri, FRONT).tolist() == [[10, 12]]
    px, depth = FRONT.project(pos.astype(np.float64))
    np.testing.assert_allclose(np.sort(px[:, 0]), [10, 10, 11, 11], atol=1e-3)  # the whole pixel
    np.testing.assert_allclose(np.sort(px[:, 1]), [12, 12, 13, 13], atol=1e-3)
    np.testing.assert_allclose(depth, 4.0 * FRONT.basis()[2] @ [0, 0, -1], rtol=1e-5)
    grid = ReconstructionSettings(kind="grid")
    _, [(_, gtri)] = reconstruct(gl, Scene([patch]), [FRONT], settings=grid)
    assert len(gtri) == 0  # the grid baseline drops it


def test_offset_quads_give_an_untaken_offset_sample_a_quad_of_its_own(gl):
    # A patch around pixel corner (10, 12): no pixel centre sees it, H's sample there does.
    patch = screen_rects([(9.8, 10.2, 11.8, 12.2)], 4.0)
    ss, [(_, tri)] = reconstruct(gl, Scene([patch]), [FRONT])
    assert ss.images[0].n_samples == 0 and ss.offsets[0].n_samples == 1 and len(tri) == 0
    _, [(pos, tri)] = reconstruct(gl, Scene([patch]), [FRONT], settings=replace(HYBRID, offset_quads=0.25))
    assert len(tri) == 2 and len(np.unique(tri)) == 4
    px, depth = FRONT.project(pos.astype(np.float64))
    np.testing.assert_allclose(np.sort(px[:, 0]), [9.75, 9.75, 10.25, 10.25], atol=1e-3)
    np.testing.assert_allclose(np.sort(px[:, 1]), [11.75, 11.75, 12.25, 12.25], atol=1e-3)
    np.testing.assert_allclose(depth, 4.0 * FRONT.basis()[2] @ [0, 0, -1], rtol=1e-5)
    with pytest.raises(ValueError, match="offset_quads"):
        ReconstructionSettings(offset_quads=0.75)


def test_fig17_corner_cases(gl):
    """S_0: all four corners from H (shared); S_2: one corner missing (tangent
    plane); S_5: isolated (four tangent-plane corners). An L-shaped patch: pixel
    centres x, y ∈ {2.5, 3.5, 4.5} minus (4.5, 2.5); lattice corners 2..5 minus
    (5, 2) and (5, 3); plus an isolated sample at pixel (20, 20) on a nearer plane."""
    l_shape = screen_rects([(1.6, 4.2, 1.6, 5.4), (4.2, 5.4, 3.2, 5.4)], 4.0, "L")
    lone = screen_rects([(20.3, 20.7, 20.3, 20.7)], 3.0, "lone")
    ss, [(pos, tri)] = reconstruct(gl, Scene([l_shape, lone]), [FRONT])
    assert ss.images[0].n_samples == 9
    quads = {tuple(p): tri[2 * q:2 * q + 2] for q, p in enumerate(quad_pixels(pos, tri, FRONT))}
    assert set(quads) == {(x, y) for x in (2, 3, 4) for y in (2, 3, 4)} - {(4, 2)} | {(20, 20)}
    refs = Counter(tri.ravel().tolist())

    def shared(q: tuple[int, int]) -> int:  # corners used by more than this quad's 2 triangles
        v = np.unique(quads[q])
        return int(sum(refs[i] > sum(int(i in t) for t in quads[q]) for i in v))

    assert shared((3, 3)) == 4  # S_0: its four corners are shared with neighbours
    # (4, 3): corners (4,3) (5,3) (5,4) (4,4); (5,3) lies outside the L → one tangent-plane corner.
    v43 = np.unique(quads[(4, 3)])
    assert len(v43) == 4 and shared((4, 3)) == 3
    assert shared((20, 20)) == 0 and len(np.unique(quads[(20, 20)])) == 4  # S_5
    # 8 L pixels' shared lattice corners (16 − 2 outside) + 1 private + 4 isolated.
    assert len(np.unique(tri)) == 14 + 1 + 4
    # Where the corners are: the L's on the lattice corners 2..5 at its depth, (4, 3)'s private
    # one at (5, 3) on its tangent plane (the L's plane), the isolated quad spanning pixel (20, 20).
    px, depth = FRONT.project(pos.astype(np.float64))
    assert np.abs(px - np.rint(px)).max() < 1e-3
    at = {tuple(np.rint(p).astype(int)): d for p, d in zip(px, depth, strict=True)}
    l_corners = {(x, y) for x in range(2, 6) for y in range(2, 6)} - {(5, 2)}
    assert set(at) == l_corners | {(x, y) for x in (20, 21) for y in (20, 21)}
    for (x, _), d in at.items():
        assert d == pytest.approx((3.0 if x >= 20 else 4.0) * FRONT.basis()[2] @ [0, 0, -1], rel=1e-5)
    private = [i for i in np.unique(quads[(4, 3)]) if refs[i] == sum(int(i in t) for t in quads[(4, 3)])]
    assert [tuple(np.rint(px[i]).astype(int)) for i in private] == [(5, 3)]


def grazing_sliver(depth: float = 4.0, turn_deg: float = 85.0) -> tuple[SceneObject, float, float]:
    """A sliver through pixel (10, 12)'s centre ray at `depth`, turned `turn_deg`
    away from facing FRONT about the image's up axis (±0.3 px wide, ±0.2 px high on
    screen, so H sees none of it); returns it, the pixel footprint at `depth` and the
    eye depth where its plane meets the corner rays on its far side."""
    r, up, f = FRONT.basis()
    p = pixel_point(10.5, 12.5, depth)
    d = p - EYE
    foot = depth * 2 * np.tan(np.radians(FRONT.fov) / 2) / H  # world size of a pixel at `depth`
    off = np.radians(90.0 - turn_deg)
    t = np.cos(off) * d / np.linalg.norm(d) + np.sin(off) * r
    a = 0.3 * foot / np.sin(off)
    b = 0.2 * foot
    verts = np.array([p - a * t - b * up, p + a * t - b * up, p + a * t + b * up, p - a * t + b * up])
    n = np.cross(verts[1] - verts[0], verts[2] - verts[0])
    faces = [[0, 1, 2], [0, 2, 3]] if n @ (EYE - p) > 0 else [[0, 2, 1], [0, 3, 2]]
    n = n / np.linalg.norm(n)
    far = 0.0
    for u in (10.0, 11.0):  # the corner rays left and right of the pixel: z·(n·d) = n·(p − eye)
        dir_ = pixel_point(u, 12.0, 1.0) - EYE
        far = max(far, float((n @ (p - EYE)) / (n @ dir_)) * float(dir_ @ f))
    return SceneObject("sliver", verts, np.array(faces), material=Material((0.5, 0.5, 0.5))), foot, far


def test_grazing_isolated_sample_corners_are_clamped(gl):
    # The sliver's tangent plane meets the corner rays (±0.5 px aside) about
    # 0.5/tan 5° ≈ 5.7 footprints in front of / behind the sample: the default clamp
    # (2 footprints) holds them at ±2; with max_corner_extent = 8 they stay on the plane.
    sliver, foot, _ = grazing_sliver()
    spread = {}
    for extent in (None, 8.0):
        settings = HYBRID if extent is None else ReconstructionSettings(max_corner_extent=extent)
        ss, [(pos, tri)] = reconstruct(gl, Scene([sliver]), [FRONT], settings=settings)
        assert ss.images[0].n_samples == 1 and ss.offsets[0].n_samples == 0
        assert quad_pixels(pos, tri, FRONT).tolist() == [[10, 12]]
        _, z = FRONT.project(pos[np.unique(tri)].astype(np.float64))
        spread[extent] = np.abs(z - 4.0) / foot  # the sample's eye depth is 4
    assert HYBRID.max_corner_extent == 2.0
    np.testing.assert_allclose(spread[None], 2.0, rtol=1e-3)  # all four corners clamped at ±2 footprints
    assert 4.5 < spread[8.0].min() and spread[8.0].max() < 7.0  # on the tangent plane, ≈ 5.7


def test_depth_gate_keeps_a_far_surface_out_of_a_grazing_samples_corners(gl):
    """Behind the grazing sliver, a wall facing the camera at the depth where the
    sliver's plane meets its far corner rays (≈ 5.7 footprints behind the sample):
    H's samples there lie on the sliver's tangent plane. Without the depth gate the
    sliver's quad takes those two corners from H, 5.7 footprints deep (a fin along
    the view ray); with it (the default) all four are clamped tangent-plane corners."""
    sliver, foot, far = grazing_sliver()
    assert 5.0 < (far - 4.0) / foot < 6.5
    wall = screen_rects([(0.0, W, 0.0, H)], far, "wall")
    spread = {}
    for gate in (True, False):
        ss, [(pos, tri)] = reconstruct(gl, Scene([sliver, wall]), [FRONT],
                                       settings=ReconstructionSettings(depth_gate=gate))
        assert ss.images[0].tri_id[12, 10] in (1, 2)  # the sliver's sample (object 0's faces)
        quad = tri[2 * int(np.flatnonzero((quad_pixels(pos, tri, FRONT) == [10, 12]).all(axis=1))[0]):][:2]
        _, z = FRONT.project(pos[np.unique(quad)].astype(np.float64))
        spread[gate] = np.sort((z - 4.0) / foot)
    assert HYBRID.depth_gate
    np.testing.assert_allclose(spread[True], [-2, -2, 2, 2], rtol=1e-3)
    np.testing.assert_allclose(spread[False][:2], [-2, -2], rtol=1e-3)
    np.testing.assert_allclose(spread[False][2:], (far - 4.0) / foot, rtol=1e-3)  # H's wall samples


def test_joined_tangent_corners_make_a_subpixel_strip_one_connected_strip(gl):
    """A strip 0.4 px high through the centres of pixels 5..14 of row 12: H's corners
    (rows 12 and 13 of the lattice) miss it, so every corner is a tangent-plane
    corner. Joined (the default), neighbours share theirs: 11 + 11 vertices, the 9
    inner edges used twice, the outline once; the compact mesh is then 2 triangles.
    Not joined (Alg. 4 as printed): 10 separate quads, 40 vertices."""
    strip = screen_rects([(5.2, 14.8, 12.3, 12.7)], 4.0, "strip")
    ss, [(pos, tri)] = reconstruct(gl, Scene([strip]), [FRONT])
    assert ss.images[0].n_samples == 10 and ss.offsets[0].n_samples == 0
    assert len(tri) == 20 and len(np.unique(tri)) == 22
    counts = edge_counts(tri)
    assert max(counts.values()) == 2 and sum(1 for c in counts.values() if c == 1) == perimeter(ss.images[0].mask)
    assert sorted(map(tuple, quad_pixels(pos, tri, FRONT).tolist())) == [(x, 12) for x in range(5, 15)]
    np.testing.assert_allclose(FRONT.project(pos.astype(np.float64))[1], 4.0, rtol=1e-5)  # on the plane
    _, [(_, sep)] = reconstruct(gl, Scene([strip]), [FRONT], settings=ReconstructionSettings(join_corners=False))
    assert len(sep) == 20 and len(np.unique(sep)) == 40
    _, [(_, ctri)] = reconstruct(gl, Scene([strip]), [FRONT], settings=ReconstructionSettings(kind="compact"))
    assert len(ctri) == 2


def test_evidence_pulls_a_later_images_fringe_to_the_expected_edge(gl):
    """The 1-D case of the evidence rule, by hand. A plane facing two parallel
    cameras at eye depth 4 holds a band whose right edge lies at u = 9.3 in I_0's
    pixel coordinates (spanning the image's height). I_0 (FRONT) samples centres up to
    8.5 and misses 9.5: its quads end at u = 9. I_1 is FRONT moved right by 0.7
    footprints, so its centres sit at u = k + 1.2: the one at 9.2 lands in I_0's
    missed texel 9, so NR image I_1 keeps that column and nothing else. Alg. 4 gives
    it the whole pixel, [8.7, 9.7]; with evidence, the outer corners (seen past by
    I_0's centre ray at 9.5) go to the middle of the sample and that ray, (9.2 +
    9.5) / 2 = 9.35, the inner ones (held by I_0) stay at 8.7: the union's edge errs
    by 0.05 px instead of 0.4 (evidence_pull = 1/2: half the move, 9.525). I_0, with
    no earlier image, is unchanged."""
    foot = 4.0 * 2 * np.tan(np.radians(FRONT.fov) / 2) / H
    shift = 0.7 * foot * FRONT.basis()[0]
    cam1 = replace(FRONT, eye=tuple(EYE + shift), target=tuple(np.asarray(FRONT.target) + shift))
    # one triangle (Alg. 3 compares triangle ids: no inner edge), its right edge at u = 9.3
    verts = np.array([pixel_point(u, v, 4.0) for u, v in ((9.3, 3.0 * H), (9.3, -2.0 * H), (-4.0 * W, 0.5 * H))])
    band = SceneObject("band", verts, np.array([[0, 1, 2]]), material=Material((0.5, 0.6, 0.7)))
    edges = {}
    for key, settings in (("evidence", HYBRID), ("off", replace(HYBRID, evidence=False)),
                          ("half pull", replace(HYBRID, evidence_pull=0.5))):
        ss, meshes = reconstruct(gl, Scene([band]), [FRONT, cam1], "non_redundant", settings)
        assert ss.images[1].n_samples == H and ss.images[1].mask[:, 8].all()  # one column, u = 9.2 in I_0
        pos, tri = meshes[1]
        uv = FRONT.project(pos[np.unique(tri)].astype(np.float64))[0]
        inner = (uv[:, 1] > 0.5) & (uv[:, 1] < H - 0.5)  # corners on the image's border have half the neighbours
        edges[key] = np.unique(np.round(uv[inner, 0], 3))
        i0_u = FRONT.project(meshes[0][0].astype(np.float64))[0][:, 0]
        assert np.isclose(i0_u.max(), 9.0, atol=1e-3)
    np.testing.assert_allclose(edges["evidence"], [8.7, 9.35], atol=2e-3)
    np.testing.assert_allclose(edges["off"], [8.7, 9.7], atol=2e-3)
    np.testing.assert_allclose(edges["half pull"], [8.7, 9.525], atol=2e-3)  # half way from 9.7 to 9.35


def test_offset_evidence_pulls_a_corner_its_own_offset_ray_saw_past(gl):
    """The 1-D case of the offset-evidence diagnostic, by hand. A band at eye depth 4
    ends at u = 8.8 over a background at depth 8. Pixel column 8 (centre 8.5) is on
    the band; H's ray at the corners u = 9 hits the background, so those corners are
    tangent-plane corners at u = 9 (Alg. 4). With offset_evidence = 1 they move to the
    middle of the samples and themselves, u = 8.75 (the edge errs by 0.05 px instead
    of 0.2); with 0.5, half that move, 8.875. The background, whose corners H holds,
    keeps its own."""
    band = screen_rects([(-W, 8.8, -H, 2 * H)], 4.0, "band")
    back = screen_rects([(-W, 2 * W, -H, 2 * H)], 8.0, "back")
    edges = {}
    for share in (0.0, 0.5, 1.0):
        _, [(pos, tri)] = reconstruct(gl, Scene([band, back]), [FRONT],
                                      settings=replace(HYBRID, offset_evidence=share))
        uv, depth = FRONT.project(pos[np.unique(tri)].astype(np.float64))
        inner = (uv[:, 1] > 0.5) & (uv[:, 1] < H - 0.5)
        on_band = inner & (depth < 6.0)
        edges[share] = uv[on_band, 0].max()
        assert np.isclose(uv[inner & (depth > 6.0), 0].min(), 9.0, atol=1e-3)  # the background keeps its corners
    np.testing.assert_allclose([edges[0.0], edges[0.5], edges[1.0]], [9.0, 8.875, 8.75], atol=2e-3)
    with pytest.raises(ValueError, match="offset_evidence"):
        ReconstructionSettings(offset_evidence=1.5)


# --- NR: no surface covered twice -------------------------------------------------------

def ray_hits(meshes: list[tuple[np.ndarray, np.ndarray]], view: Camera) -> np.ndarray:
    """(meshes, pixels) distance along each of `view`'s pixel rays to each mesh's
    front faces (inf: a miss; an empty mesh misses every ray)."""
    d = view.pixel_directions().reshape(-1, 3)
    ts = []
    for pos, tri in meshes:
        if len(tri) == 0:
            ts.append(np.full(len(d), np.inf))
            continue
        obj = SceneObject("m", pos.astype(np.float64), tri.astype(np.int64), material=Material((1, 1, 1)))
        ts.append(RayCaster(Scene([obj])).cast_from(view.eye, d).t)  # front faces only
    return np.stack(ts)


def overdraw(meshes: list[tuple[np.ndarray, np.ndarray]], view: Camera) -> float:
    """Fraction of `view`'s rays hitting reconstruction surface whose nearest hit
    is matched (within 1e-3 relative depth) by a second mesh: surface covered twice."""
    t = ray_hits(meshes, view)
    near = t.min(axis=0)
    hit = np.isfinite(near)
    t, near = t[:, hit], near[hit]
    twice = (np.abs(t - near) <= 1e-3 * near).sum(axis=0) >= 2
    return float(twice.mean())


def test_nr_reconstruction_does_not_cover_a_surface_twice(gl):
    scene = figure11_scene()
    cams = [Camera((x, 0.0, 10.0), (0.0, 0.0, 0.0), fov=40.0, width=96, height=96) for x in (-2.0, 2.0)]
    mid = Camera((0.0, 0.0, 10.0), (0.0, 0.0, 0.0), fov=40.0, width=96, height=96)
    _, nr = reconstruct(gl, scene, cams, "non_redundant")
    _, conv = reconstruct(gl, scene, cams, "conventional")
    nr_twice, conv_twice = overdraw(nr, mid), overdraw(conv, mid)
    print(f"overdraw: NR {nr_twice:.4f}, conventional {conv_twice:.4f}")
    assert conv_twice > 0.3  # both conventional images hold A's and D's fronts
    assert nr_twice < 0.012  # only texel-granularity fringes (Alg. 3) overlap (measured 0.0089)
    # ...and NR drops no surface for it: both its images add some, and the middle view sees
    # the conventional set's surface through NR's but for fringes (measured 0.0001 of its rays)
    assert all(len(tri) > 0 for _, tri in nr)
    nr_hit, conv_hit = (np.isfinite(ray_hits(m, mid)).any(axis=0) for m in (nr, conv))
    assert conv_hit.mean() > 0.3 and (conv_hit & ~nr_hit).mean() < 0.001
    alone = np.isfinite(ray_hits(nr[:1], mid)[0])
    assert (conv_hit & ~alone).mean() > 0.01  # the second NR image holds surface the first lacks


# --- baselines, compact, export, leaks ----------------------------------------------

def test_grid_joins_neighbours_but_not_across_a_discontinuity(gl):
    near = screen_rects([(4.0, 12.0, 4.0, 12.0)], 3.0, "near")
    far = screen_rects([(12.0, 20.0, 4.0, 12.0)], 4.5, "far")  # touches `near` in screen space
    _, [(pos, tri)] = reconstruct(gl, Scene([near, far]), [FRONT], settings=ReconstructionSettings(kind="grid"))
    assert len(tri) == 2 * (7 * 7) * 2  # two 8×8 sample blocks, each 7×7 quads
    z = FRONT.project(pos[tri].reshape(-1, 3).astype(np.float64))[1].reshape(-1, 3)
    assert (np.ptp(z, axis=1) < 1e-4).all()  # no triangle spans the two planes


def test_compact_keeps_the_surface_within_its_bound(gl):
    sphere = make_object("sphere", uv_sphere((0, 0, 0), 1.2, 32, 64), Material((0.8, 0.2, 0.2)))
    floor = box("floor", (-4, -1.6, -4), (4, -1.4, 2))
    cam = Camera((0.5, 1.5, 5.0), (0, -0.5, 0), fov=45.0, width=96, height=96)
    scene = Scene([sphere, floor])
    _, [(hpos, htri)] = reconstruct(gl, scene, [cam])
    ss, [(cpos, ctri)] = reconstruct(gl, scene, [cam], settings=ReconstructionSettings(kind="compact"))
    assert len(ctri) < len(htri) / 4
    img = ss.images[0]
    e = ReconstructionSettings().compact_error  # pixels across the image, median footprints in depth
    f = cam.pixel_footprint  # per unit depth
    median = float(np.median(img.depth[img.mask]))
    # Every compact vertex is one of the hybrid mesh's vertices...
    assert np.isin(cpos.view("V12").ravel(), hpos.view("V12").ravel()).all()
    # ...the compact surface stays within the bound of the hybrid one along the camera's rays:
    # e in image_space's depth coordinate median/(f·d) is a depth error of e·f·d²/median at depth d...
    obj = SceneObject("c", cpos.astype(np.float64), ctri.astype(np.int64), material=Material((1, 1, 1)))
    hobj = SceneObject("h", hpos.astype(np.float64), htri.astype(np.int64), material=Material((1, 1, 1)))
    d = cam.pixel_directions().reshape(-1, 3)
    tc = RayCaster(Scene([obj])).intersect(np.broadcast_to(cam.eye, d.shape), d, cull_back_faces=False).t
    th = RayCaster(Scene([hobj])).intersect(np.broadcast_to(cam.eye, d.shape), d, cull_back_faces=False).t
    both = np.isfinite(tc) & np.isfinite(th)
    assert both.sum() > 0.9 * img.n_samples
    cos = np.abs(d[both] @ cam.basis()[2])
    depth = th[both] * cos
    err = np.abs(tc[both] - th[both]) * cos
    ratio = err / (e * f * depth**2 / median)  # along a ray: ≥ the normal distance the bound is on
    print(f"compact error / bound along the rays: q90 {np.quantile(ratio, 0.9):.2f}, "
          f"q99 {np.quantile(ratio, 0.99):.2f}, max {ratio.max():.2f}")
    # measured q90 1.02 (at grazing angles a ray's distance exceeds the normal one), q99 1.95, max 4.25
    assert np.quantile(ratio, 0.9) <= 1.2 and np.quantile(ratio, 0.99) <= 2.5 and ratio.max() <= 6
    # ...and its outline moves less than a pixel across the image: a pixel centre covered by one
    # mesh and not the other lies next to (8-neighbourhood) a change of the hybrid's coverage.
    hc, cc = (np.isfinite(t).reshape(cam.height, cam.width) for t in (th, tc))
    padded = np.pad(hc, 1, mode="edge")
    window = np.stack([padded[1 + dy:1 + dy + cam.height, 1 + dx:1 + dx + cam.width]
                       for dy in (-1, 0, 1) for dx in (-1, 0, 1)])
    near_outline = window.any(axis=0) & ~window.all(axis=0)
    flipped = hc != cc
    assert flipped.any() and not (flipped & ~near_outline).any()


def test_compact_keeps_every_piece_the_simplifier_would_drop(gl):
    """A hybrid mesh with strips 4 × 0.3 px (a blade seen edge-on, its outline pulled in
    by the evidence rule) beside a wall of whole-pixel quads: the simplifier alone
    collapses the strips to nothing (its bound is a quadric error); the compact mesh
    keeps them as they were and still simplifies the wall."""
    depth = 4.0
    strips = [(2 + 9 * k, 6 + 9 * k, 4.35, 4.65) for k in range(4)]
    wall = [(u, u + 1, v, v + 1) for u in range(4, 36) for v in range(14, 26)]
    verts, faces = [], []
    for u0, u1, v0, v1 in strips + wall:  # one quad each, corners shared within the wall
        b = len(verts)
        verts += [tuple(pixel_point(u, v, depth)) for u, v in ((u0, v1), (u1, v1), (u1, v0), (u0, v0))]
        faces += [[b, b + 1, b + 2], [b, b + 2, b + 3]]
    unique, inverse = np.unique(np.round(np.array(verts), 9), axis=0, return_inverse=True)
    tri = inverse.reshape(-1)[np.array(faces)].astype(np.uint32)
    records = pack_vertices(unique.astype(np.float32), np.full((len(unique), 3), 0.5))
    z = np.full((H, W), np.inf, np.float32)
    z[14:26, 4:36] = depth
    image = DepthImage(FRONT, np.zeros((H, W, 3), np.float32), z, np.zeros((H, W, 3), np.float32),
                       np.zeros((H, W, 3), np.float32), np.where(np.isfinite(z), 1, 0).astype(np.uint32))
    # the premise: the simplifier alone drops the strips whole
    alone = simplify(image_space(unique, FRONT, depth), tri, ReconstructionSettings().compact_error)
    assert not np.isin(alone, tri[:8]).any()
    r = Reconstructor(gl)
    hybrid = mesh_gpu.MeshGPU.from_records(gl, records, tri)
    try:
        compact = r.compact(hybrid, image, ReconstructionSettings(kind="compact"))
        pos, ctri = mesh_arrays(compact)
        compact.release()
    finally:
        hybrid.release()
        r.release()
    rows = FRONT.project(pos[ctri].reshape(-1, 3).astype(np.float64))[0][:, 1]
    assert np.isclose(rows, 4.35, atol=1e-3).sum() + np.isclose(rows, 4.65, atol=1e-3).sum() == 4 * 2 * 3
    assert len(ctri) < 8 + 2 * len(wall) / 8


def test_keep_pieces_puts_back_the_pieces_lost_whole():
    tri = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [7, 8, 9], [7, 9, 10]], np.uint32)  # pieces of 2, 1, 2
    simplified = np.array([[0, 1, 3]], np.uint32)  # the first piece simplified, the others gone
    assert keep_pieces(tri, simplified).tolist() == [[0, 1, 3], [4, 5, 6], [7, 8, 9], [7, 9, 10]]
    assert keep_pieces(tri, tri).tolist() == tri.tolist()
    assert keep_pieces(tri, np.zeros((0, 3), np.uint32)).tolist() == tri.tolist()
    assert keep_pieces(np.zeros((0, 3), np.uint32), np.zeros((0, 3), np.uint32)).shape == (0, 3)
    with pytest.raises(ValueError, match="no input triangle"):
        keep_pieces(tri, np.array([[11, 0, 1]], np.uint32))


def test_canonical_order_depends_on_the_mesh_alone():
    rng = np.random.default_rng(3)
    records = rng.random((40, 4)).astype(np.float32)
    records[1, :3] = records[0, :3]  # two vertices at one point (a pixel corner), colours apart
    records[3] = records[2]  # and two identical ones, each in triangles of its own
    tri = np.array([rng.choice(40, 3, replace=False) for _ in range(60)], np.uint32)
    tri[0], tri[1] = (2, 10, 11), (3, 12, 13)
    ref_rec, ref_tri = canonical_order(records, tri, FRONT)
    for _ in range(10):  # the same mesh: vertices shuffled, triangles shuffled and rotated
        perm = rng.permutation(40)
        inv = np.argsort(perm)
        shuffled = inv[tri][rng.permutation(60)]
        shuffled = np.take_along_axis(shuffled, (rng.integers(0, 3, 60)[:, None] + np.arange(3)) % 3, axis=1)
        rec, t = canonical_order(records[perm], shuffled.astype(np.uint32), FRONT)
        np.testing.assert_array_equal(rec, ref_rec)
        np.testing.assert_array_equal(t, ref_tri)

    def triangles(r: np.ndarray, f: np.ndarray) -> list:  # vertex records, rotated to the least (winding kept)
        out = []
        for x in f.astype(np.int64):
            v = [tuple(r[i]) for i in x]
            k = v.index(min(v))
            out.append(tuple(v[k:] + v[:k]))
        return sorted(out)
    assert triangles(rec, t) == triangles(records, tri)


def test_compact_reconstruction_is_the_same_every_run(gl):
    sphere = make_object("sphere", uv_sphere((0, 0, 0), 1.2, 16, 32), Material((0.8, 0.2, 0.2)))
    cam = Camera((0.5, 1.5, 5.0), (0, 0, 0), fov=45.0, width=64, height=64)
    runs = [reconstruct(gl, Scene([sphere]), [cam], settings=ReconstructionSettings(kind="compact"))[1][0]
            for _ in range(6)]
    for pos, tri in runs[1:]:
        np.testing.assert_array_equal(pos, runs[0][0])
        np.testing.assert_array_equal(tri, runs[0][1])


def test_fetch_order_puts_vertices_in_first_use_order_and_drops_unused():
    records = np.arange(20, dtype=np.float32).reshape(5, 4)  # vertex k = (4k, 4k+1, 4k+2, 4k+3)
    out, idx = fetch_order(records, np.array([[3, 1, 3], [4, 1, 3]], np.uint32))
    assert idx.tolist() == [0, 1, 0, 2, 1, 0]
    assert out[:, 0].tolist() == [12, 4, 16]  # vertices 3, 1, 4; 0 and 2 are unused


def test_fetch_order_leaves_the_mesh_unchanged(gl):
    """The same triangles in another order; for the compact mesh too, whose simplifier
    sees its input in canonical order (the compute passes append in a different order
    each run)."""
    sphere = make_object("sphere", uv_sphere((0, 0, 0), 1.2, 16, 32), Material((0.8, 0.2, 0.2)))
    cam = Camera((0.5, 1.5, 5.0), (0, 0, 0), fov=45.0, width=64, height=64)
    for kind in ("hybrid", "grid", "compact"):
        a, b = (triangle_rows(*reconstruct(gl, Scene([sphere]), [cam],
                                           settings=ReconstructionSettings(kind=kind, fetch_order=order))[1][0])
                for order in (True, False))
        assert len(a) > 100 and np.array_equal(a, b), kind


def test_glb_has_one_node_per_image_with_vertex_colours(gl):
    scene = figure11_scene()
    cams = [Camera((x, 0.0, 10.0), (0.0, 0.0, 0.0), fov=40.0, width=48, height=48) for x in (-2.0, 2.0)]
    with SceneGPU(gl, scene) as sg:
        ss = render_set(gl, sg, "non_redundant", cams)
    meshes = reconstruct_set(gl, ss, HYBRID)
    try:
        glb = export_glb(meshes)
        arrays = [mesh_arrays(m) for m in meshes]
    finally:
        for m in meshes:
            m.release()
    loaded = trimesh.load(io.BytesIO(glb), file_type="glb", process=False)
    assert sorted(loaded.graph.nodes_geometry) == ["image_0", "image_1"]
    for k, (pos, tri) in enumerate(arrays):  # each node holds its image's mesh, triangle for triangle
        transform, name = loaded.graph[f"image_{k}"]
        g = loaded.geometry[name]
        assert len(tri) > 0 and np.allclose(transform, np.eye(4))
        np.testing.assert_array_equal(triangle_rows(np.asarray(g.vertices, np.float32), g.faces),
                                      triangle_rows(pos, tri))
    # COLOR_0 beside the sample material (trimesh keeps it as a vertex attribute then)
    colors = np.concatenate([g.visual.vertex_attributes["color"] for g in loaded.geometry.values()])
    assert colors[:, :3].max() > 100  # real shading colours, not the default grey/white
    assert len(np.unique(colors[:, :3], axis=0)) > 3


@pytest.mark.parametrize("kind", ["hybrid", "grid"])
def test_reconstruction_frees_its_gl_objects(kind):
    scene = figure11_scene()
    cam = Camera((2.0, 0.0, 10.0), (0.0, 0.0, 0.0), fov=40.0, width=32, height=32)

    class State(_SetState):
        def frame(self, _: int) -> None:
            img, off = self.ss.images[0], self.ss.offsets[0]
            self.rec.reconstruct(img, off, ReconstructionSettings(kind=kind)).release()

    before, after = gl_object_growth(lambda gl: State(gl, scene, [cam]), State.frame, 50)
    assert after == before


class _SetState:
    """gl_object_growth state: a scene's upload, a Reconstructor and the conventional
    set of `cams` (with offset images); `prepare()` then one `frame` run on creation."""

    def __init__(self, gl, scene: Scene, cams: list[Camera]) -> None:
        self.gl = gl
        self.sg, self.rec = SceneGPU(gl, scene), Reconstructor(gl)
        self.ss = render_set(gl, self.sg, "conventional", cams)
        self.prepare()
        self.frame(0)

    def prepare(self) -> None:
        pass

    def frame(self, _: int) -> None:
        raise NotImplementedError

    def release(self) -> None:
        self.rec.release()
        self.sg.release()


class _Failing(RuntimeError):
    """The error the failure tests below inject."""


def _fail(*_args, **_kwargs):
    raise _Failing("injected")


@pytest.mark.parametrize("where", ["hybrid", "grid", "later_image"])
def test_a_failing_reconstruction_releases_what_it_made(where):
    """A reconstruction that raises part-way frees every GL object it made: its
    scratch images and output buffers (hybrid, grid: the dispatch fails) and the
    meshes of the set's earlier images (reconstruct_set: a later one fails). 10
    failing calls."""
    scene = figure11_scene()
    cams = [Camera((2.0, 0.0, 10.0), (0.0, 0.0, 0.0), fov=40.0, width=32, height=32),
            Camera((0.0, 2.0, 10.0), (0.0, 0.0, 0.0), fov=40.0, width=32, height=32)]
    settings = replace(HYBRID, kind="grid") if where == "grid" else HYBRID

    class State(_SetState):
        def prepare(self) -> None:
            if where == "later_image":  # the second image's offset image has the wrong shape
                self.ss = replace(self.ss, offsets=[self.ss.offsets[0], self.ss.images[1]])
            else:
                self.rec._set_camera = _fail

        def frame(self, _: int) -> None:
            with pytest.raises((_Failing, ValueError)):
                reconstruct_set(self.gl, self.ss, settings, self.rec)

    before, after = gl_object_growth(lambda gl: State(gl, scene, cams), State.frame, 10)
    assert after == before


def test_a_mesh_whose_splats_fail_releases_its_buffers(monkeypatch):
    """MeshGPU.from_records frees its vertex and index buffers when making its
    splats raises (10 failing calls)."""
    monkeypatch.setattr(mesh_gpu, "QuadSplats", _fail)
    records = np.zeros((4, 4), np.float32)
    records[:, :2] = [(0, 0), (1, 0), (1, 1), (0, 1)]
    quad = np.array([[0, 1, 2], [0, 2, 3]], np.uint32)

    def frame(state: tuple, _: int) -> None:
        with pytest.raises(_Failing):
            mesh_gpu.MeshGPU.from_records(state[0], records, quad, quads=1)

    before, after = gl_object_growth(lambda gl: (gl,), frame, 10)
    assert after == before

"""Quad splats (gl_passes.quad_splats): the triangles of a reconstruction's small
pieces rasterised by a compute pass in shadow maps keep their texels and depths.

Hand-counted meshes for the matching of triangles into quads; on llvmpipe, shadow
maps of 450 tilted quads and 150 lone triangles of about a texel, scattered through
the light's frusta (some across the maps' edges, so splats straddle atlas tiles),
drawn as triangles and as splats: the same texels covered but for at most 1 % of
them [0.38 % in the atlas, none with one map per draw: texel centres within the
rasteriser's sub-pixel snapping of the vertices (1/256 texel on llvmpipe) of an
edge, which the splat's float inside test decides unsnapped; small quads have
much edge per texel], and within 2e-5 of the depth range in every texel both cover
[9e-6: float rounding; the shadow lookup's depth bias is a texel, about 1e-3 of
it], in the instanced
atlas and with one map per draw, and with the splats' dispatch split over rows;
reconstructions keep their triangles.
"""

from __future__ import annotations

import numpy as np
import pytest

from gl_passes import quad_splats
from gl_passes.mesh_gpu import MeshGPU, pack_vertices
from gl_passes.quad_splats import (
    SPLAT_PIECE,
    SPLAT_PIXELS,
    quad_corners,
    splat_corners,
    splat_pairs,
    splats_last,
    split_splats,
)
from gl_passes.reconstruction import ReconstructionSettings, mesh_arrays, reconstruct_set, render_set
from gl_passes.shadows import ShadowSettings, SoftShadowPass
from gl_passes.upload import SceneGPU
from scenes.builtin import make_builtin
from scenes.lights import default_area_light, reference_cameras
from scenes.model import AreaLight
from tests.gl_leaks import gl_object_growth
from tests.helpers import triangle_rows

LIGHT = AreaLight((0.0, 6.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, -1.0))
BOUNDS = (np.array([-2.0, -0.5, -2.0]), np.array([2.0, 0.5, 2.0]))


def test_splat_pairs_match_the_triangles_of_small_pieces():
    tri = np.array([
        [0, 1, 2], [2, 1, 3],                # an isolated quad
        [4, 5, 6], [6, 5, 7], [6, 7, 8],     # a strip of three triangles: a quad and one left
        [9, 10, 11],                          # a lone triangle
        [12, 13, 14], [15, 13, 12],          # another quad, diagonal 12–13
        [16, 17, 18], [18, 19, 20],          # two triangles sharing a vertex, no edge
        [21, 22, 23], [21, 23, 24], [21, 24, 25],  # a fan whose middle edge three triangles share ...
        [21, 24, 26],
    ] + [[30 + i, 31 + i, 32 + i] for i in range(SPLAT_PIECE + 1)])  # a strip too long to splat
    pairs, singles = splat_pairs(tri)
    assert sorted(map(sorted, pairs.tolist())) == [[0, 1], [2, 3], [6, 7], [10, 11]]
    assert sorted(singles.tolist()) == [4, 5, 8, 9, 12, 13]
    corners = quad_corners(np.arange(3 * 27, dtype=np.float32).reshape(27, 3), tri[[[6, 7]]])
    assert (corners[0, :, 0] / 3).tolist() == [12, 13, 14, 15]  # the diagonal, then each triangle's own
    lone = splat_corners(np.arange(3 * 27, dtype=np.float32).reshape(27, 3), tri[[[6, 7]]], tri[[5]])
    assert (lone[:, :, 0] / 3).tolist() == [[12, 13, 14, 15], [9, 10, 11, 11]]  # a lone one: c twice
    assert [len(x) for x in splat_pairs(tri[:0])] == [0, 0]


def test_split_splats_keeps_large_pieces_as_triangles():
    tri = np.array([[0, 1, 2], [2, 1, 3], [4, 5, 6], [6, 5, 7], [8, 9, 10], [11, 12, 13]])
    px = np.zeros((14, 2))
    px[[1, 3], 0] = 1.0
    px[[2, 3], 1] = 1.0                       # quad 0: one pixel across
    px[[5, 7], 0] = SPLAT_PIXELS + 0.5         # quad 1: wider than SPLAT_PIXELS
    px[12, 1] = SPLAT_PIXELS                   # a lone triangle just small enough
    px[9, 1] = SPLAT_PIXELS + 0.5              # and one too large
    body, quads, singles = split_splats(tri, px)
    assert quads.tolist() == [[[0, 1, 2], [2, 1, 3]]] and singles.tolist() == [[11, 12, 13]]
    assert body.tolist() == [[4, 5, 6], [6, 5, 7], [8, 9, 10]]
    ordered, n_quads, n_singles = splats_last(tri, px)  # as MeshGPU.from_records reads them: body, quads, lone
    assert (n_quads, n_singles) == (1, 1)
    assert ordered.tolist() == [[4, 5, 6], [6, 5, 7], [8, 9, 10], [0, 1, 2], [2, 1, 3], [11, 12, 13]]


def scattered_quads(n: int = 600, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """(vertex records (4n,4), triangles (2n,3)): n isolated, randomly tilted,
    slightly non-planar quads of 0.01–0.06 across, in a box a little larger than BOUNDS."""
    rng = np.random.default_rng(seed)
    centre = rng.uniform([-2.3, -0.5, -2.3], [2.3, 0.5, 2.3], (n, 3))
    a = rng.normal(size=(n, 3))
    b = np.cross(a, rng.normal(size=(n, 3)))
    size = rng.uniform(0.005, 0.03, (n, 1))
    a *= size / np.linalg.norm(a, axis=1, keepdims=True)
    b *= size * rng.uniform(0.3, 1.0, (n, 1)) / np.linalg.norm(b, axis=1, keepdims=True)
    warp = rng.normal(scale=0.002, size=(n, 3))
    pos = np.stack([centre - a - b, centre + a - b, centre - a + b + warp, centre + a + b], axis=1).reshape(-1, 3)
    base = 4 * np.arange(n)[:, None]
    tri = np.concatenate([base + [0, 1, 2], base + [2, 1, 3]], axis=1).reshape(-1, 3)
    return pack_vertices(pos), tri


def atlas_depth(gl, meshes: list[MeshGPU], settings: ShadowSettings) -> np.ndarray:
    """The depth atlas after a visibility call (one batch: every map of it)."""
    pts = np.zeros((1, 1, 3), np.float32)
    nrm = np.array([[[0.0, 1.0, 0.0]]], np.float32)
    with SoftShadowPass(gl, settings) as sp:
        sp.visibility(meshes, BOUNDS, pts, nrm, np.ones((1, 1), bool), LIGHT)
        return np.frombuffer(sp.atlas.read(), np.float32).copy()


@pytest.mark.parametrize("per_draw, max_groups", [(16, None), (1, None), (16, 2)])
def test_splats_draw_the_quads_texels_and_depths(gl, per_draw, max_groups, monkeypatch):
    if max_groups is not None:  # 600 splats are 10 work groups: 5 rows of 2
        monkeypatch.setattr(quad_splats, "MAX_GROUPS", max_groups)
    records, tri = scattered_quads()
    quads = 450  # the last 150 quads keep their first triangle only: lone triangles
    tri = np.concatenate([tri[:2 * quads], tri[2 * quads::2]])
    as_tris = MeshGPU.from_records(gl, records, tri)
    as_splats = MeshGPU.from_records(gl, records, tri, quads=quads, singles=len(tri) - 2 * quads)
    settings = ShadowSettings(samples=4, shadow_map_resolution=128, maps_per_draw=per_draw, splat_raster_min=0)
    try:
        assert as_splats.splats.count == 600 and as_splats.body_triangles == 0
        a, b = atlas_depth(gl, [as_tris], settings), atlas_depth(gl, [as_splats], settings)
    finally:
        as_tris.release()
        as_splats.release()
    ca, cb = a < 1.0, b < 1.0
    assert ca.sum() > 150 * len(a) // 128**2  # the quads cover hundreds of texels per map
    assert (ca != cb).sum() <= 0.01 * ca.sum(), ((ca != cb).sum(), ca.sum())
    np.testing.assert_allclose(b[ca & cb], a[ca & cb], atol=2e-5)


def test_splat_maps_kept_or_drawn_per_batch_give_the_same_bits(gl):
    """Nine maps in batches of 4, 4 and 1 (the last one partial): the bits of the
    maps drawn batch by batch (`visibility`), of the maps kept and looked up
    (`render_maps`, `lookup`), and of the same quads drawn as triangles."""
    records, tri = scattered_quads(1500, seed=5)
    n = 64
    xz = np.stack(np.meshgrid(np.linspace(-2, 2, n), np.linspace(-2, 2, n)), axis=-1)
    pts = np.concatenate([xz[..., :1], np.full((n, n, 1), -0.6), xz[..., 1:]], axis=-1).astype(np.float32)
    nrm = np.zeros_like(pts)
    nrm[..., 1] = 1.0
    mask = np.ones((n, n), bool)
    as_tris = MeshGPU.from_records(gl, records, tri)
    as_splats = MeshGPU.from_records(gl, records, tri, quads=len(tri) // 2)
    try:
        with SoftShadowPass(gl, ShadowSettings(samples=3, shadow_map_resolution=128, maps_per_draw=4,
                                                splat_raster_min=0)) as sp:
            drawn = sp.visibility([as_splats], BOUNDS, pts, nrm, mask, LIGHT)
            maps = sp.render_maps([as_splats], BOUNDS, LIGHT)
            try:
                kept = sp.lookup(maps, pts, nrm, mask)
            finally:
                maps.release()
            triangles = sp.visibility([as_tris], BOUNDS, pts, nrm, mask, LIGHT)
    finally:
        as_tris.release()
        as_splats.release()
    assert np.array_equal(drawn.bits, kept.bits)
    shadowed = (triangles.counts < 9).sum()
    assert shadowed > 100 and (drawn.counts < 9).sum() > 100  # the quads shadow the plane in every set of maps
    # measured 6 of 780 (0.8 %): points whose texel the rasteriser's sub-pixel snapping decides (see above)
    assert (drawn.bits != triangles.bits).any(axis=-1).sum() <= 0.012 * shadowed


def test_reconstruction_keeps_its_triangles_with_splats(gl):
    """Grass at 128² reference images: many samples are small pieces; the meshes
    with and without splats hold the same triangles, and their shadows agree."""
    scene = make_builtin("grass", 0.1)
    light = default_area_light(scene.bounds, scene.sun_direction)
    with SceneGPU(gl, scene) as sg:
        ss = render_set(gl, sg, "non_redundant", reference_cameras(light, scene.bounds, "non_redundant", 128))
    for kind in ("hybrid", "compact"):
        meshes = {s: reconstruct_set(gl, ss, ReconstructionSettings(kind=kind, quad_splats=s)) for s in (False, True)}
        try:
            assert sum(m.splats.count for m in meshes[True] if m.splats) > 100, kind
            assert all(m.splats is None for m in meshes[False])
            for a, b in zip(meshes[False], meshes[True], strict=True):
                ta, tb = (triangle_rows(*mesh_arrays(m)) for m in (a, b))
                assert len(ta) == a.n_triangles == b.n_triangles and np.array_equal(ta, tb), kind
        finally:
            for ms in meshes.values():
                for m in ms:
                    m.release()


def test_splat_meshes_free_their_gl_objects():
    records, tri = scattered_quads(50)
    pts = np.zeros((4, 4, 3), np.float32)
    nrm = np.zeros_like(pts)
    nrm[..., 1] = 1.0

    class State:
        def __init__(self, gl) -> None:
            self.gl = gl
            self.sp = SoftShadowPass(gl, ShadowSettings(samples=2, shadow_map_resolution=32, splat_raster_min=0))
            self.frame(0)

        def frame(self, _: int) -> None:
            with MeshGPU.from_records(self.gl, records, tri, quads=len(tri) // 2) as m:
                self.sp.visibility([m], BOUNDS, pts, nrm, np.ones((4, 4), bool), LIGHT)

        def release(self) -> None:
            self.sp.release()

    before, after = gl_object_growth(State, State.frame, 200)
    assert after <= before, (before, after)


def test_too_few_splats_per_texel_are_drawn_as_triangles(gl):
    """`ShadowSettings.splat_raster_min`: 600 splats in a batch of 16 maps of 128²
    (4 tile rows of 4 × 128² texels) are 600·16 / 262,144 = 0.0366 splats per
    resolved texel; at a higher minimum the batch draws their triangles (the same
    atlas, bit for bit, and no splat image is made), at that minimum the splats."""
    records, tri = scattered_quads()
    as_tris = MeshGPU.from_records(gl, records, tri)
    as_splats = MeshGPU.from_records(gl, records, tri, quads=len(tri) // 2)
    density = 600 * 16 / (4 * 4 * 128**2)
    try:
        atlas = {}
        for name, mesh, minimum in (("triangles", as_tris, 0.0), ("above", as_splats, density * 1.001),
                                    ("at", as_splats, density)):
            s = ShadowSettings(samples=4, shadow_map_resolution=128, splat_raster_min=minimum)
            with SoftShadowPass(gl, s) as sp:
                assert name == "triangles" or sp.splat_raster.pays(600, 16, minimum) == (name == "at"), name
                sp.visibility([mesh], BOUNDS, np.zeros((1, 1, 3), np.float32),
                              np.array([[[0.0, 1.0, 0.0]]], np.float32), np.ones((1, 1), bool), LIGHT)
                assert (sp.splat_raster.image is not None) == (name == "at"), name
                atlas[name] = np.frombuffer(sp.atlas.read(), np.float32).copy()
    finally:
        as_tris.release()
        as_splats.release()
    assert np.array_equal(atlas["above"], atlas["triangles"])
    # a partial batch pays for the tile rows it fills: 5 maps of a 4 × 4 atlas fill 2 rows (8 tiles)
    with SoftShadowPass(gl, ShadowSettings(samples=4, shadow_map_resolution=128)) as sp:
        assert sp.splat_raster.rows(5) == 2 and sp.splat_raster.rows(16) == 4
        # splats × 5 ≥ 0.625 × 8 × 128²  ⇔  splats ≥ 128²
        assert sp.splat_raster.pays(128**2, 5, 0.625) and not sp.splat_raster.pays(128**2 - 1, 5, 0.625)
        assert not sp.splat_raster.pays(0, 16, 0.0)
    covered = atlas["triangles"] < 1.0
    assert covered.sum() > 1000 and ((atlas["at"] < 1.0) != covered).sum() <= 0.01 * covered.sum()
    with pytest.raises(ValueError, match="splat_raster_min"):
        ShadowSettings(splat_raster_min=-1.0)


def test_splats_of_an_unresolved_batch_do_not_reach_the_next(gl):
    """The splat depth image is emptied by the resolve that reads it; a batch whose
    splats were drawn but never resolved (an error between) is emptied by the next
    batch's begin, so its depths never reach another batch's maps."""
    records, tri = scattered_quads()
    mesh = MeshGPU.from_records(gl, records, tri, quads=len(tri) // 2)
    try:
        with SoftShadowPass(gl, ShadowSettings(samples=4, shadow_map_resolution=128, splat_raster_min=0)) as sp:
            maps = sp.render_maps([mesh], BOUNDS, LIGHT)  # draws, resolves: the image is made and empty again
            maps.release()
            raster, light_vp = sp.splat_raster, np.eye(4, dtype=np.float32).tobytes() * 16
            gl.ctx.memory_barrier()
            assert (np.frombuffer(raster.image.read(), np.uint32) == 0xFFFFFFFF).all()  # emptied by the resolve
            raster.begin(light_vp, 16)
            raster.draw(mesh.splats)  # ... and no resolve
            for drawn in (False, True):
                raster.begin(light_vp, 16)
                if drawn:
                    raster.draw(mesh.splats)
                sp.fbo.use()
                sp.fbo.clear(depth=1.0)
                with sp._map_state(tiles=False):
                    raster.resolve(sp.fbo)
                assert sp.fbo.viewport == (0, 0, *sp.fbo.size)  # the resolve's tile rows, then restored
                depth = np.frombuffer(sp.atlas.read(), np.float32)
                assert (depth < 1.0).any() == drawn, drawn
    finally:
        mesh.release()

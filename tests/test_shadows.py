"""Soft-shadow visibility from shadow maps (thesis §3.3, Alg. 5): gl_passes.shadows
against the analytic box visibility and the Embree truth (reference.shadows).

Tolerances, with the values measured on llvmpipe in brackets:
  box over a plane (k = 6, 256² maps, 128² G-buffer receivers): every wrong
  (pixel, sample) decision lies within 2 shadow-map texels of a shadow boundary
  (the analytic answer flips within that distance) [all of them], and at most
  0.25 % of the decisions are wrong [0.10 %]; umbra and fully lit regions exact;
  city (detail 0.1, k = 6, 512² maps, 96² G-buffer): mean visibility error (§3.4.2,
  samples resolved wrongly per pixel) ≤ 1.6 % of k² [1.3 %; it halves with each
  doubling of the map resolution: shadow-map quantisation at silhouettes; 1.9 %
  with the bias before the slope-scaled depth bias, bench.shadow_bias.PREVIOUS];
  MeshGPU vs SceneGPU occluders of the same triangles: identical bits;
  maps_per_draw 16 (instanced atlas) vs 1 (one draw per map): identical bits;
  a plane lit at up to 88° from its normal shadows nothing of itself (no acne), and
  without the slope-scaled depth bias a small normal offset does (at 88°).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from bench.shadow_bias import GRAZING_DEGREES, grazing_lit, grazing_wrong
from gl_passes.mesh_gpu import MeshGPU
from gl_passes.shadows import MAX_SAMPLES, ShadowSettings, SoftShadowPass, popcount_words, shadow_cameras
from gl_passes.upload import SceneGPU
from reference.raycast import RayCaster
from reference.shadows import box_visibility, light_visibility, shadow_errors
from scenes.builtin import geometry as g
from scenes.builtin import make_builtin
from scenes.camera import Camera, look_at_scene
from scenes.lights import default_area_light
from scenes.model import AreaLight, Scene, SceneObject
from tests.gl_leaks import gl_object_growth
from tests.helpers import unpack_bits

BOX_LO, BOX_HI = np.array([-0.5, 0.5, -0.5]), np.array([0.5, 1.0, 0.5])
#: Overhead 1.5 × 1.5 light; u × v = +Y, so its cameras look down (scenes.lights).
LIGHT = AreaLight((0.3, 4.0, 0.2), (1.5, 0.0, 0.0), (0.0, 0.0, -1.5))
SMALL = ShadowSettings(samples=6, shadow_map_resolution=256)


def box_plane_scene() -> Scene:
    """A box floating 0.5 above a 6 × 6 ground quad at y = 0."""
    box = g.box(BOX_LO, BOX_HI)
    plane = g.grid((-3, 0, 3), (6, 0, 0), (0, 0, -6), 1, 1)
    return Scene([SceneObject("box", box[0], box[1]), SceneObject("plane", plane[0], plane[1])], name="box_plane")


@pytest.fixture(scope="module")
def box_setup(gl, gbuffer_pass):
    """(scene, SceneGPU, G-buffer) of the box over the plane, seen from above."""
    scene = box_plane_scene()
    sg = SceneGPU(gl, scene)
    cam = Camera((3, 4, 5), (0, 0.3, 0), fov=50, width=128, height=128).fit_clip(scene.bounds)
    buf = gbuffer_pass.render(sg, cam)
    yield scene, sg, buf
    sg.release()


def run(gl, occluders, scene, buf, settings=SMALL, light=LIGHT):
    with SoftShadowPass(gl, settings) as sp:
        return sp.visibility(occluders, scene.bounds, buf.position, buf.normal, buf.tri_id > 0, light)


def test_box_over_plane_matches_analytic(gl, box_setup):
    scene, sg, buf = box_setup
    k, res = SMALL.samples, SMALL.shadow_map_resolution
    mask = buf.tri_id > 0
    r = run(gl, [sg], scene, buf)
    assert r.bits.shape == (128, 128, 2) and r.bits.dtype == np.uint32
    assert r.counts.dtype == np.uint16 and r.counts.shape == (128, 128)
    assert not r.bits[~mask].any()
    assert (r.bits[..., 1] >> np.uint32(k * k - 32)).max() == 0  # bits ≥ k² stay 0
    np.testing.assert_array_equal(r.counts, popcount_words(r.bits))
    assert set(r.timings_ms) >= {"shadow_maps", "lookup"}

    samples = LIGHT.samples(k)
    n = buf.normal[mask].astype(np.float64)
    # G-buffer points may lie a float32 rounding inside the box, where the slab test
    # calls every segment blocked: lift them off the surface, as the Embree truth does.
    p = buf.position[mask] + n * 1e-5 * scene.diagonal
    truth = box_visibility(p, n, samples, BOX_LO, BOX_HI)
    got = unpack_bits(r.bits[mask], k)
    wrong = got != truth
    # Near a boundary: the analytic answer flips within 2 texels (the texel size at
    # the point's light depth) along the surface or the normal.
    cams = shadow_cameras(LIGHT, scene.bounds, k, res)
    texel = cams.light[:, 3].max() * ((p - np.asarray(LIGHT.center)) @ cams.forward[0, :3])
    t1 = np.cross(n, [0.3, 1.0, 0.1])
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    near = np.zeros_like(truth)
    for d in (t1, -t1, np.cross(n, t1), -np.cross(n, t1), n):
        near |= box_visibility(p + 2 * texel[:, None] * d, n, samples, BOX_LO, BOX_HI) != truth
    assert not (wrong & ~near).any(), f"{(wrong & ~near).sum()} wrong decisions away from shadow boundaries"
    assert wrong.mean() <= 0.0025, f"{wrong.mean():.4%} wrong decisions"
    counts, truth_counts = r.counts[mask], truth.sum(axis=1)
    interior = ~near.any(axis=1)
    umbra, lit = interior & (truth_counts == 0), interior & (truth_counts == k * k)
    assert umbra.sum() > 100 and lit.sum() > 1000
    assert (counts[umbra] == 0).all() and (counts[lit] == k * k).all()


def test_builtin_scene_matches_embree(gl, gbuffer_pass):
    scene = make_builtin("city", 0.1)
    light = default_area_light(scene.bounds, scene.sun_direction)
    k = 6
    sg = SceneGPU(gl, scene)
    try:
        buf = gbuffer_pass.render(sg, look_at_scene(scene.bounds, 35, 35, 0.7, width=96, height=96))
        mask = buf.tri_id > 0
        r = run(gl, [sg], scene, buf, ShadowSettings(samples=k, shadow_map_resolution=512), light)
    finally:
        sg.release()
    truth = light_visibility(RayCaster(scene), buf.position, buf.normal, mask, light, k)
    shadowed = (popcount_words(truth)[mask] < k * k).mean()
    assert 0.2 < shadowed < 0.9  # shadows and full light both present
    err = shadow_errors(r.bits, truth, mask)
    print(f"city: {shadowed:.0%} shadowed, mean visibility error {err.visibility_mean / k**2:.2%} of k²")
    assert err.visibility_mean <= 0.016 * k * k, err


def test_a_light_far_larger_than_the_scene_matches_embree(gl, box_setup):
    """A 200 × 200 light 4 above the box: its far samples' maps along the light's axis
    would need about 178° (texels of metres at the scene: nearly every shadow lost);
    looking at the box instead, the maps agree with Embree as for a small light."""
    scene, sg, buf = box_setup
    huge = AreaLight((0.3, 4.0, 0.2), (200.0, 0.0, 0.0), (0.0, 0.0, -200.0))
    mask = buf.tri_id > 0
    r = run(gl, [sg], scene, buf, light=huge)
    truth = light_visibility(RayCaster(scene), buf.position, buf.normal, mask, huge, SMALL.samples)
    err = shadow_errors(r.bits, truth, mask)
    assert 0 < (popcount_words(truth)[mask] < SMALL.samples ** 2).mean() < 1  # some shadow, some light
    assert err.visibility_mean <= 0.015, err  # measured 0.0089 (a fully lit result: 0.64)


class _DrawOnly:
    """An occluder with only draw(prog): drawn once per map, no instancing."""

    def __init__(self, mesh: MeshGPU) -> None:
        self.mesh = mesh

    def draw(self, prog) -> None:
        self.mesh.draw(prog)


def test_mesh_occluders_match_scene(gl, box_setup):
    scene, sg, buf = box_setup
    ref = run(gl, [sg], scene, buf)
    meshes = [MeshGPU.from_arrays(gl, o.vertices, o.faces) for o in scene.objects]
    whole = MeshGPU.from_arrays(gl, scene.vertices, scene.faces)
    try:
        np.testing.assert_array_equal(run(gl, [whole], scene, buf).bits, ref.bits)
        np.testing.assert_array_equal(run(gl, meshes, scene, buf).bits, ref.bits)  # several meshes
        np.testing.assert_array_equal(run(gl, [_DrawOnly(m) for m in meshes], scene, buf).bits, ref.bits)
    finally:
        for m in [*meshes, whole]:
            m.release()


def test_instanced_atlas_matches_one_map_per_draw(gl, box_setup):
    scene, sg, buf = box_setup
    for k in (5, 6):  # 25 maps: a partial last batch
        a = run(gl, [sg], scene, buf, ShadowSettings(samples=k, shadow_map_resolution=128, maps_per_draw=16))
        b = run(gl, [sg], scene, buf, ShadowSettings(samples=k, shadow_map_resolution=128, maps_per_draw=1))
        np.testing.assert_array_equal(a.bits, b.bits)
        assert a.counts.max() == k * k and a.counts[buf.tri_id > 0].min() == 0


def test_kept_maps_give_the_bits_of_visibility(gl, box_setup, gbuffer_pass):
    """render_maps keeps all k² maps (25: a partial last batch); lookup from them
    answers any receivers with visibility's bits; released maps, and maps of a pass
    with other settings (here the same batches of another resolution), are refused."""
    scene, sg, buf = box_setup
    settings = ShadowSettings(samples=5, shadow_map_resolution=128)
    other = gbuffer_pass.render(sg, Camera((-4, 3, 2), (0, 0.3, 0), fov=50, width=96, height=64).fit_clip(scene.bounds))
    with SoftShadowPass(gl, settings) as sp:
        maps = sp.render_maps([sg], scene.bounds, LIGHT)
        try:
            assert len(maps.atlases) == 2 and maps.nbytes == sp.maps_nbytes == 2 * (4 * 128) ** 2 * 4
            for b in (buf, other):
                direct = sp.visibility([sg], scene.bounds, b.position, b.normal, b.tri_id > 0, LIGHT)
                kept = sp.lookup(maps, b.position, b.normal, b.tri_id > 0)
                np.testing.assert_array_equal(kept.bits, direct.bits)
                assert kept.counts.max() == 25 and kept.counts[b.tri_id > 0].min() == 0
            with SoftShadowPass(gl, replace(settings, shadow_map_resolution=64)) as coarse:
                with pytest.raises(ValueError, match="other settings"):
                    coarse.lookup(maps, buf.position, buf.normal, buf.tri_id > 0)
        finally:
            maps.release()
        with pytest.raises(ValueError, match="atlases"):
            sp.lookup(maps, buf.position, buf.normal, buf.tri_id > 0)


def test_released_framebuffers_are_not_bound_again(gl, box_setup):
    """render_maps draws each batch into a framebuffer it then releases, and a pass
    released after visibility() releases the framebuffer it drew into: moderngl must
    not be left binding either, or it binds the deleted one again when it next makes
    a framebuffer or clears one (GL_INVALID_OPERATION; gl_passes.releasable)."""
    scene, sg, buf = box_setup
    settings = ShadowSettings(samples=2, shadow_map_resolution=32)
    with SoftShadowPass(gl, settings) as sp:
        sp.render_maps([sg], scene.bounds, LIGHT).release()
        assert gl.ctx.error == "GL_NO_ERROR"
        target = gl.ctx.depth_texture((8, 8))
        fbo = gl.ctx.framebuffer(depth_attachment=target)
        try:
            fbo.clear(depth=1.0)
            assert gl.ctx.error == "GL_NO_ERROR"
        finally:
            fbo.release()
            target.release()
    run(gl, [sg], scene, buf, settings)  # its pass released with its framebuffer bound
    with SoftShadowPass(gl, settings):
        assert gl.ctx.error == "GL_NO_ERROR"


@pytest.mark.parametrize("degrees", GRAZING_DEGREES)
def test_grazing_plane_has_no_acne(gl, degrees):
    """A plane tilted about a diagonal of the maps (the worst case for texel
    quantisation) receives all light samples in front of it, with the default bias."""
    lit, front = grazing_lit(gl, ShadowSettings(), degrees)
    assert front.mean() > 0.5  # most samples are in front of the plane, even at 88°
    np.testing.assert_array_equal(lit, front)


def test_depth_slope_cures_acne_a_small_offset_has(gl):
    """Without the slope-scaled depth bias a small normal offset shows acne at
    grazing tilts; the slope term alone removes it, and leaves a plane facing the
    light as it was (tan 0 = 0)."""
    small = ShadowSettings(normal_offset=0.125, depth_bias=1.0, depth_slope=0.0)
    assert 88 in grazing_wrong(gl, small)
    assert grazing_wrong(gl, replace(small, depth_slope=0.5)) == []
    np.testing.assert_array_equal(grazing_lit(gl, small, 0)[0], grazing_lit(gl, replace(small, depth_slope=0.5), 0)[0])


def test_tangent_plane_rule_and_mask(gl, box_setup):
    scene, sg, _ = box_setup
    pts = np.zeros((2, 3, 3), np.float32)
    pts[..., 0] = [[-2.5, 2.5, 0.0], [-2.5, 2.5, 0.0]]  # open ground, under the box
    nrm = np.zeros_like(pts)
    nrm[0, :, 1] = 1.0     # facing the light
    nrm[1, :, 1] = -1.0    # facing away: every sample behind the tangent plane
    mask = np.array([[True, True, True], [True, True, True]])
    mask[0, 1] = False
    with SoftShadowPass(gl, SMALL) as sp:
        r = sp.visibility([sg], scene.bounds, pts, nrm, mask, LIGHT)
        np.testing.assert_array_equal(r.counts, [[36, 0, 0], [0, 0, 0]])
        empty = sp.visibility([sg], scene.bounds, pts, nrm, np.zeros((2, 3), bool), LIGHT)
        assert not empty.bits.any() and empty.bits.shape == (2, 3, 2)
        with pytest.raises(ValueError):
            sp.visibility([sg], scene.bounds, pts[:1], nrm, mask, LIGHT)
    with pytest.raises(ValueError):
        ShadowSettings(samples=0)


def test_no_gl_object_growth():
    scene = box_plane_scene()
    pts = np.zeros((8, 8, 3), np.float32)
    nrm = np.zeros_like(pts)
    nrm[..., 1] = 1.0

    class State:
        def __init__(self, gl) -> None:
            self.sg = SceneGPU(gl, scene)
            self.sp = SoftShadowPass(gl, ShadowSettings(samples=4, shadow_map_resolution=64))
            self.frame(0)

        def frame(self, i: int) -> None:
            mask = np.ones((8, 8), bool)
            mask[: i % 8] = False  # the point buffers are reused, not re-made
            self.sp.visibility([self.sg], scene.bounds, pts, nrm, mask, LIGHT)
            maps = self.sp.render_maps([self.sg], scene.bounds, LIGHT)
            self.sp.lookup(maps, pts, nrm, mask)
            maps.release()

        def release(self) -> None:
            self.sp.release()
            self.sg.release()

    before, after = gl_object_growth(State, lambda s, i: s.frame(i + 1), 5)
    assert before > 0 and after == before


def test_settings_refuse_more_samples_than_a_count_holds():
    """Counts are uint16: 255² = 65,025 visible samples fit, 256² = 65,536 do not."""
    assert ShadowSettings(samples=MAX_SAMPLES).n_samples == 65_025
    with pytest.raises(ValueError, match="16-bit"):
        ShadowSettings(samples=MAX_SAMPLES + 1)

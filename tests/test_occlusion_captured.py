"""The thesis's occlusion-error test (reference.occlusion, §4.4 / §4.7.1): hand-made
cluster images (pure numpy), then the GL diagnostics on the planar mirror (no error,
the cluster camera is the mirrored eye) and a mirror sphere (errors, checked against
Embree visibility from the cluster cameras)."""

from __future__ import annotations

import numpy as np
import pytest

from reference.occlusion import (
    EMPTY_DEPTH,
    captured_by_clusters,
    captured_mask,
    uncaptured_error_mask,
    uncaptured_ray_percentage,
)
from tests.helpers import (
    assert_images_equal,
    mirror_camera,
    mirror_object_scene,
    planar_mirror_scene,
    props,
    sphere_mesh,
)

EMPTY = 1e30
N_FRONT = np.array([0.0, 0.0, 1.0])  # a surface facing the camera (which looks down −z)


def perspective(near: float = 0.5, far: float = 10.0) -> np.ndarray:
    """GL projection of the rectangle [−1, 1]² at unit depth (90° fov); clip w = depth."""
    m = np.zeros((4, 4))
    m[0, 0] = m[1, 1] = 1.0
    m[2, 2], m[2, 3] = -(far + near) / (far - near), -2.0 * far * near / (far - near)
    m[3, 2] = -1.0
    return m


def view_translate(centre) -> np.ndarray:
    """View matrix of a camera at `centre` looking down −z (up +y)."""
    v = np.eye(4)
    v[:3, 3] = -np.asarray(centre, np.float64)
    return v


def texel_point(col: float, row: float, depth: float, size: int = 4, centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    """World point at image position (col, row) in texels from the top-left corner
    (col + 0.5 = a texel centre) and `depth`, for a camera of `view_translate(centre)`."""
    u = (col / size) * 2.0 - 1.0
    v = 1.0 - (row / size) * 2.0
    return np.asarray(centre, np.float64) + depth * np.array([u, v, -1.0])


@pytest.fixture()
def rig():
    """Two 4×4 cluster images stacked in an 4-wide, 8-tall atlas with 2 layers:
    cluster 0 at the top (rows 0–3), cluster 1 (camera moved to x = 5) below."""
    vp = np.stack([perspective() @ view_translate((0, 0, 0)), perspective() @ view_translate((5, 0, 0))])
    viewports = np.array([[0, 0, 4, 4], [0, 4, 4, 4]])
    layers = np.full((2, 8, 4), EMPTY, np.float32)
    return vp, viewports, layers


def _cap(points, clusters, rig, **kw) -> np.ndarray:
    vp, viewports, layers = rig
    return captured_mask(np.asarray(points, np.float64), np.asarray(clusters), vp, viewports, layers, **kw)


def test_captured_point_at_a_texel_centre(rig):
    x = texel_point(1.5, 1.5, 2.0)
    rig[2][0, 1, 1] = 2.0
    assert _cap([x], [0], rig).tolist() == [True]
    assert _cap([x], [0], rig, hit_normals=[N_FRONT]).tolist() == [True]
    # the same point is not held by cluster 1's image (other camera, nothing stored there)
    assert _cap([x], [1], rig).tolist() == [False]


def test_point_behind_an_occluder_is_not_captured_unless_another_layer_holds_it(rig):
    x = texel_point(2.5, 2.5, 3.0)
    rig[2][0, 1:4, 1:4] = 1.5  # occluder in front of it, in layer 0, over the whole neighbourhood
    assert _cap([x], [0], rig).tolist() == [False]
    rig[2][1, 2, 2] = 3.0  # the second layer (e.g. the reflector's own layer) holds it
    assert _cap([x], [0], rig).tolist() == [True]


def test_point_outside_the_viewport_is_not_captured(rig):
    # just right of cluster 0's image: its depth is stored in the atlas column 3 edge texel
    # (and would be in cluster 1's image area if the viewport were ignored)
    x = texel_point(4.2, 1.5, 2.0)
    rig[2][:, :, :] = 2.0
    assert _cap([x], [0], rig).tolist() == [False]
    # beyond the far plane (10) or in front of the near plane (0.5)
    assert _cap([texel_point(1.5, 1.5, 12.0), texel_point(1.5, 1.5, 0.4)], [0, 0], rig).tolist() == [False, False]


def test_depth_mismatch_and_tolerance(rig):
    x = texel_point(1.5, 1.5, 2.0)
    rig[2][0, 0:3, 0:3] = 2.2  # 10 % behind the point
    assert _cap([x], [0], rig).tolist() == [False]
    assert _cap([x], [0], rig, rel_tol=0.15).tolist() == [True]
    rig[2][0, 1, 1] = 2.0 * 1.005  # within the default 1 %
    assert _cap([x], [0], rig).tolist() == [True]


def test_neighbour_texel_allowance(rig):
    x = texel_point(1.9, 1.5, 2.0)  # near the right edge of texel (1, 1)
    rig[2][0, 1, 2] = 2.0  # only the right neighbour holds the surface
    assert _cap([x], [0], rig).tolist() == [True]
    assert _cap([x], [0], rig, radius=0).tolist() == [False]


def test_cluster_below_in_the_atlas_uses_its_own_viewport_rows(rig):
    x = texel_point(2.5, 1.5, 4.0, centre=(5, 0, 0))  # cluster 1: texel (2, 1) → atlas row 4 + 1
    rig[2][0, 5, 2] = 4.0
    assert _cap([x], [1], rig).tolist() == [True]
    assert _cap([x], [0], rig).tolist() == [False]


def test_tangent_plane_prediction_handles_steep_surfaces(rig):
    """A surface seen almost edge-on: its depth changes by tens of % per texel, so the
    stored texel-centre depths differ from an off-centre point's by far more than
    1 %; the tangent-plane prediction still recognises them as that surface."""
    n = np.array([1.0, 0.0, 0.5])
    n /= np.linalg.norm(n)
    x = texel_point(1.8, 1.5, 2.0)
    vp, viewports, layers = rig
    for c in range(4):  # store the plane's depth at the texel centres of row 1
        d = np.array([((c + 0.5) / 4) * 2 - 1, 1.0 - (1.5 / 4) * 2, -1.0])
        s = np.dot(n, x) / np.dot(n, d)
        if s > 0:
            layers[0, 1, c] = s
    assert abs(layers[0, 1, 1] - 2.0) > 0.05 * 2.0 and abs(layers[0, 1, 2] - 2.0) > 0.05 * 2.0
    assert _cap([x], [0], rig).tolist() == [False]  # fronto-parallel prediction
    assert _cap([x], [0], rig, hit_normals=[n]).tolist() == [True]
    assert _cap([x], [0], rig, hit_normals=[n], plane_tol=0.0).tolist() == [True]  # exact on the plane
    # a parallel surface more than half a texel footprint (here 0.5 units at depth 2) away is no match
    assert _cap([x + 0.6 * n], [0], rig, hit_normals=[n]).tolist() == [False]
    # a stored sample 3 % deeper than the plane predicts (curvature, tessellation) lies within
    # half a footprint of the plane: held by the plane-distance form, not by the 1 % depth form
    d11 = layers[0, 1, 1]
    layers[0, 1, :] = EMPTY
    layers[0, 1, 1] = 1.03 * d11
    assert _cap([x], [0], rig, hit_normals=[n]).tolist() == [True]
    assert _cap([x], [0], rig, hit_normals=[n], plane_tol=0.0).tolist() == [False]


def test_clip_plane_no_hit_and_no_cluster(rig):
    x = texel_point(1.5, 1.5, 2.0)
    rig[2][0, 1, 1] = 2.0
    keep_y_above = np.array([[0.0, 1.0, 0.0, 1.0], [0.0, 1.0, 0.0, 1.0]])  # holds only y >= 1
    assert x[1] < 1.0
    assert _cap([x], [0], rig, clip_planes=keep_y_above).tolist() == [False]
    assert _cap([x], [0], rig, clip_planes=keep_y_above - [0, 0, 0, 5]).tolist() == [True]
    nan = np.full(3, np.nan)
    assert _cap([nan, x, x], [0, -1, 7], rig).tolist() == [False, False, False]
    # a camera without an image (invalid: zero viewport)
    vp, viewports, layers = rig
    assert captured_mask(x[None], np.array([0]), vp, np.zeros((2, 4), int), layers).tolist() == [False]
    assert EMPTY > EMPTY_DEPTH


def test_shapes_are_kept_and_checked(rig):
    x = texel_point(1.5, 1.5, 2.0)
    rig[2][0, 1, 1] = 2.0
    pts = np.broadcast_to(x, (2, 3, 3)).copy()
    assert _cap(pts, np.zeros((2, 3), int), rig).shape == (2, 3)
    with pytest.raises(ValueError):
        _cap(pts, np.zeros((3, 2), int), rig)


def test_uncaptured_pixels_aggregate_like_the_strict_metric():
    """ss = 2: a pixel is an error when any reflective sample with a true hit is not
    captured; a miss (NaN hit point, the ray escapes to the sky) never is."""
    refl = np.ones((2, 4), bool)
    refl[:, 2:] = False
    pts = np.zeros((2, 4, 3))
    pts[0, 1] = np.nan  # pixel 0: one sample escapes to the sky ...
    cap = np.ones((2, 4), bool)
    cap[0, 1] = False  # ... and is "uncaptured": not an error
    cap[1, 2] = False  # pixel 1: not reflective
    assert uncaptured_error_mask(refl, pts, cap, 2).tolist() == [[False, False]]
    cap[1, 0] = False
    assert uncaptured_error_mask(refl, pts, cap, 2).tolist() == [[True, False]]
    with pytest.raises(ValueError):
        uncaptured_error_mask(refl, pts, cap, 3)
    # Per reflected ray: 1 uncaptured true hit among 4 reflective samples.
    assert uncaptured_ray_percentage(refl, pts, cap) == 25.0
    assert uncaptured_ray_percentage(np.zeros((2, 4), bool), pts, cap) == 0.0


# --- GL diagnostics ----------------------------------------------------------------
@pytest.fixture(scope="module")
def refl(gl):
    from gl_passes.reflections import ClusterReflections

    with ClusterReflections(gl) as r:
        yield r


def _render_both(gl, refl, scene, size: int = 96):
    from gl_passes.upload import SceneGPU
    from reference.reflections import raytrace_reflections

    cam = mirror_camera(size).fit_clip(scene.bounds)
    with SceneGPU(gl, scene) as sg:
        ours = refl.render(sg, cam, diagnostics=True)
        plain = refl.render(sg, cam)
    return ours, plain, raytrace_reflections(scene, cam)


def _captured(ours, ref) -> np.ndarray:
    return captured_by_clusters(ours.diagnostics, ref.hit_points_samples, ref.hit_normals_samples)


def test_planar_mirror_has_no_thesis_occlusion_error(gl, refl):
    from gl_passes.reflections import N_LAYERS
    from reference.image_metrics import occlusion_error_percentage

    ours, plain, ref = _render_both(gl, refl, planar_mirror_scene())
    assert plain.diagnostics is None
    d = ours.diagnostics
    assert d.cluster_of_sample.shape == ref.reflective_samples.shape == (192, 192)
    assert set(np.unique(d.cluster_of_sample).tolist()) == {-1, 0}
    # the G-buffer's reflective samples are the reference's (up to a silhouette sample)
    assert np.sum((d.cluster_of_sample >= 0) != ref.reflective_samples) <= 2
    # one cluster, its camera valid (a non-empty image)
    assert d.layer_depths.shape[0] == N_LAYERS and d.viewports.shape == (1, 4) and np.all(d.viewports[:, 2:] > 0)
    cap = _captured(ours, ref)
    hits = ref.reflective_samples & np.isfinite(ref.hit_points_samples[..., 0]) & (d.cluster_of_sample >= 0)
    assert hits.sum() > 1000 and cap[hits].all()
    mask = uncaptured_error_mask(ref.reflective_samples, ref.hit_points_samples, cap, 2)
    assert occlusion_error_percentage(mask & ours.reflective, ref.reflective) == 0.0
    # the stored depth at a hit point's texel is the point's depth along the cluster axis
    k = np.argwhere(hits)[len(np.argwhere(hits)) // 2]
    x = ref.hit_points_samples[k[0], k[1]]
    clip = d.view_proj[0] @ np.append(x, 1.0)
    vx, vy, vw, vh = d.viewports[0]
    col = int((clip[0] / clip[3] + 1) / 2 * vw)
    row = int((1 - clip[1] / clip[3]) / 2 * vh)
    assert d.layer_depths[0, vy + row, vx + col] == pytest.approx(clip[3], rel=1e-3)


def test_sphere_errors_are_points_hidden_from_the_cluster_camera(gl, refl):
    """Mirror sphere among props: some reflected rays meet prop surfaces that the
    cluster cameras (centre e_c, not on those rays) do not see, so the thesis's error
    is > 0; where a hit is on a prop inside the cluster frustum, "captured" agrees with
    Embree's visibility of that point from e_c (the reflector removed, as the cluster
    image's first layer holds every other object) for ≥ 90 % of the points."""
    from reference.image_metrics import occlusion_error_percentage
    from reference.raycast import RayCaster
    from scenes import Scene

    ours, _, ref = _render_both(gl, refl, mirror_object_scene(sphere_mesh(), "sphere"))
    d = ours.diagnostics
    cap = _captured(ours, ref)
    mask = uncaptured_error_mask(ref.reflective_samples, ref.hit_points_samples, cap, 2)
    pct = occlusion_error_percentage(mask, ref.reflective)
    assert 0.0 < pct < 10.0, pct
    prop_caster = RayCaster(Scene(props(), name="props"))
    hits = ref.reflective_samples & np.isfinite(ref.hit_points_samples[..., 0]) & (d.cluster_of_sample >= 0)
    x, n = ref.hit_points_samples[hits], ref.hit_normals_samples[hits].astype(np.float64)
    k, c = d.cluster_of_sample[hits], cap[hits]
    on_prop = prop_caster.intersect(x + 1e-3 * n, -n, 2e-3).hit
    clip = np.einsum("mij,mj->mi", d.view_proj[k], np.c_[x, np.ones(len(x))])
    inside = (clip[:, 3] > 0) & np.all(np.abs(clip[:, :3] / clip[:, 3:]) <= 1, axis=1)
    visible = np.zeros(len(x), bool)
    for ci in np.unique(k):
        sel = np.nonzero(k == ci)[0]
        e = ours.cameras[ci].center
        v = x[sel] - e
        dist = np.linalg.norm(v, axis=1)
        h = prop_caster.cast_from(e, v / dist[:, None])
        visible[sel] = h.hit & (np.abs(h.t - dist) <= 0.01 * dist) & (np.sum(n[sel] * v, axis=1) < 0)
    use = inside & on_prop
    assert use.sum() > 1000 and (~c[use]).sum() > 0
    assert np.mean(c[use] == visible[use]) >= 0.9, np.mean(c[use] == visible[use])


@pytest.mark.parametrize("clustering", ["shading_bins", "default"])
def test_others_second_surface_captures_hidden_hits(gl, clustering):
    """Non-planar clusters' fourth layer (the other objects' second surface) holds
    true hits that their shifted camera e_c sees hidden behind another object: on
    two frames of each bench room the thesis occlusion error per reflected ray
    never rises with it; with the layer off the first three layers are unchanged
    and the fourth is empty. With the clustering the layer was measured with (bins
    of the shading normal, no components: "shading_bins") the error falls by more
    than half in total (0.73/0.90/1.83/8.41 % → 0.48/0.89/1.69/0.35 % when
    written); with the default clustering (mirror-normal bins split into
    components, issue 17), which already holds most of those hits in the first
    layer, it still falls in total."""
    from gl_passes.reflections import ClusterReflections, ClusterSettings
    from gl_passes.upload import SceneGPU
    from reference.reflections import raytrace_reflections
    from scenes.builtin import make_builtin
    from scenes.camera import flythrough_path

    base = ClusterSettings(bin_normal="shading", normal_break=0.0) if clustering == "shading_bins" \
        else ClusterSettings()
    rates = []
    with ClusterReflections(gl, base.replace(others_peel=False)) as off, ClusterReflections(gl, base) as on:
        for name in ("living_room", "bathroom"):
            scene = make_builtin(name)
            with SceneGPU(gl, scene) as sg:
                for frame in (1, 3):
                    cam = flythrough_path(scene.bounds, 8, width=64, height=64)[frame]
                    with4, with3 = on.render(sg, cam, diagnostics=True), off.render(sg, cam, diagnostics=True)
                    ref = raytrace_reflections(scene, cam)
                    for layer in range(3):
                        assert_images_equal(with4.diagnostics.layer_depths[layer],
                                            with3.diagnostics.layer_depths[layer], f"{name}_{frame}_layer{layer}")
                    for x, y, w, h in with3.diagnostics.viewports:
                        assert (with3.diagnostics.layer_depths[3, y:y + h, x:x + w] >= EMPTY_DEPTH).all()
                    rates.append([uncaptured_ray_percentage(ref.reflective_samples, ref.hit_points_samples,
                                                            _captured(o, ref)) for o in (with3, with4)])
    r = np.asarray(rates)
    assert np.all(r[:, 1] <= r[:, 0]), r
    assert r[:, 1].sum() < (0.5 if clustering == "shading_bins" else 1.0) * r[:, 0].sum(), r

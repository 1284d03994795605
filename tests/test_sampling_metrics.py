"""Alg. 2 (visibility redundancy) and the §2.3.2 sampling metrics on scenes
whose numbers can be counted by hand, by the Embree reference and (two tests) the GL
pixel-NR set."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gl_passes import depth_images
from gl_passes.upload import SceneGPU
from reference.raycast import RayCaster
from reference.sampling_metrics import evaluate_sets, sampling_metrics, texel_edge_distance
from reference.visibility import (
    conventional_reference,
    non_redundant_reference,
    non_redundant_visibility,
    visible_from,
)
from scenes.camera import Camera
from scenes.model import Scene, SceneObject
from tests.helpers import box

# --- the "strip" scene: counted by hand -------------------------------------------
#
# Cameras look down -Z from z = 10 with fov 90° and 8×8 pixels, so a pixel is 2.5
# units wide on the back plane B (z = 0, one big triangle) and 1.25 units on the
# plane z = 5, where the strip A (x in [-2.5, 2.5], every row) stands. V0 has its
# eye at x = 0, V1 at x = 5: a shift of exactly 2 pixels on B and 4 on A, so a
# sample of one camera reprojects onto a pixel centre of the other. Per row:
#   V0 columns: B(-8.75) B(-6.25) A A A A B(6.25) B(8.75)
#   V1 columns: A(0.625) A(1.875) B(1.25) B(3.75) B(6.25) B(8.75) B(11.25) B(13.75)
# V1's columns 0, 1 (A, seen by V0 at columns 4, 5) and 4, 5 (B at 6.25, 8.75,
# seen by V0 at columns 6, 7) are redundant under both definitions: 4 × 8 = 32.
# B at 1.25 and 3.75 (V1 columns 2, 3) project onto V0's A columns: not redundant;
# 11.25 and 13.75 fall outside V0's image. The non-redundant I_1 drops columns
# 4, 5 and looks behind A in columns 0, 1 (B at -3.75, -1.25: hidden from V0 and
# V1: occluded), so it holds 6 × 8 = 48 samples, 16 of them occluded.

RES = 8


def _quad(x0: float, x1: float, y0: float, y1: float, z: float) -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], np.float32)
    return v, np.array([[0, 1, 2], [0, 2, 3]], np.uint32)


def _back_plane() -> SceneObject:
    """B: the plane z = 0 as one triangle, CCW from +z."""
    b_v = np.array([[-100, -100, 0], [100, -100, 0], [0, 100, 0]], np.float32)
    return SceneObject("B", b_v, np.array([[0, 1, 2]], np.uint32))


def strip_scene() -> Scene:
    a_v, a_f = _quad(-2.5, 2.5, -30, 30, 5.0)
    return Scene([SceneObject("A", a_v, a_f), _back_plane()], name="strip")


def cam_at(x: float, res: int = RES, fov: float = 90.0) -> Camera:
    return Camera((x, 0.0, 10.0), (x, 0.0, 0.0), (0.0, 1.0, 0.0), fov, res, res)


@pytest.fixture(scope="module")
def strip():
    scene = strip_scene()
    rc = RayCaster(scene)
    cams = [cam_at(0.0), cam_at(5.0)]
    conv = conventional_reference(scene, cams, rc)
    nr = non_redundant_visibility(scene, cams, rc)
    return scene, rc, cams, conv, nr


def _columns(img) -> list[str]:
    """Per column of row 0: 'A', 'B' or '-' (no sample); rows are identical."""
    obj = {0: "-", 1: "A", 2: "A", 3: "B"}
    return [obj[int(t)] for t in img.tri_id[0]]


def test_strip_images_as_counted(strip):
    _, _, _, conv, nr = strip
    assert _columns(conv[0]) == list("BBAAAABB")
    assert _columns(conv[1]) == list("AABBBBBB")
    assert _columns(nr[0]) == list("BBAAAABB")
    assert _columns(nr[1]) == list("BBBB--BB")
    for img in conv + nr:  # every row identical
        assert np.all(img.tri_id == img.tri_id[0])
    # NR I_1 columns 0, 1 hold B behind A at x = -3.75, -1.25.
    np.testing.assert_allclose(nr[1].position[3, :2, 0], [-3.75, -1.25], atol=1e-4)
    np.testing.assert_allclose(nr[1].position[3, 2:4, 0], [1.25, 3.75], atol=1e-4)
    assert np.all(np.isinf(nr[1].depth[:, 4:6])) and np.all(np.isfinite(nr[1].depth[:, [0, 1, 2, 3, 6, 7]]))


@pytest.mark.parametrize("redundancy", ["pixel", "visibility"])
def test_strip_metrics_exact(strip, redundancy):
    scene, rc, _, conv, nr = strip
    # View at x = -5 sees B behind A over x in [-5, 0): both occluded columns are useful.
    # View at x = 2.5 (midpoint) sees none of them (A's shadow covers [-7.5, 2.5]).
    side, mid = [cam_at(-5.0)], [cam_at(2.5)]
    res = evaluate_sets(scene, {"conv": (conv, redundancy), "nr": (nr, redundancy)}, conv, side, caster=rc)
    c, n = res["conv"], res["nr"]
    assert c.samples == [64, 64] and c.redundant == [0, 32] and c.occluded == [0, 0] and c.useful == [0, 0]
    assert n.samples == [64, 48] and n.redundant == [0, 0] and n.occluded == [0, 16] and n.useful == [0, 16]
    assert c.redundant_frac == [0.0, 0.5] and n.useful_frac == [0.0, 1.0]
    # Thesis item 2 read literally: NR I_1 against C_0 only. Columns 0, 1 (hidden
    # from V0), 2, 3 (V0 sees A there) and 6, 7 (outside V0's image) are all not
    # captured by C_0: 48 occluded, of which the side view needs columns 0, 1.
    assert n.occluded_earlier == [0, 48] and n.useful_earlier == [0, 16]
    assert c.occluded_earlier == [0, 0] and c.useful_earlier == [0, 0]  # conventional: 0 by definition
    # Availability in the side view: its columns see B at -13.75, -11.25 (outside
    # both reference images), B at -8.75, -6.25 (V0: B), B at -3.75, -1.25 (hidden
    # from V0 and V1, held by NR I_1) and A at -1.875, -0.625 (V0: A).
    assert c.available == [0.5] and n.available == [0.75]
    m = sampling_metrics(scene, nr, conv, mid, redundancy=redundancy, caster=rc, keep_masks=True)
    assert m.occluded == [0, 16] and m.useful == [0, 0]
    assert m.occluded_masks[1][:, :2].all() and m.occluded_masks[1].sum() == 16
    assert not m.useful_masks[1].any()
    d = m.to_dict()
    assert d["total"]["samples"] == 112 and d["total"]["occluded"] == 16 and d["n_views"] == 1
    # The midpoint view sees B at 3.75 and 11.25 (its columns 4, 7): NR I_1's
    # columns 3 and 6, occluded under the literal reading only.
    assert d["total"]["occluded_earlier"] == 48 and d["total"]["useful_earlier"] == 16
    # An image from another viewpoint (as a peeling layer) is tested against all
    # conventional images under both readings.
    mid_img = conventional_reference(scene, mid, rc)
    o = sampling_metrics(scene, mid_img, conv, side, redundancy=redundancy, caster=rc)
    assert o.occluded_earlier == o.occluded and o.useful_earlier == o.useful


@pytest.mark.parametrize("redundancy", ["pixel", "visibility"])
def test_single_and_duplicated_images(strip, redundancy):
    scene, rc, _, conv, _ = strip
    one = sampling_metrics(scene, conv[:1], conv, [], redundancy=redundancy, caster=rc)
    assert one.redundant == [0] and one.occluded == [0] and one.available == []
    dup = sampling_metrics(scene, [conv[1], conv[1]], conv, [], redundancy=redundancy, caster=rc)
    assert dup.redundant == [0, 64]


def test_pixel_redundancy_edge_ties(strip):
    # A duplicated image: every sample of the copy reprojects onto a texel centre of
    # the original (0.5 texel from the edges): redundant, and no tie.
    scene, rc, _, conv, _ = strip
    dup = sampling_metrics(scene, [conv[1], conv[1]], conv, [], redundancy="pixel", caster=rc)
    assert dup.redundant == [0, 64] and dup.redundant_edge_ties == [0, 0]
    # Shift the copy's samples by half a pixel in x (B: 1.25 units at z = 0, A:
    # 0.625 at z = 5): each projects onto a texel edge (up to rounding), so it
    # falls in its own texel or the next one. Where that texel holds the same
    # triangle (at least B's columns 2-6, landing on B in 2-7) the sample counts
    # as redundant, but only as an edge tie.
    im = conv[1]
    pos = im.position.copy()
    on_a = pos[..., 2] > 2.5
    pos[..., 0] += np.where(on_a, 0.625, 1.25)
    shifted = replace(im, position=pos)
    m = sampling_metrics(scene, [im, shifted], conv, [], redundancy="pixel", caster=rc)
    assert m.redundant[0] == 0 and m.redundant[1] >= 5 * 8
    assert m.redundant_edge_ties == m.redundant
    assert m.to_dict()["redundant_edge_ties"] == m.redundant
    d = texel_edge_distance(im.camera, np.array([[6.25, 1.25, 0.0], [7.5, 1.25, 0.0]]))
    np.testing.assert_allclose(d, [0.5, 0.0], atol=1e-9)
    assert sampling_metrics(scene, [im, im], conv, [], redundancy="visibility", caster=rc).redundant_edge_ties is None


# --- Figs 11-12: boxes A, B, C, D -------------------------------------------------
#
# V0 at x = -2 and V1 at x = 2 look down -Z (fov 90°, so V0 sees B); C (x in [-0.5, 0.5], z in [-0.5, 0.5])
# is hidden from V0 by A (x in [-1.5, -0.5], z in [4.5, 5.5]) and from V1 by B
# (mirror image of A), but visible from the middle of the segment V0V1; D is a
# back wall at z = -2. B is visible from V0, so the NR image I_1 (Alg. 2) walks
# past B (redundant) and keeps C, which conventional I_1 misses (Figs 11-12).


def _box(name: str, lo, hi) -> SceneObject:
    """An axis-aligned box of 8 shared corners, in another vertex order than
    tests.helpers.box (each side its own vertices). The cameras below send rays
    exactly through silhouette edges of A and B (e.g. from x = -2 through x = -1.5,
    y = 1.5 at z = 5.43), where a front and a back face meet at the same t: the
    boxes fixture runs with both builders, so that how Embree breaks those ties
    cannot decide a sample's visibility from its own camera."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    v = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                  [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], np.float32)
    f = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
                  [3, 7, 6], [3, 6, 2], [0, 4, 7], [0, 7, 3], [1, 2, 6], [1, 6, 5]], np.uint32)
    return SceneObject(name, v, f)  # outward normals (CCW seen from outside)


def boxes_scene(make_box=_box) -> Scene:
    return Scene([
        make_box("A", (-1.5, -1.5, 4.5), (-0.5, 1.5, 5.5)),
        make_box("B", (0.5, -1.5, 4.5), (1.5, 1.5, 5.5)),
        make_box("C", (-0.5, -1.0, -0.5), (0.5, 1.0, 0.5)),
        make_box("D", (-10.0, -6.0, -3.0), (10.0, 6.0, -2.0)),
    ], name="abcd")


@pytest.fixture(scope="module", params=[_box, box], ids=["shared_corners", "helpers_box"])
def boxes(request):
    scene = boxes_scene(request.param)
    rc = RayCaster(scene)
    cams = [Camera((x, 0.0, 10.0), (x, 0.0, 0.0), (0.0, 1.0, 0.0), 90.0, 64, 64) for x in (-2.0, 2.0)]
    conv = conventional_reference(scene, cams, rc)
    nr = non_redundant_visibility(scene, cams, rc)
    views = [Camera((x, 0.0, 10.0), (x, 0.0, 0.0), (0.0, 1.0, 0.0), 90.0, 64, 64) for x in np.linspace(-1.5, 1.5, 7)]
    return scene, rc, cams, conv, nr, views


def _obj(scene: Scene, img) -> np.ndarray:
    o = np.zeros(img.tri_id.shape, np.int64)
    m = img.tri_id > 0
    o[m] = scene.face_object[img.tri_id[m].astype(np.int64) - 1]
    return o


def test_boxes_c_hidden_and_captured_by_nr(boxes):
    scene, rc, cams, conv, nr, views = boxes
    c_id = 3
    assert not (_obj(scene, conv[0]) == c_id).any() and not (_obj(scene, conv[1]) == c_id).any()
    assert (_obj(scene, nr[1]) == c_id).sum() > 10
    # NR image 0 is the plain ray cast.
    np.testing.assert_array_equal(nr[0].tri_id, conv[0].tri_id)
    # Every sample NR I_1 keeps is invisible from V0 (Alg. 2), and it keeps the
    # nearest such hit: where I_1 is non-empty and conventional I_1 is not visible
    # from V0, the two agree.
    m = nr[1].mask
    assert not visible_from(rc, cams[0], nr[1].position[m], nr[1].tri_id[m]).any()
    cm = conv[1].mask
    hidden = np.zeros_like(cm)
    hidden[cm] = ~visible_from(rc, cams[0], conv[1].position[cm], conv[1].tri_id[cm])
    np.testing.assert_array_equal(nr[1].tri_id[hidden], conv[1].tri_id[hidden])
    # Shading and buffers follow the gbuffer conventions.
    g = rc.gbuffer(cams[1].fit_clip(scene.bounds))
    np.testing.assert_allclose(nr[1].color[hidden], g.color[hidden], atol=1e-6)
    assert np.all(np.isinf(nr[1].depth[~m]))


def test_boxes_metrics(boxes):
    scene, rc, cams, conv, nr, views = boxes
    res = evaluate_sets(scene, {"conv": (conv, "visibility"), "nr": (nr, "visibility"),
                                "conv_px": (conv, "pixel")}, conv, views, caster=rc, keep_masks=True)
    c, n = res["conv"], res["nr"]
    assert n.redundant == [0, 0]  # visibility-NR images have no visibility-redundant samples
    assert c.redundant[0] == 0 and c.redundant[1] > 0 and c.occluded == [0, 0]
    assert res["conv_px"].occluded == [0, 0]
    c_mask = _obj(scene, nr[1]) == 3
    assert n.occluded_masks[1][c_mask].all()  # C's samples are occluded...
    assert n.useful_masks[1][c_mask].mean() > 0.5  # ...and mostly needed by the middle views
    assert n.useful[1] > 0 and n.useful[1] <= n.occluded[1]
    assert n.available_avg >= c.available_avg and n.available_min >= c.available_min
    assert n.available_avg > c.available_avg  # the middle views see C
    assert len(n.available) == len(views) and 0.0 < n.available_min <= n.available_avg <= 1.0


@pytest.mark.parametrize("redundancy", ["pixel", "visibility"])
def test_sets_evaluated_together_or_alone_agree(boxes, redundancy):
    # The benchmark evaluates conventional, NR and peeling sets in one call (shared
    # intermediate frames, shared layer walks along the reference cameras): sharing
    # must not change any set's numbers, and every set is measured against the same
    # conventional images (metric 2), whichever viewpoints the set itself uses.
    scene, rc, cams, conv, nr, views = boxes
    mid = Camera((0.0, 0.0, 10.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 90.0, 64, 64)
    other = conventional_reference(scene, [mid, cams[1]], rc)  # a set from another viewpoint, like peeling
    sets = {"conv": (conv, redundancy), "nr": (nr, redundancy), "other": (other, redundancy)}
    joint = evaluate_sets(scene, sets, conv, views, caster=rc)
    for name, (images, red) in sets.items():
        alone = sampling_metrics(scene, images, conv, views, redundancy=red, caster=rc)
        assert joint[name].to_dict() == alone.to_dict(), name
    # the midpoint view sees C, which no conventional image holds: occluded and useful
    assert joint["other"].occluded[0] > 0 and joint["other"].useful[0] == joint["other"].occluded[0]


def test_bad_redundancy(strip):
    scene, rc, _, conv, _ = strip
    with pytest.raises(ValueError):
        sampling_metrics(scene, conv, conv, [], redundancy="strict", caster=rc)


def test_gl_pixel_nr_has_no_pixel_redundancy(gl, boxes):
    scene, rc, cams, _, _, _ = boxes
    with SceneGPU(gl, scene) as sg:
        conv = depth_images.conventional(gl, sg, cams)
        nr = depth_images.non_redundant(gl, sg, cams)
    m = sampling_metrics(scene, nr, conv, [], redundancy="pixel", caster=rc)
    assert m.redundant[0] == 0 and m.redundant[1] <= 0.002 * m.samples[1]
    # C is captured by pixel-NR too (Fig. 12, first column).
    assert (_obj(scene, nr[1]) == 3).sum() > 10


# --- the "offset" scene: Alg. 3 decides a whole texel by its centre ----------------
#
# Same back plane B and camera set-up as the strip scene, with a thin bar A at
# z = 5, x in [1.45, 2.05], and V1 at x = 3.125 (a shift of 1.25 pixels on B, so
# V1's texel centres reproject 0.75 texel into V0's texels). On B a pixel of V0
# covers [-10 + 2.5c, -7.5 + 2.5c); V1's column k covers [-6.875 + 2.5k, ...) with
# its centre at -5.625 + 2.5k. V0's centre ray of column 5 meets A (at x = 1.875
# on z = 5); no other centre ray of V0 or V1 does, so C_0 = B B B B B A B B and
# C_1 is all B. Pixel-NR I_1 keeps only the columns whose centre reprojects onto
# a V0 texel without B: column 4 (B at 4.375 → V0 column 5, A) and column 7
# (B at 11.875, outside V0); nothing lies behind B, so the other six are empty.
# The midpoint view (x = 1.5625) sees B at -7.1875 + 2.5k in every column. Its
# column 4 (B at 2.8125) reprojects into V0 column 5 (A) and into V1 column 3,
# which C_1 holds but I_1 dropped: its centre (B at 1.875) reprojects into V0
# column 4, which holds B. Column 7 (B at 10.3125, outside V0) falls in V1
# column 6, dropped the same way. So the conventional set makes the whole frame
# available and the non-redundant set 6 of 8 columns, although I_1 has no
# redundant sample: a property of Alg. 3's texel granularity, not of an
# implementation. Under Alg. 2 both sets make the frame available (B at 2.8125
# is visible from V0; the view's column 7 is V1's layer 0).


def offset_scene() -> Scene:
    a_v, a_f = _quad(1.45, 2.05, -30, 30, 5.0)
    return Scene([SceneObject("A", a_v, a_f), _back_plane()], name="offset")


@pytest.fixture(scope="module")
def offset():
    scene = offset_scene()
    rc = RayCaster(scene)
    cams = [cam_at(0.0), cam_at(3.125)]
    return scene, rc, cams, conventional_reference(scene, cams, rc)


def test_pixel_nr_loses_availability_by_texel_granularity(offset):
    scene, rc, cams, conv = offset
    assert _columns(conv[0]) == list("BBBBBABB") and _columns(conv[1]) == list("BBBBBBBB")
    nr = non_redundant_reference(scene, cams, "pixel", rc)
    assert _columns(nr[0]) == _columns(conv[0]) and _columns(nr[1]) == list("----B--B")
    mid = [cam_at(1.5625)]
    res = evaluate_sets(scene, {"conv": (conv, "pixel"), "nr": (nr, "pixel")}, conv, mid, caster=rc)
    assert res["nr"].redundant == [0, 0] and res["conv"].redundant == [0, 48]
    assert res["conv"].available == [1.0] and res["nr"].available == [0.75]
    vis = non_redundant_visibility(scene, cams, rc)
    assert _columns(vis[1]) == list("-------B")
    res = evaluate_sets(scene, {"conv": (conv, "visibility"), "nr": (vis, "visibility")}, conv, mid, caster=rc)
    assert res["conv"].available == [1.0] and res["nr"].available == [1.0]


def test_gl_pixel_nr_offset_scene_as_counted(gl, offset):
    scene, _, cams, _ = offset
    with SceneGPU(gl, scene) as sg:
        nr = depth_images.non_redundant(gl, sg, cams)
    assert _columns(nr[0]) == list("BBBBBABB") and _columns(nr[1]) == list("----B--B")


@pytest.mark.parametrize("centre", [0.0, 1e4])
def test_every_sample_is_visible_from_its_own_camera_far_from_the_origin(centre):
    """A tilted quad (two triangles sharing a diagonal) 1e4 from the origin: the
    float32 positions a depth image stores lie up to ~5e-4 off their plane, so an
    occlusion segment to one can cross the plane early, on the other triangle.
    That triangle is in the sample's plane, not an occluder: every sample of the
    conventional image is visible from its own camera (it lost one before)."""
    c = np.full(3, centre)
    e1, e2 = np.array([1.0, 0.0, -0.3]), np.array([0.0, 1.0, -0.2])
    v = np.array([c - e1 / 2 - e2 / 2, c + e1 / 2 - e2 / 2, c + e1 / 2 + e2 / 2, c - e1 / 2 + e2 / 2])
    scene = Scene([SceneObject("quad", v, np.array([[0, 1, 2], [0, 2, 3]]))])
    rc = RayCaster(scene)
    cam = Camera(tuple(c + np.array([-0.8, 0.5, 1.0])), tuple(c), (0.0, 1.0, 0.0), 60.0, 128, 128)
    image = conventional_reference(scene, [cam], rc)[0]
    m = image.mask
    assert m.sum() > 4000
    assert visible_from(rc, image.camera, image.position[m], image.tri_id[m]).all()

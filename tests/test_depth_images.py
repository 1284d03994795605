"""Depth-image sets (thesis Ch. 2): conventional, non-redundant (Alg. 1 with the
pixel-redundancy test of Alg. 3), depth peeling, and the Fig. 8 camera rig.

The Figs. 11-12 example is built as a small 3-D scene of four boxes seen from
two viewpoints V0, V1 (x = ∓3, z = 10, looking at the origin): C is hidden
from V0 by D and from V1 by B, and doubly hidden (behind A, then B) from their
midpoint, the peeling viewpoint; an intermediate viewpoint sees it.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.ndimage import binary_erosion

from gl_passes import depth_images as di
from gl_passes.gbuffer import GBufferPass
from gl_passes.upload import SceneGPU
from reference.raycast import RayCaster
from scenes import Camera, Material, Scene, SceneObject
from scenes.camera import box_corners
from scenes.depth_image import DepthImage
from scenes.rig import fig8_rig, fit_distance, intermediate_views
from service.image_check import assert_images_close
from tests.gl_leaks import gl_object_growth
from tests.helpers import assert_depth_close, assert_images_equal, box, figure11_scene

RES = 160  # reference images of the Fig. 11 scene
A, B, C, D = 1, 2, 3, 4  # object ids in figure11_scene()


# --- scenes and cameras ----------------------------------------------------------------

def fig11_camera(x: float, res: int = RES) -> Camera:
    return Camera((x, 0.0, 10.0), (0.0, 0.0, 0.0), fov=40.0, width=res, height=res)


def cluttered_scene() -> Scene:
    """A sphere among seeded random boxes on a slab: many occlusion layers."""
    rng = np.random.default_rng(3)
    s = trimesh.creation.icosphere(3, radius=0.8)
    objs = [SceneObject("sphere", s.vertices, s.faces, material=Material((0.8, 0.4, 0.2)))]
    objs.append(box("slab", (-3, -1.2, -3), (3, -1.0, 3)))
    for k in range(10):
        c = rng.uniform([-2.5, -1.0, -2.5], [2.5, 0.5, 2.5])
        e = rng.uniform(0.2, 0.8, 3)
        objs.append(box(f"box{k}", c - e / 2, c + e / 2, tuple(rng.uniform(0.2, 0.9, 3))))
    return Scene(objs, name="cluttered")


# --- numpy checks ----------------------------------------------------------------------

def object_ids(scene: Scene, tri_id: np.ndarray) -> np.ndarray:
    out = np.zeros(tri_id.shape, np.int64)
    m = tri_id > 0
    out[m] = scene.face_object[tri_id[m].astype(np.int64) - 1]
    return out


def lookup(image: DepthImage, points: np.ndarray, margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(inside, tri id at the texel) of world points projected into `image`
    (pixel-redundancy lookup of Alg. 3). inside also requires the point to be at
    least `margin` pixels from a texel edge, so float rounding cannot flip it."""
    cam = image.camera
    px, z = cam.project(points)
    inside = (z >= cam.near) & (z <= cam.far) & (px[:, 0] >= 0) & (px[:, 0] < cam.width) \
        & (px[:, 1] >= 0) & (px[:, 1] < cam.height)
    if margin:
        frac = px - np.floor(px)
        inside &= np.all((frac > margin) & (frac < 1 - margin), axis=1)
    tri = np.zeros(len(points), np.uint32)
    cols, rows = np.floor(px[inside]).astype(int).T
    tri[inside] = image.tri_id[rows, cols]
    return inside, tri


def redundant_samples(images: list[DepthImage], margin: float = 1e-2) -> list[int]:
    """Per image i: samples pixel-redundant with some I_j, j < i (§2.3.2 metric 1)."""
    counts = []
    for i, im in enumerate(images):
        pts, tris = im.position[im.mask].astype(np.float64), im.tri_id[im.mask]
        red = np.zeros(len(pts), bool)
        for prev in images[:i]:
            inside, t = lookup(prev, pts, margin)
            red |= inside & (t == tris)
        counts.append(int(red.sum()))
    return counts


def available(images: list[DepthImage], points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(N,) bool: the output sample (point on triangle tris) is pixel-redundant
    with some image of the set (§2.3.2 metric 4, "available")."""
    ok = np.zeros(len(points), bool)
    for im in images:
        inside, t = lookup(im, points)
        ok |= inside & (t == tris)
    return ok


def splat(images: list[DepthImage], cam: Camera) -> np.ndarray:
    """Point-splat reconstruction: every sample of the set projected into `cam`,
    nearest per pixel wins. Returns the triangle ids (H,W)."""
    pts = np.concatenate([im.position[im.mask] for im in images]).astype(np.float64)
    tris = np.concatenate([im.tri_id[im.mask] for im in images])
    px, z = cam.project(pts)
    ok = (z > 0) & (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) & (px[:, 1] < cam.height)
    pix = np.floor(px[ok, 1]).astype(int) * cam.width + np.floor(px[ok, 0]).astype(int)
    order = np.lexsort((z[ok], pix))  # by pixel, then nearest first
    first = np.unique(pix[order], return_index=True)[1]
    out = np.zeros(cam.width * cam.height, np.uint32)
    out[pix[order][first]] = tris[ok][order][first]
    return out.reshape(cam.height, cam.width)


def cross2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def assert_real_front_facing_samples(scene: Scene, images: list[DepthImage], conv: list[DepthImage]) -> None:
    """Each sample lies on its triangle where the pixel's centre ray meets it, the
    triangle faces the camera, and it is no nearer than the conventional sample."""
    v = scene.vertices.astype(np.float64)
    f = scene.faces.astype(np.int64)
    for im, cv in zip(images, conv, strict=True):
        cam = im.camera
        rows, cols = np.nonzero(im.mask)
        tri = v[f[im.tri_id[rows, cols].astype(np.int64) - 1]]  # (N,3,3)
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        p = im.position[rows, cols].astype(np.float64)
        eye = np.asarray(cam.eye)
        assert np.abs(np.einsum("ij,ij->i", p - tri[:, 0], n)).max() < 1e-4 * scene.diagonal
        assert (np.einsum("ij,ij->i", eye - p, n) > 0).all(), "back-facing sample"
        d = cam.pixel_directions()[rows, cols]
        t = np.einsum("ij,ij->i", tri[:, 0] - eye, n) / np.einsum("ij,ij->i", d, n)
        hit = eye + t[:, None] * d
        np.testing.assert_allclose(t * (d @ cam.basis()[2]), im.depth[rows, cols], rtol=2e-5)
        np.testing.assert_allclose(hit, p, atol=1e-4 * scene.diagonal)
        # The pixel centre is inside the projected triangle (≤ 0.05 px outside an
        # edge: rounding on triangles seen edge-on).
        q = np.stack([cam.project(tri[:, k])[0] for k in range(3)], axis=1)  # (N,3,2) pixels
        centre = np.stack([cols, rows], axis=1) + 0.5
        area = cross2(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0])
        for k in range(3):
            a, b = q[:, k], q[:, (k + 1) % 3]
            length = np.maximum(np.linalg.norm(b - a, axis=1), 1e-9)
            assert (np.sign(area) * cross2(b - a, centre - a) / length).min() > -0.05
        assert (im.depth[rows, cols] >= cv.depth[rows, cols] * (1 - 1e-6)).all()


# --- fixtures --------------------------------------------------------------------------

@pytest.fixture(scope="module")
def fig11(gl):
    scene = figure11_scene()
    cams = [fig11_camera(-3.0), fig11_camera(3.0)]
    peel_cam = fig11_camera(0.0)
    with SceneGPU(gl, scene) as sg, di.DepthImageRenderer(gl) as r:
        return {
            "scene": scene, "cams": cams, "peel_cam": peel_cam,
            "conv": di.conventional(gl, sg, cams, renderer=r),
            "nr": di.non_redundant(gl, sg, cams, renderer=r),
            "peel": di.depth_peeling(gl, sg, peel_cam, 3, renderer=r),
            "conv_peel": di.conventional(gl, sg, [peel_cam], renderer=r)[0],
        }


@pytest.fixture(scope="module")
def clutter(gl):
    scene = cluttered_scene()
    cams, peel_cam = fig8_rig(scene.bounds, 96, 96, spread_deg=25.0, distance=0.9)
    with SceneGPU(gl, scene) as sg:
        yield {"scene": scene, "sg": sg, "cams": cams, "peel_cam": peel_cam,
               "conv": di.conventional(gl, sg, cams), "nr": di.non_redundant(gl, sg, cams),
               "peel": di.depth_peeling(gl, sg, peel_cam, 3)}


# --- Figs. 11-12 -----------------------------------------------------------------------

def test_fig11_scene_is_the_figure(fig11):
    """Preconditions, by Embree: C hidden from V0, V1 and the peeling view,
    visible from an intermediate view; each box is one object."""
    scene = fig11["scene"]
    rc = RayCaster(scene)
    for cam in (*fig11["cams"], fig11["peel_cam"]):
        assert not (object_ids(scene, rc.gbuffer(cam.fit_clip(scene.bounds)).tri_id) == C).any()
    mid = rc.gbuffer(fig11_camera(-1.8, 96).fit_clip(scene.bounds))
    assert (object_ids(scene, mid.tri_id) == C).sum() > 40


def test_fig11_nr_captures_C_conventional_and_peeling_do_not(fig11):
    scene = fig11["scene"]
    conv_obj = [object_ids(scene, im.tri_id) for im in fig11["conv"]]
    nr_obj = [object_ids(scene, im.tri_id) for im in fig11["nr"]]
    peel_obj = [object_ids(scene, im.tri_id) for im in fig11["peel"]]
    # Fig. 12: I0 holds the fronts of A and D (and the part of B seen from V0).
    assert {A, D} <= set(np.unique(nr_obj[0])) and not (nr_obj[0] == C).any()
    # Non-redundant I1 holds B's part unseen from V0 and C; conventional I1 only B.
    assert (nr_obj[1] == C).sum() > 100 and (nr_obj[1] == B).sum() > 100
    assert not any((o == C).any() for o in conv_obj)
    assert (conv_obj[1] == B).sum() > (nr_obj[1] == B).sum()
    # Peeling from the midpoint: C is behind A and B, so two layers miss it and
    # only the third layer reaches it.
    assert not (peel_obj[0] == C).any() and not (peel_obj[1] == C).any()
    assert (peel_obj[1] == B).sum() > 100
    assert (peel_obj[2] == C).sum() > 100


def test_fig11_intermediate_view_has_no_hole_at_C(fig11):
    """Output view at 20 % of V0V1: its Embree-visible C front pixels are available in
    the NR set (metric 4) and a point-splat reconstruction shows C there; the
    conventional set and two peeled layers leave a hole."""
    scene = fig11["scene"]
    cam = fig11_camera(-1.8, 96).fit_clip(scene.bounds)
    gt = RayCaster(scene).gbuffer(cam)
    # C's front (+z) face: its side face seen here faces away from V1 and is
    # behind D from V0, so no pixel-redundancy set over V0, V1 can hold it.
    c_mask = (object_ids(scene, gt.tri_id) == C) & (gt.normal[..., 2] > 0.99)
    inner = binary_erosion(c_mask)  # away from C's silhouette (edge pixels sample coverage)
    assert inner.sum() > 20
    pts, tris = gt.position[c_mask].astype(np.float64), gt.tri_id[c_mask]
    sets = {"nr": fig11["nr"], "conv": fig11["conv"], "peel2": fig11["peel"][:2]}
    avail = {k: available(v, pts, tris) for k, v in sets.items()}
    assert avail["nr"][inner[c_mask]].mean() >= 0.98 and avail["nr"].mean() >= 0.9, avail["nr"].mean()
    assert not avail["conv"].any() and not avail["peel2"].any()
    shown = {k: (object_ids(scene, splat(v, cam))[inner] == C).mean() for k, v in sets.items()}
    assert shown["nr"] >= 0.98 and shown["conv"] == 0 and shown["peel2"] == 0, shown


# --- non-redundant images ----------------------------------------------------------------

@pytest.mark.parametrize("which", ["fig11", "clutter"])
def test_nr_image0_is_the_conventional_image(which, request):
    s = request.getfixturevalue(which)
    c0, n0 = s["conv"][0], s["nr"][0]
    np.testing.assert_array_equal(n0.tri_id, c0.tri_id)
    assert_images_equal(n0.depth, c0.depth, "depth")
    assert_images_equal(n0.color, c0.color, "color")
    assert n0.camera == c0.camera and n0.camera.near is not None


@pytest.mark.parametrize("which", ["fig11", "clutter"])
def test_nr_images_have_no_pixel_redundant_samples(which, request):
    s = request.getfixturevalue(which)
    nr, conv = s["nr"], s["conv"]
    assert redundant_samples(nr) == [0] * len(nr)
    # The margin only skips samples within 1/100 px of a texel edge: a handful.
    assert redundant_samples(nr, margin=0.0)[1:] <= [max(2, im.n_samples // 1000) for im in nr[1:]]
    # Conventional images of the same views are heavily redundant.
    assert all(r > 0.2 * im.n_samples for r, im in zip(redundant_samples(conv)[1:], conv[1:], strict=True))


@pytest.mark.parametrize("which", ["fig11", "clutter"])
def test_nr_samples_are_real_front_facing_surface_points(which, request):
    s = request.getfixturevalue(which)
    assert_real_front_facing_samples(s["scene"], s["nr"], s["conv"])
    # NR samples differ from the conventional ones only where those are redundant.
    for im, cv in zip(s["nr"][1:], s["conv"][1:], strict=True):
        changed = im.tri_id != cv.tri_id
        assert changed.any()
        assert (im.depth[changed & im.mask] > cv.depth[changed & im.mask]).all()


def test_conventional_matches_gbuffer_and_embree(gl, clutter):
    scene, sg = clutter["scene"], clutter["sg"]
    rc = RayCaster(scene)
    every = {"max_bad_fraction": 0.0}  # every pixel within the tolerance
    with GBufferPass(gl) as gp:
        for k, im in enumerate(clutter["conv"]):
            g = gp.render(sg, im.camera)
            np.testing.assert_array_equal(im.tri_id, g.tri_id)
            m = im.mask
            assert_depth_close(im.depth, g.depth, 1e-5, mask=m, name=f"log_depth_{k}")
            assert_images_close(im.color, g.color, tolerance=1e-5, mask=m, name=f"color_{k}", **every)
            assert_images_close(im.normal, g.normal, tolerance=1e-5, mask=m, name=f"normal_{k}", **every)
            assert_images_close(im.position, g.position, tolerance=1e-5 * scene.diagonal, mask=m,
                                name=f"position_{k}", **every)
            assert not im.color[~m].any() and not im.position[~m].any() and np.isinf(im.depth[~m]).all()
            r = rc.gbuffer(im.camera)
            assert (r.tri_id == im.tri_id).mean() > 0.99


@pytest.mark.parametrize("which", ["fig11", "clutter"])
def test_pixel_nr_matches_the_embree_reference(which, request):
    """Alg. 1 + Alg. 3 by Embree (reference.visibility.non_redundant_reference):
    the same nearest non-redundant samples as the fragment shader's, except at
    the few pixels where GL and Embree pick different triangles on an edge."""
    from reference.visibility import non_redundant_reference

    s = request.getfixturevalue(which)
    nr = s["nr"]
    ref = non_redundant_reference(s["scene"], [im.camera for im in nr], "pixel")
    for a, b in zip(nr, ref, strict=True):
        assert a.camera == b.camera
        same = a.tri_id == b.tri_id
        assert same.mean() >= 0.995
        assert_depth_close(a.depth, b.depth, 1e-5, mask=same & a.mask)
    if which == "fig11":  # the reference captures C in I1 too
        assert (object_ids(s["scene"], ref[1].tri_id) == C).sum() > 50
        with pytest.raises(ValueError, match="redundancy must be one of"):
            non_redundant_reference(s["scene"], [im.camera for im in nr], "texel")


def test_projection_and_triangle_id_variants_agree(gl, clutter):
    """Per-vertex vs per-fragment reprojection, gl_PrimitiveID vs geometry shader."""
    sg, cams = clutter["sg"], clutter["cams"]
    ref = clutter["nr"]
    for vs, geom in ((False, False), (True, True)):
        with di.DepthImageRenderer(gl, vs_project=vs, tri_from_geom=geom) as r:
            out = di.non_redundant(gl, sg, cams, renderer=r)
        for a, b in zip(out, ref, strict=True):
            assert (a.tri_id != b.tri_id).sum() <= 2


def test_sixteen_images_and_limits(gl, clutter):
    sg, scene = clutter["sg"], clutter["scene"]
    lo, hi = scene.bounds
    eyes = [tuple(scene.center + 1.2 * scene.diagonal * np.array([np.cos(a), 0.4, np.sin(a)]))
            for a in np.linspace(0, 2 * np.pi, 16, endpoint=False)]
    cams = [Camera(e, tuple(scene.center), fov=50.0, width=24, height=24) for e in eyes]
    nr = di.non_redundant(gl, sg, cams, res=20)
    assert len(nr) == 16 and all(im.tri_id.shape == (20, 20) for im in nr)
    assert all(im.camera.near is not None and im.camera.width == 20 for im in nr)
    assert redundant_samples(nr) == [0] * 16
    assert sum(im.n_samples for im in nr[8:]) > 0
    with pytest.raises(ValueError):
        di.non_redundant(gl, sg, cams + cams[:1])


def test_visibility_redundancy_is_the_reference_set(fig11):
    """Alg. 2 (visibility redundancy) is Embree's, called by the caller (gl_passes
    never imports reference): its image 0 is the conventional image, image 1 holds C."""
    from reference.visibility import non_redundant_visibility

    scene = fig11["scene"]
    vis = non_redundant_visibility(scene, fig11["cams"])
    assert len(vis) == 2 and all(isinstance(im, DepthImage) for im in vis)
    assert (vis[0].tri_id == fig11["conv"][0].tri_id).mean() > 0.99
    assert (object_ids(scene, vis[1].tri_id) == C).sum() > 100


# --- depth peeling -----------------------------------------------------------------------

@pytest.mark.parametrize("which", ["fig11", "clutter"])
def test_peeling_layers(which, request, gl):
    s = request.getfixturevalue(which)
    peel = s["peel"]
    conv = s["conv_peel"] if "conv_peel" in s else di.conventional(gl, s["sg"], [s["peel_cam"]])[0]
    np.testing.assert_array_equal(peel[0].tri_id, conv.tri_id)
    assert_images_equal(peel[0].depth, conv.depth, "depth")
    for prev, cur in zip(peel[:-1], peel[1:], strict=True):
        m = cur.mask
        assert m.any() and not (m & ~prev.mask).any()
        assert (cur.depth[m] > prev.depth[m]).all()
        assert not (cur.tri_id[m] == prev.tri_id[m]).any()
    assert_real_front_facing_samples(s["scene"], peel, [conv] * len(peel))


def test_two_sided_peeling_peels_back_faces(gl, fig11):
    """cull_back_faces=False (the benchmark's variant of what the thesis's peeling
    numbers suggest): on the closed boxes, layer 0 is unchanged, and behind A's
    front face layer 1 holds A again (its back face, normal away from the eye),
    where the culled layer 1 holds B or nothing."""
    scene, cam = fig11["scene"], fig11["peel_cam"]
    with SceneGPU(gl, scene) as sg, di.DepthImageRenderer(gl, cull_back_faces=False) as r:
        two = di.depth_peeling(gl, sg, cam, 2, renderer=r)
    culled = fig11["peel"]
    np.testing.assert_array_equal(two[0].tri_id, culled[0].tri_id)
    behind_a = object_ids(scene, two[0].tri_id) == A
    assert behind_a.sum() > 100
    assert (object_ids(scene, two[1].tri_id)[behind_a] == A).all()
    assert not (object_ids(scene, culled[1].tri_id)[behind_a] == A).any()
    v, f = scene.vertices.astype(np.float64), scene.faces.astype(np.int64)
    tri = v[f[two[1].tri_id[behind_a].astype(np.int64) - 1]]  # (N,3,3)
    face_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    to_eye = np.asarray(cam.eye) - two[1].position[behind_a]
    assert (np.einsum("ij,ij->i", face_n, to_eye) < 0).all()  # back faces (the stored normal faces the eye)


# --- resources ---------------------------------------------------------------------------

def test_non_redundant_20_times_does_not_grow_gl_objects():
    """A fresh context: live GL objects are unchanged after 20 more
    non_redundant + peeling calls at varying sizes."""
    cams = [fig11_camera(-3.0, 24), fig11_camera(3.0, 24), fig11_camera(0.0, 24)]

    def setup(gl):
        sg = SceneGPU(gl, figure11_scene())
        di.non_redundant(gl, sg, cams)
        di.depth_peeling(gl, sg, cams[2], 2)
        return sg

    def frame(sg, k):
        di.non_redundant(sg.gl, sg, cams, res=16 + 4 * (k % 3))
        di.depth_peeling(sg.gl, sg, cams[2], 2)

    before, after = gl_object_growth(setup, frame, 20)
    assert before > 0
    assert after == before


def test_a_kept_renderer_holds_the_targets_of_its_last_sizes_only():
    """One renderer kept across sets of ten sizes, as a render worker keeps it:
    live GL objects after the last set equal those after the first KEPT_SIZES
    sizes (the targets of older sizes are freed), for each kind of set."""
    cams = [fig11_camera(-3.0, 24), fig11_camera(3.0, 24), fig11_camera(0.0, 24)]

    class State:
        def __init__(self, gl) -> None:
            self.gl, self.sg, self.r = gl, SceneGPU(gl, figure11_scene()), di.DepthImageRenderer(gl)
            for k in range(-di.KEPT_SIZES, 0):
                self.frame(k)

        def frame(self, k: int) -> None:
            res = 17 + k
            di.non_redundant(self.gl, self.sg, cams, res=res, renderer=self.r)
            di.conventional(self.gl, self.sg, cams, res=res, renderer=self.r)
            di.depth_peeling(self.gl, self.sg, cams[2], 2, res=res, renderer=self.r)

        def release(self) -> None:
            self.r.release()
            self.sg.release()

    before, after = gl_object_growth(State, State.frame, 10)
    assert after == before


# --- the Fig. 8 rig ------------------------------------------------------------------------

def test_fig8_rig_geometry():
    lo, hi = np.array([-1.0, 0.0, -2.0]), np.array([1.0, 2.0, 2.0])
    c, diag = (lo + hi) / 2, np.linalg.norm(hi - lo)
    cams, peel = fig8_rig((lo, hi), 64, 48, spread_deg=20.0, distance=1.5)
    assert len(cams) == 3
    eyes = np.array([cam.eye for cam in cams])
    np.testing.assert_allclose(np.linalg.norm(eyes - c, axis=1), 1.5 * diag)
    for cam in (*cams, peel):
        np.testing.assert_allclose(cam.target, c)
        assert (cam.width, cam.height) == (64, 48) and cam.near is not None
    # Eyes 20° off the rig axis (the centroid direction), 120° apart around it.
    axis = (eyes.mean(axis=0) - c) / np.linalg.norm(eyes.mean(axis=0) - c)
    dirs = (eyes - c) / np.linalg.norm(eyes - c, axis=1, keepdims=True)
    np.testing.assert_allclose(np.degrees(np.arccos(dirs @ axis)), 20.0, atol=1e-9)
    np.testing.assert_allclose(peel.eye, eyes.mean(axis=0))
    sides = np.linalg.norm(eyes - np.roll(eyes, 1, axis=0), axis=1)
    np.testing.assert_allclose(sides, sides[0])


def test_fig8_rig_default_distance_fits_the_box_in_every_view():
    expected = 0.5 / (np.sin(np.radians(22.5)) * np.cos(np.radians(20)))
    assert fit_distance(45.0, 512, 512, 20.0) == pytest.approx(expected)
    assert fit_distance(45.0, 512, 512, 20.0) == pytest.approx(1.3904, abs=1e-4)
    assert fit_distance(45.0, 512, 512) == pytest.approx(1.3066, abs=1e-4)  # one camera
    # Wider than tall: the vertical fov limits; taller than wide: the horizontal one.
    assert fit_distance(45.0, 640, 480) == fit_distance(45.0, 512, 512)
    assert fit_distance(45.0, 480, 640) > fit_distance(45.0, 512, 512)
    lo, hi = np.array([-1.0, 0.0, -2.0]), np.array([1.0, 0.5, 2.0])
    c, diag = (lo + hi) / 2, np.linalg.norm(hi - lo)
    for w, h in ((64, 64), (64, 40), (40, 64)):
        cams, peel = fig8_rig((lo, hi), w, h)
        d = fit_distance(45.0, w, h, 20.0)
        np.testing.assert_allclose([np.linalg.norm(np.subtract(cam.eye, c)) for cam in cams], d * diag)
        # the bounding sphere just fits the nearest (peeling) view: tangent to its narrower side
        views = [*cams, peel, *intermediate_views(cams, 50, seed=3)]
        half = min(np.radians(22.5), np.arctan(np.tan(np.radians(22.5)) * w / h))
        assert np.arcsin(0.5 * diag / np.linalg.norm(np.subtract(peel.eye, c))) == pytest.approx(half)
        # every corner of the box projects inside every view of the rig
        corners = box_corners((lo, hi))
        for v in views:
            xy, z = v.project(corners)
            assert np.all(z > 0)
            assert np.all((xy[:, 0] >= 0) & (xy[:, 0] <= w) & (xy[:, 1] >= 0) & (xy[:, 1] <= h))


def test_intermediate_views_are_uniform_in_the_simplex():
    cams, _ = fig8_rig((np.zeros(3), np.ones(3)), 32, 32)
    eyes = np.array([cam.eye for cam in cams])
    views = intermediate_views(cams, 3000, seed=7)
    assert [v.eye for v in views[:5]] == [v.eye for v in intermediate_views(cams, 5, seed=7)]
    assert views[0].eye != intermediate_views(cams, 1, seed=8)[0].eye
    p = np.array([v.eye for v in views])
    # Barycentric coordinates in the eye triangle: non-negative, uniform (mean 1/3,
    # P(w0 > 1/2) = 1/4 for the uniform distribution on a triangle).
    w = np.linalg.lstsq(np.vstack([eyes.T, np.ones(3)]), np.vstack([p.T, np.ones(len(p))]), rcond=None)[0].T
    np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-9)
    assert w.min() > -1e-9
    np.testing.assert_allclose(w.mean(0), 1 / 3, atol=0.02)
    assert abs((w[:, 0] > 0.5).mean() - 0.25) < 0.03
    for v in views[:10]:
        assert (v.target, v.fov, v.width, v.height, v.up) == (cams[0].target, cams[0].fov, 32, 32, cams[0].up)
        assert v.near == min(c.near for c in cams) and v.far == max(c.far for c in cams)
    # n = 2: on the segment V0V1, uniformly.
    seg = np.array([v.eye for v in intermediate_views(cams[:2], 2000, seed=1)])
    t = (seg - eyes[0]) @ (eyes[1] - eyes[0]) / np.sum((eyes[1] - eyes[0]) ** 2)
    np.testing.assert_allclose(eyes[0] + t[:, None] * (eyes[1] - eyes[0]), seg, atol=1e-9)
    assert t.min() >= 0 and t.max() <= 1 and abs(t.mean() - 0.5) < 0.03


def pixel_corner_points(image: DepthImage, du: float, dv: float) -> np.ndarray:
    """(n,3) points where the rays through each sample's pixel centre offset by
    (du, dv) pixels meet the sample's tangent plane (row 0 = top)."""
    cam = image.camera
    rows, cols = np.nonzero(image.mask)
    r, up, f = cam.basis()
    t = np.tan(np.radians(cam.fov) / 2)
    x = (2 * (cols + 0.5 + du) / cam.width - 1) * t * cam.aspect
    y = (1 - 2 * (rows + 0.5 + dv) / cam.height) * t
    d = f + x[:, None] * r + y[:, None] * up
    p, n = image.position[image.mask].astype(np.float64), image.normal[image.mask].astype(np.float64)
    eye = np.asarray(cam.eye, np.float64)
    s = np.einsum("ij,ij->i", p - eye, n) / np.einsum("ij,ij->i", d, n)
    return eye + s[:, None] * d


def footprint_held(images: list[DepthImage], target: DepthImage, margin: float = 1e-2) -> tuple[np.ndarray, ...]:
    """Per sample of `target`: (centre held by some image, centre and 4 pixel corners
    held by one image, every point ≥ margin px from a texel edge) — held: the image's
    texel at the point holds the sample's triangle."""
    offsets = [(0.0, 0.0), (-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)]
    points = [pixel_corner_points(target, du, dv) for du, dv in offsets]
    tris = target.tri_id[target.mask]
    centre, whole, sure = np.zeros(len(tris), bool), np.zeros(len(tris), bool), np.ones(len(tris), bool)
    for prev in images:
        all_held = np.ones(len(tris), bool)
        for k, pts in enumerate(points):
            inside, t = lookup(prev, pts)
            held = inside & (t == tris)
            all_held &= held
            if k == 0:
                centre |= held
            sure &= lookup(prev, pts, margin)[0] | ~inside
        whole |= all_held
    return centre, whole, sure


def test_footprint_redundancy_keeps_pixels_that_straddle_an_earlier_outline(gl, clutter):
    """With footprint = ½, a fragment is redundant only when its pixel's centre and
    four corners all land on texels of one earlier image holding its triangle: the
    nearest surface of a pixel that straddles an earlier image's outline of it stays
    in the image, where Alg. 3 (centre only) drops it."""
    sg, cams, ref, conv = clutter["sg"], clutter["cams"], clutter["nr"], clutter["conv"]
    with di.DepthImageRenderer(gl, footprint=0.5) as r:
        out = di.non_redundant(gl, sg, cams, renderer=r)
    assert_images_equal(out[0].depth, ref[0].depth, "depth")
    straddling = 0
    for i in range(1, len(out)):
        centre, whole, sure = footprint_held(out[:i], conv[i])
        kept = out[i].tri_id[conv[i].mask] == conv[i].tri_id[conv[i].mask]  # the first hit survived
        assert (kept[sure & whole]).sum() <= 2  # redundant by the footprint rule: dropped
        assert (~kept[sure & ~whole]).sum() <= max(2, conv[i].n_samples // 1000)  # otherwise kept
        straddling += int((sure & centre & ~whole).sum())
        centre_ref, _, sure_ref = footprint_held(ref[:i], conv[i])  # Alg. 3: the centre alone decides
        kept_ref = ref[i].tri_id[conv[i].mask] == conv[i].tri_id[conv[i].mask]
        assert kept_ref[sure_ref & centre_ref].sum() <= 2
    assert straddling > 50  # pixels Alg. 3 drops and the footprint rule keeps


def occlusion_seam_redundant(images: list[DepthImage], target: DepthImage, margin: float,
                             px_margin: float = 1e-2) -> tuple[np.ndarray, np.ndarray]:
    """Per sample of `target`: (redundant by footprint ½ with occluded_margin
    `margin`, the rule's decision is sure): redundant when some image holds the
    centre's triangle and none of the 4 pixel corners lands on that image's texel of
    another surface nearer than the corner by more than `margin` of its depth. Sure:
    every point ≥ px_margin px from a texel edge and no depth within 2 % of the margin."""
    offsets = [(-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)]
    centre_pts = pixel_corner_points(target, 0.0, 0.0)
    corners = [pixel_corner_points(target, du, dv) for du, dv in offsets]
    tris = target.tri_id[target.mask]
    redundant, sure = np.zeros(len(tris), bool), np.ones(len(tris), bool)
    for prev in images:
        inside, t = lookup(prev, centre_pts)
        red = inside & (t == tris)
        sure &= lookup(prev, centre_pts, px_margin)[0] | ~inside
        for pts in corners:
            inside, t = lookup(prev, pts)
            px, z = prev.camera.project(pts)
            cols, rows = np.floor(px).astype(int).clip(0, [prev.camera.width - 1, prev.camera.height - 1]).T
            other = inside & (t != tris) & (t != 0)
            nearer = prev.depth[rows, cols] < z * (1 - margin)
            red &= ~(other & nearer)
            sure &= (lookup(prev, pts, px_margin)[0] | ~inside) \
                & ~(other & (np.abs(prev.depth[rows, cols] - z * (1 - margin)) < 0.02 * z))
        redundant |= red
    return redundant, sure


def test_occluded_margin_keeps_only_straddles_of_occlusion_seams(gl, clutter):
    """footprint = ½ with occluded_margin: a pixel that straddles an earlier image's
    outline of its surface keeps the surface only where that image saw another,
    nearer surface (an occlusion seam), not where it saw past or saw nothing (both
    kinds of straddle occur in the clutter)."""
    sg, cams, ref, conv = clutter["sg"], clutter["cams"], clutter["nr"], clutter["conv"]
    with di.DepthImageRenderer(gl, footprint=0.5, occluded_margin=0.003) as r:
        out = di.non_redundant(gl, sg, cams, renderer=r)
    assert_images_equal(out[0].depth, ref[0].depth, "depth")
    seams = saw_past = 0
    for i in range(1, len(out)):
        m = conv[i].mask
        kept = out[i].tri_id[m] == conv[i].tri_id[m]  # the first hit survived
        redundant, sure = occlusion_seam_redundant(out[:i], conv[i], 0.003)
        assert kept[sure & redundant].sum() <= 2  # redundant by the rule: dropped
        assert (~kept[sure & ~redundant]).sum() <= max(2, conv[i].n_samples // 1000)  # otherwise kept
        centre, whole, _ = footprint_held(out[:i], conv[i])
        seams += int((sure & centre & ~redundant).sum())  # Alg. 3 drops these
        saw_past += int((sure & ~whole & redundant).sum())  # the full footprint rule keeps these
    assert seams > 20 and saw_past > 20
    with pytest.raises(ValueError, match="occluded_margin"):
        di.DepthImageRenderer(gl, occluded_margin=0.003)

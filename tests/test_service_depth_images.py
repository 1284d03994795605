"""POST /scenes/{id}/depth-images: methods, formats, metrics and bad input."""

from __future__ import annotations

import base64
import io

import numpy as np
import pytest

from gl_passes.depth_images import conventional, non_redundant
from gl_passes.upload import SceneGPU
from reference.visibility import non_redundant_reference, non_redundant_visibility
from scenes.builtin import make_builtin
from scenes.camera import Camera
from scenes.rig import fig8_rig
from service import image_io
from tests.helpers import assert_images_equal, frame_camera, service_client

RES = 40

client = service_client("cornell")


def post(client, sid, **body):
    return client.post(f"/scenes/{sid}/depth-images", json={"width": RES, "height": RES, **body})


def test_rig_nr_set_as_exr_matches_direct_render(client, gl):
    c, sid = client
    r = post(c, sid, method="non_redundant")
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "image/x-exr"
    parts = image_io.decode_exr_multipart(r.content)
    assert [name for name, _ in parts] == ["image_0", "image_1", "image_2"]
    scene = make_builtin("cornell")
    cams, _ = fig8_rig(scene.bounds, RES, RES)
    with SceneGPU(gl, scene) as sg:
        direct = non_redundant(gl, sg, cams)
    for k, ((_, ch), im) in enumerate(zip(parts, direct, strict=True)):
        np.testing.assert_array_equal(ch["id"], im.tri_id)
        assert_images_equal(ch["Z"], im.depth, f"depth_{k}")
        assert_images_equal(ch["RGB"], im.color, f"color_{k}")
    assert (parts[1][1]["id"] > 0).sum() < (direct[0].tri_id > 0).sum()  # later NR images hold fewer samples


def test_exr_parts_carry_their_cameras(client):
    """Each part's worldToNDC (OpenEXR's row-vector M44f) takes its samples' positions P
    to their own pixel centres; worldToCamera gives depth Z along −z; the JSON names the eye."""
    import json

    import OpenEXR

    c, sid = client
    r = post(c, sid, method="conventional")
    assert r.headers["content-disposition"] == 'attachment; filename="depth_images.exr"'
    f = OpenEXR.File(io.BytesIO(r.content))
    scene = make_builtin("cornell")
    cams, _ = fig8_rig(scene.bounds, RES, RES)
    for part, (_, ch), cam in zip(f.parts, image_io.decode_exr_multipart(r.content), cams, strict=True):
        header = part.header
        assert json.loads(header["depthviewCamera"])["eye"] == list(cam.eye)
        rows, cols = np.nonzero(ch["id"] > 0)
        p = np.c_[ch["P"][rows, cols], np.ones(len(rows))]
        clip = p @ header["worldToNDC"].astype(np.float64)
        ndc = clip[:, :2] / clip[:, 3:]
        np.testing.assert_allclose(ndc[:, 0], (cols + 0.5) / RES * 2 - 1, atol=1e-3)
        np.testing.assert_allclose(ndc[:, 1], 1 - (rows + 0.5) / RES * 2, atol=1e-3)
        eye_space = p @ header["worldToCamera"].astype(np.float64)
        np.testing.assert_allclose(-eye_space[:, 2], ch["Z"][rows, cols], rtol=1e-4)


def test_conventional_npz_with_given_cameras(client, gl):
    c, sid = client
    cam = frame_camera()
    cam2 = {**cam, "eye": [cam["eye"][0] + 0.5, cam["eye"][1], cam["eye"][2]]}
    r = post(c, sid, method="conventional", cameras=[cam, cam2], format="npz")
    assert r.status_code == 200, r.text
    z = image_io.decode_npz(r.content)
    assert z["tri_id"].shape == (2, RES, RES) and z["color"].shape == (2, RES, RES, 3)
    assert z["view"].shape == (2, 4, 4)
    scene = make_builtin("cornell")
    direct_cam = Camera(tuple(cam["eye"]), tuple(cam["target"]), tuple(cam["up"]), cam["fov"], RES, RES)
    with SceneGPU(gl, scene) as sg:
        direct = conventional(gl, sg, [direct_cam])[0]
    np.testing.assert_array_equal(z["tri_id"][0], direct.tri_id)
    assert_images_equal(z["color"][0], direct.color)


def test_peeling_layers_and_metrics_json(client):
    c, sid = client
    r = post(c, sid, method="peeling", layers=2, metrics=True, intermediate_views=3)
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["media_type"] == "image/x-exr"
    parts = image_io.decode_exr_multipart(base64.b64decode(body["images_b64"]))
    assert len(parts) == 2
    m = body["metrics"]
    assert m["n_views"] == 3 and len(m["samples"]) == 2
    assert m["redundant"] == [0, 0]  # peeling layers never repeat a pixel's triangle


def test_nr_metrics_have_no_redundant_samples(client):
    c, sid = client
    m = post(c, sid, method="non_redundant", metrics=True, intermediate_views=2).json()["metrics"]
    assert m["total"]["redundant"] == 0
    conv = post(c, sid, method="conventional", metrics=True, intermediate_views=2).json()["metrics"]
    assert conv["total"]["redundant"] > 0 and conv["total"]["occluded"] == 0
    assert 0 < m["available_min"] <= m["available_avg"] <= 1


def test_visibility_redundancy_is_served_by_embree(client):
    """The rig's visibility-redundancy NR set is Alg. 2 by Embree
    (reference.visibility.non_redundant_visibility), pixel for pixel; on this rig it
    differs from the pixel-redundancy set (Alg. 3), so serving that instead fails."""
    c, sid = client
    r = post(c, sid, method="non_redundant", redundancy="visibility")
    assert r.status_code == 200, r.text
    parts = image_io.decode_exr_multipart(r.content)
    assert [name for name, _ in parts] == ["image_0", "image_1", "image_2"]
    scene = make_builtin("cornell")
    cams, _ = fig8_rig(scene.bounds, RES, RES)
    expected = non_redundant_visibility(scene, cams)
    pixel = non_redundant_reference(scene, cams, "pixel")
    assert any(not np.array_equal(v.tri_id, p.tri_id) for v, p in zip(expected, pixel, strict=True))
    for k, ((_, ch), im) in enumerate(zip(parts, expected, strict=True)):
        assert_images_equal(ch["Z"], im.depth, f"depth_{k}")  # first: writes the depth images on failure
        np.testing.assert_array_equal(ch["id"], im.tri_id, err_msg=f"image_{k} id")
        empty = ch["id"] == 0  # no sample: colour 0 as in the GL sets (it was the sky colour)
        assert empty.any() and not ch["RGB"][empty].any() and ch["RGB"][~empty].any(), f"image_{k} colour"
    assert (parts[1][1]["id"] > 0).any()  # later images hold samples (what the earlier views cannot see)


@pytest.mark.parametrize("body, status, needle", [
    ({"method": "splat"}, 422, "method"),
    ({"redundancy": "fuzzy"}, 422, "redundancy"),
    ({"width": 5000}, 422, "width"),
    ({"layers": 0}, 422, "layers"),
    ({"layers": 17}, 422, "less than or equal to 16"),
    ({"cameras": []}, 422, "cameras"),
    ({"cameras": [{"eye": [0, 1, 3], "target": [0, 1, 0]}] * 17}, 422, "at most 16 items"),
    ({"cameras": [{"eye": [0, 1, 0], "target": [0, 1, 0]}]}, 422, "coincide"),
    ({"format": "png"}, 422, "format"),
    ({"intermediate_views": 100000}, 422, "intermediate_views"),
])
def test_bad_requests_name_the_problem(client, body, status, needle):
    c, sid = client
    r = post(c, sid, **body)
    assert r.status_code == status
    assert needle in r.text


#: Two eyes whose centroid is the first camera's target: no peeling viewpoint between them.
FACING = [{"eye": [0, 1, 3.5], "target": [0, 1, 0]}, {"eye": [0, 1, -3.5], "target": [0, 1, 0]}]


def test_a_peeling_viewpoint_on_the_target_is_422_other_methods_render(client):
    """Peeling renders from the eyes' centroid toward the first camera's target: where
    they coincide the request is 422 naming the peeling camera; the other methods do
    not use that viewpoint and render the same cameras."""
    c, sid = client
    r = post(c, sid, method="peeling", cameras=FACING, width=16, height=16, format="npz")
    assert r.status_code == 422, r.text
    assert "peeling camera" in r.text and "coincide" in r.text
    for method in ("conventional", "non_redundant"):
        r = post(c, sid, method=method, cameras=FACING, width=16, height=16, format="npz")
        assert r.status_code == 200, r.text


def test_reconstruction_peels_from_the_same_viewpoint_as_the_set(client):
    """Peeling from several cameras: /reconstruction peels from the eyes' centroid as
    /depth-images does (it used to take the first camera and ignore the rest), and a
    centroid on the target is 422 on both."""
    c, sid = client
    two = [{"eye": [1.5, 1, 3.5], "target": [0, 1, 0]}, {"eye": [-1.5, 1, 3.5], "target": [0, 1, 0]}]
    centroid = [{"eye": [0, 1, 3.5], "target": [0, 1, 0]}]

    def glb(cameras):
        r = c.post(f"/scenes/{sid}/reconstruction", json={"method": "peeling", "cameras": cameras,
                                                          "resolution": 32, "layers": 2})
        assert r.status_code == 200, r.text
        return r.content

    assert glb(two) == glb(centroid) != glb(two[:1])
    r = c.post(f"/scenes/{sid}/reconstruction", json={"method": "peeling", "cameras": FACING, "resolution": 32})
    assert r.status_code == 422 and "peeling camera" in r.text, r.text


@pytest.mark.parametrize("method", ["conventional", "peeling"])
def test_redundancy_with_a_method_it_does_not_apply_to_is_422(client, method):
    c, sid = client
    r = post(c, sid, method=method, redundancy="visibility", format="npz")
    assert r.status_code == 422 and "non_redundant only" in r.text, r.text


def test_unknown_scene_is_404(client):
    c, _ = client
    assert post(c, "0" * 64).status_code == 404

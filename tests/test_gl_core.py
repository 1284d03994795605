"""GL context, G-buffer pass and their agreement with the Embree reference."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading

import numpy as np
import pytest
import trimesh

from gl_passes.context import GLContextError, create_gl_context
from gl_passes.gbuffer import GBufferPass
from gl_passes.upload import SceneGPU
from reference.raycast import RayCaster
from scenes import Camera, Material, Scene, SceneObject, look_at_scene
from tests.gl_leaks import gl_object_growth


def sphere_on_slab() -> Scene:
    s = trimesh.creation.icosphere(4)
    b = trimesh.creation.box((3, 0.2, 3))
    b.apply_translation((0, -1.2, 0))
    return Scene([SceneObject("sphere", s.vertices, s.faces, material=Material((0.8, 0.2, 0.2), 0.5, 0.1)),
                  SceneObject("slab", b.vertices, b.faces, material=Material((0.3, 0.6, 0.3)))], name="t")


def quad_scene(facing_camera: bool) -> Scene:
    """A 2×2 quad in the plane z = 0, front face toward +z when facing_camera."""
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    if not facing_camera:
        f = f[:, ::-1]
    return Scene([SceneObject("quad", v, f, normals=np.tile([0, 0, 1.0], (4, 1)))])


def test_context_is_gl43_core_and_names_renderer(gl):
    assert gl.ctx.version_code >= 430
    assert gl.backend in ("egl", "osmesa")
    assert "llvmpipe" in gl.renderer.lower() or not gl.is_software
    assert gl.renderer in repr(gl) and isinstance(gl.is_software, bool)


def test_context_refuses_other_threads(gl):
    errors = []
    t = threading.Thread(target=lambda: errors.append(pytest.raises(RuntimeError, gl.check_thread)))
    t.start()
    t.join()
    assert errors and "thread" in str(errors[0].value)


def test_unknown_backend_is_a_clear_error():
    with pytest.raises(GLContextError, match="DEPTHVIEW_GL"):
        create_gl_context("vulkan")


def test_osmesa_backend_renders_same_as_reference():
    """The OSMesa path in a fresh process (a second context type must not disturb ours)."""
    code = (
        "import json, numpy as np\n"
        "from tests.test_gl_core import sphere_on_slab\n"
        "from gl_passes.context import create_gl_context\n"
        "from gl_passes.gbuffer import GBufferPass\nfrom gl_passes.upload import SceneGPU\n"
        "from reference.raycast import RayCaster\nfrom scenes import look_at_scene\n"
        "sc = sphere_on_slab(); gl = create_gl_context()\n"
        "cam = look_at_scene(sc.bounds, width=96, height=64)\n"
        "g = GBufferPass(gl).render(SceneGPU(gl, sc), cam); r = RayCaster(sc).gbuffer(cam)\n"
        "print(json.dumps({'backend': gl.backend, 'agree': float((g.tri_id == r.tri_id).mean())}))\n"
    )
    env = {**os.environ, "DEPTHVIEW_GL": "osmesa"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120,
                         cwd=os.path.dirname(os.path.dirname(__file__)))
    assert out.returncode == 0, out.stderr
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["backend"] == "osmesa"
    assert res["agree"] >= 0.99


def test_gbuffer_matches_reference_sphere(gl, gbuffer_pass):
    sc = sphere_on_slab()
    sg = SceneGPU(gl, sc)
    cam = look_at_scene(sc.bounds, distance=0.7, width=160, height=120)
    g = gbuffer_pass.render(sg, cam)
    r = RayCaster(sc).gbuffer(cam)
    sg.release()
    agree = g.tri_id == r.tri_id
    assert agree.mean() >= 0.99
    m = agree & g.mask
    assert m.sum() > 0.3 * m.size
    np.testing.assert_allclose(g.depth[m], r.depth[m], rtol=1e-4)
    assert np.abs(g.color[m] - r.color[m]).max() < 1 / 255
    assert np.abs(g.color[~g.mask & ~r.mask] - r.color[~g.mask & ~r.mask]).max() < 1 / 255
    np.testing.assert_allclose(g.normal[m], r.normal[m], atol=1e-3)
    np.testing.assert_allclose(g.position[m], r.position[m], atol=1e-3 * sc.diagonal)
    assert set(np.unique(g.obj_id)) == {0, 1, 2}
    np.testing.assert_array_equal(g.specular[g.obj_id == 1], 0.5)
    np.testing.assert_allclose(g.glossiness[g.obj_id == 1], 0.1, rtol=1e-6)
    assert np.isinf(g.depth[~g.mask]).all()


def test_hand_computable_quad_depth_ids_and_orientation(gl, gbuffer_pass):
    """Camera at z = 4 looking at a quad at z = 0: depth 4 everywhere on it,
    triangle ids 1/2 split along the diagonal; the quad shifted up shows in the top rows."""
    sc = quad_scene(True)
    sg = SceneGPU(gl, sc)
    cam = Camera((0, 0, 4), (0, 0, 0), fov=60, width=64, height=64).fit_clip(sc.bounds)
    g = gbuffer_pass.render(sg, cam)
    np.testing.assert_allclose(g.depth[g.mask], 4.0, rtol=1e-5)
    assert set(np.unique(g.tri_id[g.mask])) == {1, 2}
    # Triangle 1 = (v0, v1, v2) is the lower-right half in the image (row 0 = top).
    assert g.tri_id[40, 40] == 1 and g.tri_id[24, 24] == 2
    # Quad spans ±1 at distance 4 with fov 60: half-height tan(30°)·4 = 2.31 → 64·(1/2.31)/2 px.
    half = 32 / (4 * np.tan(np.radians(30)))
    rows = np.where(g.mask.any(axis=1))[0]
    assert abs((rows.max() - rows.min() + 1) - 2 * half) <= 2
    up = Camera((0, -0.9, 4), (0, -0.9, 0), fov=60, width=64, height=64).fit_clip(sc.bounds)
    g2 = gbuffer_pass.render(sg, up)
    assert g2.mask[:10].any() and not g2.mask[-10:].any()  # quad moved up in the image
    sg.release()


def test_back_face_culling_switch(gl, gbuffer_pass):
    sc = quad_scene(False)
    sg = SceneGPU(gl, sc)
    cam = Camera((0, 0, 4), (0, 0, 0), fov=60, width=32, height=32).fit_clip(sc.bounds)
    assert not gbuffer_pass.render(sg, cam, cull_back_faces=True).mask.any()
    g = gbuffer_pass.render(sg, cam, cull_back_faces=False)
    assert abs(g.mask.mean() - (2 / (8 * np.tan(np.radians(30)))) ** 2) < 0.03
    # Back face seen: shading normal flipped toward the viewer.
    np.testing.assert_allclose(g.normal[g.mask], np.tile([0, 0, -1.0], (g.mask.sum(), 1)), atol=1e-6)
    r = RayCaster(sc).gbuffer(cam, cull_back_faces=False)
    assert (r.tri_id == g.tri_id).mean() > 0.99
    assert not RayCaster(sc).gbuffer(cam).mask.any()
    sg.release()


def test_occlusion_queries_hand_checked():
    sc = quad_scene(True)
    rc = RayCaster(sc)
    a = np.array([[0, 0, 2.0], [0, 0, 2.0], [3, 0, 2.0], [0, 0, -2.0]])
    b = np.array([[0, 0, -2.0], [0.5, 0.5, 0.0], [3, 0, -2.0], [0, 0, 2.0]])
    np.testing.assert_array_equal(rc.occluded(a, b), [True, False, False, True])
    # With culling the quad only blocks rays that meet its front face.
    np.testing.assert_array_equal(rc.occluded(a, b, cull_back_faces=True), [True, False, False, False])


def test_1000_frames_do_not_grow_gl_objects():
    """Upload, render 1000 frames (several sizes, scene re-uploads) on a fresh
    context: the live GL object count is unchanged."""

    class State:
        def __init__(self, gl):
            self.gl, self.scene = gl, quad_scene(True)
            self.gp, self.sg = GBufferPass(gl), SceneGPU(gl, self.scene)
            self.cam = Camera((0, 0, 4), (0, 0, 0), width=16, height=16).fit_clip(self.scene.bounds)
            self.gp.render(self.sg, self.cam)

        def frame(self, i):
            if i % 100 == 0:  # re-upload, as the worker's scene cache does on eviction
                self.sg.release()
                self.sg = SceneGPU(self.gl, self.scene)
            self.gp.render(self.sg, self.cam.with_size(16 + (i % 3) * 8, 16))
            if i == 999:
                self.gp.render(self.sg, self.cam)

        def release(self):
            self.sg.release()
            self.gp.release()

    before, after = gl_object_growth(State, State.frame, 1000)
    assert before > 0
    assert after == before

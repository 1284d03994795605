"""GL context, G-buffer pass and their agreement with the Embree reference."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from gl_passes.context import GLContextError, create_gl_context
from gl_passes.gbuffer import GBufferPass
from gl_passes.upload import SceneGPU
from reference.raycast import RayCaster
from scenes import Camera, look_at_scene
from service.image_check import assert_images_close
from tests.gl_leaks import gl_object_growth
from tests.helpers import (
    assert_depth_close,
    osmesa_render_agreement,
    quad_scene,
    run_isolated,
    sphere_on_slab,
    worker_context_loss,
)


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
    """The OSMesa path in its own process (a second context type must not disturb ours)."""
    res = run_isolated(osmesa_render_agreement, env={"DEPTHVIEW_GL": "osmesa"})
    assert res["backend"] == "osmesa"
    assert res["agree"] >= 0.99


def test_lost_context_fails_jobs_not_the_process():
    """The render worker's context released under it (a lost context), in its own
    process: the next frame's job raises to its caller, the worker thread lives on
    and shuts down, and the process exits normally (no crash)."""
    res = run_isolated(worker_context_loss)
    assert res["first"] > 0.1
    assert res["error"] is not None
    assert res["alive"] and res["stopped"]


def test_gbuffer_matches_reference_sphere(gl, gbuffer_pass):
    sc = sphere_on_slab()
    cam = look_at_scene(sc.bounds, distance=0.7, width=160, height=120)
    with SceneGPU(gl, sc) as sg:
        g = gbuffer_pass.render(sg, cam)
    r = RayCaster(sc).gbuffer(cam)
    agree = g.tri_id == r.tri_id
    assert agree.mean() >= 0.99
    m = agree & g.mask
    assert m.sum() > 0.3 * m.size
    assert_depth_close(g.depth, r.depth, 1e-4, mask=m)
    every = {"max_bad_fraction": 0.0}  # every pixel within the tolerance
    assert_images_close(g.color, r.color, tolerance=1 / 255, mask=m, name="color", **every)
    assert_images_close(g.color, r.color, tolerance=1 / 255, mask=~g.mask & ~r.mask, name="sky", **every)
    assert_images_close(g.normal, r.normal, tolerance=1e-3, mask=m, name="normal", **every)
    assert_images_close(g.position, r.position, tolerance=1e-3 * sc.diagonal, mask=m, name="position", **every)
    assert set(np.unique(g.obj_id)) == {0, 1, 2}
    np.testing.assert_array_equal(g.specular[g.obj_id == 1], 0.5)
    np.testing.assert_allclose(g.glossiness[g.obj_id == 1], 0.1, rtol=1e-6)
    assert np.isinf(g.depth[~g.mask]).all()


def test_hand_computable_quad_depth_ids_and_orientation(gl, gbuffer_pass):
    """Camera at z = 4 looking at a quad at z = 0: depth 4 everywhere on it,
    triangle ids 1/2 split along the diagonal; the quad shifted up shows in the top rows."""
    sc = quad_scene(True)
    cam = Camera((0, 0, 4), (0, 0, 0), fov=60, width=64, height=64).fit_clip(sc.bounds)
    up = Camera((0, -0.9, 4), (0, -0.9, 0), fov=60, width=64, height=64).fit_clip(sc.bounds)
    with SceneGPU(gl, sc) as sg:
        g, g2 = gbuffer_pass.render(sg, cam), gbuffer_pass.render(sg, up)
    np.testing.assert_allclose(g.depth[g.mask], 4.0, rtol=1e-5)
    assert set(np.unique(g.tri_id[g.mask])) == {1, 2}
    # Triangle 1 = (v0, v1, v2) is the lower-right half in the image (row 0 = top).
    assert g.tri_id[40, 40] == 1 and g.tri_id[24, 24] == 2
    # Quad spans ±1 at distance 4 with fov 60: half-height tan(30°)·4 = 2.31 → 64·(1/2.31)/2 px.
    half = 32 / (4 * np.tan(np.radians(30)))
    rows = np.where(g.mask.any(axis=1))[0]
    assert abs((rows.max() - rows.min() + 1) - 2 * half) <= 2
    assert g2.mask[:10].any() and not g2.mask[-10:].any()  # quad moved up in the image


def test_back_face_culling_switch(gl, gbuffer_pass):
    sc = quad_scene(False)
    cam = Camera((0, 0, 4), (0, 0, 0), fov=60, width=32, height=32).fit_clip(sc.bounds)
    with SceneGPU(gl, sc) as sg:
        culled, g = (gbuffer_pass.render(sg, cam, cull_back_faces=c) for c in (True, False))
    assert not culled.mask.any()
    assert abs(g.mask.mean() - (2 / (8 * np.tan(np.radians(30)))) ** 2) < 0.03
    # Back face seen: shading normal flipped toward the viewer.
    np.testing.assert_allclose(g.normal[g.mask], np.tile([0, 0, -1.0], (g.mask.sum(), 1)), atol=1e-6)
    r = RayCaster(sc).gbuffer(cam, cull_back_faces=False)
    assert (r.tri_id == g.tri_id).mean() > 0.99
    assert not RayCaster(sc).gbuffer(cam).mask.any()


def test_scene_upload_is_released_by_its_with_block(gl):
    """`with SceneGPU(...)` frees the buffers on exit, also when the block raises."""
    with pytest.raises(KeyError), SceneGPU(gl, quad_scene(True)) as sg:
        assert type(sg.vbo.mglo).__name__ == "Buffer"
        raise KeyError("inside the block")
    assert {type(b.mglo).__name__ for b in (sg.vbo, sg.ibo)} == {"InvalidObject"}


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


def test_staging_buffer_reads_what_the_buffer_holds(gl):
    """readback.StagingBuffer: the bytes of a storage buffer (from an offset), through
    a copy that grows with the largest read; the source is left as it was."""
    from gl_passes.readback import StagingBuffer

    data = np.arange(1000, dtype=np.uint32)
    src = gl.ctx.buffer(data.tobytes())
    staging = StagingBuffer(gl.ctx)
    try:
        assert staging.read(src, 0) == b""
        assert np.array_equal(np.frombuffer(staging.read(src, 16, 8), np.uint32), [2, 3, 4, 5])
        small = staging.buf.size
        assert np.array_equal(np.frombuffer(staging.read(src, 4000), np.uint32), data)
        assert staging.buf.size > small
        assert np.array_equal(np.frombuffer(src.read(), np.uint32), data)
    finally:
        staging.release()
        src.release()
    assert staging.buf is None

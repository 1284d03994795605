"""Triangle chunks (gl_passes.chunks): hand-checked frustum and back-face tests,
and the G-buffer pass's chunk culling, which must not change a pixel."""

from __future__ import annotations

import numpy as np
import pytest

from gl_passes.chunks import boxes_in_frustum, chunk_table, facing_away, nearest_first, runs
from gl_passes.gbuffer import GBufferPass
from gl_passes.upload import SceneGPU
from scenes.builtin import make_builtin
from scenes.camera import Camera, flythrough_path
from tests.helpers import assert_images_equal

# One triangle in the plane z = 0, counter-clockwise seen from +z (its front side).
TRIANGLE = (np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))


def test_chunk_table_splits_objects_into_runs_with_their_boxes():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 2]])
    faces = np.array([[0, 1, 2]] * 5 + [[0, 1, 3]] * 2)
    t = chunk_table(v, faces, [(0, 5), (5, 2)], size=2)
    assert t.obj.tolist() == [0, 0, 0, 1] and t.first.tolist() == [0, 2, 4, 5] and t.count.tolist() == [2, 2, 1, 2]
    np.testing.assert_array_equal(t.bounds[3], [[0, 0, 0], [1, 0, 2]])
    # consecutive chunks of one object merge into one draw; an object boundary splits
    assert list(runs(t, np.array([0, 1, 3]))) == [(0, 0, 4), (1, 5, 2)]
    assert list(runs(t, np.array([0, 2]))) == [(0, 0, 2), (0, 4, 1)]


def test_facing_away_is_the_side_of_the_eye():
    t = chunk_table(*TRIANGLE, [(0, 1)])
    assert facing_away(np.array([0.2, 0.2, -1.0]), t.cones).tolist() == [True]
    assert facing_away(np.array([0.2, 0.2, 1.0]), t.cones).tolist() == [False]
    assert facing_away(np.array([5.0, 5.0, 0.0]), t.cones).tolist() == [False]  # edge-on: kept


def test_boxes_in_frustum_culls_what_lies_behind_or_beside():
    cam = Camera((0, 0, 5), (0, 0, 0), (0, 1, 0), 40.0, 64, 64, near=0.1, far=100.0)
    boxes = np.array([[[-1, -1, -1], [1, 1, 1]],       # in front
                      [[-1, -1, 6], [1, 1, 8]],         # behind the eye
                      [[50, -1, -1], [52, 1, 1]],       # far to the side
                      [[-1, -1, -200], [1, 1, -150]]])  # beyond the far plane
    assert boxes_in_frustum(cam.view_projection(), boxes).tolist() == [True, False, False, False]


def test_nearest_first_orders_chunks_by_box_distance():
    """Boxes at distances 3, 0 (holding the point), 1 and 1 (a tie: index order)
    from the point: order 1, 2, 3, 0; a subset keeps its relative order."""
    bounds = np.array([[[4, 0, 0], [5, 1, 1]], [[-1, -1, -1], [1, 1, 1]],
                       [[0, 2, 0], [1, 3, 1]], [[0, 0, -2], [1, 1, -1]]], float)
    assert nearest_first(bounds, [0, 1, 2, 3], [1, 1, 0]).tolist() == [1, 2, 3, 0]
    assert nearest_first(bounds, [3, 0, 2], [1, 1, 0]).tolist() == [3, 2, 0]


@pytest.mark.parametrize("name", ["living_room", "bathroom"])
def test_gbuffer_chunk_culling_changes_no_pixel(gl, name):
    """Frustum and back-face culling of chunks draw fewer triangles and give the
    same G-buffer, every attachment bit for bit, as drawing every object."""
    scene = make_builtin(name)
    cam = flythrough_path(scene.bounds, 8, width=96, height=96)[2].fit_clip(scene.bounds)
    with SceneGPU(gl, scene) as sg, GBufferPass(gl) as gb:
        culled = gb.render(sg, cam)
        drawn = gb.drawn
        # no view, no culling; the same nearest-first order
        sg.draw = lambda prog, objects=None, **kw: SceneGPU.draw(sg, prog, objects, near_first=kw["near_first"])
        full = gb.render(sg, cam)
        sg.draw = lambda prog, objects=None, **kw: SceneGPU.draw(sg, prog, objects)  # nor the order
        unordered = gb.render(sg, cam)
        assert drawn < 0.9 * len(scene.faces)
        for field in ("color", "depth", "normal", "position", "tri_id", "obj_id", "specular", "glossiness"):
            assert_images_equal(getattr(culled, field), getattr(full, field), f"{name}_{field}")
        # Drawn nearest chunk first, a pixel changes only where two surfaces tie in
        # the depth buffer (the first drawn keeps it): few pixels, each at the depth
        # it had within the buffer's resolution there.
        changed = culled.tri_id != unordered.tri_id
        assert changed.mean() < 1e-3
        rel = np.abs(culled.depth - unordered.depth)[changed] / unordered.depth[changed]
        assert rel.max(initial=0.0) < 1e-2, rel.max(initial=0.0)  # no changed pixel: nothing to bound

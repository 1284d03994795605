"""Levels of detail of the cluster depth images (gl_passes.lod): hand-built meshes
with the two structures that stop meshoptimizer on real scenes (a double-sided
sheet, a box with a vertex per face at each corner) and a clean one."""

import numpy as np
import trimesh

from gl_passes.lod import lod_faces, occurrence_rank
from gl_passes.reconstruction import simplify
from tests.helpers import face_normals, sphere_mesh


def double_sided_sheet(n: int = 10) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A flat n×n-quad sheet in z = 0 given twice, as curtains and leaves are: the
    front (normals +z) and the back (own vertices, normals -z, reversed winding)."""
    g = np.linspace(0.0, 1.0, n + 1)
    x, y = np.meshgrid(g, g)
    v = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    k = np.arange(n * (n + 1)).reshape(n, n + 1)[:, :n].ravel()
    front = np.concatenate([np.stack([k, k + 1, k + n + 2], 1), np.stack([k, k + n + 2, k + n + 1], 1)])
    back = front[:, ::-1] + len(v)
    normals = np.concatenate([np.tile([0.0, 0.0, 1.0], (len(v), 1)), np.tile([0.0, 0.0, -1.0], (len(v), 1))])
    return np.concatenate([v, v]), np.concatenate([front, back]), normals


def test_occurrence_rank_counts_the_equal_rows_before_each():
    keys = np.array([[1, 2], [3, 4], [1, 2], [1, 2], [3, 4], [5, 6]])
    assert occurrence_rank(keys).tolist() == [0, 0, 1, 2, 1, 0]


def test_a_double_sided_sheet_simplifies_to_one_quad_per_side():
    """The 400-triangle sheet is flat, so any error bound allows one quad per side;
    given as it is, meshoptimizer locks the corners the two sides share and keeps
    almost all of it. Each side keeps its own vertices (their normals face the
    way the triangle does)."""
    v, f, n = double_sided_sheet()
    assert len(simplify(v, f, 1e-3)) > len(f) // 2
    out = lod_faces(v, n, f, 1e-3)
    assert len(out) == 4
    geo = face_normals(v, out, unit=True)
    assert sorted(np.sign(geo[:, 2]).tolist()) == [-1, -1, 1, 1]
    assert np.all(np.einsum("mck,mk->mc", n[out], geo) > 0.999)


def test_a_hard_edged_box_keeps_its_flat_shading():
    """A box with a vertex per face at each corner (24 vertices, as books and tiles
    are): nothing to remove at a tiny error bound, and every corner of every output
    triangle is the vertex of its own face (normal = the face's), not another face's
    vertex at the same position."""
    box = trimesh.creation.box((1.0, 2.0, 0.5))
    tri = box.triangles.reshape(-1, 3)
    faces = np.arange(len(tri)).reshape(-1, 3)
    normals = np.repeat(box.face_normals, 3, axis=0)
    out = lod_faces(tri, normals, faces, 1e-6)
    assert len(out) == 12
    assert np.allclose(np.einsum("mck,mk->mc", normals[out], face_normals(tri, out, unit=True)), 1.0)
    assert sorted(map(tuple, np.sort(tri[out].reshape(-1, 9), axis=1))) == sorted(
        map(tuple, np.sort(tri[faces].reshape(-1, 9), axis=1)))


def test_a_clean_mesh_simplifies_within_twice_its_error_bound():
    """A closed sphere (one vertex per position, single-sided faces): nothing to weld
    or split, so the level is about as small as meshoptimizer's on the mesh as it is
    (within 5 %: welding reorders the vertices it visits). meshoptimizer's error is
    its own quadric measure, not a distance bound: the sphere's vertices lie up to
    1.7× (error 0.01) and 1.9× (0.03) that error from the simplified surface
    (measured along their radii), so the bound checked here is twice the error."""
    s = sphere_mesh()
    v = np.asarray(s.vertices)
    for error in (1e-2, 3e-2):
        ours = lod_faces(v, np.asarray(s.vertex_normals), s.faces, error)
        assert abs(len(ours) - len(simplify(v, s.faces, error))) <= 0.05 * len(ours)
        assert len(ours) < len(s.faces) / 8
        radial = v / np.linalg.norm(v, axis=1, keepdims=True)
        hit, ray, _ = trimesh.Trimesh(v, ours, process=False).ray.intersects_location(
            np.zeros_like(radial), radial, multiple_hits=False)
        assert len(np.unique(ray)) == len(v)
        assert np.all(0.6 - np.linalg.norm(hit, axis=1) <= 2.0 * error)

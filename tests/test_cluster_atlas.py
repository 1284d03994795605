"""The cluster images' atlas (gl_passes.cluster_camera.pack_atlas): which images
the texel budget shrinks, on hand-counted sizes."""

import numpy as np

from gl_passes.cluster_camera import ClusterCamera, pack_atlas


def camera(index: int, size: int, planar: bool, glossiness: float) -> ClusterCamera:
    z, x, y = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    return ClusterCamera(index=index, object_id=1, samples=100, glossiness=glossiness, plane_point=z * 0,
                         plane_normal=z, mirrored_eye=z, center=z, f=1.0, shift=0.0, planar=planar, d_n=1.0,
                         d_f=2.0, right=x, up=y, forward=-z, clip_offset=0.0, ray_length=10.0,
                         spacing=0.01, resolution=(size, size))


def test_the_budget_shrinks_every_image_but_planar_mirrors():
    """Planar mirror 100², planar glossy 200², curved 300² (140,000 texels) under a
    budget of 60,000: the mirror keeps its texel = sample grid (10,000 texels, under
    half the budget), the other two shrink by sqrt(50,000 / 130,000) = 0.6202 to
    ceil(124.03) = 125 and ceil(186.05) = 187 texels a side, their texel spacing
    widened by the same ratio; without a budget nothing shrinks."""
    cams = [camera(0, 100, True, 0.0), camera(1, 200, True, 0.3), camera(2, 300, False, 0.1)]
    pack_atlas(cams, 8192, 60000.0)
    assert [c.resolution for c in cams] == [(100, 100), (125, 125), (187, 187)]
    assert [c.atlas[2:] for c in cams] == [(100, 100), (125, 125), (187, 187)]
    assert np.allclose([c.spacing for c in cams], [0.01, 0.01 * 200 / 125, 0.01 * 300 / 187])
    cams = [camera(0, 100, True, 0.0), camera(1, 200, True, 0.3), camera(2, 300, False, 0.1)]
    pack_atlas(cams, 8192, None)
    assert [c.resolution for c in cams] == [(100, 100), (200, 200), (300, 300)]

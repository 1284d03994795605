"""Embree reference caster: splitting large batches across threads changes no result."""

from __future__ import annotations

import numpy as np
import pytest

import reference.raycast as raycast
from reference.raycast import RayCaster
from scenes.builtin import make_builtin


def _rays(scene, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    lo, hi = scene.vertices.min(0).astype(np.float64), scene.vertices.max(0).astype(np.float64)
    centre = (lo + hi) / 2
    origins = centre + rng.normal(size=(n, 3)) * np.linalg.norm(hi - lo)
    targets = lo + rng.random((n, 3)) * (hi - lo)
    d = targets - origins
    return origins, d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize("workers", [2, 3])
def test_threaded_batches_equal_single_call(monkeypatch, workers):
    scene = make_builtin("city")
    rc = RayCaster(scene)
    o, d = _rays(scene, 5003)
    tmax = np.full(len(o), 10 * scene.diagonal)
    tmax[::7] = 0.3 * scene.diagonal  # some rays end before they reach anything
    monkeypatch.setattr(raycast, "_WORKERS", 1)
    single_hits = rc.intersect(o, d, tmax)
    single_occ = rc.occluded(o, o + d * tmax[:, None])
    single_from = rc.cast_from(o[0], d)
    assert 0.2 < single_hits.hit.mean() < 0.95  # the batch mixes hits and misses
    assert 0.1 < single_occ.mean() < 0.95

    monkeypatch.setattr(raycast, "_WORKERS", workers)
    monkeypatch.setattr(raycast, "PARALLEL_MIN_RAYS", 100)
    hits = rc.intersect(o, d, tmax)
    np.testing.assert_array_equal(hits.tri_id, single_hits.tri_id)
    np.testing.assert_array_equal(hits.t, single_hits.t)
    np.testing.assert_array_equal(hits.u, single_hits.u)
    np.testing.assert_array_equal(rc.occluded(o, o + d * tmax[:, None]), single_occ)
    np.testing.assert_array_equal(rc.cast_from(o[0], d).tri_id, single_from.tri_id)

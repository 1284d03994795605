"""bench.union_find_model: the lock-step GPU model of the clustering's union-find, on
hand-counted cases and on a random maze against scipy's components."""

from __future__ import annotations

import numpy as np

from bench.union_find_model import (
    GPUModel,
    atomic_min,
    block_union,
    components,
    edge_pairs,
    find_pass,
    per_sample_union,
    run_groups,
)


def test_atomic_min_returns_what_a_sequential_order_would():
    labels = np.arange(8, dtype=np.int64)
    old = atomic_min(labels, np.array([5, 7, 5, 5]), np.array([3, 6, 1, 2]))
    assert old.tolist() == [5, 7, 3, 1]  # the second on 5 sees the first's 3, the third the second's 1
    assert labels[5] == 1 and labels[7] == 6


def test_find_walks_one_link_per_round():
    labels = np.array([0, 0, 1, 2], np.int64)  # the chain 3 → 2 → 1 → 0
    cost = find_pass(labels, np.array([3]), np.array([0]), False, GPUModel(1))
    assert (cost.rounds, cost.accesses) == (4, 5)  # loads at 3, 2, 1, 0, then the store
    assert labels[3] == 0


def test_groups_beyond_the_resident_ones_wait():
    steps = []

    def step(act):
        steps.append(act.tolist())
        return np.ones(len(act), bool), len(act)

    cost = run_groups(GPUModel(1), np.array([0, 0, 1]), step)
    assert steps == [[0, 1], [2]] and (cost.rounds, cost.accesses) == (2, 3)


def test_both_models_label_the_components_of_a_random_maze():
    rng = np.random.default_rng(3)
    h, w = 48, 64
    refl = rng.random((h, w)) < 0.8
    left = np.zeros((h, w), bool)
    up = np.zeros((h, w), bool)
    # neighbours joined or not at random (bins and normal breaks): a tile-local label differs from its
    # neighbour's along a tile side
    left[:, 1:] = refl[:, 1:] & refl[:, :-1] & (rng.random((h, w - 1)) < 0.7)
    up[1:] = refl[1:] & refl[:-1] & (rng.random((h - 1, w)) < 0.7)
    truth = components(h * w, edge_pairs(left, up, w))[refl.reshape(-1)]
    for algorithm in (per_sample_union, block_union):
        cost, labels = algorithm(refl, left, up, GPUModel(4))
        assert np.array_equal(labels[refl.reshape(-1)], truth), algorithm.__name__
        assert all(c.rounds > 0 for c in cost.values())

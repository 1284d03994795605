"""Benchmark report helpers (bench.peeling_sides, bench.rig_spread) on hand-made numbers."""

from __future__ import annotations

from bench.peeling_sides import layer_table, useful_table


def _m(useful: int, useful_earlier: int = 0, occ=(0.1, 0.5, 0.6), use=(0.9, 0.02, 0.7), avail: float = 0.9) -> dict:
    return {"total": {"useful": useful, "useful_earlier": useful_earlier}, "occluded_frac": list(occ),
            "useful_frac_of_occluded": list(use), "available_avg": avail}


def _result(scene: str, nr: tuple[int, int], culled: int, two: int, two_use=(0.9, 0.02, 0.7)) -> dict:
    metrics = {}
    for red in ("pixel", "visibility"):
        metrics[f"{red}/non_redundant"] = _m(*nr)
        metrics[f"{red}/peeling"] = _m(culled, use=(0.9, 0.5, 0.5))
        metrics[f"{red}/peeling_two_sided"] = _m(two, use=two_use)
    return {"scene": scene, "triangles": 1, "metrics": metrics}


def test_useful_table_counts_scenes_where_nr_is_ahead():
    results = [_result("nest", (100, 300), culled=200, two=100), _result("city", (50, 60), culled=40, two=70)]
    table, wins = useful_table(results, "pixel")
    # issue reading: nest 100 < 200 culled, = 100 two-sided; city 50 ≥ 40, < 70
    assert wins == {"issue/peeling": 1, "issue/peeling_two_sided": 1,
                    "thesis/peeling": 2, "thesis/peeling_two_sided": 1}
    assert "0.50 **<1**" in table and "| 1.00 |" in table and "| 1.25 |" in table


def test_layer_table_gap_to_the_thesis():
    # thesis nest peel useful L1, L2 (Table 2): 2 %, 71 %
    results = [_result("nest", (1, 1), culled=1, two=1, two_use=(0.9, 0.02, 0.71))]
    table, gaps = layer_table(results, "pixel")
    assert gaps["peeling_two_sided"] == 0.0
    assert abs(gaps["peeling"] - (abs(50 - 2) + abs(50 - 71)) / 2) < 1e-9
    assert "| nest | L1 | 50 (50) | 50 (2) | 46 (2) |" in table


def test_rig_spread_conventional_gap_is_the_mean_over_i1_i2():
    from bench.rig_spread import conv_gap

    # thesis nest, conventional redundant I1, I2: 70, 80 % (Table 2); 80, 87 % (Table 5)
    nest = {"scene": "nest", "metrics": {"pixel/conventional": {"redundant_frac": [0.0, 0.60, 0.90]},
                                         "visibility/conventional": {"redundant_frac": [0.0, 0.80, 0.87]}}}
    assert abs(conv_gap([nest], "pixel") - 10.0) < 1e-9
    assert abs(conv_gap([nest], "visibility")) < 1e-9
    other = {"scene": "diorama", "metrics": {"pixel/conventional": {"redundant_frac": [0.0, 0.0, 0.0]}}}
    assert abs(conv_gap([nest, other], "pixel") - 10.0) < 1e-9  # scenes the thesis has no row for are skipped

"""bench.host_costs' arithmetic: the per-barrier slope and the one-row-per-host table."""

from __future__ import annotations

import pytest

from bench.host_costs import barrier_slope, merge_rows


def test_barrier_slope_of_an_exact_line():
    a, b = barrier_slope((0, 1, 2, 4), [10.0, 13.0, 16.0, 22.0])
    assert a == pytest.approx(10.0) and b == pytest.approx(3.0)


def test_a_run_replaces_its_hosts_row_and_keeps_the_others():
    rows = [{"host": "a", "v": 1}, {"host": "b", "v": 2}]
    assert merge_rows(rows, {"host": "a", "v": 3}) == [{"host": "b", "v": 2}, {"host": "a", "v": 3}]
    assert merge_rows(rows, {"host": "c", "v": 4}) == [*rows, {"host": "c", "v": 4}]

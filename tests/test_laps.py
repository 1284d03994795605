"""gl_passes.laps.LapClock: laps run end to end, repeat names add up, sync waits for
the GL queue (ctx.finish) before each lap, and an unrecorded clock does nothing."""

import time

import pytest

from gl_passes.laps import LapClock


class _Ctx:
    def __init__(self) -> None:
        self.finished = 0

    def finish(self) -> None:
        self.finished += 1


def test_laps_are_consecutive_and_repeat_names_add_up() -> None:
    ctx = _Ctx()
    clock = LapClock(ctx, ms={"a": 0.0, "b": 0.0, "unused": 0.0})
    time.sleep(0.02)
    clock.lap("a")
    time.sleep(0.01)
    clock.lap("b")
    time.sleep(0.02)
    clock.lap("a")
    total = clock.total_ms()
    assert clock.ms["a"] >= 40.0 and clock.ms["b"] >= 10.0 and clock.ms["unused"] == 0.0
    # the laps tile the clock's life: no time between them is lost or counted twice
    assert sum(clock.ms.values()) == pytest.approx(total, abs=1.0)
    assert ctx.finished == 0


def test_sync_finishes_before_each_lap_and_finish_overrides_it() -> None:
    ctx = _Ctx()
    clock = LapClock(ctx, sync=True)
    clock.lap("a")
    clock.lap("b", finish=False)
    assert ctx.finished == 1
    LapClock(ctx).lap("c", finish=True)
    assert ctx.finished == 2


def test_unrecorded_clock_neither_waits_nor_records() -> None:
    ctx = _Ctx()
    clock = LapClock(ctx, sync=True, record=False)
    clock.lap("a")
    assert clock.ms == {} and ctx.finished == 0

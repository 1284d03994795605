"""Lap timing of a pass's steps (the Server-Timing and bench step tables): each
step's milliseconds run from the end of the step before, and with `sync` each lap
first waits for the GL work queued so far (`ctx.finish()`), so a step's GPU time
lands in its own lap instead of in the next read-back's."""

from __future__ import annotations

import time

import moderngl


class LapClock:
    """`ms[name]`: milliseconds of the steps lapped so far (a name lapped again adds
    to its entry). `record=False` makes every lap a no-op (untimed runs)."""

    def __init__(self, ctx: moderngl.Context, sync: bool = False, ms: dict[str, float] | None = None,
                 record: bool = True) -> None:
        self.ctx, self.sync, self.record = ctx, sync, record
        self.ms: dict[str, float] = {} if ms is None else ms
        self.start = self._t = time.perf_counter()

    def lap(self, name: str, finish: bool | None = None) -> None:
        """End step `name` now; `finish` overrides `sync` for this lap."""
        if not self.record:
            return
        if self.sync if finish is None else finish:
            self.ctx.finish()
        now = time.perf_counter()
        self.ms[name] = self.ms.get(name, 0.0) + (now - self._t) * 1e3
        self._t = now

    def total_ms(self) -> float:
        """Milliseconds since the clock was made."""
        return (time.perf_counter() - self.start) * 1e3

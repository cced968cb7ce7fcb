"""shared.timing.Pacer's accounting on a clock the test drives: every period of a run is a
tick or a skipped one, however the ticks stall (the three-host test's rate claim rests on it;
how many a machine skips is the benchmarks')."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_local_model.shared import timing
from haptic_local_model.shared.timing import Pacer

PERIOD_NS = 1_000_000


class FakeClock:
    """perf_counter_ns and wait_until on a clock that only moves when told: each wait ends at
    its deadline plus the next stall of `stalls` (0 when they run out)."""

    def __init__(self, stalls: list[int]) -> None:
        self.now = 10**12
        self.stalls = list(stalls)

    def perf_counter_ns(self) -> int:
        return self.now

    def wait_until(self, deadline_ns: int, spin_ns: int = 0) -> int:
        self.now = max(self.now, deadline_ns) + (self.stalls.pop(0) if self.stalls else 0)
        return self.now


def paced_run(monkeypatch: Any, stalls: list[int], periods: int) -> Pacer:
    clock = FakeClock(stalls)
    monkeypatch.setattr(timing, "wait_until", clock.wait_until)
    monkeypatch.setattr(timing.time, "perf_counter_ns", clock.perf_counter_ns)
    pacer = Pacer(PERIOD_NS, 0, periods * PERIOD_NS / 1e9)
    pacer.run(lambda now, seq: None, lambda: False)
    return pacer


@settings(max_examples=200, deadline=None)
@given(
    stalls=st.lists(
        st.one_of(st.just(0), st.integers(0, 5 * PERIOD_NS), st.integers(0, 80 * PERIOD_NS)),
        max_size=300,
    ),
    periods=st.integers(1, 400),
)
def test_every_period_is_a_tick_or_a_skipped_one(stalls: list[int], periods: int) -> None:
    with pytest.MonkeyPatch.context() as mp:
        p = paced_run(mp, stalls, periods)
    run = p.ticks + p.skipped
    assert periods - p.overruns <= run <= periods + 1, (p.ticks, p.skipped, p.overruns)
    assert p.figures()["ticks_skipped"] == p.skipped


def test_an_unstalled_run_skips_nothing(monkeypatch: Any) -> None:
    p = paced_run(monkeypatch, [], 250)
    assert (p.ticks, p.skipped, p.overruns) == (251, 0, 0)  # the one at the end included


def test_a_stall_of_three_and_a_half_periods_skips_three(monkeypatch: Any) -> None:
    p = paced_run(monkeypatch, [0, 0, 3_500_000], 20)
    assert (p.skipped, p.overruns) == (3, 1)

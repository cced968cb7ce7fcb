"""A real-time log's tick times (haptic_server.logger.TickDeadlines): each tick is logged at
its deadline on the wall clock, rebuilt from the rows' lateness, and agrees with the
deadlines the loop's own rule (haptic_server.paced.open_tick) kept, stalls included;
the rows' time t (clamped dts) would fall behind."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_local_model.haptic_server.logger import TickDeadlines
from haptic_local_model.haptic_server.paced import loop_record, open_tick
from haptic_local_model.shared.timing import wall_clock_at

PERIOD_NS = 1_000_000
WALL_START_NS = 1_700_000_000_000_000_000
# a tick's lateness: mostly microseconds, now and then a stall of up to 40 periods
LATENESS = st.one_of(st.integers(0, 80_000), st.integers(0, 80_000), st.integers(0, 40 * PERIOD_NS))


def _run(lateness_ns: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The loop's rule over ticks that start this late after their deadlines: the deadlines
    it kept, the rows' lateness (us) and time t (the sum of clamped dts)."""
    loop = loop_record(PERIOD_NS, (0.25, 2.0), 100 * PERIOD_NS)
    lp = loop[0]
    start = 0
    lp["deadline_ns"] = start + PERIOD_NS
    lp["last_start_ns"] = start
    deadlines, late_us, t = [], [], [0.0]
    for late in lateness_ns:
        deadlines.append(int(lp["deadline_ns"]))
        open_tick(loop, int(lp["deadline_ns"]) + late)
        late_us.append(float(lp["lateness_ns"]) / 1e3)
        t.append(t[-1] + float(lp["dt"]))
        lp["tick"] += 1
        lp["deadline_ns"] += PERIOD_NS
    return np.array(deadlines), np.array(late_us), np.array(t[:-1])


@settings(max_examples=200, deadline=None)
@given(lateness=st.lists(LATENESS, min_size=1, max_size=300), cut=st.integers(1, 300))
def test_the_log_times_are_the_loops_deadlines(lateness: list[int], cut: int) -> None:
    """Drained in two parts, as the writer drains the ring: the same deadlines."""
    deadlines, late_us, _ = _run(lateness)
    times = TickDeadlines(PERIOD_NS)
    logged = times.of(late_us[:cut], WALL_START_NS) + times.of(late_us[cut:], WALL_START_NS)
    np.testing.assert_array_equal(np.array(logged) - WALL_START_NS, deadlines)


def test_a_stall_moves_the_deadlines_and_t_falls_behind() -> None:
    """A 7.5-period stall at tick 10: the deadlines restart from that tick's start; t, its
    interval of 8.5 periods clamped to two, ends 6.5 periods behind them (the log's times
    were t's)."""
    lateness = [1_000] * 30
    lateness[10] = 7_500_000
    deadlines, late_us, t = _run(lateness)
    logged = np.array(TickDeadlines(PERIOD_NS).of(late_us, 0))
    np.testing.assert_array_equal(logged, deadlines)
    assert logged[11] == logged[10] + 7_500_000 + PERIOD_NS
    behind = logged[-1] - PERIOD_NS - round(t[-1] * 1e9)
    assert abs(behind - 6_500_000) <= 2_000, behind  # the ticks' 1 us aside


def test_lost_rows_keep_the_count_of_deadlines() -> None:
    times = TickDeadlines(PERIOD_NS)
    times.of(np.zeros(3), 0)
    times.skip(5)
    assert times.of(np.zeros(1), 0) == [9 * PERIOD_NS]


def test_the_wall_clock_at_a_monotonic_reading() -> None:
    """Read straight after one another, the wall clock and the converted monotonic reading
    agree to well within the 50 us the pointer test allows (tests/test_pointer.py)."""
    import time

    gaps = []
    for _ in range(20):
        mono = time.perf_counter_ns()
        wall = time.time_ns()
        gaps.append(wall - wall_clock_at(mono))
    assert abs(float(np.median(gaps))) < 5_000, gaps

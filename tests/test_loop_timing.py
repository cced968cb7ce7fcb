"""The loop-timing benchmark's split of work per tick into update ticks and the rest."""

from __future__ import annotations

import numpy as np

from haptic_local_model.benchmarks.loop_timing import bare_loop, median_of, work_split
from haptic_local_model.haptic_server.model import TICK_DTYPE


def test_work_split_attributes_each_row_to_the_tick_before() -> None:
    ticks = np.zeros(8, TICK_DTYPE)
    # installs at ticks 0 (first model), 3 and 6; row k holds the work of tick k - 1
    ticks["update_seq"] = [0, 0, 0, 1, 1, 1, 2, 2]
    work_of_tick = np.array([90.0, 10, 10, 80, 10, 10, 70])
    ticks["work_us"][1:] = work_of_tick
    split = work_split(ticks)
    assert split["update_ticks"]["n"] == 3
    assert split["other_ticks"]["n"] == 4
    assert split["update_ticks"]["p50"] == 80.0
    assert split["other_ticks"]["max"] == 10.0


def test_median_of_repeated_runs() -> None:
    runs = [
        {
            "ticks": n,
            "tick_rate_hz": n / 0.1,
            "late_ticks_over_1ms": late,
            "overruns": late,
            "realtime_priority": True,
            "lateness_us": {"p50": 0.0, "p99_9": p999},
        }
        for n, late, p999 in ((100, 5, 40.0), (110, 1, 900.0), (90, 3, 60.0))
    ]
    m = median_of(runs)
    assert (m["ticks"], m["late_ticks_over_1ms"], m["lateness_us"]["p99_9"]) == (100, 3, 60.0)
    assert "work_us" not in m


def test_the_bare_loop_counts_every_deadline_at_a_high_rate() -> None:
    out = bare_loop(0.02, 100_000)  # 10 kHz for 20 ms, the loop's own compiled wait
    assert out["ticks"] == 200
    # measured over the wall time (a stall and its resynchronisation lose ticks); never
    # above nominal: the first deadline is a period after the start
    assert 0.0 < out["tick_rate_hz"] <= 10_000.0
    assert 0 <= out["overruns"] <= out["ticks"]
    assert out["lateness_us"]["p50"] >= 0.0  # never early: the wait returns at the deadline

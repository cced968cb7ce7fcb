"""The local model's kind of the one compiled real-time loop (haptic_server.realtime's
local_paced: paced_ticks over its hook and its burst), run with deadlines a nanosecond
apart and dt clamped to 1 ms: it runs as fast as it computes, and its ticks are the
engine's own ticks at that dt. Its rows go into the sidecar's ring with their timing, and
it hands the opened tick to the supervisor on the run's end, on a watchdog deadline and on
an update whose install needs the engine's Python side."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from haptic_local_model.device_models.common import refill_noise
from haptic_local_model.device_models.registry import load_device
from haptic_local_model.haptic_server.engine import HapticEngine
from haptic_local_model.haptic_server.mailbox import (
    C_TICK_HEAD,
    C_UPD_HEAD,
    C_UPD_READ,
    MAILBOX_DTYPE,
    N_CTL,
)
from haptic_local_model.haptic_server.model import TICK_DTYPE
from haptic_local_model.haptic_server.paced import (
    RETURNED_DONE,
    RETURNED_NOISE,
    RETURNED_SUPERVISE,
    RETURNED_TO_PYTHON,
    loop_record,
)
from haptic_local_model.haptic_server.realtime import local_paced, local_windows, local_world
from haptic_local_model.haptic_server.simulated import run_ticks
from haptic_local_model.haptic_server.world import drive_paced
from haptic_local_model.shared.config import load_scene, load_user

NEVER = np.iinfo(np.int64).max
TICKS = 1500  # past the first noise block (a refill, then the opened tick runs compiled)


def _engine() -> HapticEngine:
    return HapticEngine(load_scene("testbed"), load_device("maglev"), load_user("swing"))


class Local:
    """An engine with its loop record (1 ns periods, dt 1 ms), a ring of TICKS rows, its
    windows, and the paced loop's status after each call."""

    def __init__(self) -> None:
        self.engine = _engine()
        self.loop = loop_record(1, (1e6, 1e6), 1)
        lp = self.loop[0]
        lp["end_ns"] = lp["trip_at_ns"] = lp["return_at_ns"] = NEVER
        lp["budget"] = 8
        self.ctl = np.zeros(N_CTL, np.int64)
        self.ring_io: tuple[Any, ...] = (
            np.zeros(TICKS, TICK_DTYPE), self.ctl, np.zeros(4, MAILBOX_DTYPE),
            np.zeros(TICKS), np.zeros(TICKS), np.zeros(8), np.zeros(3), self.engine.row,
        )  # fmt: skip
        self.ts = np.zeros(2, np.int64)

    def run(self) -> int:
        """local_paced, driven as the loop drives it (drive_paced), until it returns other
        than for a spent noise block (refilled at the opened tick's dt)."""
        engine, ring_io = self.engine, self.ring_io
        world, windows = local_world(engine, self.loop, ring_io), local_windows(ring_io)
        sim = engine.sim_device
        assert sim is not None
        return drive_paced(
            lambda: local_paced(world, ring_io[0], self.loop, windows, self.ts),
            lambda: refill_noise(sim.noise, sim.records, float(self.loop[0]["dt"])),
            lambda: False,
        )


@pytest.mark.parametrize(
    ("statuses", "goes_on", "ended", "refills", "asked"),
    [
        ([RETURNED_NOISE, RETURNED_NOISE, RETURNED_DONE], True, RETURNED_DONE, 2, 0),
        ([RETURNED_TO_PYTHON, RETURNED_NOISE, RETURNED_SUPERVISE], True, RETURNED_SUPERVISE, 1, 1),
        ([RETURNED_TO_PYTHON, RETURNED_TO_PYTHON, RETURNED_DONE], True, RETURNED_DONE, 0, 2),
        ([RETURNED_NOISE, RETURNED_TO_PYTHON, RETURNED_DONE], False, RETURNED_TO_PYTHON, 1, 1),
    ],
)
def test_the_paced_loop_s_python_side_refills_asks_between_ticks_and_returns_the_rest(
    statuses, goes_on, ended, refills, asked
):
    """drive_paced, the one Python side of the compiled loop for every world: a spent noise
    block refilled and the loop entered again; between two ticks, `between` asked whether
    to go on; the rows all run or a tick for the supervisor returned as they are."""
    script, seen = iter(statuses), {"refill": 0, "between": 0}

    def between() -> bool:
        seen["between"] += 1
        return goes_on

    def refill() -> None:
        seen["refill"] += 1

    assert drive_paced(lambda: next(script), refill, between) == ended
    assert seen == {"refill": refills, "between": asked}
    assert list(script) == statuses[statuses.index(ended) + 1 :]  # not entered again


def test_the_local_loop_runs_the_engine_s_ticks_into_the_ring():
    local = Local()
    local.loop[0]["stop_tick"] = TICKS
    assert local.run() == RETURNED_DONE
    lp = local.loop[0]
    assert lp["tick"] == local.ctl[C_TICK_HEAD] == TICKS
    assert lp["overruns"] == TICKS  # each tick started more than a period late
    ring = local.ring_io[0]
    assert list(ring["tick"]) == list(range(TICKS))
    # the same ticks at a fixed 1 ms on another engine: the same rows but their timing
    other = _engine()
    sim = other.sim_device
    assert sim is not None
    rows, k = np.zeros(TICKS, TICK_DTYPE), 0
    while k < TICKS:
        k = run_ticks(other.recs, sim.records, other.user, 1e-3, rows, k, TICKS)
        if k < TICKS:
            refill_noise(sim.noise, sim.records, 1e-3)
    timing = ("lateness_us", "work_us")
    for name in TICK_DTYPE.names:
        if name not in timing:
            assert ring[name].tobytes() == rows[name].tobytes(), name
    # each row's lateness and the work of the tick before: the loop's own measures
    lateness, work, peaks = local.ring_io[3], local.ring_io[4], local.ring_io[6]
    assert np.array_equal(ring["lateness_us"], lateness)
    assert np.array_equal(ring["work_us"][1:], work[:-1])
    assert work[-1] == lp["work_prev_us"] > 0
    assert peaks[0] == lateness.max() and peaks[1] == work.max()


@pytest.mark.parametrize("why", ["end", "watchdog", "install"])
def test_the_local_loop_hands_the_opened_tick_to_the_supervisor(why):
    """After 3 quiet ticks, the 4th is opened (its start and lateness kept) but not run:
    the run's end, a watchdog that may trip, an update waiting while the engine has had
    none (its install re-initialises the engine in Python)."""
    local = Local()
    lp = local.loop[0]
    lp["stop_tick"] = 3
    assert local.run() == RETURNED_DONE
    lp["stop_tick"] = 10  # without the hand-over it would run on to the 10th tick
    if why == "end":
        lp["end_ns"] = 0
    elif why == "watchdog":
        lp["trip_at_ns"] = 0
    else:
        local.ctl[C_UPD_HEAD] = 1
    started = int(lp["last_start_ns"])
    assert local.run() == RETURNED_SUPERVISE
    assert lp["tick"] == local.ctl[C_TICK_HEAD] == 3  # not run, no row
    assert lp["now_ns"] == lp["last_start_ns"] > started  # opened
    assert local.ring_io[3][3] == lp["lateness_ns"] / 1e3 > 0
    assert local.ctl[C_UPD_READ] == 0  # the update is left to the supervisor
    assert local.ring_io[0]["tick"][3] == 0


def test_the_local_loop_returns_after_a_tick_with_a_fault_to_report():
    """A fault the Python side has not reported (here: the reported one differs from the
    engine's, none) brings the loop back after the tick, between two ticks."""
    local = Local()
    lp = local.loop[0]
    lp["fault_reported"] = 1
    lp["stop_tick"] = 10  # without the return it would run on to the 10th tick
    for tick in (1, 2):
        assert local.run() == RETURNED_TO_PYTHON
        assert lp["tick"] == local.ctl[C_TICK_HEAD] == tick

"""The live view's degrade policy (haptic_server/view_degrade.py): down a level on an
install gap of half the watchdog budget, at most one step per HOLD_S, back up one level
after QUIET_S without strain; and the install gap read from tick rows."""

from __future__ import annotations

import json
import os
import signal
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from test_live_view import Proc, procs  # noqa: F401

from haptic_local_model.haptic_server.view_degrade import (
    HOLD_S,
    LEVELS,
    QUIET_S,
    STRAIN_FRACTION,
    DegradePolicy,
    InstallGap,
)

WATCHDOG_MS = 100.0
STRAIN_S = STRAIN_FRACTION * WATCHDOG_MS / 1e3  # 50 ms
SIM_PERIOD_S = 1 / 60  # a healthy sim's install gap


def test_healthy_gaps_keep_the_full_view() -> None:
    policy = DegradePolicy(WATCHDOG_MS)
    for i in range(600):  # 10 s of 60 Hz installs, each gap just under the strain
        assert policy.observe(i * SIM_PERIOD_S, STRAIN_S * 0.99) is None
    assert policy.level is LEVELS[0]


def test_strain_steps_down_once_per_hold_and_says_what_it_dropped() -> None:
    policy = DegradePolicy(WATCHDOG_MS)
    said = policy.observe(1.0, STRAIN_S)
    assert said is not None and policy.level is LEVELS[1]
    assert LEVELS[1].dropped in said and "50 ms" in said
    # strain again within the hold: no second step
    assert policy.observe(1.0 + HOLD_S / 2, 2 * STRAIN_S) is None
    assert policy.level is LEVELS[1]
    # strain after the hold: one more step, down to the last level and no further
    t = 1.0
    for expected in LEVELS[2:]:
        t += HOLD_S
        assert policy.observe(t, STRAIN_S) is not None
        assert policy.level is expected
    assert policy.observe(t + HOLD_S, STRAIN_S) is None
    assert policy.level is LEVELS[-1]


def test_levels_shed_in_the_order_forces_world_rate_board() -> None:
    rates = [level.frame_hz for level in LEVELS]
    assert rates == sorted(rates, reverse=True)
    first_without_forces = next(i for i, lv in enumerate(LEVELS) if not lv.forces)
    world = [level.world_hz for level in LEVELS]
    assert world == sorted(world, reverse=True) and world[-1] == 0.0
    first_slow_world = next(i for i, w in enumerate(world) if w < world[0])
    assert first_without_forces < first_slow_world < len(LEVELS) - 1


def test_quiet_steps_back_up_one_level_at_a_time() -> None:
    policy = DegradePolicy(WATCHDOG_MS)
    policy.observe(0.0, STRAIN_S)
    policy.observe(HOLD_S, STRAIN_S)
    assert policy.level is LEVELS[2]
    last_strain = HOLD_S
    # just short of the quiet period: still degraded
    assert policy.observe(last_strain + QUIET_S - 0.01, SIM_PERIOD_S) is None
    said = policy.observe(last_strain + QUIET_S, SIM_PERIOD_S)
    assert said is not None and "restored" in said and policy.level is LEVELS[1]
    # the next step up needs another quiet period from that change
    assert policy.observe(last_strain + QUIET_S + 1.0, SIM_PERIOD_S) is None
    assert policy.observe(last_strain + 2 * QUIET_S, SIM_PERIOD_S) is not None
    assert policy.level is LEVELS[0]


def test_strain_during_the_quiet_period_restarts_it() -> None:
    policy = DegradePolicy(WATCHDOG_MS)
    policy.observe(0.0, STRAIN_S)
    policy.observe(QUIET_S - 1.0, STRAIN_S)  # strain again: a second step, quiet from here
    assert policy.level is LEVELS[2]
    assert policy.observe(2 * QUIET_S - 1.01, SIM_PERIOD_S) is None
    assert policy.observe(2 * QUIET_S - 1.0, SIM_PERIOD_S) is not None


def test_a_bad_watchdog_budget_is_refused() -> None:
    with pytest.raises(ValueError, match="watchdog_ms"):
        DegradePolicy(0.0)


def test_install_gap_from_tick_rows() -> None:
    gap = InstallGap()
    assert gap.gap_s(1.0, 5) == 0.0  # the first row seen starts the count
    assert gap.gap_s(1.03, 5) == pytest.approx(0.03)
    assert gap.gap_s(1.08, 5) == pytest.approx(0.08)
    assert gap.gap_s(1.09, 6) == 0.0  # a new install
    assert gap.gap_s(1.1, 6) == pytest.approx(0.01)


# -- end to end: the sim stopped for real under a live view --------------------------------

STALL_S = 0.08  # the sim stopped this long: past the strain (50 ms), short of the watchdog
STALL_TRIES = 5  # a stall the view's 60 Hz poll misses (a loaded machine) is tried again
DEGRADED_WAIT_S = 2.0  # the view says it within a few of its frames
RUN_S = 60  # ample: the test stops the run (SIGTERM, by its pid) once the view is back


def _said(proc: Any, text: str, since: int = 0) -> list[str]:
    return [line for line in proc.lines[since:] if text in line]


def _wait_said(proc: Any, text: str, timeout_s: float, since: int = 0) -> str:
    end = time.monotonic() + timeout_s
    while not _said(proc, text, since):
        assert proc.proc.poll() is None, f"exited {proc.proc.returncode}: {proc.lines}"
        if time.monotonic() > end:
            return ""
        time.sleep(0.05)
    return _said(proc, text, since)[0]


@pytest.mark.processes
def test_a_stopped_sim_lowers_the_live_view_and_quiet_restores_it(
    tmp_path: Path,
    procs: list[Any],  # noqa: F811
) -> None:
    """`haptic-run --view` on the testbed, no browser: the sim is stopped (SIGSTOP, by its
    pid) for 80 ms; the view sees the install gap in the loop's tick rows, steps down to
    'no forces' and says what it dropped and why (the gap, >= half the watchdog); QUIET_S
    later, without another stall, it steps back up to 'full' and says so."""
    from haptic_local_model.benchmarks.browser import free_ports

    web, grpc = free_ports(2)
    run = Proc(
        [sys.executable, "-m", "haptic_local_model.haptic_server.harness.run", "--duration",
         str(RUN_S), "--view", "--view-port", str(web), "--view-grpc-port", str(grpc),
         "--json-events"],
        tmp_path,
    )  # fmt: skip
    procs.append(run)
    run.url()  # the view serves
    end = time.monotonic() + 120.0
    while not (ready := [json.loads(x) for x in run.out if '"event": "ready"' in x]):
        assert run.proc.poll() is None and time.monotonic() < end, run.lines
        time.sleep(0.1)
    sim_pid = int(ready[0]["sim_pid"])
    time.sleep(3.0)  # the sim's updates installing, the view drawing them
    assert not _said(run, "view degraded"), run.lines  # a quiet run does not degrade
    degraded, stalled_at = "", 0.0
    try:
        for _ in range(STALL_TRIES):
            os.kill(sim_pid, signal.SIGSTOP)
            stalled_at = time.monotonic()
            time.sleep(STALL_S)
            os.kill(sim_pid, signal.SIGCONT)
            if degraded := _wait_said(run, "view degraded", DEGRADED_WAIT_S):
                break
            time.sleep(HOLD_S)
    finally:
        os.kill(sim_pid, signal.SIGCONT)
    assert degraded, f"no step down after {STALL_TRIES} stalls of {STALL_S} s: {run.lines}"
    print(f"\n{degraded.strip()}")
    assert f"to '{LEVELS[1].name}': dropped {LEVELS[1].dropped}" in degraded
    gap_ms = float(degraded.split("no sim update for ")[1].split(" ms")[0])
    assert STRAIN_S * 1e3 <= gap_ms < 1e3 * (STALL_S + 0.1), degraded  # the stall, and why
    since = len(run.lines)
    restored = _wait_said(run, "view restored", QUIET_S + 15.0, since)
    back_after_s = time.monotonic() - stalled_at
    assert restored, f"not restored {QUIET_S + 15.0} s after: {run.lines[since:]}"
    print(f"{restored.strip()} ({back_after_s:.1f} s after the stall)")
    assert f"to '{LEVELS[0].name}': undid '{LEVELS[1].name}', which dropped" in restored
    assert back_after_s >= QUIET_S, back_after_s  # not before the quiet period
    assert run.stop() == 0, run.lines
    changes = _said(run, "level changes, ended at")
    assert changes and f"2 level changes, ended at '{LEVELS[0].name}'" in changes[0], run.lines

"""The live view's degrade policy (haptic_server/view_degrade.py): down a level on an
install gap of half the watchdog budget, at most one step per HOLD_S, back up one level
after QUIET_S without strain; and the install gap read from tick rows."""

from __future__ import annotations

import pytest

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

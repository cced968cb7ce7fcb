"""A station's drift from the world (benchmarks/station_links.py, registration and drift;
issue 46's done-when 3), on two logs made here whose clocks, lag and re-index are known."""

from __future__ import annotations

import numpy as np
import pytest

from haptic_local_model.benchmarks.station_links import REST_S, drift, registration
from haptic_local_model.haptic_server.ports import PORT_ROW_DTYPE
from haptic_local_model.haptic_server.stages.station import STATION_ROW_DTYPE

DT = 1e-3
STATION_START_NS = 50_000_000_000
WORLD_AHEAD_S = 2.5  # the world's loop started this long before the station's
DELAY_S = 0.15  # the world feeds the device pose this old
SPEED = 0.004  # m/s, the device's motion between 6 and 8 s of the station's clock
REINDEX_S = 16.0  # at this station time the world re-indexes the port ...
JUMP = np.array([0.0007, -0.0002, 0.003])  # ... and its registration moves by this
REGISTERED = np.array([0.0001, 0.0004, -0.002])  # the registration it took at the join
P = 1  # the port


def device_x(t: np.ndarray) -> np.ndarray:
    """The device's x at station time t: at rest, SPEED from 6 to 8 s, then at rest."""
    return 0.02 + SPEED * np.clip(t - 6.0, 0.0, 2.0)


def logs(seconds: float = 30.0) -> tuple[np.ndarray, np.ndarray, int]:
    """A station's rows and a world's (its port P fed the device DELAY_S late, through
    REGISTERED, and REGISTERED + JUMP after REINDEX_S), and the world's loop start."""
    n = round(seconds / DT)
    st = np.zeros(n, STATION_ROW_DTYPE)
    st["t"] = np.arange(n) * DT
    st["wall_ns"] = STATION_START_NS + np.arange(n) * 1_000_000 + 300_000  # paced, a bit late
    st["pose"][:, 0] = device_x(st["t"])
    st["pose"][:, 1] = -0.03
    st["pose"][:, 2] = 3.14  # near pi: the angle's difference wraps
    m = round((seconds + WORLD_AHEAD_S + 1.0) / DT)
    world = np.zeros(m, PORT_ROW_DTYPE)
    world["t"] = np.arange(m) * DT
    station_t = world["t"] - WORLD_AHEAD_S  # the same instant on the station's clock
    seen = station_t - DELAY_S
    offset = np.where((station_t >= REINDEX_S)[:, None], REGISTERED + JUMP, REGISTERED)
    world["device_pose"][:, P, 0] = device_x(seen) + offset[:, 0]
    world["device_pose"][:, P, 1] = -0.03 + offset[:, 1]
    angle = 3.14 + offset[:, 2]
    world["device_pose"][:, P, 2] = np.arctan2(np.sin(angle), np.cos(angle))
    world_start_ns = STATION_START_NS - round(WORLD_AHEAD_S * 1e9)
    return st, world, world_start_ns


def test_at_rest_the_registration_is_the_worlds_offset_and_in_motion_the_lag_too() -> None:
    """At rest the world's device less the station's is the registration the world took (mm,
    mrad); in motion at v it is −v × delay more (the closed form of a delayed ramp); after
    the re-index the registration has moved by the jump."""
    st, world, start = logs()
    at_rest = registration(st, world, start, P, (4.0, 5.0))
    assert at_rest == pytest.approx(REGISTERED * 1e3, abs=1e-9)
    moving = registration(st, world, start, P, (6.5, 7.5))
    # the world's row nearest the station's tick: at most half a tick apart, SPEED DT / 2
    lag = (REGISTERED[0] - SPEED * DELAY_S) * 1e3
    assert moving[0] == pytest.approx(lag, abs=SPEED * DT / 2 * 1e3)
    assert registration(st, world, start, P, (20.0, 21.0)) == pytest.approx(
        (REGISTERED + JUMP) * 1e3, abs=1e-9
    )


def test_the_drift_is_the_registrations_walk_between_rests_and_the_last_is_quoted() -> None:
    """Before the re-index the rests agree (the motion between them, lagged, is no drift);
    after it each is the jump away: hypot(jump x, y) mm, |jump angle| mrad."""
    st, world, start = logs()
    d = drift(st, world, start, P)
    assert [tuple(w) for w in d["rests_s"]] == list(REST_S)
    jump_mm = float(np.hypot(*JUMP[:2])) * 1e3
    assert d["apart_mm"] == pytest.approx([0.0, jump_mm, jump_mm], abs=1e-9)
    assert d["apart_mrad"] == pytest.approx([0.0, JUMP[2] * 1e3, JUMP[2] * 1e3], abs=1e-9)
    assert d["drift_mm"] == pytest.approx(jump_mm, abs=1e-9)


def test_a_shorter_run_measures_the_rests_it_reached_and_a_world_that_ended_says_nan() -> None:
    """A 14 s run (the CI's reduced point) has the rest before the press and after it; a
    window the world's rows do not cover is NaN, not a number."""
    st, world, start = logs(14.0)
    d = drift(st, world, start, P)
    assert [tuple(w) for w in d["rests_s"]] == list(REST_S[:2])
    assert d["drift_mm"] == pytest.approx(0.0, abs=1e-9)
    assert np.isnan(registration(st, world[:1000], start, P, (12.5, 13.0))).all()

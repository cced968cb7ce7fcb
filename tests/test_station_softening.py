"""A station says when its passivity controller softens it (issue 46: a station whose link
degrades past what it can render passively says so, event and summary): `softened` once
the controller damped its device on SOFTENED_SHARE of the last SOFTEN_WINDOW_S of ticks,
`restored` once that share is down to RESTORED_SHARE; through the station's own rows."""

from __future__ import annotations

import numpy as np
import pytest

from haptic_local_model.device_models.registry import load_simulated_device
from haptic_local_model.haptic_server.station import (
    RESTORED_SHARE,
    SOFTEN_WINDOW_S,
    SOFTENED_SHARE,
    Softening,
    Station,
)
from haptic_local_model.shared.config import load_user
from haptic_local_model.shared.net.stations import load_station_network
from haptic_local_model.shared.port_config import load_port_scene

WINDOW = 20
NONE = np.zeros(3)


def _feed(s: Softening, damped: list[bool], t0: int = 0) -> list[tuple[int, str]]:
    """The ticks (from t0) at which events came, and which."""
    got = []
    for k, d in enumerate(damped):
        e = s.add(d, (t0 + k) * 1e-3, np.array([7.0 if d else 0.0, 0.0, 0.0]))
        if e is not None:
            got.append((t0 + k, e["event"]))
    return got


def test_softened_once_the_share_reaches_its_bound_and_restored_once_it_falls_to_its_own() -> None:
    s = Softening(WINDOW)
    assert _feed(s, [False] * 50) == []
    on = round(SOFTENED_SHARE * WINDOW)  # damped ticks in the window that make it softened
    assert on == 4
    got = _feed(s, [True] * 10, 50)  # the window's 4th damped tick: share 0.2
    assert got == [(50 + on - 1, "softened")]
    assert s.events[0] == {"event": "softened", "t_s": 0.053, "damped_share": 0.2,
                           "damping": [7.0, 0.0, 0.0]}  # fmt: skip
    # ten damped ticks leave the window one a tick, from the 20th undamped one on: at most
    # RESTORED_SHARE * WINDOW = 1 left when the 29th undamped tick (index 28) comes
    got = _feed(s, [False] * 40, 60)
    off = round(RESTORED_SHARE * WINDOW)
    assert got == [(60 + WINDOW - 10 + (10 - off) - 1, "restored")]
    assert [e["event"] for e in s.events] == ["softened", "restored"]


def test_between_the_bounds_it_stays_as_it_was() -> None:
    """Hysteresis: 2 damped ticks in 20 (10 %) neither softens a station that is not nor
    restores one that is."""
    steady = ([True] + [False] * 9) * 10
    s = Softening(WINDOW)
    assert _feed(s, steady) == []
    s = Softening(WINDOW)
    assert _feed(s, [True] * WINDOW) == [(WINDOW - 1, "softened")]  # its first whole window
    assert _feed(s, steady, WINDOW) == []
    assert s.on


def test_nothing_is_said_before_a_whole_window() -> None:
    s = Softening(WINDOW)
    assert _feed(s, [True] * (WINDOW - 1)) == []
    assert _feed(s, [True], WINDOW - 1) == [(WINDOW - 1, "softened")]


def test_a_station_says_it_from_its_rows_in_its_summary_and_live() -> None:
    """The damping the compiled tick left in the station's record, through its row: the
    events in the summary's passivity section and to `on_event` as they happen."""
    scene = load_port_scene("grasp_vertical")
    network = load_station_network("stations_loopback", "left")
    station = Station(scene, network, "left", load_simulated_device("ideal"),
                      load_user("squeeze_left_2n"), 2000)  # fmt: skip
    heard: list[dict] = []
    station.on_event = heard.append
    window = round(SOFTEN_WINDOW_S / scene.period_s)
    st = station.station[0]
    for k in range(2 * window):
        st["pc_damping"][1] = 3.0 if window <= k < window + window // 2 else 0.0
        station.log(k * 1_000_000, 0)
    events = station.summary()["passivity"]["events"]
    assert [e["event"] for e in events] == ["softened"]
    assert events[0]["t_s"] == pytest.approx((window + SOFTENED_SHARE * window) * scene.period_s)
    assert events[0]["damping"] == [0.0, 3.0, 0.0]
    assert heard == events

"""The two real processes over Zenoh on loopback, checked from the MCAP log."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import haptic_run

from haptic_local_model.haptic_server.foxglove_view import LOG_TOPIC
from haptic_local_model.haptic_server.harness.summary import summarise
from haptic_local_model.haptic_server.log import (
    EVENT_TOPIC,
    TICK_TOPIC,
    UPDATE_TOPIC,
    iter_messages,
    read_json_topic,
    read_log,
    read_ticks,
)

REPO = Path(__file__).resolve().parent.parent
RUN_S = 4.0
PUSH_N, BOX_KG = 0.2, 1.0
# The proxy integrates with the measured dt (clamped to 2 ms), so semi-implicit Euler lags
# the closed form by at most a * dt_max * t / 2 = 0.2 mm over the first second.
CLOSED_FORM_TOL_M = PUSH_N / BOX_KG * 2e-3 * 1.0 / 2 * 1.25
MIN_TICK_FRACTION = 0.95
MIN_UPDATE_RATE_HZ = 25.0
MIN_FREE_FLIGHT_S = 0.5  # the closed form is checked over at least this much free flight


@pytest.mark.processes
def test_two_processes_over_zenoh(tmp_path: Path, network_file: Path) -> None:
    log = tmp_path / "run.mcap"
    summary_path = tmp_path / "summary.json"
    summary = haptic_run(
        network_file, log, summary_path,
        scene="free_box", device="ideal", user="constant_push", seconds=RUN_S,
    )  # fmt: skip

    ticks = read_ticks(log)
    topics = [t for t, _ in iter_messages(log)]
    assert topics.count(TICK_TOPIC) == len(ticks) == summary["ticks"]
    assert len(ticks) >= MIN_TICK_FRACTION * RUN_S * 1000
    updates = topics.count(UPDATE_TOPIC)
    assert updates / RUN_S >= MIN_UPDATE_RATE_HZ
    assert summary["updates_installed"] == summary["updates_received"] == updates
    # one name per figure: the log's summary gives the run's update age (publish -> installed)
    # to the microsecond, and its transit (publish -> received) is part of it
    from_log = summarise(read_log(log))
    for p in ("p50", "p99", "max"):
        assert from_log["update_age_ms"][p] == pytest.approx(summary["update_age_ms"][p], abs=1e-3)
    assert from_log["update_transit_ms"]["p50"] <= from_log["update_age_ms"]["p50"]
    # every event of the run is also a foxglove.Log, for Foxglove's Log panel
    assert topics.count(EVENT_TOPIC) >= 2  # at least the re-initialisation and the stop
    assert topics.count(LOG_TOPIC) == topics.count(EVENT_TOPIC)

    # the proxy under a constant push: x = F t^2 / 2m from the first installed update on, up
    # to contact, or to a watchdog trip if the machine stalled the sim for 100 ms (then the
    # proxy restarts from the sim's tool by design; tests/test_faults.py covers that)
    ready = ticks[ticks["update_seq"] >= 0]
    t = ready["t"] - ready["t"][0]
    x = ready["vm_pose"][:, 0] - ready["vm_pose"][0, 0]
    trips = [int(e["tick"]) for e in read_json_topic(log, EVENT_TOPIC) if e["kind"] == "watchdog"]
    end = min(
        [1.0]
        + [float(t[np.searchsorted(ready["tick"], k)]) for k in trips if k >= ready["tick"][0]]
    )
    assert end >= MIN_FREE_FLIGHT_S, f"a watchdog trip after only {end:.2f} s of free flight"
    before_contact = t < end
    assert ready["n_active"][before_contact].max() == 0
    x_closed = PUSH_N * t[before_contact] ** 2 / (2 * BOX_KG)
    err = np.abs(x[before_contact] - x_closed).max()
    assert err < CLOSED_FORM_TOL_M, f"proxy off the closed form by {err * 1e3:.3f} mm"

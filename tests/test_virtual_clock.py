"""The virtual clock: closed forms, determinism (the same code as the real-time servers)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from haptic_local_model.haptic_server.harness.virtual import run_virtual_named
from haptic_local_model.haptic_server.log import TICK_TOPIC, UPDATE_TOPIC, read_ticks

PUSH_N = 0.2  # configs/users/constant_push.toml
BOX_KG = 1.0  # configs/scenes/free_box.toml
DT = 1e-3
# Semi-implicit Euler under constant force lags the closed form by a*dt*t/2 (0.1 mm at 1 s).
EULER_TOL_M = PUSH_N / BOX_KG * DT * 1.0 / 2 * 1.05


def test_free_mass_matches_closed_form_before_contact() -> None:
    ticks = run_virtual_named("free_box", "ideal", "constant_push", 1.0).ticks
    t = ticks["t"]
    x_closed = PUSH_N * t**2 / (2 * BOX_KG)
    assert np.all(ticks["n_active"] == 0)  # no contact yet in the first second
    np.testing.assert_allclose(ticks["vm_pose"][:, 0], x_closed, atol=EULER_TOL_M)
    np.testing.assert_allclose(ticks["device_pose"][:, 0], x_closed, atol=EULER_TOL_M)
    assert np.abs(ticks["vm_pose"][:, 1:]).max() == 0.0  # no force off-axis, no motion


@pytest.mark.processes
def test_two_runs_log_identical_forces(tmp_path: Path) -> None:
    a = run_virtual_named("free_box", "ideal", "waypoints", 3.0, tmp_path / "a.mcap")
    b = run_virtual_named("free_box", "ideal", "waypoints", 3.0, tmp_path / "b.mcap")
    ta, tb = read_ticks(tmp_path / "a.mcap"), read_ticks(tmp_path / "b.mcap")
    assert len(ta) == len(tb) == 3000
    assert ta["n_active"].max() > 0  # the hand pushes the box into a wall: contacts ran
    for field in (
        "wrench_command",
        "f_contact",
        "f_impulse",
        "f_coordination",
        "vm_pose",
        "proxy_q",
    ):
        np.testing.assert_array_equal(ta[field], tb[field], err_msg=field)
    np.testing.assert_array_equal(ta, a.ticks)  # the log holds exactly what was computed
    assert a.updates == b.updates == 180


@pytest.mark.processes
def test_a_virtual_log_starts_at_the_run_s_wall_clock_time(tmp_path: Path) -> None:
    """A viewer places a virtual-clock log at the time it was run (not at 1970): every
    message's log time is the run's wall-clock start plus its virtual time."""
    before = time.time_ns()
    run_virtual_named("free_box", "ideal", "waypoints", 1.0, tmp_path / "v.mcap")
    after = time.time_ns()
    ticks = read_ticks(tmp_path / "v.mcap")
    with (tmp_path / "v.mcap").open("rb") as fh:
        times = {}
        for _s, channel, message in make_reader(fh).iter_messages(log_time_order=False):
            times.setdefault(channel.topic, []).append(message.log_time)
    start = times[TICK_TOPIC][0] - round(ticks["t"][0] * 1e9)
    assert before <= start <= after
    np.testing.assert_array_equal(
        np.array(times[TICK_TOPIC]) - start, (ticks["t"] * 1e9).astype(np.int64)
    )
    updates = np.array(times[UPDATE_TOPIC]) - start  # received at the sim's steps, 60 Hz
    assert len(updates) == 60
    np.testing.assert_allclose(np.diff(updates), 1e9 / 60, atol=1e6)

"""A user's own pymunk space touched live (api.run_live): the haptic server started over the
default authenticated loopback network with a simulated device, the user's space published
from the test's process by the sim's own server."""

from __future__ import annotations

import signal
import time
from pathlib import Path
from typing import Any

import numpy as np
import pymunk
import pytest
from test_user_space import load_example

from haptic_local_model import api
from haptic_local_model.shared.config import resolve
from haptic_local_model.shared.net.config import free_loopback_port

SECONDS = 3.0


@pytest.mark.processes
def test_a_users_space_runs_live_without_fault_and_its_log_replays(tmp_path: Path) -> None:
    """3 s live, the push_block user pushing a held disc 12 cm toward a wall 4 cm away: the
    loop ran its ticks at 1 kHz, every local model was installed, the wall was touched and
    pushed back, no tick faulted, and the log replays bit for bit."""
    space, hand = _wall_space()
    log = tmp_path / "live.mcap"
    run = api.run_live(space, hand, SECONDS, user="push_block", log=log)
    assert run.summary.get("haptic_exit") == 0, run.summary
    assert run.sim_steps >= 0.98 * SECONDS * 60.0, run.summary
    assert run.tick_rate_hz >= 990.0, run.summary  # ticks kept on a shared machine
    assert run.updates_installed >= 0.95 * run.sim_steps and not run.updates_rejected
    assert run.watchdog_trips == 0, run.summary
    ticks = api.read_arrays(log).ticks
    assert len(ticks) == run.ticks
    assert not np.any(ticks["fault"]), "a tick faulted"
    assert ticks["n_active"].max() > 0  # the wall was touched ...
    assert ticks["wrench_command"][:, 0].min() < -1.0  # ... and pushed the device back
    assert api.replays_identically(log)


@pytest.mark.processes
@pytest.mark.parametrize("name", ["touch_bouncing_balls", "touch_vertical_stack", "touch_pyramid"])
def test_the_examples_run_live_and_replay(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str
) -> None:
    """Each pymunk example with --live: 3 s with the ideal device, no watchdog trip, no fault
    tick, and its log replays bit for bit."""
    example = load_example(name)
    log = tmp_path / f"{name}.mcap"
    assert example.main(["--live", "--seconds", "3", "--log", str(log)]) == 0
    out = capsys.readouterr().out
    assert "watchdog trips 0" in out and "fault ticks 0" in out, out
    assert api.replays_identically(log)


@pytest.mark.processes
def test_the_users_own_loop_steps_a_space_against_a_haptic_server_it_did_not_start(
    tmp_path: Path, start_server: Any
) -> None:
    """The user runs `haptic-server --scene FILE` (FILE from api.scene_file; here a simulated
    maglev pushed toward the wall), then drives `api.touch(..., start_server=False)` from a
    loop of their own that adds a ball to the space after 1 s: the loop is paced at the
    scene's 60 Hz, every local model reaches that server and is installed, the wall is
    touched and pushes the device back, and the server's log replays bit for bit."""
    space, hand = _wall_space()
    scene = api.scene_file(space, hand, tmp_path / "my_space.toml")
    shipped = resolve("network", "loopback").read_text()
    network = tmp_path / "net.toml"
    network.write_text(shipped.replace(":7447", f":{free_loopback_port()}"))
    log = tmp_path / "server.mcap"
    server = start_server("haptic_local_model.haptic_server.cli", "--scene", str(scene),
                          "--device", "maglev", "--user", "push_block", "--network",
                          str(network), "--log", str(log))  # fmt: skip
    server.wait_ready()
    steps, added = round(SECONDS * 60.0), False
    with api.touch(space, hand, network=str(network), start_server=False) as touch:
        began = time.perf_counter()
        for _ in range(steps):
            t = touch.step()
            if t >= 1.0 and not added:  # the user's own code, between two steps
                ball = pymunk.Body(0.05, 1e-5)
                ball.position = (0.0, 0.08)
                space.add(ball, pymunk.Circle(ball, 0.01))
                added = True
        took = time.perf_counter() - began
    assert server.stop(signal.SIGTERM) == 0
    run = touch.result
    assert run is not None and run.sim_steps == steps and added
    assert took == pytest.approx(SECONDS, rel=0.1), took  # paced by step(), not free-running
    assert run.sim_overruns <= 3, run.summary
    logged = api.read_arrays(log)
    assert int(np.count_nonzero(logged["updates"]["installed"])) >= 0.95 * steps
    assert logged.ticks["n_active"].max() > 0  # the wall was touched ...
    assert logged.ticks["wrench_command"][:, 0].min() < -1.0  # ... and pushed the device back
    assert api.replays_identically(log)


def _wall_space() -> tuple[pymunk.Space, pymunk.Body]:
    """A wall 4 cm to the right of a held 1 kg disc, in SI units."""
    space = pymunk.Space()
    space.collision_slop = 1e-4
    wall = pymunk.Segment(space.static_body, (0.05, -0.1), (0.05, 0.1), 0.005)
    wall.friction = 0.4
    space.add(wall)
    hand = pymunk.Body(1.0, 1.0e-3)
    space.add(hand, pymunk.Circle(hand, 0.01))
    return space, hand

"""Watchdog and recovery on the virtual clock: the engine and sim world of the servers, with
an outage cut into the update stream (deterministic; test_faults.py does it with processes).

During a network outage the sim keeps stepping but hears no proxy, so it brings its tool to
rest; after a sim crash a new sim (new epoch) starts from the scene. Either way the haptic
side must ramp to the safe state within 50 ms of the watchdog, and on the next update start
again from the sim's pose (with the hand's velocity) with forces faded back in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from haptic_local_model.device_models.registry import load_device
from haptic_local_model.haptic_server.engine import HapticEngine
from haptic_local_model.haptic_server.harness.virtual import _target
from haptic_local_model.haptic_server.model import TICK_DTYPE
from haptic_local_model.shared.config import load_scene, load_user
from haptic_local_model.shared.net.config import load_network
from haptic_local_model.shared.protocol.update import encode_update
from haptic_local_model.sim_server.world import SimWorld

NETWORK = load_network("loopback")
WATCHDOG_S = NETWORK.watchdog_ms / 1000.0
RAMP_S = NETWORK.safe_ramp_ms / 1000.0
SAFE_WITHIN_S = 0.050  # issue 8: safe state within 50 ms of the watchdog firing
OUTAGE_START_S, OUTAGE_S, RUN_S = 1.5, 0.3, 2.2
MAX_WRENCH_N = 50.0  # configs/devices/ideal.toml
DT = 1e-3
# The fade spreads a resumed force over RAMP_S / dt ticks: the blend alone moves a command
# within +-MAX_WRENCH by at most 2 MAX_WRENCH dt / RAMP_S = 2.5 N per tick; the rendering's
# own change while it fades in adds to that (the VM meeting the wall in wall_push: 2.74 N
# measured). The bound is twice the blend's share, 10% of full scale; a resumption without
# the fade moves the command by the whole resumed force in one tick (7.9 N in wall_push:
# test_without_the_fade_the_step_is_a_jump).
FADE_SHARE_N = 2.0 * MAX_WRENCH_N * DT / RAMP_S
FADE_STEP_BOUND_N = 2.0 * FADE_SHARE_N
SAFE_FORCE_TOL_N = 1e-12  # in the safe state the command is exactly -safe_damping * twist
SAFE_DAMPING = np.array([5.0, 5.0, 0.01])  # haptic_server/engine.py params_record


@dataclass
class OutageRun:
    ticks: np.ndarray
    trip: int  # tick at which the watchdog fired
    resume: int  # tick of the first update installed after the outage
    sim_q: np.ndarray  # the sim's tool q in that update
    proxy_q: np.ndarray  # the engine's proxy q right after installing it
    engine: HapticEngine


def run_with_outage(
    scene_name: str, user_name: str, restart: bool, ramp_s: float = RAMP_S
) -> OutageRun:
    """run_virtual with no updates delivered in [OUTAGE_START_S, +OUTAGE_S), the server's
    watchdog rule, and either the same sim going on (a network cut) or a new one (restart)."""
    scene = load_scene(scene_name)
    world = SimWorld(scene)
    engine = HapticEngine(scene, load_device("ideal"), load_user(user_name), ramp_s)
    n = round(RUN_S / DT)
    rows = np.zeros(n, TICK_DTYPE)
    period = 1.0 / scene.sim_rate_hz
    next_sim_t, seq, epoch, last_valid = 0.0, 0, 1, 0.0
    stale, trip, resume, restarted = False, -1, -1, False
    sim_q = proxy_q = np.zeros(0)
    for k in range(n):
        t = k * DT
        out = OUTAGE_START_S <= t < OUTAGE_START_S + OUTAGE_S
        if t >= next_sim_t - 1e-12:
            next_sim_t += period
            if not (restart and out):  # a crashed sim publishes nothing
                if restart and not restarted and not out and t > OUTAGE_START_S:
                    world, epoch, seq, restarted = SimWorld(scene), epoch + 1, 0, True
                if seq > 0:  # the silent haptic side: the sim brings its tool to rest
                    world.step(None if out else _target(engine, False))
                raw = encode_update(world.local_model(epoch, seq, 0, period if seq else 0.0))
                seq += 1
                if not out:
                    assert engine.receive(raw) == ""
                    last_valid = t
                    if stale:
                        stale, resume = False, k
                        engine.set_safe(False)
                        sim_q = world.tool_state()[0].copy()
                        proxy_q = engine.proxy_pose()[0]
        if engine.ready and not stale and t - last_valid > WATCHDOG_S:
            stale, trip = True, k
            engine.set_stale()
        rows[k] = engine.tick(DT)[0]
    assert trip > 0 and resume > trip
    return OutageRun(rows, trip, resume, sim_q, proxy_q, engine)


def fade_window_step(run: OutageRun) -> float:
    """Largest tick-to-tick change of the commanded wrench while forces fade back in."""
    safe = run.ticks["safe"]
    end = run.resume + int(np.argmax(safe[run.resume :] <= 0.0)) + 1
    w = run.ticks["wrench_command"]
    return float(np.abs(np.diff(w[run.resume - 1 : end + 1], axis=0)).max())


CASES = [
    ("wall_push", "push_2n"),  # in contact with a stiff wall
    ("free_box", "waypoints"),  # a hand that keeps moving during the outage
    ("linkage_distal", "push_04n"),  # a held linkage (resisted directions)
]


@pytest.mark.parametrize("restart", [False, True], ids=["same-epoch", "new-epoch"])
@pytest.mark.parametrize(("scene", "user"), CASES)
def test_outage_safe_state_and_resumption(scene: str, user: str, restart: bool) -> None:
    run = run_with_outage(scene, user, restart)
    ticks = run.ticks
    # safe within 50 ms of the watchdog, then damping only until the updates return
    safe_at = run.trip + int(np.argmax(ticks["safe"][run.trip :] >= 1.0))
    assert ticks["t"][safe_at] - ticks["t"][run.trip] <= SAFE_WITHIN_S
    held = ticks[safe_at : run.resume]
    assert len(held) > 0 and np.all(held["safe"] == 1.0)
    damping_only = -SAFE_DAMPING * held["device_twist"]
    assert np.abs(held["wrench_command"] - damping_only).max() <= SAFE_FORCE_TOL_N
    # re-initialised from the sim's state, same epoch or new
    np.testing.assert_array_equal(run.proxy_q, run.sim_q)
    assert run.engine.counters.reinitialisations == 1
    assert run.engine.counters.epochs == (2 if restart else 1)
    # the device mapped onto the VM, the proxy moving with the hand: the coupling starts at
    # rest (the sim's tool was held still; a moving hand would otherwise get B v at once)
    first = ticks[run.resume]
    np.testing.assert_allclose(first["device_pose"], first["vm_pose"], atol=1e-9)
    np.testing.assert_allclose(first["device_twist"], first["vm_twist"], atol=1e-9)
    np.testing.assert_allclose(first["f_coordination"], 0.0, atol=1e-9)
    # forces fade back in over the ramp: no jump
    assert fade_window_step(run) <= FADE_STEP_BOUND_N
    assert ticks["safe"][run.resume + round(RAMP_S / DT) + 1] == 0.0
    # within the device limits and finite throughout
    assert np.all(np.isfinite(ticks["wrench_command"]))
    assert np.abs(ticks["wrench_command"]).max() <= MAX_WRENCH_N


def test_without_reinitialisation_the_proxy_has_left_the_sim() -> None:
    """Why the same-epoch case re-initialises: the proxy keeps moving during the outage while
    the sim's tool comes to rest, so they disagree when the updates return."""
    run = run_with_outage("linkage_distal", "push_04n", restart=False)
    last_before = run.ticks[run.resume - 1]
    d = int(last_before["dof"])
    drift = np.abs(last_before["proxy_q"][:d] - run.sim_q).max()
    assert drift > 0.1  # rad: the linkage swung on without the sim
    np.testing.assert_array_equal(run.proxy_q, run.sim_q)


def test_without_the_fade_the_step_is_a_jump() -> None:
    """The bound above can fail: with a one-tick ramp the resumed force arrives at once."""
    run = run_with_outage("wall_push", "push_2n", restart=False, ramp_s=DT)
    assert fade_window_step(run) > FADE_STEP_BOUND_N

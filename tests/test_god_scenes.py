"""The god-object scenes as a user runs them: both servers as processes over Zenoh on
loopback for 10 s each (haptic-run), then the log replayed (DESIGN-WAVE2 §11: every new scene
runs in real time and replays exactly). Each run is checked for what its scene is about:
contact on the moving surface, a pop-through per closing of the slabs and a ramped force,
sub-stepping past (r + rho)/dt; and for what every run must keep: no fault, no NaN, the
device's limits."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import haptic_run, write_network_file

from haptic_local_model.device_models.ideal import IdealDevice, IdealDeviceConfig
from haptic_local_model.device_models.registry import load_device
from haptic_local_model.haptic_server.harness.replay import replay
from haptic_local_model.haptic_server.harness.virtual import run_virtual
from haptic_local_model.haptic_server.log import read_log
from haptic_local_model.shared.config import BodySpec, UserConfig, load_scene
from haptic_local_model.shared.protocol.layout import DEFAULT_LIMITS
from haptic_local_model.shared.protocol.update import UpdateParser
from haptic_local_model.sim_server.world import SimWorld, ToolTarget

RUN_S = 10.0
MIN_TICK_FRACTION = 0.95  # of RUN_S at 1 kHz: a 2-core machine under the test suite
SCENES = {
    "god_rotating_box": ("ideal", "press_down"),
    "god_testbed": ("twin_pantograph", "press_down"),
    "god_slabs": ("ideal", "press_lift"),
    "god_shuttle_fast": ("ideal", "hold_still"),
    "god_crowd": ("maglev", "plough"),
    "membrane_10hz": ("ideal", "press_1n"),
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    network_file = write_network_file(tmp_path_factory.mktemp("net") / "net.toml")
    out = {}
    for scene, (device, user) in SCENES.items():
        d = tmp_path_factory.mktemp(scene)
        log = d / "run.mcap"
        summary = haptic_run(
            network_file, log, d / "summary.json",
            scene=scene, device=device, user=user, seconds=RUN_S,
        )  # fmt: skip
        # a loaded machine may stall a process past the update age limit (late); nothing the
        # sim sends about the god-object's world is ever refused
        assert set(summary["rejected_by_reason"] or {}) <= {"late"}, (scene, summary)
        out[scene] = log
    return out


@pytest.mark.processes
@pytest.mark.parametrize("scene", list(SCENES))
def test_runs_safely_in_real_time_and_replays_exactly(scene: str, runs: dict[str, Path]) -> None:
    log = read_log(runs[scene])
    ticks = log.ticks
    ready = ticks[ticks["update_seq"] >= 0]  # the run's duration counts from the first update
    assert len(ready) >= MIN_TICK_FRACTION * RUN_S * 1000
    assert (ready["fault"] == 0).all(), f"{scene}: faults {np.unique(ready['fault'])}"
    assert np.isfinite(ticks["wrench_command"]).all()
    assert np.isfinite(ticks["god_proxy"]).all()
    limit = np.asarray(load_device(SCENES[scene][0]).limits().max_wrench)
    assert (np.abs(ticks["wrench_command"][:, :2]) <= limit[:2] + 1e-9).all()
    assert ready["n_shapes"].min() >= 1  # the sim always sends the shapes near the finger
    result = replay(log)
    assert result.identical, result.differing
    assert result.updates_replayed == len(log.updates) > 0


@pytest.mark.processes
def test_the_finger_rests_on_the_rocking_box(runs: dict[str, Path]) -> None:
    """Pressed into the rocking box's top (the hand's 300 N/m spring against the 1000 N/m
    coupling): in contact with one plane from the press on, the proxy above the device's
    point all along (the finger is in the box, the proxy on it), the force pushing up."""
    ticks = read_log(runs["god_rotating_box"]).ticks
    ready = ticks[ticks["update_seq"] >= 0]
    pressed = ready[ready["t"] - ready["t"][0] > 2.0]
    assert (pressed["god_active"] == 1).mean() > 0.99
    depth = pressed["god_proxy"][:, 1] - pressed["device_pose"][:, 1]
    assert depth.min() > 0.0 and depth.max() < 8e-3
    assert (pressed["wrench_command"][:, 1] > 0.0).all()


@pytest.mark.processes
def test_each_closing_of_the_slabs_is_one_ramped_pop(runs: dict[str, Path]) -> None:
    """The gap closes below the finger's diameter at 0.33 s, 4.33 s, 8.33 s of the sim's
    time: one pop-through each (two or three fall within 10 s of the haptic run, which starts
    before the sim), and the force never changes by more than the ramp allows at a pop."""
    ticks = read_log(runs["god_slabs"]).ticks
    pops = int(ticks["god_pops"].max())
    assert 2 <= pops <= 3
    assert int(ticks["god_pop"].sum()) == pops
    scene = load_scene("god_slabs")
    f_max = min(load_device("ideal").limits().max_wrench[:2])
    ramp = f_max * 1e-3 / (scene.rendering.pop_ramp_ms / 1e3)
    f = ticks["wrench_command"][:, :2]
    steps = np.hypot(*np.diff(f, axis=0).T)  # steps[i]: tick i + 1's change
    ramp_ticks = round(scene.rendering.pop_ramp_ms)  # the ramp, at 1 kHz
    for pop in np.flatnonzero(ticks["god_pop"] == 1):
        assert steps[pop - 1 : pop - 1 + ramp_ticks].max() <= ramp + 1e-9


@pytest.mark.processes
def test_the_fast_bar_is_sub_stepped(runs: dict[str, Path]) -> None:
    """The bar passes at up to 3.1 m/s, beyond (r + rho)/dt = 2.5 m/s: the kernel sub-steps
    (3 sub-steps at 3.1 m/s: ceil(2 v dt / (r + rho))), and no pop is ever needed (the bar
    never closes on anything)."""
    ticks = read_log(runs["god_shuttle_fast"]).ticks
    assert ticks["god_substeps"].max() >= 3
    assert int(ticks["god_pops"].max()) == 0
    assert (ticks["god_contact"] > 0).any()


#: how long the pressed string takes to settle after a stall of the loop (see below)
STALL_SETTLE_S = 0.5


@pytest.mark.processes
def test_the_membrane_sampled_at_10_hz_yields_as_a_string(runs: dict[str, Path]) -> None:
    """V2.3 over Zenoh: the hand presses the string at mid-span while the sim samples it at
    10 Hz; at rest (the last 3 s) its deflection, read from the proxy, is F L / (4 T) within
    5 % of the force the hand feels, the force steady within 0.02 N peak to peak; the proxy
    touches the string's segments, keyed after the finger's shape."""
    from haptic_local_model.benchmarks.node_hold import (
        DEFLECTION_TOLERANCE,
        PEAK_TO_PEAK_N,
        press_figures,
    )

    log = read_log(runs["membrane_10hz"])
    scene = load_scene("membrane_10hz")
    ready = log.ticks[log.ticks["update_seq"] >= 0]
    # at rest means undisturbed: a stall of the loop itself (a missed deadline) sets the
    # string swinging, which is the machine, not the rendering (in CI a 5 ms stall swung the
    # force by +-0.015 N, back within 0.001 N in 0.4 s); the ticks within STALL_SETTLE_S
    # after one are left out of the last 3 s, and most of them must remain
    stalls = ready["t"][ready["lateness_us"] > 1e6 / scene.haptic_rate_hz]
    after = np.zeros(len(ready), bool)
    for t0 in stalls:
        after |= (ready["t"] >= t0) & (ready["t"] < t0 + STALL_SETTLE_S)
    end = ready["t"][ready["safe"] == 0][-1]
    assert np.count_nonzero(~after & (ready["t"] > end - 3.0)) >= 1500, stalls
    press = press_figures(ready[~after], scene, "node_foh")
    print(f"\nmembrane over Zenoh: {press}")
    assert press.force_n == pytest.approx(1.1, abs=0.1)
    assert abs(press.error) <= DEFLECTION_TOLERANCE, press
    assert press.peak_to_peak_n <= PEAK_TO_PEAK_N, press
    touched = ready["god_env_key"][ready["god_active"] > 0]
    assert np.isin(touched[touched >= 0], np.arange(1, 21)).all()


#: the sim applies the impulses of the ticks since its last step (DESIGN-WAVE2 C4): the
#: box's momentum is their sum to round-off (before 0.7 it took the newest proxy state's force
#: over each step: 1.0 % short over this run)
MOMENTUM_REL = 1e-9


def test_the_proxys_push_reaches_a_free_body_as_momentum() -> None:
    """A 0.2 kg box on a frictionless table pushed by the finger under a constant 0.5 N: the
    box's momentum in the sim, plus what the sim still keeps for its next step, equals the
    impulse the haptic side rendered on it (the sum of its force on the box's key times dt
    over the ticks the sim has received), and nothing else pushes it (the sim's finger
    body collides with nothing: no double counting)."""
    scene = load_scene("god_slabs")
    finger = next(b for b in scene.bodies if b.name == "finger")
    box = BodySpec(
        name="box", kind="dynamic", shape="box", material="slab", size=(0.02, 0.02), mass=0.2,
        position=(0.0125, 0.0),
    )  # fmt: skip
    scene = dataclasses.replace(scene, bodies=(finger, box))
    user = UserConfig(name="push", kind="constant_wrench", wrench=(0.5, 0.0, 0.0))
    res = run_virtual(scene, IdealDevice(IdealDeviceConfig()), user, 1.0)
    ticks = res.ticks
    shape = next(s for s in res.world.shape_keys if s.body is not None and s.body.mass == 0.2)
    key = res.world.shape_keys[shape]
    # the sim's last step applied the ticks before the last update's install; the rest wait
    applied = ticks[: int(np.argmax(ticks["update_seq"] == ticks["update_seq"].max()))]
    impulse = 0.0
    for j in range(2):
        on_box = applied["god_env_key"][:, j] == key
        impulse += float((applied["god_env_force"][on_box, j, 0] * applied["dt"][on_box]).sum())
    assert impulse > 0.05  # the finger pushed it for a while
    assert shape.body is not None
    momentum = shape.body.mass * shape.body.velocity.x
    kept = res.world.pending_impulses  # received, kept for the next step (a sliver of one)
    owed = float(kept.impulses[kept.keys == key, 0].sum())
    assert 0.0 <= owed < 0.1 * impulse
    assert momentum + owed == pytest.approx(impulse, rel=MOMENTUM_REL)
    assert abs(shape.body.velocity.y) < 1e-3 * abs(shape.body.velocity.x)


def test_the_sim_sends_the_shapes_about_the_proxy_not_its_lagging_finger() -> None:
    """The sim's finger follows the proxy through an 8 Hz tracking loop: centimetres behind at
    speed. A pebble the proxy touches must be in the update even if 64 others lie nearer the
    sim's finger (in a CI run of god_crowd one was left out, the proxy jumped 3 mm to the
    device in one tick and the runaway guard tripped)."""
    world = SimWorld(load_scene("god_crowd"))
    q, qd = world.tool_state()
    finger = np.array(q[:2])
    radius = load_scene("god_crowd").tool_body.radius
    pebbles = [
        s for s in world.shape_keys if s.body is not None and s.body.body_type == s.body.DYNAMIC
    ]
    far = max(
        (s for s in pebbles if 0.05 < np.hypot(*(np.array(s.body.position) - finger)) < 0.1),
        key=lambda s: np.hypot(*(np.array(s.body.position) - finger)),
    )
    centre = np.array(far.body.position)
    proxy = centre + np.array([0.0, far.radius + radius])  # resting on top of it
    target_q = q.copy()
    target_q[:2] = proxy
    target = ToolTarget(
        q=target_q, qd=qd, device_pose=np.zeros(3), device_twist=np.zeros(3),
        coupled_to_device=False, fresh=True,
    )  # fmt: skip
    world.step(target)
    raw = world.local_model_bytes(1, 0, 0)
    parser = UpdateParser()
    assert parser.parse(raw) == 0
    out = parser.out[0]
    keys = out["shapes"]["key"][: out["n_shapes"]]
    assert world.shape_keys[far] in keys
    world.step(dataclasses.replace(target, fresh=False))  # the haptic side silent: the finger
    parser.parse(world.local_model_bytes(1, 1, 0))
    assert world.shape_keys[far] not in parser.out[0]["shapes"]["key"][: parser.out[0]["n_shapes"]]


def test_a_pebble_spun_past_the_protocols_limits_leaves_the_update_valid() -> None:
    """A pebble of god_crowd near the finger spinning at 3000 rad/s and flying at 150 m/s
    (2 N of friction at the rim of a 5 g, 4 mm pebble for one step spins it at 3000 rad/s; a
    CI run under load lost updates to 'shape' that way): the update parses, the pebble's twist
    is published at the protocol's limits, in its direction, and the clamp is counted."""
    world = SimWorld(load_scene("god_crowd"))
    q, _ = world.tool_state()
    finger = np.array(q[:2])
    pebble = min(
        (s for s in world.shape_keys if s.body is not None and s.body not in world.tool_bodies),
        key=lambda s: np.hypot(*(np.array(s.body.position) - finger)),
    )
    pebble.body.angular_velocity = -3000.0
    pebble.body.velocity = (90.0, -120.0)
    raw = world.local_model_bytes(1, 1, 0)
    parser = UpdateParser()
    assert parser.parse(raw) == 0
    out = parser.out[0]
    rows = out["shapes"][: out["n_shapes"]]
    twist = rows["twist"][list(rows["key"]).index(world.shape_keys[pebble])]
    limits = DEFAULT_LIMITS
    assert twist[2] == pytest.approx(-limits.max_abs_angular_velocity, rel=1e-6)
    assert np.hypot(twist[0], twist[1]) == pytest.approx(limits.max_abs_velocity, rel=1e-6)
    assert twist[0] / twist[1] == pytest.approx(90.0 / -120.0)
    assert world.local_shapes is not None and world.local_shapes.twists_clamped == 1


class _Sample:
    def __init__(self, raw: bytes) -> None:
        self.payload = self
        self._raw = raw

    def to_bytes(self) -> bytes:
        return self._raw


class _Subscriber:
    """A ring-channel subscriber holding the given payloads (oldest first)."""

    def __init__(self, payloads: list[bytes]) -> None:
        self._waiting = [_Sample(p) for p in payloads]

    def try_recv(self) -> _Sample | None:
        return self._waiting.pop(0) if self._waiting else None


def test_the_impulses_of_every_proxy_state_reach_the_next_step_once() -> None:
    """Both ends of DESIGN-WAVE2 C4 on the real code: the I/O process sums the ticks' force
    x dt per shape since its last proxy state (across the ring's wrap), and the sim adds the
    impulses of every proxy state waiting (not only the newest's), gives them to its next
    step as forces that deliver them, and to that step only."""
    from haptic_local_model.haptic_server.mailbox import RING_TICKS
    from haptic_local_model.haptic_server.model import TICK_DTYPE
    from haptic_local_model.haptic_server.sidecar import ticks_impulses
    from haptic_local_model.shared.net.config import NetworkConfig
    from haptic_local_model.shared.protocol.codes import Method
    from haptic_local_model.shared.protocol.proxy import ShapeImpulses, encode_proxy
    from haptic_local_model.sim_server.server import SimServer

    ring = np.zeros(RING_TICKS, TICK_DTYPE)
    ring["god_env_key"] = -1
    head = RING_TICKS + 6  # the ring has wrapped: ticks RING_TICKS - 6 .. + 5 are in slots
    for i in range(head - 12, head):
        r = ring[i % RING_TICKS]
        r["dt"], r["god_env_key"] = 1e-3, (4, 9 if i % 2 else -1)
        r["god_env_arm"], r["god_env_force"] = ((0.01, 0.0), (0.0, 0.02)), ((1.0, 0.0), (0, 2))
    block = SimpleNamespace(ticks=ring)
    got = ticks_impulses(block, head - 12, head, int(Method.GOD_OBJECT))
    np.testing.assert_array_equal(got.keys, [4, 9])
    np.testing.assert_allclose(got.impulses, [[12e-3, 0.0], [0.0, 12e-3]])
    assert ticks_impulses(block, head - 12, head, int(Method.LOCAL_MODEL)).count == 0

    scene = load_scene("god_slabs")
    server = SimServer(scene, NetworkConfig())
    world = server.world
    world.local_model_bytes(server.epoch, 0, 0)
    now = time.time_ns()
    server.check.published(0, world.tool_pose, now)
    q, _ = world.tool_state()
    states = []
    for k in range(5):  # five proxy states between two sim steps, 4 ms apart
        row = np.zeros(1, TICK_DTYPE)
        r = row[0]
        r["dof"], r["update_epoch"], r["update_seq"], r["tick"] = 3, server.epoch, 0, 4 * k
        r["t"], r["proxy_q"][:3], r["device_pose"] = 0.004 * k, q, world.tool_pose
        impulse = ShapeImpulses(np.array([7]), np.array([[0.0, 0.01]]), np.array([[k, 1.0]]))
        states.append(encode_proxy(row, int(Method.GOD_OBJECT), now, impulses=impulse))
    server._read_proxies(_Subscriber(states), now)
    target = server.target(now)
    assert target is not None and target.fresh
    np.testing.assert_array_equal(target.impulses.keys, [7])
    np.testing.assert_allclose(target.impulses.impulses, [[10.0, 5.0]])  # all five, summed
    again = server.target(now)
    assert again is not None and again.impulses.count == 0  # applied once

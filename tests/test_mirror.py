"""The sim mirroring a shared world (sim_server/mirror.py, haptic_server/sim_link.py,
DESIGN-WAVE2 §6): the bodies' messages, the world's side, the sim's side, and the three
processes on loopback against closed forms."""

from __future__ import annotations

import math
import struct
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from haptic_local_model.benchmarks import mirror as bench
from haptic_local_model.haptic_server.shared_world import SharedWorld
from haptic_local_model.shared.net.stations import load_station_network
from haptic_local_model.shared.port_config import load_port_scene
from haptic_local_model.shared.protocol.station import (
    MAX_MESSAGE_BODIES,
    SIM_BODIES_MAGIC,
    WORLD_BODIES_MAGIC,
    BodiesState,
    decode_bodies,
    encode_bodies,
)
from haptic_local_model.shared.protocol.update import MessageError
from haptic_local_model.sim_server.mirror import Mirror

G = 9.81


def _sim_bodies(seq: int, pose=(0.0, 0.03, 0.0), twist=(0.0, 0.0, 0.0), impulse=None,
                epoch: int = 5, follows: int = 0, period: float = 1 / 60) -> bytes:  # fmt: skip
    j = [(0.0, 0.0, 0.0)] * MAX_MESSAGE_BODIES
    if impulse is not None:
        j[2] = impulse  # the box: q's order is the tools, then the box
    return encode_bodies(BodiesState(SIM_BODIES_MAGIC, epoch, seq, 0, ((*pose, *twist),),
                                     period, follows, tuple(j)))  # fmt: skip


def test_bodies_round_trip_and_malformed_ones_are_refused_by_field() -> None:
    m = BodiesState(WORLD_BODIES_MAGIC, 3, 4, 5, ((0.1, 0.2, 0.3, 1.0, 2.0, 3.0),) * 3, 0.004)
    back = decode_bodies(encode_bodies(m), WORLD_BODIES_MAGIC, 3)
    assert back == m
    raw = encode_bodies(m)
    with pytest.raises(MessageError) as err:
        decode_bodies(raw, SIM_BODIES_MAGIC, 3)
    assert err.value.reason == "magic"
    with pytest.raises(MessageError) as err:
        decode_bodies(raw, WORLD_BODIES_MAGIC, 2)
    assert err.value.reason == "count" and "count: 3 bodies" in str(err.value)
    with pytest.raises(MessageError) as err:
        decode_bodies(raw[:-8], WORLD_BODIES_MAGIC, 3)
    assert err.value.reason == "size"
    head = struct.calcsize("<4sHHQQqQd")
    bad = bytearray(raw)
    struct.pack_into("<d", bad, head + 8 * (6 + 4), math.nan)  # bodies[1].twist.y
    with pytest.raises(MessageError, match=r"bodies\[1\]\.twist\.y"):
        decode_bodies(bytes(bad), WORLD_BODIES_MAGIC, 3)
    bad = bytearray(raw)
    struct.pack_into("<d", bad, head + 8 * (6 * MAX_MESSAGE_BODIES + 3 * 2 + 1), 1e10)
    with pytest.raises(MessageError, match=r"impulse\[2\]\.y"):
        decode_bodies(bytes(bad), WORLD_BODIES_MAGIC, 3)
    bad = bytearray(raw)
    struct.pack_into("<d", bad, head - 8, 0.0)  # period_s
    with pytest.raises(MessageError, match="period_s"):
        decode_bodies(bytes(bad), WORLD_BODIES_MAGIC, 3)


def test_the_world_carries_the_sims_bodies_and_refuses_bad_ones(ring: Any) -> None:
    """The world's side: the newest valid SimBodies, its ball carried on by its twist for
    the time since it arrived, held (at rest) past 50 ms; a stale, malformed, other
    sim's or other world's refused by reason; a silent sim leaves the ball at rest."""
    scene = load_port_scene("grasp_ball")
    world = SharedWorld(scene, load_station_network("stations_loopback", "world"), 10)
    link = world.sim
    assert link is not None
    d = world.engine.data[0]
    slot = int(world.engine.model[0]["n_static"]) - 1  # the ball: the last wall
    now = time.perf_counter_ns()
    me = world.epoch
    link._sub = ring([
        _sim_bodies(2, pose=(0.0, 0.029, 0.0), twist=(0.0, -0.5, 0.0), follows=me),
        _sim_bodies(1, follows=me),
        b"junk", _sim_bodies(3, epoch=6, follows=me), _sim_bodies(4),
    ])  # fmt: skip
    link.take(now)
    assert link.received == 1
    assert link.reasons == {"stale": 1, "size": 1, "other_epoch": 1, "other_world": 1}
    assert list(d["wall_pose"][slot]) == [0.0, 0.029, 0.0]  # seq 2's, not the start's
    link._sub = ring([])
    link.take(now + 10_000_000)  # 10 ms later: carried on by its twist
    assert d["wall_pose"][slot][1] == pytest.approx(0.029 - 0.5 * 0.01, abs=1e-12)
    assert d["wall_twist"][slot][1] == -0.5
    link.take(now + 80_000_000)  # 80 ms: held where it was carried at 50 ms, at rest
    assert d["wall_pose"][slot][1] == pytest.approx(0.029 - 0.5 * 0.05, abs=1e-12)
    assert not d["wall_twist"][slot].any()
    link.take(now + 200_000_000)  # silent past the watchdog: still there, counted
    assert link.lost == 1
    assert d["wall_pose"][slot][1] == pytest.approx(0.029 - 0.5 * 0.05, abs=1e-12)


def test_the_world_applies_each_impulse_of_the_sim_once(ring: Any) -> None:
    """The sim's running impulse on the box, a resting weight w a step (h = 1/60 s), taken
    by the world with jitter: two in one tick, one lost, one late. Every impulse reported
    after the first (the baseline) is applied once: the force the rows log sums to the last
    running impulse less the first, to 1e-12. Tick by tick, each sample's new impulse and
    what is left of the last go over one step h: w on sample 1's 16 whole ticks; at tick
    33, samples 2 and 3 and sample 1's last 0.67 ms, (2 w h + w (h - 16 dt)) / h; nothing
    from tick 50 to 66 (sample 4 lost: its impulse comes with sample 5, at tick 67)."""
    scene = load_port_scene("grasp_ball")
    world = SharedWorld(scene, load_station_network("stations_loopback", "world"), 10)
    link = world.sim
    assert link is not None
    d = world.engine.data[0]
    me, h, dt = world.epoch, 1 / 60, 0.001
    weight = np.array([0.0, -0.2, 0.001])
    arrivals = {0: [0], 17: [1], 33: [2, 3], 67: [5], 90: [6], 100: [7], 117: [8]}  # 4: lost
    applied = np.zeros(3)
    force = np.zeros((300, 3))
    for tick in range(300):
        link._sub = ring([_sim_bodies(k + 1, impulse=tuple(weight * h * k), follows=me)
                           for k in arrivals.get(tick, [])])  # fmt: skip
        link.take(tick * 1_000_000)
        force[tick] = d["sim_wrench"][2]
        applied += force[tick] * dt
    assert applied == pytest.approx(weight * h * 8, abs=1e-12)  # samples 1..8 past sample 0
    assert not d["sim_wrench"].any()  # all of it applied, nothing more
    assert not force[:17].any()  # sample 0 is the baseline
    assert np.allclose(force[17:33], weight, atol=1e-12)  # sample 1's 16 whole ticks
    assert np.allclose(force[33], (2 * weight * h + weight * (h - 16 * dt)) / h, atol=1e-12)
    assert not force[50:67].any() and np.abs(force[67]).max() > 1.9 * np.abs(weight).max()
    assert link.clipped == 0


def _world_bodies(seq: int, box_y: float, vy: float = 0.0) -> bytes:
    bodies = ((-0.023, 0.0, 0.0, 0.0, 0.0, 0.0), (0.023, 0.0, 0.0, 0.0, 0.0, 0.0),
              (0.0, box_y, 0.0, 0.0, vy, 0.0))  # fmt: skip
    return encode_bodies(BodiesState(WORLD_BODIES_MAGIC, 1, seq, 0, bodies, 0.004))


def test_the_mirror_carries_the_ball_with_the_worlds_box_and_reports_its_weight(ring: Any) -> None:
    """The sim's side, no network: the world's box held still, the ball lands and rests on
    the mirror: the wrench on the box is the ball's weight, m g down, to 1e-6. The box then
    rises at 0.1 m/s (the world's samples each step): the mirror follows within a step's
    prediction, the ball rides on it, and the wrench is the ball's weight (its speed is
    steady)."""
    scene = load_port_scene("grasp_ball")
    mirror = Mirror(scene, load_station_network("stations_loopback", "sim"), 60.0)
    h = mirror.h
    ball = scene.sim_body_specs[0]
    t = 0
    for k in range(60):
        mirror.take(ring([_world_bodies(k + 1, 0.0)]), t)
        mirror.step(t)
        t += round(h * 1e9)
    assert mirror.wrench[2] == pytest.approx((0.0, -ball.mass * G, 0.0), abs=1e-6)
    assert not mirror.wrench[:2].any()  # the pads: the ball falls between them
    top = 0.01 + ball.radius
    assert mirror.sims[0].position.y == pytest.approx(top, abs=2e-4)  # within pymunk's slop
    for k in range(60, 90):
        y = 0.1 * (k - 60) * h
        mirror.take(ring([_world_bodies(k + 1, y, 0.1)]), t)
        mirror.step(t)
        t += round(h * 1e9)
    assert mirror.mirrored[2].position.y == pytest.approx(0.1 * 30 * h, abs=1e-9)
    assert mirror.sims[0].position.y == pytest.approx(top + 0.1 * 30 * h, abs=2e-4)
    assert mirror.sims[0].velocity.y == pytest.approx(0.1, abs=1e-3)
    assert mirror.wrench[2][1] == pytest.approx(-ball.mass * G, rel=1e-3)
    # steady motion is predicted exactly: driven to where each sample puts the box at the
    # step's end, the mirror is where the next one says (driven to the sample's own pose it
    # would lag 0.1 m/s * h = 1.7 mm)
    assert mirror.lag_mm.values()[-29:].max() < 1e-9


@pytest.mark.processes
def test_the_sim_drops_a_ball_on_the_held_box_and_the_world_feels_its_weight(
    tmp_path: Path,
) -> None:
    """Router, haptic-world and sim-server --mirror on loopback, grasp_ball, 4 s: the
    sim's 20 g ball lands on the box the two ports hold, and rests. Against closed forms:
    - the world applies the sim's impulses: resting, m g within 2.2 % (the resting
      window's two edges each cut at most a step's impulse m g h, 1.1 % of m g over 3 s;
      twice that with a sample lost or two in one tick); over the landing's first 100 ms
      m (sqrt(2 g h) + g 0.1 s) within 22 % (the landing's place in its step and the
      window's end each cut up to m g h = 3.3 mN s of 30);
    - the devices feel it: their commands sum to the weight of box, pads and ball (2e-3:
      the ball's part as its force, 2.2 % of 0.196 N of 2.158 N), and the pads sink
      m g / (the couplings' vertical stiffness) = 49 um (2 %);
    - the box stays held: slip <= 0.1 mm (V4.1's bound), and the sim's ball rests on the
      mirror's top (pymunk's 0.1 mm slop);
    - the world's log replays bit for bit with the sim's bodies as inputs."""
    bench.run_processes(tmp_path, 4.0, 60.0)
    f = bench.figures(tmp_path, load_port_scene(bench.SCENE))
    assert f["sim_rejected"] == 0 and f["world_sim"]["sim_bodies_rejected"] == 0
    assert f["resting_s"] >= 3.0 and f["world_sim"]["impulse_clipped"] == 0, f
    assert f["wrench_y_n"] == pytest.approx(f["ball_weight_n"], rel=0.022), f
    assert f["landing_impulse_ns"] == pytest.approx(f["landing_impulse_expected_ns"], rel=0.22)
    assert -f["commands_y_n"] == pytest.approx(f["held_weight_n"], rel=2e-3), f
    assert f["pads_sank_m"] == pytest.approx(f["pads_sank_expected_m"], rel=0.02), f
    assert f["slip_m"] <= 1e-4, f
    assert -1.05e-4 <= f["ball_above_mirror_m"] <= 0.0, f  # pymunk's slop: 1e-4 deep
    from haptic_local_model.haptic_server.world_runs import replay_log

    compared, differs = replay_log(tmp_path / "world.mcap")
    assert differs is None and compared == f["ticks"]
    assert np.isfinite(f["lag_mm"]["p99"])
    work = f["world_sim"]  # the world's work split: ticks that met the sim's bodies, the rest
    assert np.isfinite(work["work_us_sim_ticks"]["p50"] + work["work_us_other_ticks"]["p50"])


def test_a_shape_scenes_sim_bodies_pass_through_the_mirror(ring: Any) -> None:
    """sim_contact = "shape": the sim's bodies are obstacles that move on their own (the
    world meets them one-way at 1 kHz); the mirror does not touch them, so the ball falls
    past the box's mirror to the floor, in free fall until it meets the floor (pymunk's
    free fall to 1e-12)."""
    import dataclasses

    scene = dataclasses.replace(load_port_scene("grasp_ball"), sim_contact="shape")
    mirror = Mirror(scene, load_station_network("stations_loopback", "sim"), 60.0)
    ball = mirror.sims[0]
    y0 = ball.position.y
    for k in range(30):  # 0.5 s: it lands on the floor (0.11 m down) after 0.15 s, and settles
        mirror.take(ring([_world_bodies(k + 1, 0.0)]), 0)
        mirror.step(0)
        if k == 5:  # 0.1 s, 60 substeps of h: past the box's top, untouched; pymunk moves
            # a body by its velocity before gravity changes it: g h^2 n (n - 1) / 2 down
            hs, n = mirror.h / 10, 60
            assert ball.position.y == pytest.approx(y0 - G * hs**2 * n * (n - 1) / 2, abs=1e-12)
    assert mirror.touching == [0] and not mirror.wrench.any()
    floor = -0.08 + 0.005  # the floor segment's top
    assert ball.position.y == pytest.approx(floor + 0.006, abs=2e-4)

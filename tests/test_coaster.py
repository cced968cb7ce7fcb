"""The roller coaster end to end (seed 003 §4, DESIGN-WAVE2 §5): a train of cars on a track,
its animation variable integrated in the haptic loop, pushed by the god-object finger, the
sim's kinematic cars posed from the haptic side's state, the track's static message, the
update's AVARS trailer, and the real processes over Zenoh.

The dynamics themselves are checked against independent references in tests/test_avar.py;
here the train as the loop runs it: V3.4's work-energy balance against the forces the log
says were rendered, the free ride after the last touch against the DOP853 reference, the
port's energy, and a 10 s run of both servers over Zenoh that replays bit for bit.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import haptic_run, write_network_file

from haptic_local_model.benchmarks.coaster import (
    crank_flick_figures,
    push_figures,
    wheel_push_figures,
)
from haptic_local_model.device_models.registry import load_device
from haptic_local_model.haptic_server.engine import HapticEngine
from haptic_local_model.haptic_server.harness.replay import replay
from haptic_local_model.haptic_server.harness.virtual import run_virtual
from haptic_local_model.haptic_server.log import read_log
from haptic_local_model.shared.avar import train_energy, train_record
from haptic_local_model.shared.config import (
    ConfigError,
    SceneConfig,
    load_config_text,
    load_scene,
    load_user,
)
from haptic_local_model.shared.protocol.proxy import TrainState
from haptic_local_model.shared.protocol.static import (
    check_static,
    decode_static,
    encode_static,
    static_id,
)
from haptic_local_model.shared.protocol.update import (
    MessageError,
    decode_update,
    encode_update,
)
from haptic_local_model.shared.track import tabulate, track_point
from haptic_local_model.sim_server.world import SimWorld, ToolTarget

WORK_ENERGY = 0.01  # V3.4: E(t) - E0 against the rendered finger's work, of its largest
PORT_GIVEN_J = 1e-3  # V3.4: the device never gives the hand more than it was given, beyond this
FREE_RIDE_UM = 10.0  # V3.1's bound, for the free ride after the finger lets go
SCENE_DIR = Path(__file__).resolve().parent.parent / "configs" / "scenes"


def test_v3_4_the_finger_pushes_the_train_and_its_energy_is_the_work_rendered() -> None:
    """coaster_loop with the twin pantograph and a hand that shoves the last car: the
    train's energy change against the work of the forces the god-object rendered on the
    cars (from the log, with the track's contact Jacobians), the port's energy, and the
    free ride after the last touch against the independent reference."""
    figures = push_figures()
    assert figures["touch_ticks"] > 200 and figures["max_rate"] > 0.05, figures  # it moved
    assert figures["max_work_j"] > 1e-3, figures
    assert figures["work_energy_error"] <= WORK_ENERGY, figures
    assert figures["exact_accounting_j"] < 1e-9, figures  # Q_eff (s - s0): RK4's own work
    assert figures["port_given_max_j"] <= PORT_GIVEN_J, figures
    assert figures["free_s"] >= 2.5, figures
    assert figures["free_error_um"] <= FREE_RIDE_UM, figures
    assert figures["faults"] == 0 and figures["pops"] == 0, figures


def test_v3_6_a_flicked_crank_turns_through_its_dead_centres_unflagged() -> None:
    """crank (driven by its angle, on a table): the finger flicks the bar; the crank turns on
    through both dead centres with no flag and no NaN, its energy is the rendered finger's
    work, and its free spin keeps phi' = sqrt(2 E / M(phi)) of the reference M (finite
    differences of the closed-form positions)."""
    figures = crank_flick_figures()
    assert figures["touch_ticks"] > 5 and figures["dead_centres"] >= 6, figures
    assert figures["singular"] == 0 and figures["faults"] == 0, figures  # no singular step
    assert figures["work_energy_error"] <= WORK_ENERGY, figures
    assert figures["exact_accounting_j"] < 1e-8, figures
    assert figures["port_given_max_j"] <= PORT_GIVEN_J, figures
    assert figures["free_s"] >= 3.0 and figures["free_rate_error"] < 1e-6, figures


def test_a_pushed_ferris_wheel_turns_as_one_geared_tree() -> None:
    """ferris_wheel (a tree of arms and level gondolas on one avar through gears): the finger
    pushes the lowest gondola and the wheel turns on; its energy is the rendered finger's
    work, and balanced, its free spin holds q' (M_q constant, no torque)."""
    figures = wheel_push_figures()
    assert figures["touch_ticks"] > 5 and figures["turned_rad"] > math.pi, figures
    assert figures["singular"] == 0 and figures["faults"] == 0, figures
    assert figures["work_energy_error"] <= WORK_ENERGY, figures
    assert figures["port_given_max_j"] <= PORT_GIVEN_J, figures
    assert figures["free_s"] >= 2.5 and figures["free_rate_error"] < 1e-9, figures


def test_a_crank_driven_by_its_slider_is_refused_unless_allowed_and_then_flagged() -> None:
    """V3.6's singular form: the slider position as the avar is refused at load, naming the
    key; allowed, the loop flags its steps at the dead centres, stalls there, never NaN."""
    text = (SCENE_DIR / "crank.toml").read_text()
    slider = text.replace('driver = "crank_angle"', 'driver = "slider_position"')
    slider = slider.replace("initial_q = 1.2", "initial_q = 0.07")
    with pytest.raises(ConfigError) as info:
        load_config_text(SceneConfig, slider, "x.toml")
    assert info.value.key == "crank.driver" and "allow_singular" in info.value.problem
    allowed = load_config_text(
        SceneConfig, slider.replace("[crank]", "[crank]\nallow_singular = true"), "x.toml"
    )
    allowed = dataclasses.replace(
        allowed,
        crank=dataclasses.replace(allowed.crank, initial_rate=0.5),  # type: ignore[arg-type]
    )
    t = run_virtual(allowed, load_device("ideal"), load_user("hold_still"), 1.0).ticks
    assert np.isfinite(t["avar_s"]).all() and np.isfinite(t["wrench_command"]).all()
    assert t["avar_singular"].max() > 0  # flagged steps at the stroke's end
    assert t["avar_s"].max() <= 0.08 + 1e-12 and t["fault"].max() == 0


def test_without_a_push_the_loop_keeps_the_trains_energy_and_the_finger_feels_nothing() -> None:
    """coaster_clothoid, the finger waiting above the valley: the train rocks between its
    ends through the clothoids in the haptic loop; the energy holds (RK4) and no force
    reaches the hand."""
    scene = load_scene("coaster_clothoid")
    t = run_virtual(scene, load_device("ideal"), load_user("hold_still"), 4.0).ticks
    ready = t[t["update_seq"] >= 0]
    energy = ready["avar_energy"]
    assert np.ptp(ready["avar_s"]) > 0.1  # m: it rocks across the valley
    moving = 0.5 * 3 * scene.cars[0].mass * np.abs(ready["avar_sd"]).max() ** 2  # J, at most
    # RK4 holds a looping car to 1e-8 (test_avar.py); the clothoids' joins, where kappa'
    # steps, cost it an order of the step there: 1.2e-5 measured
    assert np.ptp(energy) / moving < 1e-4
    assert np.abs(ready["wrench_command"]).max() < 1e-9
    assert (ready["avar_cars"] == 3).all() and (ready["avar_force"] == 0.0).all()


def test_the_sim_poses_its_cars_from_the_haptic_sides_train() -> None:
    """A fresh proxy state's train: the sim's next step starts from it (carried over its
    age) and ends each car's kinematic body at its pose on the track; a stale one leaves
    the sim integrating its own, which conserves the energy."""
    scene = load_scene("coaster_loop")
    world = SimWorld(scene)
    assert world.train is not None
    target = ToolTarget(
        q=np.array([-0.034, -0.036, 0.0]), qd=np.zeros(3), device_pose=np.zeros(3),
        device_twist=np.zeros(3), coupled_to_device=False, fresh=True,
        train=TrainState(world.train.static_id, 0.1, 0.8), train_age_s=0.0,
    )  # fmt: skip
    world.step(target)
    s, _ = world.train.state
    assert s > 0.1 + 0.8 * world.period * 0.9  # it moved on from the haptic side's state
    table = tabulate(scene.track_spec)[0]
    for k, body in enumerate(world.train.bodies):
        x, y, psi, _, _ = track_point(table, s - k * scene.cars[0].spacing_m)
        assert math.hypot(body.position.x - x, body.position.y - y) < 1e-9
        assert abs(math.remainder(body.angle - psi, 2 * math.pi)) < 1e-9
    other = dataclasses.replace(target, train=TrainState(world.train.static_id + 1, 0.0, 0.0))
    world.step(other)  # another track's state is ignored
    assert world.train.state[0] > s
    cars = scene.cars[0]
    train = train_record(cars.count, cars.spacing_m, cars.mass, cars.inertia, scene.gravity)[0]
    e0 = train_energy(table, train, *world.train.state)
    for _ in range(120):  # 2 s on its own
        world.step(None)
    assert abs(train_energy(table, train, *world.train.state) - e0) < 1e-7 * abs(e0)


def test_an_update_carries_the_train_and_its_cars_are_posed_by_it() -> None:
    """The sim's update: the AVARS trailer (static id, cars, s, s') and the cars' shapes
    owned by their car, carried by the train (motion 3); it decodes as it was sent."""
    scene = load_scene("coaster_loop")
    world = SimWorld(scene)
    update = decode_update(world.local_model_bytes(1, 0, 0))
    assert update.avars is not None
    assert (update.avars.static_id, update.avars.cars) == (static_id(scene), 3)
    assert update.avars.s == pytest.approx(scene.cars[0].initial_s)
    assert update.shapes is not None
    cars = update.shapes[update.shapes["owner"] >= 0]
    assert sorted(cars["owner"].tolist()) == [0, 1, 2] and (cars["motion"] == 3).all()
    assert decode_update(encode_update(update)).avars == update.avars


def test_the_haptic_side_installs_only_its_own_scenes_train() -> None:
    """An update of another train (static id), a train scene's update without its train, or
    a train where the scene has none: refused as `static`, never installed."""
    scene = load_scene("coaster_loop")
    raw = SimWorld(scene).local_model_bytes(1, 0, 0)
    other = dataclasses.replace(scene, cars=(dataclasses.replace(scene.cars[0], mass=0.06),))
    engine = HapticEngine(other, load_device("ideal"), load_user("hold_still"))
    assert engine.receive(raw) == "static"
    engine = HapticEngine(scene, load_device("ideal"), load_user("hold_still"))
    update = decode_update(raw)
    assert (
        engine.receive(encode_update(dataclasses.replace(update, avars=None, shapes=None)))
        == "static"
    )
    plain = load_scene("god_rotating_box")
    engine = HapticEngine(plain, load_device("ideal"), load_user("hold_still"))
    assert engine.receive(SimWorld(plain).local_model_bytes(1, 0, 0)) == ""
    assert engine.receive(encode_update(dataclasses.replace(update, seq=1))) == "static"


def test_the_static_message_names_its_train_and_a_stranger_is_refused_by_name() -> None:
    scene = load_scene("coaster_loop")
    raw = encode_static(scene)
    sid, desc = decode_static(raw)
    assert sid == static_id(scene) >= 0 and desc["cars"]["count"] == 3
    assert check_static(scene, raw) == ""
    moved = dataclasses.replace(scene, cars=(dataclasses.replace(scene.cars[0], initial_s=0.05),))
    assert static_id(moved) == sid  # where the train starts is state, not its tables
    other = load_scene("coaster_clothoid")
    assert "differs from scene 'coaster_loop' in cars, track" in check_static(
        scene, encode_static(other)
    )
    assert b'"mass":0.05' in raw
    forged = raw.replace(b'"mass":0.05', b'"mass":0.06')  # the description changed under its id
    with pytest.raises(MessageError, match=r"static: static id"):
        decode_static(forged)
    with pytest.raises(MessageError, match="magic"):
        decode_static(b"XXXX" + raw[4:])
    assert "not JSON" in check_static(scene, raw[:20] + b"\xff" + raw[21:])
    assert static_id(load_scene("god_rotating_box")) == -1


@pytest.mark.parametrize(
    ("edit", "key", "problem"),
    [
        (('track = "loop"', 'track = "ring"'), "cars[0].track", "no track named 'ring'"),
        (("initial_s = 0.02", "initial_s = 0.5"), "cars[0].initial_s", "must be within"),
        (("count = 3", "count = 9"), "cars[0].count", "must be within"),
        (("semi_axes = [0.06, 0.04]", "semi_axes = [0.06, -0.04]"), "tracks[0].semi_axes[1]", ""),
        (('material = "car"\n', 'material = "wood"\n'), "cars[0].material", "unknown material"),
        (('method = "god_object"', 'method = "local_model"'), "cars", "god_object"),
    ],
)
def test_a_bad_train_is_refused_naming_its_key(
    edit: tuple[str, str], key: str, problem: str
) -> None:
    text = (SCENE_DIR / "coaster_loop.toml").read_text()
    assert edit[0] in text
    with pytest.raises(ConfigError) as info:
        load_config_text(
            type(load_scene("coaster_loop")), text.replace(edit[0], edit[1], 1), "x.toml"
        )
    assert info.value.key == key and problem in info.value.problem, str(info.value)


def test_a_track_that_cannot_be_built_is_refused_at_load() -> None:
    text = (SCENE_DIR / "coaster_clothoid.toml").read_text()
    broken = text.replace("turn = 0.08", "turn = 0.5").replace("closed", "x")
    broken = broken.replace("heading = -0.4\n", "heading = -0.4\nclosed = true\n")
    with pytest.raises(ConfigError, match=r"tracks\[0\].*closed track must end at its start"):
        load_config_text(type(load_scene("coaster_loop")), broken, "x.toml")


@pytest.mark.processes
def test_the_coaster_runs_in_real_time_over_zenoh_and_replays_exactly(tmp_path: Path) -> None:
    """coaster_loop as a user runs it: both servers as processes over Zenoh on loopback for
    10 s with the twin pantograph and the shoving hand. The sim's static message arrives and
    is this scene's; every update installs; the finger moves the train; nothing faults; the
    log replays bit for bit (the train's integration is part of the replayed tick)."""
    network_file = write_network_file(tmp_path / "net.toml")
    log_path = tmp_path / "run.mcap"
    summary = haptic_run(
        network_file, log_path, tmp_path / "summary.json",
        scene="coaster_loop", device="twin_pantograph", user="push_car", seconds=10.0,
    )  # fmt: skip
    assert set(summary["rejected_by_reason"] or {}) <= {"late"}, summary
    assert summary["static_received"] >= 8 and summary["static_refused"] == 0, summary
    log = read_log(log_path)
    ready = log.ticks[log.ticks["update_seq"] >= 0]
    assert len(ready) >= 0.95 * 10_000
    assert (ready["fault"] == 0).all() and np.isfinite(log.ticks["wrench_command"]).all()
    assert (ready["avar_cars"] == 3).all()
    assert np.ptp(ready["avar_s"]) > 0.01 and ready["avar_work"].max() > 1e-4  # pushed
    result = replay(log)
    assert result.identical, result.differing
    assert result.updates_replayed == len(log.updates) > 0


def test_a_released_god_object_is_no_runaway_but_one_carried_off_is() -> None:
    """The runaway guard's god-object rule (haptic_server/stages/safety.py): a proxy that
    lands on the hand within the tick, or nearer it by a path around a corner, is not
    running away (the 'swing' hand pressed 7 mm into a car of coaster_clothoid, the car slid
    on, and the proxy's 4.9 m/s tripped the guard), nor one that follows the hand at its
    distance; one carried away from the hand counts at the rate its distance opens, however
    deep it was pressed."""
    from haptic_local_model.haptic_server.model import DATA_DTYPE
    from haptic_local_model.haptic_server.stages.safety import _away_from_hand

    data = np.zeros(1, DATA_DTYPE)
    d = data[0]
    d["dt"] = 1e-3
    d["god"]["finger_now"] = (0.007, 0.0)
    d["state"]["q"][:2] = (0.007, 0.0)  # it moved 7 mm onto the hand: 7 m/s
    assert _away_from_hand(d, 7.0, 0.0) == (0.0, 0.0)
    d["god"]["finger_now"] = (0.00681, 0.00375)  # coaster_clothoid's tick 735, p0 at 0
    d["state"]["q"][:2] = (0.0015, -0.0017)  # round the car's corner: 7.77 -> 7.62 mm
    assert _away_from_hand(d, 1.5, -1.7) == (0.0, 0.0)
    d["god"]["finger_now"] = (0.0, 0.0)
    d["state"]["q"][:2] = (0.007, 0.0)  # from the hand, carried 7 mm off
    assert _away_from_hand(d, 7.0, 0.0) == pytest.approx((7.0, 0.0))
    d["god"]["finger_now"] = (0.0, -0.005)  # pressed 5 mm, then carried 10 mm up
    d["state"]["q"][:2] = (0.0, 0.010)
    assert _away_from_hand(d, 0.0, 10.0) == pytest.approx((0.0, 10.0))
    d["god"]["finger_now"] = (0.010, 0.0)  # a free proxy following a fast hand: 10 m/s
    d["state"]["q"][:2] = (0.010, 0.0)
    assert _away_from_hand(d, 10.0, 0.0) == (0.0, 0.0)


def test_the_io_process_counts_static_messages_and_survives_hostile_ones() -> None:
    """The sidecar's subscriber (haptic_server/sidecar.py): this scene's static message is
    counted; another scene's, a malformed one and JSON nested past Python's stack are
    refused, counted and told once per reason, and never raise out of the callback."""
    from types import SimpleNamespace
    from typing import Any

    from haptic_local_model.haptic_server.mailbox import (
        C_STATIC_BAD,
        C_STATIC_OK,
        C_STATIC_REASONS,
        N_CTL,
        STATIC_REASONS,
    )
    from haptic_local_model.haptic_server.sidecar import _static_receiver, by_reason
    from haptic_local_model.shared.protocol.static import (
        STATIC_HEADER,
        STATIC_MAGIC,
        STATIC_VERSION,
        canonical,
        id_of,
    )

    events: list[tuple[str, str]] = []
    block: Any = SimpleNamespace(
        ctl=np.zeros(N_CTL, np.int64),
        post_event=lambda tick, kind, text: events.append((kind, text)),
    )
    scene = load_scene("coaster_loop")
    receive = _static_receiver(block, static_id(scene))

    def sample(raw: bytes) -> Any:
        return SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: raw))

    nested = STATIC_HEADER.pack(STATIC_MAGIC, STATIC_VERSION, 0) + b"[" * 60_000
    started = time.monotonic()  # before the first refusal told: one a second after it
    for raw in (encode_static(scene), encode_static(load_scene("crank")), b"junk", nested, nested):
        receive(sample(raw))
    assert block.ctl[C_STATIC_OK] == 1 and block.ctl[C_STATIC_BAD] == 4
    assert len(events) == 3 and all(kind == "static" for kind, _ in events), events
    by = by_reason(block.ctl, STATIC_REASONS, C_STATIC_REASONS)
    assert by == {"foreign": 1, "malformed": 1, "hostile": 2}
    # a flood of distinct foreign ids: counted, told at most once a second per reason (it
    # was told once per distinct text: 30,000 messages grew the process by ~6.8 MB and
    # pushed 8 events out of the 256-slot ring)
    for i in range(30_000):
        desc = {"flood": i}
        receive(
            sample(STATIC_HEADER.pack(STATIC_MAGIC, STATIC_VERSION, id_of(desc)) + canonical(desc))
        )
    told = len(events) - 3  # at most one a second (a loaded host takes more than one)
    assert block.ctl[C_STATIC_BAD] == 30_004 and told <= time.monotonic() - started, events[3:]
    assert by_reason(block.ctl, STATIC_REASONS, C_STATIC_REASONS)["foreign"] == 30_001

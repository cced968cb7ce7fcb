"""A hand scene's port (haptic_server/hand_ports.py, docs/grasp.md): the mass-spring hand's
palm driven by a simulated device, its fingers by the user's glove script; the palm's command
to the device; the log and its bit-exact replay through `haptic-run` and `haptic-replay`."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from haptic_local_model.device_models.registry import load_simulated_device
from haptic_local_model.haptic_server.hand_ports import (
    HAND_ROW_DTYPE,
    HandPortRun,
    replay_hand_rows,
    run_hand_port_ticks,
)
from haptic_local_model.haptic_server.harness.replay import main as haptic_replay
from haptic_local_model.haptic_server.harness.run import main as haptic_run
from haptic_local_model.haptic_server.port_scene import glove_script
from haptic_local_model.haptic_server.world_runs import (
    HAND_TICK_TOPIC,
    read_port_log,
    write_rows_log,
)
from haptic_local_model.shared.config import ConfigError, load_user
from haptic_local_model.shared.port_config import load_hand_scene

SCENE = "hand_press"
PRESS = slice(1100, 1400)  # the palm at rest on the wall, before the glove flexes (1.5 s)


@pytest.fixture(scope="module", params=["ideal", "twin_pantograph", "maglev"])
def pressed(request: pytest.FixtureRequest) -> tuple[str, HandPortRun, np.ndarray]:
    run = HandPortRun(load_hand_scene(SCENE), load_simulated_device(request.param))
    return request.param, run, run.run(2.6).rows


def test_the_device_renders_the_wall_through_the_hand(pressed) -> None:
    """Any shipped device: the proxy hand stops at the wall, and at rest the user's hand
    holds against the wall's force on the hand, mapped to the device (100 ms means), within
    1 %: what the user feels, through the palm spring's command, the device's map and its
    actuators. (The palm command against the wall's force alone is a static balance of the
    proxy, true whatever the device renders.) Every command is the palm's, mapped and
    clipped."""
    name, run, rows = pressed
    w = rows[PRESS]
    assert w["n_contacts"].min() >= 1, name
    wall = w["contact_force"].mean(axis=0)
    assert wall[0] < -0.5, (name, wall)  # pushed back from the wall, along -x
    m = run.io[0]["map"][0]
    to_device = m["force_scale"] * m["scale"][:2]
    felt = -w["hand_wrench"][:, :2].mean(axis=0)  # the user's hand holds against the device
    assert np.abs(felt - to_device * wall).max() <= 0.01 * np.abs(to_device * wall).max(), (
        name, felt, wall,
    )  # fmt: skip
    limits = np.array(run.device.limits().max_wrench)
    scale = m["force_scale"] * m["scale"]
    assert np.array_equal(rows["out"], np.clip(scale * rows["command"], -limits, limits))
    assert rows["singular"][-1] == 0 and rows["invalid"][-1] == 0
    separation = (w["target"][:, 0] - w["q"][:, 0]).mean()
    assert separation == pytest.approx(-wall[0] / run.spec.palm_spring[0], rel=0.01)


def test_a_devices_estimated_rates_are_not_differenced_into_the_palms_acceleration() -> None:
    """The palm's tracked rates are the maglev's twist estimate: differenced by 1 / dt they
    carried its noise into the command. Not differenced, the command's noise at rest halves
    (the same seeded noise, the flag off and on)."""
    spread = {}
    for measured in (0, 1):
        run = HandPortRun(load_hand_scene(SCENE), load_simulated_device("maglev"))
        run.model[0]["measured_palm"] = measured
        rows = run.run(1.5).rows
        spread[measured] = float(rows["command"][PRESS, 0].std())
        if measured:
            assert np.all(run.data[0]["target_acc"][:3] == 0.0)
    assert spread[1] < 0.7 * spread[0], spread


def test_a_tendon_glove_only_holds_a_finger_back(pressed) -> None:
    """Unilateral glove: each joint's torque on the user is applied only when it resists
    flexion (flexion sign times torque <= 0), and then is the ungated torque itself."""
    name, run, rows = pressed
    n = run.spec.dof
    flexion = np.array([f.flexion for f in run.spec.fingers for _ in range(2)])
    gated, ungated = rows["glove_torque"][:, 3:n], rows["glove_ungated"][:, 3:n]
    pushes = flexion * ungated > 0.0
    assert pushes.any() and (~pushes & (ungated != 0.0)).any(), name  # both cases occur
    assert np.all(gated[pushes] == 0.0)
    assert np.array_equal(gated[~pushes], ungated[~pushes])


def test_a_reading_that_is_not_finite_cuts_its_drive_for_those_ticks_only() -> None:
    run = HandPortRun(load_hand_scene(SCENE), load_simulated_device("ideal"))
    rows = np.zeros(1300, HAND_ROW_DTYPE)
    args = (run.chain, run.model, run.data, run.io, run.device.records, rows)
    assert run_hand_port_ticks(*args, 0, 1200) == 1200
    offset = run.io[0]["map"][0]["offset"].copy()
    run.io[0]["map"][0]["offset"][0] = np.nan
    assert run_hand_port_ticks(*args, 1200, 1205) == 1205
    run.io[0]["map"][0]["offset"] = offset
    assert run_hand_port_ticks(*args, 1205, 1300) == 1300
    assert np.all(rows["command"][1200:1205, 0] == 0.0)  # x's reading: x's drive cut
    assert abs(rows["command"][1199, 0]) > 0.5  # it was pressing
    assert np.isfinite(rows["q"]).all() and np.isfinite(rows["command"]).all()
    assert abs(rows["command"][1299, 0]) > 0.5  # and back once the reading is


def test_the_glove_script_must_fit_the_hand() -> None:
    user = dataclasses.replace(load_user("hand_press_wall"), finger_angles=((0.0, 0.1),))
    with pytest.raises(ValueError, match="1 angles a row, the hand has 4 joints"):
        glove_script(user, [0.3, 0.2, -0.3, -0.2])
    assert glove_script(dataclasses.replace(user, finger_angles=()), [0.3, 0.2]).tolist() == [
        [0.0, 0.3, 0.2]
    ]


def test_a_hand_scene_names_what_is_wrong(tmp_path: Path) -> None:
    from haptic_local_model.shared.config import resolve

    text = resolve("ports", SCENE).read_text().replace('tool = "right_hand"', 'tool = "left"')
    bad = tmp_path / "bad_hand.toml"
    bad.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_hand_scene(str(bad))
    assert err.value.key == "ports[0].tool"


@pytest.fixture(scope="module")
def hand_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("hand") / "hand.mcap"
    argv = f"--clock virtual --scene {SCENE} --duration 2.6 --device maglev".split()
    assert haptic_run([*argv, "--log", str(path)]) == 0
    return path


def test_a_hand_run_logs_every_tick_and_replays_bit_for_bit(hand_log, tmp_path, capsys) -> None:
    rows, metadata = read_port_log(hand_log, HAND_TICK_TOPIC, HAND_ROW_DTYPE)
    assert len(rows) == 2600 and metadata["run"]["kind"] == "hand"
    assert haptic_replay([str(hand_log)]) == 0
    assert "replayed 2600 ticks" in capsys.readouterr().out
    scene = load_hand_scene(SCENE)
    limits = tuple(float(v) for v in json.loads(metadata["limits"]["max_wrench"])[0])
    tampered = rows.copy()
    q = tampered["q"]
    q[1300, 3] = np.nextafter(q[1300, 3], np.inf)  # one bit of one joint, during the press
    tampered["q"] = q
    assert replay_hand_rows(scene, limits, tampered) == (1301, 1300)
    bad = tmp_path / "tampered.mcap"
    write_rows_log(bad, tampered, HAND_TICK_TOPIC, "haptic_server/HandPortTick", metadata)
    assert haptic_replay([str(bad)]) == 1

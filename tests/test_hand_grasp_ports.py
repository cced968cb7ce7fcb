"""Two hands in ports holding one box (`hand_grasp`, haptic_server/hand_grasp_ports.py,
docs/grasp.md): each palm driven by its simulated device, both hands and the box in one
implicit step, each palm's command to its device; V5.5 with devices; the log and its
bit-exact replay through `haptic-run` and `haptic-replay`; scenes that are not two hands
on a box."""

from __future__ import annotations

import dataclasses
import itertools
import json
from pathlib import Path

import numpy as np
import pytest

from haptic_local_model.benchmarks.hand import hand_grasp_port, hand_mass
from haptic_local_model.device_models.registry import load_simulated_device
from haptic_local_model.haptic_server.hand_grasp_ports import (
    HAND_GRASP_ROW_DTYPE,
    HandGraspRun,
    replay_hand_grasp_rows,
)
from haptic_local_model.haptic_server.harness.replay import main as haptic_replay
from haptic_local_model.haptic_server.harness.run import main as haptic_run
from haptic_local_model.haptic_server.world_runs import (
    HAND_GRASP_TOPIC,
    read_port_log,
    write_rows_log,
)
from haptic_local_model.shared.config import ConfigError, resolve
from haptic_local_model.shared.port_config import load_hand_scene

SCENE = "hand_grasp"
DEVICES = ("ideal", "twin_pantograph", "maglev")


@pytest.mark.parametrize("devices", list(itertools.product(DEVICES, repeat=2)))
def test_any_shipped_device_on_either_hand_holds_the_box(devices) -> None:
    """1 s of hand_grasp on every pair of shipped devices: from its first tick the box
    stays (50 µm: each device starts where its palm's springs balance its user's push),
    both palms keep both hand-box contacts, and each device renders (its own command, in
    its frame) what its user pushes: 2 N of squeeze and the hand and half the box carried,
    (0.218 + 0.05) kg g (100 ms means, to 2 %), within its limits every tick."""
    scene = load_hand_scene(SCENE)
    run = HandGraspRun(scene, [load_simulated_device(d) for d in devices])
    rows = run.run(1.0).rows
    box = rows["box_q"]
    assert np.isfinite(rows["q"]).all() and rows["singular"][-1] == 0
    assert np.abs(box[:, :2]).max() < 5e-5, devices  # it starts at the origin
    assert rows["n_contacts"][20:].min() == 4, devices
    g = abs(scene.gravity[1])
    carried = (hand_mass(scene.hands[0]) + scene.box.mass / 2) * g
    for p, dev in enumerate(run.devices):
        m = run.io[p]["map"][0]
        rendered = rows["out"][-100:, p, :2].mean(axis=0) / (m["force_scale"] * m["scale"][:2])
        side = 1.0 if p == 1 else -1.0  # each palm is pushed back out of the grip
        np.testing.assert_allclose(rendered, [side * 2.0, -carried], rtol=0.02,
                                   err_msg=str(devices))  # fmt: skip
        limits = np.asarray(dev.limits().max_wrench)
        assert np.all(np.abs(rows["out"][:, p]) <= limits + 1e-12), devices


def test_v5_5_two_device_driven_hands_hold_the_box_as_in_v4_1() -> None:
    """V5.5 with maglevs (sensor noise on), 5 s: V4.1's slip, balance and contact losses,
    and its transparency check (each device's command against its user's wrench, 100 ms
    means). Each hand's force on the box: its user's 2 N squeeze along x, and the two shares
    of the weight along y summing to m g, each half of it (the split is friction's, so
    statically indeterminate, but the grasp is symmetric: 0.1 % apart)."""
    r = hand_grasp_port(("maglev", "maglev"))
    (lx, ly), (rx, ry) = r["hand_force_n"]
    assert lx == pytest.approx(2.0, rel=0.01) and rx == pytest.approx(-2.0, rel=0.01)
    assert ly + ry == pytest.approx(0.1 * 9.81, rel=0.01)
    assert ly == pytest.approx(0.1 * 9.81 / 2, rel=0.02) and ry == pytest.approx(ly, rel=0.02)
    assert r["hand_shares_vs_box_force_n"] < 1e-12
    assert r["contacts_tracked"] == 4
    assert r["slip_max_m"] <= 0.1e-3
    assert r["balance_max_fraction"] <= 0.01
    assert r["contact_losses"] == 0
    assert r["transparency_max_n"] <= 0.02
    assert r["squeeze_n"] == pytest.approx(2.0, rel=0.01)
    assert r["steps_held"] == 0 and r["not_finite"] == 0


def test_a_reading_that_is_not_finite_cuts_that_palms_drive_and_the_other_holds() -> None:
    """One device's reading not finite for 5 ticks: that palm's drive along x is cut (its
    command 0 there), nothing else is not finite, the other palm keeps squeezing, and the
    drive is back afterwards."""
    run = HandGraspRun(load_hand_scene(SCENE), [load_simulated_device("ideal")] * 2)
    rows = np.zeros(800, HAND_GRASP_ROW_DTYPE)
    run.ticks(rows, 0, 500)
    offset = run.io[0]["map"][0]["offset"].copy()
    run.io[0]["map"][0]["offset"][0] = np.nan
    run.ticks(rows, 500, 505)
    run.io[0]["map"][0]["offset"] = offset
    run.ticks(rows, 505, 800)
    assert np.all(rows["command"][500:505, 0, 0] == 0.0)
    assert abs(rows["command"][499, 0, 0]) > 1.5
    # only x's drive is cut: y still carries the hand, the other palm still squeezes, and
    # the coupled step never failed (a failed one is held, and counted)
    np.testing.assert_allclose(rows["command"][500:505, 0, 1], -2.63, atol=0.05)
    assert np.all(np.abs(rows["command"][500:505, 1, 0]) > 1.5)
    assert rows["singular"][-1] == 0 and rows["invalid"][-1, 1] == 0
    assert rows["invalid"][-1, 0] == 5
    assert np.isfinite(rows["q"]).all() and np.isfinite(rows["command"]).all()
    assert abs(rows["command"][799, 0, 0]) > 1.5
    assert rows["n_contacts"][799] == 4


def test_a_box_out_of_range_waits_for_the_hands_to_open_then_returns_to_its_start() -> None:
    """The box put 1 cm beyond a 0.2 m range while both hands hold where it started: held at
    rest at the range; the palms moved 0.5 m aside: back at its start, at rest, that tick."""
    scene = dataclasses.replace(load_hand_scene(SCENE), range_m=0.2)
    run = HandGraspRun(scene, [load_simulated_device("ideal")] * 2)
    rows = np.zeros(400, HAND_GRASP_ROW_DTYPE)
    run.ticks(rows, 0, 100)
    gm, gd = run.gmodel[0], run.gdata[0]
    start = gm["box_start"].copy()
    gd["q_box"][1] = -0.21
    run.ticks(rows, 100, 200)
    assert int(gd["resets"]) == 0 and int(gd["parked"]) == 100
    assert gd["q_box"][1] == -0.2 and not gd["qd_box"].any()
    for p, side in enumerate((-1.0, 1.0)):
        run.datas[p][0]["q"][0] += side * 0.5  # the palm, far aside
    run.ticks(rows, 200, 201)
    assert int(gd["resets"]) == 1 and np.array_equal(gd["q_box"], start)
    assert not gd["qd_box"].any() and not gd["touching"].any()


@pytest.mark.parametrize(
    ("old", "new", "key"),
    [
        ('[[bodies]]\nname = "box"\nkind = "dynamic"', '[[bodies]]\nname = "box"\nkind = "static"',
         "bodies"),
        ('tool = "right_hand"', 'tool = "left_hand"', "ports"),
        ('tool = "right_hand"', 'tool = "a_hand"', "ports[1].tool"),
        ('shape = "box"\nsize = [0.04, 0.02]', 'shape = "circle"\nradius = 0.01', "bodies[0]"),
        ('material = "pad"', 'material = "pad"\n\n[[bodies]]\nname = "floor"\nkind = "static"\n'
         'shape = "box"\nsize = [0.2, 0.01]\nposition = [0.0, -0.05]\nmaterial = "wall"', "bodies"),
        # a hand scene's contacts are penalty contacts: the port scenes' impulse keys are not
        ("friction_stiffness_ratio = 1.0", "friction_stiffness_ratio = 1.0\nimpulses = true",
         "contact.impulses"),
    ],
)  # fmt: skip
def test_a_two_hand_scene_names_what_is_wrong(tmp_path: Path, old, new, key) -> None:
    text = resolve("ports", SCENE).read_text()
    assert old in text
    bad = tmp_path / "bad_grasp.toml"
    bad.write_text(text.replace(old, new, 1))
    with pytest.raises(ConfigError) as err:
        load_hand_scene(str(bad))
    assert err.value.key == key


def test_one_hand_cannot_hold_a_box(tmp_path: Path) -> None:
    text = resolve("ports", "hand_press").read_text()
    bad = tmp_path / "one_hand_box.toml"
    bad.write_text(text + '\n[[bodies]]\nname = "box"\nkind = "dynamic"\nshape = "box"\n'
                   "size = [0.04, 0.02]\nposition = [0.0, 0.05]\nmaterial = \"pad\"\n")  # fmt: skip
    with pytest.raises(ConfigError) as err:
        load_hand_scene(str(bad))
    assert err.value.key == "bodies"


@pytest.fixture(scope="module")
def grasp_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("grasp") / "grasp.mcap"
    argv = f"--clock virtual --scene {SCENE} --duration 1 --device maglev".split()
    assert haptic_run([*argv, "--device", "twin_pantograph", "--log", str(path)]) == 0
    return path


def test_a_two_hand_run_logs_every_tick_and_replays_bit_for_bit(grasp_log, tmp_path, capsys):
    rows, metadata = read_port_log(grasp_log, HAND_GRASP_TOPIC, HAND_GRASP_ROW_DTYPE)
    assert len(rows) == 1000 and json.loads(metadata["configs"]["devices"]) == [
        "maglev", "twin_pantograph",
    ]  # fmt: skip
    assert haptic_replay([str(grasp_log)]) == 0
    assert "replayed 1000 ticks" in capsys.readouterr().out
    limits = [tuple(map(float, v)) for v in json.loads(metadata["limits"]["max_wrench"])]
    tampered = rows.copy()
    box = tampered["box_q"]
    box[600, 1] = np.nextafter(box[600, 1], np.inf)  # one bit of the box's height
    tampered["box_q"] = box
    assert replay_hand_grasp_rows(load_hand_scene(SCENE), limits, tampered) == (601, 600)
    bad = tmp_path / "tampered.mcap"
    write_rows_log(bad, tampered, HAND_GRASP_TOPIC, "haptic_server/HandGraspTick", metadata)
    assert haptic_replay([str(bad)]) == 1


def test_a_glove_that_does_not_fit_its_hand_is_named_by_its_users_file(tmp_path, capsys):
    bad = tmp_path / "bad_glove.toml"
    text = resolve("users", "hand_grasp_right").read_text()
    bad.write_text(text.replace('name = "hand_grasp_right"', 'name = "bad_glove"')
                   + "finger_angles = [[0.0, 0.1]]\n")  # fmt: skip
    argv = f"--clock virtual --scene {SCENE} --duration 0.01 --user hand_grasp_left".split()
    code = haptic_run([*argv, "--user", str(bad)])
    err = capsys.readouterr().err
    assert code == 2
    assert str(bad) in err and "finger_angles" in err and "hand_grasp_left" not in err

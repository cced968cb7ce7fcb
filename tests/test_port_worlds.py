"""`haptic-run` of a port scene on the virtual clock, its MCAP log and the log's bit-exact
replay through `haptic-replay` (haptic_server/world_runs.py)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from haptic_local_model.haptic_server import world_runs
from haptic_local_model.haptic_server.harness.replay import main as haptic_replay
from haptic_local_model.haptic_server.harness.run import main as haptic_run
from haptic_local_model.haptic_server.log import LogWriter
from haptic_local_model.haptic_server.ports import replay_rows
from haptic_local_model.haptic_server.world import PacedTimes, paced_loop, run_paced, run_virtual
from haptic_local_model.haptic_server.world_runs import (
    port_scene,
    read_port_log,
    replay_log,
    write_port_log,
)
from haptic_local_model.shared.config import ConfigError
from haptic_local_model.shared.memory import available_bytes
from haptic_local_model.shared.port_config import load_port_scene


@pytest.fixture(scope="module")
def logged(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("ports") / "grasp.mcap"
    argv = "--scene grasp_vertical --clock virtual --duration 1 --device maglev"
    code = haptic_run([*argv.split(), "--device", "twin_pantograph", "--log", str(path)])
    assert code == 0
    return path


def test_a_port_run_logs_every_tick_and_replays_bit_for_bit(logged, capsys):
    rows, metadata = read_port_log(logged)
    assert len(rows) == 1000
    assert np.all(rows["n_contacts"] == 4)
    assert '"maglev", "twin_pantograph"' in metadata["configs"]["devices"]
    assert not list(logged.parent.glob("*.part"))  # renamed when whole
    assert haptic_replay([str(logged)]) == 0
    assert "replayed 1000 ticks" in capsys.readouterr().out


def test_the_replay_finds_a_row_that_is_not_the_co_simulations(logged):
    """One bit of one logged body's position changed at tick 500: the replay stops there."""
    rows, metadata = read_port_log(logged)
    rows = rows.copy()
    q = rows["q"]
    q[500, 6] = np.nextafter(q[500, 6], np.inf)
    rows["q"] = q
    scene = load_port_scene("grasp_vertical")
    limits = [tuple(v) for v in json.loads(metadata["limits"]["max_wrench"])]
    assert replay_rows(scene, limits, rows) == (501, 500)


def test_haptic_replay_exits_1_on_a_port_log_that_differs(logged, tmp_path, capsys):
    rows, metadata = read_port_log(logged)
    rows = rows.copy()
    rows["command"][700, 1, 0] += 1e-9
    tampered = tmp_path / "tampered.mcap"
    write_port_log(tampered, rows, metadata)
    assert haptic_replay([str(tampered)]) == 1
    assert "tick 700" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("change", "key"),
    [
        (lambda md: md["limits"].update(max_wrench="[1, 2"), "limits.max_wrench"),
        (lambda md: md["limits"].update(max_wrench="[[1, 2, 3]]"), "limits.max_wrench"),
        (lambda md: md["run"].update(ticks="999"), "run.ticks"),
        (lambda md: md["configs"].pop("ports"), "configs.ports"),
    ],
)
def test_a_log_with_bad_metadata_is_refused_by_name(logged, tmp_path, capsys, change, key):
    rows, metadata = read_port_log(logged)
    metadata = {k: dict(v) for k, v in metadata.items()}
    change(metadata)
    bad = tmp_path / "bad.mcap"
    write_port_log(bad, rows, metadata)
    assert haptic_replay([str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bad.mcap" in err and key in err


def test_a_log_cut_short_is_refused(logged, tmp_path, capsys):
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(logged.read_bytes()[: logged.stat().st_size // 2])
    assert haptic_replay([str(cut)]) == 2
    assert "cut short" in capsys.readouterr().err


def test_a_log_that_is_not_a_port_log_is_refused_by_name(tmp_path):
    other = tmp_path / "haptic.mcap"
    writer = LogWriter(other)
    writer.close()
    with pytest.raises(ConfigError, match=r"haptic\.mcap.*/ports/tick"):
        replay_log(other)
    (tmp_path / "junk.mcap").write_bytes(b"not mcap at all")
    with pytest.raises(ConfigError, match=r"junk\.mcap"):
        read_port_log(tmp_path / "junk.mcap")


def test_three_devices_for_two_ports_is_a_usage_error(capsys):
    argv = "--scene grasp_vertical --clock virtual --duration 0.01"
    code = haptic_run([*argv.split(), *["--device", "maglev"] * 3])
    assert code == 2
    assert "--device" in capsys.readouterr().err


def test_a_port_scene_refuses_what_only_a_single_device_run_has(capsys):
    for extra in (["--haptic-rate", "2000"], ["--view"]):
        argv = ["--scene", "grasp_vertical", "--clock", "virtual", "--no-log", *extra]
        assert haptic_run(argv) == 2
        assert extra[0] in capsys.readouterr().err


def test_a_run_whose_rows_do_not_fit_in_memory_is_refused_before_it_starts(capsys, monkeypatch):
    """A port world holds every tick's row until the run ends (832 B a tick in
    grasp_vertical: 3.0 GB an hour at 1 kHz); a run that would outgrow the machine is one
    line and exit 2 before anything runs, naming --duration and how long a run fits."""
    row = port_scene("grasp_vertical", ["maglev"], None).world().kind.rows.itemsize
    available = row * 1000 * 0.2 / world_runs.ROWS_SHARE  # 0.2 s of rows at 1 kHz fit
    monkeypatch.setattr(world_runs, "available_bytes", lambda: available)
    argv = ["--scene", "grasp_vertical", "--device", "maglev", "--clock", "virtual", "--no-log"]
    assert haptic_run([*argv, "--duration", "0.25"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert "--duration" in lines[0] and f"{row} B a tick" in lines[0], lines[0]
    assert "at most 0.2 s here" in lines[0], lines[0]
    assert haptic_run([*argv, "--duration", "0.15"]) == 0  # a run that fits runs


def test_the_memory_available_is_a_part_of_the_machine_s():
    total = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    assert 0 < available_bytes() <= total


@pytest.mark.parametrize("scene", ["grasp_vertical", "hand_grasp", "box_push"])
def test_the_real_time_runner_gives_the_virtual_clock_s_rows_bit_for_bit(scene):
    """The real-time runner's compiled loop (world.run_paced: a tick a period through the
    kind's compiled ticks, a spent noise block refilled for the tick it stopped at, each
    device's next block drawn ahead in the slack after a tick) reads the same normals as
    the virtual clock's refills at need: the rows are the same, bit for bit, so a real-time
    run's figures are the virtual clock's. Its deadlines here are a nanosecond apart: it
    runs as fast as it computes, every tick counted late."""
    made = port_scene(scene, ["maglev"], None)
    virtual, _ = run_virtual(made.world(), 3.0)
    world = made.world()
    rows = np.zeros(len(virtual), world.kind.rows)
    loop, times = paced_loop(1), PacedTimes.of(len(rows))
    drawn = run_paced(world, rows, loop, times, lambda: False)
    assert rows.tobytes() == virtual.tobytes()
    # each device's next block drawn at the start, and again after the blocks ran out
    assert drawn > len(world.devices)
    lp = loop[0]
    assert lp["tick"] == times.work_us.count == times.late_us.count == len(rows)
    assert lp["overruns"] == len(rows)  # each tick started more than a period late
    # the first deadline was 0: the first tick's lateness is its start; the intervals kept
    # between the ticks' starts add up to the time from it to the last (to the clock's ns)
    first = times.late_us.values()[0] * 1e3
    span_ms = (lp["last_start_ns"] - first) / 1e6
    assert times.intervals_ms.values().sum() == pytest.approx(span_ms, abs=1e-6)


def test_one_device_pushes_a_box_into_a_wall_and_holds_it_there():
    """`box_push`, a world of one port (haptic_server/one_port.py): the hand's 2 N push
    slides the box across the 10 mm gap and presses it on the wall. At rest the box's right
    face is in the wall's surface by the push over its two corners' contact stiffness
    (2 N / (2 x 15 kN/m) = 0.067 mm; the box's small turn and the pad's push not quite
    horizontal move it by a few µm), and the device's command balances its hand's push."""
    made = port_scene("box_push", None, None)
    world = made.world()
    assert type(world).__name__ == "OnePortRun"
    rows, _ = run_virtual(world, 3.0)
    box = 3 * world.order.index("box")
    give = rows["q"][-1, box] - 0.010  # the face at the wall's surface: x = 0.030 - 0.020
    assert give == pytest.approx(2.0 / (2 * 15000.0), abs=0.015e-3)
    last = rows[-500:]
    assert np.mean(last["command"][:, 0, 0]) == pytest.approx(-2.0, rel=1e-3)
    assert not np.any(last["command"][:, 1])  # the port the scene does not have: nothing
    assert rows["n_contacts"][-1] == 6 and rows["singular"][-1] == 0


@pytest.mark.processes
def test_haptic_run_runs_a_port_scene_in_real_time_and_its_log_replays(tmp_path):
    """`haptic-run --scene grasp_vertical` in real time: two simulated devices in one
    process, the loop's figures in its summary, a log that `haptic-replay` re-runs bit for
    bit (rates and work are the benchmark's: benchmarks/port_worlds.py)."""
    log, summary = tmp_path / "grasp.mcap", tmp_path / "summary.json"
    cmd = [sys.executable, "-m", "haptic_local_model.haptic_server.harness.run",
           "--scene", "grasp_vertical", "--device", "maglev", "--duration", "2",
           "--log", str(log), "--summary-json", str(summary)]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    figures = json.loads(summary.read_text())
    assert figures["world"] == "ports" and figures["ticks"] == 2000
    assert not figures["stopped_early"]
    assert 0.0 < figures["ticks_delivered"] <= 1.0
    assert "real time: 2000 ticks" in proc.stdout
    replayed = subprocess.run(
        [sys.executable, "-m", "haptic_local_model.haptic_server.harness.replay", str(log)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert replayed.returncode == 0, replayed.stderr
    assert "replayed 2000 ticks" in replayed.stdout and "bit-exact" in replayed.stdout

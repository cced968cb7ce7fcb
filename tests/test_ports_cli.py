"""`haptic-ports`: a port scene on the virtual clock, its MCAP log and the log's bit-exact
replay (haptic_server/ports_cli.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from haptic_local_model.haptic_server.log import LogWriter
from haptic_local_model.haptic_server.ports_cli import (
    main,
    read_port_log,
    replay_rows,
    write_port_log,
)
from haptic_local_model.shared.config import ConfigError
from haptic_local_model.shared.port_config import load_port_scene


@pytest.fixture(scope="module")
def logged(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("ports") / "grasp.mcap"
    code = main(["--duration", "1", "--device", "maglev", "--device", "twin_pantograph",
                 "--log", str(path)])  # fmt: skip
    assert code == 0
    return path


def test_a_port_run_logs_every_tick_and_replays_bit_for_bit(logged, capsys):
    rows, metadata = read_port_log(logged)
    assert len(rows) == 1000
    assert np.all(rows["n_contacts"] == 4)
    assert '"maglev", "twin_pantograph"' in metadata["configs"]["devices"]
    assert not list(logged.parent.glob("*.part"))  # renamed when whole
    assert main(["--replay", str(logged)]) == 0
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


def test_haptic_ports_exits_1_on_a_log_that_differs(logged, tmp_path, capsys):
    rows, metadata = read_port_log(logged)
    rows = rows.copy()
    rows["command"][700, 1, 0] += 1e-9
    tampered = tmp_path / "tampered.mcap"
    write_port_log(tampered, rows, metadata)
    assert main(["--replay", str(tampered)]) == 1
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
    assert main(["--replay", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bad.mcap" in err and key in err


def test_a_log_cut_short_is_refused(logged, tmp_path, capsys):
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(logged.read_bytes()[: logged.stat().st_size // 2])
    assert main(["--replay", str(cut)]) == 2
    assert "cut short" in capsys.readouterr().err


def test_a_log_that_is_not_a_port_log_is_refused_by_name(tmp_path, capsys):
    other = tmp_path / "haptic.mcap"
    writer = LogWriter(other)
    writer.close()
    assert main(["--replay", str(other)]) == 2
    err = capsys.readouterr().err
    assert "haptic.mcap" in err and "/ports/tick" in err
    (tmp_path / "junk.mcap").write_bytes(b"not mcap at all")
    with pytest.raises(ConfigError, match=r"junk\.mcap"):
        read_port_log(tmp_path / "junk.mcap")


def test_three_devices_for_two_ports_is_a_usage_error(capsys):
    code = main(["--duration", "0.01", "--device", "maglev", "--device", "maglev",
                 "--device", "maglev"])  # fmt: skip
    assert code == 2
    assert "--device" in capsys.readouterr().err

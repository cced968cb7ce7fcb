"""Any log as numpy structured arrays by field, with units (haptic_server/harness/log_arrays.py,
`api.read_arrays`): a run's log read back against the run's own arrays; a station's and a
port world's rows; the units table against docs/log-format.md; bad files named."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pymunk
import pytest

from haptic_local_model import api
from haptic_local_model.haptic_server.harness.log_arrays import (
    PORT_UNITS,
    STATION_UNITS,
    TICK_UNITS,
)
from haptic_local_model.haptic_server.log import write_rows_log
from haptic_local_model.haptic_server.model import TICK_DTYPE
from haptic_local_model.haptic_server.ports import PORT_KIND, PORT_ROW_DTYPE
from haptic_local_model.haptic_server.stages.station import STATION_ROW_DTYPE
from haptic_local_model.haptic_server.station_records import STATION_TOPIC
from haptic_local_model.shared.config import ConfigError

DOCS = Path(__file__).resolve().parent.parent / "docs"


def test_the_tick_units_are_the_log_formats_table() -> None:
    """docs/log-format.md's `/haptic/tick` table gives each field's unit ("–" none): the
    code's table is the same, field for field, and covers TICK_DTYPE."""
    text = (DOCS / "log-format.md").read_text()
    section = text.split("## `/haptic/tick`")[1].split("\n## ")[0]
    documented = {
        m.group(1): m.group(2).strip().replace("–", "")
        for m in re.finditer(r"^\| `(\w+)` \| [^|]+ \| ([^|]+) \|", section, re.M)
    }
    assert documented == TICK_UNITS
    assert set(TICK_UNITS) == set(TICK_DTYPE.names or ())
    assert set(STATION_UNITS) == set(STATION_ROW_DTYPE.names or ())
    assert set(PORT_UNITS) == set(PORT_ROW_DTYPE.names or ())


def _random_rows(dtype: np.dtype, n: int, seed: int) -> np.ndarray:
    """Rows whose every field holds distinct values (t increasing, as a log's)."""
    rng = np.random.default_rng(seed)
    raw = rng.integers(0, 255, n * dtype.itemsize, dtype=np.uint8).tobytes()
    rows = np.frombuffer(raw, dtype).copy()
    for name in dtype.names or ():
        if np.issubdtype(rows[name].dtype, np.floating):
            rows[name] = rng.normal(size=rows[name].shape)
    rows["t"] = np.arange(n) * 1e-3
    return rows


@pytest.mark.parametrize(
    ("dtype", "topic", "kind", "units"),
    [
        (STATION_ROW_DTYPE, STATION_TOPIC, "station", STATION_UNITS),
        (PORT_ROW_DTYPE, PORT_KIND.topic, "ports", PORT_UNITS),
    ],
)
def test_a_station_or_port_log_reads_back_field_for_field(
    tmp_path: Path, dtype: np.dtype, topic: str, kind: str, units: dict[str, str]
) -> None:
    rows = _random_rows(dtype, 300, seed=len(topic))
    path = tmp_path / "rows.mcap"
    write_rows_log(path, rows, topic, "haptic_server/Rows", {"run": {"ticks": "300"}})
    arrays = api.read_arrays(path)
    assert arrays.kind == kind
    assert arrays.metadata["run"]["ticks"] == "300"
    table = arrays.ticks
    assert table.rows.dtype == dtype  # sub-array shapes kept
    assert table.rows.tobytes() == rows.tobytes()
    assert table.units == units


def test_columns_flatten_sub_arrays_by_index(tmp_path: Path) -> None:
    rows = _random_rows(PORT_ROW_DTYPE, 5, seed=3)
    path = tmp_path / "ports.mcap"
    write_rows_log(path, rows, PORT_KIND.topic, "haptic_server/PortTick", {})
    columns = api.read_arrays(path).ticks.columns()
    shape = PORT_ROW_DTYPE["body_force"].shape
    assert np.array_equal(columns[f"body_force[{shape[0] - 1},2]"], rows["body_force"][:, -1, 2])
    assert np.array_equal(columns["t"], rows["t"])
    width = sum(int(np.prod(PORT_ROW_DTYPE[n].shape)) for n in PORT_ROW_DTYPE.names or ())
    assert len(columns) == width
    assert all(c.shape == (5,) for c in columns.values())


def test_a_frame_without_pandas_says_what_to_install(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "station.mcap"
    write_rows_log(path, _random_rows(STATION_ROW_DTYPE, 3, 1), STATION_TOPIC, "S", {})
    monkeypatch.setitem(sys.modules, "pandas", None)  # an import of it fails
    with pytest.raises(ImportError, match=r"Table\.frame needs pandas \(pip install pandas\)"):
        api.read_arrays(path).ticks.frame()


def test_a_file_that_is_not_a_log_is_refused_by_name(tmp_path: Path) -> None:
    text = tmp_path / "notes.mcap"
    text.write_text("not a log")
    with pytest.raises(ConfigError, match=r"notes\.mcap: file: not an MCAP file"):
        api.read_arrays(text)
    with pytest.raises(ConfigError, match=r"absent\.mcap: file: no such file"):
        api.read_arrays(tmp_path / "absent.mcap")


@pytest.mark.slow
def test_an_offline_runs_log_is_the_runs_arrays_by_field(tmp_path: Path) -> None:
    """The log of a user's space run offline, read in one call: every tick row the run's own
    (poses, command, contacts, faults), every update installed in order with its q, and a
    log cut short read up to its last whole chunk."""
    space = pymunk.Space()
    space.collision_slop = 1e-4
    wall = pymunk.Segment(space.static_body, (0.05, -0.1), (0.05, 0.1), 0.005)
    space.add(wall)
    hand = pymunk.Body(1.0, 1.0e-3)
    space.add(hand, pymunk.Circle(hand, 0.01))
    log = tmp_path / "touch.mcap"
    run = api.run_offline(space, hand, seconds=2.0, user="push_block", log=log)
    arrays = api.read_arrays(log)
    assert arrays.kind == "haptic"
    ticks = arrays.ticks
    assert len(ticks) == len(run.times_s) == 2000
    assert np.array_equal(ticks["t"], run.times_s)
    assert np.array_equal(ticks["device_pose"], run.device_pose)
    assert np.array_equal(ticks["vm_pose"], run.proxy_pose)
    assert np.array_equal(ticks["wrench_command"], run.wrench_command)
    assert np.array_equal(ticks["n_contacts"], run.n_contacts)
    assert np.array_equal(ticks["fault"], run.faults)
    assert run.n_contacts.max() > 0  # the wall was touched: the fields are not all zero
    assert ticks.units["wrench_command"] == "N, N·m" and ticks.units["t"] == "s"
    updates = arrays["updates"]
    assert len(updates) == run.updates and updates["installed"].all()
    assert np.array_equal(updates["seq"], np.arange(run.updates))
    dof = updates["dof"]
    assert (dof == 3).all()
    assert np.isfinite(updates["q"][:, :3]).all() and np.isnan(updates["q"][:, 3:]).all()
    assert np.all(np.diff(updates["tick"]) > 0)
    assert arrays.metadata["configs"]["scene"].startswith('name = "user_space"')
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(log.read_bytes()[: log.stat().st_size // 2])
    part = api.read_arrays(cut).ticks
    assert 0 < len(part) < len(ticks)
    assert part.rows.tobytes() == ticks.rows[: len(part)].tobytes()

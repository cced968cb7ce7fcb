"""Any log of the project as numpy structured arrays by field, with units, in one call.

`read_arrays(path)` reads a single-device run's log (`haptic-run`, the virtual clock, and the
library's offline runs, `haptic_local_model.api.run_offline`: `/haptic/tick`, `/haptic/update`,
`/haptic/event`), a port world's (`/ports/...`) or a station's (`/station/tick`), whole or
cut short, in one streaming pass. Each table is a numpy structured array, one row per
message, its fields the log's own (docs/log-format.md), with a unit per field; `frame()`
gives a pandas DataFrame when pandas is importable (it is not a dependency).

Units are the log's (all SI, docs/log-format.md): "m, rad" for a pose (x, y, theta), "N, N·m"
for a wrench; "" for a count, an index, a flag or a fraction. docs/log-format.md's tick
table is checked equal to TICK_UNITS (tests/test_log_arrays.py).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from mcap.records import Channel, Message, Metadata, Schema

from haptic_local_model.haptic_server.log import (
    EVENT_TOPIC,
    TICK_TOPIC,
    UPDATE_TOPIC,
    require_mcap,
    ros1msg_dtype,
    ros1msg_schema,
    stream_records,
    ticks_from_rows,
)
from haptic_local_model.haptic_server.model import MAX_DOF
from haptic_local_model.haptic_server.stages.station import STATION_ROW_DTYPE
from haptic_local_model.haptic_server.station_records import STATION_TOPIC
from haptic_local_model.haptic_server.world_runs import WORLD_KINDS
from haptic_local_model.shared.config import ConfigError

POSE, TWIST, WRENCH = "m, rad", "m/s, rad/s", "N, N·m"
_FORCES = ("f_user", "f_contact", "f_impulse", "f_bias", "f_penalty", "f_coordination")
#: the unit of each field of a `/haptic/tick` row ("" none), as docs/log-format.md's table
TICK_UNITS: dict[str, str] = {
    "tick": "", "t": "s", "dt": "s", "lateness_us": "µs", "work_us": "µs",
    "update_epoch": "", "update_seq": "", "dof": "", "update_age_ms": "ms",
    "device_pose": POSE, "device_twist": TWIST, "vm_pose": POSE, "vm_twist": TWIST,
    "proxy_q": "m or rad", "proxy_qd": "m/s or rad/s",
    "hand_wrench": WRENCH, "hand_wrench_measured": WRENCH,
    **dict.fromkeys(_FORCES, WRENCH),
    "f_damping": WRENCH, "wrench_command": WRENCH, "wrench_applied": WRENCH,
    "contact_force_world": "N", "n_contacts": "", "n_active": "", "penetration": "m",
    "n_colliding": "", "n_resisted": "", "contact_stage": "", "safe": "", "fault": "",
    "device_fault": "", "device_aux": "device's", "world_offset": POSE, "port_energy": "J",
    "god_proxy": "m", "god_contact": "", "god_active": "", "god_pop": "", "god_pops": "",
    "god_substeps": "", "god_capped": "", "n_shapes": "", "god_env_key": "",
    "god_env_point": "m", "god_env_arm": "m", "god_env_force": "N", "god_blend": "",
    "avar_cars": "", "avar_static_id": "", "avar_s": "m", "avar_sd": "m/s", "avar_force": "N",
    "avar_energy": "J", "avar_work": "J", "avar_events": "", "avar_singular": "",
}  # fmt: skip
#: `/haptic/update`'s fields as a table: an update the loop could not decode has -1 in its
#: integers and NaN in its floats; `q` holds the update's `dof` entries then NaN
UPDATE_FIELDS: tuple[tuple[str, Any, str], ...] = (
    ("tick", np.int64, ""), ("installed", np.bool_, ""), ("reason", str, ""),
    ("epoch", np.int64, ""), ("seq", np.int64, ""), ("sim_time", np.float64, "s"),
    ("age_ms", np.float64, "ms"), ("latency_s", np.float64, "s"), ("dof", np.int64, ""),
    ("q", (np.float64, MAX_DOF), "m or rad"), ("n_contacts", np.int64, ""),
    ("n_resisted", np.int64, ""), ("has_gravity", np.bool_, ""),
    ("tool_touching", np.bool_, ""), ("size_bytes", np.int64, "bytes"),
)  # fmt: skip
EVENT_FIELDS: tuple[tuple[str, Any, str], ...] = (
    ("tick", np.int64, ""),
    ("kind", str, ""),
    ("detail", str, ""),
)
#: a station's rows (docs/log-format.md, "Station logs")
STATION_UNITS: dict[str, str] = {
    "t": "s", "wall_ns": "ns", "late_us": "µs", "work_us": "µs", "pose": POSE,
    "twist": TWIST, "hand": WRENCH, "coupling": WRENCH, "spring": WRENCH, "out": WRENCH,
    "tool_pose": POSE, "tool_twist": TWIST, "stiffness": "N/m, N·m/rad",
    "damping": "N·s/m, N·m·s/rad", "tool_age": "s", "have_tool": "", "held": "", "gain": "",
    "fresh": "", "cut": "", "invalid": "", "received": "", "rejected": "", "fault": "",
    "budget": "J", "energy": "J", "pc_damping": "N·s/m, N·m·s/rad", "object_pose": POSE,
    "object_twist": TWIST, "contact_w": "", "depth": "m", "local_force": WRENCH,
    "indexed": "", "device_echo": POSE, "hold_force": WRENCH,
}  # fmt: skip
#: a port world's rows (docs/log-format.md, "Port logs"); `sim_bodies` is pose then twist
PORT_UNITS: dict[str, str] = {
    "t": "s", "q": "m or rad", "qd": "m/s or rad/s", "device_pose": POSE,
    "device_twist": TWIST, "hand_wrench": WRENCH, "command": WRENCH, "body_force": WRENCH,
    "n_contacts": "", "penetration": "m", "invalid": "", "singular": "", "device_fault": "",
    "collisions": "", "sim_bodies": "m, rad, m/s, rad/s", "sim_wrench": WRENCH,
}  # fmt: skip


@dataclass(frozen=True)
class Table:
    """One topic of a log: `rows`, a numpy structured array (one row a message, a field per
    quantity, fixed-size arrays as sub-arrays), and `units`, each field's ("" none; None for
    a field whose unit this release does not document)."""

    topic: str
    rows: np.ndarray
    units: dict[str, str | None]

    def __getitem__(self, name: str) -> np.ndarray:
        return self.rows[name]

    def __len__(self) -> int:
        return len(self.rows)

    def columns(self) -> dict[str, np.ndarray]:
        """Every field as 1-D columns: a sub-array field `f` of shape (3,) as `f[0]` … `f[2]`,
        of shape (2, 2) as `f[0,0]` …"""
        out: dict[str, np.ndarray] = {}
        for name in self.rows.dtype.names or ():
            values = self.rows[name]
            if values.ndim == 1:
                out[name] = values
                continue
            for index in np.ndindex(values.shape[1:]):
                label = ",".join(str(i) for i in index)
                out[f"{name}[{label}]"] = values[(slice(None), *index)]
        return out

    def frame(self) -> Any:
        """The table as a pandas DataFrame of `columns()` (its `attrs["units"]` by column).
        pandas is not a dependency: ImportError if it is not installed."""
        try:
            import pandas
        except ImportError as e:
            raise ImportError(
                "Table.frame needs pandas (pip install pandas); the numpy rows are "
                "Table.rows, the columns Table.columns()"
            ) from e
        columns = self.columns()
        frame = pandas.DataFrame(columns)
        frame.attrs["units"] = {c: self.units.get(c.split("[")[0]) for c in columns}
        return frame


@dataclass(frozen=True)
class LogArrays:
    """A log's tables by name: `ticks` (the rows of every tick: the haptic loop's, a port
    world's or a station's), and for a single-device run `updates` and `events`; any other
    ros1msg topic by its topic. `metadata`: the run's records (configs, version)."""

    path: Path
    kind: str  # "haptic", a port world's kind ("ports", "hand", "hand_grasp") or "station"
    tables: dict[str, Table]
    metadata: dict[str, dict[str, str]]

    def __getitem__(self, name: str) -> Table:
        if name not in self.tables:
            raise KeyError(f"{self.path}: no table {name!r} (it has {sorted(self.tables)})")
        return self.tables[name]

    @property
    def ticks(self) -> Table:
        return self["ticks"]


def _json_table(
    topic: str, records: list[dict[str, Any]], fields: tuple[tuple[str, Any, str], ...]
) -> Table:
    """JSON records as a structured array: strings as wide as the longest; a value a record
    lacks is -1 (integers), NaN (floats) or False (flags)."""
    layout: list[tuple[Any, ...]] = []
    for name, kind, _unit in fields:
        if kind is str:
            width = max((len(str(r.get(name, ""))) for r in records), default=1)
            layout.append((name, f"U{max(width, 1)}"))
        elif isinstance(kind, tuple):
            layout.append((name, kind[0], (kind[1],)))
        else:
            layout.append((name, kind))
    rows = np.zeros(len(records), np.dtype(layout))
    for name, _kind, _unit in fields:
        column = rows[name]
        if np.issubdtype(column.dtype, np.floating):
            column[...] = np.nan
        elif np.issubdtype(column.dtype, np.signedinteger):
            column[...] = -1
    for k, record in enumerate(records):
        for name, kind, _unit in fields:
            value = record.get(name)
            if value is None:
                continue
            if isinstance(kind, tuple):
                q = np.asarray(value, np.float64)[: kind[1]]
                rows[name][k, : len(q)] = q
            else:
                rows[name][k] = value
    return Table(topic, rows, {name: unit for name, _kind, unit in fields})


def _rows_table(topic: str, data: bytes, schema: str | None) -> tuple[str, Table]:
    """A ros1msg topic's rows as its kind's table: its dtype (sub-array shapes kept) when the
    log's schema is the release's, else the flat layout the schema spells."""
    if topic == TICK_TOPIC:
        return "haptic", Table(topic, ticks_from_rows(data, schema)[0], dict(TICK_UNITS))
    kinds: dict[str, tuple[str, np.dtype, dict[str, str]]] = {
        t: (k.name, k.rows, PORT_UNITS if k.name == "ports" else {}) for t, k in WORLD_KINDS.items()
    }
    kinds[STATION_TOPIC] = ("station", STATION_ROW_DTYPE, STATION_UNITS)
    name, dtype, units = kinds.get(topic, ("", None, {}))
    if dtype is None or schema != ros1msg_schema(dtype):
        if schema is None:
            raise ConfigError(topic, "schema", "rows without a schema cannot be read by field")
        dtype = ros1msg_dtype(schema)
    if len(data) % dtype.itemsize:
        raise ConfigError(topic, "rows", f"{len(data)} bytes: not whole rows of {dtype.itemsize}")
    rows = np.frombuffer(data, dtype).copy()
    return name, Table(topic, rows, {f: units.get(f) for f in dtype.names or ()})


def read_arrays(path: Path | str) -> LogArrays:
    """Every table of the log at `path` (whole or cut short: every complete record), by
    field with units. A file that is not an MCAP log is refused naming it."""
    path = Path(path)
    require_mcap(path, "")
    channels: dict[int, Channel] = {}
    schemas: dict[int, Schema] = {}
    rows: dict[str, list[bytes]] = {}
    records: dict[str, list[dict[str, Any]]] = {UPDATE_TOPIC: [], EVENT_TOPIC: []}
    metadata: dict[str, dict[str, str]] = {}
    for rec in stream_records(path):
        if isinstance(rec, Message) and rec.channel_id in channels:
            channel = channels[rec.channel_id]
            if channel.topic in records:
                records[channel.topic].append(json.loads(rec.data))
            elif channel.message_encoding == "ros1":
                rows.setdefault(channel.topic, []).append(rec.data)
        elif isinstance(rec, Channel):
            channels[rec.id] = rec
        elif isinstance(rec, Schema):
            schemas[rec.id] = rec
        elif isinstance(rec, Metadata):
            metadata[rec.name] = dict(rec.metadata)
    tables: dict[str, Table] = {}
    kind = ""
    for channel in channels.values():
        if channel.message_encoding != "ros1" or channel.topic in tables:
            continue
        schema = schemas.get(channel.schema_id)
        text = schema.data.decode() if schema is not None else None
        try:
            name, table = _rows_table(channel.topic, b"".join(rows.get(channel.topic, [])), text)
        except ConfigError as e:
            raise ConfigError(str(path), e.key, e.problem) from None
        tables["ticks" if name else channel.topic] = table
        kind = kind or name
    if kind == "haptic":
        tables["updates"] = _json_table(UPDATE_TOPIC, records[UPDATE_TOPIC], UPDATE_FIELDS)
        tables["events"] = _json_table(EVENT_TOPIC, records[EVENT_TOPIC], EVENT_FIELDS)
    if not tables:
        raise ConfigError(str(path), "", "no rows of ticks: not a log of this project")
    return LogArrays(path, kind, tables, metadata)


__all__ = ["LogArrays", "Table", "read_arrays"]

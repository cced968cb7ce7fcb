"""The MCAP log of a haptic run (docs/log-format.md is the reference).

Topics:
- `/haptic/tick`: every tick, `ros1` encoding with a `ros1msg` schema generated from
  TICK_DTYPE (a packed little-endian record: Foxglove and the mcap tools read it, and numpy
  decodes it with one `frombuffer`).
- `/haptic/update`: every local-model update as received, JSON with a jsonschema schema.
- `/haptic/event`: watchdog, re-initialisations, stop, JSON (rejections are update records).
Run metadata (configs, version, host, start time) is written as MCAP metadata records.

Chunks are small and flushed often so a log cut by SIGKILL is recoverable record by record
(`recover`), and the real-time server writes through a separate process (`log_process`).
"""

from __future__ import annotations

import base64
import itertools
import json
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Channel, McapRecord, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer  # recover_log's

from haptic_local_model.haptic_server.model import TICK_DTYPE
from haptic_local_model.shared.config import ConfigError
from haptic_local_model.shared.protocol.update import UpdateParser

TICK_TOPIC = "/haptic/tick"
UPDATE_TOPIC = "/haptic/update"
EVENT_TOPIC = "/haptic/event"
# the sim's world for the live view as it arrived (shared/protocol/world_view.py), after an
# 8-byte little-endian count: the ticks the loop had run when it arrived (logged with --view)
WORLD_TOPIC = "/sim/world"
WORLD_ENCODING = "haptic-world-view"
TICK_SCHEMA_NAME = "haptic_server/Tick"
CHUNK_SIZE = 256 * 1024  # bytes: about 0.5 s of ticks, so a crash loses at most that
RECORD_SIZE_LIMIT = 64 * 2**20  # no record of ours is this big: a larger length is garbage

_ROS1_TYPES = {
    np.dtype(np.float64): "float64",
    np.dtype(np.int64): "int64",
    np.dtype(np.uint64): "uint64",
    np.dtype(np.int32): "int32",
    np.dtype(np.uint8): "uint8",
}


def ros1msg_schema(dtype: np.dtype) -> str:
    """The ros1msg definition whose serialization is exactly a packed record of `dtype`."""
    lines = []
    for name in dtype.names or ():
        sub = dtype.fields[name][0]  # type: ignore[index]
        if sub.subdtype is not None:
            base, shape = sub.subdtype
            lines.append(f"{_ROS1_TYPES[base]}[{int(np.prod(shape))}] {name}")
        else:
            lines.append(f"{_ROS1_TYPES[sub]} {name}")
    return "\n".join(lines) + "\n"


def ros1msg_dtype(schema: str) -> np.dtype:
    """The packed record a ros1msg definition of `ros1msg_schema`'s form describes (arrays
    flat: the text does not keep their shape)."""
    types = {v: k for k, v in _ROS1_TYPES.items()}
    fields: list[tuple[Any, ...]] = []
    for line in schema.splitlines():
        if not line.strip():
            continue
        kind, name = line.split()
        if "[" in kind:
            base, count = kind[:-1].split("[")
            fields.append((name, types[base], (int(count),)))
        else:
            fields.append((name, types[kind]))
    return np.dtype(fields)


def ticks_from_rows(data: bytes, schema: str | None) -> tuple[np.ndarray, tuple[str, ...]]:
    """Tick rows written under `schema` (the log's own) as TICK_DTYPE rows, and the fields
    TICK_DTYPE has that the log's rows lack (zero in the result): a log of an earlier
    release reads with today's code."""
    if schema is None or schema == ros1msg_schema(TICK_DTYPE):
        return np.frombuffer(data, TICK_DTYPE), ()
    logged = np.frombuffer(data, ros1msg_dtype(schema))
    out = np.zeros(len(logged), TICK_DTYPE)
    absent = []
    for name in TICK_DTYPE.names or ():
        if name in (logged.dtype.names or ()):
            out[name] = logged[name].reshape(out[name].shape)
        else:
            absent.append(name)
    return out, tuple(absent)


UPDATE_JSON_SCHEMA = {
    "type": "object",
    "title": "haptic_server/LocalModelUpdate",
    "properties": {
        "tick": {"type": "integer", "description": "haptic tick at which it was received"},
        "installed": {"type": "boolean"},
        "reason": {"type": "string", "description": "rejection reason, empty if installed"},
        "epoch": {"type": "integer"},
        "seq": {"type": "integer"},
        "sim_time": {"type": "number"},
        "age_ms": {
            "type": "number",
            "description": "transit: publish -> received by the haptic server (ms)",
        },
        "latency_s": {
            "type": "number",
            "description": "latency added to the contacts' extrapolation age at install (s)",
        },
        "dof": {"type": "integer"},
        "q": {"type": "array", "items": {"type": "number"}},
        "n_contacts": {"type": "integer"},
        "n_resisted": {"type": "integer"},
        "has_gravity": {"type": "boolean"},
        "tool_touching": {"type": "boolean"},
        "size_bytes": {"type": "integer", "description": "size received (raw is cut to fit)"},
        "raw_b64": {"type": "string", "description": "the message bytes as received"},
    },
}
EVENT_JSON_SCHEMA = {
    "type": "object",
    "title": "haptic_server/Event",
    "properties": {
        "tick": {"type": "integer"},
        "kind": {"type": "string"},
        "detail": {"type": "string"},
    },
}


class LogWriter:
    """Writes ticks, updates and events to an MCAP file (synchronously), through the Foxglove
    SDK's compiled MCAP writer: 1.7 us a tick row where the pure-Python `mcap` writer takes
    5.5 (`python -m haptic_local_model.benchmarks.log_writers`). Each writer has its own SDK
    context, so its channels reach this file only."""

    def __init__(self, path: Path | str, metadata: dict[str, dict[str, str]] | None = None) -> None:
        import foxglove
        from foxglove.mcap import MCAPCompression, MCAPWriteOptions

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._context = foxglove.Context()
        # lz4: 2.1 us and 339 bytes a tick row, against zstd's 2.8-3.8 us and 292 bytes
        options = MCAPWriteOptions(chunk_size=CHUNK_SIZE, compression=MCAPCompression.Lz4)
        self._writer = foxglove.open_mcap(
            self.path, allow_overwrite=True, context=self._context, writer_options=options
        )
        self._tick_ch = self._channel(
            TICK_TOPIC, "ros1", TICK_SCHEMA_NAME, "ros1msg", ros1msg_schema(TICK_DTYPE)
        )
        self._update_ch = self._channel(
            UPDATE_TOPIC, "json", "haptic_server/LocalModelUpdate", "jsonschema",
            json.dumps(UPDATE_JSON_SCHEMA),
        )  # fmt: skip
        self._event_ch = self._channel(
            EVENT_TOPIC, "json", "haptic_server/Event", "jsonschema", json.dumps(EVENT_JSON_SCHEMA)
        )
        self._world_ch: Any = None  # opened with the first world message
        for name, data in (metadata or {}).items():
            self._writer.write_metadata(name, data)
        # Foxglove's well-known channels, for its 3D and Log panels (haptic_server.foxglove_view)
        from foxglove.channels import FrameTransformsChannel, LogChannel, SceneUpdateChannel

        from haptic_local_model.haptic_server.foxglove_view import (
            LOG_TOPIC,
            SCENE_TOPIC,
            TRANSFORMS_TOPIC,
        )

        self._scene_ch = SceneUpdateChannel(SCENE_TOPIC, context=self._context)
        self._transforms_ch = FrameTransformsChannel(TRANSFORMS_TOPIC, context=self._context)
        self._log_ch = LogChannel(LOG_TOPIC, context=self._context)
        self.scene_text = (metadata or {}).get("configs", {}).get("scene")
        self.closed = False

    def _channel(
        self, topic: str, encoding: str, schema_name: str, schema_encoding: str, schema: str
    ) -> Any:
        import foxglove

        return foxglove.Channel(
            topic,
            message_encoding=encoding,
            schema=foxglove.Schema(
                name=schema_name, encoding=schema_encoding, data=schema.encode()
            ),
            context=self._context,
        )

    def tick(self, row_bytes: bytes, log_time_ns: int) -> None:
        self._tick_ch.log(row_bytes, log_time=log_time_ns)

    def update(self, record: dict[str, Any], log_time_ns: int) -> None:
        """Log a received update given as update_record(...) (decoded here, off the loop)."""
        self._update_ch.log(json.dumps(update_json(record)).encode(), log_time=log_time_ns)

    def event(self, tick: int, kind: str, detail: str, log_time_ns: int) -> None:
        msg = json.dumps({"tick": tick, "kind": kind, "detail": detail}).encode()
        self._event_ch.log(msg, log_time=log_time_ns)

    def world(self, tick: int, raw: bytes, log_time_ns: int) -> None:
        """A world message of the sim (its bodies or their poses), filed under `tick`."""
        if self._world_ch is None:
            self._world_ch = self._channel(
                WORLD_TOPIC, WORLD_ENCODING, "haptic/WorldView", WORLD_ENCODING,
                "shared/protocol/world_view.py, after an 8-byte little-endian tick",
            )  # fmt: skip
        self._world_ch.log(tick.to_bytes(8, "little") + raw, log_time=log_time_ns)

    def view_scene(self, scene: Any, log_time_ns: int) -> None:
        """A foxglove.SceneUpdate (haptic_server.foxglove_view)."""
        self._scene_ch.log(scene, log_time=log_time_ns)

    def view_transforms(self, transforms: Any, log_time_ns: int) -> None:
        self._transforms_ch.log(transforms, log_time=log_time_ns)

    def view_log(self, message: Any, log_time_ns: int) -> None:
        self._log_ch.log(message, log_time=log_time_ns)

    def flush(self) -> None:
        self._writer.flush()

    def close(self) -> None:
        if not self.closed:
            self._writer.close()
            self.closed = True


def update_record(
    tick: int,
    raw: bytes,
    reason: str,
    age_ms: float,
    latency_s: float = 0.0,
    size_bytes: int | None = None,
) -> dict[str, Any]:
    """What the loop logs of a received update: the bytes, the verdict and the latency it was
    installed with (cheap). `size_bytes` is the size received if `raw` was cut to fit."""
    size = len(raw) if size_bytes is None else size_bytes
    return {
        "tick": tick, "reason": reason, "age_ms": age_ms, "raw": raw, "latency_s": latency_s,
        "size_bytes": size,
    }  # fmt: skip


def update_json(record: dict[str, Any]) -> dict[str, Any]:
    """The JSON form of a received update (installed or rejected), decoded for the log."""
    global _PARSER
    raw = record["raw"]
    reason = record["reason"]
    if _PARSER is None:
        _PARSER = UpdateParser()
    valid = _PARSER.parse(raw) == 0  # the loop's own checks, read off the parsed record
    rec: dict[str, Any] = {
        "tick": record["tick"],
        "installed": valid and not reason,
        "reason": reason,
        "size_bytes": record["size_bytes"],
        "age_ms": record["age_ms"],
        "latency_s": record["latency_s"],
        "raw_b64": base64.b64encode(raw).decode(),
    }
    if valid:
        m = _PARSER.out[0]
        rec.update(
            epoch=int(m["epoch"]), seq=int(m["seq"]), sim_time=float(m["sim_time"]),
            dof=int(m["dof"]), q=m["q"][: int(m["dof"])].tolist(),
            n_contacts=int(m["n_contacts"]), n_resisted=int(m["n_resisted"]),
            has_gravity=bool(m["has_gravity"]), tool_touching=bool(m["tool_touching"]),
        )  # fmt: skip
    return rec


_PARSER: UpdateParser | None = None  # update_json's (one per process)


def run_metadata(
    configs: dict[str, str], extra: dict[str, str] | None = None
) -> dict[str, dict[str, str]]:
    """Metadata records: the config files' text, version, host and start time."""
    import platform

    from haptic_local_model.shared import __version__, source_hash

    meta = {
        "run": {
            "version": __version__,
            "source_hash": source_hash(),
            "host": platform.node(),
            "start_time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            **(extra or {}),
        }
    }
    meta["configs"] = configs
    return meta


# --- reading ------------------------------------------------------------------------------


def read_ticks(path: Path | str) -> np.ndarray:
    """All tick records of a log as a TICK_DTYPE array (indexed reader, else streaming)."""
    rows: list[bytes] = []
    schema: Schema | None = None
    for topic, data, message_schema in _iter_messages(path):
        if topic == TICK_TOPIC:
            rows.append(data)
            schema = message_schema
    if not rows:
        return np.zeros(0, TICK_DTYPE)
    return ticks_from_rows(b"".join(rows), schema.data.decode() if schema else None)[0]


def iter_messages(path: Path | str) -> Iterator[tuple[str, bytes]]:
    """(topic, payload) of every message in file order; tolerates a missing footer."""
    for topic, data, _schema in _iter_messages(path):
        yield topic, data


def _iter_messages(path: Path | str) -> Iterator[tuple[str, bytes, Schema | None]]:
    """(topic, payload, its schema) of every message in file order."""
    if is_indexed(path):
        with Path(path).open("rb") as fh:
            for schema, channel, message in make_reader(fh).iter_messages(log_time_order=False):
                yield channel.topic, message.data, schema
            return
    with Path(path).open("rb") as fh:
        stream = NonSeekingReader(fh)
        try:
            for schema, channel, message in stream.iter_messages(log_time_order=False):
                yield channel.topic, message.data, schema
        except Exception:
            return


def is_indexed(path: Path | str) -> bool:
    """True if the file has a readable summary (it was closed properly)."""
    with Path(path).open("rb") as fh:
        try:
            return make_reader(fh).get_summary() is not None
        except Exception:
            return False


#: the first bytes of every MCAP file
MCAP_MAGIC = b"\x89MCAP0\r\n"


def require_mcap(path: Path, key: str = "log", why: str = "") -> None:
    """Refuse by name (a ConfigError naming the file and `key`) a missing file or one that
    is not MCAP; `why` is added to the latter's problem."""
    if not path.is_file():
        raise ConfigError(str(path), key, "no such file")
    with path.open("rb") as fh:
        if fh.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise ConfigError(str(path), key, f"not an MCAP file{why}")


def whole_log_metadata(
    path: Path, why: str = "", unfinished: str = "the run did not finish it"
) -> dict[str, dict[str, str]]:
    """The metadata of a whole log (require_mcap's checks, `why` added to the MCAP one);
    a log cut short (no summary) is refused by name, `unfinished` saying why it should not be."""
    require_mcap(path, why=why)
    if not is_indexed(path):
        raise ConfigError(str(path), "log", f"cut short (no summary): {unfinished}")
    return read_metadata(path)


def read_topic_rows(path: Path, topic: str, dtype: np.dtype, noun: str = "row") -> np.ndarray:
    """Every message on `topic` of a log as one array of `dtype` records (none: empty);
    records of another layout (their schema) or size are refused by name."""
    chunks, schema_text = [], None
    for name, data, schema in _iter_messages(path):
        if name == topic:
            chunks.append(data)
            schema_text = schema.data.decode() if schema else None
    if chunks and schema_text != ros1msg_schema(dtype):
        raise ConfigError(str(path), topic, f"{noun}s of another layout (another release)")
    if any(len(c) != dtype.itemsize for c in chunks):
        raise ConfigError(str(path), topic, f"a {noun} of the wrong size")
    return np.frombuffer(b"".join(chunks), dtype)


def read_json_topic(path: Path | str, topic: str) -> list[dict[str, Any]]:
    return [json.loads(data) for t, data in iter_messages(path) if t == topic]


def read_metadata(path: Path | str) -> dict[str, dict[str, str]]:
    """The metadata records by name (also from a file without a footer)."""
    return {
        rec.name: dict(rec.metadata) for rec in stream_records(path) if isinstance(rec, Metadata)
    }


def stream_records(path: Path | str) -> Iterator[McapRecord]:
    """Every complete record in file order, chunks opened; stops quietly where the file was
    cut (a writer killed mid-chunk): read record by record."""
    with Path(path).open("rb") as fh:
        reader = StreamReader(fh, record_size_limit=RECORD_SIZE_LIMIT)
        try:
            yield from reader.records
        except Exception:  # a cut record: short read, short zstd frame, bad length
            return


#: records read from a log's start to tell what it holds (its metadata and channels lead)
HEAD_RECORDS = 1000


def head_records(path: Path) -> Iterator[McapRecord]:
    """The first HEAD_RECORDS complete records of a log (none where there is no such file)."""
    if path.is_file():
        yield from itertools.islice(stream_records(path), HEAD_RECORDS)


@dataclass
class LogContents:
    """Everything a haptic log holds, read in one pass."""

    ticks: np.ndarray  # TICK_DTYPE rows in file order
    updates: list[dict[str, Any]]
    events: list[dict[str, Any]]
    metadata: dict[str, dict[str, str]]
    indexed: bool  # closed properly (footer and summary readable by make_reader)
    absent_tick_fields: tuple[str, ...] = ()  # today's tick fields the log's rows lack
    world: list[tuple[int, bytes]] = field(default_factory=list)  # (tick, message), WORLD_TOPIC


def read_log(path: Path | str) -> LogContents:
    """Read a log, complete or cut short (streaming: every complete record)."""
    topics: dict[int, str] = {}
    rows: list[bytes] = []
    updates: list[dict[str, Any]] = []
    events: list[dict[str, Any]] = []
    world: list[tuple[int, bytes]] = []
    metadata: dict[str, dict[str, str]] = {}
    schemas: dict[int, bytes] = {}
    tick_schema: str | None = None
    for rec in stream_records(path):
        if isinstance(rec, Message):
            topic = topics.get(rec.channel_id)
            if topic == TICK_TOPIC:
                rows.append(rec.data)
            elif topic == UPDATE_TOPIC:
                updates.append(json.loads(rec.data))
            elif topic == EVENT_TOPIC:
                events.append(json.loads(rec.data))
            elif topic == WORLD_TOPIC and len(rec.data) >= 8:
                world.append((int.from_bytes(rec.data[:8], "little"), bytes(rec.data[8:])))
        elif isinstance(rec, Channel):
            topics[rec.id] = rec.topic
            if rec.topic == TICK_TOPIC:
                tick_schema = schemas.get(rec.schema_id, b"").decode() or None
        elif isinstance(rec, Schema):
            schemas[rec.id] = rec.data  # text for ours, protobuf for Foxglove's
        elif isinstance(rec, Metadata):
            metadata[rec.name] = dict(rec.metadata)
    ticks, absent = ticks_from_rows(b"".join(rows), tick_schema)
    return LogContents(ticks, updates, events, metadata, is_indexed(path), absent, world)


def recover_log(src: Path | str, dst: Path | str) -> dict[str, int]:
    """Rewrite every complete record of `src` (e.g. a log whose writer was killed, without
    footer or index) into a valid, indexed MCAP file `dst`; returns counts of what was kept."""
    schema_ids: dict[int, int] = {}
    channel_ids: dict[int, int] = {}
    counts = {"messages": 0, "ticks": 0, "metadata": 0}
    tick_channels: set[int] = set()
    dst_path = Path(dst)
    dst_path.parent.mkdir(parents=True, exist_ok=True)
    with dst_path.open("wb") as out:
        writer = Writer(out, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
        writer.start(profile="", library="haptic-local-model (recovered)")
        for rec in stream_records(src):
            if isinstance(rec, Schema) and rec.id not in schema_ids:
                schema_ids[rec.id] = writer.register_schema(rec.name, rec.encoding, rec.data)
            elif isinstance(rec, Channel) and rec.id not in channel_ids:
                channel_ids[rec.id] = writer.register_channel(
                    rec.topic, rec.message_encoding, schema_ids.get(rec.schema_id, 0),
                    dict(rec.metadata),
                )  # fmt: skip
                if rec.topic == TICK_TOPIC:
                    tick_channels.add(rec.id)
            elif isinstance(rec, Message) and rec.channel_id in channel_ids:
                writer.add_message(
                    channel_ids[rec.channel_id], rec.log_time, rec.data, rec.publish_time,
                    rec.sequence,
                )  # fmt: skip
                counts["messages"] += 1
                counts["ticks"] += rec.channel_id in tick_channels
            elif isinstance(rec, Metadata):
                writer.add_metadata(rec.name, dict(rec.metadata))
                counts["metadata"] += 1
        writer.finish()
    return counts


def write_rows_log(
    path: Path, rows: np.ndarray, topic: str, schema_name: str, metadata: dict[str, dict[str, str]]
) -> None:
    """Rows of a record dtype (one message each on `topic`, a ros1msg schema from the dtype)
    and the metadata, into a temporary file renamed to `path` when whole (removed if the
    writing fails)."""
    from haptic_local_model.shared import __version__

    path.parent.mkdir(parents=True, exist_ok=True)
    part = path.with_name(path.name + ".part")
    try:
        with part.open("wb") as fh:
            writer = Writer(fh)
            writer.start(profile="", library=f"haptic-local-model {__version__}")
            schema = writer.register_schema(
                name=schema_name, encoding="ros1msg", data=ros1msg_schema(rows.dtype).encode()
            )
            channel = writer.register_channel(topic, message_encoding="ros1", schema_id=schema)
            for name, data in metadata.items():
                writer.add_metadata(name, data)
            for k, row in enumerate(rows):
                t_ns = round(float(row["t"]) * 1e9)
                writer.add_message(channel, log_time=t_ns, data=row.tobytes(),
                                   publish_time=t_ns, sequence=k)  # fmt: skip
            writer.finish()
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(part, path)
    except BaseException:
        part.unlink(missing_ok=True)
        raise


def rows_in_order(rows: np.ndarray, written: int) -> np.ndarray:
    """A ring of rows, `written` of them written in turn: those kept, oldest first (the
    last len(rows) if more were written). The station's and the shared world's logs."""
    cap = len(rows)
    if written <= cap:
        return rows[:written].copy()
    k = written % cap
    return np.concatenate([rows[k:], rows[:k]])

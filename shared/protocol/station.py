"""The two messages between a shared world and its haptic stations (docs/stations.md).

- DeviceState `HSDV` v3, station -> world, every station tick on `<ns>/port/<name>/device`:
  the station's device pose and twist in its world frame (after its device-to-world map),
  whether it is SAFE (not rendering the world's coupling: its watchdog fired or the world
  holds it, and its command ramps to, or is at, the safe state), whether its reading
  was not finite, and, at a hand's station (GLOVE), its glove's joint angles and rates.
- ToolState `HSTL` v3, world -> station, every world tick on `<ns>/port/<name>/tool`: the
  port's tool pose and twist in the station's frame (the world re-indexes a station that
  joins, so its device meets its tool where the tool is), the coupling's stiffness and
  damping, the co-simulated object's pose and twist in the station's frame (the station's
  local model renders its pad's contact with it), the device's pose it last took, whether the
  world holds the port (its station was lost) and whether it re-indexes it (INDEXED).
- BodiesState, between the world and the sim that mirrors it (`sim-server --mirror`):
  `HSWB` world -> sim on `<ns>/world/bodies`, the co-simulated bodies (q's order), every few
  world ticks; `HSSB` sim -> world on `<ns>/sim/bodies`, the sim's bodies (the scene's
  `sim_bodies`), every sim step. Each body's pose and twist, world frame, and the sender's
  step; a SimBodies also says which world its mirror follows and carries the running
  impulse the sim's bodies have put on each mirrored body (q's order), for the world to
  apply (`sim_contact = "wrench"`).

Both are fixed-size little-endian records. A decode checks the magic, version, size, port
and that every number is finite and in range, and raises MessageError naming the field:
a malformed message is rejected and counted, never used.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from numba import njit

from haptic_local_model.shared.protocol.update import MessageError

DEVICE_MAGIC = b"HSDV"
TOOL_MAGIC = b"HSTL"
# 2: DeviceState carries the glove; 3: both carry the passivity observer's energy; 4: the
# ToolState carries the object's twist, its pose in the station's frame (the local model)
STATION_VERSION = 4
MAX_GLOVE_JOINTS = 8  # a hand's at most 4 fingers of two phalanges
GLOVE_ANGLE_LIMIT = 2.0 * math.pi  # rad
#: poses beyond this many metres, rates beyond this many m/s or rad/s: not a device's
POSE_LIMIT_M = 100.0
TWIST_LIMIT = 1000.0
GAIN_LIMIT = 1.0e7  # N/m, N s/m
#: a port's running energy beyond this many joules is not a device's (a week at 1 kW)
ENERGY_LIMIT = 1.0e9

_HEAD = struct.Struct("<4sHHQQq")  # magic, version, port, epoch, seq, publish time (ns)
HEAD_FIELDS = [("magic", "S4"), ("version", "<u2"), ("port", "<u2"), ("epoch", "<u8"),
               ("seq", "<u8"), ("publish_time_ns", "<i8")]  # fmt: skip
WORLD_BODIES_MAGIC = b"HSWB"
SIM_BODIES_MAGIC = b"HSSB"
MAX_MESSAGE_BODIES = 8  # a BodiesState's slots (a port scene's co-simulated or sim bodies)
IMPULSE_LIMIT = 1.0e9  # N s: a running impulse beyond it is not a sim's (a week at 1 kN)
# magic, version, count, epoch, seq, publish time (ns), follows, period; pose and twist a
# slot; an impulse a slot
_BODIES = struct.Struct(f"<4sHHQQqQd{9 * MAX_MESSAGE_BODIES}d")

SAFE = 1  # DeviceState flags: not rendering the world's coupling (ramping to the safe state)
CUT = 2  # its device's reading was not finite this tick
GLOVE = 4  # glove and glove_rate hold the station's glove (a hand's station)
HELD = 1  # ToolState flags: the world holds the port's anchor (its station is lost)
INDEXED = 2  # the world re-indexes the port this tick (its station says SAFE): the tool is
# where the device was (device_pose) plus the coupling's stretch at the anchor


@dataclass(frozen=True)
class DeviceState:
    port: int
    epoch: int  # the station's start (ns): a restarted station is a new one
    seq: int
    publish_time_ns: int
    pose: tuple[float, float, float]  # world frame: x, y (m), angle (rad)
    twist: tuple[float, float, float]
    flags: int = 0
    glove: tuple[float, ...] = (0.0,) * MAX_GLOVE_JOINTS  # rad, the hand's joints in order
    glove_rate: tuple[float, ...] = (0.0,) * MAX_GLOVE_JOINTS  # rad/s
    # the passivity observer's: the net work the station's device has done on the port's
    # link (its coupling) since the station started (J, per axis, signed: docs/stations.md)
    energy: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def safe(self) -> bool:
        return bool(self.flags & SAFE)

    @property
    def cut(self) -> bool:
        return bool(self.flags & CUT)

    @property
    def has_glove(self) -> bool:
        return bool(self.flags & GLOVE)


@dataclass(frozen=True)
class ToolState:
    port: int
    epoch: int  # the world's start (ns)
    seq: int
    publish_time_ns: int
    pose: tuple[float, float, float]  # the station's frame
    twist: tuple[float, float, float]
    stiffness: tuple[float, float, float]
    damping: tuple[float, float, float]
    object_pose: tuple[float, float, float]  # the co-simulated object, the station's frame
    flags: int = 0
    # the passivity observer's: the net work the port's tool has done on the link (its
    # coupling) while coupled, since the world started (J, per axis, signed: docs/stations.md)
    energy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    object_twist: tuple[float, float, float] = (0.0, 0.0, 0.0)  # the object's, world frame
    # the device's pose the world last took, as its station sent it (the station's frame):
    # while INDEXED the tool is there plus the coupling's stretch
    device_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def held(self) -> bool:
        return bool(self.flags & HELD)

    @property
    def indexed(self) -> bool:
        return bool(self.flags & INDEXED)


AXES = ("x", "y", "angle")


@dataclass(frozen=True)
class Numbers:
    """A run of a message's numbers (float64): their name, each one's label, the largest
    magnitude a sender may put there, and whether they must not be negative."""

    name: str
    labels: tuple[str, ...]
    limit: float
    nonneg: bool = False


def _axes(name: str, limit: float, nonneg: bool = False) -> Numbers:
    return Numbers(name, tuple(f"{name}.{a}" for a in AXES), limit, nonneg)


def _joints(name: str, limit: float) -> Numbers:
    return Numbers(name, tuple(f"{name}[{i}]" for i in range(MAX_GLOVE_JOINTS)), limit)


@dataclass(frozen=True)
class StationMessage:
    """A station message declared once (as shared/protocol/layout.py declares the update):
    the header (magic, version, port, epoch, seq, publish time), its numbers in order, its
    flags. From it: the record of exactly its bytes (`dtype`, which a loop fills in place
    and sends), the reference decoder and encoder below, and the compiled checks
    (shared/protocol/station_codec.py: `limits`, `nonneg`)."""

    name: str
    magic: bytes
    numbers: tuple[Numbers, ...]
    flags: int  # the flag bits a sender may set

    @cached_property
    def dtype(self) -> np.dtype:
        return np.dtype([*HEAD_FIELDS, *((n.name, "<f8", (len(n.labels),)) for n in self.numbers),
                         ("flags", "<u4")])  # fmt: skip

    @cached_property
    def labels(self) -> tuple[str, ...]:
        return tuple(label for n in self.numbers for label in n.labels)

    @cached_property
    def limits(self) -> np.ndarray:
        """Each number's largest magnitude, in the message's order."""
        return np.array([n.limit for n in self.numbers for _ in n.labels], np.float64)

    @cached_property
    def nonneg(self) -> np.ndarray:
        """Each number: 1 if it must not be negative."""
        return np.array([n.nonneg for n in self.numbers for _ in n.labels], np.int64)

    def record(self, port: int, epoch: int) -> np.ndarray:
        """A record[1] of the message for `port` from a sender of `epoch`, its header set."""
        rec = np.zeros(1, self.dtype)
        rec["magic"], rec["version"], rec["port"], rec["epoch"] = (
            self.magic, STATION_VERSION, port, epoch,
        )  # fmt: skip
        return rec

    def encode(self, m: Any) -> bytes:
        """The bytes of `m`, a dataclass with the message's fields (a run shorter than its
        slots, a glove of fewer joints, is padded with zeros)."""
        rec = self.record(m.port, m.epoch)
        rec["seq"], rec["publish_time_ns"], rec["flags"] = m.seq, m.publish_time_ns, m.flags
        for n in self.numbers:
            values = tuple(getattr(m, n.name))
            if len(values) > len(n.labels):
                raise ValueError(f"{self.name}.{n.name}: {len(values)} values, at most "
                                 f"{len(n.labels)}")  # fmt: skip
            rec[n.name][0, : len(values)] = values
        return rec.tobytes()

    def decode(self, raw: bytes, port: int) -> dict[str, Any]:
        """The fields of a message received on port `port`'s key, checked (module
        docstring): MessageError names the first field that is wrong."""
        _head(raw, self.magic, self.dtype.itemsize, self.name, port)
        rec = np.frombuffer(raw, self.dtype)[0]
        floats = np.frombuffer(raw, np.float64, len(self.labels), _HEAD.size)
        for label, v, limit, nonneg in zip(self.labels, floats.tolist(), self.limits,
                                           self.nonneg, strict=True):  # fmt: skip
            if not math.isfinite(v) or abs(v) > limit:
                raise MessageError("value", f"{self.name}.{label}: {v!r} is not finite or "
                                   f"beyond {limit:g}")  # fmt: skip
            if nonneg and v < 0.0:
                raise MessageError("value", f"{self.name}.{label}: {v!r} is negative")
        flags = int(rec["flags"])
        if flags & ~self.flags:
            raise MessageError("flags", f"{self.name}.flags: unknown bits {flags:#x}")
        head = {k: int(rec[k]) for k in ("port", "epoch", "seq", "publish_time_ns")}
        numbers = {n.name: tuple(rec[n.name].tolist()) for n in self.numbers}
        return {**head, **numbers, "flags": flags}


#: The two station messages (module docstring), each declared once.
DEVICE = StationMessage(
    "DeviceState", DEVICE_MAGIC,
    (_axes("pose", POSE_LIMIT_M), _axes("twist", TWIST_LIMIT),
     _joints("glove", GLOVE_ANGLE_LIMIT), _joints("glove_rate", TWIST_LIMIT),
     _axes("energy", ENERGY_LIMIT)),
    SAFE | CUT | GLOVE,
)  # fmt: skip
TOOL = StationMessage(
    "ToolState", TOOL_MAGIC,
    (_axes("pose", POSE_LIMIT_M), _axes("twist", TWIST_LIMIT),
     _axes("stiffness", GAIN_LIMIT, nonneg=True), _axes("damping", GAIN_LIMIT, nonneg=True),
     _axes("object_pose", POSE_LIMIT_M), _axes("object_twist", TWIST_LIMIT),
     _axes("device_pose", POSE_LIMIT_M), _axes("energy", ENERGY_LIMIT)),
    HELD | INDEXED,
)  # fmt: skip
#: Each as a numpy record of exactly the message's bytes: a loop that publishes one every
#: tick fills its fields in place and sends `.tobytes()` (about 1 us; the encoders below,
#: the reference, build a dataclass first: about 6 us).
DEVICE_RECORD = DEVICE.dtype
TOOL_RECORD = TOOL.dtype


def tool_record(port: int, epoch: int) -> np.ndarray:
    """A TOOL_RECORD[1] for `port` of the world's `epoch`, its header set."""
    return TOOL.record(port, epoch)


def device_record(port: int, epoch: int) -> np.ndarray:
    """A DEVICE_RECORD[1] for `port` from a station of `epoch`, its header set."""
    return DEVICE.record(port, epoch)


@dataclass(frozen=True)
class BodiesState:
    """Bodies' poses and twists, world frame: the world's co-simulated bodies (HSWB) or the
    sim's bodies (HSSB). A SimBodies also says which world its mirror follows (that world's
    epoch; 0: none yet) and carries, for each mirrored body, the impulse the sim's bodies
    have put on it since the sim started (N s, N s, N m s about its centre): a running sum,
    so a receiver takes the difference from the last it took, and a message lost or two
    taken in one tick neither lose nor double any of it."""

    magic: bytes
    epoch: int  # the sender's start (ns)
    seq: int
    publish_time_ns: int
    bodies: tuple[tuple[float, ...], ...]  # (x, y, angle, vx, vy, omega) a body
    period_s: float = 0.0  # the sender's step: the sim's period, the world's publishing one
    follows: int = 0  # SimBodies: the epoch of the world its mirror follows (0: none)
    impulse: tuple[tuple[float, float, float], ...] = ((0.0, 0.0, 0.0),) * MAX_MESSAGE_BODIES

    def array(self) -> np.ndarray:
        """The bodies as a count x 6 array."""
        return np.array(self.bodies, np.float64).reshape(-1, 6)


BODIES_RECORD = np.dtype(
    [("magic", "S4"), ("version", "<u2"), ("count", "<u2"), ("epoch", "<u8"), ("seq", "<u8"),
     ("publish_time_ns", "<i8"), ("follows", "<u8"), ("period_s", "<f8"),
     ("bodies", "<f8", (MAX_MESSAGE_BODIES, 6)), ("impulse", "<f8", (MAX_MESSAGE_BODIES, 3))]
)  # fmt: skip


def bodies_record(magic: bytes, count: int, epoch: int, period_s: float) -> np.ndarray:
    """A BODIES_RECORD[1] of `count` bodies from a sender of `epoch` stepping every
    `period_s`, its header set (a loop fills `bodies`, seq, the time and, from a sim,
    `follows` and `impulse` in place and sends `.tobytes()`)."""
    if not 0 < count <= MAX_MESSAGE_BODIES:
        raise ValueError(f"BodiesState: {count} bodies, 1 to {MAX_MESSAGE_BODIES}")
    rec = np.zeros(1, BODIES_RECORD)
    rec["magic"], rec["version"], rec["count"], rec["epoch"] = (
        magic,
        STATION_VERSION,
        count,
        epoch,
    )
    rec["period_s"] = period_s
    return rec


def encode_bodies(m: BodiesState) -> bytes:
    values = m.array()
    rec = bodies_record(m.magic, len(values), m.epoch, m.period_s)
    rec["seq"], rec["publish_time_ns"], rec["follows"] = m.seq, m.publish_time_ns, m.follows
    rec["bodies"][0, : len(values)] = values
    rec["impulse"][0] = np.array(m.impulse, np.float64).reshape(MAX_MESSAGE_BODIES, 3)
    return rec.tobytes()


def decode_bodies(raw: bytes, magic: bytes, count: int) -> BodiesState:
    """A BodiesState of `magic` that must carry `count` bodies (the receiver's scene's)."""
    what = "SimBodies" if magic == SIM_BODIES_MAGIC else "WorldBodies"
    _head(raw, magic, _BODIES.size, what, None)
    f = _BODIES.unpack(raw)
    if f[2] != count:
        raise MessageError("count", f"{what}.count: {f[2]} bodies, this scene has {count}")
    follows, period = f[6], f[7]
    if not (math.isfinite(period) and 0.0 < period <= 1.0):
        raise MessageError("value", f"{what}.period_s: {period!r}, not in (0, 1] s")
    bodies = tuple(tuple(f[8 + 6 * i : 14 + 6 * i]) for i in range(count))
    for i, b in enumerate(bodies):
        _numbers(b[:3], tuple(f"bodies[{i}].{a}" for a in AXES), POSE_LIMIT_M, what)
        _numbers(b[3:], tuple(f"bodies[{i}].twist.{a}" for a in AXES), TWIST_LIMIT, what)
    w0 = 8 + 6 * MAX_MESSAGE_BODIES
    impulse = tuple((f[w0 + 3 * i], f[w0 + 3 * i + 1], f[w0 + 3 * i + 2])
                    for i in range(MAX_MESSAGE_BODIES))  # fmt: skip
    for i, j in enumerate(impulse):
        _numbers(j, tuple(f"impulse[{i}].{a}" for a in AXES), IMPULSE_LIMIT, what)
    return BodiesState(magic, f[3], f[4], f[5], bodies, period, follows, impulse)


#: A refusal's reason, by code (the compiled checks count them so: station_codec.py): the
#: decoders' MessageError reasons, then the order rule's.
REASONS = ("size", "magic", "version", "port", "value", "flags", "stale", "other_epoch")
SIZE, MAGIC, VERSION, PORT, VALUE, FLAGS, STALE, OTHER_EPOCH = range(len(REASONS))


@njit(cache=True)
def order_code(has_last, last_epoch, last_seq, epoch, seq, silent):
    """The order rule of every link, as a REASONS code (-1: taken): after the last message
    taken (if any: `has_last`), one of its sender's epoch must be newer ("stale"); another
    epoch (a restarted sender, or a second one) is taken only once the present one is
    `silent` ("other_epoch"; each receiver's own silence rule). Compiled in the loops that
    take messages (station_codec.admit); run as Python by order_refusal."""
    if has_last == 0:
        return -1
    if epoch == last_epoch and seq <= last_seq:
        return STALE
    if epoch != last_epoch and not silent:
        return OTHER_EPOCH
    return -1


def order_refusal(last: Any, epoch: int, seq: int, silent: bool) -> str | None:
    """Why a message of a sender's `epoch` and `seq` is not taken after `last` (the last one
    taken, with its epoch and seq, or None), or None: order_code's rule, run as Python (its
    callers take messages on Zenoh's threads, where nothing is compiled)."""
    has_last = last is not None
    code = order_code.py_func(has_last, last.epoch if has_last else 0,
                              last.seq if has_last else 0, epoch, seq, silent)  # fmt: skip
    return None if code < 0 else REASONS[code]


class BodiesReceiver:
    """The receiving side of a BodiesState link, written once for the world (its SimBodies)
    and the sim's mirror (its WorldBodies): each payload decoded, a malformed one refused
    and counted by reason; ordered by order_refusal (and the receiver's own rule); the newest
    taken, and when; silent after `watchdog_ms` without one (the watchdog)."""

    def init_receiver(self, magic: bytes, count: int, watchdog_ms: float) -> None:
        self.magic, self.count, self.watchdog_ms = magic, count, watchdog_ms
        self.last: BodiesState | None = None
        self.rx_ns = 0
        self.received = self.rejected = self.lost = 0
        self.reasons: dict[str, int] = {}

    def refuse(self, reason: str) -> None:
        self.rejected += 1
        self.reasons[reason] = self.reasons.get(reason, 0) + 1

    def silent(self, now_ns: int) -> bool:
        return self.last is None or (now_ns - self.rx_ns) / 1e6 > self.watchdog_ms

    def accept(self, raw: bytes, now_ns: int, rule: Any = None) -> BodiesState | None:
        """`raw` decoded and ordered: the message if it may be taken (the caller takes it
        with `taken`), else None (refused and counted). `rule(m)` names a refusal of the
        receiver's own, which comes before the order's."""
        try:
            m = decode_bodies(raw, self.magic, self.count)
        except MessageError as exc:
            self.refuse(exc.reason)
            return None
        why = (rule(m) if rule is not None else None) or order_refusal(
            self.last, m.epoch, m.seq, self.silent(now_ns)
        )
        if why is not None:
            self.refuse(why)
            return None
        return m

    def taken(self, m: BodiesState, now_ns: int) -> None:
        self.last, self.rx_ns = m, now_ns
        self.received += 1

    def lose(self) -> None:
        """The sender fell silent: nothing followed until it is heard again."""
        self.lost += 1
        self.last = None


def encode_device(m: DeviceState) -> bytes:
    return DEVICE.encode(m)


def encode_tool(m: ToolState) -> bytes:
    return TOOL.encode(m)


def _head(raw: bytes, magic: bytes, size: int, what: str, port: int | None) -> None:
    """A message's header checked: its length, magic, version, size and port."""
    if len(raw) < _HEAD.size:
        raise MessageError("size", f"{what}: {len(raw)} bytes, shorter than its header")
    got_magic, version, got_port = _HEAD.unpack_from(raw)[:3]
    if got_magic != magic:
        raise MessageError("magic", f"{what}.magic: {got_magic!r}, expected {magic!r}")
    if version != STATION_VERSION:
        raise MessageError(
            "version", f"{what}.version: {version}, this build reads {STATION_VERSION}"
        )
    if len(raw) != size:
        raise MessageError("size", f"{what}: {len(raw)} bytes, expected {size}")
    if port is not None and got_port != port:
        raise MessageError("port", f"{what}.port: {got_port} on port {port}'s key")


def _numbers(values: tuple, names: tuple[str, ...], limit: float, what: str) -> None:
    for name, v in zip(names, values, strict=True):
        if not math.isfinite(v) or abs(v) > limit:
            raise MessageError("value", f"{what}.{name}: {v!r} is not finite or beyond {limit:g}")


def decode_device(raw: bytes, port: int) -> DeviceState:
    """A DeviceState received on port `port`'s key (module docstring)."""
    return DeviceState(**DEVICE.decode(raw, port))


def decode_tool(raw: bytes, port: int) -> ToolState:
    """A ToolState received on port `port`'s key (module docstring)."""
    return ToolState(**TOOL.decode(raw, port))


Vec3 = tuple[float, float, float]


def vec3(values: np.ndarray | tuple[float, ...] | list[float]) -> Vec3:
    """Three numbers as the messages' (x, y, angle) tuple."""
    x, y, a = (float(v) for v in values)
    return (x, y, a)

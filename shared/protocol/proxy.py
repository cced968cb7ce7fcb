"""The proxy state (haptic -> sim, a few hundred Hz): the proxy and the device, world frame.

One encoder, from a logged tick row (what the I/O sidecar publishes), and one decoder.
"""

from __future__ import annotations

import math
import struct
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from haptic_local_model.shared.kinematics import MAX_DOF
from haptic_local_model.shared.protocol.codes import Method
from haptic_local_model.shared.protocol.layout import DEFAULT_LIMITS, MessageLimits
from haptic_local_model.shared.protocol.update import MessageError

PROXY_MAGIC = b"HPXY"
#: The proxy state's own version. Up to 2 it was the update's PROTOCOL_VERSION; 3 added the
#: receipt -> install wait of an update, which the sim locks its phase to (sim_server/pacing.py);
#: 4 the god-object's forces on the shapes it touches (the sim applies them to their bodies);
#: 5 the impulses on them since the previous proxy state instead (DESIGN-WAVE2 C4); 6 the
#: haptic side's train state, which the sim poses its cars by (DESIGN-WAVE2 §5).
PROXY_VERSION = 6
# magic, version, flags, epoch, update_seq, tick, haptic_time, publish_time_ns, dof, method,
# wait_seq, update_wait_ns, tick_period_ns
PROXY_HEADER = struct.Struct("<4sHHQQQdqHHqqq")
MAX_TICK_PERIOD_NS = 10_000_000  # a haptic loop at >= 100 Hz
MAX_WAIT_NS = 1_000_000_000  # an update waits longer only in a stalled loop
#: version 5's trailer: int64 n (0..MAX_IMPULSES), float64 span (s, the haptic time the
#: impulses cover), n int64 shape keys (>= 0, unique), then n rows of 4 float64: the arm from
#: the shape's centre to a point on the impulse's line of action (world axes, m) and the
#: impulse (N s)
MAX_SPAN_S = 1.0  # a proxy state covers at most this much haptic time
MAX_LEVER_M = 0.1  # how far an impulse's point may move from its parts' mean to carry its moment
MAX_IMPULSES = 16
IMPULSE_FLOATS = 4
#: version 6's second trailer: int64 n (0 or 1); with 1, int64 static_id (>= 0), float64 s (m)
#: and s' (m/s) of the train the haptic side integrates
TRAIN_WORDS = 3
PROXY_SAFE_STATE = 1
PROXY_VALID = 2  # the haptic side has installed a model of this epoch


@dataclass(frozen=True)
class UpdateWait:
    """How long update `seq` waited in the haptic server between its receipt and the tick that
    installed it (both on the haptic host's clock), and the haptic tick period: what the sim
    needs to time its next update to arrive just before a tick. seq < 0: none known yet."""

    seq: int
    wait_ns: int
    tick_period_ns: int


NO_WAIT = UpdateWait(-1, -1, 0)


@dataclass(frozen=True, eq=False)
class ShapeImpulses:
    """The god-object's impulses on the shapes it touched over an interval (DESIGN-WAVE2 C4):
    per shape key, the impulse (N s: the sum of force x dt over the ticks) and where it acted,
    as an arm from the shape's centre (world axes, m: the sim applies it at its own body's
    centre plus the arm, so a body that has moved on since still gets the haptic side's
    torque, none for a push through its centre), and the haptic time they cover (span_s:
    every tick's dt, touching or not). The sim applies them whole, so no momentum is lost
    between the 1 kHz loop and its slower steps; the span lets it apply them at the rate they
    were rendered (sim_server/world.py)."""

    keys: np.ndarray  # (n,) int64
    points: np.ndarray  # (n, 2)
    impulses: np.ndarray  # (n, 2)
    span_s: float = 0.0

    @property
    def count(self) -> int:
        return int(self.keys.shape[0])

    @staticmethod
    def none() -> ShapeImpulses:
        return ShapeImpulses(np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2)))

    @staticmethod
    def of_ticks(
        keys: np.ndarray, points: np.ndarray, forces: np.ndarray, dt: np.ndarray
    ) -> ShapeImpulses:
        """Of tick rows' god_env_key (t, k), god_env_arm (t, k, 2), god_env_force (t, k, 2)
        and dt (t,): each tick's force times its dt, summed per key (-1: no shape)."""
        k = np.asarray(keys, np.int64).reshape(-1)
        p = np.asarray(points, np.float64).reshape(-1, 2)
        width = np.asarray(keys).shape[-1] if np.ndim(keys) else 1
        j = np.asarray(forces, np.float64).reshape(-1, 2) * np.repeat(dt, width)[:, None]
        touching = k >= 0
        return _grouped(k[touching], p[touching], j[touching], float(np.sum(dt)))

    def merged(self, other: ShapeImpulses) -> ShapeImpulses:
        """Both intervals' impulses, summed per key."""
        return _grouped(
            np.concatenate((self.keys, other.keys)), np.concatenate((self.points, other.points)),
            np.concatenate((self.impulses, other.impulses)), self.span_s + other.span_s,
        )  # fmt: skip

    def scaled(self, fraction: float, span_s: float) -> ShapeImpulses:
        """`fraction` of each impulse, covering span_s."""
        return ShapeImpulses(self.keys, self.points, self.impulses * fraction, span_s)

    def trailer(self) -> bytes:
        rows = np.column_stack((self.points, self.impulses)).astype("<f8")
        # a stalled I/O process's backlog is sent as at most MAX_SPAN_S (applied sooner)
        head = struct.pack("<qd", self.count, min(self.span_s, MAX_SPAN_S))
        return head + self.keys.astype("<i8").tobytes() + rows.tobytes()


def _grouped(
    keys: np.ndarray, points: np.ndarray, impulses: np.ndarray, span_s: float
) -> ShapeImpulses:
    """Impulses summed per key, each at the point on its line of action that gives the
    moment of its parts, sum (p_i - w) x J_i about their |impulse|-weighted mean point w: a
    finger sliding around a pebble pushes it through its centre at every tick, and so does
    the sum (a weighted mean point alone sits inside the pebble, off that line: 1000 rad/s
    spins seen). A sum too small to carry its moment within MAX_LEVER_M keeps w. Beyond
    MAX_IMPULSES keys, the largest impulses are kept (a publication 8 ticks apart touches at
    most 16 shapes; only a stalled I/O process drops any)."""
    if keys.shape[0] == 0:
        return ShapeImpulses(np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2)), span_s)
    unique, inverse = np.unique(keys, return_inverse=True)
    n = unique.shape[0]
    total = np.zeros((n, 2))
    np.add.at(total, inverse, impulses)
    weight = np.hypot(impulses[:, 0], impulses[:, 1])
    weight = np.where(np.bincount(inverse, weight, n)[inverse] > 0.0, weight, 1.0)
    where = np.zeros((n, 2))
    np.add.at(where, inverse, points * weight[:, None])
    where /= np.bincount(inverse, weight, n)[:, None]
    arm = points - where[inverse]
    moment = np.bincount(inverse, arm[:, 0] * impulses[:, 1] - arm[:, 1] * impulses[:, 0], n)
    size = total[:, 0] ** 2 + total[:, 1] ** 2
    lever = (
        np.column_stack((total[:, 1], -total[:, 0]))
        * (moment / np.where(size > 0.0, size, 1.0))[:, None]
    )
    carried = (size > 0.0) & (np.hypot(lever[:, 0], lever[:, 1]) <= MAX_LEVER_M)
    where = np.where(carried[:, None], where + lever, where)
    if n > MAX_IMPULSES:
        keep = np.sort(np.argsort(-np.hypot(total[:, 0], total[:, 1]))[:MAX_IMPULSES])
        unique, where, total = unique[keep], where[keep], total[keep]
    return ShapeImpulses(unique.astype(np.int64), where, total, span_s)


@dataclass(frozen=True)
class TrainState:
    """The haptic side's train (its static id, the lead car's s and s') at a tick."""

    static_id: int
    s: float
    sd: float

    def trailer(self) -> bytes:
        return struct.pack("<qqdd", 1, self.static_id, self.s, self.sd)

    @staticmethod
    def of_row(r: Any) -> TrainState | None:
        """A tick row's train, None when the scene has none (avar_cars == 0)."""
        if r["avar_cars"] == 0:
            return None
        return TrainState(int(r["avar_static_id"]), float(r["avar_s"]), float(r["avar_sd"]))


NO_TRAIN = struct.pack("<q", 0)


@dataclass(frozen=True, eq=False)
class ProxyState:
    """What the haptic server publishes for the sim: the proxy and the device (world frame)."""

    epoch: int
    update_seq: int
    tick: int
    haptic_time: float
    publish_time_ns: int
    method: int
    safe_state: bool
    valid: bool
    q: np.ndarray
    qd: np.ndarray
    device_pose: np.ndarray
    device_twist: np.ndarray
    wait: UpdateWait = NO_WAIT
    # the god-object's impulses on what it touched since the previous proxy state (none under
    # the other methods)
    impulses: ShapeImpulses = field(default_factory=ShapeImpulses.none)
    # the train the haptic side integrates (a scene with one), None otherwise
    train: TrainState | None = None


def encode_proxy(
    row: np.ndarray,
    method: int,
    publish_time_ns: int | None = None,
    wait: UpdateWait = NO_WAIT,
    impulses: ShapeImpulses | None = None,
) -> bytes:
    """The ProxyState of a tick row (TICK_DTYPE[1] or one record): proxy q, qd, the measured
    device pose and twist, the newest known update wait, and under god_object the impulses
    on the shapes touched since the previous proxy state (`impulses`, accumulated over the
    ticks by the caller; by default this row's force times its dt), the row's train state if
    the scene has one; stamped now unless `publish_time_ns` is given."""
    r = row[0] if row.ndim else row
    d = int(r["dof"])
    flags = (PROXY_SAFE_STATE if r["safe"] > 0.0 else 0) | PROXY_VALID  # a row is a tick run
    stamp = time.time_ns() if publish_time_ns is None else publish_time_ns
    header = PROXY_HEADER.pack(
        PROXY_MAGIC, PROXY_VERSION, flags, int(r["update_epoch"]), int(r["update_seq"]),
        int(r["tick"]), float(r["t"]), stamp, d, int(method), wait.seq, wait.wait_ns,
        wait.tick_period_ns,
    )  # fmt: skip
    body = np.concatenate(
        (r["proxy_q"][:d], r["proxy_qd"][:d], r["device_pose"], r["device_twist"])
    ).astype("<f8")
    if method != Method.GOD_OBJECT:
        impulses = ShapeImpulses.none()
    elif impulses is None:
        impulses = ShapeImpulses.of_ticks(
            r["god_env_key"][None], r["god_env_arm"][None], r["god_env_force"][None],
            np.array([r["dt"]]),
        )  # fmt: skip
    train = TrainState.of_row(r)
    return header + body.tobytes() + impulses.trailer() + (train.trailer() if train else NO_TRAIN)


def decode_proxy(data: bytes, limits: MessageLimits = DEFAULT_LIMITS) -> ProxyState:
    """Parse and validate a proxy state; raises MessageError naming what is wrong."""
    if len(data) < PROXY_HEADER.size:
        raise MessageError("short", f"{len(data)} bytes is shorter than the header")
    magic, version, flags, epoch, useq, tick, htime, pub_ns, d, method, wseq, wait_ns, period_ns = (
        PROXY_HEADER.unpack_from(data, 0)
    )
    if magic != PROXY_MAGIC:
        raise MessageError("magic", f"expected {PROXY_MAGIC!r}, got {magic!r}")
    if version != PROXY_VERSION:
        raise MessageError("version", f"proxy version {version}, this build speaks {PROXY_VERSION}")
    if not 0 <= d <= MAX_DOF:
        raise MessageError("dof", f"dof {d} outside [0, {MAX_DOF}]")
    if wseq >= 0 and not (0 < period_ns <= MAX_TICK_PERIOD_NS and 0 <= wait_ns <= MAX_WAIT_NS):
        raise MessageError(
            "timing", f"update wait {wait_ns} ns / tick period {period_ns} ns out of range"
        )
    body_end = PROXY_HEADER.size + 8 * (2 * d + 6)
    if len(data) < body_end + 16:
        raise MessageError("size", f"{len(data)} bytes, expected at least {body_end + 16}")
    n, span = struct.unpack_from("<qd", data, body_end)
    if not 0 <= n <= MAX_IMPULSES:
        raise MessageError("env", f"{n} impulses: 0..{MAX_IMPULSES}")
    train_at = body_end + 8 * (2 + n + IMPULSE_FLOATS * n)
    train = _train(data, train_at, limits)
    v = np.frombuffer(data, "<f8", 2 * d + 6, PROXY_HEADER.size).astype(np.float64)
    env = np.frombuffer(data, "<f8", IMPULSE_FLOATS * n, body_end + 8 * (2 + n))
    env = env.astype(np.float64).reshape(n, IMPULSE_FLOATS)
    if not (np.isfinite(v).all() and np.isfinite(htime) and np.isfinite(env).all()) or not (
        math.isfinite(span)
    ):
        raise MessageError("nonfinite", "NaN or Inf in the payload")
    if not 0.0 <= span <= MAX_SPAN_S:
        raise MessageError("env", f"impulses over {span} s: 0..{MAX_SPAN_S} s")
    if np.abs(v).max(initial=0.0) > max(limits.max_abs_position_m, limits.max_abs_angle_rad):
        raise MessageError("magnitude", "proxy state out of bounds")
    env_keys = np.frombuffer(data, "<i8", n, body_end + 16).astype(np.int64)
    if n and (env_keys.min() < 0 or np.unique(env_keys).shape[0] != n):
        raise MessageError("env", f"shape keys {env_keys.tolist()}: each >= 0, none twice")
    if np.abs(env[:, :2]).max(initial=0.0) > limits.max_abs_position_m or (
        np.abs(env[:, 2:]).max(initial=0.0) > limits.max_abs_generalized_force
    ):
        raise MessageError("magnitude", "a contact point or impulse on a shape out of bounds")
    return ProxyState(
        epoch=epoch, update_seq=useq, tick=tick, haptic_time=htime, publish_time_ns=pub_ns,
        method=method, safe_state=bool(flags & PROXY_SAFE_STATE), valid=bool(flags & PROXY_VALID),
        q=v[:d], qd=v[d : 2 * d], device_pose=v[2 * d : 2 * d + 3], device_twist=v[2 * d + 3 :],
        wait=UpdateWait(wseq, wait_ns, period_ns) if wseq >= 0 else NO_WAIT,
        impulses=ShapeImpulses(env_keys, env[:, :2].copy(), env[:, 2:].copy(), span),
        train=train,
    )  # fmt: skip


def _train(data: bytes, at: int, limits: MessageLimits) -> TrainState | None:
    """Version 6's train trailer at byte `at`, which ends the message."""
    if len(data) < at + 8:
        raise MessageError("size", f"{len(data)} bytes, expected at least {at + 8}")
    (count,) = struct.unpack_from("<q", data, at)
    if count not in (0, 1):
        raise MessageError("train", f"{count} trains: 0 or 1")
    expected = at + 8 * (1 + TRAIN_WORDS * count)
    if len(data) != expected:
        raise MessageError("size", f"{len(data)} bytes, expected {expected}")
    if count == 0:
        return None
    static_id, s, sd = struct.unpack_from("<qdd", data, at + 8)
    if not (math.isfinite(s) and math.isfinite(sd)):
        raise MessageError("nonfinite", "NaN or Inf in the train's state")
    if static_id < 0 or abs(s) > limits.max_abs_position_m or abs(sd) > limits.max_abs_velocity:
        raise MessageError("train", f"train {static_id} at s {s} m, s' {sd} m/s out of bounds")
    return TrainState(static_id, s, sd)

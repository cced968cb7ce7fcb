"""The proxy state (haptic -> sim, a few hundred Hz): the proxy and the device, world frame.

One encoder, from a logged tick row (what the I/O sidecar publishes), and one decoder.
"""

from __future__ import annotations

import struct
import time
from dataclasses import dataclass, field

import numpy as np

from haptic_local_model.shared.kinematics import MAX_DOF
from haptic_local_model.shared.protocol.codes import Method
from haptic_local_model.shared.protocol.layout import DEFAULT_LIMITS, MessageLimits
from haptic_local_model.shared.protocol.update import MessageError

PROXY_MAGIC = b"HPXY"
#: The proxy state's own version. Up to 2 it was the update's PROTOCOL_VERSION; 3 added the
#: receipt -> install wait of an update, which the sim locks its phase to (sim_server/pacing.py);
#: 4 the god-object's forces on the shapes it touches (the sim applies them to their bodies).
PROXY_VERSION = 4
# magic, version, flags, epoch, update_seq, tick, haptic_time, publish_time_ns, dof, method,
# wait_seq, update_wait_ns, tick_period_ns
PROXY_HEADER = struct.Struct("<4sHHQQQdqHHqqq")
MAX_TICK_PERIOD_NS = 10_000_000  # a haptic loop at >= 100 Hz
MAX_WAIT_NS = 1_000_000_000  # an update waits longer only in a stalled loop
#: version 4's trailer: two touched shapes' keys (-1: none), then their contact points (world,
#: m) and the forces on them (N), x y each
ENV_KEYS = struct.Struct("<qq")
ENV_FLOATS = 8
ENV_BYTES = ENV_KEYS.size + 8 * ENV_FLOATS
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
    # the god-object's forces on what it touches (god_object method; keys -1 otherwise)
    env_keys: tuple[int, int] = (-1, -1)
    env_points: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))
    env_forces: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))


def encode_proxy(
    row: np.ndarray,
    method: int,
    publish_time_ns: int | None = None,
    wait: UpdateWait = NO_WAIT,
) -> bytes:
    """The ProxyState of a tick row (TICK_DTYPE[1] or one record): proxy q, qd, the measured
    device pose and twist, and the newest known update wait; stamped now unless
    `publish_time_ns` is given."""
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
    god = method == Method.GOD_OBJECT
    keys = ENV_KEYS.pack(*(int(k) for k in r["god_env_key"])) if god else ENV_KEYS.pack(-1, -1)
    env = np.concatenate((r["god_env_point"].ravel(), r["god_env_force"].ravel())).astype("<f8")
    return header + body.tobytes() + keys + (env if god else np.zeros(ENV_FLOATS)).tobytes()


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
    expected = body_end + ENV_BYTES
    if len(data) != expected:
        raise MessageError("size", f"{len(data)} bytes, expected {expected}")
    v = np.frombuffer(data, "<f8", 2 * d + 6, PROXY_HEADER.size).astype(np.float64)
    env = np.frombuffer(data, "<f8", ENV_FLOATS, body_end + ENV_KEYS.size).astype(np.float64)
    if not np.isfinite(v).all() or not np.isfinite(htime) or not np.isfinite(env).all():
        raise MessageError("nonfinite", "NaN or Inf in the payload")
    if np.abs(v).max(initial=0.0) > max(limits.max_abs_position_m, limits.max_abs_angle_rad):
        raise MessageError("magnitude", "proxy state out of bounds")
    env_keys = ENV_KEYS.unpack_from(data, body_end)
    if min(env_keys) < -1:
        raise MessageError("env", f"shape keys {env_keys}: -1 (none) or a key >= 0")
    if np.abs(env[:4]).max() > limits.max_abs_position_m or (
        np.abs(env[4:]).max() > limits.max_abs_generalized_force
    ):
        raise MessageError("magnitude", "a contact point or force on a shape out of bounds")
    return ProxyState(
        epoch=epoch, update_seq=useq, tick=tick, haptic_time=htime, publish_time_ns=pub_ns,
        method=method, safe_state=bool(flags & PROXY_SAFE_STATE), valid=bool(flags & PROXY_VALID),
        q=v[:d], qd=v[d : 2 * d], device_pose=v[2 * d : 2 * d + 3], device_twist=v[2 * d + 3 :],
        wait=UpdateWait(wseq, wait_ns, period_ns) if wseq >= 0 else NO_WAIT,
        env_keys=env_keys, env_points=env[:4].reshape(2, 2), env_forces=env[4:].reshape(2, 2),
    )  # fmt: skip

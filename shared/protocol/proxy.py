"""The proxy state (haptic -> sim, a few hundred Hz): the proxy and the device, world frame.

One encoder, from a logged tick row (what the I/O sidecar publishes), and one decoder.
"""

from __future__ import annotations

import struct
import time
from dataclasses import dataclass

import numpy as np

from shared.kinematics import MAX_DOF
from shared.protocol.layout import DEFAULT_LIMITS, PROTOCOL_VERSION, MessageLimits
from shared.protocol.update import MessageError

PROXY_MAGIC = b"HPXY"
# magic, version, flags, epoch, update_seq, tick, haptic_time, publish_time_ns, dof, method
PROXY_HEADER = struct.Struct("<4sHHQQQdqHH")
PROXY_SAFE_STATE = 1
PROXY_VALID = 2  # the haptic side has installed a model of this epoch


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


def encode_proxy(row: np.ndarray, method: int, publish_time_ns: int | None = None) -> bytes:
    """The ProxyState of a tick row (TICK_DTYPE[1] or one record): proxy q, qd, the measured
    device pose and twist; stamped now unless `publish_time_ns` is given."""
    r = row[0] if row.ndim else row
    d = int(r["dof"])
    flags = (PROXY_SAFE_STATE if r["safe"] > 0.0 else 0) | PROXY_VALID  # a row is a tick run
    stamp = time.time_ns() if publish_time_ns is None else publish_time_ns
    header = PROXY_HEADER.pack(
        PROXY_MAGIC, PROTOCOL_VERSION, flags, int(r["update_epoch"]), int(r["update_seq"]),
        int(r["tick"]), float(r["t"]), stamp, d, int(method),
    )  # fmt: skip
    body = np.concatenate(
        (r["proxy_q"][:d], r["proxy_qd"][:d], r["device_pose"], r["device_twist"])
    ).astype("<f8")
    return header + body.tobytes()


def decode_proxy(data: bytes, limits: MessageLimits = DEFAULT_LIMITS) -> ProxyState:
    """Parse and validate a proxy state; raises MessageError naming what is wrong."""
    if len(data) < PROXY_HEADER.size:
        raise MessageError("short", f"{len(data)} bytes is shorter than the header")
    magic, version, flags, epoch, useq, tick, htime, pub_ns, d, method = PROXY_HEADER.unpack_from(
        data, 0
    )
    if magic != PROXY_MAGIC:
        raise MessageError("magic", f"expected {PROXY_MAGIC!r}, got {magic!r}")
    if version != PROTOCOL_VERSION:
        raise MessageError("version", f"protocol {version}, this build speaks {PROTOCOL_VERSION}")
    if not 0 <= d <= MAX_DOF:
        raise MessageError("dof", f"dof {d} outside [0, {MAX_DOF}]")
    expected = PROXY_HEADER.size + 8 * (2 * d + 6)
    if len(data) != expected:
        raise MessageError("size", f"{len(data)} bytes, expected {expected}")
    v = np.frombuffer(data, "<f8", 2 * d + 6, PROXY_HEADER.size).astype(np.float64)
    if not np.isfinite(v).all() or not np.isfinite(htime):
        raise MessageError("nonfinite", "NaN or Inf in the payload")
    if np.abs(v).max(initial=0.0) > max(limits.max_abs_position_m, limits.max_abs_angle_rad):
        raise MessageError("magnitude", "proxy state out of bounds")
    return ProxyState(
        epoch=epoch, update_seq=useq, tick=tick, haptic_time=htime, publish_time_ns=pub_ns,
        method=method, safe_state=bool(flags & PROXY_SAFE_STATE), valid=bool(flags & PROXY_VALID),
        q=v[:d], qd=v[d : 2 * d], device_pose=v[2 * d : 2 * d + 3], device_twist=v[2 * d + 3 :],
    )  # fmt: skip

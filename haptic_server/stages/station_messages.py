"""The stations' messages (shared/protocol/station.py), compiled: a DeviceState or a
ToolState checked in place as the reference decoders check it (`decode_device`,
`decode_tool`: they stay the reference; tests/test_world_ports.py and
tests/test_station_link.py check that both refuse the same messages for the same reason and
take the same fields), the refusal a REASONS code; and a DeviceState as a record of exactly
its bytes, for a station to fill in place and send.

A message is `bytes` (Zenoh's payload): read through `np.frombuffer` views, no copy."""

from __future__ import annotations

import math
import struct

import numpy as np
from numba import njit

from haptic_local_model.shared.protocol.station import (
    CUT,
    DEVICE_MAGIC,
    GAIN_LIMIT,
    GLOVE,
    GLOVE_ANGLE_LIMIT,
    HELD,
    MAX_GLOVE_JOINTS,
    POSE_LIMIT_M,
    SAFE,
    STATION_VERSION,
    TOOL_MAGIC,
    TWIST_LIMIT,
)

#: A refusal's reason, by code: the decoders' MessageError reasons, then order_refusal's.
REASONS = ("size", "magic", "version", "port", "value", "flags", "stale", "other_epoch")
SIZE, MAGIC, VERSION, PORT, VALUE, FLAGS, STALE, OTHER_EPOCH = range(len(REASONS))

J = MAX_GLOVE_JOINTS
HEAD_BYTES = struct.calcsize("<4sHHQQq")
DEVICE_FLOATS = 6 + 2 * J  # pose, twist, glove, glove_rate
DEVICE_BYTES = struct.calcsize(f"<4sHHQQq{DEVICE_FLOATS}dI")
TOOL_FLOATS = 15  # pose, twist, stiffness, damping, object_pose
TOOL_BYTES = struct.calcsize(f"<4sHHQQq{TOOL_FLOATS}dI")
DEVICE_MAGIC_U8 = np.frombuffer(DEVICE_MAGIC, np.uint8).copy()
TOOL_MAGIC_U8 = np.frombuffer(TOOL_MAGIC, np.uint8).copy()
DEVICE_FLAGS = SAFE | CUT | GLOVE

#: A DeviceState as a numpy record of exactly the message's bytes (as TOOL_RECORD).
DEVICE_RECORD = np.dtype(
    [("magic", "S4"), ("version", "<u2"), ("port", "<u2"), ("epoch", "<u8"), ("seq", "<u8"),
     ("publish_time_ns", "<i8"), ("pose", "<f8", (3,)), ("twist", "<f8", (3,)),
     ("glove", "<f8", (J,)), ("glove_rate", "<f8", (J,)), ("flags", "<u4")]
)  # fmt: skip
assert DEVICE_RECORD.itemsize == DEVICE_BYTES


def device_record(port: int, epoch: int) -> np.ndarray:
    """A DEVICE_RECORD[1] for `port` from a station of `epoch`, its header set."""
    rec = np.zeros(1, DEVICE_RECORD)
    rec["magic"], rec["version"], rec["port"], rec["epoch"] = (
        DEVICE_MAGIC, STATION_VERSION, port, epoch,
    )  # fmt: skip
    return rec


@njit(cache=True)
def _bad(v, limit):
    return not math.isfinite(v) or abs(v) > limit


@njit(cache=True)
def head_refusal(u, magic, size, p):
    """The header's refusal (a REASONS code) for a message of `magic` and `size` bytes on
    port p's key, or -1: the decoders' `_head`, in its order."""
    n = len(u)
    if n < HEAD_BYTES:
        return SIZE
    for i in range(4):
        if u[i] != magic[i]:
            return MAGIC
    if int(u[4]) + 256 * int(u[5]) != STATION_VERSION:
        return VERSION
    if n != size:
        return SIZE
    if int(u[6]) + 256 * int(u[7]) != p:
        return PORT
    return -1


@njit(cache=True)
def device_refusal(raw, p):
    """Why `raw` is not a DeviceState for port p (a REASONS code), or -1: decode_device's
    checks, in its order."""
    u = np.frombuffer(raw, np.uint8)
    why = head_refusal(u, DEVICE_MAGIC_U8, DEVICE_BYTES, p)
    if why >= 0:
        return why
    f = u[HEAD_BYTES : HEAD_BYTES + 8 * DEVICE_FLOATS].view(np.float64)
    for i in range(DEVICE_FLOATS):
        if i < 3 or 6 <= i < 6 + J:  # the pose, the glove
            limit = POSE_LIMIT_M if i < 3 else GLOVE_ANGLE_LIMIT
        else:  # the twist, the glove's rates
            limit = TWIST_LIMIT
        if _bad(f[i], limit):
            return VALUE
    if u[DEVICE_BYTES - 4 : DEVICE_BYTES].view(np.uint32)[0] & ~np.uint32(DEVICE_FLAGS):
        return FLAGS
    return -1


@njit(cache=True)
def tool_refusal(raw, p):
    """Why `raw` is not a ToolState for port p (a REASONS code), or -1: decode_tool's checks,
    in its order (every value check refuses as "value")."""
    u = np.frombuffer(raw, np.uint8)
    why = head_refusal(u, TOOL_MAGIC_U8, TOOL_BYTES, p)
    if why >= 0:
        return why
    f = u[HEAD_BYTES : HEAD_BYTES + 8 * TOOL_FLOATS].view(np.float64)
    for i in range(TOOL_FLOATS):
        if i < 3 or i >= 12:  # the pose, the object's pose
            limit = POSE_LIMIT_M
        elif i < 6:  # the twist
            limit = TWIST_LIMIT
        else:  # the gains
            limit = GAIN_LIMIT
        if _bad(f[i], limit) or (6 <= i < 12 and f[i] < 0.0):
            return VALUE
    if u[TOOL_BYTES - 4 : TOOL_BYTES].view(np.uint32)[0] & ~np.uint32(HELD):
        return FLAGS
    return -1


@njit(cache=True)
def order_code(has_last, last_epoch, last_seq, epoch, seq, silent):
    """shared/protocol/station.py's `order_refusal` as a REASONS code (-1: taken): within
    the sender's epoch a message must be newer; another epoch only once the taken one is
    `silent` (each side's own silence rule)."""
    if has_last == 0:
        return -1
    if epoch == last_epoch and seq <= last_seq:
        return STALE
    if epoch != last_epoch and not silent:
        return OTHER_EPOCH
    return -1


def reason_counts(counts: np.ndarray) -> dict[str, int]:
    """Refusals counted by REASONS code, as a dict of those that happened."""
    return {r: int(counts[i]) for i, r in enumerate(REASONS) if counts[i]}


@njit(cache=True)
def message_order(raw):
    """A checked message's epoch and seq (uint64)."""
    head = np.frombuffer(raw, np.uint8)[8:24].view(np.uint64)
    return head[0], head[1]


@njit(cache=True)
def message_floats(raw, n):
    """A checked message's n numbers after its header (a view)."""
    return np.frombuffer(raw, np.uint8)[HEAD_BYTES : HEAD_BYTES + 8 * n].view(np.float64)


@njit(cache=True)
def message_flags(raw):
    u = np.frombuffer(raw, np.uint8)
    return u[len(u) - 4 :].view(np.uint32)[0]

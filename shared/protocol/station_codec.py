"""The stations' messages (station.py, beside it), compiled: a DeviceState or a
ToolState checked in place as the reference decoders check it, from the same table
(`StationMessage`: its limits, its non-negative numbers, its flags; the decoders stay the
reference; tests/test_world_ports.py and tests/test_station_link.py check that both refuse
the same messages for the same reason and take the same fields), the refusal a REASONS
code.

A message is `bytes` (Zenoh's payload): read through `np.frombuffer` views, no copy."""

from __future__ import annotations

import math
import struct

import numpy as np
from numba import njit

from haptic_local_model.shared.protocol.station import (
    DEVICE,
    DEVICE_RECORD,
    FLAGS,
    MAGIC,
    PORT,
    REASONS,
    SIZE,
    STATION_VERSION,
    TOOL,
    TOOL_RECORD,
    VALUE,
    VERSION,
    order_code,
)

HEAD_BYTES = struct.calcsize("<4sHHQQq")
# each message's table (shared/protocol/station.py) as the constants its compiled check reads
DEVICE_FLOATS, TOOL_FLOATS = len(DEVICE.labels), len(TOOL.labels)
DEVICE_BYTES, TOOL_BYTES = DEVICE_RECORD.itemsize, TOOL_RECORD.itemsize
DEVICE_MAGIC_U8 = np.frombuffer(DEVICE.magic, np.uint8).copy()
TOOL_MAGIC_U8 = np.frombuffer(TOOL.magic, np.uint8).copy()
DEVICE_LIMITS, DEVICE_NONNEG, DEVICE_FLAGS = DEVICE.limits, DEVICE.nonneg, DEVICE.flags
TOOL_LIMITS, TOOL_NONNEG, TOOL_FLAGS = TOOL.limits, TOOL.nonneg, TOOL.flags


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
def message_refusal(raw, p, magic, size, limits, nonneg, flags):
    """Why `raw` is not the message of this table for port p (a REASONS code), or -1: the
    reference decoder's checks (StationMessage.decode), in its order."""
    u = np.frombuffer(raw, np.uint8)
    why = head_refusal(u, magic, size, p)
    if why >= 0:
        return why
    f = u[HEAD_BYTES : HEAD_BYTES + 8 * len(limits)].view(np.float64)
    for i in range(len(limits)):
        if _bad(f[i], limits[i]) or (nonneg[i] != 0 and f[i] < 0.0):
            return VALUE
    if u[size - 4 : size].view(np.uint32)[0] & ~np.uint32(flags):
        return FLAGS
    return -1


@njit(cache=True)
def device_refusal(raw, p):
    """Why `raw` is not a DeviceState for port p (a REASONS code), or -1."""
    return message_refusal(raw, p, DEVICE_MAGIC_U8, DEVICE_BYTES, DEVICE_LIMITS,
                           DEVICE_NONNEG, DEVICE_FLAGS)  # fmt: skip


@njit(cache=True)
def tool_refusal(raw, p):
    """Why `raw` is not a ToolState for port p (a REASONS code), or -1."""
    return message_refusal(raw, p, TOOL_MAGIC_U8, TOOL_BYTES, TOOL_LIMITS, TOOL_NONNEG,
                           TOOL_FLAGS)  # fmt: skip


@njit(cache=True)
def admit(link, raw, why, silent):
    """A message that its own check gave `why` (a REASONS code, -1: passed) judged by the
    order rule (station.order_code) against the last one `link` took (a record with has_last, epoch,
    seq, rejected and reasons; `silent`: its sender's silence rule): (taken, its epoch, its
    seq, the first of its sender's epoch: nothing taken before, or another epoch). A refused
    one is counted in `link`; a taken one is the caller's to record."""
    epoch, seq = np.uint64(0), np.uint64(0)
    if why < 0:
        epoch, seq = message_order(raw)
        why = order_code(link.has_last, link.epoch, link.seq, epoch, seq, silent)
    if why >= 0:
        link.rejected += 1
        link.reasons[why] += 1
        return False, epoch, seq, False
    return True, epoch, seq, link.has_last == 0 or epoch != link.epoch


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

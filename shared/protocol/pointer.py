"""The pointer input (a position-only input device -> haptic, up to a few hundred Hz).

A mouse or a gamepad has no force output: `haptic-pointer` reads it and publishes where the
user's hand should be, and the haptic server's simulated hand of kind "pointer" follows that
target with its spring and damper, holding the (simulated) device as a real hand would. The
target is relative to the device's pose when the hand took hold (as a user's waypoints are).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from haptic_local_model.shared.protocol.update import MessageError

POINTER_MAGIC = b"HPTR"
POINTER_VERSION = 1
# magic, version, flags (0), seq, publish_time_ns, dx, dy, dtheta, buttons, reserved (0)
POINTER_STRUCT = struct.Struct("<4sHHQqdddII")
#: A target farther than this from where the hand took hold is refused (a scene is < 1 m)
MAX_POINTER_M = 1.0
MAX_POINTER_RAD = math.pi
#: A pointer input stamped further than this from the receiver's clock is refused (late, or
#: from a clock that is off): the hand must never jump to where the pointer was long ago
MAX_POINTER_AGE_NS = 1_000_000_000


@dataclass(frozen=True)
class PointerInput:
    """Where the hand should be: (dx, dy, dtheta) from its start, and the buttons held."""

    seq: int
    publish_time_ns: int
    target: tuple[float, float, float]
    buttons: int


def encode_pointer(seq: int, publish_time_ns: int, target: tuple[float, float, float],
                   buttons: int = 0) -> bytes:  # fmt: skip
    return POINTER_STRUCT.pack(
        POINTER_MAGIC, POINTER_VERSION, 0, seq, publish_time_ns, *target, buttons, 0
    )


def decode_pointer(data: bytes) -> PointerInput:
    """Parse and validate a pointer input; raises MessageError naming what is wrong."""
    if len(data) != POINTER_STRUCT.size:
        raise MessageError("size", f"{len(data)} bytes, expected {POINTER_STRUCT.size}")
    magic, version, _flags, seq, stamp, dx, dy, dtheta, buttons, _ = POINTER_STRUCT.unpack(data)
    if magic != POINTER_MAGIC:
        raise MessageError("magic", f"expected {POINTER_MAGIC!r}, got {magic!r}")
    if version != POINTER_VERSION:
        raise MessageError("version", f"pointer version {version}, this build speaks "
                           f"{POINTER_VERSION}")  # fmt: skip
    if not all(math.isfinite(v) for v in (dx, dy, dtheta)):
        raise MessageError("nonfinite", "NaN or Inf in the target")
    if abs(dx) > MAX_POINTER_M or abs(dy) > MAX_POINTER_M or abs(dtheta) > MAX_POINTER_RAD:
        raise MessageError(
            "magnitude",
            f"target ({dx:g}, {dy:g}, {dtheta:g}) beyond {MAX_POINTER_M:g} m / pi rad",
        )
    return PointerInput(seq, stamp, (dx, dy, dtheta), buttons)

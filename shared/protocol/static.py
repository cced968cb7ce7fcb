"""The static message (sim -> haptic, key `<ns>/static`, latched, re-published at 1 Hz): what
of a scene's world never changes within an epoch and is too large for every update, the
description of its animation-variable train (DESIGN-WAVE2 C4, §5).

It carries the track and the cars as canonical JSON, named by a static id: the first 63 bits
of the BLAKE2b digest of that JSON. An update's AVARS trailer names the static id of the
train it carries; the haptic server computes the same id from its own scene and installs no
update of another (Reason.STATIC), and checks each static message it receives against its
scene (`check_static`), so a sim and a haptic server started on different tracks refuse each
other by name rather than render a car where it is not.

Bytes: magic `HLMS`, uint16 version, uint64 static id, then the JSON (UTF-8), at most
MAX_STATIC_BYTES in all.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import struct
from typing import Any

from haptic_local_model.shared.config import SceneConfig
from haptic_local_model.shared.protocol.update import MessageError

STATIC_MAGIC = b"HLMS"
STATIC_VERSION = 1
STATIC_HEADER = struct.Struct("<4sHQ")
MAX_STATIC_BYTES = 65536
STATIC_PERIOD_S = 1.0  # the sim re-publishes it this often (a late joiner waits at most this)
ID_MASK = (1 << 63) - 1


def description(scene: SceneConfig) -> dict[str, Any]:
    """The scene's mechanism as plain data: a train's track and its cars' static part, or a
    crank's, and gravity (none for a scene without one)."""
    if scene.avar_tree is not None:
        tree = dataclasses.asdict(scene.avar_tree)
        for moving in ("initial_q", "initial_rate", "material"):
            tree.pop(moving)
        return {"avar_tree": tree, "gravity": list(scene.gravity)}
    if scene.crank is not None:
        crank = dataclasses.asdict(scene.crank)
        for moving in ("initial_q", "initial_rate", "material"):
            crank.pop(moving)
        return {"crank": crank, "gravity": list(scene.gravity)}
    if not scene.cars:
        return {}
    cars = dataclasses.asdict(scene.cars[0])
    for moving in ("initial_s", "initial_speed", "material"):  # not the train's tables
        cars.pop(moving)
    return {
        "track": dataclasses.asdict(scene.tracks[0]),
        "cars": cars,
        "gravity": list(scene.gravity),
    }


def canonical(desc: dict[str, Any]) -> bytes:
    return json.dumps(desc, sort_keys=True, separators=(",", ":")).encode()


def id_of(desc: dict[str, Any]) -> int:
    return (
        int.from_bytes(hashlib.blake2b(canonical(desc), digest_size=8).digest(), "little") & ID_MASK
    )


def static_id(scene: SceneConfig) -> int:
    """The static id of the scene's mechanism (-1: the scene has none)."""
    desc = description(scene)
    return id_of(desc) if desc else -1


def has_mechanism(scene: SceneConfig) -> bool:
    return bool(scene.cars) or scene.crank is not None or scene.avar_tree is not None


def encode_static(scene: SceneConfig) -> bytes:
    desc = description(scene)
    return STATIC_HEADER.pack(STATIC_MAGIC, STATIC_VERSION, id_of(desc)) + canonical(desc)


def decode_static(data: bytes) -> tuple[int, dict[str, Any]]:
    """(static id, description) of a static message; MessageError naming what is wrong."""
    if len(data) > MAX_STATIC_BYTES:
        raise MessageError("size", f"{len(data)} bytes, at most {MAX_STATIC_BYTES}")
    if len(data) < STATIC_HEADER.size:
        raise MessageError("short", f"{len(data)} bytes is shorter than the header")
    magic, version, sid = STATIC_HEADER.unpack_from(data, 0)
    if magic != STATIC_MAGIC:
        raise MessageError("magic", f"expected {STATIC_MAGIC!r}, got {magic!r}")
    if version != STATIC_VERSION:
        raise MessageError(
            "version", f"static version {version}, this build speaks {STATIC_VERSION}"
        )
    try:
        desc = json.loads(data[STATIC_HEADER.size :].decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MessageError("static", f"the description is not JSON: {exc}") from None
    if not isinstance(desc, dict) or id_of(desc) != sid:
        raise MessageError("static", f"static id {sid} is not its description's")
    return sid, desc


def check_static(scene: SceneConfig, data: bytes) -> str:
    """Why a received static message is not this scene's train ("" if it is)."""
    try:
        sid, desc = decode_static(data)
    except MessageError as exc:
        return str(exc)
    ours = description(scene)
    if sid == id_of(ours) and ours:
        return ""
    differs = sorted(k for k in set(desc) | set(ours) if desc.get(k) != ours.get(k))
    where = ", ".join(differs) or "its id"
    return f"the sim's train {sid} differs from scene {scene.name!r} in {where}"

"""Wire messages between the sim and the haptic server: schemas, codecs and validation.

Two messages, both little-endian binary with a fixed header, a magic and a version
(docs/protocol.md is the reference; golden files in tests/golden/ pin the bytes):

- `LocalModelUpdate` (sim -> haptic, each sim step): the local model of DESIGN §3.
- `ProxyState` (haptic -> sim, a few hundred Hz): the proxy and the device.

Decoding validates everything the haptic loop will trust (sizes, finite values, D symmetric
positive definite, unit normals, magnitudes within `MessageLimits`) and raises
`MessageError` with the reason; the receiver counts and logs it and keeps running.
"""

from __future__ import annotations

import struct
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from shared.kinematics import MAX_DOF
from shared.wire import LIMIT_FIELDS, PROTOCOL_VERSION, REASONS, UpdateParser

UPDATE_MAGIC = b"HLMU"
PROXY_MAGIC = b"HPXY"

# magic, version, flags, epoch, seq, sim_time, publish_time_ns, dof, n_contacts, n_resisted,
# op_link, characteristic_length, state_lead_s
_UPDATE_HEADER = struct.Struct("<4sHHQQdqHHHHdd")
# magic, version, flags, epoch, update_seq, tick, haptic_time, publish_time_ns, dof, method
_PROXY_HEADER = struct.Struct("<4sHHQQQdqHH")

UPDATE_HAS_GRAVITY = 1
UPDATE_HAS_RESISTED = 2
UPDATE_TOOL_TOUCHING = 4
UPDATE_HAS_VELOCITY_TORQUE = 8

PROXY_SAFE_STATE = 1
PROXY_VALID = 2  # the haptic side has installed a model of this epoch

# Per-contact float fields, in wire order (see docs/protocol.md).
CONTACT_FLOAT_FIELDS = (
    "tool_point_x", "tool_point_y", "env_point_x", "env_point_y", "normal_x", "normal_y",
    "env_velocity_x", "env_velocity_y", "friction", "restitution", "stiffness", "damping",
)  # fmt: skip
_NCF = len(CONTACT_FLOAT_FIELDS)


class MessageError(ValueError):
    """A received message is malformed or out of bounds; `reason` is a short stable tag."""

    def __init__(self, reason: str, detail: str) -> None:
        self.reason = reason
        super().__init__(f"{reason}: {detail}")


@dataclass(frozen=True)
class MessageLimits:
    """Bounds on what a sane update may contain; anything beyond is rejected."""

    max_abs_position_m: float = 100.0
    max_abs_angle_rad: float = 1.0e4
    max_abs_velocity: float = 100.0
    max_mass_entry: float = 1.0e6
    min_mass_eigenvalue: float = 1.0e-12
    max_stiffness_n_per_m: float = 1.0e8
    max_damping_ns_per_m: float = 1.0e6
    max_friction: float = 10.0
    symmetry_tolerance: float = 1.0e-9  # relative
    max_abs_generalized_force: float = 1.0e4  # N or N m: gravity and velocity-product torques
    max_inverse_mass: float = 1.0e9  # entries of Lambda^-1 (1/kg, 1/(kg m), 1/(kg m^2))


DEFAULT_LIMITS = MessageLimits()


@dataclass(frozen=True, eq=False)
class ContactSet:
    """Local contact geometry (DESIGN §3): one row per contact of a tool link with the world."""

    link: np.ndarray  # (n,) int64 tool link index
    key: np.ndarray  # (n,) int64 identity that persists across updates for the same feature pair
    floats: np.ndarray  # (n, 12) float64 in CONTACT_FLOAT_FIELDS order

    @property
    def count(self) -> int:
        return int(self.link.shape[0])

    @staticmethod
    def empty() -> ContactSet:
        return ContactSet(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, _NCF)))


@dataclass(frozen=True, eq=False)
class LocalModelUpdate:
    """What the sim publishes each step about its tool (DESIGN §3)."""

    epoch: int
    seq: int
    sim_time: float
    publish_time_ns: int
    joint_types: np.ndarray  # (d,) int64
    lengths: np.ndarray  # (d,)
    base: np.ndarray  # (2,)
    base_angle: float
    op_link: int
    op_point: np.ndarray  # (2,) in the frame of op_link
    q: np.ndarray  # (d,) tool configuration at the sim
    qd: np.ndarray  # (d,)
    mass_matrix: np.ndarray  # (d, d) D(q)
    lambda_inv: np.ndarray  # (3, 3) J_h D^-1 J_h^T
    tool_pose: np.ndarray  # (3,) operational point pose at the sim
    gravity: np.ndarray | None  # (d,) G(q), None when g = 0
    velocity_torque: np.ndarray | None  # (d,) C(q, qd) qd, None for a free body (D constant)
    resisted: np.ndarray | None  # (j, 3) unit directions in the scaled space, None when j = 0
    characteristic_length: float
    contacts: ContactSet
    tool_touching: bool
    # how far ahead of its publication the state holds (s): the sim steps its world over the
    # coming period, so moving contacts are extrapolated back by this much at install
    state_lead_s: float = 0.0

    @property
    def dof(self) -> int:
        return int(self.q.shape[0])


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


# --- LocalModelUpdate ------------------------------------------------------------------------


def encode_update(u: LocalModelUpdate) -> bytes:
    d = u.dof
    n = u.contacts.count
    flags = 0
    if u.gravity is not None:
        flags |= UPDATE_HAS_GRAVITY
    if u.resisted is not None and len(u.resisted) > 0:
        flags |= UPDATE_HAS_RESISTED
    if u.tool_touching:
        flags |= UPDATE_TOOL_TOUCHING
    if u.velocity_torque is not None:
        flags |= UPDATE_HAS_VELOCITY_TORQUE
    j = 0 if u.resisted is None else len(u.resisted)
    header = _UPDATE_HEADER.pack(
        UPDATE_MAGIC, PROTOCOL_VERSION, flags, u.epoch, u.seq, u.sim_time, u.publish_time_ns,
        d, n, j, u.op_link, u.characteristic_length, u.state_lead_s,
    )  # fmt: skip
    ints = np.concatenate([u.joint_types, u.contacts.link, u.contacts.key]).astype("<i8")
    parts = [
        u.lengths, u.base, [u.base_angle], u.op_point, u.q, u.qd, u.mass_matrix.ravel(),
        u.lambda_inv.ravel(), u.tool_pose,
    ]  # fmt: skip
    if u.gravity is not None:
        parts.append(u.gravity)
    if u.velocity_torque is not None:
        parts.append(u.velocity_torque)
    if j:
        assert u.resisted is not None
        parts.append(u.resisted.ravel())
    parts.append(u.contacts.floats.ravel())
    floats = np.concatenate([np.asarray(p, dtype=np.float64).ravel() for p in parts]).astype("<f8")
    return header + ints.tobytes() + floats.tobytes()


def limits_array(limits: MessageLimits) -> np.ndarray:
    """MessageLimits as the float array parse_update takes (order: wire.LIMIT_FIELDS)."""
    return np.array([getattr(limits, name) for name in LIMIT_FIELDS], dtype=np.float64)


_DEFAULT_PARSER: UpdateParser | None = None


def decode_update(data: bytes, limits: MessageLimits = DEFAULT_LIMITS) -> LocalModelUpdate:
    """Parse and validate an update; raises MessageError naming what is wrong.

    The checks are those of `shared.wire.parse_update`, the decoder the haptic loop uses.
    """
    global _DEFAULT_PARSER
    if limits is DEFAULT_LIMITS:
        if _DEFAULT_PARSER is None:
            _DEFAULT_PARSER = UpdateParser(limits_array(DEFAULT_LIMITS))
        parser = _DEFAULT_PARSER
    else:
        parser = UpdateParser(limits_array(limits))
    code = parser.parse(data)
    if code != 0:
        raise MessageError(REASONS[code], f"rejected update of {len(data)} bytes")
    return update_from_record(parser.out[0])


def update_from_record(m: np.void) -> LocalModelUpdate:
    """The dataclass view of a parsed LOCAL_MODEL_DTYPE record (copies)."""
    d = int(m["dof"])
    n = int(m["n_contacts"])
    j = int(m["n_resisted"])
    floats = np.zeros((n, _NCF))
    if n:
        floats[:, 0:2] = m["c_tool"][:n]
        floats[:, 2:4] = m["c_env"][:n]
        floats[:, 4:6] = m["c_normal"][:n]
        floats[:, 6:8] = m["c_env_velocity"][:n]
        floats[:, 8] = m["c_friction"][:n]
        floats[:, 9] = m["c_restitution"][:n]
        floats[:, 10] = m["c_stiffness"][:n]
        floats[:, 11] = m["c_damping"][:n]
    return LocalModelUpdate(
        epoch=int(m["epoch"]), seq=int(m["seq"]), sim_time=float(m["sim_time"]),
        publish_time_ns=int(m["publish_time_ns"]), joint_types=m["joint_types"][:d].copy(),
        lengths=m["lengths"][:d].copy(), base=m["base"].copy(), base_angle=float(m["base_angle"]),
        op_link=int(m["op_link"]), op_point=m["op_point"].copy(), q=m["q"][:d].copy(),
        qd=m["qd"][:d].copy(), mass_matrix=m["mass"][:d, :d].copy(),
        lambda_inv=m["lambda_inv"].copy(), tool_pose=m["tool_pose"].copy(),
        gravity=m["gravity"][:d].copy() if m["has_gravity"] else None,
        velocity_torque=m["velocity_torque"][:d].copy() if m["has_velocity_torque"] else None,
        resisted=m["resisted"][:j].copy() if j else None,
        characteristic_length=float(m["characteristic_length"]),
        contacts=ContactSet(m["c_link"][:n].copy(), m["c_key"][:n].copy(), floats),
        tool_touching=bool(m["tool_touching"]),
        state_lead_s=float(m["state_lead_s"]),
    )  # fmt: skip


# --- ProxyState ------------------------------------------------------------------------------


def encode_proxy(p: ProxyState) -> bytes:
    d = int(p.q.shape[0])
    flags = (PROXY_SAFE_STATE if p.safe_state else 0) | (PROXY_VALID if p.valid else 0)
    header = _PROXY_HEADER.pack(
        PROXY_MAGIC, PROTOCOL_VERSION, flags, p.epoch, p.update_seq, p.tick, p.haptic_time,
        p.publish_time_ns, d, p.method,
    )  # fmt: skip
    body = np.concatenate([p.q, p.qd, p.device_pose, p.device_twist]).astype("<f8")
    return header + body.tobytes()


class ProxyEncoder:
    """encode_proxy into a preallocated buffer, straight from the engine (the 1 kHz path)."""

    def __init__(self) -> None:
        self._buf = np.zeros(_PROXY_HEADER.size + 8 * (2 * MAX_DOF + 6), np.uint8)
        _PROXY_HEADER.pack_into(
            self._buf.data, 0, PROXY_MAGIC, PROTOCOL_VERSION, 0, 0, 0, 0, 0.0, 0, 0, 0
        )

    def encode(self, engine: Any, safe: bool) -> bytes:
        """The ProxyState of a HapticEngine: proxy q, qd and the measured device pose (world)."""
        flags = (PROXY_SAFE_STATE if safe else 0) | (PROXY_VALID if engine.ready else 0)
        n = _encode_proxy_body(
            self._buf, flags, engine.epoch, engine.last_seq, engine.tick_index, engine.time,
            time.time_ns(), engine.method, engine.slots, engine.state, engine.world_sensors,
        )  # fmt: skip
        return self._buf[:n].tobytes()

    def encode_row(self, row: np.ndarray, method: int) -> bytes:
        """The ProxyState of a logged tick (TICK_DTYPE[1]): what the I/O process publishes."""
        r = row[0]
        d = int(r["dof"])
        flags = (PROXY_SAFE_STATE if r["safe"] > 0.0 else 0) | PROXY_VALID
        _PROXY_HEADER.pack_into(
            self._buf.data, 0, PROXY_MAGIC, PROTOCOL_VERSION, flags, int(r["update_epoch"]),
            int(r["update_seq"]), int(r["tick"]), float(r["t"]), time.time_ns(), d, method,
        )  # fmt: skip
        n = _PROXY_HEADER.size + 8 * (2 * d + 6)
        body = self._buf[_PROXY_HEADER.size : n].view("<f8")
        body[:d] = r["proxy_q"][:d]
        body[d : 2 * d] = r["proxy_qd"][:d]
        body[2 * d : 2 * d + 3] = r["device_pose"]
        body[2 * d + 3 :] = r["device_twist"]
        return self._buf[:n].tobytes()


@njit(cache=True)
def _encode_proxy_body(buf, flags, epoch, seq, tick, t, pub_ns, method, slots, state, sensors):
    """Fill the ProxyState fields after the constant magic and version; returns its size."""
    d = slots[0].dof
    buf[6] = flags & 0xFF
    buf[7] = (flags >> 8) & 0xFF
    head = buf[8:40].view(np.int64)
    head[0] = epoch
    head[1] = seq
    head[2] = tick
    buf[32:40].view(np.float64)[0] = t
    buf[40:48].view(np.int64)[0] = pub_ns
    buf[48] = d & 0xFF
    buf[49] = (d >> 8) & 0xFF
    buf[50] = method & 0xFF
    buf[51] = (method >> 8) & 0xFF
    body = buf[52 : 52 + 8 * (2 * d + 6)].view(np.float64)
    st = state[0]
    for k in range(d):
        body[k] = st.q[k]
        body[d + k] = st.qd[k]
    for c in range(3):
        body[2 * d + c] = sensors[0].pose[c]
        body[2 * d + 3 + c] = sensors[0].twist[c]
    return 52 + 8 * (2 * d + 6)


def decode_proxy(data: bytes, limits: MessageLimits = DEFAULT_LIMITS) -> ProxyState:
    if len(data) < _PROXY_HEADER.size:
        raise MessageError("short", f"{len(data)} bytes is shorter than the header")
    magic, version, flags, epoch, useq, tick, htime, pub_ns, d, method = _PROXY_HEADER.unpack_from(
        data, 0
    )
    if magic != PROXY_MAGIC:
        raise MessageError("magic", f"expected {PROXY_MAGIC!r}, got {magic!r}")
    if version != PROTOCOL_VERSION:
        raise MessageError("version", f"protocol {version}, this build speaks {PROTOCOL_VERSION}")
    if not 0 <= d <= MAX_DOF:
        raise MessageError("dof", f"dof {d} outside [0, {MAX_DOF}]")
    expected = _PROXY_HEADER.size + 8 * (2 * d + 6)
    if len(data) != expected:
        raise MessageError("size", f"{len(data)} bytes, expected {expected}")
    v = np.frombuffer(data, "<f8", 2 * d + 6, _PROXY_HEADER.size).astype(np.float64)
    if not np.isfinite(v).all() or not np.isfinite(htime):
        raise MessageError("nonfinite", "NaN or Inf in the payload")
    if np.abs(v).max(initial=0.0) > max(limits.max_abs_position_m, limits.max_abs_angle_rad):
        raise MessageError("magnitude", "proxy state out of bounds")
    return ProxyState(
        epoch=epoch, update_seq=useq, tick=tick, haptic_time=htime, publish_time_ns=pub_ns,
        method=method, safe_state=bool(flags & PROXY_SAFE_STATE), valid=bool(flags & PROXY_VALID),
        q=v[:d], qd=v[d : 2 * d], device_pose=v[2 * d : 2 * d + 3], device_twist=v[2 * d + 3 :],
    )  # fmt: skip

"""The local-model update: its dataclass view, the encoder, and the validating parser.

`parse_update` is the one boundary that turns an update's bytes into the record the haptic
kernels trust (a numba kernel: a few microseconds where the same checks in numpy cost
hundreds). It validates sizes, finite values, D symmetric positive definite, unit normals
and magnitudes within the limits record, and returns 0 or a `Reason` code; `decode_update`
wraps it for tools and raises `MessageError`. Layout: `shared.protocol.layout`.
"""

from __future__ import annotations

import functools
import math
import operator
import struct
from dataclasses import dataclass

import numpy as np
from numba import njit

from haptic_local_model.shared.kinematics import (
    CHAIN_AVAR,
    CHAIN_TOOL,
    MAX_CHAINS,
    MAX_PORTS,
    PRISMATIC_Y,
    REVOLUTE,
)
from haptic_local_model.shared.linalg import cholesky_inplace
from haptic_local_model.shared.protocol.codes import Flag, Reason
from haptic_local_model.shared.protocol.layout import (
    AVAR_WORDS,
    C_DAMPING,
    C_ENV,
    C_ENV_VELOCITY,
    C_FRICTION,
    C_NORMAL,
    C_RESTITUTION,
    C_STIFFNESS,
    C_TANGENTIAL_STIFFNESS,
    C_TOOL,
    CHAIN_INTS,
    CONTACT_COLUMNS,
    CONTACT_FLOATS,
    CONTACT_FLOATS_V1,
    CONTACT_ROW_DTYPE,
    DEFAULT_LIMITS,
    FIXED_FLOATS,
    FLOAT_SECTIONS,
    HEADER_AT,
    HEADER_BYTES,
    HEADER_STRUCT,
    INT_SECTIONS,
    LOCAL_MODEL_DTYPE,
    MAX_CONTACTS,
    MAX_DOF,
    MAX_RESISTED,
    PROTOCOL_VERSION,
    PUBLISH_TIME_AT,
    PUBLISH_TIME_END,
    S_FRICTION,
    S_POSE,
    S_ROUNDING,
    S_STATIC_FRICTION,
    S_TWIST,
    S_VERTICES,
    SHAPE_FLOATS,
    SHAPE_INTS,
    UPDATE_MAGIC,
    MessageLimits,
    body_counts,
    chains_words,
    limits_record,
    shapes_words,
)
from haptic_local_model.shared.shapes import MAX_SHAPES, MAX_VERTICES, MIN_EDGE_M, Motion, ShapeKind

MAGIC = tuple(UPDATE_MAGIC)
#: The largest valid update: every section, 64 contacts and 64 shapes (receive buffers)
MAX_UPDATE_BYTES = HEADER_BYTES + 8 * (
    3 * MAX_DOF + MAX_DOF * MAX_DOF + 2 * MAX_CONTACTS + 64 + 3 * MAX_RESISTED
    + CONTACT_FLOATS * MAX_CONTACTS + shapes_words(MAX_SHAPES) + MAX_DOF * 4
    + chains_words(MAX_DOF, MAX_CHAINS) + AVAR_WORDS
)  # fmt: skip
# numba reads IntEnum members but not IntFlag ones: the flags as plain ints for the kernels
FLAG_GRAVITY = int(Flag.GRAVITY)
FLAG_RESISTED = int(Flag.RESISTED)
FLAG_TOUCHING = int(Flag.TOUCHING)
FLAG_VELOCITY_TORQUE = int(Flag.VELOCITY_TORQUE)
FLAG_SHAPES = int(Flag.SHAPES)
FLAG_CHAINS = int(Flag.CHAINS)
FLAG_AVARS = int(Flag.AVARS)
MAX_TRAIN_CARS = 8  # shared.avar.MAX_CARS (the protocol does not import the dynamics)
TRAILERS = FLAG_SHAPES | FLAG_CHAINS | FLAG_AVARS
KNOWN_FLAGS = int(functools.reduce(operator.or_, Flag))  # any other bit is refused (`flags`)
AT_VERSION = HEADER_AT["version"]
AT_FLAGS = HEADER_AT["flags"]
AT_EPOCH = HEADER_AT["epoch"]
AT_SEQ = HEADER_AT["seq"]
AT_SIM_TIME = HEADER_AT["sim_time"]
AT_DOF = HEADER_AT["dof"]
AT_N_CONTACTS = HEADER_AT["n_contacts"]
AT_N_RESISTED = HEADER_AT["n_resisted"]
AT_OP_LINK = HEADER_AT["op_link"]
AT_CHAR_LENGTH = HEADER_AT["characteristic_length"]
AT_LEAD = HEADER_AT["state_lead_s"]


class MessageError(ValueError):
    """A received message is malformed or out of bounds; `reason` is a short stable tag."""

    def __init__(self, reason: str, detail: str) -> None:
        self.reason = reason
        super().__init__(f"{reason}: {detail}")


@dataclass(frozen=True, eq=False)
class ContactSet:
    """Local contact geometry (DESIGN §3): one row per contact of a tool link with the world."""

    link: np.ndarray  # (n,) int64 tool link index
    key: np.ndarray  # (n,) int64 identity that persists across updates for the same feature pair
    floats: np.ndarray  # (n, CONTACT_FLOATS) float64, columns as in layout.CONTACT_COLUMNS

    @property
    def count(self) -> int:
        return int(self.link.shape[0])

    @property
    def rows(self) -> np.ndarray:
        """The rows as CONTACT_ROW_DTYPE (a view): columns by name."""
        return np.ascontiguousarray(self.floats).view(CONTACT_ROW_DTYPE).reshape(self.count)

    @staticmethod
    def empty() -> ContactSet:
        return ContactSet(np.zeros(0, np.int64), np.zeros(0, np.int64), contact_rows(0)[1])


def contact_rows(n: int) -> tuple[np.ndarray, np.ndarray]:
    """n zeroed contact rows: (CONTACT_ROW_DTYPE view by column name, (n, CONTACT_FLOATS)
    float view of the same memory)."""
    floats = np.zeros((n, CONTACT_FLOATS))
    return floats.view(CONTACT_ROW_DTYPE).reshape(n), floats


@dataclass(frozen=True, eq=False)
class ChainTable:
    """The joints' tree and the chains of the configuration (DESIGN-WAVE2 C1; Flag.CHAINS):
    joint i hangs from link parents[i] (-1: its chain's base), chain k covers the joints from
    first[k], of kind (shared.kinematics.CHAIN_*) and device port (-1 none), based at
    bases[k - 1] (chain 0 at the update's base and base_angle)."""

    parents: np.ndarray  # (d,) int64
    first: np.ndarray  # (c,) int64
    kind: np.ndarray  # (c,) int64
    port: np.ndarray  # (c,) int64
    bases: np.ndarray  # (c - 1, 3) x, y, angle

    def trailer(self) -> bytes:
        """The CHAINS trailer (layout.CHAIN_INT_FIELDS)."""
        c = len(self.first)
        ints = np.column_stack([self.first, self.kind, self.port]).astype("<i8")
        head = np.concatenate([[c], self.parents]).astype("<i8").tobytes()
        return head + ints.tobytes() + np.asarray(self.bases, "<f8").reshape(c - 1, 3).tobytes()


@dataclass(frozen=True)
class AvarState:
    """A train's animation variable (DESIGN-WAVE2 §5; Flag.AVARS): its track and train by
    static id, the number of cars (shape owners), the lead car's arc length and rate."""

    static_id: int
    cars: int
    s: float
    sd: float

    def trailer(self) -> bytes:
        """The AVARS trailer (layout.AVAR_FIELDS)."""
        return struct.pack("<qqdd", self.static_id, self.cars, self.s, self.sd)


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
    # the local shapes near the tool (SHAPE_DTYPE rows; version 3), None: no SHAPES trailer
    shapes: np.ndarray | None = None
    # the tree and chains (version 3), None: one serial chain, no CHAINS trailer
    chains: ChainTable | None = None
    # a train's animation variable (version 3), None: no AVARS trailer
    avars: AvarState | None = None

    @property
    def dof(self) -> int:
        return int(self.q.shape[0])

    @property
    def flags(self) -> int:
        flags = 0
        if self.gravity is not None:
            flags |= Flag.GRAVITY
        if self.resisted is not None and len(self.resisted) > 0:
            flags |= Flag.RESISTED
        if self.tool_touching:
            flags |= Flag.TOUCHING
        if self.velocity_torque is not None:
            flags |= Flag.VELOCITY_TORQUE
        if self.shapes is not None and len(self.shapes) > 0:
            flags |= Flag.SHAPES
        if self.chains is not None:
            flags |= Flag.CHAINS
        if self.avars is not None:
            flags |= Flag.AVARS
        return int(flags)


def encode_update(u: LocalModelUpdate) -> bytes:
    """The update's bytes: the header, then the sections of layout.INT_SECTIONS and
    layout.FLOAT_SECTIONS in order (the flagged ones when present)."""
    d = u.dof
    n = u.contacts.count
    j = 0 if u.resisted is None else len(u.resisted)
    header = HEADER_STRUCT.pack(
        UPDATE_MAGIC, PROTOCOL_VERSION, u.flags, u.epoch, u.seq, u.sim_time, u.publish_time_ns,
        d, n, j, u.op_link, u.characteristic_length, u.state_lead_s,
    )  # fmt: skip
    sections = {
        "joint_types": u.joint_types, "contact_link": u.contacts.link,
        "contact_key": u.contacts.key, "lengths": u.lengths, "base": u.base,
        "base_angle": [u.base_angle], "op_point": u.op_point, "q": u.q, "qd": u.qd,
        "mass": u.mass_matrix, "lambda_inv": u.lambda_inv, "tool_pose": u.tool_pose,
        "gravity": u.gravity, "velocity_torque": u.velocity_torque,
        "resisted": u.resisted if j else None, "contacts": u.contacts.floats,
    }  # fmt: skip
    ints = [np.asarray(sections[s.name]).ravel() for s in INT_SECTIONS]
    floats = [
        np.asarray(sections[s.name], dtype=np.float64).ravel()
        for s in FLOAT_SECTIONS
        if sections[s.name] is not None
    ]
    return (
        header
        + np.concatenate(ints).astype("<i8").tobytes()
        + np.concatenate(floats).astype("<f8").tobytes()
        + (u.chains.trailer() if u.chains is not None else b"")
        + (u.avars.trailer() if u.avars is not None else b"")
        + (shapes_trailer(u.shapes) if u.shapes is not None and u.flags & Flag.SHAPES else b"")
    )


def shapes_trailer(shapes: np.ndarray) -> bytes:
    """The SHAPES trailer of SHAPE_DTYPE rows (layout.SHAPE_INT_FIELDS, SHAPE_FLOAT_FIELDS)."""
    n = len(shapes)
    ints = np.zeros((n, SHAPE_INTS), np.int64)
    floats = np.zeros((n, SHAPE_FLOATS))
    for k, row in enumerate(shapes):
        owner = row["owner"] if row["motion"] == Motion.TRACK else -1
        ints[k] = (row["key"], owner, row["kind"], row["n_vert"], row["generation"], row["motion"])
        floats[k, S_VERTICES : S_VERTICES + 2 * MAX_VERTICES] = row["vertices"].ravel()
        floats[k, S_ROUNDING] = row["rounding"]
        floats[k, S_POSE : S_POSE + 3] = row["pose"]
        floats[k, S_TWIST : S_TWIST + 3] = row["twist"]
        floats[k, S_STATIC_FRICTION] = row["static_friction"]
        floats[k, S_FRICTION] = row["friction"]
    head = np.array([n], "<i8").tobytes()
    return head + ints.astype("<i8").tobytes() + floats.astype("<f8").tobytes()


def stamp_publication(raw: bytearray, publish_time_ns: int, state_lead_s: float) -> None:
    """Write the publish time and the state lead into an encoded update's header, in place:
    the sim stamps them at `put`, after building and encoding the update, so the age a
    haptic server measures is the message's transit and wait, not the sim's own work."""
    struct.pack_into("<q", raw, PUBLISH_TIME_AT, publish_time_ns)
    struct.pack_into("<d", raw, AT_LEAD, state_lead_s)


# --- the compiled encoder (the sim's) -------------------------------------------------------


@njit(cache=True, inline="always")
def _put_u16(buf, o, v):
    buf[o] = v & 0xFF
    buf[o + 1] = (v >> 8) & 0xFF


@njit(cache=True, inline="always")
def _put_i64(buf, o, v):
    buf[o : o + 8].view(np.int64)[0] = v


@njit(cache=True, inline="always")
def _put_f64(buf, o, v):
    buf[o : o + 8].view(np.float64)[0] = v


@njit(cache=True)
def encode_record(out, buf):
    """The update of the local model in `out` (LOCAL_MODEL_DTYPE[1], as the sim fills it)
    into `buf` (uint8, 8-byte aligned, long enough); returns its size in bytes. The same
    bytes as `encode_update` of its dataclass view, written in `parse_update`'s order."""
    m = out[0]
    d, n, j = m.dof, m.n_contacts, m.n_resisted
    flags = 0
    if m.has_gravity == 1:
        flags |= FLAG_GRAVITY
    if j > 0:
        flags |= FLAG_RESISTED
    if m.tool_touching == 1:
        flags |= FLAG_TOUCHING
    if m.has_velocity_torque == 1:
        flags |= FLAG_VELOCITY_TORQUE
    if m.n_shapes > 0:
        flags |= FLAG_SHAPES
    if m.has_chains == 1:
        flags |= FLAG_CHAINS
    if m.has_avars == 1:
        flags |= FLAG_AVARS
    n_int = d + 2 * n
    body_end = HEADER_BYTES + 8 * (n_int + _float_count(d, j, n, flags, CONTACT_FLOATS))
    nbytes = body_end
    if (flags & FLAG_CHAINS) != 0:
        nbytes += 8 * _chains_words(d, m.n_chains)
    chains_end = nbytes
    if (flags & FLAG_AVARS) != 0:
        nbytes += 8 * AVAR_WORDS
    avars_end = nbytes
    if m.n_shapes > 0:
        nbytes += 8 * (1 + (SHAPE_INTS + SHAPE_FLOATS) * m.n_shapes)
    for i in range(4):
        buf[i] = MAGIC[i]
    _put_u16(buf, AT_VERSION, PROTOCOL_VERSION)
    _put_u16(buf, AT_FLAGS, flags)
    _put_i64(buf, AT_EPOCH, m.epoch)
    _put_i64(buf, AT_SEQ, m.seq)
    _put_f64(buf, AT_SIM_TIME, m.sim_time)
    _put_i64(buf, PUBLISH_TIME_AT, m.publish_time_ns)
    _put_u16(buf, AT_DOF, d)
    _put_u16(buf, AT_N_CONTACTS, n)
    _put_u16(buf, AT_N_RESISTED, j)
    _put_u16(buf, AT_OP_LINK, m.op_link)
    _put_f64(buf, AT_CHAR_LENGTH, m.characteristic_length)
    _put_f64(buf, AT_LEAD, m.state_lead_s)
    ints = buf[HEADER_BYTES : HEADER_BYTES + 8 * n_int].view(np.int64)
    for k in range(d):
        ints[k] = m.joint_types[k]
    for i in range(n):
        ints[d + i] = m.c_link[i]
        ints[d + n + i] = m.c_key[i]
    fl = buf[HEADER_BYTES + 8 * n_int : body_end].view(np.float64)
    o = _write_body(m, fl, flags)
    for i in range(n):
        row = fl[o + CONTACT_FLOATS * i : o + CONTACT_FLOATS * (i + 1)]
        for c in range(2):
            row[C_TOOL + c] = m.c_tool[i, c]
            row[C_ENV + c] = m.c_env[i, c]
            row[C_NORMAL + c] = m.c_normal[i, c]
            row[C_ENV_VELOCITY + c] = m.c_env_velocity[i, c]
        row[C_FRICTION] = m.c_friction[i]
        row[C_RESTITUTION] = m.c_restitution[i]
        row[C_STIFFNESS] = m.c_stiffness[i]
        row[C_DAMPING] = m.c_damping[i]
        row[C_TANGENTIAL_STIFFNESS] = m.c_tangential_stiffness[i]
    if (flags & FLAG_CHAINS) != 0:
        _write_chains(m, buf[body_end:chains_end])
    if (flags & FLAG_AVARS) != 0:
        ints = buf[chains_end : chains_end + 16].view(np.int64)
        ints[0] = m.avar_static_id
        ints[1] = m.avar_cars
        fl = buf[chains_end + 16 : avars_end].view(np.float64)
        fl[0] = m.avar_s
        fl[1] = m.avar_sd
    if m.n_shapes > 0:
        _write_shapes(m, buf[avars_end:nbytes])
    return nbytes


@njit(cache=True, inline="always")
def _chains_words(d, c):
    """layout.chains_words, compiled."""
    return 1 + d + CHAIN_INTS * c + 3 * (c - 1)


@njit(cache=True)
def _write_chains(m, trailer):
    """`_read_chains` the other way: the CHAINS trailer of the record's tree and chains."""
    d, c = m.dof, m.n_chains
    ints = trailer[: 8 * (1 + d + CHAIN_INTS * c)].view(np.int64)
    ints[0] = c
    for i in range(d):
        ints[1 + i] = m.parents[i]
    for k in range(c):
        ints[1 + d + CHAIN_INTS * k] = m.chain_first[k]
        ints[2 + d + CHAIN_INTS * k] = m.chain_kind[k]
        ints[3 + d + CHAIN_INTS * k] = m.chain_port[k]
    fl = trailer[8 * (1 + d + CHAIN_INTS * c) :].view(np.float64)
    for k in range(1, c):
        for a in range(3):
            fl[3 * (k - 1) + a] = m.chain_base[k, a]


@njit(cache=True)
def _write_shapes(m, trailer):
    """`_read_shapes` the other way: the SHAPES trailer of the record's shapes."""
    s = m.n_shapes
    ints = trailer.view(np.int64)
    ints[0] = s
    fl = trailer[8 * (1 + SHAPE_INTS * s) :].view(np.float64)
    for k in range(s):
        sh = m.shapes[k]
        row = ints[1 + SHAPE_INTS * k : 1 + SHAPE_INTS * (k + 1)]
        row[0] = sh.key
        row[1] = sh.owner if sh.motion == Motion.TRACK else -1
        row[2] = sh.kind
        row[3] = sh.n_vert
        row[4] = sh.generation
        row[5] = sh.motion
        f = fl[SHAPE_FLOATS * k : SHAPE_FLOATS * (k + 1)]
        for v in range(MAX_VERTICES):
            f[S_VERTICES + 2 * v] = sh.vertices[v, 0]
            f[S_VERTICES + 2 * v + 1] = sh.vertices[v, 1]
        f[S_ROUNDING] = sh.rounding
        for c in range(3):
            f[S_POSE + c] = sh.pose[c]
            f[S_TWIST + c] = sh.twist[c]
        f[S_STATIC_FRICTION] = sh.static_friction
        f[S_FRICTION] = sh.friction


@njit(cache=True, inline="always")
def _write_body(m, fl, flags):
    """`_read_body` the other way: the float sections; returns the contact rows' offset."""
    d = m.dof
    o = 0
    for k in range(d):
        fl[o + k] = m.lengths[k]
    o += d
    fl[o], fl[o + 1], fl[o + 2] = m.base[0], m.base[1], m.base_angle
    fl[o + 3], fl[o + 4] = m.op_point[0], m.op_point[1]
    o += 5
    for k in range(d):
        fl[o + k] = m.q[k]
        fl[o + d + k] = m.qd[k]
    o += 2 * d
    for a in range(d):
        for b in range(d):
            fl[o + a * d + b] = m.mass[a, b]
    o += d * d
    for a in range(3):
        for b in range(3):
            fl[o + a * 3 + b] = m.lambda_inv[a, b]
    o += 9
    for c in range(3):
        fl[o + c] = m.tool_pose[c]
    o += 3
    if (flags & FLAG_GRAVITY) != 0:
        for k in range(d):
            fl[o + k] = m.gravity[k]
        o += d
    if (flags & FLAG_VELOCITY_TORQUE) != 0:
        for k in range(d):
            fl[o + k] = m.velocity_torque[k]
        o += d
    for r in range(m.n_resisted):
        for c in range(3):
            fl[o + 3 * r + c] = m.resisted[r, c]
    o += 3 * m.n_resisted
    return o


# --- the parser ------------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _u16(buf, o):
    return np.int64(buf[o]) | (np.int64(buf[o + 1]) << 8)


@njit(cache=True, inline="always")
def _f64(buf, o):
    return buf[o : o + 8].view(np.float64)[0]


@njit(cache=True, inline="always")
def _i64(buf, o):
    return buf[o : o + 8].view(np.int64)[0]


@njit(cache=True)
def publish_time_ns(buf):
    """The header's publish time of the update in `buf` (8-byte aligned, at least
    PUBLISH_TIME_END bytes long)."""
    return _i64(buf, PUBLISH_TIME_AT)


@njit(cache=True)
def epoch_of(buf, nbytes):
    """The header's epoch of the update in `buf`, or -1 if it is too short to have one."""
    if nbytes < AT_EPOCH + 8:
        return np.int64(-1)
    return _i64(buf, AT_EPOCH)


@njit(cache=True, inline="always")
def _check_header(buf, nbytes):
    """Magic, version, counts and total size: (Reason or 0, d, n, j, flags, contact row
    floats, shapes, chains (0: no CHAINS trailer))."""
    code, d, n, j, flags, n_cf, body_end = _check_body(buf, nbytes)
    if code != 0 or (flags & TRAILERS) == 0:
        return code, d, n, j, flags, n_cf, 0, 0
    if _u16(buf, AT_VERSION) < 3:
        return Reason.VERSION, d, n, j, flags, n_cf, 0, 0
    if nbytes < body_end + 8 or (nbytes - body_end) % 8 != 0:
        return Reason.SIZE, d, n, j, flags, n_cf, 0, 0
    end = body_end
    c = 0
    if (flags & FLAG_CHAINS) != 0:
        c = _i64(buf, end)
        if c < 1 or c > MAX_CHAINS:
            return Reason.CHAIN, d, n, j, flags, n_cf, 0, 0
        end += 8 * _chains_words(d, c)
    if (flags & FLAG_AVARS) != 0:
        end += 8 * AVAR_WORDS
    if (flags & FLAG_SHAPES) == 0:
        if nbytes != end:
            return Reason.SIZE, d, n, j, flags, n_cf, 0, c
        return 0, d, n, j, flags, n_cf, 0, c
    if nbytes < end + 8:
        return Reason.SIZE, d, n, j, flags, n_cf, 0, c
    s = _i64(buf, end)
    if s < 1 or s > MAX_SHAPES:
        return Reason.SHAPE, d, n, j, flags, n_cf, 0, c
    if nbytes != end + 8 * (1 + (SHAPE_INTS + SHAPE_FLOATS) * s):
        return Reason.SIZE, d, n, j, flags, n_cf, 0, c
    return 0, d, n, j, flags, n_cf, s, c


@njit(cache=True, inline="always")
def _check_body(buf, nbytes):
    """The header's magic, version and counts: (Reason or 0, d, n, j, flags, contact row
    floats, end of the body in bytes); an update without trailers ends there."""
    if nbytes < HEADER_BYTES:
        return Reason.SHORT, 0, 0, 0, 0, 0, 0
    for i in range(4):
        if buf[i] != MAGIC[i]:
            return Reason.MAGIC, 0, 0, 0, 0, 0, 0
    version = _u16(buf, AT_VERSION)
    if version < 1 or version > PROTOCOL_VERSION:  # 1, 2: logs of the last releases
        return Reason.VERSION, 0, 0, 0, 0, 0, 0
    n_cf = CONTACT_FLOATS if version >= 2 else CONTACT_FLOATS_V1
    flags = _u16(buf, AT_FLAGS)
    if (flags & ~KNOWN_FLAGS) != 0:
        return Reason.FLAGS, 0, 0, 0, 0, 0, 0
    d = _u16(buf, AT_DOF)
    n = _u16(buf, AT_N_CONTACTS)
    j = _u16(buf, AT_N_RESISTED)
    if d < 1 or d > MAX_DOF:
        return Reason.DOF, d, n, j, flags, n_cf, 0
    if n > MAX_CONTACTS:
        return Reason.CONTACTS, d, n, j, flags, n_cf, 0
    if j > MAX_RESISTED or (j > 0) != ((flags & FLAG_RESISTED) != 0):
        return Reason.RESISTED, d, n, j, flags, n_cf, 0
    if _u16(buf, AT_OP_LINK) >= d:
        return Reason.OP_LINK, d, n, j, flags, n_cf, 0
    n_int = d + 2 * n
    body_end = HEADER_BYTES + 8 * (n_int + _float_count(d, j, n, flags, n_cf))
    if (flags & TRAILERS) == 0 and nbytes != body_end:
        return Reason.SIZE, d, n, j, flags, n_cf, 0
    return 0, d, n, j, flags, n_cf, body_end


@njit(cache=True, inline="always")
def _float_count(d, j, n, flags, n_cf):
    c, per_d, per_dd = FIXED_FLOATS
    count = c + per_d * d + per_dd * d * d + 3 * j + n_cf * n
    if (flags & FLAG_GRAVITY) != 0:
        count += d
    if (flags & FLAG_VELOCITY_TORQUE) != 0:
        count += d
    return count


@njit(cache=True, inline="always")
def _read_body(m, ints, fl, flags):
    """The sections into the record; returns the float offset of the contact rows."""
    d = m.dof
    o = 0
    for k in range(d):
        m.lengths[k] = fl[o + k]
    o += d
    m.base[0] = fl[o]
    m.base[1] = fl[o + 1]
    m.base_angle = fl[o + 2]
    m.op_point[0] = fl[o + 3]
    m.op_point[1] = fl[o + 4]
    o += 5
    for k in range(d):
        m.q[k] = fl[o + k]
        m.qd[k] = fl[o + d + k]
    o += 2 * d
    for a in range(d):
        for b in range(d):
            m.mass[a, b] = fl[o + a * d + b]
    o += d * d
    for a in range(3):
        for b in range(3):
            m.lambda_inv[a, b] = fl[o + a * 3 + b]
    o += 9
    for c in range(3):
        m.tool_pose[c] = fl[o + c]
    o += 3
    if (flags & FLAG_GRAVITY) != 0:
        for k in range(d):
            m.gravity[k] = fl[o + k]
        o += d
    if (flags & FLAG_VELOCITY_TORQUE) != 0:
        for k in range(d):
            m.velocity_torque[k] = fl[o + k]
        o += d
    for r in range(m.n_resisted):
        for c in range(3):
            m.resisted[r, c] = fl[o + 3 * r + c]
    o += 3 * m.n_resisted
    for k in range(d):
        m.joint_types[k] = ints[k]
    return o


@njit(cache=True, inline="always")
def _check_magnitudes(m, lim):
    """Everything the kernels read is within the limits (finite but absurd values too)."""
    d = m.dof
    max_pos = lim.max_abs_position_m
    max_ang = lim.max_abs_angle_rad
    for k in range(d):
        if abs(m.lengths[k]) > max_pos:
            return Reason.MAGNITUDE
        max_q = max_ang if m.joint_types[k] == 0 else max_pos  # revolute, else prismatic
        if abs(m.q[k]) > max_q or abs(m.qd[k]) > lim.max_abs_velocity:
            return Reason.MAGNITUDE
    if abs(m.base[0]) > max_pos or abs(m.base[1]) > max_pos:
        return Reason.MAGNITUDE
    if abs(m.tool_pose[0]) > max_pos or abs(m.tool_pose[1]) > max_pos:
        return Reason.MAGNITUDE
    if (
        abs(m.tool_pose[2]) > max_ang
        or abs(m.base_angle) > max_ang
        or m.characteristic_length > max_pos
    ):
        return Reason.MAGNITUDE
    if abs(m.op_point[0]) > max_pos or abs(m.op_point[1]) > max_pos:
        return Reason.MAGNITUDE
    max_force = lim.max_abs_generalized_force
    for k in range(d):
        if (m.has_gravity == 1 and abs(m.gravity[k]) > max_force) or (
            m.has_velocity_torque == 1 and abs(m.velocity_torque[k]) > max_force
        ):
            return Reason.MAGNITUDE
    for a in range(3):
        for b in range(3):
            if abs(m.lambda_inv[a, b]) > lim.max_inverse_mass:
                return Reason.MAGNITUDE
    return 0


@njit(cache=True, inline="always")
def _check_mass(m, lim, scratch):
    """D symmetric positive definite and bounded."""
    d = m.dof
    scale = 0.0
    for a in range(d):
        for b in range(d):
            scale = max(scale, abs(m.mass[a, b]))
    if scale > lim.max_mass_entry:
        return Reason.MASS_MATRIX
    for a in range(d):
        for b in range(a + 1, d):
            if abs(m.mass[a, b] - m.mass[b, a]) > lim.symmetry_tolerance * max(scale, 1e-300):
                return Reason.MASS_MATRIX
    if not cholesky_inplace(m.mass, d, scratch):
        return Reason.MASS_MATRIX
    for a in range(d):
        if scratch[a, a] * scratch[a, a] < lim.min_mass_eigenvalue:
            return Reason.MASS_MATRIX
    return 0


@njit(cache=True, inline="always")
def _penalty_projection(m):
    """Resisted directions must be unit vectors; their penalty projection in natural units,
    sum (S n)(S n)^T with S = diag(1, 1, L)."""
    for a in range(3):
        for b in range(3):
            m.penalty_projection[a, b] = 0.0
    for r in range(m.n_resisted):
        norm = math.sqrt(m.resisted[r, 0] ** 2 + m.resisted[r, 1] ** 2 + m.resisted[r, 2] ** 2)
        if abs(norm - 1.0) > 1e-6:
            return Reason.RESISTED
        s0 = m.resisted[r, 0]
        s1 = m.resisted[r, 1]
        s2 = m.resisted[r, 2] * m.characteristic_length
        m.penalty_projection[0, 0] += s0 * s0
        m.penalty_projection[0, 1] += s0 * s1
        m.penalty_projection[0, 2] += s0 * s2
        m.penalty_projection[1, 0] += s1 * s0
        m.penalty_projection[1, 1] += s1 * s1
        m.penalty_projection[1, 2] += s1 * s2
        m.penalty_projection[2, 0] += s2 * s0
        m.penalty_projection[2, 1] += s2 * s1
        m.penalty_projection[2, 2] += s2 * s2
    return 0


@njit(cache=True, inline="always")
def _read_contacts(m, ints, fl, o, n_cf, lim):
    """The contact rows (n_cf floats each) from float offset o, each column checked against
    its bound; a version-1 row has no tangential stiffness: K_t = K_c."""
    d = m.dof
    n = m.n_contacts
    max_pos = lim.max_abs_position_m
    max_vel = lim.max_abs_velocity
    for i in range(n):
        row = fl[o + n_cf * i : o + n_cf * (i + 1)]
        for k in range(4):  # tool and environment points
            if abs(row[k]) > max_pos:
                return Reason.CONTACT
        if abs(math.hypot(row[C_NORMAL], row[C_NORMAL + 1]) - 1.0) > 1e-6:
            return Reason.CONTACT
        if abs(row[C_ENV_VELOCITY]) > max_vel or abs(row[C_ENV_VELOCITY + 1]) > max_vel:
            return Reason.CONTACT
        mu = row[C_FRICTION]
        e = row[C_RESTITUTION]
        kk = row[C_STIFFNESS]
        bb = row[C_DAMPING]
        if mu < 0.0 or mu > lim.max_friction or e < 0.0 or e > 1.0:
            return Reason.CONTACT
        if not (kk > 0.0 and kk <= lim.max_stiffness_n_per_m):
            return Reason.CONTACT
        if bb < 0.0 or bb > lim.max_damping_ns_per_m:
            return Reason.CONTACT
        kt = row[C_TANGENTIAL_STIFFNESS] if n_cf > C_TANGENTIAL_STIFFNESS else kk
        if not (kt >= 0.0 and kt <= lim.max_stiffness_n_per_m):
            return Reason.CONTACT
        m.c_link[i] = ints[d + i]
        m.c_key[i] = ints[d + n + i]
        for c in range(2):
            m.c_tool[i, c] = row[C_TOOL + c]
            m.c_env[i, c] = row[C_ENV + c]
            m.c_normal[i, c] = row[C_NORMAL + c]
            m.c_env_velocity[i, c] = row[C_ENV_VELOCITY + c]
        m.c_friction[i] = mu
        m.c_restitution[i] = e
        m.c_stiffness[i] = kk
        m.c_damping[i] = bb
        m.c_tangential_stiffness[i] = kt
    return 0


@njit(cache=True)
def parse_update(buf, nbytes, limits, out, scratch):
    """Validate the update in buf[:nbytes] and fill `out` (LOCAL_MODEL_DTYPE[1]); 0 or a Reason.

    `buf` must be an 8-byte aligned uint8 array; `limits` a LIMITS_DTYPE[1] record;
    `scratch` a (MAX_DOF, MAX_DOF) float array. The checks run in a fixed order, so a
    message that breaks several is always rejected for the same reason.
    """
    m = out[0]
    m.valid = 0
    code, d, n, j, flags, n_cf, n_shapes, n_chains = _check_header(buf, nbytes)
    if code != 0:
        return code
    lim = limits[0]
    n_int = d + 2 * n
    body_end = HEADER_BYTES + 8 * (n_int + _float_count(d, j, n, flags, n_cf))
    ints = buf[HEADER_BYTES : HEADER_BYTES + 8 * n_int].view(np.int64)
    fl = buf[HEADER_BYTES + 8 * n_int : body_end].view(np.float64)
    sim_time = _f64(buf, AT_SIM_TIME)
    char_len = _f64(buf, AT_CHAR_LENGTH)
    lead = _f64(buf, AT_LEAD)
    if not (math.isfinite(sim_time) and math.isfinite(char_len) and math.isfinite(lead)):
        return Reason.NONFINITE
    if abs(lead) > 1.0:
        return Reason.MAGNITUDE
    for k in range(fl.shape[0]):
        if not math.isfinite(fl[k]):
            return Reason.NONFINITE
    if not char_len > 0.0:
        return Reason.CHARACTERISTIC_LENGTH
    for k in range(d):
        if ints[k] < REVOLUTE or ints[k] > PRISMATIC_Y:
            return Reason.JOINT_TYPE
    for k in range(n):
        if ints[d + k] < 0 or ints[d + k] >= d:
            return Reason.CONTACT_LINK
    m.dof = d
    m.n_resisted = j
    m.n_contacts = n
    m.characteristic_length = char_len
    m.has_gravity = 1 if (flags & FLAG_GRAVITY) != 0 else 0
    m.has_velocity_torque = 1 if (flags & FLAG_VELOCITY_TORQUE) != 0 else 0
    contacts_at = _read_body(m, ints, fl, flags)
    code = _check_magnitudes(m, lim)
    if code == 0:
        code = _check_mass(m, lim, scratch)
    if code == 0:
        code = _penalty_projection(m)
    if code == 0:
        code = _read_contacts(m, ints, fl, contacts_at, n_cf, lim)
    chains_end = body_end + (8 * _chains_words(d, n_chains) if n_chains > 0 else 0)
    if code == 0:
        code = _read_chains(m, buf[body_end:chains_end], n_chains, _u16(buf, AT_OP_LINK), lim)
    avars_end = chains_end + (8 * AVAR_WORDS if (flags & FLAG_AVARS) != 0 else 0)
    if code == 0:
        code = _read_avars(m, buf[chains_end:avars_end], lim)
    m.n_shapes = 0
    if code == 0 and n_shapes > 0:
        code = _read_shapes(m, buf[avars_end:nbytes], n_shapes, lim)
    if code != 0:
        return code
    m.epoch = _i64(buf, AT_EPOCH)
    m.seq = _i64(buf, AT_SEQ)
    m.sim_time = sim_time
    m.publish_time_ns = _i64(buf, PUBLISH_TIME_AT)
    m.op_link = _u16(buf, AT_OP_LINK)
    m.tool_touching = 1 if (flags & FLAG_TOUCHING) != 0 else 0
    m.state_lead_s = lead
    m.valid = 1
    return Reason.OK


@njit(cache=True)
def _read_chains(m, trailer, c, op_link, lim):
    """The CHAINS trailer into the record, every rule checked: 0 or Reason.NONFINITE /
    Reason.CHAIN. c = 0 (no trailer): one serial chain."""
    d = m.dof
    for k in range(MAX_CHAINS):
        m.chain_first[k] = 0
        m.chain_kind[k] = CHAIN_TOOL
        m.chain_port[k] = -1
        for a in range(3):
            m.chain_base[k, a] = 0.0
    m.chain_port[0] = 0
    m.n_chains = 1
    m.has_chains = 1 if c > 0 else 0
    for i in range(MAX_DOF):
        m.parents[i] = i - 1 if i < d else -1
    if c == 0:
        return 0
    ints = trailer[8 : 8 * (1 + d + CHAIN_INTS * c)].view(np.int64)
    fl = trailer[8 * (1 + d + CHAIN_INTS * c) :].view(np.float64)
    for k in range(fl.shape[0]):
        if not math.isfinite(fl[k]):
            return Reason.NONFINITE
    last = -1
    for k in range(c):
        first, kind, port = (
            ints[d + CHAIN_INTS * k],
            ints[d + CHAIN_INTS * k + 1],
            ints[d + CHAIN_INTS * k + 2],
        )
        if first <= last or first >= d or kind < CHAIN_TOOL or kind > CHAIN_AVAR:
            return Reason.CHAIN
        if port < -1 or port >= MAX_PORTS:
            return Reason.CHAIN
        if k == 0 and (first != 0 or kind != CHAIN_TOOL or port != 0):
            return Reason.CHAIN  # chain 0 is the held tool, from joint 0
        if k > 0:
            for a in range(2):
                if abs(fl[3 * (k - 1) + a]) > lim.max_abs_position_m:
                    return Reason.CHAIN
            if abs(fl[3 * (k - 1) + 2]) > lim.max_abs_angle_rad:
                return Reason.CHAIN
        m.chain_first[k] = first
        m.chain_kind[k] = kind
        m.chain_port[k] = port
        last = first
    if c > 1 and op_link >= m.chain_first[1]:
        return Reason.CHAIN  # the held link is the tool's
    chain = 0
    for i in range(d):
        while chain + 1 < c and m.chain_first[chain + 1] <= i:
            chain += 1
        up = ints[i]
        if up < -1 or up >= i or (up >= 0 and up < m.chain_first[chain]):
            return Reason.CHAIN
        m.parents[i] = up
    for k in range(1, c):
        for a in range(3):
            m.chain_base[k, a] = fl[3 * (k - 1) + a]
    m.n_chains = c
    return 0


@njit(cache=True)
def _read_avars(m, trailer, lim):
    """The AVARS trailer (empty: none) into the record: 0 or Reason.NONFINITE / Reason.AVAR."""
    m.has_avars = 0
    m.avar_static_id = -1
    m.avar_cars = 0
    m.avar_s = 0.0
    m.avar_sd = 0.0
    if trailer.shape[0] == 0:
        return 0
    ints = trailer[:16].view(np.int64)
    fl = trailer[16:].view(np.float64)
    if not (math.isfinite(fl[0]) and math.isfinite(fl[1])):
        return Reason.NONFINITE
    if ints[0] < 0 or ints[1] < 1 or ints[1] > MAX_TRAIN_CARS:
        return Reason.AVAR
    if abs(fl[0]) > lim.max_abs_position_m or abs(fl[1]) > lim.max_abs_velocity:
        return Reason.AVAR
    m.has_avars = 1
    m.avar_static_id = ints[0]
    m.avar_cars = ints[1]
    m.avar_s = fl[0]
    m.avar_sd = fl[1]
    return 0


@njit(cache=True)
def _read_shapes(m, trailer, s, lim):
    """The SHAPES trailer into m.shapes, every field checked (layout.SHAPE_*_FIELDS): 0 or
    Reason.NONFINITE / Reason.SHAPE."""
    ints = trailer[8 : 8 * (1 + SHAPE_INTS * s)].view(np.int64)
    fl = trailer[8 * (1 + SHAPE_INTS * s) :].view(np.float64)
    for k in range(fl.shape[0]):
        if not math.isfinite(fl[k]):
            return Reason.NONFINITE
    for k in range(s):
        code = _read_shape(m.shapes[k], ints[SHAPE_INTS * k :], fl[SHAPE_FLOATS * k :], lim)
        if code == 0:
            code = _shape_owner(m, ints[SHAPE_INTS * k + 1], ints[SHAPE_INTS * k + 5])
        if code != 0:
            return code
        m.shapes[k].owner = ints[SHAPE_INTS * k + 1]
        for i in range(k):
            if m.shapes[i].key == m.shapes[k].key:
                return Reason.SHAPE
    m.n_shapes = s
    return 0


@njit(cache=True)
def _read_shape(sh, row, f, lim):
    """One shape: its ints (row) and floats (f) checked and stored; 0 or Reason.SHAPE."""
    kind = row[2]
    nv = row[3]
    if row[0] < 0 or row[4] < 0 or row[5] < 0 or row[5] > Motion.TRACK:
        return Reason.SHAPE
    if row[5] == Motion.NODAL and (kind != ShapeKind.SEGMENT or f[S_POSE + 2] != 0.0):
        return Reason.SHAPE  # nodes about a pose with zero angle ...
    if row[5] == Motion.NODAL and (
        f[S_TWIST] != 0.0 or f[S_TWIST + 1] != 0.0 or f[S_TWIST + 2] != 0.0
    ):
        return Reason.SHAPE  # ... and no twist: the haptic side holds them
    if kind == ShapeKind.CIRCLE:
        ok = nv == 1 and f[S_ROUNDING] > 0.0
    elif kind == ShapeKind.SEGMENT:
        ok = nv == 2
    elif kind == ShapeKind.POLYGON:
        ok = 3 <= nv <= MAX_VERTICES
    else:
        ok = False
    max_pos = lim.max_abs_position_m
    rho = f[S_ROUNDING]
    if not ok or rho < 0.0 or rho > max_pos:
        return Reason.SHAPE
    if abs(f[S_POSE]) > max_pos or abs(f[S_POSE + 1]) > max_pos:
        return Reason.SHAPE
    if abs(f[S_POSE + 2]) > lim.max_abs_angle_rad:
        return Reason.SHAPE
    if math.hypot(f[S_TWIST], f[S_TWIST + 1]) > lim.max_abs_velocity:
        return Reason.SHAPE
    if abs(f[S_TWIST + 2]) > lim.max_abs_angular_velocity:
        return Reason.SHAPE
    mu_k = f[S_FRICTION]
    mu_s = f[S_STATIC_FRICTION]
    if mu_k < 0.0 or mu_s < mu_k or mu_s > lim.max_friction:
        return Reason.SHAPE
    bound = 0.0
    for v in range(MAX_VERTICES):
        x = f[S_VERTICES + 2 * v]
        y = f[S_VERTICES + 2 * v + 1]
        if v >= nv and (x != 0.0 or y != 0.0):
            return Reason.SHAPE  # unused vertices are zero: one encoding per shape
        if abs(x) > max_pos or abs(y) > max_pos:
            return Reason.SHAPE
        sh.vertices[v, 0] = x
        sh.vertices[v, 1] = y
        bound = max(bound, math.hypot(x, y))
    if not _core_is_proper(sh.vertices, nv):
        return Reason.SHAPE
    sh.key = row[0]
    sh.kind = kind
    sh.n_vert = nv
    sh.generation = row[4]
    sh.motion = row[5]
    sh.rounding = rho
    for c in range(3):
        sh.pose[c] = f[S_POSE + c]
        sh.twist[c] = f[S_TWIST + c]
    sh.static_friction = mu_s
    sh.friction = mu_k
    sh.bound = bound
    return 0


@njit(cache=True, inline="always")
def _shape_owner(m, owner, motion):
    """A shape's owner against its motion: the world's (-1) are carried by their twist, a
    car's (0..cars - 1, with AVARS only) by the train. 0 or Reason.SHAPE (no AVARS: as
    before them) / Reason.AVAR."""
    if m.has_avars == 0:
        return Reason.SHAPE if owner != -1 or motion == Motion.TRACK else 0
    if owner == -1:
        return Reason.AVAR if motion == Motion.TRACK else 0
    if owner < 0 or owner >= m.avar_cars or motion != Motion.TRACK:
        return Reason.AVAR
    return 0


@njit(cache=True)
def _core_is_proper(v, nv):
    """A segment's ends lie more than MIN_EDGE_M apart; a polygon is strictly convex and
    counter-clockwise: every vertex strictly left of every edge it is not on (as
    shared.shapes.polygon_problem asks; a left turn at each vertex alone passes a star)."""
    if nv == 2:
        return math.hypot(v[1, 0] - v[0, 0], v[1, 1] - v[0, 1]) > MIN_EDGE_M
    if nv < 3:
        return True
    for i in range(nv):
        a = v[i]
        b = v[(i + 1) % nv]
        ex = b[0] - a[0]
        ey = b[1] - a[1]
        if math.hypot(ex, ey) <= MIN_EDGE_M:
            return False
        for k in range(nv):
            if k == i or k == (i + 1) % nv:
                continue
            if ex * (v[k, 1] - a[1]) - ey * (v[k, 0] - a[0]) <= 0.0:
                return False
    return True


class UpdateParser:
    """Preallocated buffers around parse_update: one per receiver (tools, tests)."""

    def __init__(self, limits: MessageLimits = DEFAULT_LIMITS) -> None:
        self.limits = limits_record(limits)
        self.buffer = np.zeros(MAX_UPDATE_BYTES, np.uint8)
        self.out = np.zeros(1, LOCAL_MODEL_DTYPE)
        self.scratch = np.zeros((MAX_DOF, MAX_DOF))

    def parse(self, raw: bytes) -> int:
        """Parse into self.out; returns the reason code (0 = valid)."""
        n = len(raw)
        if n > self.buffer.shape[0]:
            self.out[0]["valid"] = 0
            return int(Reason.SIZE)
        self.buffer[:n] = np.frombuffer(raw, np.uint8)
        return int(parse_update(self.buffer, n, self.limits, self.out, self.scratch))


_DEFAULT_PARSER: UpdateParser | None = None


def decode_update(data: bytes, limits: MessageLimits = DEFAULT_LIMITS) -> LocalModelUpdate:
    """Parse and validate an update; raises MessageError naming what is wrong.

    The checks are those of `parse_update`, the decoder the haptic loop uses.
    """
    global _DEFAULT_PARSER
    if limits is DEFAULT_LIMITS:
        if _DEFAULT_PARSER is None:
            _DEFAULT_PARSER = UpdateParser()
        parser = _DEFAULT_PARSER
    else:
        parser = UpdateParser(limits)
    code = parser.parse(data)
    if code != 0:
        raise MessageError(Reason(code).tag, f"rejected update of {len(data)} bytes")
    return update_from_record(parser.out[0])


def update_from_record(m: np.void) -> LocalModelUpdate:
    """The dataclass view of a parsed LOCAL_MODEL_DTYPE record (copies)."""
    d = int(m["dof"])
    n = int(m["n_contacts"])
    j = int(m["n_resisted"])
    rows, floats = contact_rows(n)
    for c in CONTACT_COLUMNS:
        rows[c.name] = m[f"c_{c.name}"][:n]
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
        shapes=m["shapes"][: int(m["n_shapes"])].copy() if m["n_shapes"] else None,
        chains=_chain_table(m),
        avars=AvarState(
            int(m["avar_static_id"]), int(m["avar_cars"]), float(m["avar_s"]), float(m["avar_sd"])
        )
        if m["has_avars"]
        else None,
    )  # fmt: skip


def _chain_table(m: np.void) -> ChainTable | None:
    """A parsed record's tree and chains, None without a CHAINS trailer (one serial chain)."""
    d, c = int(m["dof"]), int(m["n_chains"])
    if not m["has_chains"]:
        return None
    return ChainTable(
        m["parents"][:d].copy(), m["chain_first"][:c].copy(), m["chain_kind"][:c].copy(),
        m["chain_port"][:c].copy(), m["chain_base"][1:c].copy(),
    )  # fmt: skip


__all__ = [
    "PUBLISH_TIME_END",
    "AvarState",
    "ChainTable",
    "ContactSet",
    "LocalModelUpdate",
    "MessageError",
    "UpdateParser",
    "body_counts",
    "decode_update",
    "encode_record",
    "encode_update",
    "parse_update",
    "publish_time_ns",
    "update_from_record",
]

"""The one boundary that converts a LocalModelUpdate's bytes into kernel arrays.

`parse_update` is a numba kernel: it validates an update (sizes, finite values, D
symmetric positive definite, unit normals, magnitudes within limits) and writes it into a
LOCAL_MODEL_DTYPE record, returning 0 or a reason code. The haptic loop calls it on every
received message (a few microseconds, where the same checks in numpy cost hundreds of
microseconds in a paced 1 kHz loop); `shared.messages.decode_update` wraps it for tools.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from shared.kinematics import MAX_DOF, PRISMATIC_Y, REVOLUTE
from shared.linalg import cholesky_inplace

PROTOCOL_VERSION = 1
MAX_CONTACTS = 64
MAX_RESISTED = 3
HEADER_BYTES = 64  # struct "<4sHHQQdqHHHHdd", see shared.messages
PUBLISH_TIME_AT = 32  # byte offset of the header's publish_time_ns (int64)
PUBLISH_TIME_END = PUBLISH_TIME_AT + 8  # a message shorter than this has no publish time
CONTACT_FLOATS = 12
MAGIC_UPDATE = (0x48, 0x4C, 0x4D, 0x55)  # b"HLMU"

FLAG_GRAVITY = 1
FLAG_RESISTED = 2
FLAG_TOUCHING = 4
FLAG_VELOCITY_TORQUE = 8

F8 = np.float64
I8 = np.int64

#: One local model as the kernels use it (plus the haptic side's per-contact state).
LOCAL_MODEL_DTYPE = np.dtype(
    [
        ("valid", I8),
        ("epoch", I8),
        ("seq", I8),
        ("sim_time", F8),
        ("publish_time_ns", I8),
        ("dof", I8),
        ("joint_types", I8, (MAX_DOF,)),
        ("lengths", F8, (MAX_DOF,)),
        ("base", F8, (2,)),
        ("base_angle", F8),
        ("op_link", I8),
        ("op_point", F8, (2,)),
        ("q", F8, (MAX_DOF,)),  # the sim's tool state (re-initialisation)
        ("qd", F8, (MAX_DOF,)),
        ("mass", F8, (MAX_DOF, MAX_DOF)),  # D^ (frozen)
        ("lambda_inv", F8, (3, 3)),
        ("has_gravity", I8),
        ("gravity", F8, (MAX_DOF,)),  # G^ (frozen)
        ("has_velocity_torque", I8),
        ("velocity_torque", F8, (MAX_DOF,)),  # C(q, qd) qd at the sim's state (frozen)
        ("n_resisted", I8),
        ("characteristic_length", F8),
        ("resisted", F8, (MAX_RESISTED, 3)),  # unit directions in the scaled space
        ("penalty_projection", F8, (3, 3)),  # sum (S n)(S n)^T, S = diag(1, 1, L)
        ("tool_pose", F8, (3,)),  # the sim's operational point pose
        ("tool_touching", I8),
        ("state_lead_s", F8),  # the state holds this long after its publication
        ("age_s", F8),  # time since the state held (negative at install): contacts move by it
        ("n_contacts", I8),
        ("c_link", I8, (MAX_CONTACTS,)),
        ("c_key", I8, (MAX_CONTACTS,)),
        ("c_tool", F8, (MAX_CONTACTS, 2)),  # contact point in the tool link's frame
        ("c_env", F8, (MAX_CONTACTS, 2)),  # environment point (world) at the update
        ("c_normal", F8, (MAX_CONTACTS, 2)),  # outward environment normal (world)
        ("c_env_velocity", F8, (MAX_CONTACTS, 2)),
        ("c_friction", F8, (MAX_CONTACTS,)),
        ("c_restitution", F8, (MAX_CONTACTS,)),
        ("c_stiffness", F8, (MAX_CONTACTS,)),
        ("c_damping", F8, (MAX_CONTACTS,)),
        ("c_in_contact", I8, (MAX_CONTACTS,)),  # haptic-side contact state, tick to tick
        ("c_stick", F8, (MAX_CONTACTS,)),  # tangential stick displacement (m)
    ]
)

# Reason codes of parse_update (0: valid), as short stable tags for counters and logs.
REASONS = (
    "ok", "short", "magic", "version", "dof", "contacts", "resisted", "op_link", "size",
    "nonfinite", "characteristic_length", "joint_type", "contact_link", "magnitude",
    "mass_matrix", "contact",
)  # fmt: skip
R_OK, R_SHORT, R_MAGIC, R_VERSION, R_DOF, R_CONTACTS, R_RESISTED, R_OP_LINK, R_SIZE = range(9)
R_NONFINITE, R_CHAR, R_JOINT, R_CLINK, R_MAGNITUDE, R_MASS, R_CONTACT = range(9, 16)

LIMIT_FIELDS = (
    "max_abs_position_m", "max_abs_angle_rad", "max_abs_velocity", "max_mass_entry",
    "min_mass_eigenvalue", "max_stiffness_n_per_m", "max_damping_ns_per_m", "max_friction",
    "symmetry_tolerance", "max_abs_generalized_force", "max_inverse_mass",
)  # fmt: skip


def float_count(d: int, n: int, j: int, has_gravity: bool) -> int:
    """Number of float64 values after the int block (docs/protocol.md)."""
    return (
        d
        + 2
        + 1
        + 2
        + d
        + d
        + d * d
        + 9
        + 3
        + (d if has_gravity else 0)
        + 3 * j
        + CONTACT_FLOATS * n
    )


@njit(cache=True)
def _u16(buf, o):
    return np.int64(buf[o]) | (np.int64(buf[o + 1]) << 8)


@njit(cache=True)
def publish_time_ns(buf):
    """The header's publish time of the update in `buf` (8-byte aligned, at least
    PUBLISH_TIME_END bytes long)."""
    return buf[PUBLISH_TIME_AT:PUBLISH_TIME_END].view(np.int64)[0]


@njit(cache=True)
def parse_update(buf, nbytes, limits, out, scratch):
    """Validate the update in buf[:nbytes] and fill `out` (LOCAL_MODEL_DTYPE[1]); 0 or a reason.

    `buf` must be an 8-byte aligned uint8 array; `scratch` a (MAX_DOF, MAX_DOF) float array.
    """
    m = out[0]
    m.valid = 0
    if nbytes < HEADER_BYTES:
        return R_SHORT
    for i in range(4):
        if buf[i] != MAGIC_UPDATE[i]:
            return R_MAGIC
    if _u16(buf, 4) != PROTOCOL_VERSION:
        return R_VERSION
    flags = _u16(buf, 6)
    head_i = buf[8:40].view(np.int64)
    head_f = buf[8:64].view(np.float64)
    d = _u16(buf, 40)
    n = _u16(buf, 42)
    j = _u16(buf, 44)
    op_link = _u16(buf, 46)
    if d < 1 or d > MAX_DOF:
        return R_DOF
    if n > MAX_CONTACTS:
        return R_CONTACTS
    has_res = (flags & FLAG_RESISTED) != 0
    if j > MAX_RESISTED or (j > 0) != has_res:
        return R_RESISTED
    if op_link >= d:
        return R_OP_LINK
    has_g = (flags & FLAG_GRAVITY) != 0
    has_c = (flags & FLAG_VELOCITY_TORQUE) != 0
    n_int = d + 2 * n
    n_float = d + 2 + 1 + 2 + 2 * d + d * d + 9 + 3 + 3 * j + CONTACT_FLOATS * n
    n_float += (d if has_g else 0) + (d if has_c else 0)
    if nbytes != HEADER_BYTES + 8 * (n_int + n_float):
        return R_SIZE
    ints = buf[HEADER_BYTES : HEADER_BYTES + 8 * n_int].view(np.int64)
    fl = buf[HEADER_BYTES + 8 * n_int : nbytes].view(np.float64)
    sim_time = head_f[2]
    char_len = head_f[5]
    lead = head_f[6]
    if not (math.isfinite(sim_time) and math.isfinite(char_len) and math.isfinite(lead)):
        return R_NONFINITE
    if abs(lead) > 1.0:
        return R_MAGNITUDE
    for k in range(n_float):
        if not math.isfinite(fl[k]):
            return R_NONFINITE
    if not char_len > 0.0:
        return R_CHAR
    max_pos = limits[0]
    max_ang = limits[1]
    max_vel = limits[2]
    for k in range(d):
        if ints[k] < REVOLUTE or ints[k] > PRISMATIC_Y:
            return R_JOINT
    for k in range(n):
        if ints[d + k] < 0 or ints[d + k] >= d:
            return R_CLINK
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
    if has_g:
        for k in range(d):
            m.gravity[k] = fl[o + k]
        o += d
    if has_c:
        for k in range(d):
            m.velocity_torque[k] = fl[o + k]
        o += d
    for r in range(j):
        for c in range(3):
            m.resisted[r, c] = fl[o + 3 * r + c]
    o += 3 * j
    contacts = o
    # magnitudes
    for k in range(d):
        if abs(m.lengths[k]) > max_pos:
            return R_MAGNITUDE
        if abs(m.q[k]) > max(max_pos, max_ang) or abs(m.qd[k]) > max_vel:
            return R_MAGNITUDE
    if abs(m.base[0]) > max_pos or abs(m.base[1]) > max_pos:
        return R_MAGNITUDE
    if abs(m.tool_pose[0]) > max_pos or abs(m.tool_pose[1]) > max_pos:
        return R_MAGNITUDE
    # the rest of what the kernels read, so no finite but absurd value reaches them
    if abs(m.tool_pose[2]) > max_ang or abs(m.base_angle) > max_ang or char_len > max_pos:
        return R_MAGNITUDE
    if abs(m.op_point[0]) > max_pos or abs(m.op_point[1]) > max_pos:
        return R_MAGNITUDE
    for k in range(d):
        if (has_g and abs(m.gravity[k]) > limits[9]) or (
            has_c and abs(m.velocity_torque[k]) > limits[9]
        ):
            return R_MAGNITUDE
    for a in range(3):
        for b in range(3):
            if abs(m.lambda_inv[a, b]) > limits[10]:
                return R_MAGNITUDE
    # D symmetric positive definite and bounded
    scale = 0.0
    for a in range(d):
        for b in range(d):
            scale = max(scale, abs(m.mass[a, b]))
    if scale > limits[3]:
        return R_MASS
    for a in range(d):
        for b in range(a + 1, d):
            if abs(m.mass[a, b] - m.mass[b, a]) > limits[8] * max(scale, 1e-300):
                return R_MASS
    if not cholesky_inplace(m.mass, d, scratch):
        return R_MASS
    for a in range(d):
        if scratch[a, a] * scratch[a, a] < limits[4]:
            return R_MASS
    # resisted directions: unit vectors; their penalty projection in natural units
    for a in range(3):
        for b in range(3):
            m.penalty_projection[a, b] = 0.0
    for r in range(j):
        norm = math.sqrt(m.resisted[r, 0] ** 2 + m.resisted[r, 1] ** 2 + m.resisted[r, 2] ** 2)
        if abs(norm - 1.0) > 1e-6:
            return R_RESISTED
        s0 = m.resisted[r, 0]
        s1 = m.resisted[r, 1]
        s2 = m.resisted[r, 2] * char_len
        m.penalty_projection[0, 0] += s0 * s0
        m.penalty_projection[0, 1] += s0 * s1
        m.penalty_projection[0, 2] += s0 * s2
        m.penalty_projection[1, 0] += s1 * s0
        m.penalty_projection[1, 1] += s1 * s1
        m.penalty_projection[1, 2] += s1 * s2
        m.penalty_projection[2, 0] += s2 * s0
        m.penalty_projection[2, 1] += s2 * s1
        m.penalty_projection[2, 2] += s2 * s2
    # contacts
    for i in range(n):
        c = contacts + CONTACT_FLOATS * i
        for k in range(4):
            if abs(fl[c + k]) > max_pos:
                return R_CONTACT
        if abs(math.hypot(fl[c + 4], fl[c + 5]) - 1.0) > 1e-6:
            return R_CONTACT
        if abs(fl[c + 6]) > max_vel or abs(fl[c + 7]) > max_vel:
            return R_CONTACT
        mu = fl[c + 8]
        e = fl[c + 9]
        kk = fl[c + 10]
        bb = fl[c + 11]
        if mu < 0.0 or mu > limits[7] or e < 0.0 or e > 1.0:
            return R_CONTACT
        if not (kk > 0.0 and kk <= limits[5]) or bb < 0.0 or bb > limits[6]:
            return R_CONTACT
        m.c_link[i] = ints[d + i]
        m.c_key[i] = ints[d + n + i]
        m.c_tool[i, 0] = fl[c]
        m.c_tool[i, 1] = fl[c + 1]
        m.c_env[i, 0] = fl[c + 2]
        m.c_env[i, 1] = fl[c + 3]
        m.c_normal[i, 0] = fl[c + 4]
        m.c_normal[i, 1] = fl[c + 5]
        m.c_env_velocity[i, 0] = fl[c + 6]
        m.c_env_velocity[i, 1] = fl[c + 7]
        m.c_friction[i] = mu
        m.c_restitution[i] = e
        m.c_stiffness[i] = kk
        m.c_damping[i] = bb
        m.c_in_contact[i] = 0
        m.c_stick[i] = 0.0
    for k in range(d):
        m.joint_types[k] = ints[k]
    m.epoch = head_i[0]
    m.seq = head_i[1]
    m.sim_time = sim_time
    m.publish_time_ns = head_i[3]
    m.dof = d
    m.op_link = op_link
    m.has_gravity = 1 if has_g else 0
    m.has_velocity_torque = 1 if has_c else 0
    m.n_resisted = j
    m.characteristic_length = char_len
    m.tool_touching = 1 if (flags & FLAG_TOUCHING) != 0 else 0
    m.state_lead_s = lead
    m.age_s = -lead  # contacts move with their velocity from the time the state holds
    m.n_contacts = n
    m.valid = 1
    return R_OK


class UpdateParser:
    """Preallocated buffers around parse_update: one per receiver."""

    def __init__(self, limits: np.ndarray) -> None:
        self.limits = limits
        self.buffer = np.zeros(HEADER_BYTES + 8 * (MAX_DOF + 2 * MAX_CONTACTS + 4096), np.uint8)
        self.out = np.zeros(1, LOCAL_MODEL_DTYPE)
        self.scratch = np.zeros((MAX_DOF, MAX_DOF))

    def parse(self, raw: bytes) -> int:
        """Parse into self.out; returns the reason code (0 = valid)."""
        n = len(raw)
        if n > self.buffer.shape[0]:
            self.out[0]["valid"] = 0
            return R_SIZE
        self.buffer[:n] = np.frombuffer(raw, np.uint8)
        return int(parse_update(self.buffer, n, self.limits, self.out, self.scratch))

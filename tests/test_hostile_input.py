"""Hostile and malformed messages against the decoders and a live HapticEngine (hypothesis).

Every message a receiver can get is thrown at it: random bytes, valid updates, and valid
updates with one field broken (NaN/Inf, counts, sizes, magnitudes, a D that is not symmetric
positive definite, wrong magic or version, truncated, padded, stale epoch or sequence). The
verdict of `parse_update` is checked against an independent reference written from
docs/protocol.md, and the engine, fed such messages between valid updates and ticks, must
reject and count every bad one, leave its installed model untouched, keep installing the
good ones, and command only finite wrenches within the device limits.

Case counts (EXAMPLES) add up to more than 10,000; the runs are derandomized, so CI sees the
same cases every time. Numeric contents come from a numpy generator seeded by hypothesis
(drawing hundreds of floats through hypothesis would cost more than the checks).
"""

from __future__ import annotations

import math
import struct
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from haptic_local_model.device_models.ideal import IdealDevice
from haptic_local_model.device_models.registry import load_device
from haptic_local_model.haptic_server.engine import HapticEngine
from haptic_local_model.haptic_server.log import update_json, update_record
from haptic_local_model.haptic_server.model import TICK_DTYPE
from haptic_local_model.shared.config import load_scene, load_user
from haptic_local_model.shared.kinematics import MAX_DOF
from haptic_local_model.shared.protocol.codes import Reason
from haptic_local_model.shared.protocol.codes import reason_tag as reason_of
from haptic_local_model.shared.protocol.layout import DEFAULT_LIMITS, MAX_CONTACTS
from haptic_local_model.shared.protocol.proxy import (
    MAX_WAIT_NS,
    NO_WAIT,
    UpdateWait,
    decode_proxy,
    encode_proxy,
)
from haptic_local_model.shared.protocol.update import (
    MessageError,
    UpdateParser,
    decode_update,
    encode_update,
)

EXAMPLES = {
    "random_bytes": 3000,
    "valid": 1000,
    "broken": 3000,
    "bit_flips": 2000,
    "proxy": 1000,
    "engine": 500,
    "shapes": 1000,
    "chains": 1000,
    "avars": 500,
}
assert sum(EXAMPLES.values()) >= 10_000  # issue 8


def cases(name: str) -> Any:
    return settings(
        max_examples=EXAMPLES[name],
        derandomize=True,
        database=None,
        deadline=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    )


LIM = DEFAULT_LIMITS
HEADER = struct.Struct("<4sHHQQdqHHHHdd")  # docs/protocol.md, LocalModelUpdate header
PROXY_HEADER = struct.Struct("<4sHHQQQdqHHqqq")  # docs/protocol.md, ProxyState header
KNOWN_REASONS = {r.tag for r in Reason if r != Reason.OK}
UNIT_TOL = 1e-6  # docs/protocol.md: unit normals and directions
PARSER = UpdateParser(LIM)


# --- an independent reference validator (docs/protocol.md) --------------------------------


#: floats of a contact row by protocol version (version 2 added the tangential stiffness)
CONTACT_WIDTH = {1: 12, 2: 13, 3: 13}
VERSION = 3
SHAPE_INTS, SHAPE_FLOATS = 6, 25  # docs/protocol.md, SHAPES trailer (version 3, flag 16)
MAX_SHAPES, MAX_VERTICES = 64, 8
MAX_CHAINS, MAX_PORTS = 4, 2  # docs/protocol.md, CHAINS trailer (version 3, flag 32)
AVAR_WORDS = 4  # docs/protocol.md, AVARS trailer (version 3, flag 64)


def chains_words(d: int, c: int) -> int:
    """8-byte words of a CHAINS trailer: c, d parents, c rows of 3 ints, c - 1 base poses."""
    return 1 + d + 3 * c + 3 * (c - 1)


def float_groups(
    d: int, n: int, j: int, flags: int, version: int = VERSION
) -> list[tuple[str, int]]:
    """The float section in wire order: (name, count)."""
    groups = [("lengths", d), ("base", 2), ("base_angle", 1), ("op_point", 2), ("q", d)]
    groups += [("qd", d), ("mass", d * d), ("lambda_inv", 9), ("tool_pose", 3)]
    if flags & 1:
        groups.append(("gravity", d))
    if flags & 8:
        groups.append(("velocity_torque", d))
    return [*groups, ("resisted", 3 * j), ("contacts", CONTACT_WIDTH[version] * n)]


def layout(raw: bytes) -> tuple[int, int, int, int, dict[str, tuple[int, int]]]:
    """d, n, j, flags and the byte offset and count of every float group of an update (and
    "shapes": the trailer's offset and its count of shapes)."""
    version, flags = struct.unpack_from("<HH", raw, 4)
    d, n, j = struct.unpack_from("<HHH", raw, 40)
    offset = HEADER.size + 8 * (d + 2 * n)
    groups = {}
    for name, count in float_groups(d, n, j, flags, version):
        groups[name] = (offset, count)
        offset += 8 * count
    if flags & 32 and len(raw) >= offset + 8:
        c = struct.unpack_from("<q", raw, offset)[0]
        groups["chains"] = (offset, c)
        offset += 8 * chains_words(d, c) if 1 <= c <= MAX_CHAINS else len(raw)
    if flags & 64 and len(raw) >= offset + 8 * AVAR_WORDS:
        groups["avars"] = (offset, AVAR_WORDS)
        offset += 8 * AVAR_WORDS
    if flags & 16 and len(raw) >= offset + 8:
        groups["shapes"] = (offset, struct.unpack_from("<q", raw, offset)[0])
    return d, n, j, flags, groups


def strictly_convex_ccw(v: np.ndarray) -> bool:
    """Every edge longer than 1e-12 m and every vertex strictly left of every other edge."""
    n = len(v)
    for i in range(n):
        a, b = v[i], v[(i + 1) % n]
        if np.hypot(*(b - a)) <= 1e-12:
            return False
        for k in range(n):
            if k not in (i, (i + 1) % n):
                rel = v[k] - a
                if (b - a)[0] * rel[1] - (b - a)[1] * rel[0] <= 0:
                    return False
    return True


def reference_shapes_accept(raw: bytes, at: int, cars: int) -> bool:
    """The SHAPES trailer at byte `at` (the rest of the message), from docs/protocol.md, in
    an update whose AVARS trailer names `cars` cars (0: none)."""
    if len(raw) < at + 8:
        return False
    s = struct.unpack_from("<q", raw, at)[0]
    if not 1 <= s <= MAX_SHAPES or len(raw) != at + 8 * (1 + (SHAPE_INTS + SHAPE_FLOATS) * s):
        return False
    ints = np.frombuffer(raw, "<i8", SHAPE_INTS * s, at + 8).reshape(s, SHAPE_INTS)
    fl = np.frombuffer(raw, "<f8", SHAPE_FLOATS * s, at + 8 * (1 + SHAPE_INTS * s))
    if not np.isfinite(fl).all():
        return False
    fl = fl.reshape(s, SHAPE_FLOATS)
    key, owner, kind, nv, generation, motion = ints.T
    if len(set(key.tolist())) != s or (key < 0).any():
        return False
    if (generation < 0).any():
        return False
    world = (owner == -1) & np.isin(motion, (0, 1, 2))
    on_car = (owner >= 0) & (owner < cars) & (motion == 3)
    if not (world | on_car).all():
        return False
    for k in range(s):
        verts, rho = fl[k, :16].reshape(8, 2), fl[k, 16]
        pose, twist, mu_s, mu_k = fl[k, 17:20], fl[k, 20:23], fl[k, 23], fl[k, 24]
        if motion[k] == 2 and (kind[k] != 1 or pose[2] != 0 or (twist != 0).any()):
            return False  # nodal: a segment's nodes about a pose of zero angle, no twist
        want = {0: (1, 1), 1: (2, 2), 2: (3, MAX_VERTICES)}.get(int(kind[k]))
        if want is None or not want[0] <= nv[k] <= want[1]:
            return False
        if rho < 0 or rho > LIM.max_abs_position_m or (kind[k] == 0 and rho <= 0):
            return False
        if (np.abs(verts) > LIM.max_abs_position_m).any() or (verts[nv[k] :] != 0).any():
            return False
        if (np.abs(pose[:2]) > LIM.max_abs_position_m).any():
            return False
        if abs(pose[2]) > LIM.max_abs_angle_rad or np.hypot(*twist[:2]) > LIM.max_abs_velocity:
            return False
        if abs(twist[2]) > LIM.max_abs_angular_velocity:
            return False
        if mu_k < 0 or mu_s < mu_k or mu_s > LIM.max_friction:
            return False
        v = verts[: nv[k]]
        if nv[k] == 2 and np.hypot(*(v[1] - v[0])) <= 1e-12:
            return False
        if nv[k] >= 3 and not strictly_convex_ccw(v):
            return False
    return True


def reference_chains_accept(raw: bytes, at: int, d: int, op_link: int) -> bool:
    """The CHAINS trailer at byte `at` (its size already checked), from docs/protocol.md."""
    c = struct.unpack_from("<q", raw, at)[0]
    parents = np.frombuffer(raw, "<i8", d, at + 8)
    rows = np.frombuffer(raw, "<i8", 3 * c, at + 8 * (1 + d)).reshape(c, 3)
    bases = np.frombuffer(raw, "<f8", 3 * (c - 1), at + 8 * (1 + d + 3 * c)).reshape(c - 1, 3)
    first, kind, port = rows.T
    if tuple(rows[0]) != (0, 0, 0) or (np.diff(first) <= 0).any() or (first >= d).any():
        return False
    if not np.isin(kind, (0, 1, 2, 3)).all() or ((port < -1) | (port >= MAX_PORTS)).any():
        return False
    if not np.isfinite(bases).all() or (np.abs(bases[:, :2]) > LIM.max_abs_position_m).any():
        return False
    if (np.abs(bases[:, 2]) > LIM.max_abs_angle_rad).any():
        return False
    if c > 1 and op_link >= first[1]:
        return False
    for i, up in enumerate(parents):
        chain_first = first[first <= i].max()
        if not (up == -1 or chain_first <= up < i):
            return False
    return True


def reference_avars_accept(raw: bytes, at: int) -> int:
    """The AVARS trailer at byte `at`: its car count if it is valid, else 0."""
    static_id, cars, s, sd = struct.unpack_from("<qqdd", raw, at)
    if static_id < 0 or not 1 <= cars <= 8 or not (math.isfinite(s) and math.isfinite(sd)):
        return 0
    if abs(s) > LIM.max_abs_position_m or abs(sd) > LIM.max_abs_velocity:
        return 0
    return cars


def reference_trailers_accept(raw: bytes, body_end: int, flags: int, d: int) -> tuple[bool, int]:
    """Sizes of the CHAINS, AVARS and SHAPES trailers: (fits, byte offset of the SHAPES
    trailer)."""
    end = body_end
    if flags & 32:
        c = trailer_count(raw, end, MAX_CHAINS)
        if c is None:
            return False, end
        end += 8 * chains_words(d, c)
    if flags & 64:
        end += 8 * AVAR_WORDS
    if flags & 16:
        s = trailer_count(raw, end, MAX_SHAPES)
        if s is None:
            return False, end
        return len(raw) == end + 8 * (1 + (SHAPE_INTS + SHAPE_FLOATS) * s), end
    return len(raw) == end, end


def trailer_count(raw: bytes, at: int, most: int) -> int | None:
    """A trailer's leading int64 count at byte `at`, if it is there and in 1..most."""
    if len(raw) < at + 8:
        return None
    count = struct.unpack_from("<q", raw, at)[0]
    return count if 1 <= count <= most else None


def reference_accepts(raw: bytes) -> bool:
    """Whether a LocalModelUpdate is valid, straight from the protocol document."""
    if len(raw) < HEADER.size:
        return False
    magic, version, flags, _, _, sim_time, _, d, n, j, op_link, char_len, lead = HEADER.unpack_from(
        raw
    )
    if magic != b"HLMU" or version not in CONTACT_WIDTH or flags & ~127 or not 1 <= d <= MAX_DOF:
        return False  # the protocol defines flags 1..64 (since 0.10 any other bit is refused)
    if n > MAX_CONTACTS or j > 3 or (j > 0) != bool(flags & 2) or op_link >= d:
        return False
    groups = float_groups(d, n, j, flags, version)
    n_int = d + 2 * n
    n_float = sum(c for _, c in groups)
    body_end = HEADER.size + 8 * (n_int + n_float)
    if flags & 112 and version < 3:
        return False
    fits, shapes_at = reference_trailers_accept(raw, body_end, flags, d)
    if not fits:
        return False
    if not all(math.isfinite(v) for v in (sim_time, char_len, lead)) or abs(lead) > 1.0:
        return False
    ints = np.frombuffer(raw, "<i8", n_int, HEADER.size)
    fl = np.frombuffer(raw, "<f8", n_float, HEADER.size + 8 * n_int)
    if not np.isfinite(fl).all() or not 0.0 < char_len <= LIM.max_abs_position_m:
        return False
    if not np.isin(ints[:d], (0, 1, 2)).all() or not ((ints[d : d + n] >= 0).all()):
        return False
    if (ints[d : d + n] >= d).any():
        return False
    g: dict[str, np.ndarray] = {}
    o = 0
    for name, count in groups:
        g[name] = fl[o : o + count]
        o += count
    pos, ang, vel = LIM.max_abs_position_m, LIM.max_abs_angle_rad, LIM.max_abs_velocity
    too_big = [
        (g["lengths"], pos), (g["base"], pos), (g["base_angle"], ang), (g["op_point"], pos),
        (g["q"], np.where(ints[:d] == 0, ang, pos)),  # revolute: an angle; prismatic: m
        (g["qd"], vel), (g["lambda_inv"], LIM.max_inverse_mass),
        (g["tool_pose"][:2], pos), (g["tool_pose"][2:], ang),
        (g.get("gravity", np.zeros(0)), LIM.max_abs_generalized_force),
        (g.get("velocity_torque", np.zeros(0)), LIM.max_abs_generalized_force),
    ]  # fmt: skip
    if any((np.abs(values) > bound).any() for values, bound in too_big):
        return False
    mass = g["mass"].reshape(d, d)
    scale = np.abs(mass).max()
    if scale > LIM.max_mass_entry:
        return False
    if (np.abs(mass - mass.T) > LIM.symmetry_tolerance * max(scale, 1e-300)).any():
        return False
    lower = np.tril(mass) + np.tril(mass, -1).T  # the factorisation reads the lower triangle
    try:
        chol = np.linalg.cholesky(lower)
    except np.linalg.LinAlgError:
        return False
    if (np.diag(chol) ** 2 < LIM.min_mass_eigenvalue).any():
        return False
    resisted = g["resisted"].reshape(j, 3)
    if (np.abs(np.linalg.norm(resisted, axis=1) - 1.0) > UNIT_TOL).any():
        return False
    c = g["contacts"].reshape(n, CONTACT_WIDTH[version])
    k_t = c[:, 12] if version >= 2 else c[:, 10]  # version 1: K_t = K_c
    if flags & 32 and not reference_chains_accept(raw, body_end, d, op_link):
        return False
    cars = 0
    if flags & 64:
        cars = reference_avars_accept(raw, shapes_at - 8 * AVAR_WORDS)
        if not cars:
            return False
    if flags & 16 and not reference_shapes_accept(raw, shapes_at, cars):
        return False
    return not (
        ((k_t < 0) | (k_t > LIM.max_stiffness_n_per_m)).any()
        or (np.abs(c[:, 0:4]) > pos).any()
        or (np.abs(np.hypot(c[:, 4], c[:, 5]) - 1.0) > UNIT_TOL).any()
        or (np.abs(c[:, 6:8]) > vel).any()
        or ((c[:, 8] < 0) | (c[:, 8] > LIM.max_friction)).any()
        or ((c[:, 9] < 0) | (c[:, 9] > 1)).any()
        or ((c[:, 10] <= 0) | (c[:, 10] > LIM.max_stiffness_n_per_m)).any()
        or ((c[:, 11] < 0) | (c[:, 11] > LIM.max_damping_ns_per_m)).any()
    )


# --- valid updates ------------------------------------------------------------------------


#: per float group: the range its random valid entries are drawn from
VALID_RANGES = {
    "lengths": (0.0, 0.1), "base": (-0.2, 0.2), "base_angle": (-np.pi, np.pi),
    "op_point": (-0.05, 0.05), "q": (-0.2, 0.2), "qd": (-0.5, 0.5), "lambda_inv": (-5.0, 5.0),
    "gravity": (-20.0, 20.0), "velocity_torque": (-1.0, 1.0),
}  # fmt: skip
CONTACT_RANGES = np.array(
    [(-0.1, 0.1)] * 2 + [(-0.3, 0.3)] * 2 + [(0, 0)] * 2 + [(-0.5, 0.5)] * 2
    + [(0.0, 1.0), (0.0, 1.0), (100.0, 1e5), (0.0, 300.0), (0.0, 1e5)]
)  # fmt: skip


def random_update(
    rng: np.random.Generator,
    d: int,
    n: int,
    j: int,
    flags: int,
    epoch: int,
    seq: int,
    n_shapes: int = 0,
) -> bytes:
    """The bytes of a valid update of the given shape with random contents."""
    groups = float_groups(d, n, j, flags)
    g = {name: rng.uniform(*VALID_RANGES.get(name, (0, 0)), count) for name, count in groups}
    a = rng.uniform(-2.0, 2.0, (d, d))
    m = a @ a.T + rng.uniform(0.01, 5.0) * np.eye(d)
    g["mass"] = (0.5 * (m + m.T)).ravel()
    li = g["lambda_inv"].reshape(3, 3)
    g["lambda_inv"] = (0.5 * (li + li.T)).ravel()
    g["tool_pose"] = np.array([*rng.uniform(-0.2, 0.2, 2), rng.uniform(-np.pi, np.pi)])
    dirs = rng.normal(size=(j, 3))
    g["resisted"] = (dirs / np.linalg.norm(dirs, axis=1, keepdims=True)).ravel()
    c = rng.uniform(CONTACT_RANGES[:, 0], CONTACT_RANGES[:, 1], (n, CONTACT_WIDTH[VERSION]))
    angles = rng.uniform(-np.pi, np.pi, n)
    c[:, 4], c[:, 5] = np.cos(angles), np.sin(angles)
    g["contacts"] = c.ravel()
    op_link = int(rng.integers(0, d))
    header = HEADER.pack(
        b"HLMU", VERSION, flags, epoch, seq, rng.uniform(0, 100), int(rng.integers(0, 2**62)), d, n,
        j, op_link, rng.uniform(0.01, 0.2), rng.uniform(-0.02, 0.02),
    )  # fmt: skip
    ints = np.concatenate(
        [rng.integers(0, 3, d), rng.integers(0, d, n), rng.integers(-(2**62), 2**62, n)]
    )
    floats = np.concatenate([g[name] for name, _ in groups])
    body = header + ints.astype("<i8").tobytes() + floats.astype("<f8").tobytes()
    body += random_chains(rng, d, op_link) if flags & 32 else b""
    cars = int(rng.integers(1, 9)) if flags & 64 else 0
    if cars:
        body += struct.pack("<qqdd", int(rng.integers(0, 2**62)), cars, *rng.uniform(-1, 1, 2))
    return body + (random_shapes(rng, n_shapes, cars) if flags & 16 else b"")


def random_chains(rng: np.random.Generator, d: int, op_link: int) -> bytes:
    """A valid CHAINS trailer: chain 0 (the tool, port 0) holds op_link, further chains start
    after it; every joint hangs from its chain's base or an earlier joint of its chain."""
    starts = [k for k in range(op_link + 1, d)]
    extra = rng.choice(starts, min(len(starts), int(rng.integers(0, MAX_CHAINS))), replace=False)
    first = np.array([0, *sorted(int(k) for k in extra)], np.int64)
    c = len(first)
    parents = np.zeros(d, np.int64)
    for i in range(d):
        lo = first[first <= i].max()
        parents[i] = -1 if i == lo or rng.uniform() < 0.2 else int(rng.integers(lo, i))
    rows = np.zeros((c, 3), np.int64)
    rows[:, 0] = first
    rows[1:, 1] = rng.integers(0, 4, c - 1)
    rows[1:, 2] = rng.integers(-1, MAX_PORTS, c - 1)
    bases = np.column_stack([rng.uniform(-0.3, 0.3, (c - 1, 2)), rng.uniform(-3, 3, c - 1)])
    head = np.array([c, *parents], "<i8").tobytes() + rows.astype("<i8").tobytes()
    return head + bases.astype("<f8").tobytes()


def random_shapes(rng: np.random.Generator, s: int, cars: int = 0) -> bytes:
    """A valid SHAPES trailer of s shapes: circles, segments and convex polygons (points on
    a circle in counter-clockwise order), random poses, twists and friction; with `cars`,
    some on a car of the train (motion 3)."""
    ints = np.zeros((s, SHAPE_INTS), np.int64)
    fl = np.zeros((s, SHAPE_FLOATS))
    keys = rng.choice(2**40, s, replace=False)
    for k in range(s):
        kind = int(rng.integers(0, 3))
        nv = (1, 2, int(rng.integers(3, MAX_VERTICES + 1)))[kind]
        if kind == 2:
            angles = np.linspace(0, 2 * np.pi, nv, endpoint=False) + rng.uniform(0, 1)
            verts = rng.uniform(0.005, 0.05) * np.column_stack([np.cos(angles), np.sin(angles)])
        else:
            verts = rng.uniform(-0.05, 0.05, (nv, 2))
        motion = int(rng.integers(0, 3 if kind == 1 else 2))  # nodal: segments only
        owner = -1
        if cars and rng.uniform() < 0.5:
            owner, motion = int(rng.integers(0, cars)), 3
        ints[k] = (keys[k], owner, kind, nv, rng.integers(0, 5), motion)
        fl[k, : 2 * nv] = verts.ravel()
        fl[k, 16] = rng.uniform(0.001, 0.01) if kind == 0 else rng.uniform(0.0, 0.002)
        fl[k, 17:20] = (*rng.uniform(-0.3, 0.3, 2), rng.uniform(-np.pi, np.pi))
        fl[k, 20:23] = (*rng.uniform(-0.5, 0.5, 2), rng.uniform(-5, 5))
        if motion == 2:
            fl[k, 19:23] = 0.0  # nodes about a pose of zero angle, no twist
        mu_k = rng.uniform(0, 1)
        fl[k, 23], fl[k, 24] = mu_k + rng.uniform(0, 0.3), mu_k
    head = np.array([s], "<i8").tobytes()
    return head + ints.astype("<i8").tobytes() + fl.astype("<f8").tobytes()


@st.composite
def valid_updates(draw: Any) -> bytes:
    """Shapes (dof, contacts) from hypothesis, so the edges 1, 12, 0 and 64 come up; the
    rest from a seeded generator (each hypothesis draw costs more than a whole check)."""
    d = draw(st.integers(1, MAX_DOF))
    n = draw(st.one_of(st.integers(0, 4), st.integers(0, MAX_CONTACTS)))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    j = int(rng.integers(0, 4))
    flags = int(rng.choice([0, 1, 4, 8, 9, 13, 16, 17, 29, 32, 41, 48, 61, 64, 80, 112]))
    flags |= 2 if j else 0
    s = draw(st.one_of(st.integers(1, 3), st.integers(1, MAX_SHAPES))) if flags & 16 else 0
    epoch, seq = (int(v) for v in rng.integers(1, 2**62, 2))
    return random_update(rng, d, n, j, flags, epoch, seq, s)


# --- breaking one field -------------------------------------------------------------------

#: field group -> the bound its entries must respect (docs/protocol.md, MessageLimits)
MAGNITUDE_BOUNDS = {
    "lengths": LIM.max_abs_position_m,
    "base": LIM.max_abs_position_m,
    "base_angle": LIM.max_abs_angle_rad,
    "op_point": LIM.max_abs_position_m,
    "q": max(LIM.max_abs_position_m, LIM.max_abs_angle_rad),
    "qd": LIM.max_abs_velocity,
    "mass": LIM.max_mass_entry,
    "lambda_inv": LIM.max_inverse_mass,
    "tool_pose": LIM.max_abs_position_m,  # x, y; the angle's bound is larger still
    "gravity": LIM.max_abs_generalized_force,
    "velocity_torque": LIM.max_abs_generalized_force,
}
#: per contact column -> a value out of range for it
CONTACT_BREAKS = {
    0: 2 * LIM.max_abs_position_m, 2: -2 * LIM.max_abs_position_m,
    4: 0.9, 6: 2 * LIM.max_abs_velocity, 8: -0.1, 9: 1.5, 10: 0.0, 11: -1.0,
    12: -1.0,
}  # fmt: skip
BREAKS = [
    "nonfinite", "magic", "version", "truncate", "pad", "count", "flag", "unknown_flag",
    "magnitude",
    "header_float", "not_spd", "asymmetric", "contact", "resisted_norm", "joint_type",
    "contact_link", "op_link", "shape",
]  # fmt: skip
#: ways to break one local shape (DESIGN-WAVE2 C4): (int field or float offset, value)
SHAPE_BREAKS = [
    "kind", "n_vert", "owner", "generation", "motion", "repeated_key", "nonconvex",
    "clockwise", "spare_vertex", "rounding", "pose", "spin", "speed", "friction",
    "static_below_kinetic", "nonfinite", "count", "negative_key", "tiny_segment", "star",
    "nodal_kind", "nodal_twist", "nodal_angle",
]  # fmt: skip


def set_float(raw: bytearray, offset: int, value: float) -> None:
    struct.pack_into("<d", raw, offset, value)


def break_update(raw: bytes, kind: str, draw: Any) -> bytes | None:
    """One field of a valid update made invalid; None if this update has no such field."""
    d, n, j, flags, groups = layout(raw)
    out = bytearray(raw)
    big = draw(st.sampled_from([1.5, 10.0, 1e6, 1e100, 1e300]))
    sign = draw(st.sampled_from([1.0, -1.0]))
    if kind == "nonfinite":  # a float of the body (the trailers' own cases break theirs)
        contacts_at, contact_floats = groups["contacts"]
        n_float = (contacts_at + 8 * contact_floats - HEADER.size) // 8 - (d + 2 * n)
        k = draw(st.integers(0, n_float - 1))
        value = draw(st.sampled_from([math.nan, math.inf, -math.inf]))
        set_float(out, HEADER.size + 8 * (d + 2 * n + k), value)
    elif kind == "header_float":  # sim_time, characteristic length or state lead
        offset, value = draw(
            st.sampled_from([(24, math.nan), (48, -0.01), (48, 0.0), (48, math.inf),
                             (48, 1e3), (56, 2.0), (56, -math.inf)])
        )  # fmt: skip
        set_float(out, offset, value)
    elif kind == "magic":
        k = draw(st.integers(0, 3))
        out[k] ^= draw(st.integers(1, 255))
    elif kind == "version":
        struct.pack_into(
            "<H", out, 4, draw(st.integers(0, 65535).filter(lambda v: v not in CONTACT_WIDTH))
        )
    elif kind == "truncate":
        return raw[: draw(st.integers(0, len(raw) - 1))]
    elif kind == "pad":
        return raw + draw(st.binary(min_size=1, max_size=64))
    elif kind == "count":
        offset, current = draw(st.sampled_from([(40, d), (42, n), (44, j)]))
        struct.pack_into(
            "<H", out, offset, draw(st.integers(0, 65535).filter(lambda v: v != current))
        )
    elif kind == "flag":  # a section (gravity, resisted, velocity torque, shapes, chains)
        struct.pack_into("<H", out, 6, flags ^ draw(st.sampled_from([1, 2, 8, 16, 32])))
    elif kind == "unknown_flag":  # a bit the protocol does not define
        struct.pack_into("<H", out, 6, flags | (1 << draw(st.integers(7, 15))))
    elif kind == "shape":
        return break_shape(raw, groups, draw)
    elif kind == "magnitude":
        name = draw(st.sampled_from(sorted(k for k in MAGNITUDE_BOUNDS if k in groups)))
        offset, count = groups[name]
        k = draw(st.integers(0, (2 if name == "tool_pose" else count) - 1))
        set_float(out, offset + 8 * k, sign * MAGNITUDE_BOUNDS[name] * big)
    elif kind in ("not_spd", "asymmetric"):
        offset, count = groups["mass"]
        mass = np.frombuffer(raw, "<f8", count, offset).reshape(d, d).copy()
        if kind == "asymmetric":
            if d < 2:
                return None
            a, b = draw(st.sampled_from([(r, c) for r in range(d) for c in range(d) if r != c]))
            mass[a, b] += np.abs(mass).max() * draw(st.sampled_from([1e-6, 1e-3, 1.0]))
        else:  # one eigenvalue clearly negative (a zero one is +-roundoff: not a sure break)
            w, v = np.linalg.eigh(mass)
            k = draw(st.integers(0, d - 1))
            w[k] = -w.max() * draw(st.sampled_from([1e-3, 1.0]))
            mass = v @ np.diag(w) @ v.T
            mass = 0.5 * (mass + mass.T)
        out[offset : offset + 8 * count] = mass.astype("<f8").tobytes()
    elif kind == "contact":
        if n == 0:
            return None
        offset, _ = groups["contacts"]
        i = draw(st.integers(0, n - 1))
        col = draw(st.sampled_from(sorted(CONTACT_BREAKS)))
        set_float(out, offset + 8 * (CONTACT_WIDTH[VERSION] * i + col), CONTACT_BREAKS[col])
    elif kind == "resisted_norm":
        if j == 0:
            return None
        offset, _ = groups["resisted"]
        k = draw(st.integers(0, j - 1))
        dirs = np.frombuffer(raw, "<f8", 3, offset + 24 * k) * draw(
            st.sampled_from([0.0, 0.5, 1.0 + 1e-4, 2.0])
        )
        out[offset + 24 * k : offset + 24 * k + 24] = dirs.astype("<f8").tobytes()
    elif kind == "joint_type":
        k = draw(st.integers(0, d - 1))
        struct.pack_into("<q", out, HEADER.size + 8 * k, draw(st.sampled_from([-1, 3, 2**40])))
    elif kind == "contact_link":
        if n == 0:
            return None
        k = draw(st.integers(0, n - 1))
        struct.pack_into("<q", out, HEADER.size + 8 * (d + k), draw(st.sampled_from([-1, d, 99])))
    elif kind == "op_link":
        struct.pack_into("<H", out, 46, draw(st.integers(d, 65535)))
    return bytes(out)


def break_shape(raw: bytes, groups: dict[str, tuple[int, int]], draw: Any) -> bytes | None:
    """One local shape of the trailer made invalid; None if the update has no shapes."""
    if "shapes" not in groups:
        return None
    at, s = groups["shapes"]
    out = bytearray(raw)
    k = draw(st.integers(0, s - 1))
    i_at = at + 8 + 8 * SHAPE_INTS * k  # this shape's ints
    f_at = at + 8 + 8 * SHAPE_INTS * s + 8 * SHAPE_FLOATS * k  # its floats
    kind, nv = struct.unpack_from("<qqqq", raw, i_at)[2:4]
    how = draw(st.sampled_from(SHAPE_BREAKS))
    if how == "kind":
        struct.pack_into("<q", out, i_at + 16, draw(st.sampled_from([-1, 3, 7, 2**40])))
    elif how == "n_vert":
        bad = {0: [0, 2, 3], 1: [1, 3, 0], 2: [0, 1, 2, 9, 100]}[kind]
        struct.pack_into("<q", out, i_at + 24, draw(st.sampled_from(bad)))
    elif how == "owner":
        # a car's index (0, 5) is an owner only with the AVARS trailer, where it may be valid
        cars = struct.unpack_from("<H", raw, 6)[0] & 64
        owners = [-2, 2**40] if cars else [-2, 0, 5, 2**40]
        struct.pack_into("<q", out, i_at + 8, draw(st.sampled_from(owners)))
    elif how == "generation":
        struct.pack_into("<q", out, i_at + 32, -1)
    elif how == "motion":
        struct.pack_into("<q", out, i_at + 40, draw(st.sampled_from([-1, 3, 99])))
    elif how == "repeated_key":
        if s < 2:
            return None
        other = (k + 1) % s
        key = struct.unpack_from("<q", raw, at + 8 + 8 * SHAPE_INTS * other)[0]
        struct.pack_into("<q", out, i_at, key)
    elif how in ("nonconvex", "clockwise"):
        if nv < 3 or (how == "nonconvex" and nv < 4):
            return None
        v = np.frombuffer(raw, "<f8", 2 * nv, f_at).reshape(nv, 2).copy()
        if how == "clockwise":
            v = v[::-1]
        else:  # pull one vertex inside the hull (past the centre)
            v[0] = -0.5 * v[0] + 0.5 * v[2]
        out[f_at : f_at + 16 * nv] = v.astype("<f8").tobytes()
    elif how == "spare_vertex":
        if nv == MAX_VERTICES:
            return None
        set_float(out, f_at + 8 * (2 * nv + 1), 0.01)
    elif how == "rounding":
        set_float(out, f_at + 8 * 16, -1e-3 if kind else 0.0)
    elif how == "pose":
        set_float(out, f_at + 8 * 17, 2 * LIM.max_abs_position_m)
    elif how == "spin":
        set_float(out, f_at + 8 * 22, -2 * LIM.max_abs_angular_velocity)
    elif how == "speed":
        set_float(out, f_at + 8 * 20, LIM.max_abs_velocity)
        set_float(out, f_at + 8 * 21, 0.01)
    elif how == "friction":
        set_float(out, f_at + 8 * 24, -0.1)
    elif how == "static_below_kinetic":
        set_float(out, f_at + 8 * 23, struct.unpack_from("<d", raw, f_at + 8 * 24)[0] - 0.05)
    elif how == "nonfinite":
        set_float(out, f_at + 8 * draw(st.integers(0, SHAPE_FLOATS - 1)), math.nan)
    elif how == "count":
        struct.pack_into("<q", out, at, draw(st.sampled_from([0, -1, s + 1, MAX_SHAPES + 1])))
    elif how == "negative_key":
        struct.pack_into("<q", out, i_at, draw(st.sampled_from([-1, -2, -(2**62)])))
    elif how == "tiny_segment":  # ends 1e-200 m apart: a point that divides by zero
        struct.pack_into("<qq", out, i_at + 16, 1, 2)
        ends = np.zeros(2 * MAX_VERTICES)
        ends[2] = 1e-200
        out[f_at : f_at + 8 * 2 * MAX_VERTICES] = ends.astype("<f8").tobytes()
    elif how == "nodal_kind":  # nodes held by the haptic side: segments only
        if kind == 1:
            return None
        struct.pack_into("<q", out, i_at + 40, 2)
    elif how in ("nodal_twist", "nodal_angle"):  # nodal: no twist, a pose of zero angle
        if kind != 1:
            return None
        struct.pack_into("<q", out, i_at + 40, 2)
        offset = draw(st.sampled_from([20, 21, 22])) if how == "nodal_twist" else 19
        value = draw(st.sampled_from([1e-9, 0.01, 0.5, -0.5]))
        set_float(out, f_at + 8 * offset, value)
    elif how == "star":  # a pentagram: a left turn at every vertex, not convex
        a = np.arange(5) * 4 * np.pi / 5
        verts = np.zeros(2 * MAX_VERTICES)
        verts[:10] = (0.01 * np.column_stack([np.cos(a), np.sin(a)])).ravel()
        struct.pack_into("<qq", out, i_at + 16, 2, 5)
        out[f_at : f_at + 8 * 2 * MAX_VERTICES] = verts.astype("<f8").tobytes()
    return bytes(out)


#: ways to break the tree and chains (DESIGN-WAVE2 C4: parents topologically ordered)
CHAIN_BREAKS = [
    "parent_after", "parent_self", "parent_below", "parent_other_chain", "count", "first_zero",
    "first_order", "first_beyond", "kind", "port", "tool_port", "op_link", "base", "nonfinite",
]  # fmt: skip


def break_chains(raw: bytes, draw: Any) -> bytes | None:
    """One rule of the CHAINS trailer broken; None if the update cannot break it."""
    d, _, _, _, groups = layout(raw)
    at, c = groups["chains"]
    out = bytearray(raw)
    p_at = at + 8  # parents
    r_at = at + 8 * (1 + d)  # chain rows
    b_at = r_at + 8 * 3 * c  # bases of chains 1..
    rows = np.frombuffer(raw, "<i8", 3 * c, r_at).reshape(c, 3)
    op_link = struct.unpack_from("<H", raw, 46)[0]
    how = draw(st.sampled_from(CHAIN_BREAKS))
    i = draw(st.integers(0, d - 1))
    if how == "parent_after":  # a parent that comes after its joint
        if i == d - 1:
            return None
        struct.pack_into("<q", out, p_at + 8 * i, draw(st.integers(i + 1, d - 1)))
    elif how == "parent_self":
        struct.pack_into("<q", out, p_at + 8 * i, i)
    elif how == "parent_below":
        struct.pack_into("<q", out, p_at + 8 * i, draw(st.sampled_from([-2, -99, -(2**62)])))
    elif how == "parent_other_chain":
        if c < 2:
            return None
        k = draw(st.integers(1, c - 1))
        if rows[k, 0] == 0:
            return None
        struct.pack_into("<q", out, p_at + 8 * int(rows[k, 0]), int(rows[k, 0]) - 1)
    elif how == "count":
        struct.pack_into("<q", out, at, draw(st.sampled_from([0, -1, MAX_CHAINS + 1, 2**40])))
    elif how == "first_zero":  # chain 0 must start at joint 0
        struct.pack_into("<q", out, r_at, draw(st.integers(1, 5)))
    elif how in ("first_order", "first_beyond"):
        if c < 2:
            return None
        k = draw(st.integers(1, c - 1))
        value = int(rows[k - 1, 0]) if how == "first_order" else d + draw(st.integers(0, 3))
        struct.pack_into("<q", out, r_at + 24 * k, value)
    elif how == "kind":
        k = draw(st.integers(0, c - 1))
        bad = [-1, 4, 99] if k else [1, 2, 3, -1]  # chain 0 is the tool
        struct.pack_into("<q", out, r_at + 24 * k + 8, draw(st.sampled_from(bad)))
    elif how == "port":
        k = draw(st.integers(0, c - 1))
        struct.pack_into("<q", out, r_at + 24 * k + 16, draw(st.sampled_from([-2, MAX_PORTS, 99])))
    elif how == "tool_port":  # chain 0 is port 0's
        struct.pack_into("<q", out, r_at + 16, -1)
    elif how == "op_link":  # the held link outside the tool's chain
        if c < 2:
            return None
        struct.pack_into("<H", out, 46, int(rows[1, 0]) + draw(st.integers(0, d - 1 - rows[1, 0])))
    elif how == "base":
        if c < 2:
            return None
        k = draw(st.integers(0, 3 * (c - 1) - 1))
        bound = LIM.max_abs_angle_rad if k % 3 == 2 else LIM.max_abs_position_m
        set_float(out, b_at + 8 * k, draw(st.sampled_from([1.5, 1e9])) * bound)
    elif how == "nonfinite":
        if c < 2:
            return None
        k = draw(st.integers(0, 3 * (c - 1) - 1))
        set_float(out, b_at + 8 * k, draw(st.sampled_from([math.nan, math.inf])))
    del op_link
    return bytes(out)


def reason_of_parse(raw: bytes) -> str:
    code = PARSER.parse(raw)
    return "" if code == 0 else Reason(code).tag


def assert_rejected_as(raw: bytes, broken: bytes | None, rule: str) -> None:
    """A valid update with one trailer field broken (None: nothing to break) is refused as
    `rule` (or `nonfinite`, or `size` for a count that no longer fits), by the parser and the
    reference alike, and logged as such."""
    assert reason_of_parse(raw) == "" and reference_accepts(raw)
    if broken is None:
        return
    reason = reason_of_parse(broken)
    assert reason in (rule, "nonfinite", "size"), reason
    assert not reference_accepts(broken)
    assert_logged_as_rejected(broken, reason)


def assert_logged_as_rejected(raw: bytes, reason: str) -> None:
    """The I/O process logs every received message; a hostile one must not break that."""
    rec = update_json(update_record(7, raw, reason, 0.0))
    assert rec["installed"] is False and rec["reason"] == reason
    assert rec["size_bytes"] == len(raw)


# --- the decoder --------------------------------------------------------------------------


@pytest.mark.slow
@cases("random_bytes")
@given(
    st.one_of(
        st.binary(max_size=2048),
        st.binary(max_size=2048).map(lambda b: b"HLMU\x01\x00" + b),  # past magic and version
    )
)
def test_random_bytes_are_rejected(raw: bytes) -> None:
    reason = reason_of_parse(raw)
    assert reason in KNOWN_REASONS
    assert not reference_accepts(raw)
    try:
        decode_update(raw)
        raise AssertionError("decode_update accepted random bytes")
    except MessageError as exc:
        assert exc.reason == reason
    assert_logged_as_rejected(raw, reason)


@pytest.mark.slow
@cases("valid")
@given(valid_updates())
def test_valid_updates_are_accepted(raw: bytes) -> None:
    assert reason_of_parse(raw) == ""
    assert reference_accepts(raw)
    back = decode_update(raw)
    assert encode_update(back) == raw  # nothing lost or altered by the validating decoder


@pytest.mark.slow
@cases("broken")
@given(valid_updates(), st.sampled_from(BREAKS), st.data())
def test_each_broken_field_is_rejected(raw: bytes, kind: str, data: st.DataObject) -> None:
    broken = break_update(raw, kind, data.draw)
    if broken is None:
        return
    reason = reason_of_parse(broken)
    assert reason in KNOWN_REASONS, kind
    assert not reference_accepts(broken), kind
    assert_logged_as_rejected(broken, reason)


@st.composite
def updates_with_shapes(draw: Any) -> bytes:
    d = draw(st.integers(1, MAX_DOF))
    s = draw(st.one_of(st.integers(1, 4), st.integers(1, MAX_SHAPES)))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    epoch, seq = (int(v) for v in rng.integers(1, 2**62, 2))
    return random_update(rng, d, int(rng.integers(0, 4)), 0, 16, epoch, seq, s)


@pytest.mark.slow
@cases("shapes")
@given(updates_with_shapes(), st.data())
def test_each_broken_shape_is_rejected_and_named(raw: bytes, data: st.DataObject) -> None:
    """Every v3 shape field (DESIGN-WAVE2 C4): a bad kind or vertex count, a non-convex or
    clockwise polygon, an owner other than the world, a repeated key, a twist, pose, rounding
    or friction beyond its bound, a NaN, a wrong count. Rejected as `shape` (or, for the
    NaN and the count that no longer fits, `nonfinite` and `size`), never a crash."""
    assert_rejected_as(raw, break_shape(raw, layout(raw)[4], data.draw), "shape")


@st.composite
def updates_with_chains(draw: Any) -> bytes:
    d = draw(st.integers(1, MAX_DOF))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    epoch, seq = (int(v) for v in rng.integers(1, 2**62, 2))
    flags = 32 | int(rng.choice([0, 16]))
    return random_update(rng, d, int(rng.integers(0, 4)), 0, flags, epoch, seq, 2)


@pytest.mark.slow
@cases("chains")
@given(updates_with_chains(), st.data())
def test_each_broken_chain_is_rejected_and_named(raw: bytes, data: st.DataObject) -> None:
    """The tree and chains (DESIGN-WAVE2 C1, C4): a parent after its joint, itself, below -1
    or in another chain; a wrong count; chains that do not start at 0 or out of order; a kind
    or port out of range, chain 0 not the tool of port 0, the held link outside it; a base
    beyond limits or not finite. Rejected as `chain` (or `nonfinite`, `size` for a count that
    no longer fits), never a crash."""
    assert_rejected_as(raw, break_chains(raw, data.draw), "chain")


@st.composite
def updates_with_avars(draw: Any) -> bytes:
    d = draw(st.integers(1, MAX_DOF))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    epoch, seq = (int(v) for v in rng.integers(1, 2**62, 2))
    flags = 64 | int(rng.choice([16, 16, 48]))
    return random_update(rng, d, int(rng.integers(0, 4)), 0, flags, epoch, seq, 4)


AVAR_BREAKS = (
    "static_id", "cars", "nonfinite", "s", "sd", "owner_beyond", "owner_world_track",
    "car_not_track",
)  # fmt: skip


def break_avars(raw: bytes, draw: Any) -> bytes | None:
    """One rule of the AVARS trailer, or of a shape's owner against it, broken; None if the
    update cannot break it."""
    _, _, _, _, groups = layout(raw)
    at, _ = groups["avars"]
    shapes_at, s = groups["shapes"]
    cars = struct.unpack_from("<q", raw, at + 8)[0]
    ints = np.frombuffer(raw, "<i8", SHAPE_INTS * s, shapes_at + 8).reshape(s, SHAPE_INTS)
    out = bytearray(raw)
    how = draw(st.sampled_from(AVAR_BREAKS))
    k = draw(st.integers(0, s - 1))
    row = shapes_at + 8 * (1 + SHAPE_INTS * k)
    if how == "static_id":
        struct.pack_into("<q", out, at, draw(st.sampled_from([-1, -(2**62)])))
    elif how == "cars":
        struct.pack_into("<q", out, at + 8, draw(st.sampled_from([0, -1, 9, 2**40])))
    elif how == "nonfinite":
        set_float(
            out, at + 16 + 8 * draw(st.integers(0, 1)), draw(st.sampled_from([math.nan, math.inf]))
        )
    elif how == "s":
        set_float(out, at + 16, draw(st.sampled_from([1.5, 1e9])) * LIM.max_abs_position_m)
    elif how == "sd":
        set_float(out, at + 24, draw(st.sampled_from([-1.5, 1e9])) * LIM.max_abs_velocity)
    elif how == "owner_beyond":  # a car the train does not have
        struct.pack_into("<q", out, row + 8, cars + draw(st.integers(0, 3)))
        struct.pack_into("<q", out, row + 40, 3)
    elif how == "owner_world_track":  # a world shape carried by the train
        if ints[k, 5] == 2:
            return None  # a nodal segment's pose rules come first
        struct.pack_into("<q", out, row + 8, -1)
        struct.pack_into("<q", out, row + 40, 3)
    elif how == "car_not_track":  # a car's shape carried by its own twist
        struct.pack_into("<q", out, row + 8, draw(st.integers(0, cars - 1)))
        struct.pack_into("<q", out, row + 40, draw(st.sampled_from([0, 1])))
    return bytes(out)


@pytest.mark.slow
@cases("avars")
@given(updates_with_avars(), st.data())
def test_each_broken_avar_is_rejected_and_named(raw: bytes, data: st.DataObject) -> None:
    """A train's animation variable (DESIGN-WAVE2 §5, C4): a negative static id, a car count
    out of 1..8, s or s' beyond limits or not finite, a shape on a car the train does not
    have, a world shape carried by the train, a car's shape carried by its twist. Rejected
    as `avar` (or `nonfinite`), never a crash."""
    assert_rejected_as(raw, break_avars(raw, data.draw), "avar")


@pytest.mark.slow
@cases("bit_flips")
@given(
    valid_updates(),
    st.lists(st.tuples(st.integers(0, 2**31), st.integers(0, 7)), min_size=1, max_size=4),
)
def test_bit_flips_agree_with_the_reference(valid: bytes, flips: list[tuple[int, int]]) -> None:
    """Arbitrary corruption: the decoder accepts exactly what the protocol allows."""
    raw = bytearray(valid)
    for position, bit in flips:
        raw[position % len(raw)] ^= 1 << bit
    reason = reason_of_parse(bytes(raw))
    assert (reason == "") == reference_accepts(bytes(raw)), reason


# --- the proxy decoder (what the sim receives) ---------------------------------------------


def proxy_bytes(rng: np.random.Generator, d: int) -> bytes:
    """A valid proxy state from a random tick row, through the one encoder."""
    row = np.zeros(1, TICK_DTYPE)
    r = row[0]
    r["update_epoch"], r["update_seq"] = int(rng.integers(1, 2**40)), int(rng.integers(0, 2**40))
    r["tick"], r["t"] = int(rng.integers(0, 2**40)), float(rng.uniform(0, 100))
    r["dof"], r["safe"] = d, float(rng.integers(0, 2))
    r["proxy_q"][:d] = rng.uniform(-1, 1, d)
    r["proxy_qd"][:d] = rng.uniform(-1, 1, d)
    r["device_pose"] = rng.uniform(-1, 1, 3)
    r["device_twist"] = rng.uniform(-1, 1, 3)
    wait = UpdateWait(
        int(rng.integers(0, 2**40)), int(rng.integers(0, MAX_WAIT_NS)), int(rng.integers(1, 10**7))
    )
    return encode_proxy(row, int(rng.integers(0, 4)), int(rng.integers(0, 2**62)), wait)


@pytest.mark.slow
@cases("proxy")
@given(
    st.integers(0, MAX_DOF),
    st.integers(0, 2**32 - 1),
    st.lists(st.tuples(st.integers(0, 2**31), st.integers(0, 255)), max_size=4),
    st.sampled_from(["none", "truncate", "pad", "nonfinite", "huge"]),
    st.binary(max_size=300),
)
def test_proxy_decoder_rejects_or_returns_sane_state(
    d: int, seed: int, edits: list[tuple[int, int]], kind: str, noise: bytes
) -> None:
    """The sim's decoder: anything it accepts is finite and bounded; anything else is a
    MessageError (never another exception that would stop the sim)."""
    rng = np.random.default_rng(seed)
    raw = bytearray(proxy_bytes(rng, d))
    for position, value in edits:
        raw[position % len(raw)] = value
    body = PROXY_HEADER.size
    if kind == "truncate":
        raw = raw[: seed % len(raw)]
    elif kind == "pad":
        raw += noise or b"\0"
    elif kind in ("nonfinite", "huge") and len(raw) > body:
        k = seed % ((len(raw) - body) // 8)
        set_float(raw, body + 8 * k, math.nan if kind == "nonfinite" else 1e300)
    for candidate in (bytes(raw), noise):
        try:
            p = decode_proxy(candidate)
        except MessageError:
            continue
        values = np.concatenate([p.q, p.qd, p.device_pose, p.device_twist])
        assert np.isfinite(values).all() and math.isfinite(p.haptic_time)
        assert np.abs(values).max(initial=0.0) <= LIM.max_abs_angle_rad
        w = p.wait  # what the sim's phase lock reads: none, or a wait within its bounds
        assert w == NO_WAIT or (
            w.seq >= 0 and 0 <= w.wait_ns <= MAX_WAIT_NS and w.tick_period_ns > 0
        )


# --- a live engine ------------------------------------------------------------------------

SCENE = load_scene("free_box")
USER = load_user("waypoints")
DEVICE_CONFIG = load_device("ideal").config
MAX_WRENCH = np.array(IdealDevice(DEVICE_CONFIG).limits().max_wrench)

ACTIONS = st.one_of(
    st.tuples(st.just("valid"), st.integers(0, 2**32 - 1)),
    st.tuples(st.just("broken"), st.integers(0, 2**32 - 1), st.sampled_from(BREAKS)),
    st.tuples(st.just("random"), st.binary(max_size=600)),
    st.tuples(st.just("ticks"), st.integers(1, 12)),
    st.tuples(st.just("replay"), st.integers(0, 2**32 - 1)),
    st.tuples(st.just("old_epoch"), st.integers(0, 2**32 - 1)),
    st.tuples(st.just("new_epoch"), st.integers(0, 2**32 - 1)),
    st.tuples(st.just("oversize"), st.integers(1, 64)),
    st.tuples(st.just("stale"), st.just(0)),
)


class EngineHarness:
    """A HapticEngine with the books a test keeps: what was sent, what must have happened."""

    def __init__(self) -> None:
        # updates at the parser's limits, not of the scene's tool: the kernels' own
        # robustness, below the plausibility check (test_plausible.py covers that)
        self.engine = HapticEngine(SCENE, IdealDevice(DEVICE_CONFIG), USER, 0.04).unguarded()
        self.epoch = 1_000
        self.seq = 0
        self.installed = 0
        self.rejected: dict[str, int] = {}
        self.reinitialisations = 0

    def update(self, seed: int, epoch: int | None = None, seq: int | None = None) -> bytes:
        """One of ENGINE_POOL stamped with an epoch and a sequence number (by default the
        next of the current epoch)."""
        raw = bytearray(ENGINE_POOL[seed % len(ENGINE_POOL)])
        epoch = self.epoch if epoch is None else epoch
        struct.pack_into("<QQ", raw, 8, epoch, self.seq + 1 if seq is None else seq)
        return bytes(raw)

    def send_valid(self, raw: bytes, epoch: int, seq: int) -> None:
        e = self.engine
        new_epoch = epoch != self.epoch
        reinit = e.ready and (new_epoch or e.stale)
        assert e.receive(raw) == ""
        self.epoch, self.seq = epoch, seq
        self.installed += 1
        self.reinitialisations += int(reinit)
        assert (e.epoch, e.last_seq) == (epoch, seq)

    def send_bad(self, raw: bytes | int) -> None:
        """A message that must be rejected: counted by its reason, nothing installed. An int
        is a mailbox slot length as the I/O process marks an oversize message (< 0)."""
        e = self.engine
        before = (e.slots.tobytes(), e.state.tobytes(), e.epoch, e.last_seq)
        if isinstance(raw, int):
            reason = reason_of(e.receive_buffer(e.buffer, raw))
        else:
            reason = e.receive(raw)
        assert reason in KNOWN_REASONS
        self.rejected[reason] = self.rejected.get(reason, 0) + 1
        assert (e.slots.tobytes(), e.state.tobytes(), e.epoch, e.last_seq) == before

    def ticks(self, k: int) -> None:
        for _ in range(k):
            row = self.engine.tick(SCENE_DT)[0]
            for name in ("wrench_command", "wrench_applied"):
                w = row[name]
                assert np.isfinite(w).all(), name
                assert (np.abs(w) <= MAX_WRENCH).all(), name
            assert np.isfinite(row["device_pose"]).all()

    def check_books(self) -> None:
        c = self.engine.counters
        assert c.installed == self.installed
        assert c.rejected == sum(self.rejected.values())
        assert c.rejected_by_reason == self.rejected
        assert c.reinitialisations == self.reinitialisations


SCENE_DT = 1.0 / SCENE.haptic_rate_hz
EDGE = 0.99  # "at the limit": a fraction of each bound, so the message is still valid


def extreme_update(rng: np.random.Generator) -> bytes:
    """A valid update at the edges of MessageLimits: stiff, fast, ill-conditioned, heavy
    gravity, contacts in deep penetration. The kernels must still command only finite
    wrenches within the device limits."""
    n = int(rng.integers(1, 9))
    raw = bytearray(random_update(rng, 3, n, 1, 1 | 2 | 8, 1, 0))
    _, _, _, _, groups = layout(bytes(raw))
    w = 10.0 ** rng.uniform(-5, 5.9, 3)  # eigenvalues over 11 decades, entries < 1e6
    v, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    mass = v @ np.diag(w) @ v.T
    values = {
        "mass": 0.5 * (mass + mass.T),
        "qd": rng.choice([-1.0, 1.0], 3) * LIM.max_abs_velocity * EDGE,
        "gravity": rng.choice([-1.0, 1.0], 3) * LIM.max_abs_generalized_force * EDGE,
        "velocity_torque": rng.uniform(-1, 1, 3) * LIM.max_abs_generalized_force * EDGE,
    }
    for name, value in values.items():
        offset, count = groups[name]
        raw[offset : offset + 8 * count] = np.ravel(value).astype("<f8").tobytes()
    offset, _ = groups["contacts"]
    width = CONTACT_WIDTH[VERSION]
    c = np.frombuffer(bytes(raw), "<f8", width * n, offset).reshape(n, width).copy()
    c[:, 10] = LIM.max_stiffness_n_per_m * EDGE
    c[:, 11] = LIM.max_damping_ns_per_m * EDGE
    c[:, 2:4] = c[:, 0:2] + 0.05 * c[:, 4:6]  # the tool point 5 cm inside the surface
    raw[offset : offset + 8 * width * n] = c.astype("<f8").tobytes()
    assert reference_accepts(bytes(raw))
    return bytes(raw)


_POOL_RNG = np.random.default_rng(8)
#: valid updates for the engine (d = 3: a tool keeps its dof within an epoch), a quarter of
#: them at the edges of the limits
ENGINE_POOL = [
    random_update(_POOL_RNG, 3, int(n), int(j), int(f) | (2 if j else 0), 1, 0)
    for n, j, f in zip(
        _POOL_RNG.integers(0, 5, 48), _POOL_RNG.integers(0, 2, 48),
        _POOL_RNG.choice([0, 1, 8, 9, 13], 48), strict=True,
    )
] + [extreme_update(_POOL_RNG) for _ in range(16)]  # fmt: skip


@pytest.mark.slow
@cases("engine")
@given(st.integers(0, 2**32 - 1), st.lists(ACTIONS, min_size=1, max_size=30), st.data())
def test_live_engine_under_interleaved_garbage(
    first: int, actions: list[Any], data: st.DataObject
) -> None:
    h = EngineHarness()
    h.ticks(2)  # before any model: nothing rendered, nothing to break
    h.send_valid(h.update(first, seq=0), h.epoch, 0)
    for action in actions:
        kind = action[0]
        if kind == "valid":
            h.send_valid(h.update(action[1]), h.epoch, h.seq + 1)
        elif kind == "broken":
            broken = break_update(h.update(action[1]), action[2], data.draw)
            if broken is not None:
                h.send_bad(broken)
        elif kind == "random":
            h.send_bad(action[1])
        elif kind == "replay":  # a valid message again, or an older one of this epoch
            h.send_bad(h.update(action[1], seq=max(0, h.seq - action[1] % 3)))
        elif kind in ("old_epoch", "new_epoch"):  # another sim's, or a restarted one's
            epoch = h.epoch + 1 if kind == "new_epoch" else h.epoch - 1 - action[1] % 5
            raw = h.update(action[1], epoch=epoch, seq=0)
            if h.engine.stale:  # after the watchdog: installed, re-initialises
                h.send_valid(raw, epoch, 0)
            else:  # while this epoch's updates flow: rejected, whichever is higher
                h.send_bad(raw)
        elif kind == "oversize":
            size = h.engine.buffer.shape[0] + action[1]
            h.send_bad(b"\0" * size if action[1] % 2 else -size)
        elif kind == "stale":
            h.engine.set_stale()
        else:
            h.ticks(action[1])
        h.check_books()
    h.ticks(3)
    h.check_books()

"""THE wire table of the local-model update (sim -> haptic), declared once.

Everything else is derived from the tables below: the header's struct and byte offsets, the
body's section order and sizes, the contact columns' offsets (module constants such as
`C_STIFFNESS`, which numba freezes into the parser), the parsed record `LOCAL_MODEL_DTYPE`,
the limits record, and the tables of docs/protocol.md (`markdown_tables`). To add a contact
column: one `Column` line below, then fill it in the sim (by name) and read it in the haptic
contact stage (`slot.c_<name>`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, fields

import numpy as np

from haptic_local_model.shared.kinematics import MAX_CHAINS, MAX_DOF, MAX_PORTS
from haptic_local_model.shared.protocol.codes import Flag
from haptic_local_model.shared.shapes import MAX_SHAPES, MAX_VERTICES, SHAPE_DTYPE

PROTOCOL_VERSION = 3  # what this build sends (3: the local shapes, DESIGN-WAVE2 C4)
SUPPORTED_VERSIONS = (1, 2, 3)  # what it parses (logs of the previous releases replay)
UPDATE_MAGIC = b"HLMU"
MAX_CONTACTS = 64
MAX_RESISTED = 3


@dataclass(frozen=True)
class HeaderField:
    name: str
    code: str  # struct format code (little-endian)
    unit: str
    doc: str


#: The fixed header, in wire order.
HEADER = (
    HeaderField("magic", "4s", "", 'b"HLMU"'),
    HeaderField("version", "H", "", f"protocol version ({PROTOCOL_VERSION})"),
    HeaderField(
        "flags",
        "H",
        "",
        "sections present (Flag: 1 gravity, 2 resisted, 4 tool touching, 8 velocity torque,"
        " 16 shapes, 32 chains, 64 avars)",
    ),
    HeaderField("epoch", "Q", "", "changes when the sim restarts or reloads"),
    HeaderField("seq", "Q", "", "update number within the epoch"),
    HeaderField("sim_time", "d", "s", "the sim's time of the state"),
    HeaderField("publish_time_ns", "q", "ns", "wall clock (Unix) at publication"),
    HeaderField("dof", "H", "", "d, tool degrees of freedom (1..12)"),
    HeaderField("n_contacts", "H", "", "n, contacts in the neighbourhood (0..64)"),
    HeaderField("n_resisted", "H", "", "j, directions resisted by the joints (0..3)"),
    HeaderField("op_link", "H", "", "link of the operational point (< d)"),
    HeaderField("characteristic_length", "d", "m", "scales the angular row of J_h"),
    HeaderField("state_lead_s", "d", "s", "the state holds this long after publication"),
)
HEADER_STRUCT = struct.Struct("<" + "".join(f.code for f in HEADER))
HEADER_BYTES = HEADER_STRUCT.size
HEADER_AT = {}  # byte offset of each header field
_offset = 0
for _f in HEADER:
    HEADER_AT[_f.name] = _offset
    _offset += struct.calcsize("<" + _f.code)
PUBLISH_TIME_AT = HEADER_AT["publish_time_ns"]
PUBLISH_TIME_END = PUBLISH_TIME_AT + 8  # a message shorter than this has no publish time


@dataclass(frozen=True)
class Section:
    """A run of the body: `size` = (constant, per d, per d^2, per j, per n) values."""

    name: str
    size: tuple[int, int, int, int, int]
    unit: str
    doc: str
    flag: int = 0  # present only when this header flag is set

    def count(self, d: int, j: int, n: int) -> int:
        c, per_d, per_dd, per_j, per_n = self.size
        return c + per_d * d + per_dd * d * d + per_j * j + per_n * n


#: int64 block, then float64 block, each in this order.
INT_SECTIONS = (
    Section("joint_types", (0, 1, 0, 0, 0), "", "0 revolute, 1 prismatic x, 2 prismatic y"),
    Section("contact_link", (0, 0, 0, 0, 1), "", "tool link of each contact"),
    Section("contact_key", (0, 0, 0, 0, 1), "", "feature-pair identity, stable across updates"),
)


@dataclass(frozen=True)
class Column:
    """One column of a contact row: its name (record field `c_<name>`), width, unit, and
    the bound the parser checks (a MessageLimits field, or a fixed range in words)."""

    name: str
    width: int
    unit: str
    bound: str
    doc: str
    since: int = 1  # the protocol version that added it (older messages lack it)


#: A contact row, in wire order; a column added later goes at the end, with its version.
CONTACT_COLUMNS = (
    Column("tool", 2, "m", "|x| <= max_abs_position_m", "contact point in the tool link's frame"),
    Column("env", 2, "m", "|x| <= max_abs_position_m", "environment point (world)"),
    Column("normal", 2, "", "unit length (1e-6)", "outward environment normal (world)"),
    Column("env_velocity", 2, "m/s", "|v| <= max_abs_velocity", "environment point velocity"),
    Column("friction", 1, "", "0 <= mu <= max_friction", "Coulomb coefficient mu"),
    Column("restitution", 1, "", "0 <= e <= 1", "Poisson restitution e"),
    Column("stiffness", 1, "N/m", "0 < K <= max_stiffness_n_per_m", "contact stiffness K_c"),
    Column("damping", 1, "N s/m", "0 <= B <= max_damping_ns_per_m", "contact damping B_c"),
    Column(
        "tangential_stiffness",
        1,
        "N/m",
        "0 <= K_t <= max_stiffness_n_per_m",
        "stick stiffness of Coulomb friction (version 1: K_t = K_c)",
        since=2,
    ),
)
CONTACT_AT = {}  # float offset of each column within a contact row
_offset = 0
for _c in CONTACT_COLUMNS:
    CONTACT_AT[_c.name] = _offset
    _offset += _c.width
CONTACT_FLOATS = _offset


def contact_floats(version: int) -> int:
    """Floats of a contact row in messages of `version`."""
    return sum(c.width for c in CONTACT_COLUMNS if c.since <= version)


CONTACT_FLOATS_V1 = contact_floats(1)
C_TOOL = CONTACT_AT["tool"]
C_ENV = CONTACT_AT["env"]
C_NORMAL = CONTACT_AT["normal"]
C_ENV_VELOCITY = CONTACT_AT["env_velocity"]
C_FRICTION = CONTACT_AT["friction"]
C_RESTITUTION = CONTACT_AT["restitution"]
C_STIFFNESS = CONTACT_AT["stiffness"]
C_DAMPING = CONTACT_AT["damping"]
C_TANGENTIAL_STIFFNESS = CONTACT_AT["tangential_stiffness"]

#: One contact row as a structured dtype (same bytes as CONTACT_FLOATS float64): the sim
#: fills rows by column name.
CONTACT_ROW_DTYPE = np.dtype(
    [(c.name, "<f8", (c.width,)) if c.width > 1 else (c.name, "<f8") for c in CONTACT_COLUMNS]
)


@dataclass(frozen=True)
class ShapeField:
    """One field of a local shape in the SHAPES trailer (the SHAPE_DTYPE field of that name)."""

    name: str
    width: int
    unit: str
    bound: str
    doc: str


#: The SHAPES trailer (flag 16, version 3), after the float sections: int64 s (the number of
#: shapes, <= MAX_SHAPES), then s rows of SHAPE_INTS int64, then s rows of SHAPE_FLOATS float64.
SHAPE_INT_FIELDS = (
    ShapeField("key", 1, "", ">= 0, unique in the update", "identity, stable across updates"),
    ShapeField(
        "owner",
        1,
        "",
        "-1; 0..cars-1 with motion 3 and AVARS",
        "-1: the world; k: car k of the train (shapes on tool links come with the tools)",
    ),
    ShapeField("kind", 1, "", "0, 1, 2", "0 circle, 1 segment, 2 convex polygon"),
    ShapeField("n_vert", 1, "", "1; 2; 3..8", "vertices of the core (by kind)"),
    ShapeField("generation", 1, "", ">= 0", "topology generation (deformables)"),
    ShapeField(
        "motion",
        1,
        "",
        "0..3; 3 iff owner >= 0",
        "pose carried by 0 ballistic, 1 screw motion; 2 nodal: a segment's nodes, held by the "
        "haptic side (pose angle and twist 0); 3 track: posed by the haptic side's train",
    ),
)
SHAPE_FLOAT_FIELDS = (
    ShapeField(
        "vertices",
        2 * MAX_VERTICES,
        "m",
        "|x| <= max_abs_position_m; convex, CCW",
        "core vertices about the COM, body frame; unused ones 0",
    ),
    ShapeField("rounding", 1, "m", "0 <= rho <= max_abs_position_m (> 0 circle)", "rho"),
    ShapeField("pose", 3, "m, rad", "|x| <= max_abs_position_m", "COM position and angle"),
    ShapeField(
        "twist",
        3,
        "m/s, rad/s",
        "<= max_abs_velocity, max_abs_angular_velocity",
        "COM velocity, angular velocity",
    ),
    ShapeField("static_friction", 1, "", "mu_k <= mu_s <= max_friction", "mu_s"),
    ShapeField("friction", 1, "", "0 <= mu_k <= max_friction", "mu_k"),
)
SHAPE_INTS = sum(f.width for f in SHAPE_INT_FIELDS)
SHAPE_FLOATS = sum(f.width for f in SHAPE_FLOAT_FIELDS)
SHAPE_AT = {}  # float offset of each float field within a shape row
_offset = 0
for _s in SHAPE_FLOAT_FIELDS:
    SHAPE_AT[_s.name] = _offset
    _offset += _s.width
S_VERTICES = SHAPE_AT["vertices"]
S_ROUNDING = SHAPE_AT["rounding"]
S_POSE = SHAPE_AT["pose"]
S_TWIST = SHAPE_AT["twist"]
S_STATIC_FRICTION = SHAPE_AT["static_friction"]
S_FRICTION = SHAPE_AT["friction"]


def shapes_words(n_shapes: int) -> int:
    """8-byte words of a SHAPES trailer of n_shapes shapes."""
    return 1 + (SHAPE_INTS + SHAPE_FLOATS) * n_shapes


#: The CHAINS trailer (flag 32, version 3; DESIGN-WAVE2 C1, C4), after the float sections and
#: before a SHAPES trailer: int64 c (chains, 1..MAX_CHAINS), d int64 `parents`, c rows of
#: CHAIN_INTS int64, then c - 1 rows of 3 float64, the base pose of chains 1 .. c - 1 (chain
#: 0's is the body's base and base_angle). Without it the joints are one serial chain,
#: parents[i] = i - 1: the encoder sends it only for a tree or several chains.
CHAIN_INT_FIELDS = (
    ShapeField("first", 1, "", "0 for chain 0, then increasing, < d", "its first joint"),
    ShapeField("kind", 1, "", "0..3; 0 for chain 0", "0 tool, 1 object, 2 hand, 3 avar"),
    ShapeField("port", 1, "", f"-1..{MAX_PORTS - 1}; 0 for chain 0", "device port, -1 none"),
)
CHAIN_INTS = len(CHAIN_INT_FIELDS)


#: The AVARS trailer (flag 64, version 3; DESIGN-WAVE2 §5), after a CHAINS trailer and
#: before a SHAPES trailer: the state of the scene's one animation variable, the arc length s
#: of the lead car of its train (used only to re-initialise: the haptic side integrates it).
AVAR_FIELDS = (
    ShapeField("static_id", 1, "", ">= 0", "the track and train (the `<ns>/static` message's)"),
    ShapeField("cars", 1, "", "1..8", "cars of the train (owners of the shapes on cars)"),
    ShapeField("s", 1, "m", "|s| <= max_abs_position_m", "the lead car's arc length"),
    ShapeField("sd", 1, "m/s", "|s'| <= max_abs_velocity", "its rate"),
)
AVAR_WORDS = len(AVAR_FIELDS)


def chains_words(d: int, n_chains: int) -> int:
    """8-byte words of a CHAINS trailer of n_chains chains over d joints."""
    return 1 + d + CHAIN_INTS * n_chains + 3 * (n_chains - 1)


FLOAT_SECTIONS = (
    Section("lengths", (0, 1, 0, 0, 0), "m", "link lengths"),
    Section("base", (2, 0, 0, 0, 0), "m", "base position (world)"),
    Section("base_angle", (1, 0, 0, 0, 0), "rad", "base orientation"),
    Section("op_point", (2, 0, 0, 0, 0), "m", "operational point in the frame of op_link"),
    Section("q", (0, 1, 0, 0, 0), "rad or m", "the sim's tool configuration"),
    Section("qd", (0, 1, 0, 0, 0), "rad/s or m/s", "its velocity"),
    Section("mass", (0, 0, 1, 0, 0), "kg, kg m, kg m^2", "D(q), row-major"),
    Section("lambda_inv", (9, 0, 0, 0, 0), "1/kg ...", "J_h D^-1 J_h^T, row-major"),
    Section("tool_pose", (3, 0, 0, 0, 0), "m, rad", "operational point pose at the sim"),
    Section("gravity", (0, 1, 0, 0, 0), "N or N m", "G(q)", Flag.GRAVITY),
    Section("velocity_torque", (0, 1, 0, 0, 0), "N or N m", "C(q, qd) qd", Flag.VELOCITY_TORQUE),
    Section("resisted", (0, 0, 0, 3, 0), "", "unit directions in the scaled space", Flag.RESISTED),
    Section("contacts", (0, 0, 0, 0, CONTACT_FLOATS), "", "one row per contact (below)"),
)


#: float values of the body present in every update (unflagged, not per contact), as
#: (constant, per d, per d^2): the parser's size check adds the flagged sections and rows
FIXED_FLOATS = tuple(
    sum(s.size[k] for s in FLOAT_SECTIONS if not s.flag and s.name != "contacts") for k in range(3)
)


def body_counts(
    d: int, j: int, n: int, flags: int, version: int = PROTOCOL_VERSION
) -> tuple[int, int]:
    """(int64 values, float64 values) of an update's body."""
    present = [s for s in INT_SECTIONS + FLOAT_SECTIONS if not s.flag or flags & s.flag]
    n_int = sum(s.count(d, j, n) for s in present if s in INT_SECTIONS)
    n_float = sum(s.count(d, j, n) for s in present if s in FLOAT_SECTIONS)
    return n_int, n_float - (CONTACT_FLOATS - contact_floats(version)) * n


def update_size(
    d: int,
    j: int,
    n: int,
    flags: int,
    version: int = PROTOCOL_VERSION,
    n_shapes: int = 0,
    n_chains: int = 1,
) -> int:
    """Bytes of an update with these counts and flags (and shapes, with Flag.SHAPES; chains,
    with Flag.CHAINS; the avars' fixed trailer with Flag.AVARS)."""
    n_int, n_float = body_counts(d, j, n, flags, version)
    trailer = shapes_words(n_shapes) if flags & Flag.SHAPES else 0
    trailer += chains_words(d, n_chains) if flags & Flag.CHAINS else 0
    trailer += AVAR_WORDS if flags & Flag.AVARS else 0
    return HEADER_BYTES + 8 * (n_int + n_float + trailer)


# --- limits ----------------------------------------------------------------------------------

#: A receiver takes an update only if its age (receiver's clock - publish time) is at most
#: this (the watchdog's default period: an update older than an outage never ends it) ...
DEFAULT_MAX_UPDATE_AGE_MS = 100.0
#: ... and at least minus this: how far the sim's clock may run ahead of the receiver's.
DEFAULT_CLOCK_SKEW_MS = 50.0


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
    max_abs_angular_velocity: float = 1.0e3  # rad/s: a local shape's spin


DEFAULT_LIMITS = MessageLimits()
LIMITS_DTYPE = np.dtype([(f.name, np.float64) for f in fields(MessageLimits)])


def limits_record(limits: MessageLimits = DEFAULT_LIMITS) -> np.ndarray:
    """The limits as the record the parser reads (LIMITS_DTYPE[1])."""
    rec = np.zeros(1, LIMITS_DTYPE)
    for f in fields(MessageLimits):
        rec[0][f.name] = getattr(limits, f.name)
    return rec


# --- the parsed record -----------------------------------------------------------------------

F8 = np.float64
I8 = np.int64

#: One local model as the haptic kernels read it: the wire fields, plus what the parser
#: derives (valid, has_*, the penalty projection).
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
        ("n_contacts", I8),
        ("c_link", I8, (MAX_CONTACTS,)),
        ("c_key", I8, (MAX_CONTACTS,)),
        # the tree and chains (Flag.CHAINS; otherwise one serial chain): shared.kinematics
        ("has_chains", I8),  # the update carries the CHAINS trailer
        ("parents", I8, (MAX_DOF,)),
        ("n_chains", I8),
        ("chain_first", I8, (MAX_CHAINS,)),
        ("chain_kind", I8, (MAX_CHAINS,)),
        ("chain_port", I8, (MAX_CHAINS,)),
        ("chain_base", F8, (MAX_CHAINS, 3)),  # chains 1..: x, y, angle (chain 0: base)
        # a train's animation variable (Flag.AVARS): shared.avar
        ("has_avars", I8),
        ("avar_static_id", I8),
        ("avar_cars", I8),
        ("avar_s", F8),
        ("avar_sd", F8),
        ("n_shapes", I8),  # local shapes (version 3, Flag.SHAPES; 0 otherwise)
        ("shapes", SHAPE_DTYPE, (MAX_SHAPES,)),
        *[
            (f"c_{c.name}", F8, (MAX_CONTACTS, c.width) if c.width > 1 else (MAX_CONTACTS,))
            for c in CONTACT_COLUMNS
        ],
    ]
)


# --- docs ------------------------------------------------------------------------------------


def markdown_tables() -> str:
    """The header, body and contact-row tables of docs/protocol.md."""
    lines = [
        f"Header ({HEADER_BYTES} bytes, little-endian, struct `{HEADER_STRUCT.format}`):",
        "",
        "| offset | field | type | unit | meaning |",
        "|---|---|---|---|---|",
    ]
    for f in HEADER:
        unit = f.unit or "-"
        lines.append(f"| {HEADER_AT[f.name]} | `{f.name}` | `{f.code}` | {unit} | {f.doc} |")
    lines += [
        "",
        "Body: the int64 sections, then the float64 sections, in this order (d = dof,",
        "j = n_resisted, n = n_contacts; a section with a flag is present only when it is set):",
        "",
        "| block | section | values | flag | unit | meaning |",
        "|---|---|---|---|---|---|",
    ]
    for block, sections in (("int64", INT_SECTIONS), ("float64", FLOAT_SECTIONS)):
        for s in sections:
            lines.append(
                f"| {block} | `{s.name}` | {_count_text(s.size)} | {s.flag or '-'} |"
                f" {s.unit or '-'} | {s.doc} |"
            )
    lines += [
        "",
        f"Contact row ({CONTACT_FLOATS} float64 values; a version-1 message has the"
        f" {CONTACT_FLOATS_V1} columns of version 1):",
        "",
        "| offset | column | width | unit | bound | since | meaning |",
        "|---|---|---|---|---|---|---|",
    ]
    for c in CONTACT_COLUMNS:
        lines.append(
            f"| {CONTACT_AT[c.name]} | `{c.name}` | {c.width} | {c.unit or '-'} | {c.bound} |"
            f" {c.since} | {c.doc} |"
        )
    lines += [
        "",
        f"SHAPES trailer (flag {int(Flag.SHAPES)}, version 3), after the float sections: int64"
        f" s (0..{MAX_SHAPES}), then s rows of {SHAPE_INTS} int64, then s rows of"
        f" {SHAPE_FLOATS} float64:",
        "",
        "| block | offset | field | width | unit | bound | meaning |",
        "|---|---|---|---|---|---|---|",
    ]
    for k, sf in enumerate(SHAPE_INT_FIELDS):
        lines.append(
            f"| int64 | {k} | `{sf.name}` | {sf.width} | {sf.unit or '-'} | {sf.bound} | {sf.doc} |"
        )
    for sf in SHAPE_FLOAT_FIELDS:
        lines.append(
            f"| float64 | {SHAPE_AT[sf.name]} | `{sf.name}` | {sf.width} | {sf.unit or '-'} |"
            f" {sf.bound} | {sf.doc} |"
        )
    lines += [
        "",
        f"CHAINS trailer (flag {int(Flag.CHAINS)}, version 3), after the float sections and"
        f" before a SHAPES trailer: int64 c (1..{MAX_CHAINS}), d int64 `parents` (joint i hangs"
        " from the tip of link parents[i], -1 from its chain's base; every parent before its"
        f" joint and in its chain), c rows of {CHAIN_INTS} int64, then c - 1 rows of 3 float64"
        " `base` (x m, y m within max_abs_position_m, angle rad within max_abs_angle_rad) of"
        " chains 1 .. c - 1. Absent: one serial chain (parents[i] = i - 1) at base, base_angle.",
        "",
        "| offset | field | bound | meaning |",
        "|---|---|---|---|",
    ]
    for k, cf in enumerate(CHAIN_INT_FIELDS):
        lines.append(f"| {k} | `{cf.name}` | {cf.bound} | {cf.doc} |")
    lines += [
        "",
        f"AVARS trailer (flag {int(Flag.AVARS)}, version 3), after a CHAINS trailer and before"
        f" a SHAPES trailer: {AVAR_WORDS} words, int64 then float64:",
        "",
        "| offset | field | unit | bound | meaning |",
        "|---|---|---|---|---|",
    ]
    for k, af in enumerate(AVAR_FIELDS):
        lines.append(f"| {k} | `{af.name}` | {af.unit or '-'} | {af.bound} | {af.doc} |")
    return "\n".join(lines) + "\n"


def _count_text(size: tuple[int, int, int, int, int]) -> str:
    names = ("", "d", "d^2", "j", "n")
    terms = []
    for value, name in zip(size, names, strict=True):
        if value:
            terms.append(f"{value}" if not name else (name if value == 1 else f"{value} {name}"))
    return " + ".join(terms) or "0"

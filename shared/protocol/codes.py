"""Integer codes that cross a boundary: rendering methods, loop faults, update verdicts, flags.

Each is an `IntEnum` (numba reads members as int64 constants, so kernels compare against
`Method.LOCAL_MODEL` directly) with the short tag that logs, counters and configs use.
"""

from __future__ import annotations

from enum import IntEnum, IntFlag


class Method(IntEnum):
    """The rendering method of a scene's [rendering] table (DESIGN §4)."""

    LOCAL_MODEL = 0  # seed 000: the configuration-space local model
    IMPEDANCE_ONLY = 1  # the local model without joint penalties (the seed's baseline)
    VIRTUAL_COUPLING = 2  # a spring-damper between device and proxy
    VIRTUAL_COUPLING_FOH = 3  # seed 002: servo to the sim's tool by first-order hold
    GOD_OBJECT = 4  # seed 003 §3: a finite-sphere god-object against the local shapes

    @property
    def tag(self) -> str:
        return self.name.lower()

    @classmethod
    def from_tag(cls, tag: str) -> Method:
        return cls[tag.upper()]


class Fault(IntEnum):
    """The haptic loop's own fault code, in the state record and the tick row."""

    NONE = 0
    NONFINITE = 1  # a NaN/Inf appeared in the command or the proxy: safe state at once
    RUNAWAY = 2  # the proxy moved faster, or held more energy, than the scene allows
    PASSIVITY = 3  # the device port gave out more energy than the passivity observer allows


class Reason(IntEnum):
    """An update's verdict: 0 installed, else why it was rejected (stable: logs keep them).

    1-15, 25-27 and 29 come from the validating parser, 16-18, 28 and 30 from the order and scene
    checks at install, 19-21 from the time check at install (the receiver's clock against
    the update's times), 22-24 from the plausibility check against the scene
    (haptic_server/stages/plausible.py)."""

    OK = 0
    SHORT = 1
    MAGIC = 2
    VERSION = 3
    DOF = 4
    CONTACTS = 5
    RESISTED = 6
    OP_LINK = 7
    SIZE = 8
    NONFINITE = 9
    CHARACTERISTIC_LENGTH = 10
    JOINT_TYPE = 11
    CONTACT_LINK = 12
    MAGNITUDE = 13
    MASS_MATRIX = 14
    CONTACT = 15
    STALE_EPOCH = 16
    SEQUENCE = 17
    DOF_CHANGE = 18
    LATE = 19  # older than max_update_age_ms when it arrived: the world has moved on
    FUTURE = 20  # published later than the receiver's clock allows (a forged or skewed time)
    EPOCH_AHEAD = 21  # 0.3 only: an epoch after the update's own publish time (not since)
    INCONSISTENT = 22  # fields that must agree do not: D, G, C qd, Lambda^-1, the tool pose
    # or the chain against the scene's tool at the update's own q
    IMPLAUSIBLE = 23  # beyond what the scene allows: speeds, energy, contact materials, depth
    JUMP = 24  # the tool (or the sequence) moved on farther than it could since the last one
    SHAPE = 25  # a local shape breaks a rule: kind and vertex count, a non-convex or clockwise
    # polygon, an owner other than the world, a repeated key, a twist or friction beyond limits
    CHAIN = 26  # the chains break a rule: a parent not before its joint or in another chain,
    # chains out of order, empty or too many, a kind or port out of range, the held link
    # outside chain 0, a base beyond limits
    AVAR = 27  # the AVARS trailer breaks a rule: a negative static id, a car count out of
    # range, s or s' beyond limits; or a shape on a car (owner >= 0) without it, beyond its
    # cars, or not carried by the train (motion 3), or a world shape carried by it
    STATIC = 28  # the update's track (its static id) is not the one this scene rides
    FLAGS = 29  # a header flag bit this protocol does not define (a newer peer or a forgery)
    UNBOUND = 30  # an epoch not the live sim's: another session holds the sim's liveliness

    @property
    def tag(self) -> str:
        return _REASON_TAGS.get(self, self.name.lower())


_REASON_TAGS = {Reason.STALE_EPOCH: "epoch", Reason.SEQUENCE: "sequence", Reason.DOF_CHANGE: "dof"}


def reason_tag(code: int) -> str:
    """A verdict code as its tag ("" never: 0 is "ok"); an unknown code reads as "size"."""
    try:
        return Reason(code).tag
    except ValueError:
        return "size"


class Flag(IntFlag):
    """Sections present in a local-model update (header flags)."""

    GRAVITY = 1
    RESISTED = 2
    TOUCHING = 4
    VELOCITY_TORQUE = 8
    SHAPES = 16  # version 3: the local shapes trail the body (layout.SHAPE_FIELDS)
    CHAINS = 32  # version 3: the tree and chains of the configuration (layout.CHAIN_FIELDS)
    AVARS = 64  # version 3: the animation variable of a train of cars (layout.AVAR_FIELDS)

"""The held tool of a scene as a chain (DESIGN §2): one construction for both servers.

The sim builds its pymunk tool and computes D, G, C qd and J_h from this chain; the haptic
server builds the same chain from the same scene to check what the sim sends
(haptic_server/stages/plausible.py): an update whose dynamics terms disagree with the
chain at the update's own q is refused. Moments of inertia are pymunk's, bit for bit
(shared/coupling.py), so both sides compute from the same numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from haptic_local_model.shared.config import BodySpec, SceneConfig
from haptic_local_model.shared.kinematics import MAX_DOF, chain_record, free_body_chain


@dataclass(frozen=True, eq=False)
class ToolChain:
    """The tool's chain record, operational point, gravity and the outline of each link's
    shape (a capsule a-b of radius r in the link's frame, enclosing the shape) for checking
    where a contact may touch it."""

    kind: str  # "body" or "linkage"
    chain: np.ndarray  # CHAIN_DTYPE[1]
    op_link: int
    op_point: np.ndarray  # (2,) in op_link's frame
    gravity: np.ndarray  # (2,) m/s^2
    outline_a: np.ndarray  # (d, 2) capsule ends per link, link frame
    outline_b: np.ndarray  # (d, 2)
    outline_radius: np.ndarray  # (d,)

    @property
    def dof(self) -> int:
        return int(self.chain[0]["dof"])

    @property
    def total_mass(self) -> float:
        return float(self.chain[0]["masses"].sum())


def tool_chain(scene: SceneConfig) -> ToolChain:
    """The chain of the scene's held tool: a free body (prismatic x, prismatic y, revolute,
    its mass and moment on the last) or the joints of a linkage."""
    tool = scene.tool
    gravity = np.array(scene.gravity, dtype=float)
    if tool.kind == "body":
        spec = scene.tool_body
        joint_types, lengths = free_body_chain()
        chain = chain_record(
            joint_types, lengths, np.zeros(2), 0.0, np.array([0.0, 0.0, spec.mass]),
            np.array([0.0, 0.0, spec.moment]), np.zeros((3, 2)),
        )  # fmt: skip
        a, b, r = _body_outline(spec)
        outline_a, outline_b = np.zeros((3, 2)), np.zeros((3, 2))
        outline_radius = np.zeros(3)
        outline_a[2], outline_b[2], outline_radius[2] = a, b, r
        op_link = 2
    else:
        lk = scene.tool_linkage
        n = len(lk.lengths)
        if n > MAX_DOF:
            raise ValueError(f"tool has {n} DOF; at most {MAX_DOF} supported")
        chain = chain_record(
            np.zeros(n, dtype=np.int64), np.array(lk.lengths, dtype=float),
            np.array(lk.base, dtype=float), lk.base_angle, np.array(lk.masses, dtype=float),
            np.array(lk.inertias, dtype=float), np.array(lk.com_offsets, dtype=float),
            np.array([lk.parent_of(i) for i in range(n)], dtype=np.int64),
        )  # fmt: skip
        outline_a = np.zeros((n, 2))
        outline_b = np.column_stack([np.array(lk.lengths, dtype=float), np.zeros(n)])
        outline_radius = np.full(n, lk.radius)
        op_link = tool.link
    return ToolChain(
        tool.kind, chain, op_link, np.array(tool.point, dtype=float), gravity,
        outline_a, outline_b, outline_radius,
    )  # fmt: skip


def _body_outline(spec: BodySpec) -> tuple[tuple[float, float], tuple[float, float], float]:
    """A capsule enclosing a body's shape in its own frame."""
    if spec.shape == "box":
        return (0.0, 0.0), (0.0, 0.0), 0.5 * float(np.hypot(*spec.size))
    if spec.shape == "circle":
        return (0.0, 0.0), (0.0, 0.0), spec.radius
    return spec.a, spec.b, spec.radius


#: the sim's tool tracks the proxy, and overshoots it when the proxy changes speed sharply:
#: its updates may move this much faster than the proxy's own bounds before they are refused
TRACKING_MARGIN = 1.5


@dataclass(frozen=True)
class ToolBounds:
    """How fast the scene's tool may move (SafetySpec, with its moving bodies): the proxy's
    bounds (the loop's runaway guard, the sim's check of proxy states); `tracking()` gives
    the sim's tool's (the haptic side's check of updates)."""

    speed: float  # m/s: the operational point
    spin: float  # rad/s: any link
    energy: float  # J: kinetic, every point of the tool at most speed + spin * reach

    def tracking(self) -> ToolBounds:
        m = TRACKING_MARGIN
        return ToolBounds(m * self.speed, m * self.spin, m * m * self.energy)


def tool_bounds(scene: SceneConfig) -> ToolBounds:
    """The scene's [safety] speeds plus twice its fastest kinematic body's (a tool it strikes
    rebounds at up to twice its speed), and the kinetic energy they allow the tool."""
    tool = tool_chain(scene)
    spin_kin = max(
        (
            abs(b.angular_velocity)
            + (2 * np.pi * abs(b.angle_amplitude) / b.angle_period_s if b.angle_period_s else 0)
            for b in scene.bodies
            if b.kind == "kinematic"
        ),
        default=0,
    )
    speed = scene.safety.max_tool_speed_m_per_s + 2.0 * scene.kinematic_speed_m_per_s
    spin = scene.safety.max_tool_angular_speed_rad_per_s + 2.0 * spin_kin
    c, d = tool.chain[0], tool.dof
    reach = float(c["lengths"][:d].sum() + np.abs(c["com_offsets"][:d]).sum())
    reach += float(np.abs(tool.op_point).sum() + tool.outline_radius.max())
    point_speed = speed + spin * reach
    energy = 0.5 * float(c["masses"][:d].sum()) * point_speed**2
    energy += 0.5 * float(c["inertias"][:d].sum()) * spin**2
    return ToolBounds(speed, spin, energy)

"""A string under tension in pymunk, and its segments as the haptic side's NODAL shapes
(DESIGN-WAVE2 §4, F2; config.DeformableSpec).

The string is `nodes` point masses from a to b: the two ends are pinned (anchors on the
static body), the others are free bodies of infinite moment (points), and each pair of
neighbours is joined by a zero-rest-length damped spring of stiffness k = T (n - 1) / L. A
zero-rest-length spring's tension is k times its length, so the straight string's tension is
T, and under a point load F at mid-span each half stays straight with the same ratio of
tension to length: the deflection is F L / (4 T) exactly, at any depth (the closed form the
membrane scene is checked against). pymunk applies a spring's force explicitly, so a substep
must satisfy 2 sqrt(k / m) h < 1 for the highest mode (checked at construction).

Each node is damped by two dashpots to the world (zero-stiffness damped springs along x and y,
c = damping_per_s times its mass): pymunk solves a dashpot's impulse implicitly after the
springs' and exerts none at rest, so the string's equilibrium is exactly the springs' (a drag
in the body's velocity function would scale the springs' impulses, applied before it, by
exp(-gamma h), and bias the deflection by as much).

The haptic side gets each segment as a SEGMENT with Motion.NODAL about its midpoint (no
twist: the haptic side holds the nodes between updates) and its force back through the proxy
state; that force is split over the segment's two nodes by where the proxy touches it.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pymunk

from haptic_local_model.shared.config import DeformableSpec, Material
from haptic_local_model.shared.shapes import Motion, ShapeKind, set_core


class Membrane:
    """One string of the world: its bodies, springs and segment keys."""

    def __init__(
        self, space: pymunk.Space, spec: DeformableSpec, material: Material, first_key: int,
        substep_s: float,
    ) -> None:  # fmt: skip
        self.spec = spec
        self.material = material
        n = spec.nodes
        k = spec.spring_stiffness
        node_mass = spec.mass / (n - 2)
        omega = spec.highest_mode_rad_s  # (the scene loader checks it too)
        if omega * substep_s >= 1.0:
            raise ValueError(
                f"deformables.{spec.name}: the string's highest mode ({omega:.0f} rad/s) needs "
                f"a sim substep under {1e3 / omega:.3f} ms for pymunk's explicit spring, got "
                f"{1e3 * substep_s:.3f} ms: raise sim_substeps, lower nodes or tension, or "
                "add mass"
            )
        ends = np.linspace(spec.a, spec.b, n)
        self.pinned = (pymunk.Vec2d(*ends[0]), pymunk.Vec2d(*ends[-1]))
        self.bodies: list[pymunk.Body] = []
        static = space.static_body
        dashpot = spec.damping_per_s * node_mass
        for x, y in ends[1:-1]:
            body = pymunk.Body(node_mass, math.inf)
            body.position = (float(x), float(y))
            space.add(body)
            if dashpot > 0.0:
                for ax, ay in ((1.0, 0.0), (0.0, 1.0)):  # 1 m away: the axis stays put
                    anchor = (float(x) + ax, float(y) + ay)
                    space.add(pymunk.DampedSpring(static, body, anchor, (0, 0), 1.0, 0.0, dashpot))
            self.bodies.append(body)
        c = spec.spring_damping_ns_per_m
        chain = [(static, self.pinned[0]), *((b, (0.0, 0.0)) for b in self.bodies)]
        chain.append((static, self.pinned[1]))
        for (b0, a0), (b1, a1) in itertools.pairwise(chain):
            space.add(pymunk.DampedSpring(b0, b1, a0, a1, 0.0, k, c))
        self.first_key = first_key
        self.keys = range(first_key, first_key + n - 1)
        self.published = self.nodes()  # the last sample the haptic side was sent
        self.every = 1  # sim steps per sample (set by the world from publish_hz)
        self.steps = 0

    def stepped(self) -> None:
        """One sim step done: every `every` steps the surface is sampled anew."""
        self.steps += 1
        if self.steps % self.every == 0:
            self.published = self.nodes()

    def nodes(self) -> np.ndarray:
        """The nodes' world positions, (nodes, 2), ends included."""
        inner = [tuple(b.position) for b in self.bodies]
        return np.array([tuple(self.pinned[0]), *inner, tuple(self.pinned[1])])

    def fill_row(self, row: np.void, segment: int, a: np.ndarray, b: np.ndarray) -> None:
        """Segment `segment` (nodes a -> b of the published sample, world) as a NODAL shape
        row (bit-identical between samples: the haptic side tells a new sample by a change)."""
        mid = 0.5 * (a + b)
        set_core(row, ShapeKind.SEGMENT, [a - mid, b - mid], self.spec.radius)
        row["key"] = self.first_key + segment
        row["generation"] = 0  # the topology never changes
        row["motion"] = int(Motion.NODAL)
        row["pose"] = (mid[0], mid[1], 0.0)
        row["twist"] = 0.0
        row["static_friction"] = self.material.static_coefficient
        row["friction"] = self.material.friction

    def midpoint(self, key: int) -> np.ndarray:
        """Segment `key`'s midpoint now (the centre the haptic side's arms start from)."""
        i = key - self.first_key
        nodes = self.nodes()
        return 0.5 * (nodes[i] + nodes[i + 1])

    def pushes(
        self, key: int, point: np.ndarray, force: np.ndarray
    ) -> list[tuple[pymunk.Body, np.ndarray, np.ndarray]]:
        """The force on segment `key` at `point` as forces on its free nodes (at each node,
        by the point's barycentric weight along the segment); a pinned end takes its share."""
        i = key - self.first_key
        nodes = self.nodes()
        a, b = nodes[i], nodes[i + 1]
        ab = b - a
        w = float(np.clip(np.dot(point - a, ab) / max(np.dot(ab, ab), 1e-300), 0.0, 1.0))
        out = []
        for node, share in ((i, 1.0 - w), (i + 1, w)):
            if 0 < node < len(nodes) - 1 and share > 0.0:
                out.append((self.bodies[node - 1], nodes[node], share * force))
        return out

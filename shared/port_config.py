"""Scenes of several ports on one co-simulated world (DESIGN-WAVE2 §2 C3, §6).

A port is a device, its map onto the world, a simulated user and the tool the device holds.
A port scene declares P = 2 ports and the free bodies the haptic side integrates at 1 kHz
with the tools (`haptic_server/stages/cosim.py`): the tools themselves, the grasped object,
and static walls. Dynamic bodies named in `sim_bodies` are not co-simulated: the sim steps
them (`sim-server --mirror`, sim_server/mirror.py). With `sim_contact = "wrench"` its mirror
of the co-simulated bodies pushes them and the haptic side takes the impulses they put on
the mirror; with "shape" they move on their own and the haptic side meets them as moving
shapes (DESIGN-WAVE2 §6).
Files live in `configs/ports/`; keys are checked as a scene's are, and an error names the
file and the key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from haptic_local_model.shared.config import (
    FRICTION_RANGE,
    BodySpec,
    Vec2,
    Vec3,
    load_config_file,
    read_toml,
    require,
    resolve,
    shipped,
    within,
    within_all,
)

MAX_PORTS = 2  # this wave's ports (DESIGN-WAVE2 C3: P <= 2)
MAX_COSIM_BODIES = 4  # co-simulated free bodies: the tools and the objects
# static walls, floors and posts: with a box and two pads, 64 shapes (DESIGN-WAVE2 §8)
MAX_STATIC_BODIES = 61
MAX_SIM_BODIES = 4  # dynamic bodies the sim steps, moving shapes at 1 kHz (with the static)
#: the largest scene range (`range_m`): half the station messages' POSE_LIMIT_M
#: (shared/protocol/station.py), so a body within it is within a message's limit in any
#: station's frame that is not farther off the world's origin than that
RANGE_LIMIT_M = 50.0


@dataclass(frozen=True)
class CosimContact:
    """Every co-simulated contact (seed 001 eq 8, DESIGN-WAVE2 §6): penalty k, b along the
    normal, a stick spring of ratio * k capped at mu f_n along the tangent."""

    stiffness_n_per_m: float = 15000.0
    damping_ns_per_m: float = 30.0
    friction: float = 0.5
    friction_stiffness_ratio: float = 1.0

    def __post_init__(self) -> None:
        within(self.stiffness_n_per_m, (1.0, 1e7), "stiffness_n_per_m", "N/m")
        within(self.damping_ns_per_m, (0.0, 1e4), "damping_ns_per_m", "N s/m")
        within(self.friction, FRICTION_RANGE, "friction")
        within(self.friction_stiffness_ratio, (0.0, 10.0), "friction_stiffness_ratio")


@dataclass(frozen=True)
class PortContact(CosimContact):
    """A port scene's contacts: besides the penalty and friction, a contact that starts
    penetrating while approaching faster than collision_speed collides, and a tick's
    colliding contacts are resolved by simultaneous impulses with restitution e
    (seed 001 eq 5-6; haptic_server/stages/cosim.py). Hand scenes have penalty contacts only."""

    impulses: bool = True
    restitution: float = 0.0
    collision_speed_m_per_s: float = 0.01

    def __post_init__(self) -> None:
        super().__post_init__()
        require(0.0 <= self.restitution <= 1.0, "restitution", "must be in [0, 1]")
        within(self.collision_speed_m_per_s, (0.0, 10.0), "collision_speed_m_per_s", "m/s")


@dataclass(frozen=True)
class PortSpec:
    """One device on the world: the tool body it holds (a dynamic body of the scene), its
    simulated user and device (names or paths, overridable on the command line), and the
    virtual coupling between the device and the tool."""

    name: str
    tool: str
    user: str
    device: str = "maglev"
    coupling_stiffness: Vec3 = (2000.0, 2000.0, 0.5)  # N/m, N/m, N m/rad
    coupling_damping: Vec3 = (40.0, 40.0, 0.01)  # N s/m, N s/m, N m s/rad
    # where the device starts, device frame (a lift starts low to use the device's range)
    device_start: Vec3 = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        require(bool(self.name), "name", "must not be empty")
        within_all(self.device_start, (-1.0, 1.0), "device_start")
        within_all(self.coupling_stiffness, (0.0, 1e6), "coupling_stiffness")
        within_all(self.coupling_damping, (0.0, 1e4), "coupling_damping")


@dataclass(frozen=True)
class PortSceneConfig:
    """Two ports and the bodies co-simulated with their tools."""

    name: str
    description: str = ""
    gravity: Vec2 = (0.0, -9.81)
    haptic_rate_hz: float = 1000.0
    contact: PortContact = field(default_factory=PortContact)
    ports: tuple[PortSpec, ...] = ()
    bodies: tuple[BodySpec, ...] = ()
    # dynamic bodies the sim steps (sim-server --mirror), and how they meet the co-simulated
    # ones: "wrench", the sim's mirror pushes them and their contact wrench on it is applied
    # in the world (two-way, momentum kept, at the sim's rate), or "shape", obstacles that
    # move on their own: moving shapes of infinite mass in the co-simulation's contacts at
    # 1 kHz, which the mirror does not touch (one-way)
    sim_bodies: tuple[str, ...] = ()
    sim_contact: str = "wrench"
    # an object beyond it (|x| or |y|, m) returns to its start pose (haptic_server/stages/
    # cosim.py, step 5): a world with no floor does not throw its box out of what a
    # station's messages can carry (POSE_LIMIT_M)
    range_m: float = 10.0

    def __post_init__(self) -> None:
        within_all(self.gravity, (-100.0, 100.0), "gravity", "m/s^2")
        within(self.range_m, (0.01, RANGE_LIMIT_M), "range_m", "m")
        within(self.haptic_rate_hz, (100.0, 20000.0), "haptic_rate_hz", "Hz")
        self._check_sim_bodies()
        require(
            1 <= len(self.ports) <= MAX_PORTS,
            "ports",
            f"declares {len(self.ports)} ports; this build co-simulates 1 to {MAX_PORTS}",
        )
        names = [b.name for b in self.bodies]
        require(len(set(names)) == len(names), "bodies", "body names must be unique")
        dynamic = self.dynamic_bodies
        static = self.static_bodies
        require(
            len(dynamic) <= MAX_COSIM_BODIES,
            "bodies",
            f"{len(dynamic)} dynamic bodies; at most {MAX_COSIM_BODIES} are co-simulated",
        )
        require(
            len(static) <= MAX_STATIC_BODIES,
            "bodies",
            f"{len(static)} static bodies and sim bodies; at most {MAX_STATIC_BODIES}",
        )
        for i, b in enumerate(self.bodies):
            require(
                b.kind != "kinematic",
                f"bodies[{i}].kind",
                "kinematic bodies are not co-simulated (static or dynamic)",
            )
            require(
                b.shape != "segment" or b.kind == "static",
                f"bodies[{i}].shape",
                "a co-simulated body is a box or a circle",
            )
        tools = [p.tool for p in self.ports]
        require(len(set(tools)) == len(tools), "ports", "two ports hold the same tool")
        for i, p in enumerate(self.ports):
            require(
                p.tool in [b.name for b in dynamic],
                f"ports[{i}].tool",
                f"{p.tool!r} is not a dynamic body of the scene",
            )
        require(len(dynamic) > len(tools), "bodies", "needs an object besides the tools")

    def _check_sim_bodies(self) -> None:
        sim = self.sim_bodies
        require(self.sim_contact in ("wrench", "shape"), "sim_contact", "wrench or shape")
        require(len(set(sim)) == len(sim), "sim_bodies", "names a body twice")
        require(len(sim) <= MAX_SIM_BODIES, "sim_bodies", f"at most {MAX_SIM_BODIES}")
        tools = {p.tool for p in self.ports}
        for i, name in enumerate(sim):
            body = next((b for b in self.bodies if b.name == name), None)
            require(body is not None, f"sim_bodies[{i}]", f"{name!r} is no body of the scene")
            require(
                body is not None and body.kind == "dynamic",
                f"sim_bodies[{i}]",
                f"{name!r} is not a dynamic body",
            )
            require(name not in tools, f"sim_bodies[{i}]", f"{name!r} is a port's tool")

    @property
    def dynamic_bodies(self) -> list[BodySpec]:
        """The co-simulated bodies (the sim's bodies are not)."""
        return [b for b in self.bodies if b.kind == "dynamic" and b.name not in self.sim_bodies]

    def cosim_order(self) -> list[str]:
        """The co-simulated bodies in q's order: the tools in port order, then the objects."""
        tools = [p.tool for p in self.ports]
        return tools + [b.name for b in self.dynamic_bodies if b.name not in tools]

    @property
    def sim_body_specs(self) -> list[BodySpec]:
        """The bodies the sim steps, in `sim_bodies`' order."""
        return [self.body(name) for name in self.sim_bodies]

    @property
    def static_bodies(self) -> list[BodySpec]:
        """The co-simulation's walls: the static bodies, then the sim's bodies (moving)."""
        return [b for b in self.bodies if b.kind == "static"] + self.sim_body_specs

    def body(self, name: str) -> BodySpec:
        return next(b for b in self.bodies if b.name == name)

    @property
    def period_s(self) -> float:
        return 1.0 / self.haptic_rate_hz

    def squeeze_frequency_hz(self) -> float:
        """The stiffest co-simulated mode: the lightest body between two contacts,
        sqrt(2 k / m) / 2 pi (DESIGN-WAVE2 §6)."""
        lightest = min(b.mass for b in self.dynamic_bodies)
        return math.sqrt(2.0 * self.contact.stiffness_n_per_m / lightest) / (2.0 * math.pi)


def load_port_scene(name_or_path: str) -> PortSceneConfig:
    """A port scene by name (`configs/ports/<name>.toml`) or path."""
    return load_config_file(PortSceneConfig, "ports", name_or_path)[0]


@dataclass(frozen=True)
class FingerSpec:
    """A finger of two revolute phalanges hanging from the palm's front edge: capsules of
    the given radius along each phalanx (DESIGN-WAVE2 §7)."""

    lengths: Vec2 = (0.02, 0.015)  # m
    masses: Vec2 = (0.005, 0.004)  # kg
    inertias: Vec2 = (2.0e-7, 1.0e-7)  # kg m^2 about each phalanx's centre
    radius: float = 0.004  # m
    rest: Vec2 = (0.0, 0.0)  # rad: the joint angles the glove reads at the start
    flexion: float = 1.0  # +1: a positive joint angle closes the finger; -1: a mirrored one

    def __post_init__(self) -> None:
        within_all(self.lengths, (1e-3, 0.2), "lengths", "m")
        within_all(self.masses, (1e-4, 1.0), "masses", "kg")
        within_all(self.inertias, (1e-10, 1e-2), "inertias", "kg m^2")
        within(self.radius, (1e-4, 0.05), "radius", "m")
        within_all(self.rest, (-math.pi, math.pi), "rest", "rad")
        require(self.flexion in (-1.0, 1.0), "flexion", "must be 1 or -1")


@dataclass(frozen=True)
class HandSpec:
    """The mass-spring hand (DESIGN-WAVE2 §7): a palm box (x, y, theta) with fingers of two
    phalanges, coupled to the tracked palm and to the glove's joint angles by springs with
    the corrected signs, the drives solved implicitly (`haptic_server/stages/hand.py`)."""

    palm_size: Vec2 = (0.04, 0.015)  # m: the fingers hang from the middle of the front edge
    palm_mass: float = 0.2
    palm_inertia: float = 3.0e-5
    fingers: tuple[FingerSpec, ...] = (
        FingerSpec(rest=(0.3, 0.2)),
        FingerSpec(rest=(-0.3, -0.2), flexion=-1.0),
    )
    palm_spring: Vec3 = (500.0, 500.0, 0.5)  # k_t, k_t, k_theta
    palm_damping: Vec3 = (20.0, 20.0, 0.01)
    joint_spring: float = 0.2  # k_j, N m/rad
    joint_damping: float = 1.0e-4  # d_j, N m s/rad
    damping: str = "relative"  # relative: b (v_t - v_s); absolute: -b v_s (seed 002's)
    glove: str = "unilateral"  # none | bilateral | unilateral
    glove_max_torque: float = 0.3  # N m: the glove's actuators' limit per joint

    def __post_init__(self) -> None:
        within_all(self.palm_size, (1e-3, 0.5), "palm_size", "m")
        within(self.palm_mass, (1e-3, 10.0), "palm_mass", "kg")
        within(self.palm_inertia, (1e-9, 1.0), "palm_inertia", "kg m^2")
        require(1 <= len(self.fingers) <= 4, "fingers", "1 to 4 fingers")
        within_all(self.palm_spring, (0.0, 1e6), "palm_spring")
        within_all(self.palm_damping, (0.0, 1e4), "palm_damping")
        within(self.joint_spring, (0.0, 1e4), "joint_spring", "N m/rad")
        within(self.joint_damping, (0.0, 1e2), "joint_damping", "N m s/rad")
        require(self.damping in ("relative", "absolute"), "damping", "relative or absolute")
        within(self.glove_max_torque, (1e-4, 10.0), "glove_max_torque", "N m")
        require(
            self.glove in ("none", "bilateral", "unilateral"),
            "glove",
            "none, bilateral or unilateral",
        )

    @property
    def dof(self) -> int:
        return 3 + 2 * len(self.fingers)


#: a hand scene's static walls, floors and posts (haptic_server/stages/hand.py: MAX_WALLS)
MAX_HAND_WALLS = 4


@dataclass(frozen=True)
class HandTable(HandSpec):
    """A hand of a hand scene: HandSpec's keys, the name a port's `tool` gives, and where
    its palm starts (x, y, theta in the world; its fingers at their rest angles)."""

    name: str = "hand"
    pose: Vec3 = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        within_all(self.pose[:2], (-1.0, 1.0), "pose[0:2]", "m")
        within(self.pose[2], (-2.0 * math.pi, 2.0 * math.pi), "pose[2]", "rad")


@dataclass(frozen=True)
class HandSceneConfig:
    """One or two ports whose tools are mass-spring hands (DESIGN-WAVE2 §7,
    `configs/ports/hand_*`): each port's device drives its hand's tracked palm, its user's
    `finger_angles` the glove; the hand's palm command goes to the device. Static walls and
    posts; with two hands, one free box they hold (`hand_grasp`: both hands and the box in
    one implicit step, haptic_server/stages/hand_grasp.py). A hand's palm springs are its
    port's coupling: the port's coupling_* keys are not used."""

    name: str
    description: str = ""
    gravity: Vec2 = (0.0, 0.0)
    haptic_rate_hz: float = 1000.0
    contact: CosimContact = field(default_factory=CosimContact)
    ports: tuple[PortSpec, ...] = ()
    hands: tuple[HandTable, ...] = ()
    bodies: tuple[BodySpec, ...] = ()
    # a box beyond it (|x| or |y|, m) returns to its start (stages/hand_grasp.py), as a port
    # scene's objects do
    range_m: float = 10.0

    def __post_init__(self) -> None:
        within_all(self.gravity, (-100.0, 100.0), "gravity", "m/s^2")
        within(self.range_m, (0.01, RANGE_LIMIT_M), "range_m", "m")
        within(self.haptic_rate_hz, (100.0, 20000.0), "haptic_rate_hz", "Hz")
        require(1 <= len(self.ports) <= MAX_PORTS, "ports", f"a hand scene has 1 to {MAX_PORTS}")
        require(len(self.hands) == len(self.ports), "hands", "a hand scene has one hand a port")
        names = [h.name for h in self.hands]
        require(len(set(names)) == len(names), "hands", "two hands of one name")
        for i, port in enumerate(self.ports):
            require(port.tool in names, f"ports[{i}].tool", f"{port.tool!r} is none of {names}")
        require(
            len({p.tool for p in self.ports}) == len(self.ports),
            "ports",
            "two ports hold one hand",
        )
        walls = [b for b in self.bodies if b.kind == "static"]
        free = [(i, b) for i, b in enumerate(self.bodies) if b.kind != "static"]
        require(len(walls) <= MAX_HAND_WALLS, "bodies", f"at most {MAX_HAND_WALLS} static")
        for i, b in free:
            require(b.kind == "dynamic" and b.shape == "box", f"bodies[{i}]",
                    "a hand scene's free body is a dynamic box")  # fmt: skip
        if len(self.ports) == 2:
            require(len(free) == 1, "bodies", f"two hands hold one dynamic box ({len(free)} here)")
            require(not walls, "bodies", "two hands on a box: no static bodies (the box would "
                    "not meet them: not built)")  # fmt: skip
        else:
            require(not free, "bodies", "one hand: static bodies only (a box needs two hands)")

    @property
    def period_s(self) -> float:
        return 1.0 / self.haptic_rate_hz

    def hand_of(self, p: int) -> HandTable:
        """Port p's hand."""
        return next(h for h in self.hands if h.name == self.ports[p].tool)

    @property
    def walls(self) -> tuple[BodySpec, ...]:
        return tuple(b for b in self.bodies if b.kind == "static")

    @property
    def box(self) -> BodySpec | None:
        """The box two hands hold, if any."""
        return next((b for b in self.bodies if b.kind != "static"), None)


def is_hand_scene(data: dict[str, Any]) -> bool:
    """A port scene's table declares hands: a hand scene."""
    return "hands" in data


def load_hand_scene(name_or_path: str) -> HandSceneConfig:
    """A hand scene by name (`configs/ports/<name>.toml`) or path."""
    return load_config_file(HandSceneConfig, "ports", name_or_path)[0]


def shipped_port_scenes(hands: bool) -> list[str]:
    """The shipped port scenes with hands (hands=True) or with two co-simulated tools (a
    scene of one port, `box_push`, is neither)."""
    out = []
    for name in shipped("ports"):
        data = read_toml(resolve("ports", name))
        if is_hand_scene(data) == hands and (hands or len(data.get("ports", ())) == MAX_PORTS):
            out.append(name)
    return sorted(out)


def shipped_station_scenes() -> list[str]:
    """The shipped scenes a shared world serves to stations: every two-tool port scene and
    every scene of two hands on a box."""
    hands = [n for n in shipped_port_scenes(hands=True) if len(load_hand_scene(n).ports) == 2]
    return shipped_port_scenes(hands=False) + hands

"""A user's own pymunk space, touchable: the sim's local model over a space we did not build.

`UserSpaceWorld(space, tool_body)` checks what the space holds (`check_space`: an element we
cannot render raises `UnsupportedSpaceError` naming it; one we render differently warns with
`SpaceWarning`, saying what is rendered instead), writes the scene the haptic side renders it
with (`scene_text`: the rates, the gains and the held body, as a scene file holds them, so a
log of the run names it and `haptic-replay` rebuilds it), and builds the local model from the
space with the one builder (sim_server/space_model.py). Its `step` is the scene world's: the
tool driven toward the proxy and the user's space stepped, in one compiled call
(sim_server/drive.py), so the proxy's pushes reach the user's bodies through the tool's
contacts in their own space.

What a user's body keeps: its mass, moment, shapes, friction and elasticity (a contact's
friction and restitution are the touched shape's own). What it takes from us: the tool's
shapes get friction and elasticity 1 (pymunk multiplies a pair's: the touched shape's alone
is then what is simulated and what is felt, as in our scenes), and every contact the
stiffness and damping of `contact` (pymunk has none).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pymunk

from haptic_local_model.shared.config import (
    FRICTION_RANGE,
    Material,
    RenderingSpec,
    SceneConfig,
    load_config_text,
    softened_coordination,
)
from haptic_local_model.shared.tool_chain import tool_chain
from haptic_local_model.sim_server.drive import DRIVE_PROXY, KINEMATIC_DTYPE
from haptic_local_model.sim_server.held_chain import ChainError, HeldChain, find_held_chain
from haptic_local_model.sim_server.local_model import TOOL_GROUP, StageStats
from haptic_local_model.sim_server.shapes import LocalShapes
from haptic_local_model.sim_server.space_model import SpaceLocalModel
from haptic_local_model.sim_server.tool_drive import ToolDrive
from haptic_local_model.sim_server.world import TOOL_FRICTION, ToolTarget

#: what a contact of a user's space feels like where pymunk has no number for it
DEFAULT_CONTACT = Material(stiffness_n_per_m=15000.0, damping_ns_per_m=20.0)
#: the scene's name for a user's space and its held body (in the log's scene text)
USER_SCENE, USER_TOOL = "user_space", "tool"
#: a tool's centre of gravity this far (m) off its body's origin is refused: a free tool's
#: chain (shared/tool_chain.py) has its mass at the origin
COG_TOLERANCE_M = 1.0e-9


class UnsupportedSpaceError(ValueError):
    """A user's space holds what cannot be rendered: names the body, shape or constraint."""


class SpaceWarning(UserWarning):
    """A user's space holds what is rendered differently: says what is rendered instead."""


def _name(thing: object, index: int) -> str:
    """A body, shape or constraint as a message names it: its type and its index in the
    space's list of its kind (space.bodies, space.shapes, space.constraints)."""
    if isinstance(thing, pymunk.Shape) and thing.body is not None:
        return f"{type(thing).__name__} #{index} (on body at {tuple(thing.body.position)})"
    return f"{type(thing).__name__} #{index}"


def _finite_body(body: pymunk.Body, index: int) -> None:
    values = (*body.position, body.angle, *body.velocity, body.angular_velocity)
    if not all(math.isfinite(v) for v in values):
        raise UnsupportedSpaceError(
            f"{_name(body, index)}: its position, angle or velocity is not finite "
            f"(position {tuple(body.position)}, angle {body.angle}): nothing can be rendered"
        )


def _check_tool(space: pymunk.Space, tool: pymunk.Body, free: bool, held: bool = True) -> None:
    """The held body (or a link of the held chain): in the space, dynamic, of finite positive
    mass and moment, a free body's mass at its origin, with shapes of area."""
    bodies = list(space.bodies)
    if tool not in bodies:
        raise UnsupportedSpaceError("the tool body is not in the space (space.add it first)")
    name = _name(tool, bodies.index(tool))
    if tool.body_type != pymunk.Body.DYNAMIC:
        kind = "static" if tool.body_type == pymunk.Body.STATIC else "kinematic"
        raise UnsupportedSpaceError(
            f"tool {name} is {kind}: a hand can only hold a dynamic body (nothing rendered)"
        )
    for value, what in ((tool.mass, "mass"), (tool.moment, "moment")):
        if not (math.isfinite(value) and value > 0.0):
            raise UnsupportedSpaceError(
                f"tool {name} has {what} {value}: the tool needs a finite {what} > 0 "
                "(give its shapes a density or the body a mass and moment)"
            )
    if free and math.hypot(*tool.center_of_gravity) > COG_TOLERANCE_M:
        raise UnsupportedSpaceError(
            f"tool {name} has its centre of gravity at {tuple(tool.center_of_gravity)}, off "
            "its origin: a free tool's mass must be at its body's origin"
        )
    if held and not _shapes_of(tool, space):
        raise UnsupportedSpaceError(f"tool {name} has no shapes: it can touch nothing")
    shapes = list(space.shapes)
    for shape in _shapes_of(tool, space):
        if _extent(shape) <= 0.0:
            raise UnsupportedSpaceError(
                f"tool shape {_name(shape, shapes.index(shape))} has zero size: the tool "
                "needs a shape of area"
            )


def _check_constraints(space: pymunk.Space, tool: pymunk.Body, chain: HeldChain | None) -> None:
    """Constraints on the held body or chain: its own pivots are the chain; a spring acts in
    the user's space but is not felt; any other joint is refused."""
    held = set(chain.bodies) if chain is not None else {tool}
    pivots = set(chain.joints) if chain is not None else set()
    for index, c in enumerate(space.constraints):
        if c in pivots or not ({c.a, c.b} & held):
            continue
        if isinstance(c, pymunk.DampedSpring | pymunk.DampedRotarySpring):
            warnings.warn(
                f"{_name(c, index)} on the tool: not rendered (the hand feels the tool as "
                "free; the spring acts in the simulation only, felt late through the tool)",
                SpaceWarning,
                stacklevel=3,
            )
            continue
        raise UnsupportedSpaceError(
            f"{_name(c, index)} joins the held body or chain to another body: a held chain "
            "is rendered only as PivotJoints from a static body (DESIGN §2)"
        )


def _check_world(space: pymunk.Space, held: set[pymunk.Body]) -> list[pymunk.Shape]:
    """The world shapes the tool may touch (not those of the `held` bodies); sensors,
    zero-size shapes and shapes in the tool's filter group are named in a warning."""
    rendered = []
    for index, shape in enumerate(space.shapes):
        if shape.body in held:
            continue
        name = _name(shape, index)
        if type(shape) not in (pymunk.Circle, pymunk.Segment, pymunk.Poly):
            raise UnsupportedSpaceError(f"shape {name}: an unsupported shape type")
        if shape.sensor:
            warnings.warn(
                f"shape {name} is a sensor: not rendered (no contact is felt)",
                SpaceWarning,
                stacklevel=3,
            )
            continue
        if shape.filter.group == TOOL_GROUP:
            warnings.warn(
                f"shape {name} is in filter group {TOOL_GROUP}, the tool's: not rendered",
                SpaceWarning,
                stacklevel=3,
            )
            continue
        if _extent(shape) <= 0.0:
            warnings.warn(
                f"shape {name} has zero size: rendered as a point (a contact only at it)",
                SpaceWarning,
                stacklevel=3,
            )
        rendered.append(shape)
    return rendered


def check_space(space: pymunk.Space, tool: pymunk.Body) -> list[pymunk.Shape]:
    """What of `space` is rendered when `tool` is held: its world shapes. Raises
    UnsupportedSpaceError for what cannot be rendered; warns (SpaceWarning) for what is
    rendered differently."""
    return _inspect(space, tool)[0]


def _inspect(space: pymunk.Space, tool: pymunk.Body) -> tuple[list[pymunk.Shape], HeldChain | None]:
    """check_space's world shapes and the held chain `tool` is a link of (None: free)."""
    for index, body in enumerate(space.bodies):
        _finite_body(body, index)
    if tool not in space.bodies:
        raise UnsupportedSpaceError("the tool body is not in the space (space.add it first)")
    try:
        chain = find_held_chain(space, tool)
    except ChainError as e:
        raise UnsupportedSpaceError(str(e)) from e
    _check_tool(space, tool, chain is None)
    for body in chain.bodies if chain is not None else ():
        _check_tool(space, body, False, body is tool)
    _check_constraints(space, tool, chain)
    g = space.gravity
    if not all(math.isfinite(v) for v in g):
        raise UnsupportedSpaceError(f"the space's gravity {tuple(g)} is not finite")
    held = set(chain.bodies) if chain is not None else {tool}
    return _check_world(space, held), chain


def _shapes_of(body: pymunk.Body, space: pymunk.Space | None) -> list[pymunk.Shape]:
    """A body's shapes in `space`, in the space's order (pymunk's body.shapes also holds
    shapes made on it and never added, such as the local model's inflated query copies)."""
    if space is None:
        return []
    return [s for s in space.shapes if s.body is body]


def _extent(shape: pymunk.Shape) -> float:
    """The farthest point of a shape from its body's origin (m); 0 for a shape of no size."""
    if isinstance(shape, pymunk.Circle):
        return math.hypot(*shape.offset) + shape.radius if shape.radius > 0.0 else 0.0
    if isinstance(shape, pymunk.Segment):
        if shape.radius <= 0.0 and shape.a == shape.b:
            return 0.0
        return max(math.hypot(*shape.a), math.hypot(*shape.b)) + shape.radius
    assert isinstance(shape, pymunk.Poly)
    verts = shape.get_vertices()
    area = abs(pymunk.area_for_poly(verts, 0.0))
    if area <= 0.0 and shape.radius <= 0.0:
        return 0.0
    return max(math.hypot(*v) for v in verts) + shape.radius


def _tool_shape_toml(tool: pymunk.Body) -> str:
    """The held body's outline as a scene's body table holds it: its circle if it is one
    centred circle, else a box enclosing its shapes (only where contacts may touch it is
    checked with it; its contacts are its real shapes')."""
    shapes = _shapes_of(tool, tool.space)
    one = shapes[0]
    if len(shapes) == 1 and isinstance(one, pymunk.Circle) and one.offset == (0.0, 0.0):
        return f'shape = "circle"\nradius = {one.radius!r}\n'
    reach = max(_extent(s) for s in shapes)
    side = math.sqrt(2.0) * reach  # half its diagonal is the reach
    return f'shape = "box"\nsize = [{side!r}, {side!r}]\n'


def coordination_gains(tool: pymunk.Body, rate_hz: float) -> tuple[str, str]:
    """The `[rendering]` lines of a held free body's coordination coupling ("" when the
    defaults are stable on it) and, if softened, the warning that says so. The coupling acts
    on the proxy, a copy of the held body: SceneConfig._check_coordination's bound
    K dt^2 + 2 B dt < 2 m on each axis (the mass, or the moment about the third); a body
    too light for the defaults gets both gains of that axis softened
    (shared.config.softened_coordination), so the device follows the proxy more loosely
    instead of chattering."""
    defaults = RenderingSpec()
    ks, bs, softened = softened_coordination(
        (defaults.coordination_stiffness, defaults.coordination_damping),
        tool.mass, tool.moment, rate_hz,
    )  # fmt: skip
    if not softened:
        return "", ""
    lines = f"coordination_stiffness = {ks!r}\ncoordination_damping = {bs!r}\n"
    return lines, (
        f"the held body ({tool.mass:g} kg, {tool.moment:g} kg m^2) is lighter than the "
        f"coordination coupling's default gains render stably at {rate_hz:g} Hz (a body of "
        f"at least {' and '.join(dict.fromkeys(softened))}): its coupling is softened to "
        f"stiffness {[float(f'{k:.4g}') for k in ks]}, damping "
        f"{[float(f'{b:.4g}') for b in bs]} (the device follows it more loosely)"
    )


def scene_text(
    space: pymunk.Space,
    tool: pymunk.Body,
    rate_hz: float,
    substeps: int,
    touched: Material,
    margin_m: float,
    chain: HeldChain | None = None,
    coordination: str = "",
) -> str:
    """The scene the haptic side renders a user's space with, as TOML: the rates, the held
    body (its mass, moment and pose) and `touched`, the material whose friction and
    restitution are the highest of the world's shapes (the haptic side checks every contact
    against the scene's materials); no other bodies (the world is the user's space). A held
    `chain` is the scene's linkage, held at its body's centre of gravity."""
    gx, gy = space.gravity
    contact = touched
    x, y = tool.position
    if chain is not None:
        px, py = tool.center_of_gravity
        kind = f'"linkage"\nlink = {chain.held}\npoint = [{float(px)!r}, {float(py)!r}]'
        held = chain.toml(USER_TOOL, USER_TOOL)
    else:
        kind = '"body"'
        held = (
            f'[[bodies]]\nname = "{USER_TOOL}"\nkind = "dynamic"\nmaterial = "{USER_TOOL}"\n'
            f"{_tool_shape_toml(tool)}"
            f"mass = {float(tool.mass)!r}\nmoment_kg_m2 = {float(tool.moment)!r}\n"
            f"position = [{float(x)!r}, {float(y)!r}]\nangle = {float(tool.angle)!r}\n"
        )
    return (
        f'name = "{USER_SCENE}"\n'
        'description = "a user\'s own pymunk space (haptic_local_model.api)"\n'
        f"gravity = [{float(gx)!r}, {float(gy)!r}]\n"
        f"sim_rate_hz = {float(rate_hz)!r}\nsim_substeps = {int(substeps)}\n\n"
        f'[tool]\nkind = {kind}\nname = "{USER_TOOL}"\n'
        f"neighbourhood_margin_m = {float(margin_m)!r}\n\n"
        f'[rendering]\nmethod = "local_model"\n{coordination}\n'
        f"[materials.{USER_TOOL}]\n"
        f"stiffness_n_per_m = {contact.stiffness_n_per_m!r}\n"
        f"damping_ns_per_m = {contact.damping_ns_per_m!r}\n"
        f"friction = {contact.friction!r}\nrestitution = {contact.restitution!r}\n\n"
        f"{held}"
    )


class UserSpaceWorld:
    """A user's pymunk space with one held body, as the virtual clock and the sim server
    drive a scene's world: `step(target)`, `local_model_bytes(...)`, `time`, `stats`."""

    def __init__(
        self,
        space: pymunk.Space,
        tool: pymunk.Body,
        rate_hz: float = 60.0,
        substeps: int = 10,
        contact: Material = DEFAULT_CONTACT,
        margin_m: float = 0.02,
        after_step: Callable[[float], None] | None = None,
    ) -> None:
        """after_step: the user's own code of a step of their loop, called after each step
        with the space's time (s)."""
        rendered, chain = _inspect(space, tool)
        self.after_step = after_step
        self.space, self.tool_body = space, tool
        self.held_chain = chain
        self._tool_bodies = list(chain.bodies) if chain is not None else [tool]
        # the live view's names and tools (sim_server/world_view.py): the user's bodies are
        # drawn by their index, the held one (or its chain) as the tool
        self.tool_bodies = self._tool_bodies
        self.body_names: dict[pymunk.Body, str] = {tool: "tool"}
        # a user's space is rendered by the local model's contacts, never as a god-object's
        # local shapes (SimWorld.local_shapes; the sim server's summary reads it)
        self.local_shapes: LocalShapes | None = None
        materials: dict[tuple[float, float], Material] = {}
        for shape in rendered:
            _shape_material(shape, contact, materials)
        friction = max((f for f, _ in materials), default=0.0)
        restitution = max((e for _, e in materials), default=0.0)
        self._touched = _shape_material(_Surface(friction, restitution), contact, {})
        coordination, softened = "", ""
        if chain is None:
            coordination, softened = coordination_gains(tool, SceneConfig.haptic_rate_hz)
        if softened:
            name = _name(tool, list(space.bodies).index(tool))
            warnings.warn(f"body {name}: {softened}", SpaceWarning, stacklevel=2)
        self.text = scene_text(
            space, tool, rate_hz, substeps, self._touched, margin_m, chain, coordination
        )
        self.scene: SceneConfig = load_config_text(SceneConfig, self.text, "user space")
        self.time = 0.0
        self.period = 1.0 / self.scene.sim_rate_hz
        self.substeps = self.scene.sim_substeps
        # the touched shape's friction alone (module docstring)
        for shape in (s for b in self._tool_bodies for s in _shapes_of(b, space)):
            shape.friction = shape.elasticity = TOOL_FRICTION
        self._chain = tool_chain(self.scene)
        self._contact = contact
        self._build(rendered)
        self._drive = ToolDrive(np.zeros(0, KINEMATIC_DTYPE))  # the user moves their own

    def _build(self, rendered: list[pymunk.Shape]) -> None:
        """The local model's builder over the space's shapes now (`rendered`: those of the
        world). A shape's friction or elasticity above the scene's material (set from the
        space's shapes at the start) is clipped to it: the haptic side refuses a contact
        beyond its scene's materials. The shapes are kept alive, so a shape the user
        removes cannot leave its address to a new one."""
        keys = {s: k for k, s in enumerate(self.space.shapes)}  # registration order
        top = self._touched
        made: dict[tuple[float, float], Material] = {}
        env = []
        for shape in rendered:
            surface = _Surface(
                min(float(shape.friction), top.friction),
                min(float(shape.elasticity), top.restitution),
            )
            env.append((shape, keys[shape], _shape_material(surface, self._contact, made)))
        self._rendered = rendered
        self._shape_count = len(self.space.shapes)
        bodies = self._tool_bodies
        links = range(len(bodies)) if self.held_chain is not None else [2]  # a free body: q[2]
        tool_shapes = [
            (s, link)
            for b, link in zip(bodies, links, strict=True)
            for s in _shapes_of(b, self.space)
        ]
        self.model = SpaceLocalModel(
            self.space, bodies, tool_shapes, self._chain, env,
            self.scene.tool, self.scene.rendering,
        )  # fmt: skip

    def step(self, target: ToolTarget | None) -> None:
        """One period: the tool driven toward the proxy (held at rest without a fresh
        target) and the user's space stepped `substeps` times (one compiled call)."""
        self._drive.aim(target, DRIVE_PROXY)
        self._drive.step(self.model.tool, self._chain.chain, self.time, self.period, self.substeps)
        self.time += self.period
        if self.after_step is not None:
            self.after_step(self.time)

    def local_model_bytes(
        self, epoch: int, seq: int, publish_time_ns: int, state_lead_s: float = 0.0
    ) -> bytes:
        """The encoded local model at the tool's current state (as SimWorld's); the world's
        shapes are taken again when the space's count of shapes has changed (a shape added
        and another removed within one step are seen at the next change of count)."""
        if len(self.space.shapes) != self._shape_count:
            self._build(_check_world(self.space, set(self._tool_bodies)))
        self.model.build()
        return self.model.encode(epoch, seq, self.time, publish_time_ns, state_lead_s)

    @property
    def stats(self) -> StageStats:
        """What the last local model's query found (a free tool: no SVD)."""
        m, counts = self.model.record[0], self.model.kernel.counts
        return StageStats(
            svd=self.held_chain is not None,
            gravity=bool(m["has_gravity"]),
            contacts_sent=int(m["n_contacts"]),
            shapes_queried=int(counts[0]),
            hits_dropped=int(counts[1]),
        )

    def tool_state(self) -> tuple[np.ndarray, np.ndarray]:
        """The held body's configuration q and velocity qd in the last local model built."""
        m = self.model.record[0]
        dof = int(m["dof"])
        return m["q"][:dof].copy(), m["qd"][:dof].copy()

    @property
    def tool_pose(self) -> np.ndarray:
        """The held body's pose (x, y, angle) in the last local model built (a copy)."""
        return self.model.record[0]["tool_pose"].copy()


@dataclass(frozen=True)
class _Surface:
    """A shape's friction and elasticity (pymunk's names)."""

    friction: float
    elasticity: float


def _shape_material(
    shape: pymunk.Shape | _Surface, contact: Material, made: dict[tuple[float, float], Material]
) -> Material:
    """A world shape's contact: its own friction and elasticity, `contact`'s stiffness and
    damping (friction clipped to the scenes' range, elasticity to [0, 1]); one Material per
    pair of values (`made`)."""
    friction = min(max(float(shape.friction), FRICTION_RANGE[0]), FRICTION_RANGE[1])
    restitution = min(max(float(shape.elasticity), 0.0), 1.0)
    key = (friction, restitution)
    if key not in made:
        made[key] = Material(
            stiffness_n_per_m=contact.stiffness_n_per_m,
            damping_ns_per_m=contact.damping_ns_per_m,
            friction=friction,
            restitution=restitution,
            tangential_stiffness_n_per_m=contact.tangential_stiffness_n_per_m,
        )
    return made[key]


__all__ = [
    "DEFAULT_CONTACT",
    "SpaceWarning",
    "UnsupportedSpaceError",
    "UserSpaceWorld",
    "check_space",
    "scene_text",
]

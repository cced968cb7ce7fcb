"""Configuration: TOML files loaded once into frozen dataclasses, validated at load.

Every problem is reported as a `ConfigError` naming the file, the dotted key and what is
wrong; the command-line entry points turn it into exit code 2. CLI flags only choose files
(and a few overrides), they never mutate a loaded config.
"""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
import types
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from haptic_local_model.shared import coupling

REPO_ROOT = Path(__file__).resolve().parent.parent  # a source tree's (a checkout, -e)
_SHIPPED = Path(__file__).resolve().parent / "configs"  # package data, in an installed wheel
#: The shipped scenes, devices, users and networks: inside the package when installed from a
#: wheel, the source tree's configs/ otherwise (a checkout or an editable install).
CONFIG_ROOT = _SHIPPED if _SHIPPED.is_dir() else REPO_ROOT / "configs"
CONFIG_KINDS = ("scenes", "devices", "users", "network")

Vec2 = tuple[float, float]
Vec3 = tuple[float, float, float]


def coordination_bound(stiffness: float, damping: float, dt: float) -> float:
    """K dt^2 + 2 B dt of a coordination coupling's axis: it must stay below twice the
    held body's mass (moment) on that axis (SceneConfig._check_coordination)."""
    return stiffness * dt * dt + 2.0 * damping * dt


#: a light held body's coordination coupling is softened to this share of its bound
COORDINATION_MARGIN = 0.8


def softened_coordination(
    gains: tuple[Sequence[float], Sequence[float]], mass: float, moment: float, rate_hz: float
) -> tuple[list[float], list[float], list[str]]:
    """The coordination coupling's (stiffness, damping) for a held body of `mass` and
    `moment` at rate_hz: an axis whose gains break SceneConfig._check_coordination's bound
    K dt^2 + 2 B dt < 2 m has both scaled to COORDINATION_MARGIN of it, so the device
    follows the body more loosely instead of chattering. Also: for each softened axis, the
    lightest body its given gains are stable on ("0.07 kg")."""
    dt = 1.0 / rate_hz
    ks, bs = [float(k) for k in gains[0]], [float(b) for b in gains[1]]
    softened = []
    for axis, m in enumerate((mass, mass, moment)):
        bound = coordination_bound(ks[axis], bs[axis], dt)
        if bound >= COORDINATION_MARGIN * 2.0 * m:
            scale = COORDINATION_MARGIN * 2.0 * m / bound
            ks[axis], bs[axis] = ks[axis] * scale, bs[axis] * scale
            softened.append(f"{0.5 * bound:.3g} {'kg m^2' if axis == 2 else 'kg'}")
    return ks, bs, softened


class ConfigError(ValueError):
    """A config file is missing, unreadable or wrong: names the file, the key and the problem."""

    def __init__(self, source: str, key: str, problem: str) -> None:
        self.source, self.key, self.problem = source, key, problem
        where = f"key '{key}'" if key else "file"
        super().__init__(f"{source}: {where}: {problem}")


# --- generic strict loader ------------------------------------------------------------------


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin is Literal:
        return " | ".join(repr(a) for a in typing.get_args(tp))
    if origin in (tuple, dict) or isinstance(tp, types.UnionType):
        return str(tp).replace("typing.", "")
    return getattr(tp, "__name__", str(tp))


def _convert(value: Any, tp: Any, source: str, key: str) -> Any:
    """Check `value` against the annotation `tp` and convert lists to tuples."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    bad = ConfigError(source, key, f"expected {_type_name(tp)}, got {value!r}")
    if isinstance(tp, types.UnionType) or origin is typing.Union:
        for option in args:
            if option is type(None) and value is None:
                return None
        non_none = [a for a in args if a is not type(None)]
        return _convert(value, non_none[0], source, key)
    if origin is Literal:
        if value not in args:
            raise ConfigError(source, key, f"must be one of {list(args)}, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise bad
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise bad
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise bad
        if not math.isfinite(value):  # TOML has nan and inf: no limit, gain or rate may be
            raise ConfigError(source, key, f"must be a finite number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise bad
        return value
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise bad
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(v, args[0], source, f"{key}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(source, key, f"expected {len(args)} values, got {len(value)}")
        return tuple(
            _convert(v, a, source, f"{key}[{i}]")
            for i, (v, a) in enumerate(zip(value, args, strict=True))
        )
    if origin is dict:
        if not isinstance(value, Mapping):
            raise bad
        return {k: _convert(v, args[1], source, f"{key}.{k}") for k, v in value.items()}
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, Mapping):
            raise ConfigError(source, key, f"expected a table, got {value!r}")
        return load_dataclass(tp, value, source, key)
    raise TypeError(f"unsupported config annotation {tp!r} at {key}")


def load_dataclass(cls: Any, data: Mapping[str, Any], source: str, prefix: str = "") -> Any:
    """Build the frozen dataclass `cls` from a TOML table, rejecting unknown or missing keys."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for key in data:
        if key not in fields:
            known = ", ".join(sorted(fields))
            raise ConfigError(source, _join(prefix, key), f"unknown key (known keys: {known})")
    kwargs: dict[str, Any] = {}
    for name, f in fields.items():
        key = _join(prefix, name)
        if name in data:
            kwargs[name] = _convert(data[name], hints[name], source, key)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ConfigError(source, key, "missing required key")
    try:
        return cls(**kwargs)
    except ValueError as exc:  # raised by __post_init__ checks as "key: problem"
        sub_key, _, problem = str(exc).partition(": ")
        raise ConfigError(source, _join(prefix, sub_key), problem or str(exc)) from None


def _join(prefix: str, key: str) -> str:
    return f"{prefix}.{key}" if prefix else key


def read_toml(path: Path | str) -> dict[str, Any]:
    """Read a TOML file, turning every failure into a ConfigError naming the file."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(str(p), "", "file not found")
    try:
        with p.open("rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(str(p), "", f"not valid TOML: {exc}") from None


def load_config_file(cls: Any, kind: str, name_or_path: str) -> tuple[Any, Path]:
    """The config dataclass `cls` from a file of `kind` by name or path (resolve), and that
    file's path; every failure is a ConfigError naming the file."""
    path = resolve(kind, name_or_path)
    return load_dataclass(cls, read_toml(path), str(path)), path


def parse_toml_text(text: str, source: str) -> dict[str, Any]:
    """Parse TOML text (e.g. a config file's text stored in a log) into a table."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(source, "", f"not valid TOML: {exc}") from None


def load_config_text(cls: Any, text: str, source: str) -> Any:
    """Build config dataclass `cls` from TOML text, as strictly as from a file."""
    return load_dataclass(cls, parse_toml_text(text, source), source)


def is_config_path(name_or_path: str) -> bool:
    """A path (`my.toml`, `dir/x`), not the bare name of a shipped config (`free_box`)."""
    p = Path(name_or_path)
    return p.suffix == ".toml" or p.parent != Path(".")


def resolve(kind: str, name_or_path: str) -> Path:
    """A bare name `free_box` means the shipped <kind>/free_box.toml; anything else is a path
    (relative to the working directory)."""
    if is_config_path(name_or_path):
        return Path(name_or_path)
    return CONFIG_ROOT / kind / f"{name_or_path}.toml"


def absolute_ref(name_or_path: str) -> str:
    """A config reference another process can use from any directory: a bare name as it is,
    a path made absolute (against this process's working directory)."""
    return str(Path(name_or_path).resolve()) if is_config_path(name_or_path) else name_or_path


def shipped(kind: str) -> dict[str, str]:
    """The shipped configs of a kind: name -> one-line description (the file's `description`
    key, else the first sentence of its opening comment)."""
    out = {}
    for path in sorted((CONFIG_ROOT / kind).glob("*.toml")):
        text = path.read_text()
        try:
            described = tomllib.loads(text).get("description")
        except tomllib.TOMLDecodeError:
            described = None
        if not isinstance(described, str):
            lines = []
            for line in text.splitlines():
                if not line.startswith("#"):
                    break
                lines.append(line.lstrip("# ").strip())
            described = " ".join(lines).split(". ")[0].rstrip(".")
        out[path.stem] = described
    return out


def require(cond: bool, key: str, problem: str) -> None:
    """A config check in a dataclass's __post_init__: load_dataclass names the file and key."""
    if not cond:
        raise ValueError(f"{key}: {problem}")


#: Stated ranges of scene and user values (docs/scenes.md): what a local model built from them
#: can carry within the protocol's MessageLimits (positions within 100 m, velocities within
#: 100 m/s, D entries within 1e6, stiffness, damping and friction within theirs), so that a
#: typo is refused here, naming its key, not later by the validator as every update.
WORLD_M = 100.0  # |position| (MessageLimits.max_abs_position_m)
SIZE_RANGE_M = (0.0, 100.0)
MASS_RANGE_KG = (1e-6, 1e4)
INERTIA_RANGE_KGM2 = (1e-12, 1e4)
LINK_LENGTH_RANGE_M = (1e-4, 10.0)
ANGLE_RAD = 1e4  # |angle| (MessageLimits.max_abs_angle_rad)
SPEED_M_PER_S = 100.0  # |velocity| (MessageLimits.max_abs_velocity)
GRAVITY_M_PER_S2 = 100.0  # |g|: G(q) within max_abs_generalized_force for these masses
STIFFNESS_RANGE_N_PER_M = (1e-9, 1e8)
#: The heaviest device (kg; kg m^2 about its handle) a device config may state: the haptic
#: side's gains are bounded by what would be stable on it (SceneConfig._check_gains)
HEAVIEST_DEVICE = 100.0
DAMPING_RANGE_NS_PER_M = (0.0, 1e6)
FRICTION_RANGE = (0.0, 10.0)
HAND_FORCE_N, HAND_TORQUE_NM = 1000.0, 100.0  # a simulated hand pushes no harder


def within_all(
    values: Sequence[float], bounds: tuple[float, float], key: str, unit: str = ""
) -> None:
    """`within` for each entry of a tuple, naming the entry (key[i])."""
    for i, value in enumerate(values):
        within(value, bounds, f"{key}[{i}]", unit)


def within(value: float, bounds: tuple[float, float], key: str, unit: str = "") -> None:
    """A `require` that value lies in the closed range bounds (NaN never does)."""
    low, high = bounds
    require(low <= value <= high, key, f"must be within [{low:g}, {high:g}] {unit}, got {value!r}")


# --- scene ----------------------------------------------------------------------------------

RenderingMethod = Literal[
    "local_model", "impedance_only", "virtual_coupling", "virtual_coupling_foh", "god_object"
]
BodyKind = Literal["static", "dynamic", "kinematic"]
ShapeKind = Literal["box", "segment", "circle"]


@dataclass(frozen=True)
class Material:
    """Contact parameters of a surface (seed 001 eq 8; Poisson restitution)."""

    stiffness_n_per_m: float
    damping_ns_per_m: float
    friction: float = 0.0
    restitution: float = 0.0
    # stick stiffness of Coulomb friction (seed 001 §3.2); unset: the normal stiffness
    tangential_stiffness_n_per_m: float | None = None
    # mu_s of the god-object's stick/slip (DESIGN-WAVE2 §3 step 4); unset: friction (mu_k)
    static_friction: float | None = None

    @property
    def tangential_stiffness(self) -> float:
        t = self.tangential_stiffness_n_per_m
        return self.stiffness_n_per_m if t is None else t

    @property
    def static_coefficient(self) -> float:
        """mu_s: static_friction, or friction when it is unset."""
        return self.friction if self.static_friction is None else self.static_friction

    def __post_init__(self) -> None:
        within(self.stiffness_n_per_m, STIFFNESS_RANGE_N_PER_M, "stiffness_n_per_m", "N/m")
        require(
            self.tangential_stiffness_n_per_m is None or self.tangential_stiffness_n_per_m >= 0,
            "tangential_stiffness_n_per_m",
            "must be >= 0",
        )
        within(self.damping_ns_per_m, DAMPING_RANGE_NS_PER_M, "damping_ns_per_m", "N s/m")
        within(self.friction, FRICTION_RANGE, "friction")
        if self.static_friction is not None:
            within(self.static_friction, FRICTION_RANGE, "static_friction")
            require(
                self.static_friction >= self.friction,
                "static_friction",
                f"must be >= friction ({self.friction:g}): mu_s >= mu_k",
            )
        require(0 <= self.restitution <= 1, "restitution", "must be in [0, 1]")


@dataclass(frozen=True)
class BodySpec:
    """A rigid body of the world: walls are static boxes or segments."""

    name: str
    kind: BodyKind
    shape: ShapeKind
    material: str
    position: Vec2 = (0.0, 0.0)
    angle: float = 0.0
    size: Vec2 = (0.0, 0.0)  # box width, height (m)
    a: Vec2 = (0.0, 0.0)  # segment end points in the body frame (m)
    b: Vec2 = (0.0, 0.0)
    radius: float = 0.0  # circle radius or segment half-thickness (m)
    mass: float = 1.0  # kg (dynamic bodies)
    velocity: Vec2 = (0.0, 0.0)  # initial (dynamic) or constant (kinematic), m/s
    angular_velocity: float = 0.0
    linear_damping_per_s: float = 0.0  # dynamic bodies: drag of the table they slide on
    oscillation_amplitude: Vec2 = (0.0, 0.0)  # kinematic bodies: x(t) = x0 + A sin(2 pi t / T)
    oscillation_period_s: float = 0.0
    angle_amplitude: float = 0.0  # kinematic bodies: theta(t) = theta0 + a sin(2 pi t / T_a)
    angle_period_s: float = 0.0
    # kg m^2 about the body's origin; unset: the shape's (a user's own space gives its own)
    moment_kg_m2: float | None = None

    def __post_init__(self) -> None:
        if self.moment_kg_m2 is not None:
            within(self.moment_kg_m2, INERTIA_RANGE_KGM2, "moment_kg_m2", "kg m^2")
        if self.shape == "box":
            require(self.size[0] > 0 and self.size[1] > 0, "size", "box sides must be > 0")
        if self.shape == "circle":
            require(self.radius > 0, "radius", "circle radius must be > 0")
        if self.shape == "segment":
            require(self.a != self.b, "b", "segment end points must differ")
        within(self.mass, MASS_RANGE_KG, "mass", "kg")
        require(self.oscillation_period_s >= 0, "oscillation_period_s", "must be >= 0")
        require(self.angle_period_s >= 0, "angle_period_s", "must be >= 0")
        within(self.angle_amplitude, (-ANGLE_RAD, ANGLE_RAD), "angle_amplitude", "rad")
        if self.angle_amplitude:
            require(
                self.kind == "kinematic" and self.angle_period_s > 0,
                "angle_period_s",
                "an angle oscillation needs a kinematic body and a period > 0",
            )
        require(self.linear_damping_per_s >= 0, "linear_damping_per_s", "must be >= 0")
        within_all(self.position, (-WORLD_M, WORLD_M), "position", "m")
        within_all(self.a, (-WORLD_M, WORLD_M), "a", "m")
        within_all(self.b, (-WORLD_M, WORLD_M), "b", "m")
        within_all(self.size, SIZE_RANGE_M, "size", "m")
        within(self.radius, SIZE_RANGE_M, "radius", "m")
        within_all(self.velocity, (-SPEED_M_PER_S, SPEED_M_PER_S), "velocity", "m/s")
        within_all(self.oscillation_amplitude, (-WORLD_M, WORLD_M), "oscillation_amplitude")
        if any(self.oscillation_amplitude):
            period = self.oscillation_period_s
            peak = 2 * math.pi * max(map(abs, self.oscillation_amplitude)) / max(period, 1e-300)
            require(
                peak <= SPEED_M_PER_S,
                "oscillation_period_s",
                f"the oscillation's peak speed {peak:.3g} m/s exceeds {SPEED_M_PER_S:g} m/s",
            )

    @property
    def extent(self) -> float:
        """The farthest point of the shape from the body's origin (m)."""
        if self.shape == "box":
            return 0.5 * math.hypot(*self.size)
        if self.shape == "circle":
            return self.radius
        return max(math.hypot(*self.a), math.hypot(*self.b)) + self.radius

    @property
    def moment(self) -> float:
        """Moment of inertia about the body's origin (kg m^2), as pymunk computes it."""
        if self.moment_kg_m2 is not None:
            return self.moment_kg_m2
        if self.shape == "box":
            return coupling.box_moment(self.mass, self.size[0], self.size[1])
        if self.shape == "circle":
            return coupling.circle_moment(self.mass, self.radius)
        return coupling.segment_moment(self.mass, self.a, self.b, self.radius)

    def to_world(self, px: float, py: float) -> Vec2:
        """A point of the body's frame (a segment's end, a box's corner) in the world, at the
        body's initial position and angle."""
        c, s = math.cos(self.angle), math.sin(self.angle)
        x, y = self.position
        return (x + c * px - s * py, y + s * px + c * py)


#: Animation-variable linkages (seed 003 §4; shared/track.py, shared/avar.py)
TRACK_SIZE_M = 10.0  # a track's lengths and radii
MAX_CURVATURE = 1.0e4  # 1/m: a 0.1 mm radius
MAX_TRAIN = 8  # cars of a train (shared/avar.py MAX_CARS)
SegmentKindName = Literal["line", "arc", "clothoid", "kink"]


@dataclass(frozen=True)
class SegmentConfig:
    """One piece of a segment track (shared/track.py): a line (length), an arc (radius,
    turn), a clothoid (length, kappa0 -> kappa1) or a kink (turn: a C0 corner)."""

    kind: SegmentKindName
    length: float = 0.0  # m (line, clothoid)
    radius: float = 0.0  # m (arc)
    turn: float = 0.0  # rad, positive to the left (arc, kink)
    kappa0: float = 0.0  # 1/m, positive to the left (clothoid)
    kappa1: float = 0.0

    def __post_init__(self) -> None:
        if self.kind in ("line", "clothoid"):
            require(
                0.0 < self.length <= TRACK_SIZE_M, "length", f"must be in (0, {TRACK_SIZE_M:g}] m"
            )
        if self.kind == "arc":
            require(
                0.0 < self.radius <= TRACK_SIZE_M, "radius", f"must be in (0, {TRACK_SIZE_M:g}] m"
            )
            require(
                0.0 < abs(self.turn) <= 8.0 * math.pi,
                "turn",
                "an arc turns by 0 < |turn| <= 8 pi rad",
            )
        if self.kind == "kink":
            require(0.0 < abs(self.turn) < math.pi, "turn", "a kink turns by 0 < |turn| < pi rad")
        within(self.kappa0, (-MAX_CURVATURE, MAX_CURVATURE), "kappa0", "1/m")
        within(self.kappa1, (-MAX_CURVATURE, MAX_CURVATURE), "kappa1", "1/m")

    @property
    def arc_length(self) -> float:
        return self.radius * abs(self.turn) if self.kind == "arc" else self.length


@dataclass(frozen=True)
class TrackConfig:
    """A track the cars of a scene ride (shared/track.py): an ellipse (centre, semi-axes; a
    loop from its lowest point, counter-clockwise) or segments laid from `start` heading
    `heading` (open, with end bumpers, unless `closed`)."""

    name: str
    kind: Literal["ellipse", "segments"]
    center: Vec2 = (0.0, 0.0)
    semi_axes: Vec2 = (0.0, 0.0)
    start: Vec2 = (0.0, 0.0)
    heading: float = 0.0
    closed: bool = False
    segments: tuple[SegmentConfig, ...] = ()

    def __post_init__(self) -> None:
        within_all(self.center, (-WORLD_M, WORLD_M), "center", "m")
        within_all(self.start, (-WORLD_M, WORLD_M), "start", "m")
        within(self.heading, (-ANGLE_RAD, ANGLE_RAD), "heading", "rad")
        if self.kind == "ellipse":
            within_all(self.semi_axes, (1e-4, TRACK_SIZE_M), "semi_axes", "m")
            require(not self.segments, "segments", "an ellipse has no segments")
        else:
            require(
                any(seg.kind != "kink" for seg in self.segments),
                "segments",
                "a segment track needs at least one line, arc or clothoid",
            )
            require(self.semi_axes == (0.0, 0.0), "semi_axes", "only an ellipse has semi_axes")

    @property
    def length(self) -> float:
        """The track's arc length (m; the ellipse's by Simpson's rule, to 1e-9)."""
        if self.kind == "segments":
            return sum(seg.arc_length for seg in self.segments)
        a, b = self.semi_axes
        n = 2000
        h = 2.0 * math.pi / n
        f = [math.hypot(a * math.cos(i * h), b * math.sin(i * h)) for i in range(n + 1)]
        return h / 3.0 * (f[0] + f[n] + 4.0 * sum(f[1:n:2]) + 2.0 * sum(f[2:n:2]))

    @property
    def is_closed(self) -> bool:
        return self.kind == "ellipse" or self.closed


@dataclass(frozen=True)
class CarsConfig:
    """A train of `count` cars on a track, coupled `spacing_m` apart in arc length (car k
    at s - k spacing), each a box `size` (along the track, across it) centred on the track,
    of mass m and moment I about that point; the lead car starts at initial_s."""

    track: str
    material: str
    count: int = 1
    spacing_m: float = 0.02
    mass: float = 0.05
    inertia: float = 2.0e-6  # kg m^2
    size: Vec2 = (0.015, 0.008)
    initial_s: float = 0.0
    initial_speed: float = 0.0
    restitution: float = 0.5  # of an open track's end bumpers

    def __post_init__(self) -> None:
        within(self.count, (1, MAX_TRAIN), "count")
        within(self.spacing_m, (0.0, TRACK_SIZE_M), "spacing_m", "m")
        within(self.mass, MASS_RANGE_KG, "mass", "kg")
        within(self.inertia, INERTIA_RANGE_KGM2, "inertia", "kg m^2")
        within_all(self.size, (1e-4, TRACK_SIZE_M), "size", "m")
        within(self.initial_speed, (-SPEED_M_PER_S, SPEED_M_PER_S), "initial_speed", "m/s")
        within(self.restitution, (0.0, 1.0), "restitution")


@dataclass(frozen=True)
class CrankConfig:
    """A slider-crank driven by one animation variable (shared/crank.py, docs/avars.md): a
    crank of `crank_length` about `pivot`, a rod of `rod_length` to a slider on the pivot's
    horizontal line, uniform bars of `width` (their rounding) and a box slider; its avar the
    crank angle (an immersion) or the slider position (singular at the dead centres: refused
    unless `allow_singular`)."""

    material: str
    pivot: Vec2 = (0.0, 0.0)
    crank_length: float = 0.02
    rod_length: float = 0.06
    crank_mass: float = 0.02
    rod_mass: float = 0.03
    slider_mass: float = 0.05
    width: float = 0.003  # m: the bars' rounding radius
    slider_size: Vec2 = (0.016, 0.01)
    driver: Literal["crank_angle", "slider_position"] = "crank_angle"
    allow_singular: bool = False
    initial_q: float = 0.0  # rad (crank angle) or m (slider position, from the pivot)
    initial_rate: float = 0.0

    def __post_init__(self) -> None:
        within_all(self.pivot, (-WORLD_M, WORLD_M), "pivot", "m")
        within(self.crank_length, (1e-4, TRACK_SIZE_M), "crank_length", "m")
        require(
            self.crank_length < self.rod_length <= TRACK_SIZE_M,
            "rod_length",
            f"must exceed crank_length ({self.crank_length:g} m) and be <= {TRACK_SIZE_M:g} m",
        )
        for key in ("crank_mass", "rod_mass", "slider_mass"):
            within(getattr(self, key), MASS_RANGE_KG, key, "kg")
        within(self.width, (0.0, TRACK_SIZE_M), "width", "m")
        within_all(self.slider_size, (1e-4, TRACK_SIZE_M), "slider_size", "m")
        within(self.initial_rate, (-SPEED_M_PER_S, SPEED_M_PER_S), "initial_rate")
        if self.driver == "slider_position":
            stroke = (self.rod_length - self.crank_length, self.rod_length + self.crank_length)
            within(self.initial_q, stroke, "initial_q", "m (the slider's stroke)")
        else:
            within(self.initial_q, (-ANGLE_RAD, ANGLE_RAD), "initial_q", "rad")


@dataclass(frozen=True)
class AvarTreeConfig:
    """A tree linkage driven by one animation variable through gears (shared/avar_tree.py,
    docs/avars.md): link i on the tip of link parents[i] (-1 the base), its joint angle
    offsets[i] + gears[i] q; gears are whole numbers (a turn of q brings the tree back)."""

    material: str
    lengths: tuple[float, ...]
    masses: tuple[float, ...]
    inertias: tuple[float, ...]  # about each link's COM, kg m^2
    com_offsets: tuple[Vec2, ...]  # COM in the link frame, m
    parents: tuple[int, ...]
    gears: tuple[int, ...]
    offsets: tuple[float, ...]  # rad
    base: Vec2 = (0.0, 0.0)
    width: float = 0.003  # m: the links' rounding radius
    initial_q: float = 0.0  # rad
    initial_rate: float = 0.0  # rad/s

    def __post_init__(self) -> None:
        n = len(self.lengths)
        require(1 <= n <= MAX_TRAIN, "lengths", f"a geared tree has 1..{MAX_TRAIN} links, got {n}")
        for key in ("masses", "inertias", "com_offsets", "parents", "gears", "offsets"):
            require(len(getattr(self, key)) == n, key, f"needs {n} entries, one per link")
        for i, up in enumerate(self.parents):
            require(-1 <= up < i, "parents", f"link {i} hangs from {up}: -1 or an earlier link")
        require(any(self.gears), "gears", "the animation variable must turn some link")
        within_all(self.gears, (-100, 100), "gears")
        within_all(self.lengths, LINK_LENGTH_RANGE_M, "lengths", "m")
        within_all(self.masses, MASS_RANGE_KG, "masses", "kg")
        within_all(self.inertias, INERTIA_RANGE_KGM2, "inertias", "kg m^2")
        within_all(self.offsets, (-ANGLE_RAD, ANGLE_RAD), "offsets", "rad")
        within_all(self.base, (-WORLD_M, WORLD_M), "base", "m")
        within(self.width, (0.0, TRACK_SIZE_M), "width", "m")
        within(self.initial_q, (-ANGLE_RAD, ANGLE_RAD), "initial_q", "rad")
        within(self.initial_rate, (-SPEED_M_PER_S, SPEED_M_PER_S), "initial_rate", "rad/s")


MAX_MEMBRANE_NODES = 33  # 32 segments: half the local shapes an update carries


@dataclass(frozen=True)
class DeformableSpec:
    """A string under tension (DESIGN-WAVE2 §4): `nodes` point masses from a to b, the two
    ends pinned, each pair of neighbours joined by a zero-rest-length damped spring whose
    stiffness makes the straight string's tension `tension_n` (so the tension grows with the
    length as the string stretches, and a point load F at mid-span deflects it by exactly
    F L / (4 T)). The haptic side renders its segments, rounded by `radius`, as NODAL shapes
    held between updates by the scene's geometry_blend."""

    name: str
    a: Vec2
    b: Vec2
    material: str
    kind: Literal["string"] = "string"
    nodes: int = 21
    mass: float = 0.6  # kg, the moving nodes' total
    tension_n: float = 5.0
    radius: float = 0.001  # rho of the segments, m
    publish_hz: float = 10.0  # the surface is sampled for the haptic side at this rate
    damping_per_s: float = 600.0  # gamma of the dashpots on each node (c = gamma m_node)
    spring_damping_ns_per_m: float = 0.0  # along each spring

    def __post_init__(self) -> None:
        require(self.kind == "string", "kind", f"only 'string' is known, got {self.kind!r}")
        within(self.nodes, (3, MAX_MEMBRANE_NODES), "nodes")
        within_all((*self.a, *self.b), (-WORLD_M, WORLD_M), "a", "m")
        require(math.dist(self.a, self.b) >= 1e-3, "b", "the string must be >= 1 mm long")
        within(self.mass, MASS_RANGE_KG, "mass", "kg")
        within(self.tension_n, (1e-3, 1e4), "tension_n", "N")
        within(self.radius, SIZE_RANGE_M, "radius", "m")
        within(self.publish_hz, (1.0, 1000.0), "publish_hz", "Hz")
        within(self.damping_per_s, (0.0, 1e5), "damping_per_s", "1/s")
        within(self.spring_damping_ns_per_m, (0.0, 1e5), "spring_damping_ns_per_m", "N s/m")

    @property
    def length(self) -> float:
        """L, m."""
        return math.dist(self.a, self.b)

    @property
    def spring_stiffness(self) -> float:
        """k of each spring: T = k L / (nodes - 1) when straight."""
        return self.tension_n * (self.nodes - 1) / self.length

    @property
    def highest_mode_rad_s(self) -> float:
        """2 sqrt(k / m_node): the chain's fastest mode (pymunk's explicit spring needs
        it times the substep below 1)."""
        return 2.0 * math.sqrt(self.spring_stiffness * (self.nodes - 2) / self.mass)

    def loop_gain(self, coupling_n_per_m: float, predicted: bool) -> float:
        """The gain, per sample, of the loop the god-object closes through the string: a
        surface step dy changes the coupling's force by K dy before the device can follow;
        the string yields C = L / (4 T) per newton at mid-span, all of it within a sample if
        it is quick, or T_u / tau of it if its dashpots make it slow (tau = gamma m L / (12 T),
        the mid-span mode's effective mass m / 3 against 4 T / L): min(C K, 3 K / (f gamma m)).
        The node hold's prediction extrapolates each step once more: twice the gain. Above 1
        the press limit-cycles (membrane_10hz at K = 1000 N/m with node_foh: 4 N peak to
        peak; at 300 N/m: 0.3 mN)."""
        quick = self.length / (4.0 * self.tension_n) * coupling_n_per_m
        slow = (
            3.0 * coupling_n_per_m / max(self.publish_hz * self.damping_per_s * self.mass, 1e-300)
        )
        return min(quick, slow) * (2.0 if predicted else 1.0)


@dataclass(frozen=True)
class CrowdSpec:
    """Many like dynamic bodies on a jittered grid filling a rectangle: `count` bodies named
    `<name>_0` ... (a scene of a thousand without a thousand tables)."""

    name: str
    count: int
    shape: Literal["circle", "box"]
    material: str
    region: tuple[Vec2, Vec2]  # lower-left and upper-right corners, m
    spacing_m: float  # grid pitch
    radius: float = 0.0  # circle radius, m
    size: Vec2 = (0.0, 0.0)  # box sides, m
    mass: float = 0.01  # kg
    jitter_m: float = 0.0  # each position moved by up to this much (uniform), seeded
    seed: int = 0
    linear_damping_per_s: float = 0.0  # drag of the table they slide on

    def __post_init__(self) -> None:
        require(self.count >= 1, "count", "must be >= 1")
        within(self.spacing_m, SIZE_RANGE_M, "spacing_m", "m")
        within(self.mass, MASS_RANGE_KG, "mass", "kg")
        within(self.radius, SIZE_RANGE_M, "radius", "m")
        within_all(self.size, SIZE_RANGE_M, "size", "m")
        within_all((*self.region[0], *self.region[1]), (-WORLD_M, WORLD_M), "region", "m")
        require(0 <= self.seed < 2**63, "seed", "must be in [0, 2^63)")
        require(self.jitter_m >= 0, "jitter_m", "must be >= 0")
        require(self.linear_damping_per_s >= 0, "linear_damping_per_s", "must be >= 0")
        extent = 2 * self.radius if self.shape == "circle" else max(self.size)
        require(extent > 0, "radius" if self.shape == "circle" else "size", "must be > 0")
        require(
            extent + 2 * self.jitter_m < self.spacing_m,
            "spacing_m",
            f"must exceed the body's extent plus twice the jitter ({extent + 2 * self.jitter_m:g}"
            " m): neighbours would start overlapping",
        )
        (x0, y0), (x1, y1) = self.region
        require(x1 > x0 and y1 > y0, "region", "needs [[x_min, y_min], [x_max, y_max]]")
        fits = (int((x1 - x0) / self.spacing_m) + 1) * (int((y1 - y0) / self.spacing_m) + 1)
        require(
            fits >= self.count, "count", f"{self.count} bodies do not fit the region ({fits} do)"
        )

    def bodies(self) -> tuple[BodySpec, ...]:
        """The bodies, row by row from the lower-left corner (the same for the same spec)."""
        import numpy as np  # config loading stays light where no scene has a crowd

        (x0, _), (x1, _) = self.region
        columns = int((x1 - x0) / self.spacing_m) + 1
        rng = np.random.default_rng(self.seed)
        jitter = rng.uniform(-self.jitter_m, self.jitter_m, (self.count, 2))
        return tuple(self._body(i, columns, jitter[i]) for i in range(self.count))

    def _body(self, i: int, columns: int, jitter: Any) -> BodySpec:
        (x0, y0), _ = self.region
        position = (
            x0 + (i % columns) * self.spacing_m + float(jitter[0]),
            y0 + (i // columns) * self.spacing_m + float(jitter[1]),
        )
        return BodySpec(
            name=f"{self.name}_{i}", kind="dynamic", shape=self.shape, material=self.material,
            radius=self.radius, size=self.size, mass=self.mass, position=position,
            linear_damping_per_s=self.linear_damping_per_s,
        )  # fmt: skip


@dataclass(frozen=True)
class SpaceSpec:
    """pymunk's broad phase and sleeping, for scenes of many bodies (defaults: pymunk's)."""

    spatial_hash_cell_m: float = 0.0  # > 0: a spatial hash of this cell size (else a BB tree)
    spatial_hash_count: int = 1000  # its table size: about the number of shapes
    sleep_time_s: float = 0.0  # > 0: bodies idle this long fall asleep until touched
    idle_speed_m_per_s: float = 0.0  # below this a body counts as idle (0: pymunk's guess)

    def __post_init__(self) -> None:
        require(self.spatial_hash_cell_m >= 0, "spatial_hash_cell_m", "must be >= 0")
        within(self.spatial_hash_count, (1, 1_000_000), "spatial_hash_count")
        require(self.sleep_time_s >= 0, "sleep_time_s", "must be >= 0")
        require(self.idle_speed_m_per_s >= 0, "idle_speed_m_per_s", "must be >= 0")


@dataclass(frozen=True)
class LinkageSpec:
    """A grounded planar linkage with revolute joints (DESIGN §2): serial, or a tree when
    `parents` names the link each link hangs from (at that link's far end; -1 the base),
    every parent before its child (DESIGN-WAVE2 C1)."""

    name: str
    base: Vec2
    lengths: tuple[float, ...]
    masses: tuple[float, ...]
    inertias: tuple[float, ...]  # about each link's COM, kg m^2
    com_offsets: tuple[Vec2, ...]  # COM in the link frame (x along the link), m
    initial_angles: tuple[float, ...]  # joint angles q0, rad
    material: str
    base_angle: float = 0.0
    radius: float = 0.004  # half-thickness of the capsule drawn for each link, m
    parents: tuple[int, ...] = ()  # empty: serial, link i on link i - 1

    def __post_init__(self) -> None:
        n = len(self.lengths)
        require(n >= 1, "lengths", "a linkage needs at least one link")
        for key in ("masses", "inertias", "com_offsets", "initial_angles"):
            require(len(getattr(self, key)) == n, key, f"needs {n} entries, one per link")
        if self.parents:
            require(len(self.parents) == n, "parents", f"needs {n} entries, one per link")
            for i, up in enumerate(self.parents):
                require(
                    -1 <= up < i,
                    "parents",
                    f"link {i} hangs from {up}: it must be -1 (the base) or an earlier link",
                )
        within_all(self.lengths, LINK_LENGTH_RANGE_M, "lengths", "m")
        within_all(self.masses, MASS_RANGE_KG, "masses", "kg")
        within_all(self.inertias, INERTIA_RANGE_KGM2, "inertias", "kg m^2")
        within(self.radius, (1e-6, 1.0), "radius", "m")
        within_all(self.base, (-WORLD_M, WORLD_M), "base", "m")
        for i, offset in enumerate(self.com_offsets):
            within_all(
                offset, (-LINK_LENGTH_RANGE_M[1], LINK_LENGTH_RANGE_M[1]), f"com_offsets[{i}]"
            )
        within_all(self.initial_angles, (-ANGLE_RAD, ANGLE_RAD), "initial_angles", "rad")

    def parent_of(self, i: int) -> int:
        """The link link i hangs from (-1: the base)."""
        return self.parents[i] if self.parents else i - 1


@dataclass(frozen=True)
class ToolSpec:
    """What the user holds: a free body, or link `link` of a linkage, at `point` (local frame)."""

    kind: Literal["body", "linkage"]
    name: str
    link: int = 0
    point: Vec2 = (0.0, 0.0)
    characteristic_length_m: float = 0.05  # scales the angular row of J_h (DESIGN §3)
    rank_tolerance: float = 0.05  # relative singular value below which a direction is resisted
    neighbourhood_margin_m: float = 0.02  # contacts within this gap are sent (DESIGN §3)
    tracking_bandwidth_hz: float = 8.0  # how hard the sim's tool follows the proxy

    def __post_init__(self) -> None:
        within(self.characteristic_length_m, (1e-4, WORLD_M), "characteristic_length_m", "m")
        within_all(self.point, (-LINK_LENGTH_RANGE_M[1], LINK_LENGTH_RANGE_M[1]), "point", "m")
        require(0 < self.rank_tolerance < 1, "rank_tolerance", "must be in (0, 1)")
        within(self.neighbourhood_margin_m, (1e-6, 1.0), "neighbourhood_margin_m", "m")
        within(self.tracking_bandwidth_hz, (1e-3, 1000.0), "tracking_bandwidth_hz", "Hz")


@dataclass(frozen=True)
class RenderingSpec:
    """Haptic-side gains and the rendering method (DESIGN §4, §6)."""

    method: RenderingMethod = "local_model"
    coordination_stiffness: Vec3 = (100.0, 100.0, 0.5)  # K_pc, N/m, N/m, Nm/rad
    coordination_damping: Vec3 = (70.0, 70.0, 0.375)  # B_pc
    penalty_stiffness: float = 200.0  # k_j, N/m/kg (seed 000 eq 17)
    penalty_damping: float = 50.0  # b_j, N s/m/kg
    desired_damping: Vec3 = (0.0, 0.0, 0.0)  # b_d of the VM at the hand (seed 000 eq 4)
    desired_stiffness: Vec3 = (0.0, 0.0, 0.0)  # k_d
    # M_d J_h_dot qd in the device's command (DESIGN §4.3): the operational point's
    # centripetal acceleration; false renders seed 000 eq 11/18 as printed (the device lags a
    # spinning VM and the coordination spring bends the VM off its free path)
    jdot_qd: bool = True
    impulses: bool = True  # colliding contacts resolved by impulses (seed 001 §3.2)
    collision_speed_m_per_s: float = 0.01  # approach speed above which a new contact collides
    # the version of the impulse handling: "0.2" computes a colliding tick's contact forces
    # from the velocity its impulses leave, and spreads an impulse the device cannot deliver
    # in one tick over the next ones without the coordination coupling braking the device a
    # second time; "0.13" adds the device's impact ledger (stages/control.py impact_ledger):
    # the device's share of an impulse it cannot take in one tick is delivered half before
    # the predicted impact, and the displacement its limits cause is returned by feedforward
    # instead of by the coordination coupling's slow pole; "0.1" as version 0.1 did (kept to
    # replay its logs)
    impulse_law: Literal["0.1", "0.2", "0.13"] = "0.13"
    blend_ms: float = 8.0  # cross-fade of old and new geometry after an update
    virtual_coupling_stiffness: Vec3 = (50.0, 50.0, 0.2)  # seed 000 §VIII baseline
    virtual_coupling_damping: Vec3 = (3.0, 3.0, 0.005)
    # god_object (seed 003 §3, docs/god-object.md): the device-proxy spring K_vc, B_vc
    # (B_vc >= K_vc dt / 2, checked), sub-steps per tick at most, and how long a pop's force
    # change takes at least
    god_object_stiffness: Vec2 = (1000.0, 1000.0)
    god_object_damping: Vec2 = (2.0, 2.0)
    max_substeps: int = 16
    pop_ramp_ms: float = 5.0
    # how a deformable surface's segments move between its updates (DESIGN-WAVE2 §4):
    # node_foh toward the predicted next surface, linear toward the newest, none holds it
    geometry_blend: Literal["node_foh", "linear", "none"] = "node_foh"
    # virtual_coupling_foh, sim side (seed 002 table, SI): the tool's spring to the device
    foh_spring_stiffness: Vec3 = (1.0e5, 1.0e5, 800.0)
    foh_spring_damping: Vec3 = (1.0e4, 1.0e4, 20.0)
    # virtual_coupling_foh renders its spring only while the tool touches something (seed 002:
    # free space feels free); true renders it always, as a virtual coupling to a held
    # mechanism must (its joints constrain the hand with no contact at all)
    foh_free_space_force: bool = False
    # K_damp on the tool's velocity relative to the device's (a virtual coupling's damper)
    # instead of its absolute velocity (seed 002: the tool then moves as through honey)
    foh_relative_damping: bool = False

    def __post_init__(self) -> None:
        for key in (
            "coordination_stiffness", "coordination_damping", "desired_damping",
            "desired_stiffness", "foh_spring_stiffness", "foh_spring_damping",
            "virtual_coupling_stiffness", "virtual_coupling_damping", "god_object_stiffness",
            "god_object_damping",
        ):  # fmt: skip
            require(all(v >= 0 for v in getattr(self, key)), key, "must be >= 0")
        within(self.max_substeps, (1, 64), "max_substeps")
        within(self.pop_ramp_ms, (0.1, 1000.0), "pop_ramp_ms", "ms")
        require(
            self.geometry_blend in ("node_foh", "linear", "none"),
            "geometry_blend",
            f"must be node_foh, linear or none, got {self.geometry_blend!r}",
        )
        require(self.penalty_stiffness >= 0, "penalty_stiffness", "must be >= 0")
        require(self.penalty_damping >= 0, "penalty_damping", "must be >= 0")
        require(self.blend_ms >= 0, "blend_ms", "must be >= 0")
        require(self.collision_speed_m_per_s >= 0, "collision_speed_m_per_s", "must be >= 0")


@dataclass(frozen=True)
class SafetySpec:
    """What the scene allows its tool to do: the bounds the haptic server checks every update
    against (haptic_server/stages/plausible.py) and its runaway guard and passivity observer
    trip at (haptic_server/stages/safety.py). Speeds are of the operational point and of
    each link's rotation; the scene's fastest kinematic body is added (twice: a tool it
    strikes may rebound at up to twice its speed)."""

    max_tool_speed_m_per_s: float = 2.0  # a hand's reach: the tool's operational point
    max_tool_angular_speed_rad_per_s: float = 30.0  # any link of the tool
    max_penetration_m: float = 0.04  # of a contact at the sim's own tool state
    passivity_window_s: float = 0.2  # the passivity observer forgets energy over this
    passivity_limit_j: float = 0.5  # energy the device port may give out within the window

    def __post_init__(self) -> None:
        within(self.max_tool_speed_m_per_s, (1e-3, SPEED_M_PER_S), "max_tool_speed_m_per_s")
        within(
            self.max_tool_angular_speed_rad_per_s, (1e-3, 1e3), "max_tool_angular_speed_rad_per_s"
        )
        within(self.max_penetration_m, (1e-6, 1.0), "max_penetration_m", "m")
        within(self.passivity_window_s, (1e-3, 10.0), "passivity_window_s", "s")
        within(self.passivity_limit_j, (1e-6, 1e4), "passivity_limit_j", "J")


MAX_HAPTIC_RATE_HZ = 10000.0


@dataclass(frozen=True)
class SceneConfig:
    """A scene: the world the sim builds and the gains the haptic side renders it with."""

    name: str
    description: str
    tool: ToolSpec
    materials: dict[str, Material]
    gravity: Vec2 = (0.0, 0.0)
    sim_rate_hz: float = 60.0
    sim_substeps: int = 10
    haptic_rate_hz: float = 1000.0
    initial_device_offset: Vec3 = (0.0, 0.0, 0.0)  # device start pose minus the VM's, m, rad
    bodies: tuple[BodySpec, ...] = ()
    crowds: tuple[CrowdSpec, ...] = ()
    linkages: tuple[LinkageSpec, ...] = ()
    deformables: tuple[DeformableSpec, ...] = ()
    tracks: tuple[TrackConfig, ...] = ()
    cars: tuple[CarsConfig, ...] = ()
    crank: CrankConfig | None = None
    avar_tree: AvarTreeConfig | None = None
    rendering: RenderingSpec = field(default_factory=RenderingSpec)
    space: SpaceSpec = field(default_factory=SpaceSpec)
    safety: SafetySpec = field(default_factory=SafetySpec)

    def __post_init__(self) -> None:
        # up to 1 kHz: the world stepped every haptic tick, as benchmarks/front.py compares
        require(10.0 <= self.sim_rate_hz <= 1000.0, "sim_rate_hz", "must be in [10, 1000] Hz")
        within(self.sim_substeps, (1, 100_000), "sim_substeps")  # each one costs every step
        within_all(self.gravity, (-GRAVITY_M_PER_S2, GRAVITY_M_PER_S2), "gravity", "m/s^2")
        offset = self.initial_device_offset
        within_all(offset[:2], (-WORLD_M, WORLD_M), "initial_device_offset", "m")
        within(offset[2], (-ANGLE_RAD, ANGLE_RAD), "initial_device_offset[2]", "rad")
        require(
            100.0 <= self.haptic_rate_hz <= MAX_HAPTIC_RATE_HZ,
            "haptic_rate_hz",
            f"must be in [100, {MAX_HAPTIC_RATE_HZ:g}] Hz",
        )
        names = [b.name for b in self.bodies] + [lk.name for lk in self.linkages]
        names += [f"{c.name}_{i}" for c in self.crowds for i in range(c.count)]
        names += [m.name for m in self.deformables]
        require(
            len(names) == len(set(names)),
            "bodies",
            "body, crowd, linkage and deformable names must be unique",
        )
        for kind in ("crowds", "bodies", "deformables", "linkages"):  # what has a material
            for i, item in enumerate(getattr(self, kind)):
                require(
                    item.material in self.materials,
                    f"{kind}[{i}].material",
                    f"unknown material {item.material!r}",
                )
        for i, dm in enumerate(self.deformables):
            require(
                self.rendering.method == "god_object",
                f"deformables[{i}]",
                "a deformable is rendered by the god_object method only",
            )
            every = self.sim_rate_hz / dm.publish_hz
            require(
                every >= 1.0 and abs(every - round(every)) <= 1e-9 * every,
                f"deformables[{i}].publish_hz",
                f"{dm.publish_hz:g} Hz must divide sim_rate_hz {self.sim_rate_hz:g} (the sim "
                "samples the string every sim_rate_hz / publish_hz steps)",
            )
            require(
                dm.publish_hz == self.deformables[0].publish_hz,
                f"deformables[{i}].publish_hz",
                "every deformable of a scene is sampled at the same rate",
            )
            h = 1.0 / (self.sim_rate_hz * self.sim_substeps)
            omega = dm.highest_mode_rad_s
            require(
                omega * h < 1.0,
                "sim_substeps",
                f"deformables[{i}]: the string's highest mode ({omega:.0f} rad/s) needs a sim "
                f"substep under {1e3 / omega:.3f} ms for pymunk's explicit spring, got "
                f"{1e3 * h:.3f} ms: raise sim_substeps, lower nodes or tension, or add mass",
            )
            k = max(self.rendering.god_object_stiffness)
            gain = dm.loop_gain(k, self.rendering.geometry_blend == "node_foh")
            require(
                gain < 1.0,
                f"deformables[{i}]",
                f"the god-object's loop through the string sampled at {dm.publish_hz:g} Hz has "
                f"a gain of {gain:.2f} per sample (>= 1: the press would limit-cycle; "
                "DeformableSpec.loop_gain): lower rendering.god_object_stiffness, raise the "
                "string's mass or damping_per_s, or publish it faster",
            )
        if self.tool.kind == "body":
            match = [b for b in self.bodies if b.name == self.tool.name]
            require(bool(match), "tool.name", f"no body named {self.tool.name!r}")
            require(match[0].kind == "dynamic", "tool.name", "the held body must be dynamic")
        else:
            match_l = [lk for lk in self.linkages if lk.name == self.tool.name]
            require(bool(match_l), "tool.name", f"no linkage named {self.tool.name!r}")
            require(0 <= self.tool.link < len(match_l[0].lengths), "tool.link", "no such link")
        if self.rendering.method == "virtual_coupling_foh" and self.tool.kind == "body":
            self._check_coupling_substeps(match[0])
        self._check_gains()
        if self.rendering.method == "god_object":
            self._check_god_object()
        if self.tracks or self.cars:
            self._check_train()
        if self.rendering.method == "local_model" and self.tool.kind == "body":
            self._check_coordination(match[0])
        if self.crank is not None:
            self._check_crank(self.crank)
        if self.avar_tree is not None:
            mechanisms = bool(self.cars) + (self.crank is not None)
            require(not mechanisms, "avar_tree", "a scene has one mechanism")
            self._check_mechanism(
                "avar_tree", "avar_tree.material", self.avar_tree.material, "a geared tree"
            )

    def _check_train(self) -> None:
        """One train on one track (one avar per scene in this build), pushed by a god-object
        finger, fitting its track; the track itself is tabulated here once, so a spec that
        does not close or needs too many knots is refused at load."""
        from haptic_local_model.shared.track import tabulate  # numpy only, at load

        require(len(self.tracks) == 1, "tracks", "a scene has one track (for its one train)")
        require(len(self.cars) == 1, "cars", "a scene has one train of cars on its track")
        track, cars = self.tracks[0], self.cars[0]
        require(cars.track == track.name, "cars[0].track", f"no track named {cars.track!r}")
        self._check_mechanism("cars", "cars[0].material", cars.material, "a train")
        try:
            tabulate(self.track_spec)
        except ValueError as exc:
            raise ValueError(f"tracks[0]: {exc}") from None
        length = track.length
        tail = (cars.count - 1) * cars.spacing_m
        if track.is_closed:
            require(tail < length, "cars[0].spacing_m", f"the train ({tail:g} m) exceeds the loop")
            within(cars.initial_s, (0.0, length), "cars[0].initial_s", "m")
        else:
            within(
                cars.initial_s, (tail, length), "cars[0].initial_s", "m (the train on the track)"
            )

    def _check_mechanism(self, key: str, material_key: str, material: str, what: str) -> None:
        """A mechanism's material exists, and the god-object's finger pushes it."""
        require(material in self.materials, material_key, f"unknown material {material!r}")
        require(
            self.rendering.method == "god_object",
            key,
            f"{what} is pushed by the god_object method's finger (rendering.method)",
        )

    def _check_crank(self, crank: CrankConfig) -> None:
        """One mechanism per scene, pushed by the god-object; a singular avar only if
        allowed (shared/crank.py check_conditioning)."""
        from haptic_local_model.shared.crank import CrankDriver, check_conditioning, crank_record

        require(not self.cars, "crank", "a scene has one mechanism: a train or a crank")
        self._check_mechanism("crank", "crank.material", crank.material, "a crank")
        record = crank_record(
            crank.crank_length, crank.rod_length, crank.crank_mass, crank.rod_mass,
            crank.slider_mass, self.gravity, CrankDriver[crank.driver.upper()], crank.pivot,
        )  # fmt: skip
        try:
            check_conditioning(record, crank.allow_singular, "driver")
        except ValueError as exc:
            raise ValueError(f"crank.{exc}") from None

    @property
    def track_spec(self) -> Any:
        """The scene's track as shared.track.TrackSpec."""
        from haptic_local_model.shared.track import Segment, SegmentKind, TrackSpec

        t = self.tracks[0]
        if t.kind == "ellipse":
            return TrackSpec(center=t.center, semi_axes=t.semi_axes)
        segments = []
        for seg in t.segments:
            kind = SegmentKind[seg.kind.upper()]
            if kind == SegmentKind.ARC:
                segments.append(Segment.arc(seg.radius, seg.turn))
            elif kind == SegmentKind.KINK:
                segments.append(Segment.kink(seg.turn))
            else:
                k0, k1 = (seg.kappa0, seg.kappa1) if kind == SegmentKind.CLOTHOID else (0.0, 0.0)
                segments.append(Segment(kind, seg.length, k0, k1))
        return TrackSpec(tuple(segments), t.start, t.heading, t.closed)

    def _check_gains(self) -> None:
        """Every spring-damper the haptic side puts on the device (the god-object's, the
        virtual coupling's, the coordination coupling's) must be stable on some device at the
        haptic rate: its discrete step on a mass m is stable only if K dt^2 + 2 B dt < 4 m
        (semi-implicit Euler), and no admitted device is heavier than HEAVIEST_DEVICE (kg,
        or kg m^2 about the handle). A gain past it is a typo that would chatter the device
        at its force limit, and is refused by its own key."""
        r = self.rendering
        dt = 1.0 / self.haptic_rate_hz
        m = HEAVIEST_DEVICE
        for name in ("god_object", "virtual_coupling", "coordination"):
            ks, bs = getattr(r, f"{name}_stiffness"), getattr(r, f"{name}_damping")
            for axis, (k, b) in enumerate(zip(ks, bs, strict=True)):
                unit = "N/m" if axis < 2 else "N m/rad"
                require(
                    k * dt * dt < 4.0 * m,
                    f"rendering.{name}_stiffness",
                    f"{k:g} {unit} on axis {axis} cannot be stable on any device at "
                    f"{self.haptic_rate_hz:g} Hz: K dt^2 + 2 B dt < 4 m for the heaviest "
                    f"device admitted ({m:g}) gives K < {4.0 * m / (dt * dt):.4g}",
                )
                b_max = (4.0 * m - k * dt * dt) / (2.0 * dt)
                require(
                    b < b_max,
                    f"rendering.{name}_damping",
                    f"{b:g} on axis {axis} with stiffness {k:g} cannot be stable on any device "
                    f"at {self.haptic_rate_hz:g} Hz: K dt^2 + 2 B dt < 4 m for the heaviest "
                    f"device admitted ({m:g}) gives B < {b_max:.4g}",
                )

    def _check_coordination(self, tool: BodySpec) -> None:
        """The coordination coupling also acts on the proxy, a copy of the held body: on its
        mass (its moment about the third axis) the step is stable only if
        K dt^2 + 2 B dt < 2 m, half the undelayed bound of _check_gains, since the device's
        answer reaches the proxy a tick later (coordination_bound). Measured on the ideal
        device with the default gains at 1 kHz (api.run_offline, a disc alone, moved): one
        of 0.065 kg commanded +-50 N, tick by tick, with no fault; 0.072 kg was quiet; the
        bound says 0.070. Refused by its own key, naming the held body."""
        r = self.rendering
        dt = 1.0 / self.haptic_rate_hz
        for axis, (k, b) in enumerate(
            zip(r.coordination_stiffness, r.coordination_damping, strict=True)
        ):
            m = tool.moment if axis == 2 else tool.mass
            unit = "kg m^2 (its moment)" if axis == 2 else "kg"
            key = "stiffness" if k * dt * dt >= 2.0 * m else "damping"
            require(
                coordination_bound(k, b, dt) < 2.0 * m,
                f"rendering.coordination_{key}",
                f"({k:g}, {b:g}) on axis {axis} cannot be stable on the held body "
                f"{tool.name!r} of {m:g} {unit} at {self.haptic_rate_hz:g} Hz: "
                f"K dt^2 + 2 B dt < 2 m gives B < {max(0.0, m - 0.5 * k * dt * dt) / dt:.4g} "
                f"(or a body of at least {0.5 * coordination_bound(k, b, dt):.4g} {unit})",
            )

    def _check_god_object(self) -> None:
        """A god-object is a disc held as a free body, and its coupling is passive (Colgate:
        B >= K dt / 2 at the haptic rate)."""
        require(
            self.tool.kind == "body" and self.tool_body.shape == "circle",
            "tool.name",
            "the god_object method renders a disc: the held tool must be a circle body",
        )
        r = self.rendering
        dt = 1.0 / self.haptic_rate_hz
        for axis in range(2):
            k, b = r.god_object_stiffness[axis], r.god_object_damping[axis]
            require(
                b >= 0.5 * k * dt,
                "rendering.god_object_damping",
                f"{b:g} N s/m on axis {axis} is below K dt / 2 = {0.5 * k * dt:g} (passivity "
                f"of the {k:g} N/m spring at {self.haptic_rate_hz:g} Hz)",
            )

    def _check_coupling_substeps(self, body: BodySpec) -> None:
        """The sim's stiff tool-device coupling must be stable in pymunk (shared/coupling.py;
        checked for a held free body, whose effective mass is fixed)."""
        moment = body.moment
        r = self.rendering
        needed, h_max = coupling.coupling_substeps(
            self.sim_rate_hz, body.mass, moment, self.tool.point,
            r.foh_spring_stiffness, r.foh_spring_damping,
        )  # fmt: skip
        require(
            self.sim_substeps >= needed,
            "sim_substeps",
            f"virtual_coupling_foh needs >= {needed} at {self.sim_rate_hz:g} Hz for the tool "
            f"{body.name!r} (m = {body.mass:g} kg, I = {moment:.3g} kg m^2): the coupling's "
            f"semi-implicit Euler step limit is {1e3 * h_max:.3f} ms, and substeps must be "
            f"at most half of it (shared/coupling.py)",
        )

    @property
    def all_bodies(self) -> tuple[BodySpec, ...]:
        """The bodies and every crowd's bodies, in that order (what the sim builds)."""
        return self.bodies + tuple(b for c in self.crowds for b in c.bodies())

    @property
    def kinematic_speed_m_per_s(self) -> float:
        """The fastest a point of a kinematic body moves: its velocity, its oscillation's peak
        and its spin times its extent."""
        fastest = 0.0
        for b in self.bodies:
            if b.kind != "kinematic":
                continue
            peak = 0.0
            if b.oscillation_period_s > 0:
                amplitude = math.hypot(*b.oscillation_amplitude)
                peak = 2 * math.pi * amplitude / b.oscillation_period_s
            spin = abs(b.angular_velocity)
            if b.angle_period_s > 0:
                spin += 2 * math.pi * abs(b.angle_amplitude) / b.angle_period_s
            fastest = max(fastest, math.hypot(*b.velocity) + peak + spin * b.extent)
        return fastest

    @property
    def tool_body(self) -> BodySpec:
        return next(b for b in self.bodies if b.name == self.tool.name)

    @property
    def tool_linkage(self) -> LinkageSpec:
        return next(lk for lk in self.linkages if lk.name == self.tool.name)


# --- users (simulated hands) ----------------------------------------------------------------


@dataclass(frozen=True)
class UserConfig:
    """A simulated hand: a constant wrench, a spring-damper following waypoints, or one
    following a pointer (`haptic-pointer`: a mouse or a gamepad).

    Waypoints are (t_s, dx, dy, dtheta) relative to the device's start pose, linearly
    interpolated and held after the last one; a pointer's targets are relative to the same
    start, and the hand holds the start until the first one arrives.
    """

    name: str
    kind: Literal["constant_wrench", "waypoints", "pointer"]
    # N, N, N m: constant_wrench's wrench; with waypoints or a pointer, a constant push added
    # to the springs (a hand that squeezes along x while it holds its height: stiffness 0 on x)
    wrench: Vec3 = (0.0, 0.0, 0.0)
    stiffness: Vec3 = (200.0, 200.0, 0.5)  # hand grip stiffness (waypoints)
    damping: Vec3 = (10.0, 10.0, 0.02)
    waypoints: tuple[tuple[float, float, float, float], ...] = ()
    max_wrench: Vec3 = (20.0, 20.0, 1.0)  # a hand pushes no harder than this
    # a glove's joint angles for a hand scene (docs/grasp.md): (t_s, a_1, a_2, ...) rad, one
    # per phalanx in the hand's order, linear in between, held after the last
    finger_angles: tuple[tuple[float, ...], ...] = ()

    def __post_init__(self) -> None:
        if self.kind == "waypoints":
            require(len(self.waypoints) >= 1, "waypoints", "needs at least one waypoint")
            times = [w[0] for w in self.waypoints]
            require(times == sorted(times), "waypoints", "times must be increasing")
        hand = (HAND_FORCE_N, HAND_FORCE_N, HAND_TORQUE_NM)
        for i, (value, limit) in enumerate(zip(self.max_wrench, hand, strict=True)):
            within(value, (1e-6, limit), f"max_wrench[{i}]")
        for i, (value, limit) in enumerate(zip(self.wrench, hand, strict=True)):
            within(value, (-limit, limit), f"wrench[{i}]")
        within_all(self.stiffness, (0.0, 1e6), "stiffness")
        within_all(self.damping, (0.0, 1e4), "damping")
        times = [row[0] if row else 0.0 for row in self.finger_angles]
        require(times == sorted(times), "finger_angles", "times must not decrease")
        widths = {len(row) for row in self.finger_angles}
        require(len(widths) <= 1, "finger_angles", "every row needs as many angles")
        for i, row in enumerate(self.finger_angles):
            require(len(row) >= 2, f"finger_angles[{i}]", "t and at least one angle")
            within(row[0], (0.0, 1e6), f"finger_angles[{i}][0]", "s")
            within_all(row[1:], (-ANGLE_RAD, ANGLE_RAD), f"finger_angles[{i}][1:]", "rad")
        for i, (t, dx, dy, dtheta) in enumerate(self.waypoints):
            within(t, (0.0, 1e6), f"waypoints[{i}][0]", "s")
            within_all((dx, dy), (-WORLD_M, WORLD_M), f"waypoints[{i}][1:3]", "m")
            within(dtheta, (-ANGLE_RAD, ANGLE_RAD), f"waypoints[{i}][3]", "rad")


# --- loading entry points -------------------------------------------------------------------


def static_bodies(scene_text: str | None) -> list[BodySpec]:
    """The static bodies (walls, floors) of a scene given as text, e.g. the one a log or a
    run carries; none if there is no text or it does not load (the viewers draw without)."""
    if not scene_text:
        return []
    try:
        scene = load_config_text(SceneConfig, scene_text, "the run's scene")
    except (ConfigError, ValueError):
        return []
    return [body for body in scene.bodies if body.kind == "static"]


def load_scene(name_or_path: str, haptic_rate_hz: float | None = None) -> SceneConfig:
    """A scene by name or path; `haptic_rate_hz` overrides the file's (haptic-run
    --haptic-rate), checked like the file's own value."""
    path = resolve("scenes", name_or_path)
    if haptic_rate_hz is None:
        return load_config_file(SceneConfig, "scenes", name_or_path)[0]
    return load_config_text(
        SceneConfig, scene_text(path, haptic_rate_hz), f"{path} (--haptic-rate)"
    )


def scene_text(path: Path, haptic_rate_hz: float | None = None) -> str:
    """The scene file's text, with `haptic_rate_hz` set to the override if one is given: what
    a run logs, so that a replay builds the engine the run had."""
    text = path.read_text()
    if haptic_rate_hz is None:
        return text
    line = f"haptic_rate_hz = {float(haptic_rate_hz)!r}  # --haptic-rate"
    pattern = re.compile(r"^haptic_rate_hz\s*=.*$", re.MULTILINE)
    if pattern.search(text):
        return pattern.sub(line, text, count=1)
    return f"{line}\n{text}"  # a top-level key goes before any table


def load_user(name_or_path: str) -> UserConfig:
    return load_config_file(UserConfig, "users", name_or_path)[0]


def load_model_config(cls: Any, data: dict[str, Any], source: str, model: str) -> Any:
    """A device model's config from its file's table; a `model` key, if present, must match."""
    table = dict(data)
    found = table.pop("model", model)
    if found != model:
        raise ConfigError(source, "model", f"expected {model!r}, got {found!r}")
    return load_dataclass(cls, table, source)


def load_device_table(name_or_path: str) -> tuple[str, dict[str, Any], str]:
    """Read a device file: returns (model name, the rest of the table, source path)."""
    path = resolve("devices", name_or_path)
    return split_device_table(read_toml(path), str(path))


def split_device_table(data: dict[str, Any], source: str) -> tuple[str, dict[str, Any], str]:
    """A device table as (model name, the rest of the table, source)."""
    model = data.pop("model", None)
    if not isinstance(model, str):
        raise ConfigError(source, "model", 'missing or not a string (e.g. model = "ideal")')
    return model, data, source

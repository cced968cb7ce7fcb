"""The network of a shared world and its haptic stations (docs/stations.md).

Three roles meet through one Zenoh router (Zenoh's own router mode, `haptic-router`):
the world (`haptic-world`, the co-simulated object and every port's tool) and one haptic
station per port (`haptic-station`, a device and its user), each a Zenoh client of the
router, on the same host or others. The router authenticates every client (usrpwd) and its
access control, default deny, lets each through only its own flows:

- the world may publish every port's ToolState and follow every port's DeviceState;
- the station of port P may publish P's DeviceState and follow P's ToolState, nothing else
  (not another port's device, not another port's tool);
- the sim that mirrors the world (`sim-server --mirror`, optional) may publish the sim's
  bodies and follow the world's, and the world the other way.

Keys: `<ns>/port/<P>/device` (station -> world), `<ns>/port/<P>/tool` (world -> station),
`<ns>/world/bodies` (world -> sim), `<ns>/sim/bodies` (sim -> world).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import zenoh

from haptic_local_model.shared.config import ConfigError, load_config_file, require, within
from haptic_local_model.shared.net.config import (
    WATCHDOG_MS_RANGE,
    EndpointSpec,
    _read_users,
    require_safe_state,
)
from haptic_local_model.shared.net.transport import session_config

PORT_NAME_CHARS = set("abcdefghijklmnopqrstuvwxyz0123456789_-")
STATE_RELIABILITY = {
    "reliable": zenoh.Reliability.RELIABLE,
    "best_effort": zenoh.Reliability.BEST_EFFORT,
}
PASSIVITY = ("tdpa", "off")


def port_keys(namespace: str, port: str) -> tuple[str, str]:
    """(device key, tool key) of a port."""
    return f"{namespace}/port/{port}/device", f"{namespace}/port/{port}/tool"


def mirror_keys(namespace: str) -> tuple[str, str]:
    """(the world's bodies, the sim's bodies): world -> sim, sim -> world."""
    return f"{namespace}/world/bodies", f"{namespace}/sim/bodies"


@dataclass(frozen=True)
class StationNetworkConfig:
    """Where the router listens, who may be the world and which station drives which port,
    and the endpoints of each role (files relative to the config)."""

    namespace: str = "haptic/stations"
    watchdog_ms: float = 100.0  # a station with no ToolState for this long goes safe
    safe_ramp_ms: float = 40.0  # its force ramps to the safe state (and back) over this
    # the world holds a port whose DeviceState is this old, and re-indexes it when it returns
    world_watchdog_ms: float = 100.0
    router: EndpointSpec = field(default_factory=EndpointSpec)
    world_user: str = "world"
    station_users: dict[str, str] = field(default_factory=dict)  # port -> user
    world: EndpointSpec = field(default_factory=EndpointSpec)
    stations: dict[str, EndpointSpec] = field(default_factory=dict)  # port -> endpoints
    # the sim that mirrors the world (sim-server --mirror): optional, no connect: none
    sim_user: str = "sim"
    sim: EndpointSpec = field(default_factory=EndpointSpec)
    # a router without authentication lets anyone drive the ports: refused unless set
    unauthenticated_insecure: bool = False
    # how ToolStates and DeviceStates are sent: "reliable" (retransmitted: on a TCP link a
    # lost packet holds every newer state behind it), or "best_effort" (a lost one stays
    # lost; on a transport with a UDP link beside its TCP one they take the UDP link, and
    # the declarations, the access control's and the sim's messages stay on TCP)
    state_reliability: str = "reliable"
    # each port link's passivity controllers (docs/stations.md, "Passivity"): "tdpa" (the
    # world's and the station's act on what the link would generate) or "off" (the
    # observers only: the energies are still counted, exchanged and logged)
    passivity: str = "tdpa"
    # each station renders its tool's contact with the object on its own side (docs/
    # stations.md, "The local model at the station"): on by default, it kept the grip and
    # the ports passive at 50 and 150 ms one way where the coupling alone lost the box;
    # false: the coupling alone
    local_model: bool = True

    def __post_init__(self) -> None:
        require_safe_state(self.namespace, self.watchdog_ms, self.safe_ramp_ms)
        require(
            self.state_reliability in STATE_RELIABILITY,
            "state_reliability",
            f"must be one of {sorted(STATE_RELIABILITY)}, not {self.state_reliability!r}",
        )
        require(
            self.passivity in PASSIVITY,
            "passivity",
            f"must be one of {sorted(PASSIVITY)}, not {self.passivity!r}",
        )
        within(self.world_watchdog_ms, WATCHDOG_MS_RANGE, "world_watchdog_ms", "ms")
        require(bool(self.router.listen), "router.listen", "the router must listen somewhere")
        require(bool(self.world.connect), "world.connect", "the world must connect to the router")
        for port, spec in self.stations.items():
            require(set(port) <= PORT_NAME_CHARS, f"stations.{port}", "not a plain port name")
            require(bool(spec.connect), f"stations.{port}.connect", "must connect to the router")
        authenticated = bool(self.router.users_file)
        require(
            authenticated or self.unauthenticated_insecure,
            "router.users_file",
            "the router accepts anyone: set users_file, or, knowingly, "
            "unauthenticated_insecure = true",
        )
        if not authenticated:
            return
        require(self.world.user == self.world_user, "world.user", f"must be {self.world_user!r}")
        for port, spec in self.stations.items():
            require(port in self.station_users, f"station_users.{port}", "no user drives it")
            require(
                spec.user == self.station_users[port],
                f"stations.{port}.user",
                f"must be {self.station_users[port]!r}, the user station_users gives port {port}",
            )
        users = list(self.station_users.values())
        require(len(set(users)) == len(users), "station_users", "one user per port")
        require(self.world_user not in users, "station_users", "the world's user drives no port")
        if self.sim.connect:
            require("sim" not in self.stations, "stations.sim", "a port named sim: the sim's role")
            require(self.sim.user == self.sim_user, "sim.user", f"must be {self.sim_user!r}")
            require(
                self.sim_user not in [*users, self.world_user],
                "sim_user",
                "the sim's user is neither the world's nor a station's",
            )

    def station(self, port: str) -> EndpointSpec:
        if port not in self.stations:
            known = ", ".join(sorted(self.stations))
            raise ValueError(f"stations.{port}: no such station (known: {known})")
        return self.stations[port]


def state_publisher(session: zenoh.Session, key: str, reliability: str) -> Any:
    """A publisher of a port's states (ToolState or DeviceState): the newest matters, so a
    congested link drops (it does not block the loop), express (not batched), with the
    network's `state_reliability`."""
    return session.declare_publisher(
        key,
        congestion_control=zenoh.CongestionControl.DROP,
        express=True,
        reliability=STATE_RELIABILITY[reliability],
    )


#: how often a link's end looks at its routes (ns): a route lost is declared again this late
ROUTE_CHECK_NS = 1_000_000_000


class StateRoute:
    """One end of a port's link: the subscriber of the other end's states and the publisher
    of its own, each declared again when its route is missing.

    Over a UDP link (`stations_three_hosts_udp`) the session's declarations ride
    unretransmitted, and one lost is lost for the session's life. A Zenoh client filters
    its puts at the publisher by the subscribers its router declared to it: in one of four
    runs at 5 % loss (benchmarks/station_links.py) a station's DeviceStates never left it,
    the world received none in 14 s and the station was never joined. So every
    ROUTE_CHECK_NS, `check` declares the publisher again if no subscriber matches it (its
    interest sent again: the router answers with what it has), and the subscriber again if
    nothing arrived on it since the last check (its declaration sent again). Neither costs a
    state: nothing was getting through. Both are counted (`redeclared`). Before the other
    end exists it declares them once a second, which is harmless."""

    def __init__(
        self, session: zenoh.Session, keys: tuple[str, str], ring: int, reliability: str
    ) -> None:
        self._session, self._keys, self._ring = session, keys, ring
        self._reliability = reliability
        self.sub = session.declare_subscriber(keys[0], zenoh.handlers.RingChannel(ring))
        self.pub = state_publisher(session, keys[1], reliability)
        self.redeclared = {"publisher": 0, "subscriber": 0}
        self._next_ns: int | None = None
        self._received = -1

    def check(self, now_ns: int, received: Callable[[], int]) -> None:
        """At now_ns (any monotonic clock, ns); `received()`: the states this end has taken or
        refused so far, counted only when a look is due (a loop calls this every tick, as
        FloodTrim.after)."""
        if self._next_ns is not None and now_ns < self._next_ns:
            return
        count = received()
        if self._next_ns is not None:  # the first look only notes what has arrived
            self._look(count)
        self._received, self._next_ns = count, now_ns + ROUTE_CHECK_NS

    def _look(self, count: int) -> None:
        """Each route declared again if it is missing (the class's docstring)."""
        if not self.pub.matching_status.matching:
            self.pub.undeclare()
            self.pub = state_publisher(self._session, self._keys[1], self._reliability)
            self.redeclared["publisher"] += 1
        if count == self._received:
            self.sub.undeclare()
            self.sub = self._session.declare_subscriber(
                self._keys[0], zenoh.handlers.RingChannel(self._ring)
            )
            self.redeclared["subscriber"] += 1


def access_control(config: StationNetworkConfig, ports: list[str]) -> dict[str, Any]:
    """The router's table (module docstring): default deny, then each role's own flows.
    A router forwards a put it received (ingress from the sender) to a subscriber (egress to
    it) and a subscriber's declaration the other way, so each flow is allowed both ways."""
    ns = config.namespace
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = [{"id": "world", "usernames": [config.world_user]}]
    policies: list[dict[str, Any]] = []

    def allow(rule_id: str, message: str, flow: str, key: str) -> str:
        rules.append({"id": rule_id, "messages": [message], "flows": [flow],
                      "permission": "allow", "key_exprs": [key]})  # fmt: skip
        return rule_id

    world_rules = [
        allow("world_puts_tools", "put", "ingress", f"{ns}/port/*/tool"),
        allow("world_follows_devices", "declare_subscriber", "ingress", f"{ns}/port/*/device"),
        allow("devices_to_world", "put", "egress", f"{ns}/port/*/device"),
        allow("tools_followed", "declare_subscriber", "egress", f"{ns}/port/*/tool"),
    ]
    world_bodies, sim_bodies = mirror_keys(ns)
    world_rules += [
        allow("world_puts_bodies", "put", "ingress", world_bodies),
        allow("world_follows_sim", "declare_subscriber", "ingress", sim_bodies),
        allow("sim_bodies_to_world", "put", "egress", sim_bodies),
        allow("world_bodies_followed", "declare_subscriber", "egress", world_bodies),
    ]
    policies.append({"id": "world_drives", "subjects": ["world"], "rules": world_rules})
    if config.sim.connect:
        subjects.append({"id": "sim", "usernames": [config.sim_user]})
        sim_rules = [
            allow("sim_puts_bodies", "put", "ingress", sim_bodies),
            allow("sim_follows_world", "declare_subscriber", "ingress", world_bodies),
            allow("world_bodies_to_sim", "put", "egress", world_bodies),
            allow("sim_bodies_followed", "declare_subscriber", "egress", sim_bodies),
        ]
        policies.append({"id": "sim_mirrors", "subjects": ["sim"], "rules": sim_rules})
    for port in ports:
        device, tool = port_keys(ns, port)
        subjects.append({"id": f"station_{port}", "usernames": [config.station_users[port]]})
        mine = [
            allow(f"{port}_puts_device", "put", "ingress", device),
            allow(f"{port}_follows_tool", "declare_subscriber", "ingress", tool),
            allow(f"{port}_tool_to_station", "put", "egress", tool),
            allow(f"{port}_device_followed", "declare_subscriber", "egress", device),
        ]
        policies.append({"id": f"station_{port}_drives", "subjects": [f"station_{port}"],
                         "rules": mine})  # fmt: skip
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}  # fmt: skip


def router_config(config: StationNetworkConfig) -> zenoh.Config:
    """Zenoh's router mode on router.listen, with the stations' access control."""
    conf = session_config(config.router, mode="router")
    if config.router.users_file:
        acl = access_control(config, sorted(config.station_users))
        conf.insert_json5("access_control", json.dumps(acl))
    return conf


def client_config(endpoints: EndpointSpec) -> zenoh.Config:
    """A client of the router (the world or a station): all its traffic goes through it."""
    return session_config(endpoints, mode="client")


def open_client(endpoints: EndpointSpec) -> zenoh.Session:
    """A client session with the router; ConnectionError naming its endpoints if it cannot
    be reached (or refuses the credentials)."""
    try:
        return zenoh.open(client_config(endpoints))
    except zenoh.ZError as exc:
        raise ConnectionError(
            f"cannot reach the router at {list(endpoints.connect)}: {exc}"
        ) from None


def load_station_network(name_or_path: str, role: str) -> StationNetworkConfig:
    """Load a station network; its files made absolute (relative to the config's folder).
    `role` ("router", "world" or a port's name) names the files that must exist here: a
    host needs only its own."""
    config: StationNetworkConfig
    config, path = load_config_file(StationNetworkConfig, "network", name_or_path)
    config = dataclasses.replace(
        config,
        router=config.router.under(path.parent),
        world=config.world.under(path.parent),
        sim=config.sim.under(path.parent),
        stations={p: s.under(path.parent) for p, s in config.stations.items()},
    )
    if role == "router":
        key, spec = "router", config.router
    elif role == "world":
        key, spec = "world", config.world
    elif role == "sim" and config.sim.connect:
        key, spec = "sim", config.sim
    elif role in config.stations:
        key, spec = f"stations.{role}", config.stations[role]
    else:
        sim = ["sim"] if config.sim.connect else []
        known = ", ".join(["router", "world", *sim, *sorted(config.stations)])
        raise ConfigError(str(path), "stations", f"no role {role!r} (known: {known})")
    spec.require_files(str(path), key)
    if role == "router" and config.router.users_file:
        users = _read_users(config.router.users_file, str(path))
        sim_user = [config.sim_user] if config.sim.connect else []
        for user in [config.world_user, *config.station_users.values(), *sim_user]:
            if user not in users:
                raise ConfigError(
                    str(path), "router.users_file", f"user {user!r} is not in {spec.users_file}"
                )
    try:
        router_config(config) if role == "router" else client_config(spec)
    except ValueError as exc:
        sub, _, problem = str(exc).partition(": ")
        raise ConfigError(str(path), f"{key}.{sub}", problem) from None
    return config

"""The network config: Zenoh endpoints and credentials of the two processes, the namespace,
the watchdog and the safe-state ramp (configs/network/, docs/security.md)."""

from __future__ import annotations

import dataclasses
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

from haptic_local_model.shared.config import ConfigError, load_config_file, require, within
from haptic_local_model.shared.net.credentials import LOCAL, CredentialsError, local_credentials
from haptic_local_model.shared.protocol.layout import (
    DEFAULT_CLOCK_SKEW_MS,
    DEFAULT_MAX_UPDATE_AGE_MS,
)

# --- network --------------------------------------------------------------------------------


#: a Zenoh locator as its config parser takes it: <protocol>/<address>[?metadata][#config]
ENDPOINT = re.compile(r"(tcp|udp|tls|quic|ws|unixsock-stream|unixpipe|serial|vsock)/[^\s/?#][^\s]*")


@dataclass(frozen=True)
class EndpointSpec:
    """Zenoh endpoints of one process (peer mode, no multicast scouting) and, optionally, its
    credentials and who may talk to it (docs/security.md). Files are relative to the config."""

    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    # usrpwd authentication when connecting: the user presented, its password in a file
    user: str = ""
    password_file: str = ""
    # the listening side: `user:password` lines of the peers it accepts (others are refused)
    users_file: str = ""
    # access control on the listener, default deny (on when sim_users is set): who may drive
    # (publish local models, follow the proxy) and who may only follow the proxy
    sim_users: tuple[str, ...] = ()
    observer_users: tuple[str, ...] = ()
    # Zenoh's low-latency unicast transport (no batching, no QoS priorities, no fragmentation:
    # messages < 64 KB). Negotiated: it is used only when both ends ask for it. Measured on
    # loopback: update transit p50 0.23 -> 0.15 ms, p99 0.85 -> 0.33 ms (docs/bench/speed.md).
    low_latency: bool = True
    # the largest message this end takes (bytes): anything longer is dropped by Zenoh before
    # it is delivered (an update is at most ~9 KB, a proxy state ~250 B)
    max_message_bytes: int = 65536
    # further Zenoh config keys, path -> JSON value, e.g. "transport/link/tx/lease" = "3000"
    zenoh: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for key in ("listen", "connect"):
            for i, endpoint in enumerate(getattr(self, key)):
                require(
                    ENDPOINT.fullmatch(endpoint) is not None,
                    f"{key}[{i}]",
                    f"{endpoint!r} is not a Zenoh endpoint <protocol>/<address>[:port]"
                    " (e.g. tcp/127.0.0.1:7447)",
                )
        require(
            bool(self.user) == bool(self.password_file),
            "password_file" if self.user else "user",
            "user and password_file go together",
        )
        for key in ("user", "sim_users", "observer_users"):
            value = getattr(self, key)
            for name in (value,) if isinstance(value, str) else value:
                require(
                    ":" not in name and name.strip() == name and (bool(name) or key == "user"),
                    key,
                    f"bad user name {name!r}",
                )
        require(
            not self.sim_users or bool(self.users_file),
            "sim_users",
            "access control by user name needs authentication: set users_file",
        )
        require(
            not self.observer_users or bool(self.sim_users), "observer_users", "needs sim_users"
        )
        within(self.max_message_bytes, MESSAGE_BYTES_RANGE, "max_message_bytes", "bytes")
        for path, value in self.zenoh.items():
            require(
                not any(path == m or path.startswith(m + "/") for m in ZENOH_MANAGED_KEYS),
                f"zenoh.{path}",
                "set by the endpoint keys above, not here",
            )
            try:
                json.loads(value)
            except json.JSONDecodeError as exc:
                raise ValueError(f"zenoh.{path}: not a JSON value ({exc})") from None

    def files(self) -> dict[str, str]:
        """The files this endpoint reads, by key."""
        names = ("password_file", "users_file")
        return {k: getattr(self, k) for k in names if getattr(self, k)}

    def under(self, folder: Path) -> EndpointSpec:
        """This endpoint with its files made absolute, relative to `folder` (its config's);
        "@local" (this installation's own credentials) stays as it is."""
        return dataclasses.replace(
            self,
            password_file=_absolute(folder, self.password_file),
            users_file=_absolute(folder, self.users_file),
        )

    def require_files(self, source: str, key: str) -> None:
        """Every file this endpoint reads exists (else a ConfigError naming `key`.<its key>)."""
        for name, file in self.files().items():
            if not Path(file).is_file():
                raise ConfigError(source, f"{key}.{name}", f"file not found: {file}")


# Zenoh config paths the endpoint keys set; the `zenoh` table may not override them
ZENOH_MANAGED_KEYS = (
    "mode", "listen/endpoints", "connect/endpoints", "transport/auth/usrpwd", "access_control",
    "transport/unicast/lowlatency", "transport/unicast/qos", "transport/link/rx/max_message_size",
    "low_pass_filter",
)  # fmt: skip
MESSAGE_BYTES_RANGE = (4096, 16 * 1024 * 1024)


PROXY_HZ_RANGE = (1.0, 10_000.0)
VIEW_HZ_RANGE = (1.0, 120.0)
WATCHDOG_MS_RANGE = (10.0, 1000.0)
SAFE_RAMP_MS_RANGE = (1.0, 50.0)
CLOCK_SKEW_MS_RANGE = (0.0, 1000.0)


def require_safe_state(namespace: str, watchdog_ms: float, safe_ramp_ms: float) -> None:
    """The checks every network config (this one, a station network's) makes of its namespace
    (a plain key) and of its safe state: the watchdog's period and the force ramp within their
    stated ranges (the loader rejects nan and inf). A watchdog that never fires or a ramp that
    never ends switch the safe state off, and the device must be safe within 50 ms of the
    watchdog."""
    require(bool(namespace) and "*" not in namespace, "namespace", "must be a plain key")
    within(watchdog_ms, WATCHDOG_MS_RANGE, "watchdog_ms", "ms")
    within(safe_ramp_ms, SAFE_RAMP_MS_RANGE, "safe_ramp_ms", "ms")


@dataclass(frozen=True)
class NetworkConfig:
    """Key-expression namespace and the endpoints of both processes."""

    namespace: str = "haptic/default"
    haptic: EndpointSpec = field(default_factory=EndpointSpec)
    sim: EndpointSpec = field(default_factory=EndpointSpec)
    proxy_publish_hz: float = 250.0  # haptic -> sim proxy state rate
    # sim -> live view: the world's poses this often, only while a view subscribes
    view_publish_hz: float = 30.0
    watchdog_ms: float = 100.0  # no valid update for this long: device to safe state
    safe_ramp_ms: float = 40.0  # force ramp into (and out of) the safe state (< 50 ms)
    # an update older than this when the haptic server takes it is rejected as late
    max_update_age_ms: float = DEFAULT_MAX_UPDATE_AGE_MS
    # how far the sim's clock may run ahead of the haptic server's (two hosts: sync them)
    clock_skew_ms: float = DEFAULT_CLOCK_SKEW_MS
    # a haptic server that listens without authentication drives the device for anyone who
    # reaches its endpoint: refused unless this says, knowingly, that it may (docs/security.md)
    unauthenticated_insecure: bool = False

    def __post_init__(self) -> None:
        require_safe_state(self.namespace, self.watchdog_ms, self.safe_ramp_ms)
        # a proxy rate of zero would switch the safe state off as well
        within(self.proxy_publish_hz, PROXY_HZ_RANGE, "proxy_publish_hz", "Hz")
        within(self.view_publish_hz, VIEW_HZ_RANGE, "view_publish_hz", "Hz")
        # an update older than the watchdog's period could end an outage it predates
        within(self.max_update_age_ms, (1.0, self.watchdog_ms), "max_update_age_ms", "ms")
        within(self.clock_skew_ms, CLOCK_SKEW_MS_RANGE, "clock_skew_ms", "ms")
        require(
            not self.haptic.listen or bool(self.haptic.users_file) or self.unauthenticated_insecure,
            "haptic.users_file",
            "the haptic server listens without authentication: anyone who reaches "
            f'{list(self.haptic.listen)} could drive the device. Set users_file ("{LOCAL}": '
            "this installation's own credentials) with sim.user and sim.password_file, or, "
            "knowingly, unauthenticated_insecure = true",
        )
        if self.haptic.users_file and self.sim.connect:
            require(bool(self.sim.user), "sim.user", "the haptic server requires a user")
        if self.haptic.sim_users and self.sim.connect:
            require(
                self.sim.user in self.haptic.sim_users,
                "sim.user",
                f"not in haptic.sim_users {list(self.haptic.sim_users)}: it could not drive",
            )


#: an endpoint's address: <protocol>/<host>:<port>, then metadata or config
_HOST_PORT = re.compile(r"(?P<head>[a-z-]+/(?P<host>.+)):(?P<port>\d+)(?P<tail>[?#].*)?")
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "[::1]")


def on_port(network: NetworkConfig, port: int) -> NetworkConfig:
    """The network with the haptic server listening, and the sim connecting, on `port`
    (every endpoint of haptic.listen and sim.connect): haptic-run's free port, --port."""
    within(port, (1, 65535), "port")

    def moved(endpoints: tuple[str, ...]) -> tuple[str, ...]:
        out = []
        for e in endpoints:
            m = _HOST_PORT.fullmatch(e)
            out.append(f"{m['head']}:{port}{m['tail'] or ''}" if m else e)
        return tuple(out)

    haptic = dataclasses.replace(network.haptic, listen=moved(network.haptic.listen))
    sim = dataclasses.replace(network.sim, connect=moved(network.sim.connect))
    return dataclasses.replace(network, haptic=haptic, sim=sim)


def on_loopback(network: NetworkConfig) -> bool:
    """Both ends of the network are this host's loopback (haptic-run may move them to a free
    port of their own)."""
    ends = network.haptic.listen + network.sim.connect
    matches = [_HOST_PORT.fullmatch(e) for e in ends]
    return bool(ends) and all(m is not None and m["host"] in LOOPBACK_HOSTS for m in matches)


def free_loopback_port() -> int:
    """A TCP port free on 127.0.0.1 now (the kernel's choice)."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def load_network(name_or_path: str, roles: tuple[str, ...] = ("haptic", "sim")) -> NetworkConfig:
    """Load a network config; credential files are made absolute (relative to the config's
    folder) and those of `roles` must exist, so a host needs only its own secrets."""
    network: NetworkConfig
    network, path = load_config_file(NetworkConfig, "network", name_or_path)
    specs = {}
    for role in ("haptic", "sim"):
        spec: EndpointSpec = getattr(network, role)
        if LOCAL in (spec.password_file, spec.users_file) and role in roles:
            try:
                local_users, local_password = local_credentials()
            except CredentialsError as exc:
                key = "users_file" if spec.users_file == LOCAL else "password_file"
                raise ConfigError(str(path), f"{role}.{key}", str(exc)) from None
            spec = dataclasses.replace(
                spec,
                password_file=(
                    str(local_password) if spec.password_file == LOCAL else spec.password_file
                ),
                users_file=str(local_users) if spec.users_file == LOCAL else spec.users_file,
            )
        spec = spec.under(path.parent)  # another host's "@local" stays: not needed here
        if role in roles:
            spec.require_files(str(path), role)
        specs[role] = spec
    network = dataclasses.replace(network, haptic=specs["haptic"], sim=specs["sim"])
    from haptic_local_model.shared.net.transport import (
        session_config,  # Zenoh checks its own keys (and is heavy)
    )

    for role in roles:
        try:
            session_config(getattr(network, role), None, network.namespace)
        except ValueError as exc:
            key, _, problem = str(exc).partition(": ")
            raise ConfigError(str(path), f"{role}.{key}", problem) from None
    if "haptic" in roles and network.haptic.users_file:
        users = _read_users(network.haptic.users_file, str(path))
        if "sim" in roles and network.sim.user:
            # a refused peer is not told (STACK-NOTES): catch a mismatch here instead
            password = Path(network.sim.password_file).read_text().splitlines()[:1]
            _require_config(
                users.get(network.sim.user) == (password or [""])[0],
                str(path),
                "sim.password_file",
                f"user {network.sim.user!r} and this password are not in haptic.users_file",
            )
    return network


def _absolute(folder: Path, file: str) -> str:
    return str((folder / file).resolve()) if file and file != LOCAL else file


def _read_users(users_file: str, source: str) -> dict[str, str]:
    """The `user:password` lines of a Zenoh usrpwd dictionary (blank lines allowed)."""
    users: dict[str, str] = {}
    for n, line in enumerate(Path(users_file).read_text().splitlines(), 1):
        if not line.strip():
            continue
        user, sep, password = line.partition(":")
        _require_config(
            bool(sep and user and password),
            source,
            "haptic.users_file",
            f"{users_file} line {n}: expected user:password",
        )
        users[user] = password
    return users


def _require_config(cond: bool, source: str, key: str, problem: str) -> None:
    if not cond:
        raise ConfigError(source, key, problem)

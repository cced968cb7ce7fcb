"""Network configs with credentials: what loads, what is refused with the key named, and the
Zenoh config they turn into (shared/net/security.py)."""

from __future__ import annotations

import json
import re
import textwrap
from pathlib import Path

import pytest

from haptic_local_model.shared.config import CONFIG_ROOT, ConfigError
from haptic_local_model.shared.net.config import load_network
from haptic_local_model.shared.net.security import zenoh_keys
from haptic_local_model.shared.net.transport import session_config

CREDENTIALS = CONFIG_ROOT / "credentials"
SIM_PASSWORD = (CREDENTIALS / "example_sim.password").read_text().splitlines()[0]


def _secure(tmp_path: Path, haptic_extra: str = "", sim_extra: str = "") -> Path:
    """A secure config in tmp_path whose credential files sit next to it (relative paths)."""
    for f in ("example_users.txt", "example_sim.password"):
        (tmp_path / f).write_text((CREDENTIALS / f).read_text())
    path = tmp_path / "net.toml"
    path.write_text(
        'namespace = "haptic/t"\n'
        "[haptic]\n"
        'listen = ["tcp/127.0.0.1:7999"]\n'
        'users_file = "example_users.txt"\n'
        'sim_users = ["sim"]\n'
        f"{haptic_extra}"
        "[sim]\n"
        'connect = ["tcp/127.0.0.1:7999"]\n'
        'user = "sim"\n'
        'password_file = "example_sim.password"\n'
        f"{sim_extra}"
    )
    return path


def test_shipped_network_configs_load_and_make_zenoh_configs() -> None:
    for path in sorted((CONFIG_ROOT / "network").glob("*.toml")):
        if path.name.startswith("stations_"):  # a world and its stations: test_stations.py
            continue
        network = load_network(str(path))
        for spec in (network.haptic, network.sim):
            session_config(spec, None, network.namespace)  # zenoh accepts every key


def test_no_shared_memory_transport() -> None:
    """Zenoh's shared memory is off for both endpoints: with it, the haptic server's I/O
    process mapped each sim's 16 MB pool (a killed one's too) and kept it resident."""
    network = load_network("loopback")
    for spec in (network.haptic, network.sim):
        conf = session_config(spec, None, network.namespace)
        assert json.loads(conf.get_json("transport/shared_memory/enabled")) is False


def test_relative_credential_paths_are_resolved_next_to_the_config(tmp_path: Path) -> None:
    network = load_network(str(_secure(tmp_path)))
    assert network.haptic.users_file == str(tmp_path / "example_users.txt")
    keys = zenoh_keys(network.sim, network.namespace)
    assert json.loads(keys["transport/auth/usrpwd/password"]) == SIM_PASSWORD
    acl = json.loads(zenoh_keys(network.haptic, network.namespace)["access_control"])
    assert acl["default_permission"] == "deny"
    allowed = {(r["messages"][0], r["flows"][0], r["key_exprs"][0]) for r in acl["rules"]}
    assert ("put", "ingress", "haptic/t/local_model") in allowed
    assert ("declare_subscriber", "egress", "haptic/t/local_model") in allowed
    assert all(r["permission"] == "allow" for r in acl["rules"])


def test_a_host_needs_only_its_own_secrets(tmp_path: Path) -> None:
    path = _secure(tmp_path)
    (tmp_path / "example_sim.password").unlink()
    load_network(str(path), roles=("haptic",))
    with pytest.raises(ConfigError) as err:
        load_network(str(path), roles=("sim",))
    assert err.value.key == "sim.password_file" and "file not found" in err.value.problem


@pytest.mark.parametrize(
    ("haptic_extra", "sim_extra", "key", "needle"),
    [
        ("", 'zenoh = { "transport/link/tx/lease" = "soon" }\n',
         "sim.zenoh.transport/link/tx/lease", "not a JSON value"),
        ('zenoh = { "access_control" = "{}" }\n', "", "haptic.zenoh.access_control",
         "set by the endpoint keys"),
        ('observer_users = ["a:b"]\n', "", "haptic.observer_users", "bad user name"),
        ("", 'zenoh = { "connect/retry/period_ms" = "250" }\n', "sim.zenoh.connect/retry/period_ms",
         "unknown key"),
    ],
)  # fmt: skip
def test_bad_security_keys_are_named(
    tmp_path: Path, haptic_extra: str, sim_extra: str, key: str, needle: str
) -> None:
    with pytest.raises(ConfigError) as err:
        load_network(str(_secure(tmp_path, haptic_extra, sim_extra)))
    assert err.value.key == key and needle in err.value.problem


def test_inconsistent_credentials_are_caught_at_load(tmp_path: Path) -> None:
    """A refused peer is not told (STACK-NOTES), so mismatches must fail before the run."""
    path = _secure(tmp_path)
    (tmp_path / "example_sim.password").write_text("not-the-password\n")
    with pytest.raises(ConfigError) as err:
        load_network(str(path))
    assert err.value.key == "sim.password_file"
    path.write_text(path.read_text().replace('user = "sim"', 'user = "monitor"'))
    with pytest.raises(ConfigError) as err:
        load_network(str(path))
    assert err.value.key == "sim.user" and "sim_users" in err.value.problem
    path.write_text(path.read_text().replace('user = "monitor"\n', ""))
    with pytest.raises(ConfigError) as err:
        load_network(str(path))
    assert err.value.key == "sim.user" and "go together" in err.value.problem
    path = _secure(tmp_path)
    (tmp_path / "example_users.txt").write_text("sim-without-a-password\n")
    with pytest.raises(ConfigError) as err:
        load_network(str(path))
    assert err.value.key == "haptic.users_file" and "line 1" in err.value.problem


def test_access_control_needs_authentication(tmp_path: Path) -> None:
    path = tmp_path / "net.toml"
    path.write_text('[haptic]\nlisten = ["tcp/127.0.0.1:7999"]\nsim_users = ["sim"]\n')
    with pytest.raises(ConfigError) as err:
        load_network(str(path))
    assert err.value.key == "haptic.sim_users" and "users_file" in err.value.problem


def test_the_deployment_example_in_the_docs_loads(tmp_path: Path) -> None:
    doc = (CONFIG_ROOT.parent / "docs/security.md").read_text()
    block = re.search(r"<!-- credentials-config.*?```toml\n(.*?)```", doc, re.S)
    assert block
    (tmp_path / "users.txt").write_text((CREDENTIALS / "example_users.txt").read_text())
    (tmp_path / "sim.password").write_text(SIM_PASSWORD + "\n")
    path = tmp_path / "lab1.toml"
    path.write_text(textwrap.dedent(block.group(1)).replace("/etc/haptic/", f"{tmp_path}/"))
    network = load_network(str(path))
    assert network.haptic.sim_users == ("sim",) and network.sim.user == "sim"


def test_flood_trim_trims_in_a_floods_seconds_and_the_one_after() -> None:
    """FloodTrim counts once a window: it trims in each window a flood's worth of messages
    arrived in and in the one after (the flood's last freed buffers), never in quiet ones."""
    from haptic_local_model.shared.memory import TRIM_AFTER, TRIM_EVERY_S, FloodTrim

    trim = FloodTrim()
    calls: list[int] = []
    trim._trim = calls.append  # the test's malloc_trim
    received = [0]
    per_window = [10, 60, TRIM_AFTER + 5, 3 * TRIM_AFTER, 4, 6, 6, TRIM_AFTER, 0, 0]
    trimmed = []
    for window, n in enumerate(per_window):
        received[0] += n
        before = len(calls)
        for k in range(4):  # called often: counts and acts once a window
            trim.after((window + 1.0 + k * 0.2) * TRIM_EVERY_S, lambda: received[0])
        trimmed.append(len(calls) - before)
    assert trimmed == [0, 0, 1, 1, 1, 0, 0, 1, 1, 0]

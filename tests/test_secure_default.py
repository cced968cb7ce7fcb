"""The default configuration is the safe one (docs/security.md).

- Its credentials are this installation's own: made on first use, once (two processes that
  start together agree), readable by the user only, never shipped; a config listening without
  authentication is refused unless it says, by a loud name, that it may be.
- Real processes on the default network: a stranger without credentials installs nothing and
  does not slow the sim's updates while it sends models, 1, 10 and 100 MB messages and a
  10 kHz flood (benchmarks/stranger.py); a message beyond Zenoh's size limit is dropped by the
  transport even from the sim's own credentials; two default runs at once do not collide
  (haptic-run takes a free port of its own).
"""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from haptic_local_model.benchmarks.stranger import PHASES, run
from haptic_local_model.haptic_server.log import UPDATE_TOPIC, read_json_topic, read_ticks
from haptic_local_model.shared.config import CONFIG_ROOT, ConfigError
from haptic_local_model.shared.net.config import EndpointSpec, load_network, on_loopback, on_port
from haptic_local_model.shared.net.credentials import CredentialsError, local_credentials
from haptic_local_model.shared.net.transport import keys, open_session

REPO = Path(__file__).resolve().parent.parent
#: the sim's update age during an attack phase: within noise of the quiet phase. A bound that
#: only a real slow-down breaks on a noisy 2-core VM: p90 (a 1 s phase holds 60 updates, so
#: its p99 is one update, and one VM stall of 80 ms was seen in 1 of 7 runs of the benchmark,
#: in a phase whose messages never left the stranger); measured p90 0.3-0.9 ms in every phase
AGE_P90_FACTOR, AGE_P90_SLACK_MS = 3.0, 5.0


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_local_credentials_are_made_once_and_private(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    folder = tmp_path / "creds"
    monkeypatch.setenv("HAPTIC_CREDENTIALS_DIR", str(folder))
    users, password = local_credentials()
    assert _mode(folder) == 0o700 and _mode(users) == 0o600 and _mode(password) == 0o600
    secret = password.read_text().splitlines()[0]
    assert len(secret) >= 32
    assert users.read_text() == f"sim:{secret}\n"
    assert local_credentials() == (users, password)
    assert password.read_text().splitlines()[0] == secret  # not made again
    network = load_network("loopback")
    assert network.haptic.users_file == str(users)
    assert network.sim.password_file == str(password)
    password.chmod(0o644)
    with pytest.raises(CredentialsError, match="readable by others"):
        local_credentials()
    with pytest.raises(ConfigError) as err:
        load_network("loopback")
    assert err.value.key in ("haptic.users_file", "sim.password_file")
    assert str(password) in err.value.problem


def _password_of(folder: str) -> str:
    os.environ["HAPTIC_CREDENTIALS_DIR"] = folder
    return local_credentials()[1].read_text()


@pytest.mark.processes
def test_processes_that_start_together_agree_on_one_password(tmp_path: Path) -> None:
    folder = str(tmp_path / "creds")
    with ProcessPoolExecutor(6) as pool:
        passwords = list(pool.map(_password_of, [folder] * 12))
    assert len(set(passwords)) == 1


def test_listening_without_authentication_is_refused_unless_it_says_so(tmp_path: Path) -> None:
    open_config = 'namespace = "x"\n[haptic]\nlisten = ["tcp/127.0.0.1:7999"]\n'
    path = tmp_path / "open.toml"
    path.write_text(open_config)
    with pytest.raises(ConfigError) as err:
        load_network(str(path))
    assert err.value.key == "haptic.users_file" and "anyone" in err.value.problem
    path.write_text("unauthenticated_insecure = true\n" + open_config)
    assert load_network(str(path)).unauthenticated_insecure
    shipped = load_network("insecure_open_loopback")
    assert shipped.unauthenticated_insecure and not shipped.haptic.users_file
    assert "INSECURE" in (CONFIG_ROOT / "network/insecure_open_loopback.toml").read_text()
    default = load_network("loopback")
    assert default.haptic.users_file and default.haptic.sim_users == ("sim",)
    assert not default.unauthenticated_insecure
    assert default.haptic.max_message_bytes == 65536


def test_a_run_moves_to_a_port_of_its_own() -> None:
    network = load_network("loopback")
    assert on_loopback(network)
    moved = on_port(network, 5123)
    assert moved.haptic.listen == ("tcp/127.0.0.1:5123",)
    assert moved.sim.connect == ("tcp/127.0.0.1:5123",)
    assert not on_loopback(load_network("two_hosts", roles=("haptic",)))


@pytest.mark.processes
def test_a_stranger_installs_nothing_and_slows_nothing(tmp_path: Path) -> None:
    result = run(1.0, tmp_path)
    assert result.stranger_sent > 10_000
    assert result.stranger_arrived == 0
    assert result.installed_epochs == {result.sim_epoch}
    quiet = max(result.percentile("quiet", 90), result.percentile("quiet_after", 90))
    for phase in PHASES:
        assert result.ages_ms.get(phase), f"no update of the sim installed during {phase}"
        bound = max(AGE_P90_FACTOR * quiet, quiet + AGE_P90_SLACK_MS)
        p90 = result.percentile(phase, 90)
        assert p90 <= bound, f"{phase}: p90 {p90:.2f} ms"


@pytest.mark.processes
def test_a_message_beyond_the_size_limit_is_dropped_by_the_transport(
    tmp_path: Path, network_file: Path, start_server: Any
) -> None:
    """Even with the sim's own credentials: 200 KB never reaches the haptic server's
    mailbox (Zenoh drops it), while 32 KB (within Zenoh's limit, beyond a mailbox slot)
    arrives and is refused as too large: the path itself works."""
    log = tmp_path / "run.mcap"
    common = ["--scene", "free_box", "--network", str(network_file)]
    haptic = start_server(
        "haptic_local_model.haptic_server.cli",
        *common,
        "--user",
        "constant_push",
        "--log",
        str(log),
    )
    haptic.wait_ready()
    sim = start_server("haptic_local_model.sim_server.cli", *common)
    sim.wait_ready()
    network = load_network(str(network_file))
    spec = EndpointSpec(
        connect=network.sim.connect, user="sim", password_file=network.sim.password_file
    )
    peer = open_session(spec)
    pub = peer.declare_publisher(
        keys(network.namespace).update, congestion_control=zenoh.CongestionControl.BLOCK
    )
    time.sleep(1.0)  # the peer's session up, the sim's updates flowing
    try:
        for size in (200 * 1024, 32 * 1024) * 3:
            pub.put(bytes(size))
            time.sleep(0.2)
    finally:
        peer.close()
    time.sleep(0.5)
    assert haptic.stop() == 0
    assert sim.stop() == 0
    sizes = [r["size_bytes"] for r in read_json_topic(log, UPDATE_TOPIC)]
    assert 32 * 1024 in sizes, "the control never arrived"
    assert max(sizes) < network.haptic.max_message_bytes
    ticks = read_ticks(log)
    assert (ticks["update_seq"] >= 0).any()


@pytest.mark.processes
def test_two_default_runs_at_once_do_not_collide(tmp_path: Path) -> None:
    runs = []
    for i in range(2):
        summary = tmp_path / f"summary-{i}.json"
        argv = [
            sys.executable, "-m", "haptic_local_model.haptic_server.harness.run", "--scene",
            "free_box",
            "--user", "constant_push", "--duration", "2", "--no-log", "--summary-json",
            str(summary),
        ]  # fmt: skip
        proc = subprocess.Popen(argv, cwd=tmp_path, stdout=subprocess.PIPE, text=True)
        runs.append((proc, summary))
    try:
        for proc, _ in runs:
            proc.wait(600)
    finally:
        for proc, _ in runs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    for proc, summary in runs:
        assert proc.returncode == 0
        data: dict[str, Any] = json.loads(summary.read_text())
        assert data["updates_installed"] > 0 and data["rejected_by_reason"] == {}
    assert np.all([proc.returncode == 0 for proc, _ in runs])


@pytest.mark.slow
@pytest.mark.processes
def test_a_flood_on_every_key_is_counted_by_reason_and_loses_no_safety_event(
    tmp_path: Path,
) -> None:
    """30,000 refused messages on each of the haptic server's keys and on the sim's proxy
    key, twice, with the sim's credentials and the sim stopped throughout
    (benchmarks/flood.py): every one is refused
    and counted by its reason (an update the mailbox had no room for is counted as lost),
    the watchdog's trip during the flood is in the log and no event was lost, and none of
    the haptic server's processes grows by more than 1 MB in either round beyond what it
    grows by in the same round of a control run without the flood, run after it (the
    benchmark's measure: with no flood at all the I/O process grew by 0.37 MB in a round on
    a loaded machine, and a clean-clone CI once saw it grow by 1.125 MB in a flood's round).
    (The I/O process's first flood grew it by 0-24 MB, glibc's arenas keeping what Zenoh's
    receive path freed, until it trimmed them after a flood: shared.memory.FloodTrim.)"""
    from haptic_local_model.benchmarks import flood

    result = flood.run(tmp_path, flood.MESSAGES, rounds=2)
    s = result.summary
    sent = result.sent
    assert sent == {name: 2 * flood.MESSAGES for name in flood.FLOODS}
    assert sum(s["rejected_by_reason"].values()) + s["updates_lost"] == sent["update"]
    assert set(s["rejected_by_reason"]) == {"magic"}, s["rejected_by_reason"]
    assert s["pointer_rejected_by_reason"] == {"future": sent["pointer"]}
    assert s["static_refused_by_reason"] == {"foreign": sent["static"]}
    # the proxy states sent toward the sim were dropped by the access control: none reached
    # it (its ring would have kept the newest 32, each refused and counted by its reason)
    assert result.sim_summary["proxies_rejected_by_reason"] == {}, result.sim_summary
    assert result.watchdog_trips >= 1 and result.events_lost == 0
    control = flood.run(tmp_path, flood.MESSAGES, rounds=2, control_s=result.flood_s)
    for r in range(2):
        own = result.own_growth_mb(control, r)
        print(f"\nflood round {r + 1}: resident growth " +
              ", ".join(f"{p} {mb:+.2f} MB" for p, mb in result.growth_mb(r).items()) +
              "; the control's " +
              ", ".join(f"{p} {mb:+.2f} MB" for p, mb in control.growth_mb(r).items()))  # fmt: skip
        assert max(own.values()) <= flood.GROWTH_TARGET_MB, (own, control.growth_mb(r))


class _Payload:
    def __init__(self, raw: bytes) -> None:
        self._raw = raw

    def to_bytes(self) -> bytes:
        return self._raw


class _Sample:
    def __init__(self, raw: bytes) -> None:
        self.payload = _Payload(raw)


class _Ring:
    """A ring-channel subscriber holding the given payloads (oldest first)."""

    def __init__(self, payloads: list[bytes]) -> None:
        self._waiting = [_Sample(p) for p in payloads]

    def try_recv(self) -> _Sample | None:
        return self._waiting.pop(0) if self._waiting else None


def test_the_sim_counts_the_proxy_states_it_refuses_by_reason() -> None:
    """What reaches the sim on its proxy key (only the haptic server may publish there) and
    is malformed is refused and counted by the parser's reason, in its summary; the newest
    valid one is still taken."""
    from haptic_local_model.benchmarks.flood import junk_proxy
    from haptic_local_model.shared.config import load_scene
    from haptic_local_model.shared.net.config import NetworkConfig
    from haptic_local_model.sim_server.server import SimServer

    server = SimServer(load_scene("free_box"), NetworkConfig())
    short = junk_proxy(0)[:10]
    server._read_proxies(_Ring([junk_proxy(i) for i in range(5)] + [short]), time.time_ns())
    assert server.stats.proxies_rejected == 6
    assert dict(server.stats.proxies_rejected_by_reason) == {"magic": 5, "short": 1}
    assert server._proxy is None

"""Only the configured sim drives a haptic server: Zenoh authentication and access control.

The haptic server and the sim run as real processes on the shipped `secure_loopback` config
(on a free port). Peers opened here publish valid local models, with a newer epoch than the
sim's (which the haptic server would switch to if it accepted them), on the same key: one
without credentials, one with a wrong password, one authenticated as an observer that may not
publish. None of their updates reaches the haptic server. A last peer presenting the sim's own
credentials is the control: its updates reach the haptic server, which refuses them only as
another epoch while the sim's updates flow (`test_forgery.py` follows that layer further).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import pytest
import zenoh
from conftest import free_port

from haptic_local_model.haptic_server.log import UPDATE_TOPIC, read_json_topic, read_ticks
from haptic_local_model.shared.config import CONFIG_ROOT, load_scene
from haptic_local_model.shared.net.config import EndpointSpec, load_network
from haptic_local_model.shared.net.transport import keys, open_session
from haptic_local_model.shared.protocol.update import encode_update
from haptic_local_model.sim_server.world import SimWorld

SCENE = "free_box"
UPDATES_PER_PEER = 60  # each peer publishes this many,
PUBLISH_HZ = 60.0  # as fast as the sim does
SIM_FLOW_S = 1.0  # the sim's updates are flowing for this long before the first intruder
MIN_SIM_FRACTION = 0.5  # of the sim's updates over the run installed (noisy 2-core VM)
# of the control's updates received: the first may race the subscriber's declaration at the
# new peer
MIN_CONTROL_FRACTION = 0.8
CREDENTIALS = CONFIG_ROOT / "credentials"
# A logged update that cannot be decoded: its mailbox slot was reused before the I/O process
# logged it (it lags on a loaded machine). The tick records say what was installed.
UNDECODED = -1


def secure_network(tmp_path: Path) -> Path:
    """The shipped secure_loopback config on a free port, with absolute credential paths."""
    port = free_port()
    text = (CONFIG_ROOT / "network/secure_loopback.toml").read_text()
    text = text.replace("127.0.0.1:7448", f"127.0.0.1:{port}")
    text = text.replace('"haptic/secure"', f'"haptic/secure{port}"')
    text = text.replace('"../credentials/', f'"{CREDENTIALS}/')
    path = tmp_path / "secure.toml"
    path.write_text(text)
    return path


def publish_updates(session: zenoh.Session, key: str, epoch: int) -> None:
    """UPDATES_PER_PEER valid local models of the scene under `epoch`, at the sim's rate."""
    world = SimWorld(load_scene(SCENE))
    publisher = session.declare_publisher(key)
    for seq in range(UPDATES_PER_PEER):
        publisher.put(encode_update(world.local_model(epoch, seq, time.time_ns())))
        time.sleep(1.0 / PUBLISH_HZ)
    publisher.undeclare()


def peer(connect: str, user: str = "", password: str = "", tmp: Path | None = None) -> Any:
    """A Zenoh peer connecting to the haptic server, with these credentials (or none)."""
    spec = EndpointSpec(connect=(connect,))
    if user:
        assert tmp is not None
        pw = tmp / f"{user}-{len(password)}.password"
        pw.write_text(password + "\n")
        spec = EndpointSpec(connect=(connect,), user=user, password_file=str(pw))
    return open_session(spec)


@pytest.mark.processes
def test_only_the_configured_sim_drives_the_haptic_server(
    tmp_path: Path, start_server: Any
) -> None:
    net_path = secure_network(tmp_path)
    network = load_network(str(net_path))
    endpoint = network.haptic.listen[0]
    key = keys(network.namespace).update
    log = tmp_path / "run.mcap"
    haptic = start_server(
        "haptic_local_model.haptic_server.cli", "--scene", SCENE, "--device", "ideal", "--user",
        "constant_push",
        "--network", str(net_path), "--log", str(log),
        "--summary-json", str(tmp_path / "haptic.json"),
    )  # fmt: skip
    haptic.wait_ready()
    sim = start_server(
        "haptic_local_model.sim_server.cli", "--scene", SCENE, "--network", str(net_path),
        "--summary-json", str(tmp_path / "sim.json"),
    )  # fmt: skip
    sim.wait_ready()
    sim_epoch = int(next(e for e in sim.events if e.get("event") == "ready")["epoch"])
    time.sleep(SIM_FLOW_S)

    sim_password = (CREDENTIALS / "example_sim.password").read_text().splitlines()[0]
    monitor_password = (CREDENTIALS / "example_monitor.password").read_text().splitlines()[0]
    intruders = {
        "no credentials": peer(endpoint),
        "wrong password": peer(endpoint, "sim", sim_password + "x", tmp_path),
        "unknown user": peer(endpoint, "mallory", sim_password, tmp_path),
        "observer (may not publish)": peer(endpoint, "monitor", monitor_password, tmp_path),
    }
    proxies_seen: dict[str, int] = {}
    epochs: dict[str, int] = {}
    for name, session in intruders.items():
        count = [0]

        def seen(_sample: Any, count: list[int] = count) -> None:
            count[0] += 1

        sub = session.declare_subscriber(keys(network.namespace).proxy, seen)
        epochs[name] = time.time_ns()  # newer than the sim's: it would take over if accepted
        publish_updates(session, key, epochs[name])
        sub.undeclare()
        proxies_seen[name] = count[0]
        session.close()

    # control: the same updates with the sim's own credentials reach the haptic server
    control = peer(endpoint, "sim", sim_password, tmp_path)
    epochs["control (sim credentials)"] = control_epoch = time.time_ns()
    publish_updates(control, key, control_epoch)
    control.close()

    assert haptic.stop() == 0
    assert sim.stop() == 0
    haptic_summary = json.loads((tmp_path / "haptic.json").read_text())
    sim_summary = json.loads((tmp_path / "sim.json").read_text())

    # what was installed, from the tick records (every tick holds the installed epoch)
    ticks = read_ticks(log)
    installed_epochs = set(ticks["update_epoch"][ticks["update_seq"] >= 0].tolist())
    assert installed_epochs == {sim_epoch}
    # what was received: the loop took no more updates than the sim and the control sent
    # (fewer: the sim's first ones go out before it has connected); the intruders' would add
    # len(intruders) * UPDATES_PER_PEER
    assert haptic_summary["updates_received"] <= sim_summary["steps"] + UPDATES_PER_PEER
    # and no received update the log could decode came from an intruder
    records = read_json_topic(log, UPDATE_TOPIC)
    by_epoch: dict[int, list[dict[str, Any]]] = {}
    for r in records:
        by_epoch.setdefault(int(r.get("epoch", UNDECODED)), []).append(r)
    for name in intruders:
        assert epochs[name] not in by_epoch, f"{name}: its updates reached the haptic server"
    assert set(by_epoch) - {UNDECODED} <= {sim_epoch, control_epoch}, "an unknown epoch"
    assert not any(r["installed"] for r in by_epoch.get(UNDECODED, []))
    # the observer was let in (it follows the proxy) and only its puts were denied
    assert proxies_seen["observer (may not publish)"] > 0
    assert proxies_seen["no credentials"] == proxies_seen["wrong password"] == 0
    assert proxies_seen["unknown user"] == 0
    control_verdicts = [r["reason"] for r in by_epoch.get(control_epoch, [])]
    assert len(control_verdicts) >= UPDATES_PER_PEER * MIN_CONTROL_FRACTION
    # another epoch while the sim's updates flow: refused by the epoch rule; the age check
    # comes first (stages/install.py admit_live), so one the loaded machine took more than
    # the scene's max_update_age_ms after it was sent is refused as late (a clean-clone CI
    # beside other work: {'epoch', 'late'}); none installs, most meet the epoch rule
    assert set(control_verdicts) <= {"epoch", "late"}, control_verdicts
    assert control_verdicts.count("epoch") > len(control_verdicts) / 2, control_verdicts
    installed_sim = [r for r in by_epoch.get(sim_epoch, []) if r["installed"]]
    run_s = SIM_FLOW_S + len(intruders) * UPDATES_PER_PEER / PUBLISH_HZ
    assert len(installed_sim) >= MIN_SIM_FRACTION * run_s * load_scene(SCENE).sim_rate_hz


@pytest.mark.processes
def test_a_second_authenticated_sim_cannot_take_over_a_stalled_one(tmp_path: Path) -> None:
    """The sim's epoch is bound to its session's liveliness (haptic_server/sidecar.py
    SimLiveliness): the sim is stopped (SIGSTOP) past the watchdog, and a second process with
    the sim's own credentials, declaring itself alive too, publishes plausible updates of a
    new epoch. While the first sim's session lives none of them installs (`unbound`); up to
    0.9 the first one after the watchdog began its epoch. The first sim, resumed, renders
    again."""
    import os
    import signal

    from haptic_local_model.benchmarks.stranger import server_pair
    from haptic_local_model.haptic_server.log import UPDATE_TOPIC, read_json_topic
    from haptic_local_model.shared.config import load_scene
    from haptic_local_model.shared.net.transport import keys, open_session
    from haptic_local_model.shared.protocol.update import encode_update
    from haptic_local_model.sim_server.world import SimWorld

    scene = "free_box"
    with server_pair(
        tmp_path, "second-sim", scene, "loopback", ["--user", "constant_push"]
    ) as pair:
        time.sleep(1.0)
        k = keys(pair.net.namespace)
        second = open_session(pair.net.sim)  # the sim's own credentials
        try:
            forged_epoch = time.time_ns()
            token = second.liveliness().declare_token(f"{k.alive}/{forged_epoch}")
            pub = second.declare_publisher(k.update)
            world = SimWorld(load_scene(scene))
            os.kill(pair.sim_pid, signal.SIGSTOP)
            try:
                time.sleep(0.5)  # past the watchdog
                for seq in range(60):
                    pub.put(encode_update(world.local_model(forged_epoch, seq, time.time_ns())))
                    time.sleep(1 / 60)
            finally:
                os.kill(pair.sim_pid, signal.SIGCONT)
            token.undeclare()
        finally:
            second.close()
        time.sleep(1.0)
    records = read_json_topic(pair.log, UPDATE_TOPIC)
    forged = [r for r in records if r.get("epoch") == forged_epoch]
    assert len(forged) >= 50, len(forged)
    assert not any(r["installed"] for r in forged)
    assert {r["reason"] for r in forged} == {"unbound"}
    after = [r for r in records if r.get("epoch") == pair.epoch and r["installed"]]
    assert after and after[-1]["tick"] > max(r["tick"] for r in forged)

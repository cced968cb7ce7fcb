"""Forged epochs and times, with the sim's own credentials, against the real processes.

Authentication keeps strangers out (`test_access.py`); this is the next layer, for a peer
that holds valid credentials (a compromised or buggy sim host). The haptic server and the sim
run on the shipped `secure_loopback` config; a peer presenting the sim's credentials follows
the proxy states and publishes on the update key:

- an epoch of 2^63 - 1 (before 0.3 it was installed, commanded the device to its limit and
  locked the real sim out until a restart: now it is just another epoch), a plausible new
  epoch while the sim's updates flow, and updates in the sim's own epoch with publish times
  of 0, +1000 s and -2^63: none installs, and the sim's updates keep installing;
- the sim stopped (SIGSTOP): updates of its epoch delayed 0.5, 1 and 3 s, as a stalled link
  flushes them, never end the outage (the device stays safe);
- after the outage, while the stopped sim's session lives (its liveliness token), a fresh
  epoch of the peer's is refused (`unbound`, since 0.10: up to 0.9 anyone holding the
  credentials could drive a device whose sim had stalled past the watchdog) and the device
  stays safe; the real sim, resumed, is rendered again.
"""

from __future__ import annotations

import os
import signal
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_access import CREDENTIALS, secure_network
from test_faults import ProxyWatch

from haptic_local_model.haptic_server.log import UPDATE_TOPIC, read_json_topic, read_ticks
from haptic_local_model.shared.config import load_scene
from haptic_local_model.shared.net.config import EndpointSpec, load_network
from haptic_local_model.shared.protocol.update import encode_update
from haptic_local_model.sim_server.world import SimWorld

SCENE = "free_box"
MAX_WRENCH_N = 50.0  # configs/devices/ideal.toml
COPIES = 5  # of each forged message, 20 ms apart
INT64_MAX, INT64_MIN = 2**63 - 1, -(2**63)
STALL_AGES_S = (0.5, 1.0, 3.0)
QUIET_S = 0.5  # the safe state holds this long after the delayed updates arrive
TAKEOVER_COPIES = 25  # 0.5 s of a forged epoch: past the 40 ms ramp out of the safe state


def forged(world: SimWorld, epoch: int, seq: int, published_ns: int) -> bytes:
    """The forger's world as the sim would publish update `seq`: a stream whose sim time
    advances a period per update (one that stood still would be refused as a jump)."""
    world.time = seq * world.period
    return encode_update(world.local_model(epoch, seq, published_ns))


@pytest.mark.processes
def test_forged_epochs_and_times_with_the_sims_credentials(
    tmp_path: Path, start_server: Any
) -> None:
    net_path = secure_network(tmp_path)
    network = load_network(str(net_path))
    log = tmp_path / "run.mcap"
    haptic = start_server(
        "haptic_local_model.haptic_server.cli", "--scene", SCENE, "--device", "ideal", "--user",
        "constant_push",
        "--network", str(net_path), "--log", str(log),
    )  # fmt: skip
    haptic.wait_ready()
    sim = start_server(
        "haptic_local_model.sim_server.cli", "--scene", SCENE, "--network", str(net_path)
    )
    sim.wait_ready()
    sim_epoch = int(next(e for e in sim.events if e.get("event") == "ready")["epoch"])
    password = tmp_path / "sim.password"
    password.write_text((CREDENTIALS / "example_sim.password").read_text())
    spec = EndpointSpec(connect=network.sim.connect, user="sim", password_file=str(password))
    watch = ProxyWatch(net_path, spec)
    world = SimWorld(load_scene(SCENE))
    try:
        last = watch.rendering(sim_epoch)

        def put(make: Any, copies: int = COPIES) -> None:
            """Publish make(i) for i < copies, 20 ms apart (i: the forged seq's offset)."""
            for i in range(copies):
                watch.publisher.put(make(i))
                time.sleep(0.02)

        # while the sim's updates flow: nothing forged installs
        far = 10**12  # a sequence number far ahead of the sim's: it would lock it out
        now = time.time_ns
        put(lambda i: forged(world, INT64_MAX, i, now()))  # epoch 2^63 - 1
        put(lambda i: forged(world, now(), i, now()))  # a plausible epoch, while the sim's flow
        put(lambda i: forged(world, sim_epoch, far + i, 0))  # published at 0
        put(lambda i: forged(world, sim_epoch, far + i, now() + 10**12))  # at +1000 s
        put(lambda i: forged(world, sim_epoch, far + i, INT64_MIN))  # at -2^63
        last = watch.rendering(sim_epoch, after_seq=last.update_seq + 3)

        # the sim stalls: delayed updates of its epoch never end the outage
        os.kill(sim.proc.pid, signal.SIGSTOP)
        watch.safe()
        for age in STALL_AGES_S:
            late_ns = round(age * 1e9)
            put(lambda i, late_ns=late_ns: forged(world, sim_epoch, far + i, now() - late_ns))
        mark = watch.mark()
        time.sleep(QUIET_S)
        assert watch.proxies[mark:], "no proxy states while safe"
        assert all(p.safe_state for p in watch.proxies[mark:]), "a late update ended the outage"

        # after the outage a fresh epoch of another session does not install while the
        # stalled sim's session lives; resumed, the real sim is rendered again
        takeover = now()
        mark = watch.mark()
        put(lambda i: forged(world, takeover, i, now()), TAKEOVER_COPIES)
        time.sleep(QUIET_S)
        assert all(p.safe_state for p in watch.proxies[mark:]), "a takeover ended the outage"
        os.kill(sim.proc.pid, signal.SIGCONT)
        watch.rendering(sim_epoch, after_seq=last.update_seq)
    finally:
        os.kill(sim.proc.pid, signal.SIGCONT)
        watch.close()
    assert haptic.stop() == 0
    assert sim.stop() == 0

    ticks = read_ticks(log)
    rendered = ticks[ticks["update_seq"] >= 0]
    assert set(np.unique(rendered["update_epoch"]).tolist()) == {sim_epoch}
    assert np.isfinite(ticks["wrench_command"]).all()
    assert np.abs(ticks["wrench_command"][:, :2]).max() <= MAX_WRENCH_N
    records = read_json_topic(log, UPDATE_TOPIC)
    # the forged ones: not the sim's own (which a loaded host may delay past the age bound)
    # nor the takeover's, and decoded (a slot the I/O process logged late may be reused)
    forged_records = [
        r
        for r in records
        if "epoch" in r and r["epoch"] != takeover and (r["epoch"] != sim_epoch or r["seq"] >= far)
    ]
    verdicts = Counter((r["reason"], r["seq"] >= far) for r in forged_records)
    # the forged ones, by verdict (some copies may be dropped by Zenoh under load: at least one)
    assert verdicts[("epoch", False)] >= 2  # 2^63 - 1, and a plausible epoch while it flowed
    assert verdicts[("late", True)] >= 2 + len(STALL_AGES_S)  # at 0, at -2^63, the stall's
    assert verdicts[("future", True)] >= 1
    assert set(verdicts) <= {
        ("epoch", False),
        ("late", True),
        ("future", True),
    }, verdicts
    assert not any(r["installed"] for r in records if r.get("seq", 0) >= far)
    assert not any(r["installed"] for r in records if r.get("epoch") == INT64_MAX)
    # the real sim's updates installed before and after every forgery
    sim_installed = [r["tick"] for r in records if r.get("epoch") == sim_epoch and r["installed"]]
    takeovers = [r for r in records if r.get("epoch") == takeover]
    assert takeovers and {r["reason"] for r in takeovers} == {"unbound"}
    assert sim_installed[-1] > max(r["tick"] for r in takeovers)

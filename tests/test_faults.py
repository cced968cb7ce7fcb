"""Faults with the real processes over loopback (issue 8): a sim that stalls, dies and comes
back, garbage on the update key, a haptic server that dies, and signals.

The test follows the haptic server the way the sim does: its own Zenoh peer on the haptic
server's endpoint receives the proxy states (epoch, installed sequence, safe flag), so every
wait is on an event the servers publish, never on a guessed sleep. Sleeps below are the
lengths of the faults themselves. Figures are read back from the MCAP log afterwards.
"""

from __future__ import annotations

import base64
import json
import math
import os
import signal
import struct
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from haptic_local_model.haptic_server.log import (
    EVENT_TOPIC,
    UPDATE_TOPIC,
    is_indexed,
    read_json_topic,
    read_ticks,
)
from haptic_local_model.haptic_server.loop import DT_CLAMP
from haptic_local_model.haptic_server.mailbox import SLOT_BYTES
from haptic_local_model.haptic_server.model import params_record
from haptic_local_model.shared.config import load_scene
from haptic_local_model.shared.net.config import EndpointSpec, load_network
from haptic_local_model.shared.net.transport import keys, open_session
from haptic_local_model.shared.protocol.codes import Reason
from haptic_local_model.shared.protocol.layout import DEFAULT_LIMITS
from haptic_local_model.shared.protocol.proxy import ProxyState, decode_proxy
from haptic_local_model.shared.protocol.update import MessageError, UpdateParser, encode_update
from haptic_local_model.sim_server.world import SimWorld

SCENE, DEVICE, USER = "free_box", "ideal", "constant_push"
MAX_WRENCH_N = 50.0  # configs/devices/ideal.toml
EVENT_TIMEOUT_S = 30.0  # a reconnecting Zenoh peer takes ~2.5 s; a busy 2-core VM more
SAFE_WITHIN_S = 0.050  # issue 8: the safe state within 50 ms of the watchdog
OUTAGE_S = 0.3  # how long the sim stays stopped (> watchdog 100 ms + ramp 40 ms)
# the clean window compared with the garbage one is as long as it and ends 0.1 s before it:
# CLEAN_S leaves room for the garbage taking longer than GARBAGE_S to send on a busy machine
CLEAN_S, GARBAGE_S, GARBAGE_HZ = 2.6, 2.0, 200.0
MIN_TICK_RATE_HZ = 950.0  # the loop keeps its rate through every fault (1 kHz nominal)
# Late ticks (> 1 ms) with garbage against the clean window just before it, same processes:
# an idle VM stalls about once per 10 s (STACK-NOTES) and a shared 2-core one more often, so
# the windows differ by noise; a loop slowed by the garbage would be late around many of the
# ~400 ticks that take a message. Allowed: twice the clean count plus 0.5% of the ticks.
LATE_FACTOR, LATE_ALLOWANCE = 2.0, 0.005
# The fade spreads a resumed force over safe_ramp / dt ticks, dt <= 2 ms measured: the blend
# alone moves a command within +-MAX_WRENCH by at most 2 MAX_WRENCH dt_max / ramp per tick
# (5 N); the bound doubles it for the rendering's own change while it fades in (see
# test_watchdog.py for scenes that come close). Without the fade: the whole force at once.
RAMP_S = load_network("loopback").safe_ramp_ms / 1000.0
FADE_STEP_BOUND_N = 2.0 * (2.0 * MAX_WRENCH_N * DT_CLAMP[1] * 1e-3 / RAMP_S)
SAFE_FORCE_TOL_N = 1e-12  # in the safe state the command is exactly -safe_damping * twist
# children of a killed process must be gone by then: they stop cleanly (the log is closed),
# 1.5-4 s here, 9 s once with the two cores loaded by other work
ORPHAN_TIMEOUT_S = 20.0
MIN_SIM_STEP_FRACTION = 0.75
ENCLOSURE_HALF_M = 0.15  # configs/scenes/free_box.toml: walls at +-0.15 m


# --- following the haptic server like the sim does -------------------------------------------


class ProxyWatch:
    """A Zenoh peer on the haptic server's endpoint: receives its proxy states and can
    publish on the update key (garbage)."""

    def __init__(self, network_file: Path, spec: EndpointSpec | None = None) -> None:
        """On the network's sim endpoint with the sim's credentials (a faulty sim's
        messages), or as `spec` says."""
        net = load_network(str(network_file))
        self.keys = keys(net.namespace)
        sim = EndpointSpec(
            listen=(), connect=net.sim.connect, user=net.sim.user,
            password_file=net.sim.password_file,
        )  # fmt: skip
        self.session = open_session(spec or sim)
        self.publisher = self.session.declare_publisher(
            self.keys.update, congestion_control=zenoh.CongestionControl.BLOCK
        )
        self.proxies: list[ProxyState] = []
        self._cond = threading.Condition()
        self._sub = self.session.declare_subscriber(self.keys.proxy, self._receive)

    def _receive(self, sample: Any) -> None:
        try:
            proxy = decode_proxy(sample.payload.to_bytes())
        except MessageError:
            return
        with self._cond:
            self.proxies.append(proxy)
            self._cond.notify_all()

    def mark(self) -> int:
        with self._cond:
            return len(self.proxies)

    def wait(
        self, what: str, predicate: Callable[[ProxyState], bool], since: int | None = None
    ) -> ProxyState:
        """The first proxy state published after `since` (default: now) that satisfies it."""
        start = self.mark() if since is None else since
        end = time.monotonic() + EVENT_TIMEOUT_S
        with self._cond:
            while True:
                for p in self.proxies[start:]:
                    if predicate(p):
                        return p
                start = len(self.proxies)
                left = end - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"no proxy state: {what}")
                self._cond.wait(left)

    def rendering(self, epoch: int, since: int | None = None, after_seq: int = -1) -> ProxyState:
        """Wait until the haptic server renders the model of `epoch` (not in the safe state)."""
        return self.wait(
            f"rendering epoch {epoch} after seq {after_seq}",
            lambda p: (
                p.valid and p.epoch == epoch and not p.safe_state and p.update_seq > after_seq
            ),
            since,
        )

    def safe(self) -> ProxyState:
        return self.wait("the safe state", lambda p: p.safe_state)

    def close(self) -> None:
        self._sub.undeclare()
        self.session.close()


@pytest.fixture
def watch_factory() -> Any:
    made: list[ProxyWatch] = []

    def make(network_file: Path) -> ProxyWatch:
        w = ProxyWatch(network_file)
        made.append(w)
        return w

    yield make
    for w in made:
        w.close()


# --- garbage ------------------------------------------------------------------------------


def garbage(epoch: int, count: int) -> tuple[list[tuple[bytes, bool]], Counter[str]]:
    """Messages the haptic server must reject, and the reasons it must give, cycling through
    random bytes, an oversize and an empty payload, broken fields of a real update of the
    scene, a replay (sequence), an older epoch and one published long ago (late). Each comes
    with whether to stamp it as it is sent (`stamped`): the replay and the older epoch."""
    rng = np.random.default_rng(81)
    parser = UpdateParser(DEFAULT_LIMITS)
    valid = bytearray(encode_update(SimWorld(load_scene(SCENE)).local_model(epoch, 0, 0)))
    d, n = struct.unpack_from("<HH", valid, 40)
    floats = 64 + 8 * (d + 2 * n)  # lengths, base, base angle, op point, q, ...
    q_at, mass_at = floats + 8 * (d + 5), floats + 8 * (3 * d + 5)

    def edit(fmt: str, offset: int, *values: Any) -> bytes:
        out = bytearray(valid)
        struct.pack_into(fmt, out, offset, *values)
        return bytes(out)

    makers: dict[str, Callable[[], tuple[bytes, str]]] = {
        "random": lambda: (rng.bytes(int(rng.integers(1, 3000))), ""),
        "oversize": lambda: (rng.bytes(SLOT_BYTES + 1), "size"),
        "empty": lambda: (b"", "short"),
        "nan": lambda: (edit("<d", q_at, math.nan), ""),
        "magic": lambda: (edit("<4s", 0, b"HLMX"), ""),
        "version": lambda: (edit("<H", 4, 99), ""),
        "truncated": lambda: (bytes(valid[: int(rng.integers(0, len(valid)))]), ""),
        "padded": lambda: (bytes(valid) + rng.bytes(int(rng.integers(1, 64))), ""),
        "not_spd": lambda: (edit("<d", mass_at, -1.0), ""),
        "huge": lambda: (edit("<d", q_at, 1e12), ""),
        "count": lambda: (edit("<H", 42, n + 1), ""),
        "replay": lambda: (bytes(valid), "sequence"),
        "old_epoch": lambda: (edit("<Q", 8, epoch - 1), "epoch"),
        "late": lambda: (bytes(valid), "late"),  # published at 0
    }
    messages: list[tuple[bytes, bool]] = []
    reasons: Counter[str] = Counter()
    kinds = list(makers)
    for i in range(count):
        raw, reason = makers[kinds[i % len(kinds)]]()
        if not reason:
            code = parser.parse(raw)
            assert code != 0, kinds[i % len(kinds)]
            reason = Reason(code).tag
        messages.append((raw, kinds[i % len(kinds)] in ("replay", "old_epoch")))
        reasons[reason] += 1
    return messages, reasons


def taken_late(rejected: list[dict[str, Any]], epoch: int, max_age_s: float) -> Counter[str]:
    """The stamped garbage (the replay, the older epoch) that the loop took more than the
    update age limit after its stamp, by the reason it was sent for: the time check comes
    before the order check, so it was refused as late (a loaded machine can hold a message
    that long between the put and the loop). What it must be refused for follows from the
    latency it was taken at, which the log keeps, and that latency must be beyond the
    limit. The garbage published long ago ("late") is late by its own stamp, 0."""
    moved: Counter[str] = Counter()
    for u in rejected:
        if (
            u["reason"] != "late"
            or struct.unpack_from("<q", base64.b64decode(u["raw_b64"]), 32)[0] == 0
        ):
            continue
        assert u["latency_s"] > max_age_s, u
        moved["epoch" if u.get("epoch") == epoch - 1 else "sequence"] += 1
    return moved


def stamped(raw: bytes) -> bytes:
    """A message published now (the order check's garbage: late otherwise)."""
    out = bytearray(raw)
    struct.pack_into("<q", out, 32, time.time_ns())
    return bytes(out)


# --- reading the log ----------------------------------------------------------------------


@dataclass
class Log:
    ticks: np.ndarray
    events: list[dict[str, Any]]
    updates: list[dict[str, Any]]

    @staticmethod
    def read(path: Path) -> Log:
        return Log(
            read_ticks(path),
            read_json_topic(path, EVENT_TOPIC),
            read_json_topic(path, UPDATE_TOPIC),
        )

    def event_ticks(self, kind: str, contains: str = "") -> list[int]:
        return [e["tick"] for e in self.events if e["kind"] == kind and contains in e["detail"]]

    def row(self, tick: int) -> np.ndarray:
        i = int(np.searchsorted(self.ticks["tick"], tick))
        assert self.ticks["tick"][i] == tick
        return self.ticks[i:]


def outage(log: Log, trip: int, clear: int) -> np.ndarray:
    """The ticks from the watchdog's trip until the updates returned."""
    return log.ticks[(log.ticks["tick"] >= trip) & (log.ticks["tick"] < clear)]


def safe_decay_s(log: Log, trip: int, clear: int) -> float | None:
    """Loop time from the watchdog's tick to the first tick in the full safe state; None if
    the updates returned first (a short stall), which the ramp must then not have missed."""
    ticks = outage(log, trip, clear)
    reached = np.flatnonzero(ticks["safe"] >= 1.0)
    if len(reached) == 0:
        assert log.row(clear)[0]["t"] - ticks["t"][0] < SAFE_WITHIN_S, "never safe"
        assert np.all(np.diff(ticks["safe"]) > 0), "the ramp to the safe state stalled"
        return None
    return float(ticks["t"][reached[0]] - ticks["t"][0])


def assert_damping_only(log: Log, trip: int, clear: int, safe_damping: np.ndarray) -> None:
    """From the full safe state until the updates return, the device gets damping alone."""
    held = outage(log, trip, clear)
    held = held[held["safe"] >= 1.0]
    expected = np.clip(-safe_damping * held["device_twist"], -MAX_WRENCH_N, MAX_WRENCH_N)
    assert np.abs(held["wrench_command"] - expected).max(initial=0.0) <= SAFE_FORCE_TOL_N


def resumption_step(log: Log, tick: int) -> float:
    """Largest tick-to-tick change of the commanded wrench while forces fade back in."""
    after = log.row(tick - 1)
    end = 1 + int(np.argmax(after["safe"][1:] <= 0.0))
    assert after["safe"][end] == 0.0, "forces never faded back in"
    return float(np.abs(np.diff(after["wrench_command"][: end + 2], axis=0)).max())


def late_ticks(ticks: np.ndarray) -> int:
    return int(np.count_nonzero(ticks["lateness_us"] > 1000.0))


def server_args(network_file: Path, *extra: str) -> list[str]:
    return ["--scene", SCENE, "--network", str(network_file), *extra]


def haptic_args(network_file: Path, log: Path, summary: Path) -> list[str]:
    return server_args(
        network_file, "--device", DEVICE, "--user", USER, "--log", str(log),
        "--summary-json", str(summary),
    )  # fmt: skip


def stopped(process: Any) -> dict[str, Any]:
    events = [e for e in process.events if e.get("event") == "stopped"]
    assert len(events) == 1
    return events[0]


FIGURES: dict[str, Any] = {}  # measured figures, printed at the end of each test (pytest -s)


def report(name: str, **figures: Any) -> None:
    FIGURES[name] = figures
    print(f"\n[{name}] " + json.dumps(figures))


# --- the sim's faults ---------------------------------------------------------------------


@pytest.mark.processes
def test_sim_garbage_stall_kill_and_restart(
    tmp_path: Path, network_file: Path, start_server: Any, watch_factory: Any
) -> None:
    """One haptic server through: a clean window, garbage between the sim's updates, the sim
    stopped (SIGSTOP, same epoch on SIGCONT), the sim killed and a new one started, SIGTERM."""
    log_path, summary_path = tmp_path / "haptic.mcap", tmp_path / "haptic.json"
    haptic = start_server(
        "haptic_local_model.haptic_server.cli", *haptic_args(network_file, log_path, summary_path)
    )
    haptic.wait_ready()
    sim1 = start_server("haptic_local_model.sim_server.cli", *server_args(network_file))
    sim1.wait_ready()
    epoch1 = sim1.events[0]["epoch"]
    watch = watch_factory(network_file)
    watch.rendering(epoch1)

    # a clean window, then garbage between the sim's updates
    time.sleep(CLEAN_S)
    messages, expected_reasons = garbage(epoch1, round(GARBAGE_S * GARBAGE_HZ))
    next_put = time.monotonic()
    for raw, stamp in messages:
        watch.publisher.put(stamped(raw) if stamp else raw)
        next_put += 1.0 / GARBAGE_HZ
        time.sleep(max(0.0, next_put - time.monotonic()))
    last = watch.rendering(epoch1)
    watch.rendering(epoch1, after_seq=last.update_seq + 3)  # valid updates still install

    # the sim stalls (SIGSTOP): safe state; it goes on (SIGCONT, same epoch): re-initialised
    stall_seq = watch.rendering(epoch1).update_seq
    os.kill(sim1.proc.pid, signal.SIGSTOP)
    watch.safe()
    time.sleep(OUTAGE_S)
    os.kill(sim1.proc.pid, signal.SIGCONT)
    watch.rendering(epoch1, after_seq=stall_seq)

    # the sim dies (SIGKILL): safe state; a new sim (new epoch): re-initialised
    os.kill(sim1.proc.pid, signal.SIGKILL)
    assert sim1.proc.wait(10.0) == -signal.SIGKILL
    watch.safe()
    sim2 = start_server("haptic_local_model.sim_server.cli", *server_args(network_file))
    sim2.wait_ready()
    epoch2 = sim2.events[0]["epoch"]
    assert epoch2 > epoch1
    watch.rendering(epoch2, after_seq=10)

    # SIGTERM (haptic) and SIGINT (sim): both stop cleanly
    assert haptic.stop(signal.SIGTERM) == 0
    assert sim2.stop(signal.SIGINT) == 0
    summary = json.loads(summary_path.read_text())
    assert stopped(haptic)["ticks"] == summary["ticks"]
    assert stopped(sim2)["epoch"] == epoch2

    log = Log.read(log_path)
    assert is_indexed(log_path), "the log was not finalised"
    assert len(log.ticks) == summary["ticks"]
    assert np.all(np.diff(log.ticks["tick"]) == 1), "ticks missing from the log"
    assert summary["tick_rate_hz"] >= MIN_TICK_RATE_HZ
    assert log.ticks["safe"][-1] == 1.0, "not in the safe state when it stopped"
    assert [e["kind"] for e in log.events[-2:]] == ["stop", "stopped"]

    # garbage: every message rejected, counted by reason, the sim's own all installed
    assert summary["updates_lost"] == 0
    assert summary["updates_rejected"] == len(messages)
    rejected = [u for u in log.updates if not u["installed"]]
    max_age_s = load_network(network_file).max_update_age_ms / 1e3
    moved = taken_late(rejected, epoch1, max_age_s)
    expected_reasons = expected_reasons - moved + Counter(late=moved.total())
    assert summary["rejected_by_reason"] == dict(expected_reasons)
    assert Counter(u["reason"] for u in rejected) == expected_reasons
    installed = [u for u in log.updates if u["installed"]]
    assert summary["updates_installed"] == len(installed)
    assert {u["epoch"] for u in installed} == {epoch1, epoch2}
    g0, g1 = rejected[0]["tick"], rejected[-1]["tick"]
    between = [u for u in installed if g0 < u["tick"] < g1]
    assert len(between) >= 0.5 * 60 * GARBAGE_S, "the sim's updates did not get through"
    window = g1 - g0
    garbage_ticks = log.ticks[(log.ticks["tick"] >= g0) & (log.ticks["tick"] < g1)]
    clean_ticks = log.ticks[
        (log.ticks["tick"] >= g0 - window - 100) & (log.ticks["tick"] < g0 - 100)
    ]
    first_install = installed[0]["tick"]
    assert clean_ticks["tick"][0] > first_install, "the clean window started before rendering"
    late_clean, late_garbage = late_ticks(clean_ticks), late_ticks(garbage_ticks)
    assert late_garbage <= LATE_FACTOR * late_clean + LATE_ALLOWANCE * window

    # the watchdog: at least the stall and the kill (a loaded machine can stall the sim past
    # 100 ms by itself: that trips it too, and must behave the same), each within 50 ms to
    # the safe state, damping only until the updates return, and ended by re-initialising
    safe_damping = params_record(load_scene(SCENE).rendering, np.full(3, MAX_WRENCH_N))[0][
        "safe_damping"
    ]
    trips, clears = log.event_ticks("watchdog"), log.event_ticks("watchdog_clear")
    reinits = log.event_ticks("reinitialise")[1:]  # the first is the first install
    assert len(trips) >= 2, log.events
    assert len(trips) == len(clears) == summary["watchdog_trips"], log.events
    assert reinits == clears and summary["reinitialisations"] == len(trips), log.events
    decays = [safe_decay_s(log, trip, clear) for trip, clear in zip(trips, clears, strict=True)]
    measured = [v for v in decays if v is not None]
    assert len(measured) >= 2 and max(measured) <= SAFE_WITHIN_S  # the stall and the kill
    for trip, clear in zip(trips, clears, strict=True):
        assert_damping_only(log, trip, clear, safe_damping)
    # the same epoch after the stall, the new one after the restart
    assert log.event_ticks("reinitialise", f"same epoch {epoch1}"), log.events
    assert len(log.event_ticks("reinitialise", f"new epoch {epoch2}")) == 1, log.events
    for tick in reinits:
        update = next(u for u in installed if u["tick"] == tick)
        row = log.row(tick)[0]
        d = update["dof"]
        # the proxy starts from the sim's q (one tick of integration later)
        moved = np.abs(row["proxy_qd"][:d]).max() * DT_CLAMP[1] * 1e-3 + 1e-12
        assert np.abs(row["proxy_q"][:d] - update["q"]).max() <= moved
        # the device mapped onto the VM, the proxy moving with the hand: coupling at rest
        np.testing.assert_allclose(row["device_pose"], row["vm_pose"], atol=1e-6)
        np.testing.assert_allclose(row["device_twist"], row["vm_twist"], atol=1e-6)
    steps = [resumption_step(log, tick) for tick in reinits]
    assert max(steps) <= FADE_STEP_BOUND_N
    report(
        "sim faults",
        safe_decay_ms=[None if v is None else round(1e3 * v, 1) for v in decays],
        outage_ms=[
            round(1e3 * float(log.row(c)[0]["t"] - log.row(t)[0]["t"]), 1)
            for t, c in zip(trips, clears, strict=True)
        ],
        watchdog_trips=len(trips),
        resumption_step_n=[round(v, 4) for v in steps],
        garbage_sent=len(messages),
        rejected_by_reason=summary["rejected_by_reason"],
        late_ticks={"clean": late_clean, "garbage": late_garbage, "window_ticks": window},
        lateness_p99_us={
            "clean": float(np.percentile(clean_ticks["lateness_us"], 99)),
            "garbage": float(np.percentile(garbage_ticks["lateness_us"], 99)),
        },
        work_p99_us={
            "clean": float(np.percentile(clean_ticks["work_us"], 99)),
            "garbage": float(np.percentile(garbage_ticks["work_us"], 99)),
        },
        tick_rate_hz=summary["tick_rate_hz"],
    )


# --- the haptic server's faults ------------------------------------------------------------


def process_table() -> dict[int, tuple[int, str, str]]:
    """pid -> (parent pid, state, start time) of every process (Linux /proc)."""
    table = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            text = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        fields = text.rsplit(")", 1)[1].split()
        table[int(entry)] = (int(fields[1]), fields[0], fields[19])
    return table


def descendants(pid: int) -> dict[int, str]:
    """Every live descendant of pid: pid -> start time (so a reused pid is not mistaken)."""
    table = process_table()
    found: dict[int, str] = {}
    frontier = [pid]
    while frontier:
        parent = frontier.pop()
        for child, (ppid, state, start) in table.items():
            if ppid == parent and child not in found and state != "Z":
                found[child] = start
                frontier.append(child)
    return found


def wait_gone(processes: dict[int, str], timeout: float = ORPHAN_TIMEOUT_S) -> dict[int, str]:
    """Wait until none of the processes lives (zombies count as gone); returns those left."""
    end = time.monotonic() + timeout
    while True:
        table = process_table()
        left = {
            pid: start
            for pid, start in processes.items()
            if pid in table and table[pid][2] == start and table[pid][1] != "Z"
        }
        if not left or time.monotonic() > end:
            return left
        time.sleep(0.05)


@pytest.mark.processes
def test_haptic_server_killed_sim_carries_on(
    tmp_path: Path, network_file: Path, start_server: Any, watch_factory: Any
) -> None:
    """SIGKILL the haptic server: its I/O process finishes the log and exits, the sim keeps
    stepping; a new haptic server picks the sim up; SIGTERM (sim) and SIGINT (haptic)."""
    log1, log2 = tmp_path / "h1.mcap", tmp_path / "h2.mcap"
    haptic1 = start_server(
        "haptic_local_model.haptic_server.cli",
        *haptic_args(network_file, log1, tmp_path / "1.json"),
    )
    haptic1.wait_ready()
    sim = start_server(
        "haptic_local_model.sim_server.cli",
        *server_args(network_file, "--summary-json", str(tmp_path / "sim.json")),
    )
    sim.wait_ready()
    sim_ready = time.monotonic()
    epoch = sim.events[0]["epoch"]
    watch = watch_factory(network_file)
    watch.rendering(epoch)
    watch.rendering(epoch, after_seq=watch.rendering(epoch).update_seq + 10)

    helpers = descendants(haptic1.proc.pid)  # the I/O process (and a resource tracker)
    assert helpers, "the haptic server has no I/O process"
    os.kill(haptic1.proc.pid, signal.SIGKILL)
    assert haptic1.proc.wait(10.0) == -signal.SIGKILL
    killed = time.monotonic()
    assert not wait_gone(helpers), "the haptic server's helpers outlived it"
    assert sim.proc.poll() is None, "the sim died with the haptic server"

    log = Log.read(log1)
    assert len(log.ticks) > 0 and np.all(np.diff(log.ticks["tick"]) == 1)
    last_seq_1 = max(u["seq"] for u in log.updates if u["installed"])

    haptic2 = start_server(
        "haptic_local_model.haptic_server.cli",
        *haptic_args(network_file, log2, tmp_path / "2.json"),
    )
    haptic2.wait_ready()
    mark = watch.mark()
    watch.rendering(epoch, since=mark)  # the same sim, re-initialised by a new haptic server
    resumed = time.monotonic()
    watch.rendering(epoch, since=watch.mark(), after_seq=watch.rendering(epoch).update_seq + 10)

    assert sim.stop(signal.SIGTERM) == 0
    stop_time = time.monotonic()
    assert haptic2.stop(signal.SIGINT) == 0
    sim_summary = json.loads((tmp_path / "sim.json").read_text())
    sim_rate = load_scene(SCENE).sim_rate_hz
    # the sim stepped throughout, with or without a haptic server (an overrun on a busy
    # machine drops steps rather than catching up: 75% of the rate at least)
    assert sim_summary["steps"] >= MIN_SIM_STEP_FRACTION * sim_rate * (stop_time - sim_ready)
    tool_q = np.array(sim_summary["tool_q"])  # a sensible tool: still inside the enclosure
    assert np.isfinite(tool_q).all() and np.abs(tool_q[:2]).max() < ENCLOSURE_HALF_M
    second = Log.read(log2)
    assert is_indexed(log2)
    assert second.ticks["safe"][-1] == 1.0, "not in the safe state when it stopped"
    first_seq_2 = min(u["seq"] for u in second.updates if u["installed"])
    gap_s = resumed - killed
    assert first_seq_2 - last_seq_1 >= 0.5 * sim_rate * gap_s  # it stepped while alone
    assert second.event_ticks("reinitialise", f"new epoch {epoch}")
    report(
        "haptic killed",
        first_log_indexed=is_indexed(log1),
        first_log_ticks=len(log.ticks),
        no_haptic_s=round(gap_s, 2),
        sim_seq_gap=first_seq_2 - last_seq_1,
        sim_steps=sim_summary["steps"],
        sim_expected_steps=round(sim_rate * (stop_time - sim_ready)),
    )


# --- haptic-run ---------------------------------------------------------------------------


def haptic_run_args(network_file: Path, log: Path) -> list[str]:
    return [
        "--scene", SCENE, "--device", DEVICE, "--user", USER, "--network", str(network_file),
        "--duration", "120", "--log", str(log), "--json-events",
    ]  # fmt: skip


@pytest.mark.processes
def test_haptic_run_killed_leaves_no_orphan(
    tmp_path: Path, network_file: Path, start_server: Any
) -> None:
    """SIGKILL haptic-run itself: PR_SET_PDEATHSIG stops both servers (and the haptic
    server's I/O process); the haptic log is still finalised."""
    log = tmp_path / "run.mcap"
    run = start_server(
        "haptic_local_model.haptic_server.harness.run", *haptic_run_args(network_file, log)
    )
    run.wait_ready()
    ready = next(e for e in run.events if e.get("event") == "ready")
    family = descendants(run.proc.pid)
    assert {ready["haptic_pid"], ready["sim_pid"]} <= set(family)
    assert len(family) >= 3  # the two servers and the haptic server's I/O process
    os.kill(run.proc.pid, signal.SIGKILL)
    assert run.proc.wait(10.0) == -signal.SIGKILL
    killed = time.monotonic()
    left = wait_gone(family)
    assert not left, f"orphans after haptic-run was killed: {left}"
    report(
        "haptic-run killed", children=len(family), gone_after_s=round(time.monotonic() - killed, 2)
    )
    assert is_indexed(log)


@pytest.mark.processes
def test_haptic_run_stops_the_other_child(
    tmp_path: Path, network_file: Path, start_server: Any
) -> None:
    """SIGKILL the sim: haptic-run stops the haptic server (cleanly: its log is complete) and
    exits non-zero; nothing is left. (The haptic server's own helpers after a SIGKILL:
    test_haptic_server_killed_sim_carries_on.)"""
    log = tmp_path / "run.mcap"
    run = start_server(
        "haptic_local_model.haptic_server.harness.run", *haptic_run_args(network_file, log)
    )
    run.wait_ready()
    ready = next(e for e in run.events if e.get("event") == "ready")
    family = descendants(run.proc.pid)
    os.kill(ready["sim_pid"], signal.SIGKILL)
    assert run.proc.wait(EVENT_TIMEOUT_S) == 1
    assert not wait_gone(family), "a process outlived haptic-run"
    assert is_indexed(log)


@pytest.mark.processes
def test_haptic_run_sigint_stops_both_cleanly(
    tmp_path: Path, network_file: Path, start_server: Any
) -> None:
    """SIGINT to haptic-run (Ctrl-C): both servers stop cleanly, haptic-run exits 0."""
    log, summary_path = tmp_path / "run.mcap", tmp_path / "summary.json"
    run = start_server(
        "haptic_local_model.haptic_server.harness.run", *haptic_run_args(network_file, log),
        "--summary-json", str(summary_path),
    )  # fmt: skip
    run.wait_ready()
    family = descendants(run.proc.pid)
    os.kill(run.proc.pid, signal.SIGINT)
    assert run.proc.wait(EVENT_TIMEOUT_S) == 0
    assert not wait_gone(family)
    summary = json.loads(summary_path.read_text())
    assert summary["exit_codes"] == {"haptic": 0, "sim": 0}
    assert summary["stopped_by_signal"] is True
    assert is_indexed(log)
    assert read_ticks(log)["safe"][-1] == 1.0

"""The impairment forwarder (benchmarks/impair.py): its delay, jitter and loss statistics
against their closed forms; forwarding over datagram sockets; a station pair coupling
through it on three network namespaces (benchmarks/station_links.py)."""

from __future__ import annotations

import socket
import struct
import threading
import time
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from haptic_local_model.benchmarks import station_links, station_pause
from haptic_local_model.benchmarks.impair import Direction, Forwarder, Impairment
from haptic_local_model.benchmarks.stations import PORTS, netns_unavailable
from haptic_local_model.shared.config import ConfigError, resolve
from haptic_local_model.shared.net.stations import (
    ROUTE_CHECK_NS,
    StateRoute,
    load_station_network,
    state_publisher,
)

N = 20000
SIGMAS = 4.0  # a sampled figure within this many standard errors of its closed form
# how late a packet may leave past its release time on this shared 2-core machine (the
# forwarder's select wake-up and the test's own receive): a bound, not a measurement
LATE_S = 0.010


def _releases(imp: Impairment, gap_s: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    d = Direction(imp, 0)
    sent = np.arange(N) * gap_s
    out = [d.release_at(t) for t in sent]
    kept = np.array([r is not None for r in out])
    return sent[kept], np.array([r for r in out if r is not None])


def test_delay_is_uniform_about_d_and_loss_is_bernoulli() -> None:
    imp = Impairment(delay_s=0.05, jitter_s=0.01, loss=0.05, reorder=True, seed=3)
    sent, released = _releases(imp)
    delay = released - sent
    # uniform on [D - j, D + j]: mean D, variance j²/3
    assert delay.min() >= imp.delay_s - imp.jitter_s and delay.max() <= imp.delay_s + imp.jitter_s
    sd = imp.jitter_s / np.sqrt(3.0)
    assert abs(delay.mean() - imp.delay_s) <= SIGMAS * sd / np.sqrt(len(delay))
    assert abs(delay.std() - sd) <= SIGMAS * sd / np.sqrt(2 * len(delay))
    # and flat: each fifth of the range holds a fifth of the packets
    counts = np.histogram(delay, 5, (imp.delay_s - imp.jitter_s, imp.delay_s + imp.jitter_s))[0]
    share = counts / len(delay)
    assert np.all(np.abs(share - 0.2) <= SIGMAS * np.sqrt(0.2 * 0.8 / len(delay)))
    lost = 1.0 - len(sent) / N
    assert abs(lost - imp.loss) <= SIGMAS * np.sqrt(imp.loss * (1 - imp.loss) / N)
    # packets 1 ms apart with ±10 ms of jitter: later ones overtake
    assert np.any(np.diff(released) < 0)


def test_without_reorder_packets_leave_in_order_and_never_early() -> None:
    imp = Impairment(delay_s=0.05, jitter_s=0.01, loss=0.0, reorder=False, seed=3)
    sent, released = _releases(imp)
    assert len(sent) == N
    assert np.all(np.diff(released) >= 0.0)
    # a packet held behind an earlier one leaves when that one does: no earlier than D - j
    # after it was sent, no later than the latest release among the packets sent up to it
    d = Direction(imp, 0)
    free = np.array([sent[i] + imp.delay_s + imp.jitter_s * (2 * d.rng.random() - 1)
                     for i in range(N)])  # fmt: skip
    assert np.array_equal(released, np.maximum.accumulate(free))


def test_an_impairment_out_of_range_is_refused_by_name() -> None:
    with pytest.raises(ValueError, match="jitter_s"):
        Impairment(delay_s=0.01, jitter_s=0.02)
    with pytest.raises(ValueError, match="loss"):
        Impairment(loss=1.0)
    with pytest.raises(ValueError, match="delay_s"):
        Impairment(delay_s=-0.001)


def test_a_pause_holds_one_or_both_directions_for_its_window_and_loses_nothing() -> None:
    """Packets 1 ms apart at D = 20 ms; a pause of 130.5 ms taken at 0.1 s: each packet that
    arrives in its window leaves at its end + D, in order; the others at their arrival + D;
    none lost. A pause of one direction leaves the other as it was; out of range, refused."""
    imp = Impairment(delay_s=0.02, pause_s=0.1305, pause_dir="a_to_b")
    fwd = Forwarder(0, 1, imp)  # descriptors never read: the directions' timing only
    sent = np.arange(400) * 1e-3
    a_to_b, b_to_a = [], []
    for t in sent:
        if t == sent[100]:  # the SIGUSR1, at 0.1 s
            fwd.pause(t, imp.pause_s, imp.pause_dir)
        a_to_b.append(fwd.directions[0].release_at(t))
        b_to_a.append(fwd.directions[1].release_at(t))
    end = sent[100] + imp.pause_s
    inside = (sent >= sent[100]) & (sent < end)
    assert inside.sum() == 131
    assert np.array_equal(a_to_b, np.where(inside, end + 0.02, sent + 0.02))
    assert np.array_equal(b_to_a, sent + 0.02)
    assert fwd.directions[0].passed == 400 and fwd.directions[0].dropped == 0
    both = Forwarder(0, 1, Impairment(delay_s=0.02))
    both.pause(0.1, 0.13)
    assert both.directions[1].release_at(0.15) == both.directions[0].release_at(0.15)
    assert both.directions[0].release_at(0.15) == pytest.approx(0.25, abs=1e-12)
    assert imp.argv()[imp.argv().index("--pause-ms") + 1] == "130.5"
    with pytest.raises(ValueError, match="pause_dir"):
        Impairment(pause_dir="up")
    with pytest.raises(ValueError, match="pause_s"):
        Impairment(pause_s=-1.0)


class _Route:
    """A stand-in for a Zenoh session's declarations: whether a publisher has a matching
    subscriber is set by the test; undeclared entities are recorded."""

    def __init__(self) -> None:
        self.matching = False
        self.declared: list[str] = []
        self.undeclared: list[str] = []

    def declare_publisher(self, key: str, **_: Any) -> Any:
        return self._entity("publisher " + key)

    def declare_subscriber(self, key: str, handler: Any) -> Any:
        return self._entity("subscriber " + key)

    def _entity(self, name: str) -> Any:
        self.declared.append(name)
        route = self

        class Entity:
            @property
            def matching_status(self) -> Any:
                return types.SimpleNamespace(matching=route.matching)

            def undeclare(self) -> None:
                route.undeclared.append(name)

        return Entity()


def test_a_state_route_lost_on_a_lossy_link_is_declared_again() -> None:
    """StateRoute (a station's, and each of the world's ports): once a second, a publisher
    no subscriber matches is declared again (a client filters its puts by the subscribers
    its router declared to it, and over UDP a lost declaration is lost for good: in one of
    four runs at 5 % loss a station's DeviceStates never left it), and a subscriber nothing
    arrived on since the last look; a route that works is left alone, and nothing is
    declared again before a second has passed."""
    session = _Route()
    keys = ("ns/port/left/tool", "ns/port/left/device")
    route = StateRoute(session, keys, 64, "best_effort")  # type: ignore[arg-type]
    assert session.declared == ["subscriber ns/port/left/tool", "publisher ns/port/left/device"]
    second = ROUTE_CHECK_NS
    route.check(0, lambda: 0)  # the first look only notes what has arrived
    route.check(second - 1, lambda: 0)  # too soon
    assert route.redeclared == {"publisher": 0, "subscriber": 0} and session.undeclared == []
    route.check(second, lambda: 0)  # nothing either way: both again
    assert route.redeclared == {"publisher": 1, "subscriber": 1}
    assert session.undeclared == ["publisher ns/port/left/device", "subscriber ns/port/left/tool"]
    session.matching = True
    route.check(2 * second, lambda: 5)  # states arrive and the puts have a subscriber
    route.check(3 * second, lambda: 9)
    assert route.redeclared == {"publisher": 1, "subscriber": 1} and len(session.declared) == 4
    session.matching = False  # the subscriber's declaration lost: only the publisher again
    route.check(4 * second, lambda: 12)
    assert route.redeclared == {"publisher": 2, "subscriber": 1}
    assert session.declared[-1] == "publisher ns/port/left/device"


@pytest.mark.processes
def test_the_forwarder_delays_and_drops_datagrams_both_ways() -> None:
    """Datagram sockets stand in for the TUN devices: what is sent at one end arrives at
    the other after D ± j (and at most LATE_S more), in order, with about L of it lost."""
    imp = Impairment(delay_s=0.02, jitter_s=0.004, loss=0.1, seed=5)
    a_out, a_fwd = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    b_out, b_fwd = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    fwd = Forwarder(a_fwd.fileno(), b_fwd.fileno(), imp)
    n = 400
    thread = threading.Thread(target=fwd.run, args=(time.monotonic() + 30.0,), daemon=True)
    thread.start()
    try:
        for src, dst in ((a_out, b_out), (b_out, a_out)):
            for i in range(n):
                src.send(struct.pack("<id", i, time.monotonic()))
            dst.settimeout(imp.delay_s + imp.jitter_s + 0.5)
            got = []
            while len(got) < n:
                try:
                    i, t = struct.unpack("<id", dst.recv(64))
                except TimeoutError:
                    break
                got.append((i, time.monotonic() - t))
            seq = np.array([g[0] for g in got])
            delay = np.array([g[1] for g in got])
            assert np.all(np.diff(seq) > 0)  # in order, none twice
            assert delay.min() >= imp.delay_s - imp.jitter_s
            assert delay.max() <= imp.delay_s + imp.jitter_s + LATE_S
            lost = 1.0 - len(got) / n
            assert abs(lost - imp.loss) <= SIGMAS * np.sqrt(imp.loss * (1 - imp.loss) / n)
    finally:
        fwd.stop = True
        thread.join(5.0)
        for s in (a_out, a_fwd, b_out, b_fwd):
            s.close()
    counts = fwd.counts()
    assert counts["a_to_b"]["passed"] + counts["a_to_b"]["dropped"] == n
    assert counts["b_to_a"]["passed"] + counts["b_to_a"]["dropped"] == n


@pytest.mark.processes
def test_a_station_pair_couples_through_the_impaired_links_at_10_ms(tmp_path: Path) -> None:
    """grasp_vertical at two stations, each link 10 ms ± 2 ms one way through the forwarder:
    both stations render the coupling with no watchdog trip, every packet of each link went
    through the forwarder, the box is held (the couplings' sag only, as on the veth links)
    and no port gives out energy beyond the issue's bound."""
    reason = netns_unavailable()
    if reason:
        pytest.skip(reason)
    f = station_links.run(8.0, Impairment(0.01, 0.002, 0.0), tmp_path, "stations_three_hosts")
    assert f["left_over"] == [] and set(f["exit_codes"].values()) == {0}, f
    for p in PORTS:
        s = f[p]
        assert s["watchdog_trips"] == 0 and s["tool_states_rejected"] == 0, s
        assert s["coupled_fraction"] > 0.99, s
        link = s["link"]
        assert link is not None and min(d["passed"] for d in link.values()) > 1000, s
        assert all(d["dropped"] == 0 for d in link.values()), s
        assert s["energy_out_j"] <= 0.05, s  # issue 46's bound
    assert f["box_sank_mm"] < 3.0, f  # as tests/test_stations.py's three hosts


def test_state_reliability_is_checked_by_name_and_reaches_the_publishers(tmp_path: Path) -> None:
    """The network's state_reliability: a wrong value is refused naming its key; the shipped
    UDP network sends states best effort, the others reliably; state_publisher declares
    them so (a recording stand-in for the session)."""
    shipped = resolve("network", "stations_three_hosts_udp")
    src = shipped.read_text().replace("../credentials", str(shipped.parent.parent / "credentials"))
    bad = tmp_path / "bad.toml"
    bad.write_text(src.replace('state_reliability = "best_effort"', 'state_reliability = "fast"'))
    with pytest.raises(ConfigError) as err:
        load_station_network(str(bad), "router")
    assert err.value.key == "state_reliability", err.value
    assert load_station_network("stations_three_hosts_udp", "left").state_reliability == (
        "best_effort"
    )
    assert load_station_network("stations_three_hosts", "left").state_reliability == "reliable"

    class Session:
        def declare_publisher(self, key: str, **qos: Any) -> dict[str, Any]:
            return {"key": key, **qos}

    pub = state_publisher(Session(), "k", "best_effort")  # type: ignore[arg-type]
    assert pub["reliability"] == zenoh.Reliability.BEST_EFFORT
    assert pub["congestion_control"] == zenoh.CongestionControl.DROP and pub["express"]
    assert state_publisher(Session(), "k", "reliable")["reliability"] == (  # type: ignore[arg-type]
        zenoh.Reliability.RELIABLE
    )


@pytest.mark.processes
def test_best_effort_states_over_udp_hold_the_box_at_5_percent_loss(tmp_path: Path) -> None:
    """stations_three_hosts_udp at 10 ms ± 2 ms one way and 5 % loss: every packet of each
    link is UDP, so none waits behind a TCP retransmission, and some were lost; both
    stations couple through it. (Whether the box is held is the benchmark's: in 1 of 6 runs
    of 8 s here it fell, docs/bench/station_links.md.)"""
    reason = netns_unavailable()
    if reason:
        pytest.skip(reason)
    f = station_links.run(8.0, Impairment(0.01, 0.002, 0.05), tmp_path, "stations_three_hosts_udp")
    assert f["left_over"] == [] and set(f["exit_codes"].values()) == {0}, f
    for p in PORTS:
        s = f[p]
        link = s["link"]
        assert link is not None, s
        for d in link.values():
            assert d["tcp"] == 0 and d["udp"] > 1000 and d["dropped"] > 0, s
        assert s["coupled_fraction"] > 0.0 and s["tool_states_rejected"] == 0, s


@pytest.mark.processes
def test_a_station_whose_link_pauses_mid_press_holds_its_device_where_the_world_has_it(
    tmp_path: Path,
) -> None:
    """grasp_vertical at two stations, the users pressing; the right station's link paused
    both ways for 130 ms in the press's hold (benchmarks/station_pause.py): the station goes
    safe and holds its device where the coupling put it, so it goes under a millimetre into
    the box (the damped-only safe state let it go 5.7-9.5 mm) and the world's offset of the
    port moves under a millimetre (issue 46's done-when 3 bound for the drift; 5.9-9.8 mm
    damped only); its command's largest step at the return is within its own largest step
    before the pause plus the ramp's share (1/40) of the hold's cap (5 N on the maglev)."""
    reason = netns_unavailable()
    if reason:
        pytest.skip(reason)
    f = station_pause.run(tmp_path, 0.0, 130.0, 8.3)
    assert f["left_over"] == [] and set(f["exit_codes"].values()) == {0}, f
    assert f["went_safe"] and f["least_gain"] < 0.5, f  # the watchdog fired: the hold acted
    assert f["into_box_mm"] < 1.0, f
    assert f["registration_mm"]["change"] < 1.0, f
    assert f["rejoin_step_n"] <= f["steady_step_max_n"] + 0.1 * 50.0 / 40.0, f

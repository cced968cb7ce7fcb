"""A shared world and two haptic stations on three hosts (docs/stations.md): the world and
the router in one network namespace, a station in each of two others, each joined to the
world's by a veth pair (10.214.1.0/30, 10.214.2.0/30; `configs/network/stations_three_hosts`).
`grasp_vertical` runs for `--seconds`; after `--cut-after` seconds the left station's link is
cut for `--cut` seconds, then restored. Reports, from the processes' own logs:

- each station's tick rate (per second: median and least) and ticks, lateness, work;
- the box: how far it sank below its start at worst (held: the couplings' sag only);
- the cut station: its watchdog after the cut (counted from when `ip link set down` had
  returned; how long that took beside it), the safe state after its watchdog (the ramp);
  when tool states came back after the restore, and the largest change of its rendered
  spring force from one tick to the next in the 200 ms after (a force jump), beside the
  same in the 2 s before the cut; its command before the cut and after the ramp;
- the other station: whether it rendered the coupling through the whole cut.

With `--check` it exits 1 unless each station delivered at least 98 % of its run's ticks and
its median second at least 990 of them (the rate target: a property of the machine as much as
of the code, so it lives here, not in the tests).

Needs root (network namespaces); everything it creates is removed, and every process it
starts stopped by its pid, however it ends.

    sudo .venv/bin/python -m haptic_local_model.benchmarks.stations [--seconds 24] [--cut 3] [--json out.json] [--check]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import tomllib
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from haptic_local_model.benchmarks.impair import Impairment
from haptic_local_model.haptic_server.log import _iter_messages
from haptic_local_model.haptic_server.stages.station import STATION_ROW_DTYPE
from haptic_local_model.haptic_server.station_records import STATION_TOPIC
from haptic_local_model.shared.config import resolve
from haptic_local_model.shared.net.config import free_loopback_port

CLI = [sys.executable, "-m", "haptic_local_model.haptic_server.stations_cli"]
NETWORK = "stations_three_hosts"
READY_S = 120.0  # a cold numba cache compiles for a while on 2 cores
STOP_S = 30.0
IP_TIMEOUT_S = 10.0
PORTS = ("left", "right")
JUMP_WINDOW = 200  # ticks after the tool states return
STEADY_WINDOW = 2000  # ticks before the cut
DELIVERED_MIN = 0.98  # the rate target (--check): of the run's ticks, each station's ...
MEDIAN_HZ_MIN = 990.0  # ... and its median second


def ip(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        ["ip", *args], capture_output=True, text=True, timeout=IP_TIMEOUT_S, check=check
    )


def netns_unavailable() -> str:
    """Why this machine cannot make network namespaces ('' if it can)."""
    if os.geteuid() != 0:
        return "needs root to create network namespaces"
    if shutil.which("ip") is None:
        return "iproute2 `ip` not installed"
    try:
        ip("netns", "list")
    except (subprocess.CalledProcessError, subprocess.TimeoutExpired) as exc:
        return f"`ip netns` unavailable: {exc}"
    return ""


class Process:
    """A process in a namespace; its JSON event lines read on a thread."""

    def __init__(self, argv: list[str]) -> None:
        self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, text=True)
        self.ready = threading.Event()
        self.ready_at = float("nan")  # when it said it was ready (time.monotonic)
        self.events: list[dict[str, Any]] = []  # every JSON event line, in order
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with contextlib.suppress(json.JSONDecodeError, AttributeError):
                event = json.loads(line)
                self.events.append(event)
                if event.get("event") == "ready":
                    self.ready_at = time.monotonic()
                    self.ready.set()

    def wait_ready(self, timeout_s: float = READY_S) -> None:
        end = time.monotonic() + timeout_s
        while not self.ready.wait(0.1):
            if self.proc.poll() is not None or time.monotonic() > end:
                raise RuntimeError(f"{self.proc.args} not ready (exit {self.proc.poll()})")

    def stop(self, timeout_s: float = STOP_S) -> int:
        if self.proc.poll() is None:
            os.kill(self.proc.pid, signal.SIGTERM)
        try:
            return self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            os.kill(self.proc.pid, signal.SIGKILL)
            return self.proc.wait()


class ThreeHosts:
    """The world's namespace joined to each station's by its own veth pair, or, for a port in
    `impair`, by a TUN device in each namespace with the impairment forwarder between them
    (benchmarks/impair.py): a context manager that stops every process started in them by
    its pid and deletes them, however the block ends."""

    def __init__(self, tag: str = "", impair: dict[str, Impairment] | None = None) -> None:
        tag = tag or f"{os.getpid() % 100000}"
        self.world_ns = f"hlm{tag}w"
        self.station_ns = {p: f"hlm{tag}{p[0]}" for p in PORTS}
        self.links = {p: (f"hlm{tag}w{p[0]}", f"hlm{tag}s{p[0]}") for p in PORTS}
        self.processes: list[Process] = []
        self.namespaces: list[str] = []
        self.veths: list[str] = []
        self.impair = impair or {}
        self.forwarders: dict[str, Process] = {}

    def __enter__(self) -> ThreeHosts:
        try:
            for ns in (self.world_ns, *self.station_ns.values()):
                ip("netns", "add", ns)
                self.namespaces.append(ns)
            for n, (port, (w_if, s_if)) in enumerate(self.links.items(), 1):
                if port in self.impair:
                    self.forward(port)
                else:
                    ip("link", "add", w_if, "type", "veth", "peer", "name", s_if)
                    self.veths.append(w_if)
                for ns, dev, host in ((self.world_ns, w_if, 1), (self.station_ns[port], s_if, 2)):
                    ip("link", "set", dev, "netns", ns)
                    ip("-n", ns, "addr", "add", f"10.214.{n}.{host}/30", "dev", dev)
                    ip("-n", ns, "link", "set", dev, "up")
                    ip("-n", ns, "link", "set", "lo", "up")
        except BaseException:
            self.cleanup()
            raise
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.cleanup()

    def forward(self, port: str) -> None:
        """The port's impairment forwarder, in this namespace: its two TUN devices made (to
        be moved into the world's and the station's namespaces), stopped by its pid."""
        argv = [sys.executable, "-m", "haptic_local_model.benchmarks.impair",
                "--tun", *self.links[port], *self.impair[port].argv()]  # fmt: skip
        p = Process(argv)
        self.processes.append(p)
        self.forwarders[port] = p
        p.wait_ready(IP_TIMEOUT_S)

    def start(self, ns: str, argv: list[str]) -> Process:
        """`ip netns exec` execs the command: the pid is the process's own."""
        p = Process(["ip", "netns", "exec", ns, *argv])
        self.processes.append(p)
        return p

    def set_link(self, port: str, up: bool) -> None:
        """Cut or restore a station's link at its end (the carrier drops at both ends)."""
        ip("-n", self.station_ns[port], "link", "set", self.links[port][1],
           "up" if up else "down")  # fmt: skip

    def cleanup(self) -> None:
        for p in self.processes:
            if p.proc.poll() is None:
                p.stop()
        for ns in self.namespaces:
            for pid in ip("netns", "pids", ns, check=False).stdout.split():
                with contextlib.suppress(ProcessLookupError):
                    os.kill(int(pid), signal.SIGKILL)
            ip("netns", "del", ns, check=False)
        for dev in self.veths:
            ip("link", "del", dev, check=False)

    def leftovers(self) -> list[str]:
        names = ip("netns", "list").stdout.split()
        out = [ns for ns in (self.world_ns, *self.station_ns.values()) if ns in names]
        out += [d for d in self.veths if ip("link", "show", d, check=False).returncode == 0]
        return out + [f"pid {p.proc.pid}" for p in self.processes if p.proc.poll() is None]


def loopback_network(folder: Path) -> str:
    """The shipped loopback station network on a free port of its own (a copy in folder)."""
    shipped = resolve("network", "stations_loopback")
    credentials = str(shipped.parent.parent / "credentials")
    path = folder / "stations.toml"
    text = shipped.read_text().replace("../credentials", credentials)
    path.write_text(text.replace(":7460", f":{free_loopback_port()}"))
    return str(path)


def loopback_run(
    scene: str, seconds: float, folder: Path, world_args: tuple[str, ...] = ()
) -> dict[str, Any]:
    """The router, the world (with `world_args`, e.g. its --view) and both stations on this
    host's loopback for `seconds`, no logs: the world's summary and each station's
    (benchmarks/loop_timing.py --stations, world_view.py); for a scene with sim bodies, its
    sim too (`sim-server --mirror`)."""
    net = ["--network", loopback_network(folder)]
    sim = [sys.executable, "-m", "haptic_local_model.sim_server.cli", "--mirror", scene, *net]
    started: list[Process] = []
    try:
        for argv in ([*CLI, "router", *net],
                     [*CLI, "world", *net, "--scene", scene, "--duration", str(seconds + 60.0),
                      "--json", str(folder / "world.json"), *world_args],
                     *([sim] if _has_sim_bodies(scene) else [])):  # fmt: skip
            started.append(Process(argv))
            started[-1].wait_ready()
        for p in PORTS:
            started.append(Process([*CLI, "station", *net, "--scene", scene, "--port", p,
                                    "--duration", str(seconds),
                                    "--json", str(folder / f"{p}.json")]))  # fmt: skip
        stations = started[-len(PORTS) :]
        for s in stations:
            s.wait_ready()
        for s in stations:
            s.proc.wait(seconds + STOP_S)
        started[1].stop()  # the world: its summary covers the stations' run
    finally:
        for s in started:
            s.stop()
    out = {"world": json.loads((folder / "world.json").read_text())}
    for p in PORTS:
        out[p] = json.loads((folder / f"{p}.json").read_text())
    return out


def _has_sim_bodies(scene: str) -> bool:
    text = resolve("ports", scene).read_text()
    return "sim_bodies" in tomllib.loads(text)


def station_rows(path: Path) -> np.ndarray:
    """A station log's rows."""
    chunks = [data for topic, data, _ in _iter_messages(path) if topic == STATION_TOPIC]
    return np.frombuffer(b"".join(chunks), STATION_ROW_DTYPE)


def after(rows: np.ndarray, t_ns: int) -> int:
    """The first row at or after the loop-clock time t_ns."""
    return int(np.searchsorted(rows["wall_ns"], t_ns))


def first(mask: np.ndarray, what: str) -> int:
    """The first index where mask holds; an error naming it if it never does."""
    if not mask.any():
        raise RuntimeError(f"never happened: {what}")
    return int(np.argmax(mask))


def largest_step(rows: np.ndarray, a: int, b: int) -> float:
    """The largest change from one tick to the next of the coupling's spring force as
    rendered (ramp included) over ticks a..b: a re-index that missed, or a force switched on
    at once, steps it by newtons. (The whole command also carries the damping of the device's
    noisy twist: on the maglev 0.14 N a tick at the median.)"""
    rendered = rows["spring"][a:b, :2] * rows["gain"][a:b, None]
    return float(np.abs(np.diff(rendered, axis=0)).max())


def ramp_bound(rows: np.ndarray, a: int, b: int, steady: float) -> float:
    """The most a ramp over 40 ticks can step the spring force by, its own change (the
    steady figure) and 10 mN on top."""
    return float(np.abs(rows["spring"][a:b, :2]).max()) / 40 + steady + 0.01


def cut_figures(left: np.ndarray, right: np.ndarray, cut: int, restored: int) -> dict[str, Any]:
    """The cut station's (left) watchdog, safe state, return and force steps; the other's
    rendering through the cut (module docstring)."""
    c = after(left, cut)
    wd = c + first(left["fresh"][c:] == 0, "the cut station's watchdog")
    safe = wd + first(left["gain"][wd:] == 0.0, "the cut station's safe state")
    b = after(left, restored)
    back = b + first(left["fresh"][b:] == 1, "the cut station's return")
    steady = largest_step(left, c - STEADY_WINDOW, c)
    r0, r1 = after(right, cut), after(right, restored)
    return {
        "watchdog_after_cut_ms": float((left["wall_ns"][wd] - cut) / 1e6),
        # the newest tool state the watchdog had (what was in flight when the link went down)
        "last_tool_state_after_cut_ms": float(
            (left["wall_ns"][wd] - left["tool_age"][wd] * 1e9 - cut) / 1e6
        ),
        "watchdog_tick_late_ms": float(left["late_us"][wd] / 1e3),
        "safe_after_watchdog_ms": float((left["wall_ns"][safe] - left["wall_ns"][wd]) / 1e6),
        "resumed_after_restore_ms": float((left["wall_ns"][back] - restored) / 1e6),
        "largest_step_after_n": largest_step(left, back, back + JUMP_WINDOW),
        "largest_step_steady_n": steady,
        "step_bound_n": ramp_bound(left, back, back + JUMP_WINDOW, steady),
        "command_before_n": left["out"][c - 500 : c, :2].mean(axis=0).tolist(),
        "command_after_n": left["out"][back + 500 : back + 1500, :2].mean(axis=0).tolist(),
        "other_rendered_through": bool(
            right["fresh"][r0:r1].all() and right["gain"][r0:r1].min() == 1.0
        ),
    }


def run(seconds: float, cut_after_s: float, cut_s: float, folder: Path) -> dict[str, Any]:
    """The three-host run (module docstring); its figures."""
    with ThreeHosts() as h:
        h.start(h.world_ns, [*CLI, "router", "--network", NETWORK]).wait_ready()
        world_json = folder / "world.json"
        world_args = ["--duration", str(seconds + 6.0), "--log", str(folder / "world.mcap"),
                      "--json", str(world_json)]  # fmt: skip
        world = h.start(h.world_ns, [*CLI, "world", "--network", NETWORK, *world_args])
        world.wait_ready()
        stations = {}
        for p in PORTS:
            args = ["--port", p, "--duration", str(seconds), "--log", str(folder / f"{p}.mcap"),
                    "--json", str(folder / f"{p}.json")]  # fmt: skip
            stations[p] = h.start(h.station_ns[p], [*CLI, "station", "--network", NETWORK, *args])
        for s in stations.values():
            s.wait_ready()
        time.sleep(cut_after_s)
        begun = time.perf_counter_ns()
        h.set_link("left", False)
        cut = time.perf_counter_ns()  # down by now: its watchdog counts from here at the latest
        time.sleep(cut_s)
        h.set_link("left", True)
        restored = time.perf_counter_ns()
        codes = {p: s.proc.wait(seconds + STOP_S) for p, s in stations.items()}
        codes["world"] = world.proc.wait(STOP_S + 10.0)
    left_over = h.leftovers()  # after the cleanup: nothing
    figures: dict[str, Any] = {"exit_codes": codes}
    for p in PORTS:
        s = json.loads((folder / f"{p}.json").read_text())
        figures[p] = {k: s[k] for k in ("ticks", "ticks_skipped", "overruns", "tick_rate_hz",
                                         "late_us", "work_us", "safe_entries",
                                         "tool_states_rejected")}  # fmt: skip
    w = json.loads(world_json.read_text())
    box = w["bodies"]["box"]
    figures["world"] = {k: w[k] for k in ("ticks", "tick_rate_hz", "late_us", "work_us", "events")}
    figures["box_sank_m"] = float(box["start"][1] - box["lowest_y"])
    rows = {p: station_rows(folder / f"{p}.mcap") for p in PORTS}
    figures["cut"] = cut_figures(rows["left"], rows["right"], cut, restored)
    figures["cut"]["cutting_took_ms"] = (cut - begun) / 1e6  # `ip link set down`, a process
    figures["world_log"] = str(folder / "world.mcap")
    figures["left_over"] = left_over
    return figures


def rate_shortfalls(figures: dict[str, Any], seconds: float) -> list[str]:
    """Where a station missed the rate target (module docstring): each device rendered at
    least DELIVERED_MIN of the run's ticks, its median second at least MEDIAN_HZ_MIN. A
    timing target of the machine as much as of the code: measured here, not in the tests."""
    out = []
    for p in PORTS:
        f = figures[p]
        delivered = f["ticks"] / (seconds * 1000.0)
        if delivered < DELIVERED_MIN:
            out.append(f"{p}: {delivered:.2%} of the ticks delivered (< {DELIVERED_MIN:.0%})")
        if f["tick_rate_hz"]["p50"] < MEDIAN_HZ_MIN:
            out.append(f"{p}: median second {f['tick_rate_hz']['p50']} Hz (< {MEDIAN_HZ_MIN})")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=24.0, help="the stations' run (s)")
    ap.add_argument("--cut-after", type=float, default=8.0, help="s after the stations start")
    ap.add_argument("--cut", type=float, default=3.0, help="how long the link is cut (s)")
    ap.add_argument("--out", type=Path, default=None, help="keep the logs here")
    ap.add_argument("--json", type=Path, default=None, help="write the figures here")
    ap.add_argument("--check", action="store_true", help="exit 1 if a station missed the rate")
    args = ap.parse_args(argv)
    reason = netns_unavailable()
    if reason:
        print(f"stations benchmark: {reason}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.out or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        figures = run(args.seconds, args.cut_after, args.cut, folder)
    print(json.dumps(figures, indent=2))
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2))
    short = rate_shortfalls(figures, args.seconds)
    for line in short:
        print(f"stations benchmark: {line}", file=sys.stderr)
    return 1 if args.check and short else 0


if __name__ == "__main__":
    sys.exit(main())

"""The real-time haptic server: a 1 kHz loop around the HapticEngine, over Zenoh.

Per tick (DESIGN §1, §4): wait for the deadline (sleep, then spin), take any new updates
without blocking (validate, install the newest, count the rest), run the engine tick,
publish the proxy state at `proxy_publish_hz`, copy the tick record to the log process.
Overruns resynchronise instead of bursting catch-up ticks; dt is the measured period
(clamped). A stale sim (no valid update for `watchdog_ms`) ramps the device to the safe
state; a restarted sim (new epoch) re-initialises the proxy and forces fade back in.
"""

from __future__ import annotations

import json
import signal
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from device_models.base import SimulatedDevice
from haptic_server.engine import HapticEngine
from haptic_server.log_process import LogProcess
from haptic_server.mcap_log import run_metadata, update_record
from haptic_server.virtual import run_virtual
from shared.config import NetworkConfig, SceneConfig, UserConfig
from shared.messages import ProxyState, encode_proxy
from shared.timing import LoopCounters, SampleWindow, wait_until
from shared.transport import keys, newest_payload, open_session

DT_CLAMP = (0.25, 2.0)  # measured dt is clamped to these multiples of the nominal period
WINDOW_TICKS = 600_000  # percentiles over the newest 10 min at 1 kHz


@dataclass
class HapticRunStats:
    """Figures of a run, for the summary (haptic-run --summary-json)."""

    counters: LoopCounters = field(default_factory=LoopCounters)
    lateness_us: SampleWindow = field(default_factory=lambda: SampleWindow(WINDOW_TICKS))
    work_us: SampleWindow = field(default_factory=lambda: SampleWindow(WINDOW_TICKS))
    update_age_ms: SampleWindow = field(default_factory=lambda: SampleWindow(100_000))
    updates_received: int = 0
    updates_installed: int = 0
    watchdog_trips: int = 0
    wall_s: float = 0.0
    lost_log_ticks: int = 0

    def summary(self, log_path: Path | None) -> dict[str, Any]:
        c = self.counters
        return {
            "ticks": c.ticks,
            "duration_s": self.wall_s,
            "tick_rate_hz": c.ticks / self.wall_s if self.wall_s > 0 else 0.0,
            "lateness_us": self.lateness_us.percentiles(50, 99, 99.9),
            "late_ticks_over_1ms": c.late_over_1ms,
            "overruns": c.overruns,
            "work_us": self.work_us.percentiles(50, 99),
            "updates_received": self.updates_received,
            "updates_installed": self.updates_installed,
            "update_rate_hz": self.updates_received / self.wall_s if self.wall_s > 0 else 0.0,
            "update_age_ms": self.update_age_ms.percentiles(50, 99),
            "watchdog_trips": self.watchdog_trips,
            "lost_log_ticks": self.lost_log_ticks,
            "log": str(log_path) if log_path else None,
        }


class HapticServer:
    """One haptic server process: engine + Zenoh + log process + the real-time loop."""

    def __init__(
        self,
        scene: SceneConfig,
        device: SimulatedDevice,
        user: UserConfig,
        network: NetworkConfig,
        log_path: Path | None,
        configs: dict[str, str],
        zenoh_extra: dict[str, Any] | None = None,
    ) -> None:
        self.scene = scene
        self.network = network
        self.engine = HapticEngine(scene, device, user, network.safe_ramp_ms / 1000.0)
        self.log_path = log_path
        self.configs = configs
        self.zenoh_extra = zenoh_extra
        self.stats = HapticRunStats()
        self._stop = False

    def request_stop(self, *_: object) -> None:
        self._stop = True

    def warm_up(self, device_factory: Any, user: UserConfig) -> None:
        """Compile (or load from cache) every kernel before the loop starts."""
        run_virtual(self.scene, device_factory(), user, 0.05)

    def run(self, duration_s: float | None, ready: Any = None) -> dict[str, Any]:
        """The loop; returns the summary. `ready` is called once the loop is about to start."""
        engine = self.engine
        k = keys(self.network.namespace)
        session = open_session(self.network.haptic, self.zenoh_extra)
        sub = session.declare_subscriber(k.update, zenoh.handlers.RingChannel(16))
        pub = session.declare_publisher(
            k.proxy, congestion_control=zenoh.CongestionControl.DROP, express=True
        )
        wall_start_ns = time.time_ns()
        log = (
            LogProcess(
                self.log_path, run_metadata(self.configs, {"clock": "real-time"}), wall_start_ns
            )
            if self.log_path
            else None
        )
        period_ns = round(1e9 / self.scene.haptic_rate_hz)
        dt_nominal = period_ns / 1e9
        publish_every = max(1, round(self.scene.haptic_rate_hz / self.network.proxy_publish_hz))
        watchdog_ns = int(self.network.watchdog_ms * 1e6)
        stats = self.stats
        counters = stats.counters
        row_meta_seq = -1
        row_age_ms = float("nan")
        last_valid_ns = 0
        stale = False
        if ready is not None:
            ready()
        start_ns = time.perf_counter_ns()
        end_ns = start_ns + int(duration_s * 1e9) if duration_s else None
        deadline = start_ns + period_ns
        last_start = start_ns
        work_prev_us = 0.0
        try:
            while not self._stop:
                now = wait_until(deadline)
                lateness_ns = now - deadline
                dt_ns = now - last_start if counters.ticks else period_ns
                last_start = now
                if lateness_ns > period_ns:
                    counters.overruns += 1
                    deadline = now  # resynchronise: no burst of catch-up ticks
                if lateness_ns > 1_000_000:
                    counters.late_over_1ms += 1
                dt = min(max(dt_ns / 1e9, DT_CLAMP[0] * dt_nominal), DT_CLAMP[1] * dt_nominal)

                for raw in newest_payload(sub):
                    stats.updates_received += 1
                    reason = engine.receive(raw)
                    if reason:
                        if log:
                            log.event(counters.ticks, "rejected", reason, engine.time)
                    else:
                        stats.updates_installed += 1
                        last_valid_ns = now
                        newest = engine.slots[0]
                        row_meta_seq = int(newest["seq"])
                        row_age_ms = (time.time_ns() - int(newest["publish_time_ns"])) / 1e6
                        stats.update_age_ms.add(row_age_ms)
                        if stale:
                            stale = False
                            engine.set_safe(False)
                            if log:
                                log.event(
                                    counters.ticks,
                                    "watchdog_clear",
                                    f"update seq {row_meta_seq}",
                                    engine.time,
                                )
                    if log:
                        log.update(
                            update_record(counters.ticks, raw, reason, row_age_ms), engine.time
                        )

                if engine.ready and not stale and now - last_valid_ns > watchdog_ns:
                    stale = True
                    stats.watchdog_trips += 1
                    engine.set_safe(True)
                    if log:
                        log.event(
                            counters.ticks,
                            "watchdog",
                            f"no valid update for {(now - last_valid_ns) / 1e6:.1f} ms",
                            engine.time,
                        )

                row = engine.tick(dt)
                r = row[0]
                r["lateness_us"] = lateness_ns / 1e3
                r["work_us"] = work_prev_us
                r["update_seq"] = row_meta_seq
                r["update_age_ms"] = row_age_ms
                if engine.ready and counters.ticks % publish_every == 0:
                    pub.put(encode_proxy(self._proxy_state(stale)))
                if log:
                    log.tick(row)
                counters.ticks += 1
                stats.lateness_us.add(lateness_ns / 1e3)
                work_prev_us = (time.perf_counter_ns() - now) / 1e3
                stats.work_us.add(work_prev_us)
                deadline += period_ns
                if end_ns is not None and now >= end_ns:
                    break
        finally:
            stats.wall_s = (time.perf_counter_ns() - start_ns) / 1e9
            engine.device.safe_stop()
            if log:
                log.event(counters.ticks, "stop", "loop ended", engine.time)
                stats.lost_log_ticks = log.close()
            session.close()
        return stats.summary(self.log_path)

    def _proxy_state(self, stale: bool) -> ProxyState:
        engine = self.engine
        q, qd = engine.proxy_pose()
        pose, twist = engine.device_world_pose()
        return ProxyState(
            epoch=engine.epoch, update_seq=engine.last_seq, tick=engine.tick_index,
            haptic_time=engine.time, publish_time_ns=time.time_ns(), method=engine.method,
            safe_state=stale, valid=engine.ready, q=q, qd=qd, device_pose=pose, device_twist=twist,
        )  # fmt: skip


def install_signal_handlers(server: HapticServer) -> None:
    signal.signal(signal.SIGTERM, server.request_stop)
    signal.signal(signal.SIGINT, server.request_stop)


def print_event(kind: str, **fields: Any) -> None:
    """One JSON line on stdout: how haptic-run and tests learn what the process is doing."""
    print(json.dumps({"event": kind, **fields}), flush=True)

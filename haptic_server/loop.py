"""The real-time haptic server: a 1 kHz loop around the HapticEngine, over Zenoh.

Per tick (DESIGN §1, §4): wait for the deadline (sleep, then spin), take the updates waiting
in the mailbox without blocking (validate, order-check and install each, oldest first, up to
MAX_UPDATES_PER_TICK, in one numba call), run the engine tick, copy the tick record to the
log process's ring (which publishes the proxy state at `proxy_publish_hz`).

The loop is kept Python-light on purpose: on this VM code runs 3-10x slower right after
the vCPU has idled (each sleep), so work per tick is mostly the number of Python operations
and kernel calls, not the arithmetic in them.
Overruns resynchronise instead of bursting catch-up ticks; dt is the measured period
(clamped). A stale sim (no valid update for `watchdog_ms`) ramps the device to the safe
state; the next valid update, from a restarted sim (new epoch) or from the same sim after an
outage, re-initialises the proxy from the sim's state and forces fade back in. A stop (signal
or end of the run) ramps the device to the safe state before the loop ends.
"""

from __future__ import annotations

import dataclasses
import gc
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from haptic_local_model.device_models.base import Device
from haptic_local_model.device_models.common import refill_noise
from haptic_local_model.haptic_server.engine import HapticEngine, warm_kernels
from haptic_local_model.haptic_server.log import run_metadata
from haptic_local_model.haptic_server.mailbox import (
    C_UPD_HEAD,
    C_UPD_READ,
    C_WALL_START,
    MAILBOX_SLOTS,
    compile_loop_kernels,
    push_row,
)
from haptic_local_model.haptic_server.paced import (
    RETURNED_TO_PYTHON,
    loop_record,
    open_tick,
)
from haptic_local_model.haptic_server.realtime import (
    compile_realtime_kernels,
    local_paced,
    local_windows,
    local_world,
)
from haptic_local_model.haptic_server.sidecar import LoopIO
from haptic_local_model.haptic_server.supervisor import Event, TickEvents, WatchdogClock, supervise
from haptic_local_model.haptic_server.view_address import ViewAddress
from haptic_local_model.haptic_server.world import RETURN_EVERY_NS, drive_paced
from haptic_local_model.shared.config import SceneConfig, UserConfig
from haptic_local_model.shared.net.config import NetworkConfig
from haptic_local_model.shared.protocol.codes import Fault
from haptic_local_model.shared.timing import (
    LoopCounters,
    SampleWindow,
    keep_to_cpu,
    loop_cpu,
    try_realtime_priority,
    wait_until,
    wall_clock_at,
)

DT_CLAMP = (0.25, 2.0)  # measured dt is clamped to these multiples of the nominal period
FIRST_UPDATE_WAIT_S = 60.0  # --duration starts at the first update, or gives up after this
# updates taken from the mailbox per tick: a flood of messages (garbage or not) costs the loop
# at most this many validations (~10 us each) per tick; the rest wait in the mailbox
MAX_UPDATES_PER_TICK = 8
# ...but when the watchdog came due while the loop itself was stopped (SIGSTOP, a hypervisor
# pause), everything that arrived meanwhile is judged in that tick before silence is: up to
# the mailbox (~10 us each), once per such stall
WINDOW_TICKS = 600_000  # percentiles over the newest 10 min at 1 kHz
IO_CHECK_S = 0.05  # how often the loop's Python side looks whether its I/O process is awake


@dataclass
class HapticRunStats:
    """Figures of a run, for the summary (haptic-run --summary-json)."""

    counters: LoopCounters = field(default_factory=LoopCounters)
    lateness_us: SampleWindow = field(default_factory=lambda: SampleWindow(WINDOW_TICKS))
    work_us: SampleWindow = field(default_factory=lambda: SampleWindow(WINDOW_TICKS))
    update_age_ms: SampleWindow = field(default_factory=lambda: SampleWindow(100_000))
    updates_received: int = 0
    updates_installed: int = 0
    rejected_by_reason: dict[str, int] = field(default_factory=dict)
    reinitialisations: int = 0
    watchdog_trips: int = 0
    wall_s: float = 0.0
    lost_log_ticks: int = 0
    proxy_published: int = 0
    pointer_received: int = 0  # pointer inputs (a user of kind "pointer") received
    pointer_rejected: int = 0  # ... refused: malformed, out of range, late, future
    pointer_rejected_by_reason: dict[str, int] = field(default_factory=dict)
    static_received: int = 0  # the sim's static messages of this scene's train ...
    static_refused: int = 0  # ... and of another train, or malformed
    static_refused_by_reason: dict[str, int] = field(default_factory=dict)
    updates_lost: int = 0
    events_lost: int = 0  # overwritten in the event ring before the log writer read them
    log_failed: str = ""  # why the log writer stopped (a full disk): the run went on
    io_stalls: int = 0  # the I/O sidecar did not wake for a watchdog period (starved)
    io_lost: bool = False  # the I/O sidecar died: the run was stopped
    guard_trips: dict[str, int] = field(default_factory=dict)  # faults by kind (Fault)
    realtime_priority: bool = False
    loop_cpu: int | None = None  # the CPU the loop kept to itself (None: not pinned)

    def summary(self, log_path: Path | None) -> dict[str, Any]:
        c = self.counters
        return {
            "ticks": c.ticks,
            "duration_s": self.wall_s,
            "tick_rate_hz": c.ticks / self.wall_s if self.wall_s > 0 else 0.0,
            "lateness_us": self.lateness_us.percentiles(50, 99, 99.9),
            "late_ticks_over_1ms": c.late_over_1ms,
            "overruns": c.overruns,
            "ticks_skipped": c.skipped,  # every period of the run is a tick or one of these
            "work_us": self.work_us.percentiles(50, 99),
            "updates_received": self.updates_received,
            "updates_installed": self.updates_installed,
            "updates_rejected": sum(self.rejected_by_reason.values()),
            "rejected_by_reason": dict(self.rejected_by_reason),
            "reinitialisations": self.reinitialisations,
            "update_rate_hz": self.updates_received / self.wall_s if self.wall_s > 0 else 0.0,
            "update_age_ms": self.update_age_ms.percentiles(50, 99),
            "watchdog_trips": self.watchdog_trips,
            "guard_trips": dict(self.guard_trips),
            "realtime_priority": self.realtime_priority,
            "loop_cpu": self.loop_cpu,
            "lost_log_ticks": self.lost_log_ticks,
            "updates_lost": self.updates_lost,
            "events_lost": self.events_lost,
            "log_failed": self.log_failed,
            "io_stalls": self.io_stalls,
            "io_lost": self.io_lost,
            "proxy_published": self.proxy_published,
            "pointer_received": self.pointer_received,
            "pointer_rejected": self.pointer_rejected,
            "pointer_rejected_by_reason": dict(self.pointer_rejected_by_reason),
            "static_received": self.static_received,
            "static_refused": self.static_refused,
            "static_refused_by_reason": dict(self.static_refused_by_reason),
            "log": str(log_path) if log_path else None,
        }


@dataclass(frozen=True)
class InjectedFaults:
    """Deliberate faults for testing the soak's checks (haptic-server --inject-*)."""

    leak_bytes_per_tick: int = 0
    nan_after_s: float | None = None


@dataclass(frozen=True)
class ServerExtras:
    """What a haptic server may have beside its configs: extra Zenoh settings, a live view,
    injected faults."""

    zenoh: dict[str, Any] | None = None
    view: ViewAddress | None = None
    faults: InjectedFaults = field(default_factory=InjectedFaults)


class HapticServer:
    """One haptic server process: engine + Zenoh + log process + the real-time loop."""

    def __init__(
        self,
        scene: SceneConfig,
        device: Device,
        user: UserConfig,
        network: NetworkConfig,
        log_path: Path | None,
        configs: dict[str, str],
        extras: ServerExtras | None = None,
    ) -> None:
        self.extras = extras or ServerExtras()
        self.scene = scene
        self.network = network
        self.engine = HapticEngine(scene, device, user, network.safe_ramp_ms / 1000.0)
        self.engine.set_admission(network.max_update_age_ms / 1e3, network.clock_skew_ms / 1e3)
        self.log_path = log_path
        self.configs = configs
        self.stats = HapticRunStats()
        self._stop = False
        # the running loop's parts, set by run() (read by the supervisor's install step)
        self._io: LoopIO
        self._supervisor: WatchdogClock
        self._tick = 0
        self._lateness_ns = 0  # the tick's (set by _ticks, read by the install step)
        self._duration_ns: int | None = None
        self._newest_seq = -1
        self._newest_age_ms = float("nan")
        self._peaks = np.zeros(3)  # the largest lateness and work of the run (us; paced.PEAK_*)
        self._io_stalled = False
        self._io_check_ticks = max(1, round(IO_CHECK_S * scene.haptic_rate_hz))

    def request_stop(self, *_: object) -> None:
        self._stop = True

    def warm_up(self, device_factory: Any, user: UserConfig) -> None:
        """Compile (or load from cache) every kernel before the loop starts."""
        warm_kernels(self.scene, device_factory(), user)
        compile_loop_kernels(self.engine)
        compile_realtime_kernels(self.engine)

    def _take_updates(self) -> int:
        """The supervisor's install step: validate and install what waits in the mailbox (one
        numba call; the engine's Python side only after a new epoch, the watchdog, or for FOH
        setpoints); the first install starts the run's duration."""
        stats, sup = self.stats, self._supervisor
        budget = MAX_UPDATES_PER_TICK
        if sup.now_ns > sup.trip_at_ns >= sup.now_ns - self._lateness_ns:
            budget = MAILBOX_SLOTS  # due at a deadline the loop missed: its silence, not the sim's
        taken, installed, seq, latency_s = self._io.take_updates(self.engine, self._tick, budget)
        stats.updates_received += taken
        if installed:
            if stats.updates_installed == 0 and self._duration_ns is not None:
                # the duration counts from the first install
                sup.end_ns = sup.now_ns + self._duration_ns
            stats.updates_installed += installed
            self._newest_seq = seq
            self._newest_age_ms = latency_s * 1e3
            stats.update_age_ms.add(self._newest_age_ms)
        return installed

    def _log_events(
        self, io: LoopIO, tick: int, events: TickEvents, supervisor: WatchdogClock
    ) -> None:
        """The tick's supervisor events into the event ring (and the watchdog counter)."""
        engine = self.engine
        if events.stop:
            why = supervisor.stop_reason
            io.event(tick, Event.STOP, f"{why}: ramping to the safe state")
        if events.reinitialised:
            how = "new epoch" if events.new_epoch else "same epoch"
            io.event(
                tick,
                Event.REINITIALISE,
                f"{how} {engine.epoch} seq {self._newest_seq}: proxy from the sim",
            )
        if events.watchdog_clear:
            io.event(tick, Event.WATCHDOG_CLEAR, f"update seq {self._newest_seq}")
        if events.watchdog:
            self.stats.watchdog_trips += 1
            silent_ms = (supervisor.now_ns - supervisor.last_valid_ns) / 1e6
            io.event(tick, Event.WATCHDOG, f"no valid update for {silent_ms:.1f} ms")

    def run(self, duration_s: float | None, ready: Any = None, warm: Any = None) -> dict[str, Any]:
        """The loop; returns the summary. `ready` is called once the loop is about to start;
        `warm` (warm_up), if given, while the I/O process starts (the kernels load from the
        cache in about a second, as long as the I/O process takes to start)."""
        engine = self.engine
        stats = self.stats
        cpu = loop_cpu()
        period_ns = round(1e9 / self.scene.haptic_rate_hz)
        io = self._open_io(cpu, period_ns)
        try:  # from here on every exit path closes the I/O process (its log, its session)
            if warm is not None:
                warm()
            io.wait_ready()
            if engine.follows_pointer:  # its targets come from the sidecar
                engine.share_user(io.block.user)
            watchdog_ns = int(self.network.watchdog_ms * 1e6)
            self._newest_seq = -1
            self._newest_age_ms = float("nan")
            self._io = io
            self._tick = 0
            stats.realtime_priority = try_realtime_priority()
            if not stats.realtime_priority:
                io.lower_io_priority()
            elif keep_to_cpu(cpu):  # the sidecar keeps off it (it was told `cpu`)
                stats.loop_cpu = cpu
            loop = loop_record(period_ns, DT_CLAMP, watchdog_ns)
            loop[0]["budget"] = MAX_UPDATES_PER_TICK
            # everything allocated so far lives as long as the process: out of the cyclic
            # collector's sight, so a full collection during the loop has little to traverse
            gc.collect()
            gc.freeze()
            if ready is not None:
                ready()
            start_ns = time.perf_counter_ns()
            io.block.ctl[C_WALL_START] = wall_clock_at(start_ns)  # the log's time of t = 0
            # the duration counts from the first installed update (a sim that starts later, or
            # compiles first, does not eat into it); without any update it ends all the same
            # after FIRST_UPDATE_WAIT_S more
            self._duration_ns = int(duration_s * 1e9) if duration_s else None
            supervisor = WatchdogClock(engine, watchdog_ns, self._take_updates)
            self._supervisor = supervisor
            if self._duration_ns:  # no duration: runs until stopped
                supervisor.end_ns = start_ns + self._duration_ns + int(FIRST_UPDATE_WAIT_S * 1e9)
            loop[0]["deadline_ns"] = start_ns + period_ns
            loop[0]["last_start_ns"] = start_ns
        except BaseException:
            io.close()
            raise
        try:
            self._ticks(io, supervisor, loop)
        finally:
            lp = loop[0]
            ticks = int(lp["tick"])
            counters = stats.counters
            counters.ticks, counters.overruns = ticks, int(lp["overruns"])
            counters.late_over_1ms = int(lp["late_over_1ms"])
            counters.skipped = int(lp["skipped"])
            stats.wall_s = (time.perf_counter_ns() - start_ns) / 1e9
            work_prev_us = float(lp["work_prev_us"])
            work_window = stats.work_us.buffer
            if ticks:  # the last tick's work is in no row
                work_window[(ticks - 1) % work_window.shape[0]] = work_prev_us
            stats.lateness_us.filled(ticks, float(self._peaks[0]))
            stats.work_us.filled(ticks, max(float(self._peaks[1]), work_prev_us))
            self._finish(io)
        return stats.summary(self.log_path)

    def _ticks(self, io: LoopIO, supervisor: WatchdogClock, loop: np.ndarray) -> None:
        """Tick until the stop ramp has ended. Quiet ticks of a simulated device run in the
        compiled paced loop (haptic_server.paced over the local model's kind,
        haptic_server.realtime); a tick that needs the supervisor, every tick of a hardware
        driver, and every tick under an injected fault run here."""
        engine, stats = self.engine, self.stats
        period_ns = int(loop[0]["period_ns"])
        spin_ns = int(loop[0]["spin_ns"])
        # one-element views of the loop record's fields this side reads and writes per tick
        deadline, tick_count = loop["deadline_ns"], loop["tick"]
        now_v, lateness_v, dt_v = loop["now_ns"], loop["lateness_ns"], loop["dt"]
        work_v = loop["work_prev_us"]
        ring, ctl = io.block.ticks, io.block.ctl
        lateness_window, work_window = stats.lateness_us.buffer, stats.work_us.buffer
        self._peaks = peaks = np.zeros(3)
        ring_io = (
            ring, ctl, io.block.mailbox, lateness_window, work_window,
            stats.update_age_ms.buffer, peaks, engine.row,
        )  # fmt: skip
        ts = np.zeros(2, np.int64)
        leak_bytes = self.extras.faults.leak_bytes_per_tick
        leak: list[bytes] = []  # only ever grows under --inject-leak
        nan_tick = (
            round(self.extras.faults.nan_after_s * self.scene.haptic_rate_hz)
            if self.extras.faults.nan_after_s is not None
            else -1
        )
        sim = engine.sim_device
        compiled = sim is not None and not leak_bytes and nan_tick < 0
        # the compiled loop's arguments, once a run (the records live as long as the engine)
        burst_io = (
            (local_world(engine, loop, ring_io), local_windows(ring_io), ring) if compiled else ()
        )
        fault_state = engine.state["fault"]
        self._fault_seen = fault_seen = loop["fault_reported"]
        self._check_io_at = 0
        while True:
            if compiled and not (self._stop or supervisor.stopping):
                status = self._burst(io, supervisor, loop, burst_io, ts)
                if status == RETURNED_TO_PYTHON:
                    continue  # between two ticks: signals, then the next burst
            else:
                open_tick(loop, wait_until(int(deadline[0]), spin_ns))
            now, lateness_ns, dt = int(now_v[0]), int(lateness_v[0]), float(dt_v[0])
            tick = int(tick_count[0])
            if (  # anything for the supervisor? (cheap checks first: most ticks skip it)
                self._stop
                or now >= supervisor.end_ns
                or ctl[C_UPD_READ] < ctl[C_UPD_HEAD]
                or now > supervisor.trip_at_ns
            ):
                supervisor.now_ns = now
                supervisor.stop_requested = self._stop
                self._tick, self._lateness_ns = tick, lateness_ns
                events = supervise(engine, supervisor)
                if events.stop or events.reinitialised or events.watchdog_clear or events.watchdog:
                    self._log_events(io, tick, events, supervisor)
            if supervisor.stopping and (not engine.ready or engine.state[0]["safe"] >= 1.0):
                break

            if leak_bytes:
                leak.append(bytes(leak_bytes))
            if tick == nan_tick:
                engine.user[0]["kind"] = 0  # the hand's wrench turns NaN from now on
                engine.user[0]["wrench"] = float("nan")
            row = engine.tick(
                dt, lateness_ns / 1e3, float(work_v[0]), self._newest_seq, self._newest_age_ms
            )
            push_row(ring, ctl, row, lateness_window, work_window, peaks)
            if fault_state[0] != fault_seen[0]:
                self._report_fault(io, tick, fault_seen)
            if tick >= self._check_io_at:
                self._check_io_at = tick + self._io_check_ticks
                self._check_io(io, tick, supervisor)
            tick_count[0] = tick + 1
            work_v[0] = (time.perf_counter_ns() - now) / 1e3
            deadline[0] += period_ns

    def _check_io(self, io: LoopIO, tick: int, supervisor: WatchdogClock) -> None:
        """Is the I/O sidecar awake? (every IO_CHECK_S) Starved for a watchdog period: said
        once per stall (the watchdog has sent the device safe: no update came in); dead: said,
        and the run is stopped (no update can come in again)."""
        stats = self.stats
        state = io.io_state(time.monotonic_ns(), int(self.network.watchdog_ms * 1e6))
        if state == "lost" and not stats.io_lost:
            stats.io_lost = True
            io.event(tick, "io_lost", "the I/O process died: stopping, the device to safe")
            supervisor.stop_why = "the I/O process died"
            self._stop = True
        elif state == "stalled" and not self._io_stalled:
            self._io_stalled = True
            stats.io_stalls += 1
            io.event(
                tick,
                "io_stalled",
                f"the I/O process has not woken for {self.network.watchdog_ms:g} ms",
            )
        elif state == "" and self._io_stalled:
            self._io_stalled = False
            io.event(tick, "io_resumed", "the I/O process is awake again")

    def _report_fault(self, io: LoopIO, tick: int, fault_seen: np.ndarray) -> None:
        """The engine's fault changed at `tick`: a new one (the guard or the NaN check sent the
        device safe) is counted and logged; a cleared one (re-initialised) only noted."""
        fault = int(self.engine.state[0]["fault"])
        fault_seen[0] = fault
        if fault == Fault.NONE:
            return
        tag = Fault(fault).name.lower()
        trips = self.stats.guard_trips
        trips[tag] = trips.get(tag, 0) + 1
        io.event(tick, Event.FAULT, f"{tag}: device to the safe state until the next update")

    def _after_burst(self, io: LoopIO, tick: int, supervisor: WatchdogClock) -> None:
        """Between two ticks after compiled ones (`tick`: the next): a fault they brought
        reported, the I/O process looked at when due. (The compiled loop comes back between
        two ticks after any tick that brought a fault, before it hands a tick to the
        supervisor; a tick the supervisor runs looks at the I/O process itself.)"""
        if self.engine.state[0]["fault"] != self._fault_seen[0]:
            self._report_fault(io, tick - 1, self._fault_seen)
        if tick >= self._check_io_at:
            self._check_io_at = tick + self._io_check_ticks
            self._check_io(io, tick, supervisor)

    def _burst(
        self,
        io: LoopIO,
        supervisor: WatchdogClock,
        loop: np.ndarray,
        burst_io: tuple[Any, ...],
        ts: np.ndarray,
    ) -> int:
        """Run quiet ticks compiled (local_paced, driven by drive_paced) until one needs this
        side (that tick is left opened), or, between two ticks, a stop is asked (every
        RETURN_EVERY_NS, or after a tick that brought a fault, which is reported there); a
        spent noise block is refilled for the opened tick, which then runs compiled.
        burst_io: local_paced's world, windows and ring. Returns the status."""
        engine, stats = self.engine, self.stats
        sim = engine.sim_device
        assert sim is not None
        lp = loop[0]
        lp["end_ns"], lp["trip_at_ns"] = supervisor.end_ns, supervisor.trip_at_ns
        lp["last_valid_ns"] = supervisor.last_valid_ns
        lp["return_at_ns"] = lp["deadline_ns"] + RETURN_EVERY_NS
        lp["newest_seq"], lp["newest_age_ms"] = self._newest_seq, self._newest_age_ms
        lp["age_count"], lp["received"], lp["installed"] = stats.update_age_ms.count, 0, 0
        world, windows, ring = burst_io

        def between() -> bool:
            self._after_burst(io, int(lp["tick"]), supervisor)
            if self._stop or supervisor.stopping:  # the stop ramp is the supervisor's, in Python
                return False
            lp["return_at_ns"] = lp["deadline_ns"] + RETURN_EVERY_NS
            return True

        status = drive_paced(
            lambda: local_paced(world, ring, loop, windows, ts),
            lambda: refill_noise(sim.noise, sim.records, float(lp["dt"])),
            between,
        )
        lp = loop[0]
        supervisor.trip_at_ns, supervisor.last_valid_ns = (
            int(lp["trip_at_ns"]),
            int(lp["last_valid_ns"]),
        )
        self._newest_seq, self._newest_age_ms = int(lp["newest_seq"]), float(lp["newest_age_ms"])
        stats.updates_received += int(lp["received"])
        stats.updates_installed += int(lp["installed"])
        stats.update_age_ms.filled(int(lp["age_count"]), float(lp["age_max"]))
        engine.set_update(self._newest_seq, self._newest_age_ms)
        return status

    def _open_io(self, cpu: int | None, period_ns: int) -> LoopIO:
        """Start the I/O sidecar (Zenoh session, MCAP writer) and map its shared memory; it
        keeps off `cpu`, which the loop will keep to itself."""
        view = self.extras.view
        return LoopIO(
            {
                "loop_cpu": cpu,
                "tick_period_ns": period_ns,
                "namespace": self.network.namespace,
                "endpoints": dataclasses.asdict(self.network.haptic),  # with credentials
                "zenoh_extra": self.extras.zenoh,
                "log_path": str(self.log_path) if self.log_path else None,
                "metadata": run_metadata(self.configs, {"clock": "real-time"}),
                "wall_start_ns": time.time_ns(),
                "proxy_publish_hz": self.network.proxy_publish_hz,
                "method": self.engine.method,
                "pointer": self.engine.follows_pointer,
                "clock_skew_ns": round(self.network.clock_skew_ms * 1e6),
                "static_id": int(self.engine.model[0]["train"]["static_id"]),
                "view": None if view is None else {
                    **dataclasses.asdict(view), "scene_text": self.configs.get("scene"),
                    "watchdog_ms": self.network.watchdog_ms,
                },
            }
        )  # fmt: skip

    def _finish(self, io: LoopIO) -> None:
        """The loop has ended: device safe, the counters into the stats, the sidecar closed."""
        stats, engine = self.stats, self.engine
        stats.rejected_by_reason = dict(engine.counters.rejected_by_reason)
        stats.reinitialisations = engine.counters.reinitialisations
        stop_failed: Exception | None = None
        try:
            engine.device.safe_stop()
        except Exception as exc:  # the log and the I/O process are closed all the same
            stop_failed = exc
            io.event(stats.counters.ticks, "safe_stop_failed", f"{type(exc).__name__}: {exc}")
        else:
            io.event(stats.counters.ticks, "stopped", "loop ended; device in its safe state")
        stats.log_failed = io.log_failure
        ticks_logged = io.ticks_logged
        io_counters = io.close()
        stats.lost_log_ticks = io_counters["lost_log_ticks"]
        if stats.log_failed and self.log_path is not None:  # the writer cannot count them
            stats.lost_log_ticks = stats.counters.ticks - ticks_logged
        stats.proxy_published = io_counters["proxy_published"]
        stats.pointer_received = io_counters["pointer_received"]
        stats.pointer_rejected = io_counters["pointer_rejected"]
        stats.static_received = io_counters["static_received"]
        stats.static_refused = io_counters["static_refused"]
        stats.pointer_rejected_by_reason = io.refused["pointer"]
        stats.static_refused_by_reason = io.refused["static"]
        stats.updates_lost = io_counters["lost_updates"]
        stats.events_lost = io_counters["lost_events"]
        if stop_failed is not None:
            raise stop_failed

"""All of the haptic server's I/O in processes beside the loop, so the loop does none.

The loop and its helpers share one block of memory (`haptic_server.mailbox`):
- the **update mailbox**: the sidecar's Zenoh subscriber thread copies each received
  LocalModelUpdate into the next slot; the loop validates and installs it in place (one
  numba call) and writes its verdict next to it;
- the **tick ring**: the loop copies each tick record in (one numba call);
- the **event ring**: watchdog trips and other events, as short text.
The sidecar (this module) owns the Zenoh session: it receives updates and publishes the
proxy state (read from the newest tick record) at `proxy_publish_hz`. It runs with real-time
priority below the loop's where permitted, off the loop's CPU, so a received update reaches
the mailbox within microseconds of its arrival. The MCAP log is written by a third process
(`haptic_server.logger`). Neither runs Python in the loop's process, so neither competes for
the loop's GIL; if the loop dies, even by SIGKILL, both notice, and the writer drains what
is there and closes the log.
"""

from __future__ import annotations

import contextlib
import gc
import multiprocessing as mp
import os
import struct
import sys
import threading
import time
from multiprocessing import shared_memory
from typing import TYPE_CHECKING, Any

import numpy as np

from haptic_local_model.haptic_server.live_view import ViewProcess
from haptic_local_model.haptic_server.logger import LogProcess
from haptic_local_model.haptic_server.mailbox import (
    C_CLOSED,
    C_EVT_LOST,
    C_IO_BEAT,
    C_LOG_FAILED,
    C_LOG_READY,
    C_LOWER_IO,
    C_PTR_REASONS,
    C_PTR_RECEIVED,
    C_PTR_REJECTED,
    C_PUBLISHED,
    C_READY,
    C_RECEIVED,
    C_SIM_BOUND,
    C_SIM_OWNER,
    C_STATIC_BAD,
    C_STATIC_OK,
    C_STATIC_REASONS,
    C_TICK_HEAD,
    C_TICK_LOGGED,
    C_TICK_LOST,
    C_UPD_HEAD,
    C_UPD_LOST,
    C_UPD_READ,
    MAILBOX_SLOTS,
    POINTER_REASONS,
    RING_TICKS,
    STATIC_REASONS,
    SharedBlock,
    take_updates,
)
from haptic_local_model.haptic_server.view_board import ViewBoard
from haptic_local_model.shared.protocol.codes import Method
from haptic_local_model.shared.protocol.proxy import (
    MAX_WAIT_NS,
    NO_WAIT,
    ShapeImpulses,
    UpdateWait,
)
from haptic_local_model.shared.protocol.update import AT_SEQ
from haptic_local_model.shared.timing import (
    GIL_SWITCH_INTERVAL_S,
    REALTIME_PRIORITY,
    avoid_cpu,
    try_realtime_priority,
)

if TYPE_CHECKING:
    from haptic_local_model.haptic_server.engine import HapticEngine

IO_POLL_S = 0.004  # the sidecar wakes at least this often (and for each proxy publish)
IO_NICENESS = 10  # only when the loop could not get real-time priority (see _lower_priority)
IO_PRIORITY = REALTIME_PRIORITY // 2  # SCHED_FIFO below the loop's
VIEW_CLOSE_S = 5.0  # the live view's last frame and flush
RING_MARGIN = 64  # ring slots the impulse sum leaves alone: the loop may be writing them


class LoopIO:
    """The loop's side: take updates, give verdicts, push ticks and events. No syscalls.

    Built, it has started its processes (the log writer and the sidecar, side by side);
    `wait_ready` waits for both (the loop compiles its kernels meanwhile)."""

    def __init__(self, config: dict[str, Any]) -> None:
        self.block = SharedBlock.create()  # its pages touched: the loop's memory stays flat
        self._shm = self.block.shm
        # the sim's world for the live view (and the log), only when a view is asked for
        self.board = ViewBoard.create() if config.get("view") else None
        if self.board is not None:
            config = {**config, "view_board": self.board.name}
        self._logger: LogProcess | None = None
        self.refused: dict[str, dict[str, int]] = {"pointer": {}, "static": {}}  # at close
        if config.get("log_path"):
            try:
                keys = ("log_path", "metadata", "wall_start_ns", "loop_cpu", "tick_period_ns")
                log_config = {k: config[k] for k in keys}
                log_config["view_board"] = config.get("view_board")
                self._logger = LogProcess(self._shm.name, self.block, log_config, wait=False)
            except BaseException:
                self._release()
                raise
        self._config = config
        self._view: ViewProcess | None = None
        ctx = mp.get_context("spawn")
        self._proc = ctx.Process(
            target=_sidecar_main, args=(self._shm.name, config, os.getpid()),
            name="haptic-io", daemon=False,
        )  # fmt: skip
        self._proc.start()

    def wait_ready(self, timeout_s: float = 120.0) -> None:
        """Return once the sidecar has opened its session and the writer its file (then the
        live view is started, if asked for: it never delays a start); raise if either did
        not start (the caller closes, as on every exit path)."""
        end = time.monotonic() + timeout_s
        while self.block.ctl[C_READY] == 0:
            if not self._proc.is_alive() or time.monotonic() > end:
                raise RuntimeError("the haptic I/O process did not start")
            time.sleep(0.01)
        if self._logger is not None:
            self._logger.wait_ready(max(end - time.monotonic(), 1.0))
        config = self._config
        if config.get("view"):
            view_config = {**config["view"], "loop_cpu": config.get("loop_cpu"),
                           "view_board": config["view_board"]}  # fmt: skip
            self._view = ViewProcess(self._shm.name, view_config)

    def take_updates(
        self, engine: HapticEngine, tick: int, budget: int
    ) -> tuple[int, int, int, float]:
        """Validate and install up to `budget` waiting updates into `engine`, oldest first:
        one numba call, and the engine's Python side only for an install that needs it.
        Returns (taken, installed, seq of the newest install, its publish -> now latency
        in s)."""
        b = self.block
        taken_all = installed_all = 0
        newest_seq, newest_latency_s = -1, 0.0
        while budget > 0:
            taken, installed, follow, seq, latency_s = take_updates(
                b.ctl, b.mailbox, tick, time.time_ns(), budget, engine.loop_recs
            )  # fmt: skip
            taken_all += taken
            installed_all += installed
            if installed:
                newest_seq, newest_latency_s = seq, latency_s
            if not follow:
                break
            engine.installed()  # re-initialise, FOH: then go on with what still waits
            budget -= taken
        return taken_all, installed_all, newest_seq, newest_latency_s

    def lower_io_priority(self) -> None:
        """Ask the sidecar to yield the CPU to the loop (when the loop is not real-time)."""
        self.block.ctl[C_LOWER_IO] = 1

    def event(self, tick: int, kind: str, detail: str) -> None:
        """A rare event (watchdog, stop): text into the event ring."""
        self.block.post_event(tick, kind, detail)

    @property
    def log_failure(self) -> str:
        """Why the log writer stopped ("" while it writes, or without a log)."""
        return self.block.log_failure

    def io_state(self, now_ns: int, stall_ns: int) -> str:
        """ "lost" if the sidecar process has died, "stalled" if it has not woken for
        `stall_ns` (starved of CPU, stopped), else "" (a waitpid: call it rarely)."""
        if not self._proc.is_alive():
            return "lost"
        return "stalled" if now_ns - int(self.block.ctl[C_IO_BEAT]) > stall_ns else ""

    @property
    def ticks_logged(self) -> int:
        return int(self.block.ctl[C_TICK_LOGGED])

    @property
    def counters(self) -> dict[str, int]:
        c = self.block.ctl
        return {
            "lost_log_ticks": int(c[C_TICK_LOST]),
            "lost_updates": int(c[C_UPD_LOST]),
            "lost_events": int(c[C_EVT_LOST]),
            "proxy_published": int(c[C_PUBLISHED]),
            "updates_arrived": int(c[C_RECEIVED]),
            "pointer_received": int(c[C_PTR_RECEIVED]),
            "pointer_rejected": int(c[C_PTR_REJECTED]),
            "static_received": int(c[C_STATIC_OK]),
            "static_refused": int(c[C_STATIC_BAD]),
        }

    @property
    def refused_by_reason(self) -> dict[str, dict[str, int]]:
        """The pointer inputs and static messages refused, by reason (those that happened)."""
        c = self.block.ctl
        return {
            "pointer": by_reason(c, POINTER_REASONS, C_PTR_REASONS),
            "static": by_reason(c, STATIC_REASONS, C_STATIC_REASONS),
        }

    def close(self, timeout_s: float = 30.0) -> dict[str, int]:
        """Stop the sidecar and the log writer (it writes what remains); returns the
        counters."""
        self.block.ctl[C_CLOSED] = 1
        self._proc.join(timeout_s)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(5.0)
        if self._logger is not None:
            self._logger.join(timeout_s)
        if self._view is not None:
            self._view.join(VIEW_CLOSE_S)
        counters = self.counters
        self.refused = self.refused_by_reason  # read before the block is released
        self._release()
        return counters

    def _release(self) -> None:
        if self.board is not None:
            self.board.close()
        self.block.release()
        self._shm.close()
        self._shm.unlink()


# --- the sidecar process ----------------------------------------------------------------


def _sidecar_main(shm_name: str, config: dict[str, Any], parent_pid: int) -> None:
    """Zenoh in and out until the loop closes the block or dies."""
    import signal

    import zenoh

    from haptic_local_model.shared.memory import FloodTrim
    from haptic_local_model.shared.net.config import EndpointSpec
    from haptic_local_model.shared.net.transport import keys, open_session
    from haptic_local_model.shared.protocol.proxy import encode_proxy

    # the loop decides when I/O ends: a Ctrl-C to the process group is ignored; SIGTERM (the
    # loop's close() after a timeout, or anyone's kill) closes the session and exits
    terminated = threading.Event()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, lambda *_: terminated.set())
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    # before Zenoh starts its threads: they inherit both
    avoid_cpu(config.get("loop_cpu"))
    realtime = try_realtime_priority(IO_PRIORITY)
    shm = shared_memory.SharedMemory(name=shm_name)
    block = SharedBlock(shm)
    ctl = block.ctl
    int(
        np.ndarray((shm.size,), np.uint8, shm.buf)[::4096].sum()
    )  # map every page now, not while logging
    k = keys(config["namespace"])
    session = open_session(
        EndpointSpec(**config["endpoints"]), config.get("zenoh_extra"), config["namespace"]
    )
    publisher = session.declare_publisher(
        k.proxy, congestion_control=zenoh.CongestionControl.DROP, express=True
    )

    logging = bool(config.get("log_path"))  # a slot is reused only once the writer has it

    def receive(sample: Any) -> None:
        """Subscriber callback (a Zenoh thread of this process): the update into the mailbox."""
        ctl[C_RECEIVED] += 1
        if not block.post_update(sample.payload.to_bytes(), time.time_ns(), logging):
            ctl[C_UPD_LOST] += 1  # the loop (or the writer) is not reading: stopped or dead

    subscriber = session.declare_subscriber(k.update, receive)
    skew_ns = int(config.get("clock_skew_ns", 0))
    pointer_sub = (
        session.declare_subscriber(k.pointer, _pointer_receiver(block, skew_ns))
        if config.get("pointer")
        else None
    )
    static_sub = (
        session.declare_subscriber(k.static, _static_receiver(block, int(config["static_id"])))
        if int(config.get("static_id", -1)) >= 0
        else None
    )
    view = ViewSubscription(session, k.view, block, config.get("view_board"))
    alive_sub = session.liveliness().declare_subscriber(
        f"{k.alive}/*", SimLiveliness(block).receive, history=True
    )
    publish_period = 1.0 / float(config["proxy_publish_hz"])
    method = int(config["method"])
    tick_period_ns = int(config["tick_period_ns"])
    waits_scanned, wait = 0, NO_WAIT
    last_published_tick = -1
    impulses_from = 0  # the ring's count of ticks whose impulses are published
    next_publish = time.monotonic()
    lowered = False
    # a full collection of everything imported so far holds the GIL for up to ~50 ms, and
    # the Zenoh thread that receives an update waits for it (measured: update age max 52 ms
    # -> 5 ms): keep it out of the collector's sight
    gc.collect()
    gc.freeze()
    ctl[C_IO_BEAT] = time.monotonic_ns()
    ctl[C_READY] = 1
    log_failure_told = False
    trim = FloodTrim()  # a flood's memory back to the system after it

    def received() -> int:
        """Every message taken, refused or lost, on every key."""
        return int(ctl[C_UPD_HEAD] + ctl[C_UPD_LOST] + ctl[C_PTR_RECEIVED] + ctl[C_PTR_REJECTED]
                   + ctl[C_STATIC_OK] + ctl[C_STATIC_BAD])  # fmt: skip

    try:
        while True:
            ctl[C_IO_BEAT] = time.monotonic_ns()  # the loop watches it (HapticServer)
            closing = ctl[C_CLOSED] == 1 or os.getppid() != parent_pid or terminated.is_set()
            if ctl[C_LOG_FAILED] and ctl[C_LOG_READY] and not log_failure_told:
                log_failure_told = True  # the I/O process says so: the loop does no I/O
                _tell_log_failure(block)
            if ctl[C_LOWER_IO] == 1 and not lowered and not realtime:
                _lower_priority()
                lowered = True
            head = int(ctl[C_TICK_HEAD])
            now = time.monotonic()
            if head > 0 and now >= next_publish:
                newest = block.ticks[(head - 1) % RING_TICKS : (head - 1) % RING_TICKS + 1]
                if int(newest["update_seq"][0]) < 0:
                    impulses_from = head  # no model yet: nothing rendered to push with
                elif int(newest["tick"][0]) != last_published_tick:
                    waits_scanned, wait = newest_wait(block, waits_scanned, wait, tick_period_ns)
                    impulses = ticks_impulses(block, impulses_from, head, method)
                    impulses_from = head
                    publisher.put(encode_proxy(newest, method, wait=wait, impulses=impulses))
                    ctl[C_PUBLISHED] += 1
                    last_published_tick = int(newest["tick"][0])
                next_publish = now + publish_period
            trim.after(now, received)
            if closing:
                break
            time.sleep(max(0.0005, min(next_publish - time.monotonic(), IO_POLL_S)))
    finally:
        subscriber.undeclare()
        if pointer_sub is not None:
            pointer_sub.undeclare()
        if static_sub is not None:
            static_sub.undeclare()
        view.close()
        alive_sub.undeclare()
        session.close()
        block.release()
        shm.close()


def ticks_impulses(block: SharedBlock, start: int, head: int, method: int) -> ShapeImpulses:
    """The god-object's impulses on shapes over the ring's ticks start .. head - 1 (those
    still in the ring), for the proxy state (DESIGN-WAVE2 C4); none under other methods."""
    if method != Method.GOD_OBJECT or head <= start:
        return ShapeImpulses.none()
    # the loop writes slot head % RING_TICKS next: keep clear of the oldest slots
    rows = block.ticks[np.arange(max(start, head - RING_TICKS + RING_MARGIN), head) % RING_TICKS]
    return ShapeImpulses.of_ticks(
        rows["god_env_key"], rows["god_env_arm"], rows["god_env_force"], rows["dt"]
    )


class Refusals:
    """Refused messages of one kind counted by reason in fixed shared counters (the summary's
    `<kind>_rejected_by_reason`), and told in the event ring at most once per reason every
    EVENT_PERIOD_S, with how many of that reason went untold since: a flood of any size costs
    no memory and cannot push a safety event (watchdog, fault, safe) out of the ring."""

    EVENT_PERIOD_S = 1.0

    def __init__(self, block: SharedBlock, kind: str, reasons: tuple[str, ...], at: int) -> None:
        self.block, self.kind, self.at = block, kind, at
        self.index = {r: i for i, r in enumerate(reasons)}
        self.next_ns = [0] * len(reasons)
        self.untold = [0] * len(reasons)

    def refuse(self, reason: str, detail: str) -> None:
        """Count one refusal of `reason` (one of the kind's reasons) and tell it if due."""
        i = self.index[reason]
        ctl = self.block.ctl
        ctl[self.at + i] += 1
        now = time.monotonic_ns()
        if now < self.next_ns[i]:
            self.untold[i] += 1
            return
        more = f" (and {self.untold[i]} more since the last told)" if self.untold[i] else ""
        self.block.post_event(int(ctl[C_TICK_HEAD]), self.kind, f"{reason}: {detail}{more}")
        self.untold[i] = 0
        self.next_ns[i] = now + int(self.EVENT_PERIOD_S * 1e9)


def by_reason(ctl: np.ndarray, reasons: tuple[str, ...], at: int) -> dict[str, int]:
    """The refusals counted by Refusals, those that happened."""
    return {r: int(ctl[at + i]) for i, r in enumerate(reasons) if ctl[at + i]}


def _pointer_receiver(block: SharedBlock, skew_ns: int) -> Any:
    """The subscriber callback for pointer inputs: a valid one, stamped at most
    MAX_POINTER_AGE_NS behind this clock and at most `skew_ns` ahead of it (the clock skew
    the network allows), and newer than the last (by its publish time, so a restarted
    `haptic-pointer` is taken at once), becomes the user's target; anything else is refused
    and counted by reason, never installed. The last taken stamp is remembered as at most
    this clock's time then, so one input stamped ahead cannot lock out the next ones."""
    from haptic_local_model.shared.protocol.pointer import MAX_POINTER_AGE_NS, decode_pointer
    from haptic_local_model.shared.protocol.update import MessageError

    ctl = block.ctl
    refusals = Refusals(block, "pointer", POINTER_REASONS, C_PTR_REASONS)
    newest = [-(2**63)]

    def receive(sample: Any) -> None:
        ctl[C_PTR_RECEIVED] += 1
        try:
            pointer = decode_pointer(sample.payload.to_bytes())
        except MessageError as exc:
            ctl[C_PTR_REJECTED] += 1
            refusals.refuse(exc.reason, str(exc))
            return
        stamp, now = pointer.publish_time_ns, time.time_ns()
        reason = ""
        if stamp > now + skew_ns:
            reason = "future"
        elif stamp < now - MAX_POINTER_AGE_NS:
            reason = "late"
        elif stamp <= newest[0]:
            reason = "repeated"
        if reason:
            ctl[C_PTR_REJECTED] += 1
            refusals.refuse(reason, f"stamped {(stamp - now) / 1e6:+.1f} ms from this clock")
            return
        newest[0] = min(stamp, now)
        block.post_pointer(pointer.target)

    return receive


class SimLiveliness:
    """The sims' liveliness tokens (`<ns>/alive/sim/<epoch>`, declared by `sim-server` on its
    session): while one is alive, the earliest declared of them owns the namespace and only
    its epoch installs (Reason.UNBOUND); when its session ends or loses us (Zenoh drops the
    token), the next one alive, or none, and then any epoch may begin after the watchdog.
    A second authenticated sim cannot take over a sim that stalled past the watchdog but
    lives. At most MAX_TOKENS are remembered (a flood of tokens costs nothing more)."""

    MAX_TOKENS = 16

    def __init__(self, block: SharedBlock) -> None:
        self.block = block
        self.alive: dict[int, int] = {}  # epoch -> the order it was declared in
        self.declared = 0

    def receive(self, sample: Any) -> None:
        from zenoh import SampleKind  # the loop's process never imports Zenoh

        tail = str(sample.key_expr).rsplit("/", 1)[-1]
        if not (tail.isdigit() and 0 < int(tail) < 2**63):
            return  # not an epoch: nothing a sim declares
        epoch = int(tail)
        if sample.kind == SampleKind.DELETE:
            self.alive.pop(epoch, None)
        elif epoch not in self.alive and len(self.alive) < self.MAX_TOKENS:
            self.alive[epoch] = self.declared
            self.declared += 1
        ctl = self.block.ctl
        owner = min(self.alive, key=self.alive.__getitem__) if self.alive else 0
        if owner != int(ctl[C_SIM_OWNER]) or (owner != 0) != bool(ctl[C_SIM_BOUND]):
            # plain aligned int64 stores, in program order (x86-64 keeps it; the loop reads
            # with load_acquire): no compiled call in a Zenoh thread, which on a cold cache
            # would compile there
            ctl[C_SIM_BOUND] = 0  # no owner while it changes
            ctl[C_SIM_OWNER] = owner
            ctl[C_SIM_BOUND] = 1 if owner else 0


def _static_receiver(block: SharedBlock, static_id: int) -> Any:
    """Subscriber callback for the sim's static message (shared/protocol/static.py): one of
    this scene's train is counted; any other, or a malformed one, is refused and counted by
    reason (Refusals: told at most once a second per reason, whatever the flood); the loop
    installs no update of another train (Reason.STATIC)."""
    from haptic_local_model.shared.protocol.static import decode_static
    from haptic_local_model.shared.protocol.update import MessageError

    ctl = block.ctl
    refusals = Refusals(block, "static", STATIC_REASONS, C_STATIC_REASONS)

    def receive(sample: Any) -> None:
        try:
            sid, _ = decode_static(sample.payload.to_bytes())
            reason, problem = ("", "") if sid == static_id else (
                "foreign", f"the sim's train {sid} is not this scene's {static_id}"
            )  # fmt: skip
        except MessageError as exc:
            reason, problem = "malformed", f"a malformed static message: {exc}"
        except Exception as exc:  # a hostile payload (JSON nested past the stack)
            reason, problem = "hostile", f"a malformed static message: {type(exc).__name__}"
        if not reason:
            ctl[C_STATIC_OK] += 1
            return
        ctl[C_STATIC_BAD] += 1
        refusals.refuse(reason, problem)

    return receive


class ViewSubscription:
    """The sim's world (`<ns>/view/world`) onto the view board, subscribed only with a view
    (the sim sends the world only while someone subscribes). The callback copies the bytes,
    filed under the loop's newest tick; the view and the log writer check them, never here."""

    def __init__(self, session: Any, key: str, block: SharedBlock, board: str | None) -> None:
        # spawned by multiprocessing: the parent's resource tracker is this process's too
        self.board = ViewBoard.attach(board, own_tracker=False) if board else None
        self.ctl = block.ctl
        self.sub = session.declare_subscriber(key, self.receive) if self.board else None

    def receive(self, sample: Any) -> None:
        if self.board is not None:
            self.board.post(sample.payload.to_bytes(), int(self.ctl[C_TICK_HEAD]))

    def close(self) -> None:
        if self.sub is not None:
            self.sub.undeclare()
        if self.board is not None:
            self.board.close()


def _tell_log_failure(block: SharedBlock) -> None:
    """The log writer has stopped (a full disk, an I/O error): one event line for haptic-run
    and people, into the event ring for the live view. Rendering and networking go on. Not
    for a writer that failed before it opened its file (C_LOG_READY 0): logging never
    started, and the loop refuses to start (LoopIO.wait_ready) and says why."""
    from haptic_local_model.shared.cli import emit

    reason = block.log_failure
    head = int(block.ctl[C_TICK_HEAD])
    block.post_event(head, "log_failed", reason)
    print(f"haptic-server: logging stopped ({reason}); rendering goes on", file=sys.stderr)
    emit("log_failed", process="haptic", reason=reason)


def _lower_priority() -> None:
    """Nice every thread of this process (Linux nice is per thread): a loop without real-time
    priority then gets the CPU first. A SCHED_FIFO loop preempts us anyway, and a niced
    sidecar starved by other work on a busy machine delays updates and loses log ticks."""
    for tid in os.listdir("/proc/self/task"):
        with contextlib.suppress(OSError):  # the thread ended meanwhile
            os.setpriority(os.PRIO_PROCESS, int(tid), IO_NICENESS)


def newest_wait(
    block: SharedBlock, scanned: int, wait: UpdateWait, tick_period_ns: int
) -> tuple[int, UpdateWait]:
    """The receipt -> install wait of the newest update the loop installed, from the mailbox
    slots it has read since `scanned` (the sim times its steps by it: sim_server/pacing.py).
    Returns the new scan mark and the wait (`wait` if none was installed since)."""
    read = int(block.ctl[C_UPD_READ])
    for i in range(max(scanned, read - MAILBOX_SLOTS), read):
        slot = i % MAILBOX_SLOTS
        if int(block.update_verdict[slot]) != 0:
            continue
        raw = block.updates[slot, : AT_SEQ + 8].tobytes()
        wait_ns = int(block.update_install_ns[slot]) - int(block.update_recv_ns[slot])
        seq = int(struct.unpack_from("<Q", raw, AT_SEQ)[0])
        if seq >= 2**63:  # valid on the wire, but beyond the proxy's signed field
            continue
        wait = UpdateWait(seq, min(max(wait_ns, 0), MAX_WAIT_NS), tick_period_ns)
    return read, wait

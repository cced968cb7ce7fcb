"""All of the haptic server's I/O in a sidecar process, so the 1 kHz loop does none.

The loop and the sidecar share one block of memory:
- the **update mailbox**: the sidecar's Zenoh subscriber thread copies each received
  LocalModelUpdate into the next slot; the loop validates and installs it in place (one
  numba call) and writes its verdict next to it;
- the **tick ring**: the loop copies each tick record in (one numba call);
- the **event ring**: watchdog trips and other events, as short text.
The sidecar publishes the proxy state (read from the newest tick record) at
`proxy_publish_hz`, and writes ticks, updates (with their verdicts) and events to MCAP. It
runs no Python code in the loop's process, so it never competes for the loop's GIL; if the
loop dies, even by SIGKILL, the sidecar notices, drains what is there and closes the log.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import struct
import threading
import time
from multiprocessing import shared_memory
from typing import TYPE_CHECKING, Any

import numpy as np
from numba import njit

from haptic_server.model import TICK_DTYPE
from haptic_server.stages.install import accept_update
from shared.protocol.layout import PUBLISH_TIME_AT, PUBLISH_TIME_END
from shared.protocol.update import publish_time_ns

if TYPE_CHECKING:
    from haptic_server.engine import HapticEngine

RING_TICKS = 16384  # 16 s of ticks at 1 kHz: the writer may stall this long without loss
MAILBOX_SLOTS = 256  # updates waiting for the loop or the log writer (about 4 s at 60 Hz)
SLOT_BYTES = 16384  # >= the largest valid update (12 DOF, 64 contacts: about 9 KB)
EVENT_SLOTS = 256
EVENT_BYTES = 256
VERDICT_PENDING = -1
IO_POLL_S = 0.004  # the sidecar wakes at least this often (and for each proxy publish)
IO_NICENESS = 10  # only when the loop could not get real-time priority (see _lower_priority)

# control words
C_READY, C_CLOSED, C_TICK_HEAD, C_TICK_LOST, C_UPD_HEAD, C_UPD_READ = 0, 1, 2, 3, 4, 5
C_UPD_LOST, C_EVT_HEAD, C_EVT_LOST, C_PUBLISHED, C_RECEIVED = 6, 7, 8, 9, 10
C_UPD_LOGGED = 11  # updates the log writer has written (a slot is reused only after that)
C_LOWER_IO = 12  # set by the loop when it runs without real-time priority
N_CTL = 16

#: One mailbox slot: a received update's bytes and what the loop made of it.
MAILBOX_DTYPE = np.dtype(
    [
        ("length", np.int64),  # bytes received; negative: too long for the slot
        ("verdict", np.int64),  # VERDICT_PENDING, 0 installed, else the reason code
        ("tick", np.int64),  # the tick it was taken at
        ("recv_ns", np.int64),  # wall clock when the sidecar received it
        ("latency_s", np.float64),  # publish -> install, as installed
        ("raw", np.uint8, (SLOT_BYTES,)),  # 8-byte aligned: the parser reads floats in place
    ]
)


class SharedBlock:
    """The layout of the shared memory (both sides map the same named segment)."""

    def __init__(self, shm: shared_memory.SharedMemory) -> None:
        self.shm = shm
        buf = shm.buf
        o = 0
        self.ctl = np.ndarray((N_CTL,), np.int64, buf, o)
        o += 8 * N_CTL
        self.ticks = np.ndarray((RING_TICKS,), TICK_DTYPE, buf, o)
        o += RING_TICKS * TICK_DTYPE.itemsize
        o = (o + 7) // 8 * 8
        self.mailbox = np.ndarray((MAILBOX_SLOTS,), MAILBOX_DTYPE, buf, o)
        o += MAILBOX_SLOTS * MAILBOX_DTYPE.itemsize
        # the mailbox's columns, for the sidecar's Python side
        self.update_len = self.mailbox["length"]
        self.update_verdict = self.mailbox["verdict"]
        self.update_tick = self.mailbox["tick"]
        self.update_recv_ns = self.mailbox["recv_ns"]
        self.update_latency_s = self.mailbox["latency_s"]
        self.updates = self.mailbox["raw"]
        self.events = np.ndarray((EVENT_SLOTS, EVENT_BYTES), np.uint8, buf, o)
        o += EVENT_SLOTS * EVENT_BYTES
        self.size = o

    @staticmethod
    def nbytes() -> int:
        return (
            8 * N_CTL
            + (RING_TICKS * TICK_DTYPE.itemsize + 7) // 8 * 8
            + MAILBOX_SLOTS * MAILBOX_DTYPE.itemsize
            + EVENT_SLOTS * EVENT_BYTES
        )

    def post_update(self, raw: bytes, recv_ns: int, logging: bool) -> bool:
        """Put a received message into the next mailbox slot, as the sidecar's Zenoh thread
        does; False (nothing written) if no slot is free: the loop has not read them, or,
        with `logging`, the log writer has not written them. A message longer than a slot
        is marked by a negative length (the loop rejects it as too large)."""
        ctl = self.ctl
        head = int(ctl[C_UPD_HEAD])
        done = int(ctl[C_UPD_READ])
        if logging:
            done = min(done, int(ctl[C_UPD_LOGGED]))
        if head - done >= MAILBOX_SLOTS:
            return False
        slot = head % MAILBOX_SLOTS
        n = min(len(raw), SLOT_BYTES)
        self.updates[slot, :n] = np.frombuffer(raw, np.uint8, n)
        self.update_len[slot] = len(raw) if len(raw) <= SLOT_BYTES else -len(raw)
        self.update_verdict[slot] = VERDICT_PENDING
        self.update_recv_ns[slot] = recv_ns
        ctl[C_UPD_HEAD] = head + 1
        return True

    def release(self) -> None:
        for name in (
            "ctl", "ticks", "mailbox", "update_len", "update_verdict", "update_tick",
            "update_recv_ns", "update_latency_s", "updates", "events",
        ):  # fmt: skip
            setattr(self, name, None)


@njit(cache=True)
def push_row(ring, ctl, row, lateness, work, peaks):
    """Copy the row into the ring slot of the head, then publish the new head. Also keep
    the loop's timing windows: the row's lateness, and its work (that of the tick before,
    the newest known when the row is made), with their peaks in peaks[0], peaks[1]."""
    head = ctl[C_TICK_HEAD]
    r = row[0]
    ring[head % ring.shape[0]] = r
    ctl[C_TICK_HEAD] = head + 1
    lateness[head % lateness.shape[0]] = r.lateness_us
    peaks[0] = max(peaks[0], r.lateness_us)
    if head > 0:
        work[(head - 1) % work.shape[0]] = r.work_us
        peaks[1] = max(peaks[1], r.work_us)


MAX_LATENCY_S = 1.0  # publish -> install is clamped to [0, this] (a clock step between hosts)


@njit(cache=True)
def take_updates(ctl, mailbox, tick, now_ns, budget, model, data, install):
    """Validate and install the updates waiting in the mailbox, oldest first, in one call.

    Takes up to `budget` updates, and stops after an install that needs the engine's Python
    side (a new epoch, or install.follow: after the watchdog, or FOH setpoints). Each verdict
    (0 installed, else the reason code, counted in install.reject_counts), the tick and the
    publish -> now latency it was installed with go next to its update in the mailbox (the
    log writer logs them, so a replay is exact); only then is the update marked read (the
    writer and the Zenoh thread read the mark). Returns (taken, installed, follow-up
    needed, seq of the newest install, its latency in s).
    """
    ins = install[0]
    taken = 0
    installed = 0
    follow = 0
    seq = np.int64(-1)
    newest_latency = 0.0
    while taken < budget:
        read = ctl[C_UPD_READ]
        if read >= ctl[C_UPD_HEAD]:
            break
        slot = mailbox[read % mailbox.shape[0]]
        n = slot.length
        latency = 0.0
        if n >= PUBLISH_TIME_END:
            latency = min(max((now_ns - publish_time_ns(slot.raw)) / 1e9, 0.0), MAX_LATENCY_S)
        code = accept_update(slot.raw, n, latency, model, data, install)
        if code != 0:
            ins.reject_counts[code] += 1
        slot.tick = tick
        slot.latency_s = latency
        slot.verdict = code
        ctl[C_UPD_READ] = read + 1
        taken += 1
        if code == 0:
            installed += 1
            seq = ins.seq
            newest_latency = latency
            if ins.new_epoch == 1 or ins.follow == 1:
                follow = 1
                break
    return taken, installed, follow, seq, newest_latency


def compile_loop_kernels(engine: HapticEngine) -> None:
    """Compile (or load from the cache) the loop's ring and mailbox kernels for `engine`'s
    records, before the loop starts: a message too short to parse, into scratch counts."""
    ctl = np.zeros(N_CTL, np.int64)
    push_row(np.zeros(2, TICK_DTYPE), ctl, engine.row, np.zeros(2), np.zeros(2), np.zeros(2))
    ctl[C_UPD_HEAD] = 1
    mailbox = np.zeros(1, MAILBOX_DTYPE)
    mailbox[0]["length"] = 8
    install = engine.install.copy()
    take_updates(ctl, mailbox, 0, 0, 1, engine.model.copy(), engine.data.copy(), install)


class LoopIO:
    """The loop's side: take updates, give verdicts, push ticks and events. No syscalls."""

    def __init__(self, config: dict[str, Any], ready_timeout_s: float = 120.0) -> None:
        self._shm = shared_memory.SharedMemory(create=True, size=SharedBlock.nbytes())
        self.block = SharedBlock(self._shm)
        # touch every page now, so the loop's memory stays flat while the ring fills
        np.ndarray((self._shm.size,), np.uint8, self._shm.buf)[:] = 0
        self.block.ctl[:] = 0
        self.block.update_verdict[:] = VERDICT_PENDING
        ctx = mp.get_context("spawn")
        self._proc = ctx.Process(
            target=_sidecar_main, args=(self._shm.name, config, os.getpid()),
            name="haptic-io", daemon=False,
        )  # fmt: skip
        self._proc.start()
        end = time.monotonic() + ready_timeout_s
        while self.block.ctl[C_READY] == 0:
            if not self._proc.is_alive() or time.monotonic() > end:
                self.close()
                raise RuntimeError("the haptic I/O process did not start")
            time.sleep(0.01)

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
                b.ctl, b.mailbox, tick, time.time_ns(), budget, engine.model, engine.data,
                engine.install,
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
        """A rare event (watchdog, stop): text into the event ring, dropped if full."""
        ctl = self.block.ctl
        head = int(ctl[C_EVT_HEAD])
        data = f"{tick}\t{kind}\t{detail}".encode()[: EVENT_BYTES - 1]
        slot = self.block.events[head % EVENT_SLOTS]
        slot[: len(data)] = np.frombuffer(data, np.uint8)
        slot[len(data)] = 0
        ctl[C_EVT_HEAD] = head + 1

    @property
    def counters(self) -> dict[str, int]:
        c = self.block.ctl
        return {
            "lost_log_ticks": int(c[C_TICK_LOST]),
            "lost_updates": int(c[C_UPD_LOST]),
            "proxy_published": int(c[C_PUBLISHED]),
            "updates_arrived": int(c[C_RECEIVED]),
        }

    def close(self, timeout_s: float = 30.0) -> dict[str, int]:
        """Stop the sidecar (it finishes the log); returns its counters."""
        self.block.ctl[C_CLOSED] = 1
        self._proc.join(timeout_s)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(5.0)
        counters = self.counters
        self.block.release()
        self._shm.close()
        self._shm.unlink()
        return counters


# --- the sidecar process ----------------------------------------------------------------


def _sidecar_main(shm_name: str, config: dict[str, Any], parent_pid: int) -> None:
    """Zenoh in and out, MCAP out, until the loop closes the block or dies."""
    import signal

    import zenoh

    from haptic_server.log import LogWriter, update_record
    from shared.net.config import EndpointSpec
    from shared.net.transport import keys, open_session
    from shared.protocol.codes import reason_tag as reason_of
    from shared.protocol.proxy import encode_proxy

    # the loop decides when I/O ends: a Ctrl-C to the process group is ignored; SIGTERM (the
    # loop's close() after a timeout, or anyone's kill) finishes the log and exits
    terminated = threading.Event()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, lambda *_: terminated.set())
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

    logging = bool(config.get("log_path"))

    def receive(sample: Any) -> None:
        """Subscriber callback (a Zenoh thread of this process): the update into the mailbox."""
        ctl[C_RECEIVED] += 1
        if not block.post_update(sample.payload.to_bytes(), time.time_ns(), logging):
            ctl[C_UPD_LOST] += 1  # the loop (or the writer) is not reading: stopped or dead

    subscriber = session.declare_subscriber(k.update, receive)
    log = LogWriter(config["log_path"], config["metadata"]) if config.get("log_path") else None
    wall_start_ns = int(config["wall_start_ns"])
    publish_period = 1.0 / float(config["proxy_publish_hz"])
    method = int(config["method"])
    tick_tail = 0
    upd_logged = 0
    evt_tail = 0
    last_published_tick = -1
    next_publish = time.monotonic()
    last_flush = time.monotonic()
    lowered = False
    ctl[C_READY] = 1
    try:
        while True:
            closing = ctl[C_CLOSED] == 1 or os.getppid() != parent_pid or terminated.is_set()
            if ctl[C_LOWER_IO] == 1 and not lowered:
                _lower_priority()
                lowered = True
            head = int(ctl[C_TICK_HEAD])
            now = time.monotonic()
            if head > 0 and now >= next_publish:
                newest = block.ticks[(head - 1) % RING_TICKS : (head - 1) % RING_TICKS + 1]
                if (
                    int(newest["tick"][0]) != last_published_tick
                    and int(newest["update_seq"][0]) >= 0
                ):
                    publisher.put(encode_proxy(newest, method))
                    ctl[C_PUBLISHED] += 1
                    last_published_tick = int(newest["tick"][0])
                next_publish = now + publish_period
            if log is not None:
                # `head` was read first: every update and event of a tick below it is already
                # in the mailbox / ring, and is written before that tick's row, so a file cut
                # anywhere holds all the updates of every complete tick it holds (replay).
                read = int(ctl[C_UPD_READ])
                evt_head = int(ctl[C_EVT_HEAD])
                while upd_logged < read:
                    slot = upd_logged % MAILBOX_SLOTS
                    n = int(block.update_len[slot])
                    code = int(block.update_verdict[slot])
                    raw = block.updates[slot, : min(abs(n), SLOT_BYTES)].tobytes()
                    recv_ns = int(block.update_recv_ns[slot])
                    age_ms = (recv_ns - _publish_time_ns(raw)) / 1e6
                    reason = "" if code == 0 else reason_of(code)
                    rec = update_record(
                        int(block.update_tick[slot]), raw, reason, age_ms,
                        float(block.update_latency_s[slot]), abs(n),
                    )  # fmt: skip
                    log.update(rec, recv_ns)
                    upd_logged += 1
                    ctl[C_UPD_LOGGED] = upd_logged
                while evt_tail < evt_head:
                    text = bytes(block.events[evt_tail % EVENT_SLOTS]).split(b"\0", 1)[0].decode()
                    tick_s, kind, detail = [*text.split("\t", 2), "", ""][:3]
                    log.event(int(tick_s or 0), kind, detail, time.time_ns())
                    evt_tail += 1
                if head - tick_tail > RING_TICKS:
                    ctl[C_TICK_LOST] += head - tick_tail - RING_TICKS
                    tick_tail = head - RING_TICKS
                while tick_tail < head:
                    row = block.ticks[tick_tail % RING_TICKS : tick_tail % RING_TICKS + 1]
                    log.tick(row.tobytes(), wall_start_ns + int(float(row["t"][0]) * 1e9))
                    tick_tail += 1
                if now - last_flush > 0.2:
                    log.flush()
                    last_flush = now
            if (closing and int(ctl[C_TICK_HEAD]) == tick_tail) or (closing and log is None):
                break
            time.sleep(max(0.0005, min(next_publish - time.monotonic(), IO_POLL_S)))
    finally:
        subscriber.undeclare()
        if log is not None:
            log.close()
        session.close()
        block.release()
        shm.close()


def _lower_priority() -> None:
    """Nice every thread of this process (Linux nice is per thread): a loop without real-time
    priority then gets the CPU first. A SCHED_FIFO loop preempts us anyway, and a niced
    sidecar starved by other work on a busy machine delays updates and loses log ticks."""
    for tid in os.listdir("/proc/self/task"):
        with contextlib.suppress(OSError):  # the thread ended meanwhile
            os.setpriority(os.PRIO_PROCESS, int(tid), IO_NICENESS)


def _publish_time_ns(raw: bytes) -> int:
    """The publish time in an update's header (0 if the message is too short to have one)."""
    return (
        int(struct.unpack_from("<q", raw, PUBLISH_TIME_AT)[0])
        if len(raw) >= PUBLISH_TIME_END
        else 0
    )

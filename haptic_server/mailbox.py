"""The block of shared memory between the real-time loop, its I/O sidecar and its log writer,
and the loop's kernels on it.

- the **update mailbox** (MAILBOX_DTYPE slots): the sidecar's Zenoh thread copies each
  received LocalModelUpdate into the next slot; the loop validates and installs it in place
  (`take_updates`, one numba call for every waiting update) and writes its verdict next to it;
- the **tick ring**: the loop copies each tick record in (`push_row`);
- the **event ring**: watchdog trips and other events, as short text;
- the control words `C_*` (heads, read marks, counters).
"""

from __future__ import annotations

import contextlib
import os
import secrets
from multiprocessing import resource_tracker, shared_memory
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numba import njit

from haptic_local_model.haptic_server.model import TICK_DTYPE
from haptic_local_model.haptic_server.stages.install import accept_update
from haptic_local_model.haptic_server.users import USER_DTYPE
from haptic_local_model.shared.atomics import load_acquire, store_release
from haptic_local_model.shared.protocol.layout import PUBLISH_TIME_END
from haptic_local_model.shared.protocol.update import MAX_UPDATE_BYTES, publish_time_ns

if TYPE_CHECKING:
    from haptic_local_model.haptic_server.engine import HapticEngine

RING_TICKS = 16384  # 16 s of ticks at 1 kHz: the writer may stall this long without loss
MAILBOX_SLOTS = 256  # updates waiting for the loop or the log writer (about 4 s at 60 Hz)
#: >= the largest valid update (12 DOF, 64 contacts, 64 shapes: about 26 KB), whole KiB
SLOT_BYTES = -(-MAX_UPDATE_BYTES // 1024) * 1024
EVENT_SLOTS = 256
EVENT_BYTES = 256
VERDICT_PENDING = -1

# control words
C_READY, C_CLOSED, C_TICK_HEAD, C_TICK_LOST, C_UPD_HEAD, C_UPD_READ = 0, 1, 2, 3, 4, 5
C_UPD_LOST, C_EVT_HEAD, C_EVT_LOST, C_PUBLISHED, C_RECEIVED = 6, 7, 8, 9, 10
C_UPD_LOGGED = 11  # updates the log writer has written (a slot is reused only after that)
C_LOWER_IO = 12  # set by the loop when it runs without real-time priority
C_TICK_LOGGED = 13  # tick rows the log writer has written (the virtual clock waits on it)
C_LOG_READY, C_LOG_FAILED = 14, 15  # the log writer has opened its file / has failed
C_LOG_DONE = 16  # the log writer has closed its file
C_IO_BEAT = 17  # the I/O sidecar's heartbeat: its monotonic clock (ns) at its last wake-up
C_PTR_RECEIVED, C_PTR_REJECTED = 18, 19  # pointer inputs received / refused by the sidecar
C_WALL_START = 20  # the wall clock (ns) at the real-time loop's start: tick t = 0
C_STATIC_OK, C_STATIC_BAD = 21, 22  # static messages of this scene's train / refused
#: the sim's liveliness (sidecar): 1 while a sim's token is alive, and that sim's epoch (the
#: earliest declared of those alive): while bound, only that epoch installs (Reason.UNBOUND)
C_SIM_BOUND = 23
#: refusals by reason, fixed counters (sidecar.Refusals): the pointer's, then the static's
POINTER_REASONS = ("size", "magic", "version", "nonfinite", "magnitude", "late", "future",
                   "repeated")  # fmt: skip
STATIC_REASONS = ("foreign", "malformed", "hostile")
C_PTR_REASONS = 24
C_STATIC_REASONS = C_PTR_REASONS + len(POINTER_REASONS)
C_SIM_OWNER = C_STATIC_REASONS + len(STATIC_REASONS)
N_CTL = C_SIM_OWNER + 1
ERROR_BYTES = 256  # the log writer's last error, as text

#: One mailbox slot: a received update's bytes and what the loop made of it.
MAILBOX_DTYPE = np.dtype(
    [
        ("length", np.int64),  # bytes received; negative: too long for the slot
        ("verdict", np.int64),  # VERDICT_PENDING, 0 installed, else the reason code
        ("tick", np.int64),  # the tick it was taken at
        ("recv_ns", np.int64),  # wall clock when the sidecar received it
        ("install_ns", np.int64),  # wall clock when the loop took it (its tick's start)
        ("latency_s", np.float64),  # its age when taken: install clock - publish time (s)
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
        self.update_install_ns = self.mailbox["install_ns"]
        self.update_latency_s = self.mailbox["latency_s"]
        self.updates = self.mailbox["raw"]
        self.events = np.ndarray((EVENT_SLOTS, EVENT_BYTES), np.uint8, buf, o)
        o += EVENT_SLOTS * EVENT_BYTES
        self.log_error = np.ndarray((ERROR_BYTES,), np.uint8, buf, o)
        o += ERROR_BYTES
        o = (o + 7) // 8 * 8
        # the simulated user, when it follows a pointer: the sidecar writes its targets
        self.user = np.ndarray((1,), USER_DTYPE, buf, o)
        o += USER_DTYPE.itemsize
        self.size = o

    @classmethod
    def create(cls) -> SharedBlock:
        """A new named segment, empty, with every page touched now (not one by one as the
        ring first fills: a page fault is a few microseconds in the loop or the feed). Its
        name carries this process's pid; segments of processes that died without removing
        theirs (a SIGKILL of the whole group) are removed first (`sweep_segments`)."""
        sweep_segments()
        name = f"{SEGMENT_PREFIX}{os.getpid()}-{secrets.token_hex(4)}"
        shm = shared_memory.SharedMemory(name=name, create=True, size=cls.nbytes())
        np.ndarray((shm.size,), np.uint8, shm.buf).fill(0)
        block = cls(shm)
        block.update_verdict[:] = VERDICT_PENDING
        return block

    @classmethod
    def attach(cls, name: str) -> SharedBlock:
        """The named segment another process created, mapped by a helper that must not remove
        it: Python < 3.13 registers every attach with this process's resource tracker, which
        would unlink the segment when this process exits (its creator unlinks it)."""
        shm = shared_memory.SharedMemory(name=name)
        resource_tracker.unregister(shm._name, "shared_memory")  # type: ignore[attr-defined]
        return cls(shm)

    def post_pointer(self, target: tuple[float, float, float]) -> None:
        """A pointer's new target for the user record (the sidecar's side): into the slot the
        loop is not reading, then the index flips to it (one aligned 8-byte store, after the
        target's; x86 keeps stores in order). See haptic_server.users on what a read sees."""
        u = self.user[0]
        slot = 1 - int(u["target_index"])
        u["targets"][slot] = target
        u["target_index"] = slot

    def post_event(self, tick: int, kind: str, detail: str) -> None:
        """A rare event (watchdog, stop) as text into the event ring (the oldest overwritten
        when its readers are behind: `skip_overwritten` counts them)."""
        head = int(self.ctl[C_EVT_HEAD])
        data = f"{tick}\t{kind}\t{detail}".encode()[: EVENT_BYTES - 1]
        slot = self.events[head % EVENT_SLOTS]
        slot[: len(data)] = np.frombuffer(data, np.uint8)
        slot[len(data)] = 0
        self.ctl[C_EVT_HEAD] = head + 1

    def skip_overwritten(self, tail: int, head: int) -> tuple[int, int]:
        """A reader at `tail` of the event ring whose head is `head`: (the events overwritten
        before it read them, the first one it can still read). The lost ones are counted in
        the block's C_EVT_LOST, so the summary says so."""
        lost = max(0, head - EVENT_SLOTS - tail)
        if lost:
            self.ctl[C_EVT_LOST] += lost
        return lost, tail + lost

    def event_at(self, i: int) -> tuple[int, str, str]:
        """Event `i` of the ring: (tick, kind, detail). The text may have been cut inside a
        character: what cannot be decoded is replaced."""
        text = bytes(self.events[i % EVENT_SLOTS]).split(b"\0", 1)[0].decode(errors="replace")
        tick, kind, detail = [*text.split("\t", 2), "", ""][:3]
        return int(tick or 0), kind, detail

    @staticmethod
    def nbytes() -> int:
        return (
            8 * N_CTL
            + (RING_TICKS * TICK_DTYPE.itemsize + 7) // 8 * 8
            + MAILBOX_SLOTS * MAILBOX_DTYPE.itemsize
            + EVENT_SLOTS * EVENT_BYTES
            + (ERROR_BYTES + 7) // 8 * 8
            + USER_DTYPE.itemsize
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

    def fail_log(self, error: str) -> None:
        """The log writer has stopped on `error`: its text for the loop's side, then the flag."""
        data = error.encode(errors="replace")[: ERROR_BYTES - 1]
        self.log_error[: len(data)] = np.frombuffer(data, np.uint8)
        self.log_error[len(data)] = 0
        self.ctl[C_LOG_FAILED] = 1

    @property
    def log_failure(self) -> str:
        """Why the log writer stopped ("" if it has not)."""
        if not self.ctl[C_LOG_FAILED]:
            return ""
        text = bytes(self.log_error).split(b"\0", 1)[0].decode(errors="replace")
        return text or "the log writer stopped"

    def release(self) -> None:
        for name in (
            "ctl", "ticks", "mailbox", "update_len", "update_verdict", "update_tick",
            "update_recv_ns", "update_install_ns", "update_latency_s", "updates", "events",
            "log_error",
        ):  # fmt: skip
            setattr(self, name, None)


SEGMENT_PREFIX = "haptic-"  # /dev/shm/haptic-<pid>-<random>: the creator's pid
SHM_DIR = Path("/dev/shm")


def sweep_segments(folder: Path = SHM_DIR) -> list[str]:
    """Remove the shared-memory segments of this project whose creating process is gone;
    returns their names. A segment of a live process (or of a pid reused since) is kept."""
    removed = []
    for path in folder.glob(f"{SEGMENT_PREFIX}*"):
        pid_text = path.name[len(SEGMENT_PREFIX) :].split("-", 1)[0]
        if not pid_text.isdigit():
            continue
        try:
            os.kill(int(pid_text), 0)
            continue  # alive (or another's process of that pid: not ours to judge)
        except ProcessLookupError:
            pass
        except PermissionError:
            continue
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
            removed.append(path.name)
    return removed


@njit(cache=True)
def push_row(ring, ctl, row, lateness, work, peaks):
    """Copy the row into the ring slot of the head, then publish the new head. Also keep
    the loop's timing windows: the row's lateness, and its work (that of the tick before,
    the newest known when the row is made), with their peaks in peaks[0], peaks[1]."""
    head = load_acquire(ctl, C_TICK_HEAD)
    r = row[0]
    ring[head % ring.shape[0]] = r
    store_release(ctl, C_TICK_HEAD, head + 1)  # the row is in before the sidecar sees it
    lateness[head % lateness.shape[0]] = r.lateness_us
    peaks[0] = max(peaks[0], r.lateness_us)
    if head > 0:
        work[(head - 1) % work.shape[0]] = r.work_us
        peaks[1] = max(peaks[1], r.work_us)


#: beyond this many ns between the clock and a publish time the age is only its sign (a
#: forged time may be anywhere in int64: their difference would wrap)
AGE_SPAN_NS = 1 << 61


@njit(cache=True)
def age_s(now_ns, published_ns):
    """The receiver's clock minus a publish time, in s, without int64 wrap-around: exact
    (the difference in ns) within AGE_SPAN_NS, else +-AGE_SPAN_NS (73 years) by sign."""
    if published_ns < now_ns - AGE_SPAN_NS:
        return AGE_SPAN_NS / 1e9
    if published_ns > now_ns + AGE_SPAN_NS:
        return -AGE_SPAN_NS / 1e9
    return (now_ns - published_ns) / 1e9


@njit(cache=True)
def take_updates(ctl, mailbox, tick, now_ns, budget, recs):
    """Validate and install the updates waiting in the mailbox, oldest first, in one call.

    Takes up to `budget` updates, and stops after an install that needs the engine's Python
    side (a new epoch, install.follow: after the watchdog, or FOH setpoints; a fault). Each verdict
    (0 installed, else the reason code, counted in install.reject_counts), the tick and the
    publish -> now latency it was installed with go next to its update in the mailbox (the
    log writer logs them, so a replay is exact); only then is the update marked read (the
    writer and the Zenoh thread read the mark). Returns (taken, installed, follow-up
    needed, seq of the newest install, its latency in s). recs is the engine's `loop_recs`
    (its step's records and its install record).
    """
    model, data, god, install = recs[0], recs[1], recs[5], recs[6]
    ins = install[0]
    ins.bound = load_acquire(ctl, C_SIM_BOUND)  # the sim's liveliness, as the sidecar saw it
    ins.owner = load_acquire(ctl, C_SIM_OWNER)
    taken = 0
    installed = 0
    follow = 0
    seq = np.int64(-1)
    newest_latency = 0.0
    while taken < budget:
        read = load_acquire(ctl, C_UPD_READ)
        if read >= load_acquire(ctl, C_UPD_HEAD):  # afresh: the sidecar writes it
            break
        slot = mailbox[read % mailbox.shape[0]]
        n = slot.length
        latency = 0.0
        if n >= PUBLISH_TIME_END:
            latency = age_s(now_ns, publish_time_ns(slot.raw))
        code = accept_update(slot.raw, n, latency, model, data, install, god)
        if code != 0:
            ins.reject_counts[code] += 1
        slot.tick = tick
        slot.install_ns = now_ns
        slot.latency_s = latency
        slot.verdict = code
        store_release(ctl, C_UPD_READ, read + 1)  # after the verdict: the writer reads both
        taken += 1
        if code == 0:
            installed += 1
            seq = ins.seq
            newest_latency = latency
            # a new epoch, a watchdog trip (install.follow) or a fault of the guard: the
            # engine's Python side re-initialises the proxy
            if ins.new_epoch == 1 or ins.follow == 1 or data[0].state.fault != 0:
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
    take_updates(ctl, mailbox, 0, 0, 1, engine.loop_recs_copy())

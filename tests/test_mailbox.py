"""The real-time server's mailbox path installs exactly what `HapticEngine.receive` installs.

The 1 kHz loop takes updates from the shared-memory mailbox with one numba call
(`mailbox.take_updates`: validate, order-check, install, verdict, counts) and runs the
engine's Python side only for installs that need it (a new epoch, after the watchdog, FOH
setpoints). Replay and the virtual clock go through `HapticEngine.receive` instead. Here
both paths get the same stream (the sim's own updates with garbage, truncated, oversize,
repeated, old-epoch and new-epoch messages mixed in, several per tick, and watchdog trips)
and must leave bit-identical engines, verdicts and books after every tick.
"""

from __future__ import annotations

import struct
import time
from multiprocessing import shared_memory
from typing import Any

import numpy as np
import pytest

from haptic_local_model.device_models.registry import load_device, load_simulated_device
from haptic_local_model.haptic_server.engine import HapticEngine
from haptic_local_model.haptic_server.harness.virtual import run_virtual
from haptic_local_model.haptic_server.mailbox import (
    C_EVT_HEAD,
    C_EVT_LOST,
    C_UPD_READ,
    EVENT_SLOTS,
    MAILBOX_SLOTS,
    SLOT_BYTES,
    SharedBlock,
)
from haptic_local_model.haptic_server.sidecar import LoopIO
from haptic_local_model.haptic_server.stages.install import DEFAULT_MAX_AGE_S
from haptic_local_model.shared.config import load_scene, load_user
from haptic_local_model.shared.protocol.codes import Reason
from haptic_local_model.shared.protocol.codes import reason_tag as reason_of

R_SIZE = Reason.SIZE


class MailboxOnly(LoopIO):
    """The loop's side of the I/O block without the sidecar: the test posts updates the way
    the sidecar's Zenoh thread does (`SharedBlock.post_update`)."""

    def __init__(self, block: SharedBlock) -> None:
        self.block = block

    def put(self, raw: bytes) -> None:
        assert self.block.post_update(raw, 0, logging=False)


@pytest.fixture
def mailbox() -> Any:
    shm = shared_memory.SharedMemory(create=True, size=SharedBlock.nbytes())
    block = SharedBlock(shm)
    block.ctl[:] = 0
    try:
        yield MailboxOnly(block)
    finally:
        block.release()
        shm.close()
        shm.unlink()


def sim_updates(scene: str, user: str, seconds: float) -> list[bytes]:
    """The sim's own updates of a virtual run, as sent."""
    captured: list[bytes] = []
    receive = HapticEngine.receive

    def capture(self: HapticEngine, raw: bytes, latency_s: float = 0.0) -> str:
        captured.append(raw)
        return receive(self, raw, latency_s)

    HapticEngine.receive = capture  # type: ignore[method-assign]
    try:
        run_virtual(load_scene(scene), load_simulated_device("ideal"), load_user(user), seconds)
    finally:
        HapticEngine.receive = receive  # type: ignore[method-assign]
    return captured


def restamp(raw: bytes, epoch: int, seq: int, published_ns: int) -> bytes:
    out = bytearray(raw)
    struct.pack_into("<QQ", out, 8, epoch, seq)
    struct.pack_into("<q", out, 32, published_ns)
    return bytes(out)


def engine_state(e: HapticEngine) -> tuple[Any, ...]:
    c = e.counters
    return (
        e.slots.tobytes(), e.state.tobytes(), e.world_map.tobytes(), e.ready, e.stale,
        c.installed, c.rejected_by_reason, c.epochs, c.reinitialisations,
        e.epoch, e.last_seq,
    )  # fmt: skip


@pytest.mark.parametrize(
    ("scene", "user"),
    [("testbed", "swing"), ("maglev_scoop", "scoop")],  # local model; FOH virtual coupling
)
def test_mailbox_path_matches_receive(mailbox: MailboxOnly, scene: str, user: str) -> None:
    rng = np.random.default_rng(7)
    pool = sim_updates(scene, user, 1.5)
    engines = [
        HapticEngine(load_scene(scene), load_device("ideal"), load_user(user)) for _ in range(2)
    ]
    by_receive, by_mailbox = engines
    epoch, seq, k = time.time_ns() - 10**9, 0, 0  # the sim's start time, as a sim's epoch
    verdicts_seen: dict[str, int] = {}
    for tick in range(900):
        now = time.time_ns()  # the mailbox takes them at its own clock: a few us later
        batch: list[tuple[bytes, int | None]] = []
        if tick == 640:  # a restarted sim, as the watchdog fires (below)
            epoch, seq = epoch + 10**9, 0
            batch.append((restamp(pool[k % len(pool)], epoch, seq, now), None))
        elif tick % 17 == 0 or rng.random() < 0.02:  # the sim's rate, and a few extra
            base = pool[k % len(pool)]
            k += 1
            kind = rng.integers(0, 14)
            if kind in (4, 5) and (by_receive.stale or not by_receive.ready):  # any epoch would do
                kind = 13
            if kind == 0:  # random garbage
                batch.append(
                    (rng.integers(0, 256, int(rng.integers(1, 900)), np.uint8).tobytes(), None)
                )
            elif kind == 1:  # truncated
                batch.append(
                    (restamp(base, epoch, seq + 1, now)[: int(rng.integers(1, len(base)))], None)
                )
            elif kind == 2:  # oversize: the mailbox marks it with a negative length
                batch.append((base + bytes(SLOT_BYTES + 1 - len(base)), -(SLOT_BYTES + 1)))
            elif kind == 3:  # a repeat of the installed sequence number
                batch.append((restamp(base, epoch, seq, now), None))
            elif kind == 4:  # an older epoch
                batch.append((restamp(base, epoch - 1, seq + 5, now), None))
            elif kind == 5:  # another sim's newer epoch: installed only after a trip
                batch.append((restamp(base, epoch + 1, 0, now), None))
            elif kind == 7:  # delayed in the network beyond max_update_age_ms
                batch.append((restamp(base, epoch, seq + 1, now - 500_000_000), None))
            elif kind == 8:  # published in the future (a forged time)
                batch.append((restamp(base, epoch, seq + 1, now + 10**12), None))
            elif kind == 6:  # a backlog: several valid ones in one tick
                for _ in range(3):
                    seq += 1
                    batch.append((restamp(pool[k % len(pool)], epoch, seq, now), None))
                    k += 1
            else:
                seq += 1
                batch.append((restamp(base, epoch, seq, now - 2_000_000), None))
        if tick in (200, 640):  # the watchdog fired on both
            for e in engines:
                e.set_stale()
        if batch:
            for raw, _ in batch:
                mailbox.put(raw)
            read = int(mailbox.block.ctl[C_UPD_READ])
            taken, installed, newest_seq, latency_s = mailbox.take_updates(
                by_mailbox, tick, budget=8
            )
            assert taken == len(batch)
            assert int(mailbox.block.ctl[C_UPD_READ]) == read + len(batch)
            n_ok = 0
            for i, (raw, length) in enumerate(batch):
                slot = (read + i) % MAILBOX_SLOTS
                latency = float(mailbox.block.update_latency_s[slot])
                if length is not None:
                    assert int(mailbox.block.update_len[slot]) == length
                    code = by_receive.receive_buffer(by_receive.buffer, length, latency)
                    reason = reason_of(code) if code else ""
                    assert code == R_SIZE
                else:
                    reason = by_receive.receive(raw, latency)
                assert int(mailbox.block.update_tick[slot]) == tick
                verdict = int(mailbox.block.update_verdict[slot])
                assert (reason_of(verdict) if verdict else "") == reason
                verdicts_seen[reason or "installed"] = (
                    verdicts_seen.get(reason or "installed", 0) + 1
                )
                if not reason:
                    n_ok += 1
                    assert 0.0 <= latency <= DEFAULT_MAX_AGE_S
                    if length is None and i == len(batch) - 1:
                        assert latency == pytest.approx(latency_s)
            assert installed == n_ok
            if n_ok:
                assert newest_seq == by_receive.last_seq
        assert engine_state(by_mailbox) == engine_state(by_receive)
        rows = [e.tick(1e-3)[0].tobytes() for e in engines]
        assert rows[0] == rows[1], f"tick {tick}"
    # the stream exercised every path it was built for
    assert verdicts_seen["installed"] > 40, verdicts_seen
    assert {"size", "sequence", "epoch", "late", "future"} <= verdicts_seen.keys()
    assert by_receive.counters.epochs >= 2
    assert by_receive.counters.reinitialisations >= 1


def test_events_overwritten_before_they_are_read_are_counted_never_misread() -> None:
    """A reader that falls EVENT_SLOTS + 44 events behind loses the 44 oldest: counted (the
    summary's events_lost), and what it reads next is the oldest still in the ring, in order
    (before, it read the overwritten slots as if they were the lost events)."""
    block = SharedBlock.create()
    try:
        for tick in range(EVENT_SLOTS + 44):
            block.post_event(tick, "watchdog", f"event {tick}")
        head = int(block.ctl[C_EVT_HEAD])
        lost, tail = block.skip_overwritten(0, head)
        assert (lost, tail) == (44, 44)
        assert int(block.ctl[C_EVT_LOST]) == 44
        read = [block.event_at(i) for i in range(tail, head)]
        assert read == [(t, "watchdog", f"event {t}") for t in range(44, EVENT_SLOTS + 44)]
        assert block.skip_overwritten(tail, head) == (0, tail)  # caught up: nothing more lost
    finally:
        block.release()
        block.shm.close()
        block.shm.unlink()

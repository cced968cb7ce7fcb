"""Logging from the 1 kHz loop without perturbing it: a writer process fed by shared memory.

The loop copies each tick record into a shared-memory ring (about 1 us) and sends the rare
update and event records through a pipe; a separate process, which never competes for the
loop's GIL, encodes them into MCAP. If the haptic server dies (even by SIGKILL) the writer
notices its parent is gone, drains the ring and closes the file properly.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import time
from multiprocessing import shared_memory
from pathlib import Path
from typing import Any

import numpy as np

from haptic_server.layout import TICK_DTYPE

RING_TICKS = 16384  # 16 s of ticks at 1 kHz: the writer may stall this long without loss
POLL_S = 0.02
_HEAD, _TAIL, _LOST, _CLOSED = 0, 1, 2, 3


class LogProcess:
    """The loop's side: push ticks and records; close to finish the file."""

    def __init__(
        self, path: Path | str, metadata: dict[str, dict[str, str]], wall_start_ns: int
    ) -> None:
        self.path = Path(path)
        itemsize = TICK_DTYPE.itemsize
        self._shm = shared_memory.SharedMemory(create=True, size=64 + RING_TICKS * itemsize)
        self._ctl = np.ndarray((8,), np.int64, self._shm.buf, 0)
        self._ctl[:] = 0
        self._ring = np.ndarray((RING_TICKS,), TICK_DTYPE, self._shm.buf, 64)
        ctx = mp.get_context("spawn")
        self._records_rx, self._records_tx = ctx.Pipe(duplex=False)
        self._proc = ctx.Process(
            target=_writer_main,
            args=(
                self._shm.name,
                str(self.path),
                metadata,
                wall_start_ns,
                self._records_rx,
                os.getpid(),
            ),
            name="haptic-log-writer",
            daemon=False,
        )
        self._proc.start()
        self._head = 0

    def tick(self, row: np.ndarray) -> None:
        """Copy one tick record into the ring (the writer picks it up)."""
        self._ring[self._head % RING_TICKS] = row[0]
        self._head += 1
        self._ctl[_HEAD] = self._head

    def update(self, payload: dict[str, Any], t: float) -> None:
        """A received update (a few tens per second), logged as JSON."""
        self._records_tx.send(("update", {**payload, "t": t}))

    def event(self, tick: int, kind: str, detail: str, t: float) -> None:
        """A watchdog, rejection, fault or lifecycle event."""
        self._records_tx.send(("event", {"tick": tick, "kind": kind, "detail": detail, "t": t}))

    @property
    def lost_ticks(self) -> int:
        return int(self._ctl[_LOST])

    def close(self, timeout_s: float = 30.0) -> int:
        """Finish the file; returns the number of tick records lost (0 unless overrun)."""
        self._ctl[_CLOSED] = 1
        self._proc.join(timeout_s)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(5.0)
        lost = self.lost_ticks
        self._ctl = np.zeros(8, np.int64)
        self._ring = np.zeros(0, TICK_DTYPE)
        self._shm.close()
        self._shm.unlink()
        return lost


def _writer_main(
    shm_name: str,
    path: str,
    metadata: dict[str, dict[str, str]],
    wall_start_ns: int,
    records: Any,
    parent_pid: int,
) -> None:
    """The writer process: drain the ring and the pipe into MCAP until closed or orphaned."""
    import signal

    from haptic_server.mcap_log import LogWriter

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides when logging ends
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    shm = shared_memory.SharedMemory(name=shm_name)
    ctl = np.ndarray((8,), np.int64, shm.buf, 0)
    ring = np.ndarray((RING_TICKS,), TICK_DTYPE, shm.buf, 64)
    writer = LogWriter(path, metadata)
    tail = 0
    last_flush = time.monotonic()
    try:
        while True:
            closing = ctl[_CLOSED] == 1 or os.getppid() != parent_pid
            head = int(ctl[_HEAD])
            if head - tail > RING_TICKS:
                ctl[_LOST] += head - tail - RING_TICKS
                tail = head - RING_TICKS
            while tail < head:
                row = ring[tail % RING_TICKS : tail % RING_TICKS + 1]
                writer.tick(row.tobytes(), wall_start_ns + int(float(row["t"][0]) * 1e9))
                tail += 1
            try:
                while records.poll():
                    kind, payload = records.recv()
                    t_ns = wall_start_ns + int(payload.pop("t", 0.0) * 1e9)
                    if kind == "update":
                        writer.update(payload, t_ns)
                    else:
                        writer.event(int(payload["tick"]), payload["kind"], payload["detail"], t_ns)
            except (EOFError, OSError):  # the loop's end of the pipe is gone: finish up
                closing = True
            if closing and int(ctl[_HEAD]) == tail:
                break
            if time.monotonic() - last_flush > 0.2:
                writer.flush()
                last_flush = time.monotonic()
            time.sleep(POLL_S)
    finally:
        writer.close()
        del ctl, ring
        shm.close()

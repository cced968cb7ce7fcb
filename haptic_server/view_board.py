"""The view board: the sim's world messages (`<ns>/view/world`) from the I/O sidecar to the
live view and the log writer, in a shared-memory ring of its own (made only with --view).

The sidecar's Zenoh callback copies a message in and moves the head, nothing else (no
parsing, no numba: its thread must not hold the GIL). Readers keep their own cursors and
take nothing: a message is checked by whoever reads it (`shared/protocol/world_view.py`).
One writer; a reader re-reads the head after a copy and drops a slot overwritten meanwhile.
"""

from __future__ import annotations

from multiprocessing import resource_tracker, shared_memory

import numpy as np

BOARD_SLOTS = 16  # half a second of poses at 30 Hz, with the shapes between them
SLOT_BYTES = 65536  # the network's default max_message_bytes: a longer one is counted lost
B_HEAD, B_LOST, B_TICK = 0, 1, 2  # header: messages written, too long, the loop's tick


class ViewBoard:
    """The ring over one shared-memory block: a header, slot lengths, the slots, and the
    tick at which each message was written (the log writer files it under that tick)."""

    def __init__(self, shm: shared_memory.SharedMemory, owner: bool) -> None:
        self.shm, self.owner = shm, owner
        buf = shm.buf
        self.ctl = np.ndarray((4,), np.int64, buf, 0)
        self.lengths = np.ndarray((BOARD_SLOTS,), np.int64, buf, 32)
        self.ticks = np.ndarray((BOARD_SLOTS,), np.int64, buf, 32 + 8 * BOARD_SLOTS)
        start = 32 + 16 * BOARD_SLOTS
        self.slots = np.ndarray((BOARD_SLOTS, SLOT_BYTES), np.uint8, buf, start)

    @classmethod
    def create(cls) -> ViewBoard:
        size = 32 + 16 * BOARD_SLOTS + BOARD_SLOTS * SLOT_BYTES
        board = cls(shared_memory.SharedMemory(create=True, size=size), True)
        board.ctl[:] = 0
        return board

    @classmethod
    def attach(cls, name: str, own_tracker: bool = True) -> ViewBoard:
        """The board another process made; unregistered from this process's resource
        tracker, which would unlink it at exit (Python < 3.13; as SharedBlock.attach). A
        child spawned by multiprocessing shares its parent's tracker (`own_tracker` False):
        the parent's registration stays."""
        shm = shared_memory.SharedMemory(name=name)
        if own_tracker:
            resource_tracker.unregister(shm._name, "shared_memory")  # type: ignore[attr-defined]
        return cls(shm, False)

    @property
    def name(self) -> str:
        return self.shm.name

    def post(self, raw: bytes, tick: int) -> bool:
        """A message into the next slot (the writer only); False if it is too long."""
        n = len(raw)
        if n > SLOT_BYTES:
            self.ctl[B_LOST] += 1
            return False
        head = int(self.ctl[B_HEAD])
        slot = head % BOARD_SLOTS
        self.slots[slot, :n] = np.frombuffer(raw, np.uint8)
        self.lengths[slot] = n
        self.ticks[slot] = tick
        self.ctl[B_HEAD] = head + 1
        return True

    def read_since(self, seen: int) -> tuple[list[tuple[int, bytes]], int]:
        """The messages written since `seen` that are still on the board, with their ticks,
        oldest first, and the new cursor."""
        head = int(self.ctl[B_HEAD])
        out = []
        for i in range(max(seen, head - BOARD_SLOTS + 1), head):
            slot = i % BOARD_SLOTS
            n, tick = int(self.lengths[slot]), int(self.ticks[slot])
            raw = self.slots[slot, :n].tobytes()
            if int(self.ctl[B_HEAD]) - i < BOARD_SLOTS:  # not overwritten while copied
                out.append((tick, raw))
        return out, head

    def close(self) -> None:
        del self.ctl, self.lengths, self.ticks, self.slots
        self.shm.close()
        if self.owner:
            self.shm.unlink()

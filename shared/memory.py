"""What a process does about memory: how much the machine can give (a run that holds its rows
asks before it starts), and, in a receiving process, after a flood of messages, what their
buffers took handed back to the system (benchmarks/flood.py, docs/security.md)."""

from __future__ import annotations

import contextlib
import ctypes
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any


def available_bytes() -> int:
    """The memory this machine can give a process now without swapping: the kernel's
    MemAvailable (free memory and what it can reclaim from its caches), or, where there is no
    /proc/meminfo, the free pages."""
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


TRIM_EVERY_S = 0.25  # counted this often
TRIM_AFTER = 250  # messages received in one count's window: a flood's worth (1,000/s)


class FloodTrim:
    """After a flood, the memory its messages took handed back to the system: Zenoh's receive
    path allocates through glibc, whose per-thread arenas keep what was freed, and a first
    flood of 30,000 messages on a key left a receiving process 0-24 MB larger for good
    (benchmarks/flood.py). A loop calls `after` as often as it likes, with how to count its
    messages received (taken, refused or dropped): it counts them every TRIM_EVERY_S, and
    `malloc_trim` runs (ctypes releases the GIL for it; tens of microseconds) in each such
    window a flood's worth arrived in and in the one after (the flood's last buffers freed:
    within half a second of its end)."""

    def __init__(self) -> None:
        self._trim: Any = None
        with contextlib.suppress(OSError, AttributeError):  # not glibc: nothing to trim
            self._trim = ctypes.CDLL("libc.so.6").malloc_trim
        self._counted = 0
        self._flooding = False
        self._next = 0.0

    def after(self, now_s: float, count: Callable[[], int]) -> None:
        """At `now_s` (a monotonic clock, in s); `count()`: the messages received so far."""
        if self._trim is None or now_s < self._next:
            return
        counted = count()
        flooding = counted - self._counted >= TRIM_AFTER
        if flooding or self._flooding:  # in a flood's seconds, and the one after its end
            self._trim(0)
        self._counted, self._flooding, self._next = counted, flooding, now_s + TRIM_EVERY_S

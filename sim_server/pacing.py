"""When the sim starts each step: on its own grid of deadlines, shifted so that its update
reaches the haptic loop just before one of the loop's ticks (a phase lock).

An update that arrives just after a haptic tick waits for the next one: up to a whole tick
period T, half of it at the median (0.5 ms at 1 kHz), longer than the Zenoh hop itself. The
sim cannot make the hop shorter, but it can start its step later, so that the state it
publishes is fresher when the tick that uses it runs.

The haptic server reports, in its proxy state, how long update s waited between its receipt
and the tick that installed it (w_s; both instants on the haptic host's clock, so the hosts'
clocks need not agree). The sim put update s at p_s on its own clock, so p_s + w_s is a tick
time less the hop h_s: modulo T it is the phase of the haptic tick grid as the sim sees it,
less the hop. That holds whether the update caught its tick or missed it (then it waited a
period more), so one late message does not disturb the estimate; the circular mean of the
newest reports averages the hop's jitter out. The sim then starts each step, 0 <= shift < T
after its deadline (its rate does not change), so that it puts its update `margin` before
that phase, its step's duration predicted by the median of the last few steps.
"""

from __future__ import annotations

import math
from collections import OrderedDict, deque

import numpy as np

from haptic_local_model.shared.protocol.proxy import UpdateWait

ARRIVAL_MARGIN_NS = 200_000  # aim for arrivals this long before a tick (at most T / 2)
PHASE_REPORTS = 16  # reports averaged into the phase estimate
BUSY_HISTORY = 8  # steps whose start -> put time predicts the next one's
KEEP_STEPS = 64  # steps whose put time is remembered, for reports that arrive late


class PhaseLock:
    """The shift of each sim step from its deadline (see the module docstring)."""

    def __init__(self, margin_ns: int = ARRIVAL_MARGIN_NS) -> None:
        self.margin_ns = margin_ns
        self.tick_period_ns = 0  # of the haptic loop reporting; 0 until a report arrives
        self._put_ns: OrderedDict[int, int] = OrderedDict()  # seq -> when it was put
        self._busy_ns: deque[int] = deque(maxlen=BUSY_HISTORY)  # step start -> put
        self._phases: deque[float] = deque(maxlen=PHASE_REPORTS)  # radians of the tick grid
        self._newest = -1

    def report(self, wait: UpdateWait) -> None:
        """The haptic server's newest report (of this sim's epoch: the caller checks)."""
        if wait.seq <= self._newest or wait.seq not in self._put_ns or wait.tick_period_ns <= 0:
            return
        if wait.tick_period_ns != self.tick_period_ns:  # another loop, or another rate
            self._phases.clear()
            self.tick_period_ns = wait.tick_period_ns
        self._newest = wait.seq
        phase = (self._put_ns[wait.seq] + wait.wait_ns) % self.tick_period_ns
        self._phases.append(2.0 * math.pi * phase / self.tick_period_ns)

    def shift_ns(self, deadline_ns: int) -> int:
        """How long after `deadline_ns` the step due then starts; 0 until reports arrive."""
        if not self._phases:
            return 0
        period = self.tick_period_ns
        angles = np.array(self._phases)
        mean = math.atan2(float(np.sin(angles).sum()), float(np.cos(angles).sum()))
        tick_phase = round(mean / (2.0 * math.pi) * period)
        busy = int(np.median(self._busy_ns)) if self._busy_ns else 0
        margin = min(self.margin_ns, period // 2)
        return int((tick_phase - margin - busy - deadline_ns) % period)

    def published(self, seq: int, start_ns: int, put_ns: int) -> None:
        """Step `seq` started at `start_ns` and put its update at `put_ns` (the sim's clock)."""
        self._put_ns[seq] = put_ns
        while len(self._put_ns) > KEEP_STEPS:
            self._put_ns.popitem(last=False)
        self._busy_ns.append(put_ns - start_ns)

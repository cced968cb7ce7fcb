"""The order of things within a tick, coded once: stop, installs, watchdog clear, watchdog trip.

Three drivers run ticks of the same `HapticEngine`: the real-time loop (decisions from the
wall clock), the virtual clock (installs only) and `haptic-replay` (decisions read back from
the log). Each hands `supervise` an `EventSource` that answers the four questions of a tick;
`supervise` asks them in the one defined order and applies the answers to the engine, so a
replay of a logged run switches the safe state exactly where the run did. The only
watchdog flag is the engine's own `stale`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Protocol

from haptic_local_model.haptic_server.engine import HapticEngine

NEVER_NS = 1 << 62


class Event(StrEnum):
    """What a tick can do to the safe state, as logged (event kinds of the MCAP log)."""

    STOP = "stop"  # ramp to the safe state: the run ends
    REINITIALISE = "reinitialise"  # an install restarted the proxy from the sim's state
    WATCHDOG_CLEAR = "watchdog_clear"  # an update arrived after a trip: normal rendering
    WATCHDOG = "watchdog"  # no valid update for watchdog_ms: ramp to the safe state
    # the loop's guard sent the device safe (a kernel's decision: a replay recomputes it, so
    # it is logged for people, not replayed); the next installed update re-initialises
    FAULT = "fault"


class EventSource(Protocol):
    """Answers the questions of one tick, in the order `supervise` asks them."""

    def stop(self) -> bool:
        """Does the run stop at this tick? (asked first; no update is taken once stopping)"""

    def install(self) -> int:
        """Install what waits for this tick; returns how many were installed."""

    def watchdog_clear(self, installed: int, was_stale: bool) -> bool:
        """Does an install of this tick end a watchdog trip?"""

    def watchdog_trip(self) -> bool:
        """Has the watchdog run out at this tick? (asked last)"""


@dataclass(slots=True)
class TickEvents:
    """What `supervise` did at one tick."""

    installed: int = 0
    stop: bool = False
    reinitialised: bool = False  # a new epoch, or the first install after a trip
    new_epoch: bool = False
    watchdog_clear: bool = False
    watchdog: bool = False


def supervise(engine: HapticEngine, source: EventSource) -> TickEvents:
    """Apply one tick's events to `engine` in the one order: stop, installs, watchdog clear,
    watchdog trip (then the caller runs `engine.tick`)."""
    events = TickEvents()
    if source.stop():
        engine.set_safe(True)
        events.stop = True
    epochs, was_stale, reinit = engine.counters.epochs, engine.stale, engine.needs_reinit
    events.installed = source.install()
    if events.installed:
        events.new_epoch = engine.counters.epochs != epochs
        events.reinitialised = events.new_epoch or reinit
    if source.watchdog_clear(events.installed, was_stale):
        engine.set_safe(False)
        events.watchdog_clear = True
    if source.watchdog_trip():
        engine.set_stale()
        events.watchdog = True
    return events


class WatchdogClock:
    """The real-time loop's decisions: stop at a request or the end of the run, clear the
    watchdog with an install after a trip, trip it when no valid update came for
    watchdog_ms. `install` is the loop's mailbox call; `now_ns` is set by the loop."""

    def __init__(self, engine: HapticEngine, watchdog_ns: int, install: Callable[[], int]) -> None:
        self.engine = engine
        self.watchdog_ns = watchdog_ns
        self._install = install
        self.stopping = False
        self.stop_requested = False
        self.end_ns = 1 << 62
        self.now_ns = 0
        self.last_valid_ns = 0
        self.stop_reason = ""
        self.stop_why = ""  # a reason of the loop's own for a stop request (a lost I/O process)
        # the earliest time the watchdog can trip (armed by an install, disarmed by a trip or
        # the stop): the loop skips the supervisor on ticks before it with nothing waiting
        self.trip_at_ns = NEVER_NS

    def stop(self) -> bool:
        if self.stopping or not (self.stop_requested or self.now_ns >= self.end_ns):
            return False
        self.stopping = True
        self.stop_reason = (
            (self.stop_why or "stop requested") if self.stop_requested else "duration reached"
        )
        self.trip_at_ns = NEVER_NS
        return True

    def install(self) -> int:
        if self.stopping:
            return 0
        installed = self._install()
        if installed:
            self.last_valid_ns = self.now_ns
            self.trip_at_ns = self.now_ns + self.watchdog_ns
        return installed

    def watchdog_clear(self, installed: int, was_stale: bool) -> bool:
        return installed > 0 and was_stale

    def watchdog_trip(self) -> bool:
        if self.now_ns <= self.trip_at_ns:  # armed by an install since, or disarmed: no trip
            return False
        engine = self.engine
        trip = (
            engine.ready
            and not engine.stale
            and not self.stopping
            and self.now_ns - self.last_valid_ns > self.watchdog_ns
        )
        if trip:
            self.trip_at_ns = NEVER_NS  # until the next install
        return trip


class InstallOnly:
    """The virtual clock's source: the sim's update of this tick, nothing else."""

    def __init__(self, install: Callable[[], int]) -> None:
        self._install = install

    def stop(self) -> bool:
        return False

    def install(self) -> int:
        return self._install()

    def watchdog_clear(self, installed: int, was_stale: bool) -> bool:
        return False

    def watchdog_trip(self) -> bool:
        return False


class LoggedEvents:
    """A replay's source: the events the run logged at this tick (`kinds`), and its
    updates' bytes installed by `install`."""

    def __init__(self, kinds: set[str], install: Callable[[], int]) -> None:
        self.kinds = kinds
        self._install = install

    def stop(self) -> bool:
        return Event.STOP in self.kinds

    def install(self) -> int:
        return self._install()

    def watchdog_clear(self, installed: int, was_stale: bool) -> bool:
        return Event.WATCHDOG_CLEAR in self.kinds

    def watchdog_trip(self) -> bool:
        return Event.WATCHDOG in self.kinds

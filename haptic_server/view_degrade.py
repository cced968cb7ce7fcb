"""The live view lowers itself when the sim falls behind, and says so.

Measured on 2 cores with a headless Chromium drawing the view (docs/live-view.md): the
haptic loop's own lateness stays flat up to a watchdog trip; what comes first is the gap
between installed updates (the sim's steps reaching the loop): gaps of half the watchdog
budget and more appear seconds before the first trip. The view sees that gap in the tick
rows it already reads (`update_seq`, `t`), so it needs no new channel.

The policy is a pure state machine over (time, gap): on a gap of at least STRAIN_FRACTION of
the watchdog budget it steps down one level (at most one step per HOLD_S); after QUIET_S
without one it steps back up one level. Each level keeps fewer channels at a lower rate.
"""

from __future__ import annotations

from dataclasses import dataclass

STRAIN_FRACTION = 0.5  # an install gap this fraction of the watchdog budget is strain
HOLD_S = 1.0  # at most one step down per second: a step's effect shows within it
QUIET_S = 10.0  # this long without strain: one step back up


@dataclass(frozen=True)
class ViewLevel:
    """What the view draws at one level: its frame rate, and which channels it keeps."""

    name: str
    frame_hz: float
    forces: bool  # the force arrows, the force plots and the contacts with their normals
    world_hz: float  # the sim's world poses drawn at most this often (0: the world dropped)
    dropped: str  # what this level drops against the one above, said in the event


LEVELS = (
    ViewLevel("full", 60.0, True, 60.0, ""),
    ViewLevel("no forces", 30.0, False, 60.0, "the forces and contacts, frames 60 -> 30 Hz"),
    ViewLevel("slow world", 15.0, False, 5.0, "the world's poses 30 -> 5 Hz, frames -> 15 Hz"),
    ViewLevel("tool only", 5.0, False, 0.0, "the sim's world (the board), frames -> 5 Hz"),
)


class DegradePolicy:
    """Which ViewLevel to draw at, from the install gaps the view sees."""

    def __init__(self, watchdog_ms: float) -> None:
        if not watchdog_ms > 0:
            raise ValueError(f"watchdog_ms {watchdog_ms!r}: must be > 0")
        self.strain_s = STRAIN_FRACTION * watchdog_ms / 1e3
        self.index = 0
        self._last_change_s = float("-inf")
        self._last_strain_s = float("-inf")

    @property
    def level(self) -> ViewLevel:
        return LEVELS[self.index]

    def observe(self, now_s: float, install_gap_s: float) -> str | None:
        """The newest gap since an install at `now_s` (run time, s): the event text if the
        level changed, else None."""
        if install_gap_s >= self.strain_s:
            self._last_strain_s = now_s
            if self.index + 1 < len(LEVELS) and now_s - self._last_change_s >= HOLD_S:
                self.index += 1
                self._last_change_s = now_s
                return (
                    f"view degraded to '{self.level.name}': dropped {self.level.dropped} "
                    f"(no sim update for {1e3 * install_gap_s:.0f} ms, "
                    f"{STRAIN_FRACTION:g} of the watchdog's {2e3 * self.strain_s:.0f} ms)"
                )
            return None
        quiet = now_s - max(self._last_strain_s, self._last_change_s)
        if self.index > 0 and quiet >= QUIET_S:
            left = LEVELS[self.index]
            self.index -= 1
            self._last_change_s = now_s
            return (
                f"view restored to '{self.level.name}': undid '{left.name}', which dropped "
                f"{left.dropped} (no strain for {quiet:.0f} s)"
            )
        return None


class InstallGap:
    """The time since the newest install, from the tick rows the view reads: a row's
    `update_seq` changes when an update is installed."""

    def __init__(self) -> None:
        self._seq = -2
        self._since_s = 0.0

    def gap_s(self, t_s: float, seq: int) -> float:
        if seq != self._seq:
            self._seq, self._since_s = seq, t_s
        return t_s - self._since_s

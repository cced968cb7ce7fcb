"""Logs recorded before the redesign (tests/golden/logs, build 2ccdfb6) replay exactly.

Each log carries its scene, device and user config texts and every update's bytes; the replay
drives today's engine with them and compares every tick row with the logged one. Fields the
tick schema has grown since are reported by name and left out of the comparison; every field
the old log has must match to the bit.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from haptic_server.harness.replay import replay
from haptic_server.log import read_log

GOLDEN = Path(__file__).parent / "golden" / "logs"
LOGS = sorted(GOLDEN.glob("*.mcap"))


def test_the_golden_logs_are_there() -> None:
    assert len(LOGS) >= 12, f"expected the 12 golden logs in {GOLDEN}"


@pytest.mark.parametrize("path", LOGS, ids=[p.stem for p in LOGS])
def test_golden_log_replays_exactly(path: Path) -> None:
    log = read_log(path)
    result = replay(log)
    assert len(result.ticks) == len(log.ticks), result.note
    assert result.updates_replayed == len(log.updates)
    assert not result.verdict_mismatches, result.verdict_mismatches[:5]
    assert not result.differing, f"{path.name}: {result.differing}"

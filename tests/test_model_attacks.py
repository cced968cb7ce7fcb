"""Each forged model of haptic_server/harness/forgeries.py, with the sim's own credentials,
against the real processes on the default network (benchmarks/model_attacks.py runs them and
writes the table of docs/security.md): refused for its reason, or installed and stopped by the
loop's guard; at most 50 ms at the device's limit, normal rendering within 200 ms of the
sim's next good update after a trip, and none of the sim's own updates refused.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from haptic_local_model.benchmarks.model_attacks import attack
from haptic_local_model.haptic_server.harness.forgeries import (
    EXPECTED,
    FORGERIES,
    LIMIT_MS,
    RESUME_MS,
)


@pytest.mark.processes
@pytest.mark.parametrize("forgery", sorted(FORGERIES))
def test_a_forged_model_is_refused_or_neutralised(tmp_path: Path, forgery: str) -> None:
    r = attack(forgery, tmp_path)
    assert r.arrived, "the forgery never reached the haptic server"
    if EXPECTED[forgery] == "guard":
        assert r.verdict == "installed"
    else:
        assert r.verdict == EXPECTED[forgery], r
    assert r.at_limit_ms <= LIMIT_MS, r
    assert r.resumed_ms <= RESUME_MS, r
    assert r.own_refused == 0, r

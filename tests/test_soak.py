"""The soak can fail: a leak or a NaN injected into the haptic server is caught and named."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SEGMENT_S = 15.0  # 2 KB a tick after a 25% warm-up leaks ~22 MB: over the 10 MB bound


def soak(tmp_path: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "haptic_local_model.haptic_server.harness.soak", "--minutes",
        str(SEGMENT_S / 60),
         "--segment-s", str(SEGMENT_S), "--out", str(tmp_path), *extra],
        cwd=REPO, capture_output=True, text=True, timeout=600,
    )  # fmt: skip


@pytest.mark.processes
@pytest.mark.slow
def test_a_leaking_loop_fails_the_soak(tmp_path: Path) -> None:
    res = soak(tmp_path, "--inject-leak")
    assert res.returncode == 1, res.stdout + res.stderr
    assert "haptic resident memory grew" in res.stderr
    assert "FAILED" in (tmp_path / "soak.md").read_text()


@pytest.mark.processes
@pytest.mark.slow
def test_a_nan_fails_the_soak(tmp_path: Path) -> None:
    res = soak(tmp_path, "--inject-nan-after", "3")
    assert res.returncode == 1, res.stdout + res.stderr
    assert "NaN/Inf in" in res.stderr and "kernel fault 1" in res.stderr

"""`haptic-soak`, `haptic-run` and config errors: one line on stderr naming the file (or
config) and the key, exit code 2, no traceback and no report, whether the soak finds the
error itself (before any server starts) or only a server does (it stops with exit 2 before
it is ready).

haptic-soak takes no config options (its segments are shipped scenes, devices and users), so
these tests point its SEGMENTS at a file in tmp_path and run `main` in a child Python from
tmp_path, as a user runs it from a directory of their own."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from haptic_local_model.haptic_server.harness.soak import SEGMENTS, Segment, check_configs

REPO = Path(__file__).resolve().parent.parent
WALL_PUSH = REPO / "configs" / "scenes" / "wall_push.toml"


def _soak_with(tmp_path: Path, segment: tuple[str, str, str]) -> subprocess.CompletedProcess[str]:
    code = (
        "import sys\n"
        "import haptic_local_model.haptic_server.harness.soak as soak\n"
        f"soak.SEGMENTS = (soak.Segment(*{segment!r}),)\n"
        "sys.exit(soak.main(['--minutes', '0.2', '--segment-s', '5', '--out', 'out']))\n"
    )
    return subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300
    )


def _with_top_level(text: str, line: str) -> str:
    """`line` added as a top-level key (before the first table)."""
    head, sep, tail = text.partition("\n[")
    return f"{head}\n{line}\n{sep}{tail}"


def _one_error_line(res: subprocess.CompletedProcess[str]) -> str:
    assert res.returncode == 2, res.stderr + res.stdout
    assert "Traceback" not in res.stderr + res.stdout
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    return lines[0]


@pytest.mark.processes
def test_an_error_only_the_haptic_server_finds_stops_the_soak_with_its_reason(
    tmp_path: Path,
) -> None:
    """Every file is valid on its own (the soak loads them all first), but the scene's haptic
    rate exceeds the device's max_rate_hz: only the haptic server's engine checks the pair."""
    text = WALL_PUSH.read_text().replace('name = "wall_push"', 'name = "too_fast"', 1)
    text = text.replace("haptic_rate_hz = 1000.0", "haptic_rate_hz = 2500.0", 1)
    assert 'name = "too_fast"' in text and "haptic_rate_hz = 2500.0" in text
    scene = tmp_path / "too_fast.toml"
    scene.write_text(text)
    check_configs((Segment(str(scene), "maglev", "push_2n"),))  # the soak's own check passes it
    res = _soak_with(tmp_path, (str(scene), "maglev", "push_2n"))
    line = _one_error_line(res)
    assert "'too_fast'" in line and "'maglev'" in line, line
    assert "'haptic_rate_hz'" in line and "max_rate_hz 1400" in line, line
    assert "FAILED" not in res.stdout and not (tmp_path / "out" / "soak.md").exists()


@pytest.mark.processes
def test_a_bad_segment_file_stops_the_soak_before_a_server_starts(tmp_path: Path) -> None:
    scene = tmp_path / "unknown_key.toml"
    scene.write_text(_with_top_level(WALL_PUSH.read_text(), "bogus_key = 1"))
    res = _soak_with(tmp_path, (str(scene), "ideal", "push_2n"))
    line = _one_error_line(res)
    assert str(scene) in line and "'bogus_key'" in line, line
    assert not (tmp_path / "out").exists()  # found before the soak made its output directory


def test_the_shipped_segments_pass_the_soaks_own_check() -> None:
    check_configs(SEGMENTS)


@pytest.mark.processes
def test_haptic_run_passes_a_child_reason_up(tmp_path: Path) -> None:
    """The same pair given to haptic-run, which checks each file but not the pair: the haptic
    server's one line, and exit 2, nothing added."""
    res = subprocess.run(
        [sys.executable, "-m", "haptic_local_model.haptic_server.harness.run", "--scene",
        str(WALL_PUSH),
         "--device", "maglev", "--haptic-rate", "5000", "--duration", "1", "--no-log"],
        cwd=tmp_path, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    line = _one_error_line(res)
    assert "'maglev'" in line and "haptic_rate_hz" in line, line

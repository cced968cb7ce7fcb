"""One error path: every console script that reads config files turns a missing file, an
unknown key or a value of the wrong type into one line on stderr naming the file and the key,
exit code 2, no traceback — run as a user runs it, from a directory of their own."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent

#: option -> (a valid shipped file to start from, (key, line) of an unknown key, (key, line) of
#: a value of the wrong type)
FAULTS = {
    "--scene": ("scenes/wall_push.toml", "bogus_key", ("sim_rate_hz", 'sim_rate_hz = "fast"')),
    "--device": ("devices/ideal.toml", "bogus_key", ("model", "model = 3")),
    "--user": ("users/push_2n.toml", "bogus_key", ("wrench", 'wrench = "x"')),
    "--network": ("network/loopback.toml", "bogus_key", ("namespace", "namespace = 5")),
}
SCRIPTS = {
    "haptic-run": ("--scene", "--device", "--user", "--network"),
    "haptic-run --clock virtual": ("--scene", "--device", "--user", "--network"),
    "haptic-server": ("--scene", "--device", "--user", "--network"),
    "sim-server": ("--scene", "--network"),
}
CASES = [
    (script, option, fault)
    for script, options in SCRIPTS.items()
    for option in options
    for fault in ("missing", "unknown_key", "wrong_type")
]


def _write_fault(tmp_path: Path, option: str, fault: str) -> tuple[str, str]:
    """The file to pass (relative to tmp_path) and the key the error must name."""
    shipped, unknown, (key, line) = FAULTS[option]
    text = (REPO / "configs" / shipped).read_text()
    name = f"{fault}.toml"
    if fault == "missing":
        return name, ""
    if fault == "unknown_key":
        # a top-level key: before the first table, where every file's own keys are
        head, sep, tail = text.partition("\n[")
        (tmp_path / name).write_text(f"{head}\n{unknown} = 1\n{sep}{tail}")
        return name, unknown
    lines = [line if ln.split("=")[0].strip() == key else ln for ln in text.splitlines()]
    assert line in lines, f"{shipped} has no top-level {key}"
    (tmp_path / name).write_text("\n".join(lines) + "\n")
    return name, key


def _the_one_error_line(argv: list[str], cwd: Path) -> str:
    """Run a console script (argv[0], installed beside this Python) from `cwd`: it must exit
    2 with one line on stderr and no traceback; that line."""
    res = subprocess.run(
        [str(BIN / argv[0]), *argv[1:]], cwd=cwd, capture_output=True, text=True, timeout=120
    )
    assert res.returncode == 2, res.stderr + res.stdout
    assert "Traceback" not in res.stderr + res.stdout
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    return lines[0]


@pytest.mark.processes
@pytest.mark.parametrize(("script", "option", "fault"), CASES)
def test_a_bad_config_is_one_line_and_exit_2(
    tmp_path: Path, script: str, option: str, fault: str
) -> None:
    name, key = _write_fault(tmp_path, option, fault)
    exe, *flags = script.split()
    line = _the_one_error_line([exe, *flags, option, name, "--duration", "1"], tmp_path)
    assert name in line
    if key:
        assert f"'{key}'" in line
    else:
        assert "not found" in line


@pytest.mark.processes
def test_replay_of_a_missing_or_foreign_file_is_one_line_and_exit_2(tmp_path: Path) -> None:
    (tmp_path / "notes.mcap").write_text("not a log\n")
    for name in ("absent.mcap", "notes.mcap"):
        res = subprocess.run(
            [str(BIN / "haptic-replay"), name, "--no-progress"],
            cwd=tmp_path, capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert res.returncode == 2, res.stderr + res.stdout
        assert "Traceback" not in res.stderr + res.stdout
        lines = res.stderr.strip().splitlines()
        assert len(lines) == 1 and "haptic-replay" in lines[0], res.stderr


@pytest.mark.processes
@pytest.mark.parametrize("scene", ["testbed", "grasp_vertical"])
@pytest.mark.parametrize("clock", ["real", "virtual"])
def test_a_log_that_cannot_be_written_is_refused_before_the_run(
    tmp_path: Path, scene: str, clock: str
) -> None:
    """A --log whose folder cannot be made (a file stands where it would be) is one line
    naming --log and why, exit 2, before anything runs: a port scene, which writes its log
    after the run, would otherwise lose the run to a traceback."""
    (tmp_path / "taken").write_text("a file, not a folder\n")
    argv = ["haptic-run", "--scene", scene, "--clock", clock, "--duration", "1"]
    line = _the_one_error_line([*argv, "--log", "taken/run.mcap"], tmp_path)
    assert "'--log'" in line and "taken is a file, not a folder" in line, line
    assert not (tmp_path / "taken" / "run.mcap.part").exists()


def test_the_log_check_leaves_nothing_and_no_other_run_s_file_touched(tmp_path: Path) -> None:
    """check_log_writable makes the log's folder and writes a file of its own name there,
    then removes it: another run's log and its .part (written beside the log, renamed when
    whole) keep their bytes."""
    from haptic_local_model.shared.cli import check_log_writable

    log = tmp_path / "new" / "deeper" / "run.mcap"
    check_log_writable(log)
    assert log.parent.is_dir() and list(log.parent.iterdir()) == []
    other = tmp_path / "run.mcap.part"
    other.write_bytes(b"another run's rows")
    check_log_writable(tmp_path / "run.mcap")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new", "run.mcap.part"]
    assert other.read_bytes() == b"another run's rows"

"""haptic-replay: logs reproduce exactly, changes are detected, crashed logs stay usable."""

from __future__ import annotations

import json
import os
import shutil
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader

from haptic_local_model.haptic_server.harness.replay import FORCE_FIELDS, POSE_FIELDS, main, replay
from haptic_local_model.haptic_server.harness.virtual import run_virtual_named
from haptic_local_model.haptic_server.log import (
    CHUNK_SIZE,
    TICK_TOPIC,
    is_indexed,
    read_log,
    read_metadata,
)

VIRTUAL_RUNS = {  # scene: (device, user, seconds): each scene with the user it is built for
    "free_box": ("ideal", "waypoints", 3.0),
    "wall_push": ("ideal", "push_2n", 2.0),
    "testbed": ("ideal", "swing", 3.0),
    "linkage_distal": ("ideal", "push_04n", 2.0),
    "linkage_tree": ("ideal", "push_04n", 2.0),  # a tree: its update carries the CHAINS
    # a device with seeded sensor noise: its generator must replay in step
    "testbed_free_tool": ("twin_pantograph", "push_block", 2.0),
}
REAL_RUN_S = 3.0  # seconds of a real-time run after the first update arrived
UPDATE_TIMEOUT_S = 60.0
KILL_AFTER_S = 3.0
CRASH_LOSS_S = 1.0  # issue 6: a log killed at time T holds at least T - 1 s of ticks
SIDECAR_EXIT_TIMEOUT_S = 30.0
COMPARED = (*FORCE_FIELDS, *POSE_FIELDS)


def virtual_log(tmp_path: Path, scene: str) -> Path:
    device, user, seconds = VIRTUAL_RUNS[scene]
    path = tmp_path / f"{scene}.mcap"
    run_virtual_named(scene, device, user, seconds, path)
    return path


def assert_exact(path: Path, min_ticks: int) -> None:
    """Replaying the log reproduces every logged row and every update verdict exactly."""
    log = read_log(path)
    result = replay(log)
    assert len(result.ticks) == len(log.ticks) >= min_ticks
    assert result.updates_replayed == len(log.updates) > 0
    assert not result.verdict_mismatches
    assert result.differing == {}, result.differing
    for name in COMPARED:  # the headline quantities, spelled out
        assert result.max_abs_diff[name] == 0.0, name
    assert result.ticks.tobytes() == log.ticks.tobytes()  # bit for bit, NaNs included


@pytest.mark.processes
@pytest.mark.parametrize("scene", sorted(VIRTUAL_RUNS))
def test_virtual_clock_logs_replay_exactly(tmp_path: Path, scene: str) -> None:
    path = virtual_log(tmp_path, scene)
    ticks = read_log(path).ticks
    if not scene.startswith("linkage"):  # the linkages push in free space: penalties instead
        assert ticks["n_active"].max() > 0, "the run should exercise contacts"
    else:
        assert ticks["n_resisted"].max() > 0, "the run should exercise joint penalties"
    assert_exact(path, int(VIRTUAL_RUNS[scene][2] * 1000))


@pytest.mark.processes
def test_changed_gain_is_detected(tmp_path: Path) -> None:
    path = virtual_log(tmp_path, "free_box")
    log = read_log(path)
    configs = dict(log.metadata["configs"])
    original = "coordination_stiffness = [100.0, 100.0, 0.05]"
    assert original in configs["scene"]
    configs["scene"] = configs["scene"].replace(
        original, "coordination_stiffness = [101.0, 100.0, 0.05]"
    )
    result = replay(log, configs)
    assert not result.identical
    for name in ("f_coordination", "wrench_command", "device_pose", "vm_pose"):
        assert result.max_abs_diff[name] > 0.0, name
    assert replay(log).identical  # and the log's own configs still reproduce it


@pytest.mark.processes
def test_cli_summary_plot_and_exit_code(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = virtual_log(tmp_path, "wall_push")
    png = tmp_path / "run.png"
    out_json = tmp_path / "summary.json"
    code = main([str(path), "--summary", "--summary-json", str(out_json), "--plot", str(png)])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "identical" in text and str(png.resolve()) in text
    assert png.stat().st_size > 20_000  # a real figure, not an empty canvas
    summary = json.loads(out_json.read_text())
    assert summary["ticks"] == 2000 and summary["clock"] == "virtual"
    assert summary["updates_received"] == summary["updates_installed"] == 120


@pytest.mark.processes
def test_log_cut_mid_chunk_is_read_and_recovered(tmp_path: Path) -> None:
    """A writer killed mid-write leaves a file cut inside a chunk without footer or index:
    the streaming reader returns every complete chunk, replay still matches, and --recover
    rewrites it into an indexed file that make_reader reads."""
    full = virtual_log(tmp_path, "testbed")
    full_ticks = read_log(full).ticks
    with full.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    assert len(chunks) >= 4
    inside = chunks[len(chunks) // 2]
    cut_at = inside.chunk_start_offset + inside.chunk_length // 2  # in the middle of a chunk
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(full.read_bytes()[:cut_at])

    assert not is_indexed(cut)
    with cut.open("rb") as fh, pytest.raises(McapError):  # no footer: the index is unreachable
        make_reader(fh).get_summary()
    log = read_log(cut)
    at_chunk = tmp_path / "at_chunk.mcap"  # cut where the chunk starts: every chunk before
    at_chunk.write_bytes(full.read_bytes()[: inside.chunk_start_offset])
    expected_min = len(read_log(at_chunk).ticks)
    assert 0 < expected_min <= len(log.ticks) < len(full_ticks)
    np.testing.assert_array_equal(log.ticks, full_ticks[: len(log.ticks)])  # a prefix
    assert log.metadata["configs"] == read_metadata(full)["configs"]
    result = replay(log)
    assert result.identical and len(result.ticks) == len(log.ticks)

    recovered = tmp_path / "recovered.mcap"
    assert main([str(cut), "--recover", str(recovered), "--no-replay"]) == 0
    assert is_indexed(recovered)
    with recovered.open("rb") as fh:
        reader = make_reader(fh)
        rows = [m.data for _, ch, m in reader.iter_messages() if ch.topic == TICK_TOPIC]
        assert {m.name for m in reader.iter_metadata()} == {"run", "configs"}
    assert len(rows) == len(log.ticks)
    assert chunks[0].uncompressed_size <= CHUNK_SIZE * 2  # chunks stay small (crash loss)


# --- real processes -------------------------------------------------------------------------


def wait_for_logged_update(path: Path, process, timeout_s: float = UPDATE_TIMEOUT_S) -> None:  # type: ignore[no-untyped-def]
    """Wait until the growing log holds an update (the sim has connected): Zenoh peers find
    each other a few seconds after start, more on a loaded machine."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        assert process.proc.poll() is None, "the haptic server died"
        if path.exists() and read_log(path).updates:
            return
        time.sleep(0.5)
    raise AssertionError(f"no update logged within {timeout_s} s")


@pytest.mark.processes
def test_real_time_log_replays_exactly(tmp_path: Path, network_file: Path, start_server) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "rt.mcap"
    summary_path = tmp_path / "haptic.json"
    haptic = start_server(
        "haptic_local_model.haptic_server.cli", "--scene", "testbed", "--user", "swing",
        "--network",
        str(network_file), "--log", str(path), "--summary-json", str(summary_path),
    )  # fmt: skip
    haptic.wait_ready()
    start_server(
        "haptic_local_model.sim_server.cli", "--scene", "testbed", "--network", str(network_file)
    ).wait_ready()
    wait_for_logged_update(path, haptic)
    time.sleep(REAL_RUN_S)
    assert haptic.stop(signal.SIGTERM) == 0
    summary = json.loads(summary_path.read_text())
    log = read_log(path)
    assert log.indexed and len(log.ticks) == summary["ticks"]
    assert len(log.updates) == summary["updates_received"]
    assert log.metadata["run"]["clock"] == "real-time"
    assert_exact(path, int(REAL_RUN_S * 1000))
    # every update is written before its tick's row: a log cut anywhere still replays exactly
    half = tmp_path / "half.mcap"
    half.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    cut_log = read_log(half)
    assert 0 < len(cut_log.ticks) < len(log.ticks)
    assert replay(cut_log).identical


def _children(pid: int) -> list[int]:
    """The child pids of `pid` (Linux /proc), to wait for the log sidecar after a kill."""
    kids: list[int] = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        text = (task / "children").read_text().split()
        kids.extend(int(k) for k in text)
    return kids


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"


@pytest.mark.processes
def test_sigkilled_haptic_server_leaves_a_usable_log(
    tmp_path: Path,
    network_file: Path,
    start_server,  # type: ignore[no-untyped-def]
) -> None:
    """SIGKILL the haptic loop after ~3 s: its I/O sidecar notices, drains the shared ring and
    closes the file; the log holds the run up to within 1 s of the kill and replays exactly."""
    path = tmp_path / "killed.mcap"
    haptic = start_server(
        "haptic_local_model.haptic_server.cli", "--scene", "free_box", "--user",
        "constant_push", "--network",
        str(network_file), "--log", str(path),
    )  # fmt: skip
    haptic.wait_ready()
    ready_at = time.monotonic()
    sidecars = _children(haptic.proc.pid)
    assert sidecars, "the haptic server should have its I/O sidecar"
    start_server(
        "haptic_local_model.sim_server.cli", "--scene", "free_box", "--network", str(network_file)
    )
    wait_for_logged_update(path, haptic)  # so the log has updates to replay
    time.sleep(max(0.5, KILL_AFTER_S - (time.monotonic() - ready_at)))
    killed_at = time.monotonic() - ready_at
    haptic.proc.send_signal(signal.SIGKILL)
    haptic.proc.wait(10.0)
    end = time.monotonic() + SIDECAR_EXIT_TIMEOUT_S
    try:
        while any(_alive(p) for p in sidecars) and time.monotonic() < end:
            time.sleep(0.05)
        assert not any(_alive(p) for p in sidecars), "the sidecar did not finish the log"
    finally:
        for p in sidecars:
            if _alive(p):
                os.kill(p, signal.SIGKILL)
    log = read_log(path)
    assert log.indexed  # the sidecar closed the file properly
    logged_s = float(log.ticks["t"][-1] + log.ticks["dt"][-1])
    assert logged_s >= killed_at - CRASH_LOSS_S, (logged_s, killed_at)
    assert log.updates and replay(log).identical
    copy = tmp_path / "copy.mcap"
    shutil.copy(path, copy)
    assert main([str(copy), "--summary", "--no-progress"]) == 0

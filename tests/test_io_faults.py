"""Faults of the haptic server's I/O and of time, with the real processes (docs/soak.md, the
fault list of docs/security.md):

- a full disk while logging (a 3 MB filesystem the test mounts): logging stops with an event
  and exit status 3, the file keeps what was written up to the failure (readable to within
  1 s of it), rendering and networking go on to the end of the run;
- the I/O sidecar starved (SIGSTOP for 0.5 s): the device is safe within 50 ms of the
  watchdog, the loop says so (`io_stalled`) and resumes with the sidecar (`io_resumed`);
  killed (SIGKILL): the loop says so within a watchdog period and a check, stops the run
  with the device safe, exit status 1;
- the loop itself stopped (SIGSTOP for 0.5 s) while its user pushes on a wall: it resumes
  on the sim's newest update, its first tick's dt clamped, the command's step 10 mN (the
  fade's bound: 10 N) and its largest 6 % above the steady push (bound: 10 %);
- a group SIGKILL leaves the shared-memory segment in /dev/shm: the next server's start
  removes it (a live server's is kept);
- the sim's clock stepped by +-10 s for 1 s (NTP stepping one host): its updates are refused
  as future or late, the device is safe within 50 ms of the watchdog, and rendering comes
  back without a force jump once the clock is right again.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_faults import (
    FADE_STEP_BOUND_N,
    SAFE_WITHIN_S,
    Log,
    ProxyWatch,
    descendants,
    haptic_args,
    report,
    resumption_step,
    safe_decay_s,
    server_args,
)

from haptic_local_model.haptic_server.log import read_log
from haptic_local_model.haptic_server.loop import DT_CLAMP
from haptic_local_model.haptic_server.mailbox import SEGMENT_PREFIX, SHM_DIR, sweep_segments

REPO = Path(__file__).resolve().parent.parent
FULL_FS_BYTES = 3 * 1024 * 1024  # an 8 s run's log is larger
RUN_S = 8.0
STALL_S = 0.5
JUMP_AT_S, JUMP_FOR_S, JUMP_MS = 2.0, 1.0, 10_000.0


@pytest.fixture
def small_filesystem(tmp_path: Path) -> Any:
    """A 3 MB tmpfs mounted for the test (root only; CI requires it: .ci/run)."""
    mount = tmp_path / "small"
    mount.mkdir()
    res = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={FULL_FS_BYTES}", "tmpfs", str(mount)],
        capture_output=True, text=True,
    )  # fmt: skip
    if res.returncode != 0:
        if os.environ.get("HAPTIC_REQUIRE_MOUNT"):
            pytest.fail(f"cannot mount a tmpfs: {res.stderr.strip()}")
        pytest.skip(f"cannot mount a tmpfs here: {res.stderr.strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


@pytest.mark.processes
def test_a_full_disk_stops_logging_not_the_run(tmp_path: Path, small_filesystem: Path) -> None:
    log = small_filesystem / "run.mcap"
    summary_path = tmp_path / "summary.json"
    res = subprocess.run(
        [
            sys.executable, "-m", "haptic_local_model.haptic_server.harness.run", "--scene",
            "testbed",
            "--duration", str(RUN_S), "--log", str(log), "--summary-json", str(summary_path),
            "--json-events",
        ],
        cwd=tmp_path, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert res.returncode == 3, res.stderr
    assert "logging stopped" in res.stderr and "Traceback" not in res.stderr, res.stderr
    summary: dict[str, Any] = json.loads(summary_path.read_text())
    assert "no space left" in summary["log_failed"].lower(), summary["log_failed"]
    assert summary["exit_codes"] == {"haptic": 3, "sim": 0}
    # the event, for programs that follow the run: haptic-run passes its servers' lines on
    # (not JSON: a JSON line of a child is an event haptic-run reads)
    # networking went on to the end: the sim's updates installed, proxy states published
    sim_steps = summary["sim"]["steps"]
    assert summary["updates_installed"] >= 0.95 * sim_steps
    assert summary["proxy_published"] >= 0.9 * RUN_S * 250.0
    # the file keeps what was written up to the failure, to within 1 s of it
    written = read_log(log)
    assert not written.indexed  # cut short: no footer
    logged = len(written.ticks)
    assert np.all(np.diff(written.ticks["tick"].astype(np.int64)) == 1)
    failed_at = summary["ticks"] - summary["lost_log_ticks"]
    rate = summary["tick_rate_hz"]
    assert logged >= failed_at - rate, f"{logged} ticks logged, the failure at {failed_at}"
    assert logged < summary["ticks"]


def _sidecar(haptic_pid: int) -> int:
    """The haptic server's I/O sidecar (a multiprocessing child of it)."""
    for pid in descendants(haptic_pid):
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ")
        if b"spawn_main" in cmdline:
            return pid
    raise AssertionError("no I/O sidecar")


def _both(start_server: Any, network_file: Path, log_path: Path, summary_path: Path) -> Any:
    """The haptic server (logging to log_path), then the sim, each ready."""
    haptic = start_server(
        "haptic_local_model.haptic_server.cli", *haptic_args(network_file, log_path, summary_path)
    )
    haptic.wait_ready()
    sim = start_server("haptic_local_model.sim_server.cli", *server_args(network_file))
    sim.wait_ready()
    return haptic, sim


def _logged_event(log_path: Path, kind: str, timeout_s: float = 20.0) -> None:
    """Wait until the log being written holds an event of `kind` (the log writer flushes
    small chunks often: a cut-short read sees every complete record)."""
    end = time.monotonic() + timeout_s
    while not any(e["kind"] == kind for e in read_log(log_path).events):
        if time.monotonic() > end:
            raise AssertionError(f"no {kind} event logged within {timeout_s:g} s")
        time.sleep(0.1)


@pytest.mark.processes
def test_a_starved_then_killed_sidecar(
    tmp_path: Path, network_file: Path, start_server: Any
) -> None:
    log_path, summary_path = tmp_path / "h.mcap", tmp_path / "h.json"
    haptic, sim = _both(start_server, network_file, log_path, summary_path)
    epoch = sim.events[0]["epoch"]
    watch = ProxyWatch(network_file)
    try:
        watch.rendering(epoch)
        sidecar = _sidecar(haptic.proc.pid)
        os.kill(sidecar, signal.SIGSTOP)
        time.sleep(STALL_S)
        os.kill(sidecar, signal.SIGCONT)
        watch.rendering(epoch, after_seq=watch.rendering(epoch).update_seq)
    finally:
        watch.close()
    # the loop looks at its sidecar every IO_CHECK_S: killed sooner after it woke, the
    # resumption is never seen (a clean-clone CI run killed it first); wait until it is said
    _logged_event(log_path, "io_resumed")
    os.kill(sidecar, signal.SIGKILL)
    assert haptic.proc.wait(10.0) == 1  # the loop noticed, stopped the run, said so
    assert sim.stop() == 0
    summary = json.loads(summary_path.read_text())
    assert summary["io_lost"]
    log = Log.read(log_path)
    kinds = [e["kind"] for e in log.events]
    assert "io_stalled" in kinds and "io_resumed" in kinds and "io_lost" in kinds, kinds
    # said once per stall: the stop's, and any the machine's load added after it (a 2-core
    # CI host starved the resumed sidecar a second time once), each ended by a resumption
    # but a last one the kill cut short
    stalls, resumed = kinds.count("io_stalled"), kinds.count("io_resumed")
    assert summary["io_stalls"] == stalls >= 1 and stalls - resumed in (0, 1), kinds
    trip = log.event_ticks("watchdog")[0]
    stalled = log.event_ticks("io_stalled")[0]
    clear = log.event_ticks("watchdog_clear")[0]
    decay = safe_decay_s(log, trip, clear)
    assert decay is not None and decay <= SAFE_WITHIN_S
    period_ticks = 1e-3 * 100.0 / float(np.median(log.ticks["dt"]))  # the watchdog, in ticks
    assert stalled - trip <= period_ticks + 60  # said within a watchdog period and a check
    assert resumption_step(log, clear) <= FADE_STEP_BOUND_N
    lost = log.event_ticks("io_lost")[0]
    assert log.ticks["tick"][-1] - lost <= 200  # stopped at once: the ramp to safe, the stop
    assert log.ticks["safe"][-1] == 1.0


@pytest.mark.processes
def test_a_group_kill_leaves_a_segment_the_next_start_removes(network_file: Path) -> None:
    argv = [
        sys.executable,
        "-m",
        "haptic_local_model.haptic_server.cli",
        *server_args(network_file),
    ]
    first = subprocess.Popen(argv, cwd=REPO, stdout=subprocess.PIPE, start_new_session=True)
    try:
        assert first.stdout is not None
        assert b'"ready"' in first.stdout.readline()
        mine = sorted(SHM_DIR.glob(f"{SEGMENT_PREFIX}{first.pid}-*"))
        assert len(mine) == 1
        os.killpg(first.pid, signal.SIGKILL)
        first.wait(10.0)
        time.sleep(0.5)  # its I/O processes die with their group
        assert mine[0].exists(), "nothing left to sweep"
    finally:
        if first.poll() is None:
            os.killpg(first.pid, signal.SIGKILL)
            first.wait()
    live = subprocess.Popen(argv, cwd=REPO, stdout=subprocess.PIPE, start_new_session=True)
    try:
        assert live.stdout is not None
        assert b'"ready"' in live.stdout.readline()
        assert not mine[0].exists(), "the dead server's segment was not removed"
        assert list(SHM_DIR.glob(f"{SEGMENT_PREFIX}{live.pid}-*")), "the live one's is gone"
        assert sweep_segments() == []  # a live server's segment is never swept
    finally:
        live.send_signal(signal.SIGTERM)
        assert live.wait(30.0) == 0
    assert not list(SHM_DIR.glob(f"{SEGMENT_PREFIX}{live.pid}-*")), "left in /dev/shm"


@pytest.mark.processes
@pytest.mark.parametrize("jump_ms", [JUMP_MS, -JUMP_MS], ids=["ahead", "behind"])
def test_a_clock_step_of_the_sim(
    tmp_path: Path, network_file: Path, start_server: Any, jump_ms: float
) -> None:
    log_path, summary_path = tmp_path / "h.mcap", tmp_path / "h.json"
    haptic = start_server(
        "haptic_local_model.haptic_server.cli", *haptic_args(network_file, log_path, summary_path)
    )
    haptic.wait_ready()
    jump = f"{JUMP_AT_S},{jump_ms},{JUMP_FOR_S}"
    sim = start_server(
        "haptic_local_model.sim_server.cli", *server_args(network_file, "--inject-clock-jump", jump)
    )
    sim.wait_ready()
    time.sleep(JUMP_AT_S + JUMP_FOR_S + 1.5)
    assert haptic.stop() == 0
    assert sim.stop() == 0
    log = Log.read(log_path)
    reasons = {u["reason"] for u in log.updates if not u["installed"]}
    assert reasons == {"future" if jump_ms > 0 else "late"}, reasons
    trips, clears = log.event_ticks("watchdog"), log.event_ticks("watchdog_clear")
    assert len(trips) == len(clears) == 1
    decay = safe_decay_s(log, trips[0], clears[0])
    assert decay is not None and decay <= SAFE_WITHIN_S
    assert resumption_step(log, clears[0]) <= FADE_STEP_BOUND_N
    outage_s = float(log.row(clears[0])[0]["t"] - log.row(trips[0])[0]["t"])
    assert outage_s <= JUMP_FOR_S + 0.2  # back with the clock's first right update


@pytest.mark.processes
def test_the_loop_stalled_resumes_without_a_jump(
    tmp_path: Path, network_file: Path, start_server: Any
) -> None:
    """The haptic server's own loop stopped (SIGSTOP) for 0.5 s while its user pushes (issue
    48): it resumes on the sim's newest update in its first tick, without a watchdog trip
    (the silence was the loop's, not the sim's: the backlog is judged first), its first
    tick's dt clamped (DT_CLAMP), no command step above the fade's bound and no command
    above the pre-stall push + 10 %.
    (A simulated device stops with the loop; a real one holds the last command through the
    stall: its driver's own watchdog is what bounds that, docs/devices.md.)"""
    log_path, summary_path = tmp_path / "h.mcap", tmp_path / "h.json"
    haptic, sim = _both(start_server, network_file, log_path, summary_path)
    watch = ProxyWatch(network_file)
    try:
        watch.rendering(sim.events[0]["epoch"])
        time.sleep(6.0)  # pushing steadily on the wall (the impact settled: issue 47)
        os.kill(haptic.proc.pid, signal.SIGSTOP)
        time.sleep(STALL_S)
        os.kill(haptic.proc.pid, signal.SIGCONT)
        time.sleep(1.5)
    finally:
        os.kill(haptic.proc.pid, signal.SIGCONT)
        watch.close()
    assert haptic.stop() == 0
    assert sim.stop() == 0
    log = Log.read(log_path)
    ticks = log.ticks
    k = int(np.argmax(ticks["lateness_us"]))  # the tick the stall made late
    assert ticks["lateness_us"][k] >= 0.8e6 * STALL_S
    # (before the backlog was judged first, the watchdog tripped here and the proxy's
    # re-initialisation 3 ticks later overshot the push by 50 % on a loaded CI host)
    assert not log.event_ticks("watchdog"), log.events
    newest = max(u["seq"] for u in log.updates if u["tick"] <= k)
    assert [u["seq"] for u in log.updates if u["tick"] == k and u["installed"]][-1] == newest
    assert ticks["dt"][k] <= DT_CLAMP[1] * 1e-3 + 1e-12
    command = ticks["wrench_command"][:, :2]
    pushed = np.abs(command[k - 500 : k]).max(axis=0)
    steady = np.abs(np.diff(command[k - 500 : k], axis=0)).max()
    after = command[k : k + 1000]
    step = np.abs(np.diff(command[k - 1 : k + 1000], axis=0)).max()
    report("loop stalled", stall_s=STALL_S, step_n=step, steady_step_n=steady,
           pushed_n=pushed.tolist(), after_max_n=np.abs(after).max(axis=0).tolist())  # fmt: skip
    assert steady < 1e-3 and step <= FADE_STEP_BOUND_N, (step, steady)  # a steady push before
    assert np.all(np.abs(after).max(axis=0) <= 1.1 * pushed + 1e-3), (after, pushed)


@pytest.mark.processes
def test_a_log_writer_that_cannot_open_its_file_stops_the_start_once(
    tmp_path: Path, network_file: Path
) -> None:
    """The log writer and the sidecar start side by side: a writer that cannot open its file
    (its folder cannot be made) keeps the loop from starting, said once as the writer not
    starting with the writer's reason, exit 1, no traceback. The sidecar, which saw the
    writer fail, does not say that logging stopped with rendering going on (it never
    started), and closing the I/O process after the refusal raises nothing more."""
    res = subprocess.run(
        [
            sys.executable, "-m", "haptic_local_model.haptic_server.cli", "--scene", "testbed",
            "--network", str(network_file), "--duration", "1",
            "--log", "/proc/no-such-dir/run.mcap",
        ],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert res.returncode == 1, res.stderr[-2000:]
    assert "Traceback" not in res.stderr, res.stderr[-2000:]
    # one line: the writer's own reason, said by the server, not the writer's traceback
    assert res.stderr.strip().splitlines()[-1] == (
        "haptic-server: the log writer did not start (/proc/no-such-dir/run.mcap): "
        "[Errno 2] No such file or directory: '/proc/no-such-dir'"
    ), res.stderr
    assert "rendering goes on" not in res.stdout + res.stderr
    assert "TypeError" not in res.stderr and '"event": "ready"' not in res.stdout

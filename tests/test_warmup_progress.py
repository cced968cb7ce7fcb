"""`make warm` (python -m haptic_local_model.haptic_server.harness.warmup) says what it
compiles: a line per group of kernels on stderr (what, how long, compiled or loaded from the
cache) and the total, at most ten lines; `--quiet` and library calls print nothing. The
groups are faked here (the real ones compile for a minute on a cold cache); that they cover
every warm run is checked."""

from __future__ import annotations

import os
from functools import partial
from pathlib import Path

import pytest

from haptic_local_model.haptic_server.harness import warmup
from haptic_local_model.haptic_server.harness.warm_marks import (
    ALL_WARMED,
    KEEP_BUILDS,
    MAX_UNUSED_DAYS,
    Run,
    mark_used,
    mark_warmed,
    prune_builds,
    run_key,
    runs_warmed,
)


@pytest.fixture
def fake_groups(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Two groups: the first 'compiles' (writes a kernel into the cache), the second loads."""
    cache = tmp_path / "numba"
    cache.mkdir()
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(cache))

    def compile_one() -> None:
        (cache / "kernel-12.py311.1.nbc").write_bytes(b"x")

    groups = [("scene kernels", compile_one), ("device kernels", lambda: None)]
    monkeypatch.setattr(warmup, "warm_groups", lambda run=None: groups)
    return cache


def test_a_line_per_group_and_the_total_on_stderr(
    fake_groups: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert warmup.main([]) == 0
    out, err = capsys.readouterr()
    assert out == ""
    lines = err.splitlines()
    assert len(lines) == 4, err
    assert str(fake_groups) in lines[0]
    assert lines[1].startswith("  scene kernels ...") and "(compiled, 1 cached)" in lines[1]
    assert lines[2].startswith("  device kernels ...") and "(loaded from the cache)" in lines[2]
    assert lines[1].split("...")[1].strip().split()[1] == "s"  # "<seconds> s (...)"
    assert lines[3].startswith("numba kernels ready in ")


def test_quiet_and_library_calls_print_nothing(
    fake_groups: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert warmup.main(["--quiet"]) == 0
    assert warmup.warm_all() >= 0.0
    assert capsys.readouterr() == ("", "")


def test_the_groups_cover_every_warm_run_in_at_most_ten_lines() -> None:
    groups = warmup.warm_groups()
    assert len(groups) + 2 <= 10  # the groups, a first line and the total
    covered = [
        run
        for _, call in groups
        if isinstance(call, partial) and call.func is warmup._run_virtual
        for run in call.args[0]
    ]
    assert sorted(covered) == sorted(warmup.warm_runs())
    assert any(call is warmup._loop_kernels for _, call in groups)


def test_the_demo_warms_the_run_make_demo_starts() -> None:
    """`make warm-demo` compiles the kernels of haptic-run's defaults (a scene of one device:
    shared.cli's defaults), and the real-time loop's for that device."""
    import argparse

    from haptic_local_model.shared.cli import add_config_args

    parser = argparse.ArgumentParser()
    add_config_args(parser)
    defaults = parser.parse_args([])
    scene, device, user, _ = warmup.DEMO_RUN
    assert (defaults.scene, defaults.device, defaults.user) == (scene, device, user)
    (_, updates), (_, loop) = warmup.run_groups(warmup.DEMO_RUN)
    assert isinstance(updates, partial) and updates.func is warmup._updates_lane
    assert isinstance(loop, partial) and loop.func is warmup._loop_lane
    assert updates.args == loop.args == (warmup.DEMO_RUN,)


def test_a_cold_run_compiles_first_once_and_says_where(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """haptic-run's first run of a scene and device on a build compiles their kernels before
    either server starts (run.compile_first), says so with the cache's place, and marks
    them warmed; `make warm` marks every run warmed."""
    import argparse

    from haptic_local_model.haptic_server.harness import run as run_cli

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    calls = []

    def fake_warm(out: object, jobs: int = 1, run: Run | None = None) -> float:
        calls.append((jobs, run))
        mark_warmed(tmp_path, run_key(run) if run else ALL_WARMED)
        return 0.0

    monkeypatch.setattr(warmup, "warm_all", fake_warm)
    args = argparse.Namespace(scene="testbed", device="ideal", user="swing")
    assert not runs_warmed(warmup.DEMO_RUN)
    run_cli.compile_first(args)
    run_cli.compile_first(args)  # warmed now: nothing more
    assert calls == [(2, warmup.DEMO_RUN)]
    err = capsys.readouterr().err
    assert err.count("the first run of testbed with ideal") == 1 and str(tmp_path) in err
    other = ("god_slabs", "maglev", "press_lift", 1.0)
    assert not runs_warmed(other)
    mark_warmed(tmp_path, ALL_WARMED)
    assert runs_warmed(other)


def test_the_cold_start_benchmark_reads_what_the_warm_up_prints(
    fake_groups: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """benchmarks/cold_start.py reads make demo's output for the kernels a warm-up compiled
    and each group's seconds: the lines warm_all writes."""
    from haptic_local_model.benchmarks.cold_start import _kernels, _parts

    assert warmup.main([]) == 0
    err = capsys.readouterr().err
    assert _kernels(err) == 1
    parts = _parts(err)
    assert set(parts) == {"scene kernels", "device kernels", "warm-up total"}
    assert all(v >= 0.0 for v in parts.values())
    assert _kernels("numba kernels ready in 0.4 s (all loaded from the cache)") == 0


def test_old_builds_caches_are_pruned_and_the_users_own_cache_is_left_alone(
    tmp_path: Path,
) -> None:
    """Beside the build in use, the KEEP_BUILDS most recently used builds' caches stay, and
    of those only the ones used within MAX_UNUSED_DAYS; other folders are never touched, and
    neither is anything when the cache in use is one the user chose elsewhere."""
    root = tmp_path / "numba"
    now = 1_000_000_000.0
    day = 86400.0

    def build(name: str, used_days_ago: float) -> Path:
        folder = root / name
        (folder / "shared").mkdir(parents=True)
        (folder / "shared" / "kernel.nbc").write_bytes(b"x" * 1000)
        mark_used(folder)
        os.utime(folder / "used", (now - used_days_ago * day,) * 2)
        return folder

    current = build("0123456789ab", 400.0)  # in use: never removed, however old its mark
    recent = [build(f"{k:012x}", k) for k in range(1, KEEP_BUILDS + 2)]  # 1..5 days ago
    stale = build("fedcba987654", MAX_UNUSED_DAYS + 1)
    (root / "notes").mkdir()  # not a build's cache
    removed = prune_builds(current, root, now)
    assert {p for p, _ in removed} == {recent[-1], stale}
    assert all(size == 1000 for _, size in removed)
    assert current.exists() and (root / "notes").exists()
    assert all(p.exists() for p in recent[:KEEP_BUILDS])
    assert prune_builds(tmp_path / "mine" / "0123456789ab", root, now) == []
    assert all(p.exists() for p in recent[:KEEP_BUILDS])

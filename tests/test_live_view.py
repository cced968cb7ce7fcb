"""The live view in a real browser: headless Chromium (Debian's package) driven by Playwright
opens the view of a real run (haptic-run --view: both servers, Zenoh on loopback) and of a
replayed log (haptic-replay LOG --view), and finds the scene drawn and moving.

The Rerun viewer draws into a WebGL canvas, so "drawn" is read off the screenshot: the
colours the view gives the static bodies, the linkage, the device and the proxy are there,
and the scene differs between two samples a second apart. The screenshots are kept as test
artifacts (HAPTIC_TEST_ARTIFACTS, default runs/test-artifacts). Without a browser the test
skips, unless HAPTIC_REQUIRE_BROWSER is set (CI sets it: there it must run).
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from haptic_local_model.benchmarks.browser import (
    chromium,
    colour_count,
    free_ports,
    open_page,
    pixels,
)
from haptic_local_model.haptic_server.live_view import _DEVICE, _LINKAGE, _PROXY, _STATIC

ROOT = Path(__file__).resolve().parents[1]
ARTIFACTS = Path(os.environ.get("HAPTIC_TEST_ARTIFACTS", ROOT / "runs" / "test-artifacts"))
SCENE = (slice(60, 770), slice(0, 790))  # the scene's view in the layout, in a 1200x800 page
SETTLE_S = 8.0  # the viewer loads its wasm, connects and catches up
URL_TIMEOUT_S = 120.0


def _browser() -> str:
    path = chromium()
    try:
        import playwright  # noqa: F401
    except ImportError:
        path = None
    if path is None:
        if os.environ.get("HAPTIC_REQUIRE_BROWSER"):
            pytest.fail("HAPTIC_REQUIRE_BROWSER is set but Chromium or Playwright is missing")
        pytest.skip("no Chromium (apt-get install chromium) or Playwright")
    return path


class Proc:
    """A command whose stderr lines are collected on a thread (and passed through)."""

    def __init__(self, argv: list[str], cwd: Path) -> None:
        self.proc = subprocess.Popen(
            argv, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        self.lines: list[str] = []
        self.out: list[str] = []
        threading.Thread(
            target=self._read, args=(self.proc.stderr, self.lines), daemon=True
        ).start()
        threading.Thread(target=self._read, args=(self.proc.stdout, self.out), daemon=True).start()

    @staticmethod
    def _read(stream: object, into: list[str]) -> None:
        for line in stream:  # type: ignore[attr-defined]
            into.append(line)
            sys.stderr.write(line)

    def url(self) -> str:
        end = time.monotonic() + URL_TIMEOUT_S
        while time.monotonic() < end:
            for line in list(self.lines):
                if line.startswith("live view: http"):
                    return line.split("live view: ", 1)[1].strip()
            assert self.proc.poll() is None, f"exited {self.proc.returncode}: {self.lines}"
            time.sleep(0.2)
        raise AssertionError(f"no live view URL in {URL_TIMEOUT_S} s: {self.lines}")

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            return self.proc.wait(60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(10)
            raise


@pytest.fixture
def procs() -> Iterator[list[Proc]]:
    started: list[Proc] = []
    yield started
    for p in started:  # stopped by their own pid, whatever the test did
        if p.proc.poll() is None:
            p.proc.kill()
            p.proc.wait(10)


def _samples(url: str, name: str, browser: str) -> tuple[np.ndarray, np.ndarray]:
    """Two screenshots of the view a second and a half apart (kept as artifacts)."""
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    with open_page(url, browser) as page:
        time.sleep(SETTLE_S)
        first = page.screenshot()
        time.sleep(1.5)
        second = page.screenshot()
    (ARTIFACTS / f"{name}-1.png").write_bytes(first)
    (ARTIFACTS / f"{name}-2.png").write_bytes(second)
    return pixels(first)[SCENE], pixels(second)[SCENE]


def _assert_scene_drawn(img: np.ndarray, what: str) -> None:
    counts = {
        "static bodies": colour_count(img, _STATIC),
        "linkage": colour_count(img, _LINKAGE),
        # the device and the proxy, drawn over it: where they coincide, a ring of the first
        "device and proxy": colour_count(img, _DEVICE, tol=20) + colour_count(img, _PROXY, tol=20),
    }
    # the enclosure's walls are long strips; the linkage three links; the tool two discs
    floors = {"static bodies": 2000, "linkage": 200, "device and proxy": 60}
    missing = {k: v for k, v in counts.items() if v < floors[k]}
    assert not missing, f"{what}: too few pixels of {missing} (floors {floors}; all {counts})"


def _changed(a: np.ndarray, b: np.ndarray) -> int:
    return int(np.count_nonzero(np.abs(a.astype(np.int16) - b.astype(np.int16)).max(-1) > 30))


@pytest.mark.processes
def test_live_view_of_a_real_run_and_of_its_log(tmp_path: Path, procs: list[Proc]) -> None:
    browser = _browser()
    web, grpc = free_ports(2)
    run = Proc(
        [sys.executable, "-m", "haptic_local_model.haptic_server.harness.run", "--duration", "30",
         "--log", "run.mcap", "--view", "--view-port", str(web), "--view-grpc-port", str(grpc)],
        tmp_path,
    )  # fmt: skip
    procs.append(run)
    url = run.url()
    assert f":{web}/" in url and f":{grpc}/" in url and "127.0.0.1" in url
    first, second = _samples(url, "live-run", browser)
    _assert_scene_drawn(first, "live run")
    _assert_scene_drawn(second, "live run")
    moved = _changed(first, second)
    assert moved > 100, f"the live view did not change between two samples ({moved} pixels)"
    assert run.stop() == 0, run.lines
    stats = [line for line in run.lines if "frames in" in line]
    assert stats, "the view did not report its frames"
    frames = int(stats[0].split("live view: ", 1)[1].split()[0])
    assert frames > 60, stats[0]  # >= 1 s of frames at 60 Hz
    for port in (web, grpc):  # the Rerun server went with the run
        with socket.socket() as s:
            assert s.connect_ex(("127.0.0.1", port)) != 0, f"port {port} still open"

    web, grpc = free_ports(2)
    replay = Proc(
        [sys.executable, "-m", "haptic_local_model.haptic_server.harness.replay", "run.mcap",
        "--view",
         "--view-port", str(web), "--view-grpc-port", str(grpc), "--view-seconds", "120",
         "--view-speed", "1"],
        tmp_path,
    )  # fmt: skip
    procs.append(replay)
    first, second = _samples(replay.url(), "replay", browser)
    _assert_scene_drawn(first, "replay")
    assert _changed(first, second) > 100, "the replayed view did not move at 1x log time"
    assert replay.stop() == 0, replay.lines
    assert any("frames drawn" in line for line in replay.out), replay.out


@pytest.mark.processes
def test_view_options_are_checked() -> None:
    """--view with the virtual clock, and one port for both, are usage errors (exit 2)."""
    for argv in (
        ["--clock", "virtual", "--view", "--duration", "1"],
        ["--view", "--view-port", "9100", "--view-grpc-port", "9100", "--duration", "1"],
    ):
        out = subprocess.run(
            [sys.executable, "-m", "haptic_local_model.haptic_server.harness.run", "--no-log",
            *argv],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert out.returncode == 2, out
        assert "--view" in out.stderr and "Traceback" not in out.stderr


def test_a_view_without_the_rerun_sdk_says_what_to_install(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The Rerun SDK is an extra (`[view]`): --view without it is refused on the command
    line, naming the option and what installs it; without --view nothing asks for it."""
    import argparse
    import importlib.util

    from haptic_local_model.haptic_server import view_address as va
    from haptic_local_model.shared.config import ConfigError

    parser = argparse.ArgumentParser()
    va.add_view_args(parser)
    found = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "rerun" else found(name, *a)
    )
    assert va.view_address(parser.parse_args([])) is None
    with pytest.raises(ConfigError) as refused:
        va.view_address(parser.parse_args(["--view"]))
    assert "--view" in str(refused.value) and "haptic-local-model[view]" in str(refused.value)
    monkeypatch.setattr(importlib.util, "find_spec", found)
    assert va.view_address(parser.parse_args(["--view"])) == va.ViewAddress()


@pytest.mark.processes
def test_a_file_without_ticks_is_refused(tmp_path: Path) -> None:
    """haptic-replay NOT_A_LOG --view: one line naming the file, exit 2, no server left."""
    bogus = tmp_path / "notes.mcap"
    bogus.write_text("not a log\n")
    web, grpc = free_ports(2)
    out = subprocess.run(
        [sys.executable, "-m", "haptic_local_model.haptic_server.harness.replay", str(bogus),
        "--view",
         "--view-port", str(web), "--view-grpc-port", str(grpc), "--view-seconds", "5"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert out.returncode == 2, out
    assert str(bogus) in out.stderr and "Traceback" not in out.stderr

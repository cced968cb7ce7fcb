"""Shared fixtures: loopback endpoints on free ports, process helpers that always clean up."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import sysconfig
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import settings

from haptic_local_model.shared.net.config import free_loopback_port

pytest_plugins = ["pytester"]  # tests/test_tiers.py runs a pytest of its own

# hypothesis's per-example deadline (200 ms) is a timing claim: on a loaded 2-core machine it
# fails the example a preemption lands in, not the code. Time belongs to the tiers (below)
# and to the benchmarks.
settings.register_profile("suite", deadline=None)
settings.load_profile("suite")

REPO = Path(__file__).resolve().parent.parent
READY_TIMEOUT_S = 300.0  # a cold numba cache compiles for a while on 2 cores


free_port = free_loopback_port  # the tests' name for it


@pytest.fixture(scope="session", autouse=True)
def local_credentials_of_the_tests(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """ "@local" credentials (shared/net/credentials.py) made for the test session, not in the
    user's config directory: every process a test starts inherits the variable."""
    folder = tmp_path_factory.mktemp("home") / "credentials"
    before = os.environ.get("HAPTIC_CREDENTIALS_DIR")
    os.environ["HAPTIC_CREDENTIALS_DIR"] = str(folder)
    yield folder
    if before is None:
        os.environ.pop("HAPTIC_CREDENTIALS_DIR", None)
    else:
        os.environ["HAPTIC_CREDENTIALS_DIR"] = before


@pytest.fixture
def network_file(tmp_path: Path) -> Path:
    """The default network (this installation's credentials, access control) on a free
    port, so tests never collide."""
    return write_network_file(tmp_path / "net.toml")


def write_network_file(path: Path) -> Path:
    """network_file's config at `path` (for fixtures of a wider scope)."""
    port = free_port()
    path.write_text(
        f'namespace = "haptic/test{port}"\n'
        "[haptic]\n"
        f'listen = ["tcp/127.0.0.1:{port}"]\n'
        'users_file = "@local"\n'
        'sim_users = ["sim"]\n'
        "[sim]\n"
        f'connect = ["tcp/127.0.0.1:{port}"]\n'
        'user = "sim"\n'
        'password_file = "@local"\n'
    )
    return path


def haptic_run(
    network_file: Path,
    log: Path,
    summary_path: Path,
    *,
    scene: str,
    device: str,
    user: str,
    seconds: float,
) -> dict[str, Any]:
    """Run `haptic-run` (both servers as processes over `network_file`) to the end; checks it
    and both servers exited 0, and returns its summary."""
    res = subprocess.run(
        [
            sys.executable, "-m", "haptic_local_model.haptic_server.harness.run", "--scene",
            scene, "--device", device,
            "--user", user, "--network", str(network_file), "--duration", str(seconds),
            "--log", str(log), "--summary-json", str(summary_path),
        ],
        cwd=REPO, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr + res.stdout
    summary: dict[str, Any] = json.loads(summary_path.read_text())
    assert summary["exit_codes"] == {"haptic": 0, "sim": 0}
    return summary


class ServerProcess:
    """A server started by a test: JSON event lines read on a thread; stopped by its pid."""

    def __init__(self, argv: list[str]) -> None:
        self.proc = subprocess.Popen(argv, cwd=REPO, stdout=subprocess.PIPE, text=True)
        self.events: list[dict[str, Any]] = []
        self._ready = threading.Event()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            try:
                event = json.loads(line)
            except json.JSONDecodeError:
                continue
            self.events.append(event)
            if event.get("event") == "ready":
                self._ready.set()

    def wait_ready(self, timeout: float = READY_TIMEOUT_S) -> None:
        end = time.monotonic() + timeout
        while not self._ready.wait(0.1):
            if self.proc.poll() is not None or time.monotonic() > end:
                raise AssertionError(f"{self.proc.args} not ready (exit {self.proc.poll()})")

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 30.0) -> int:
        if self.proc.poll() is None:
            os.kill(self.proc.pid, sig)
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            os.kill(self.proc.pid, signal.SIGKILL)
            return self.proc.wait()


@pytest.fixture
def start_server() -> Iterator[Any]:
    """Start `python -m <module> args...`; every process is stopped at teardown by its pid."""
    started: list[ServerProcess] = []

    def start(module: str, *args: str) -> ServerProcess:
        p = ServerProcess([sys.executable, "-m", module, *args])
        started.append(p)
        return p

    yield start
    for p in started:
        p.stop(signal.SIGKILL if p.proc.poll() is None else signal.SIGTERM, timeout=10.0)


# The project as a user installs it (tests/test_install.py, tests/test_plugins.py): a wheel
# built from a copy of the sources, in a fresh virtual environment of its own.
#: what a build never needs: outputs, caches, environments
UNSHIPPED = (".git", ".venv", "build", "runs", "*.egg-info", "__pycache__", ".*_cache", "tests")


@pytest.fixture(scope="session")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The project's wheel, built as `pip install .` builds it, from a copy of the sources
    (setuptools reuses a tree's build/lib: a stale one would slip old packages in)."""
    wheels = tmp_path_factory.mktemp("wheels")
    source = tmp_path_factory.mktemp("source") / "project"
    shutil.copytree(REPO, source, ignore=shutil.ignore_patterns(*UNSHIPPED))
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(wheels), str(source)],
        check=True, timeout=600,
    )  # fmt: skip
    (built,) = wheels.glob("haptic_local_model-*.whl")
    return built


@pytest.fixture(scope="session")
def installed(tmp_path_factory: pytest.TempPathFactory, wheel: Path) -> Path:
    """A fresh virtual environment with the project's wheel installed (not editable). Its
    dependencies come from this environment's site-packages as a plain path (a .pth line):
    that adds numpy, numba, ... but not this environment's editable install of the project,
    whose finder only a site directory's own .pth files would load."""
    root = tmp_path_factory.mktemp("install")
    venv = root / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    py = venv / "bin" / "python"
    subprocess.run(
        [str(py), "-m", "pip", "install", "--quiet", "--no-deps", str(wheel)],
        check=True, timeout=600,
    )  # fmt: skip
    site = subprocess.run(
        [str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True, capture_output=True, text=True,
    ).stdout.strip()  # fmt: skip
    (Path(site) / "project_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    return venv


def run_installed(
    venv: Path, cwd: Path, *argv: str, timeout: float = 900
) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    exe = venv / "bin" / argv[0]
    return subprocess.run(
        [str(exe), *argv[1:]], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout
    )


class Ring:
    """A subscriber's ring of raw messages, as zenoh's try_recv gives them: a loop's
    `newest_payload` reads it as it reads a ring-channel subscriber (no network)."""

    def __init__(self, messages: list[bytes]) -> None:
        self.messages = list(messages)

    def try_recv(self) -> Any:
        if not self.messages:
            return None
        raw = self.messages.pop(0)
        payload = type("Payload", (), {"to_bytes": lambda _self: raw})()
        return type("Sample", (), {"payload": payload})()


@pytest.fixture
def ring() -> type[Ring]:
    """Ring: messages as a subscriber delivers them, for a loop's taking step."""
    return Ring


# --- tiers ----------------------------------------------------------------------------------
# The fast tier (`make check`: -m "not slow and not processes") is what a developer runs
# before each commit. A test outside it carries its marker: `processes` if it starts a
# process or opens a socket or a Zenoh session, `slow` if it sleeps or runs for more than
# FAST_S. Enforced here: an unmarked test that does one of those fails and says which marker
# it needs. Its time is measured less what numba spent compiling or loading kernels in it (a
# cold cache is not the test's) and less the time its thread waited for a CPU while another
# process ran (Linux's schedstat: a loaded machine's time, not the test's; a fast test of
# 0.7 s took 2.2 s on a machine running the suite beside other work), and fails only past
# OVERRUN_S: twice the tier's second (tests/test_tiers.py).
FAST_S = 1.0
OVERRUN_S = 2.0 * FAST_S
TIER_MARKERS = ("slow", "processes")


class TierError(Exception):
    """An unmarked (fast-tier) test did what only a marked test may."""


def _refuse(original: Any, what: str, marker: str) -> Any:
    """`original`, refused in the thread the test runs in (a library's own threads go on)."""
    owner = threading.get_ident()

    def refused(*args: Any, **kwargs: Any) -> Any:
        if threading.get_ident() != owner:
            return original(*args, **kwargs)
        raise TierError(f"this test {what}: mark it @pytest.mark.{marker} (tests/conftest.py)")

    return refused


def _guards(mp: pytest.MonkeyPatch) -> None:
    """What a fast-tier test may not do, refused for the length of one of its phases."""
    import multiprocessing.process
    import socket

    import zenoh

    for owner, name, what, marker in (
        (subprocess.Popen, "__init__", "starts a process", "processes"),
        (multiprocessing.process.BaseProcess, "start", "starts a process", "processes"),
        (socket.socket, "__init__", "opens a socket", "processes"),
        (zenoh, "open", "opens a Zenoh session", "processes"),
        (time, "sleep", "sleeps", "slow"),
    ):
        mp.setattr(owner, name, _refuse(getattr(owner, name), what, marker))


class CompileClock:
    """The seconds numba spends compiling (or loading from its cache) while installed."""

    def __init__(self) -> None:
        from numba.core import event

        self.seconds = 0.0
        self._event = event
        self._listener = event.TimingListener()

    def __enter__(self) -> CompileClock:
        self._event.register("numba:compiler_lock", self._listener)
        return self

    def __exit__(self, *exc: object) -> None:
        self._event.unregister("numba:compiler_lock", self._listener)
        self.seconds = self._listener.duration if self._listener.done else 0.0


def _cpu_wait_s() -> float:
    """The seconds this thread has waited, runnable, for a CPU so far (the second field of
    /proc/thread-self/schedstat, ns); 0 where the kernel does not say."""
    try:
        with open("/proc/thread-self/schedstat") as f:
            return int(f.read().split()[1]) / 1e9
    except (OSError, ValueError, IndexError):
        return 0.0


def _fast_tier(item: pytest.Item) -> bool:
    return not any(item.get_closest_marker(m) for m in TIER_MARKERS)


def _guarded_phase(item: pytest.Item) -> Iterator[None]:
    """One phase of a test: guarded and timed if it is in the fast tier."""
    if not _fast_tier(item):
        yield
        return
    start, waited = time.perf_counter(), _cpu_wait_s()
    with pytest.MonkeyPatch.context() as mp, CompileClock() as compiling:
        _guards(mp)
        yield
    wall = time.perf_counter() - start - (_cpu_wait_s() - waited)
    spent = getattr(item, "_tier_seconds", 0.0) + wall - compiling.seconds
    item._tier_seconds = spent  # type: ignore[attr-defined]


@pytest.hookimpl(wrapper=True)
def pytest_runtest_setup(item: pytest.Item) -> Iterator[None]:
    yield from _guarded_phase(item)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item: pytest.Item) -> Iterator[None]:
    yield from _guarded_phase(item)
    spent = getattr(item, "_tier_seconds", 0.0)
    item.user_properties.append(("tier_seconds", round(spent, 3)))  # --junitxml keeps it
    if spent > OVERRUN_S:
        raise TierError(
            f"took {spent:.2f} s (setup and call, numba's compiling and the waits for a CPU "
            f"aside) in the fast tier "
            f"(<= {FAST_S:.0f} s, failed past {OVERRUN_S:.0f} s): mark it @pytest.mark.slow"
        )

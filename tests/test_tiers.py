"""The test tiers (tests/conftest.py): an unmarked test that starts a process, opens a socket
or a Zenoh session, sleeps, or overruns the fast tier's time fails and names the marker it
needs; a marked one may do all of that. Run in a pytest of its own (a process)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import OVERRUN_S

CASES = """
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
import zenoh
from numba import njit


def test_unmarked_starts_a_process():
    subprocess.run([sys.executable, "-c", "pass"], check=True)


def test_unmarked_opens_a_socket():
    socket.socket()


def test_unmarked_opens_zenoh():
    zenoh.open(zenoh.Config())


def test_unmarked_sleeps():
    time.sleep(0.01)


def test_unmarked_overruns():
    end = time.thread_time() + 2.5
    while time.thread_time() < end:
        pass


def test_unmarked_starved_but_quick():  # the waits for a CPU another process held: not its
    end = time.thread_time() + 1.2
    while time.thread_time() < end:
        pass


def test_unmarked_compiles_for_long():  # numba's compiling is not the test's time
    @njit
    def f(x):
        return np.sin(x) + 1.0

    end = time.perf_counter() + 0.2
    while time.perf_counter() < end:
        pass
    assert f(0.0) == 1.0


def test_unmarked_is_quick():
    assert sum(range(1000)) == 499500


@pytest.mark.processes
def test_marked_starts_a_process_and_sleeps():
    subprocess.run([sys.executable, "-c", "pass"], check=True)
    time.sleep(0.01)


@pytest.mark.slow
def test_marked_runs_long():
    end = time.perf_counter() + 2.5
    while time.perf_counter() < end:
        pass
"""


@pytest.mark.processes
def test_the_fast_tier_refuses_what_needs_a_marker(pytester: pytest.Pytester) -> None:
    conftest = Path(__file__).with_name("conftest.py").read_text()
    pytester.makeconftest(conftest)
    pytester.makeini("[pytest]\nmarkers =\n    slow: long\n    processes: processes and sockets\n")
    pytester.makepyfile(test_cases=CASES)
    # the cases share one CPU with a process that spins: the starved one takes about twice
    # its 1.2 s of its own, past OVERRUN_S on the wall clock, and still passes
    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    mine = os.sched_getaffinity(0)
    cpu = min(mine)
    try:
        os.sched_setaffinity(hog.pid, {cpu})
        os.sched_setaffinity(0, {cpu})  # the cases' pytest, started now, inherits it
        result = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider", "--durations=0")
    finally:
        os.sched_setaffinity(0, mine)
        hog.kill()
        hog.wait(10)
    result.assert_outcomes(passed=5, failed=5)
    out = result.stdout.str()
    starved = re.search(r"([\d.]+)s call +test_cases.py::test_unmarked_starved_but_quick", out)
    assert starved is not None and float(starved.group(1)) > OVERRUN_S, out
    for name, needs in (
        ("starts_a_process", "this test starts a process: mark it @pytest.mark.processes"),
        ("opens_a_socket", "this test opens a socket: mark it @pytest.mark.processes"),
        ("opens_zenoh", "this test opens a Zenoh session: mark it @pytest.mark.processes"),
        ("sleeps", "this test sleeps: mark it @pytest.mark.slow"),
        ("overruns", "in the fast tier (<= 1 s, failed past 2 s): mark it @pytest.mark.slow"),
    ):
        assert f"FAILED test_cases.py::test_unmarked_{name}" in out, name
        assert needs in out, name

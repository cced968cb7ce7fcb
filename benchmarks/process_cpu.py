"""Where the CPU goes while a run is watched: every process on the machine sampled from
/proc (psutil) once a second, its CPU time (user + system) over the run grouped by what it
is (the sim, the haptic server's processes, the live view, the Rerun server, the browser:
the processes this one started, and their children), and everything else on the machine
(other people's work on a shared one).

Used by `benchmarks.loop_timing --view`: the CPU seconds of each group per second of the
run, so the view's degrade lever goes where the cost is (docs/live-view.md).
"""

from __future__ import annotations

import os
import threading
import time
from typing import Any

#: Groups in the order they are matched against a process's command line (first wins).
GROUPS = (
    ("sim", ("sim_server",)),
    ("live view", ("haptic_server.live_view",)),
    ("rerun server", ("rerun_cli", "--serve-web")),
    ("browser", ("chromium", "chrome", "playwright")),
    ("haptic server", ("haptic_server",)),
    ("haptic-run", ("harness.run", "bin/haptic-run")),
    ("benchmark", ("benchmarks.loop_timing",)),
)
OTHER = "rest of the machine"
SAMPLE_S = 1.0


def group_of(cmdline: list[str]) -> str:
    """The group a command line belongs to (OTHER when none matches)."""
    text = " ".join(cmdline)
    for name, marks in GROUPS:
        if any(mark in text for mark in marks):
            return name
    return OTHER


WARMUP_S = 8.0  # a run's start (imports, numba's cache, the browser's launch) left out


def _group(pid: int, infos: dict[int, dict[str, Any]], own: int) -> str:
    """A process's group: its own command line's, else its nearest ancestor's (a
    multiprocessing child is its parent's); OTHER unless it descends from `own`."""
    chain, seen = [], set()
    while pid in infos and pid not in seen:
        seen.add(pid)
        chain.append(pid)
        if pid == own:
            break
        pid = int(infos[pid].get("ppid") or 0)
    if own not in chain:
        return OTHER
    for p in chain:
        group = group_of(infos[p].get("cmdline") or [])
        if group != OTHER:
            return group
    return OTHER


class CpuSampler:
    """Samples every process's CPU time until stopped; `shares()` is CPU s per wall s per
    group from WARMUP_S on (a process started later counts from its start). A process that
    ends between two samples loses at most its last second."""

    def __init__(self, warmup_s: float = WARMUP_S) -> None:
        self._warmup_s = warmup_s
        self._own = os.getpid()
        self._first: dict[tuple[int, float], float] = {}
        self._first_wait: dict[tuple[int, float], float] = {}
        self._last_wait: dict[tuple[int, float], float] = {}
        self._steal0 = self._steal1 = 0.0
        self._last: dict[tuple[int, float], tuple[str, float]] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._t0 = self._t1 = 0.0

    def start(self) -> CpuSampler:
        self._thread.start()
        return self

    def stop(self) -> dict[str, float]:
        self._stop.set()
        self._thread.join()
        return self.shares()

    def _run(self) -> None:
        if self._stop.wait(self._warmup_s):
            return
        self._t0 = time.monotonic()
        self._sample(first=True)
        while not self._stop.wait(SAMPLE_S):
            self._sample(first=False)

    def _sample(self, first: bool) -> None:
        import psutil

        infos = {
            proc.pid: proc.info
            for proc in psutil.process_iter(["cmdline", "cpu_times", "create_time", "ppid"])
        }
        for pid, info in infos.items():
            times = info.get("cpu_times")
            if times is None:
                continue
            key = (pid, float(info.get("create_time") or 0.0))
            cpu = float(times.user + times.system)
            wait = _runqueue_wait_s(pid)
            if first:
                self._first[key] = cpu
                self._first_wait[key] = wait
            self._last[key] = (_group(pid, infos, self._own), cpu)
            self._last_wait[key] = wait
        steal = _steal_s()
        if first:
            self._steal0 = steal
        self._steal1 = steal
        self._t1 = time.monotonic()

    def shares(self) -> dict[str, float]:
        """CPU seconds per wall second in each group between the first and last samples
        (2.0 is both CPUs of a 2-core machine); `<group> waiting`: seconds per second its
        threads were runnable but not running (the scheduler's run-queue wait, summed over
        threads: a starved process shows here); `host steal`: the CPU the VM's host took."""
        if self._t1 <= self._t0:
            return {}
        wall = self._t1 - self._t0
        out = {name: 0.0 for name, _ in GROUPS} | {OTHER: 0.0}
        for key, (group, cpu) in self._last.items():
            out[group] += (cpu - self._first.get(key, 0.0)) / wall
            waited = self._last_wait[key] - self._first_wait.get(key, 0.0)
            out[f"{group} waiting"] = out.get(f"{group} waiting", 0.0) + waited / wall
        out["host steal"] = (self._steal1 - self._steal0) / wall
        return out


def _runqueue_wait_s(pid: int) -> float:
    """Time the process's threads spent runnable, waiting for a CPU (/proc/PID/schedstat
    of every task), s."""
    total = 0
    try:
        for task in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{task}/schedstat") as f:
                total += int(f.read().split()[1])
    except (OSError, ValueError, IndexError):
        pass
    return total / 1e9


def _steal_s() -> float:
    """CPU time the hypervisor took from this VM, all CPUs (/proc/stat), s."""
    try:
        with open("/proc/stat") as f:
            fields = f.readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return 0.0

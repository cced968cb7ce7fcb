"""`haptic-run`: launch the sim and haptic servers as two OS processes, run, stop, summarise.

With `--clock virtual` it runs the same code in one process on a simulated clock instead.
Children get PR_SET_PDEATHSIG, so they never outlive haptic-run (even after a SIGKILL of
haptic-run), and every child is stopped by its own pid whatever happens to the other: if
either child exits early, the other is stopped and haptic-run exits non-zero. SIGINT and
SIGTERM stop both servers cleanly (the device ramps to its safe state, the log is closed).
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from haptic_local_model.haptic_server.view_address import add_view_args, view_address
from haptic_local_model.shared.cli import (
    EXIT_CONFIG,
    EXIT_LOG_FAILED,
    add_config_args,
    check_log_writable,
    done_with_signals,
    emit,
    log_file,
    print_shipped,
    run_main,
    seconds,
    single,
    write_summary,
)
from haptic_local_model.shared.config import (
    ConfigError,
    absolute_ref,
    load_scene,
    load_user,
)
from haptic_local_model.shared.net.config import free_loopback_port, load_network, on_loopback
from haptic_local_model.shared.timing import avoid_cpu as keep_off_cpu

READY_TIMEOUT_S = 300.0  # a cold numba cache compiles for a minute or two on 2 cores
STOP_TIMEOUT_S = 30.0
POLL_S = 0.05  # how often haptic-run looks at its children while they run
PR_SET_PDEATHSIG = 1

try:
    _LIBC: ctypes.CDLL | None = ctypes.CDLL("libc.so.6", use_errno=True)
except OSError:
    _LIBC = None


def _die_with_parent(parent_pid: int, avoid_cpu: int | None = None) -> Callable[[], None]:
    """Child side of Popen: SIGTERM us if haptic-run dies (Linux prctl PR_SET_PDEATHSIG), and
    keep off `avoid_cpu` (the haptic loop's: every thread the child starts inherits it).

    Runs between fork and exec, so it only calls what was loaded before the fork. If
    haptic-run died before the prctl took effect, the child exits at once.
    """

    def preexec() -> None:
        if _LIBC is not None:
            _LIBC.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
        if os.getppid() != parent_pid:
            os._exit(1)
        keep_off_cpu(avoid_cpu)

    return preexec


class Child:
    """A server process whose JSON event lines are read on a thread."""

    def __init__(self, name: str, argv: list[str], avoid_cpu: int | None = None) -> None:
        self.name = name
        self.proc = subprocess.Popen(
            argv, stdout=subprocess.PIPE, stderr=None, text=True,
            preexec_fn=_die_with_parent(os.getpid(), avoid_cpu),
        )  # fmt: skip
        self.events: list[dict[str, Any]] = []
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._read, args=(self.proc.stdout,), daemon=True)
        self._thread.start()

    def _read(self, stream: IO[str] | None) -> None:
        assert stream is not None
        for line in stream:
            try:
                event = json.loads(line)
            except json.JSONDecodeError:
                sys.stdout.write(f"[{self.name}] {line}")
                continue
            self.events.append(event)
            if event.get("event") == "ready":
                self._ready.set()

    def wait_ready(self, timeout: float, abort: threading.Event | None = None) -> bool:
        """True once the child said it is ready; False if it exited, timed out or `abort`."""
        end = time.monotonic() + timeout
        while time.monotonic() < end and not (abort is not None and abort.is_set()):
            if self._ready.wait(0.1):
                return True
            if self.proc.poll() is not None:
                return False
        return False

    def stop(self, timeout: float = STOP_TIMEOUT_S) -> int:
        """SIGTERM, then SIGKILL after `timeout`; returns the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            code = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            code = self.proc.wait()
        self._thread.join(2.0)
        return code


def _server_argv(module: str, args: argparse.Namespace, extra: list[str]) -> list[str]:
    argv = [sys.executable, "-m", module, "--scene", absolute_ref(args.scene)]
    if args.port is not None:
        argv += ["--port", str(args.port)]
    return [*argv, "--network", absolute_ref(args.network), *extra]


def compile_first(args: argparse.Namespace) -> None:
    """A run whose kernels the cache does not hold yet compiles them before either server
    starts, and says so: started cold, the two servers compile side by side and the haptic
    loop waits on a sim that is still compiling (a watchdog trip that is no fault). Once per
    run and build; `make warm` compiles every feature's at once."""
    from haptic_local_model.haptic_server.harness.warm_marks import runs_warmed

    run = (args.scene, args.device, args.user, 1.0)
    if runs_warmed(run):
        return
    from haptic_local_model.haptic_server.harness import warmup  # numba: only to compile

    print(
        f"haptic-run: the first run of {Path(args.scene).stem} with {Path(args.device).stem} "
        f"on this build compiles its kernels (about 70 s on two cores, once) into "
        f"{os.environ['NUMBA_CACHE_DIR']}",
        file=sys.stderr,
    )
    try:
        warmup.warm_all(sys.stderr, jobs=2, run=run)
    except Exception as exc:  # the servers compile what they need as they start
        print(f"haptic-run: compiling ahead failed ({exc}); the servers compile as they start",
              file=sys.stderr)  # fmt: skip


@contextmanager
def signals_kept(restore: bool) -> Iterator[None]:
    """SIGTERM's and SIGINT's handlers as they are on leaving, restored only if `restore`.
    A real-time run sets its own (they set the stop it watches) once it has compiled, and
    they must stay until its summary is written and printed: a signal while the run
    finishes is the stop it is already making. (Restored as soon as the servers were
    stopped, a SIGTERM that came as the run ended found the default handler, and haptic-run
    died with -15 while it wrote its summary.) haptic-run as a process of its own keeps
    them to its exit; called in another program's process, that program's come back."""
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield
    finally:
        if restore:
            for sig, handler in previous.items():
                signal.signal(sig, handler)


def run_real_time(args: argparse.Namespace) -> dict[str, Any]:
    """The two-process system: haptic (listener) first, then the sim, then the duration.

    Returns the haptic server's summary with the sim's, the exit codes and, if something
    went wrong (a child exited early or failed), `failure`.
    """
    # validate every file here so a bad config fails fast with exit 2
    load_scene(args.scene, args.haptic_rate)
    pointer = load_user(args.user).kind == "pointer"
    network = load_network(args.network)
    if args.port is None and on_loopback(network) and not pointer:
        # a port of this run's own: runs never collide. Not for a hand that follows a
        # pointer: `haptic-pointer` on the same network must find the haptic server
        args.port = free_loopback_port()
    from haptic_local_model.device_models.registry import check_device

    model = check_device(args.device)  # not built: a hardware driver is the haptic server's
    if model.simulated and not pointer:
        compile_first(args)
    # the servers' own summaries: in a folder of this run's, not beside the log (whose disk
    # may fill up: that is the log's failure, not the run's)
    summary_dir = Path(tempfile.mkdtemp(prefix="haptic-run-"))
    haptic_json = summary_dir / "haptic-summary.json"
    sim_json = summary_dir / "sim-summary.json"
    haptic_extra = [
        "--device",
        absolute_ref(args.device),
        "--user",
        absolute_ref(args.user),
        "--duration",
        str(args.duration),
        "--summary-json",
        str(haptic_json),
    ]
    if args.log:
        haptic_extra += ["--log", str(Path(args.log).resolve())]
    if args.haptic_rate is not None:
        haptic_extra += ["--haptic-rate", repr(float(args.haptic_rate))]
    view = view_address(args)
    if view is not None:
        haptic_extra += view.argv()
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    failure: str | None = None
    haptic = Child(
        "haptic", _server_argv("haptic_local_model.haptic_server.cli", args, haptic_extra)
    )
    sim: Child | None = None
    try:
        if not haptic.wait_ready(READY_TIMEOUT_S, stop):
            if not stop.is_set():
                failure = f"haptic server did not become ready (exit {haptic.proc.poll()})"
        else:
            # the sim keeps off the CPU the haptic loop keeps to itself (if it could)
            loop_cpu = next(
                (e.get("loop_cpu") for e in haptic.events if e.get("event") == "ready"), None
            )
            sim = Child(
                "sim",
                _server_argv(
                    "haptic_local_model.sim_server.cli", args, ["--summary-json", str(sim_json)]
                ),
                avoid_cpu=loop_cpu,
            )
            if not sim.wait_ready(READY_TIMEOUT_S, stop):
                if not stop.is_set():
                    failure = f"sim server did not become ready (exit {sim.proc.poll()})"
            else:
                pids = {"haptic_pid": haptic.proc.pid, "sim_pid": sim.proc.pid}
                if args.json_events:  # for programs that follow the run (tests, soak)
                    emit("ready", process="haptic-run", **pids)
                else:
                    print(
                        f"running: haptic server pid {pids['haptic_pid']}, sim server pid "
                        f"{pids['sim_pid']} (Ctrl-C stops both; the device ramps to safe)",
                        flush=True,
                    )
                    if pointer:
                        port = f" --port {args.port}" if args.port is not None else ""
                        print(
                            f"the hand follows a pointer: haptic-pointer --network "
                            f"{args.network}{port} --evdev /dev/input/eventN (--list: devices)",
                            flush=True,
                        )
                failure = _watch(haptic, sim, stop, args.duration + STOP_TIMEOUT_S + 30.0)
    finally:
        codes = {"haptic": haptic.stop()}  # the haptic side first: it ramps the device to safe
        if sim is not None:
            codes["sim"] = sim.stop()
        # the handlers stay until haptic-run has written its summary (signals_kept)
    summary: dict[str, Any] = _read_summary(haptic_json) or {"clock": "real-time"}
    summary["sim"] = _read_summary(sim_json)
    shutil.rmtree(summary_dir, ignore_errors=True)
    log_failed = codes.get("haptic") == EXIT_LOG_FAILED and summary.get("log_failed")
    if log_failed and failure in (None, f"haptic server exited with {EXIT_LOG_FAILED}"):
        failure = f"logging stopped: {summary['log_failed']} (the run itself went on)"
    elif failure is None and any(code != 0 for code in codes.values()):
        failure = f"a server exited with an error: {codes}"
    summary["exit_codes"] = codes
    summary["stopped_by_signal"] = stop.is_set()
    if failure is not None:
        summary["failure"] = failure
        # a server that refused its configs (exit 2) before it was ready has said why, in one
        # line naming the file and key: haptic-run exits 2 after it, adding nothing
        summary["config_error"] = EXIT_CONFIG in codes.values() and not summary.get("ticks")
    return summary


def _read_summary(path: Path) -> dict[str, Any] | None:
    """A server's summary file, or None if it wrote none (it failed before, or could not)."""
    try:
        data: dict[str, Any] = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    return data


def _watch(haptic: Child, sim: Child, stop: threading.Event, timeout_s: float) -> str | None:
    """Wait for the run to end: the haptic server finishing its duration (None), a signal
    (None), or a child exiting early or failing (a message: the caller stops the other)."""
    end = time.monotonic() + timeout_s
    while not stop.wait(POLL_S):
        code = haptic.proc.poll()
        if code is not None:
            return None if code == 0 else f"haptic server exited with {code}"
        code = sim.proc.poll()
        if code is not None:
            return f"sim server exited with {code} while the haptic server ran"
        if time.monotonic() > end:
            return "haptic server did not finish its run in time"
    return None


def run_virtual_clock(args: argparse.Namespace) -> dict[str, Any]:
    from haptic_local_model.haptic_server.harness.virtual import run_virtual_named

    load_network(args.network)  # not used on a virtual clock, but a bad file is still an error
    result = run_virtual_named(
        args.scene, args.device, args.user, args.duration, args.log, args.haptic_rate
    )
    ticks = result.ticks
    return {
        "clock": "virtual",
        "ticks": int(ticks.shape[0]),
        "simulated_s": result.sim_s,
        "wall_s": result.wall_s,
        "speedup": result.speedup,
        "kernels_load_s": result.load_s,
        "setup_s": result.setup_s,
        "updates_received": result.updates,
        "log": str(args.log) if args.log else None,
    }


def run_port_world(args: argparse.Namespace) -> int:
    """A port scene: its world and both (or one) simulated devices in this process, in real
    time or on the virtual clock (haptic_server.world_runs)."""
    from haptic_local_model.haptic_server.world_runs import port_scene, run_port_scene

    for flag, given in (("--haptic-rate", args.haptic_rate), ("--port", args.port)):
        if given is not None:
            raise ConfigError("command line", flag, "not for a port scene: it runs in this "
                              "process at its scene's haptic_rate_hz")  # fmt: skip
    view = view_address(args)
    if view is not None and args.clock == "virtual":
        raise ConfigError("command line", "--view", "needs --clock real")
    scene = port_scene(args.scene, args.device, args.user)
    figures = run_port_scene(scene, args.duration, args.clock, args.log, view)
    figures["log"] = str(args.log) if args.log else None
    if args.clock == "real":
        work, late = figures["work_us"], figures["late_us"]
        print(
            f"real time: {figures['ticks']} ticks, delivered "
            f"{100 * figures['ticks_delivered']:.2f} %, overruns {figures['overruns']}; work "
            f"(us) p50 {work['p50']:.1f} p99 {work['p99']:.1f} p99.9 {work['p99_9']:.1f}; "
            f"late (us) p99 {late['p99']:.1f}"
        )
    return 0 if write_summary(args.summary_json, figures, "haptic-run") else 1


def print_summary(s: dict[str, Any]) -> None:
    if s.get("clock") == "virtual":
        print(
            f"virtual clock: {s['ticks']} ticks, {s['simulated_s']:.2f} s simulated in "
            f"{s['wall_s']:.2f} s ({s['speedup']:.3g}x real time), {s['updates_received']} updates"
            f" (before it: kernels loaded in {s['kernels_load_s']:.2f} s, world, engine and log"
            f" writer made in {s['setup_s']:.2f} s)"
        )
    else:
        lat, work, age = s["lateness_us"], s["work_us"], s["update_age_ms"]
        print(
            f"ticks:         {s['ticks']} in {s['duration_s']:.2f} s ({s['tick_rate_hz']:.1f} Hz)"
        )
        print(
            f"lateness (us): p50 {lat['p50']:.1f}  p99 {lat['p99']:.1f}  "
            f"p99.9 {lat['p99_9']:.1f}  max {lat['max']:.1f}"
        )
        print(f"late > 1 ms:   {s['late_ticks_over_1ms']}   overruns: {s['overruns']}")
        print(f"work (us):     p50 {work['p50']:.1f}  p99 {work['p99']:.1f}  max {work['max']:.1f}")
        print(
            f"updates:       {s['updates_received']} ({s['update_rate_hz']:.1f} Hz), "
            f"age (publish -> installed) p50 {age['p50']:.2f} ms  p99 {age['p99']:.2f} ms"
        )
        print(f"rejected:      {s['updates_rejected']} {s['rejected_by_reason'] or ''}")
        print(
            f"watchdog:      {s['watchdog_trips']} trips, {s['reinitialisations']} "
            f"re-initialisations; exit codes {s.get('exit_codes')}"
        )
    if s.get("log"):
        print(f"log:           {s['log']}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="haptic-run", description=__doc__)
    add_config_args(parser, rate=True, per_port=True)
    parser.add_argument(
        "--duration", type=seconds, default=10.0, help="seconds to run (default 10)"
    )
    parser.add_argument("--clock", choices=["real", "virtual"], default="real")
    parser.add_argument(
        "--log", type=log_file, default=None, help="MCAP log (default ./runs/<time>-<scene>.mcap)"
    )
    parser.add_argument("--no-log", action="store_true", help="run without a log")
    parser.add_argument("--summary-json", type=Path, default=None)
    parser.add_argument(
        "--list", action="store_true", help="list the shipped scenes, devices, users, networks"
    )
    add_view_args(parser)
    parser.add_argument(
        "--json-events", action="store_true",
        help="say 'ready' as a JSON line on stdout (for programs that follow the run)",
    )  # fmt: skip
    args = parser.parse_args(argv)
    if args.list:
        from haptic_local_model.device_models.registry import model_lines

        print_shipped(model_lines())
        return 0
    if args.log is None and not args.no_log:
        stem = f"{time.strftime('%Y%m%d-%H%M%S')}-{Path(args.scene).stem}"
        args.log = Path.cwd() / "runs" / f"{stem}.mcap"
    if args.no_log:
        args.log = None

    def body() -> int:
        from haptic_local_model.haptic_server.world_runs import is_port_scene

        if args.log is not None:
            check_log_writable(args.log)
        if is_port_scene(args.scene):
            return run_port_world(args)
        args.device = single(args.device, "ideal", "--device")
        args.user = single(args.user, "swing", "--user")
        view = view_address(args)
        if view is not None and args.clock == "virtual":
            raise ConfigError(
                "command line", "--view",
                "needs --clock real (a virtual-clock run outpaces any view: draw its log with "
                "haptic-replay LOG --view)",
            )  # fmt: skip
        with signals_kept(restore=argv is not None):
            summary = run_virtual_clock(args) if args.clock == "virtual" else run_real_time(args)
            return _finish(args, summary)

    return done_with_signals(run_main(body), argv)


def _finish(args: argparse.Namespace, summary: dict[str, Any]) -> int:
    """The run's summary written (--summary-json) and printed; haptic-run's exit code."""
    if not write_summary(args.summary_json, summary, "haptic-run"):
        summary.setdefault("failure", "the summary was not written")
    if summary.get("config_error"):
        return EXIT_CONFIG
    if "failure" in summary:
        print(f"haptic-run: {summary['failure']}", file=sys.stderr)
        return EXIT_LOG_FAILED if summary["failure"].startswith("logging stopped") else 1
    print_summary(summary)
    return 0


if __name__ == "__main__":
    sys.exit(main())

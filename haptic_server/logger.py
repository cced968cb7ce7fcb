"""The MCAP log writer in a process of its own, fed through the shared block.

It reads what the others leave in `haptic_server.mailbox`'s shared memory: the tick rows the
loop pushes into the ring, the updates in the mailbox once the loop has given its verdict,
the events; and writes them with `haptic_server.log.LogWriter`. Kept apart from the Zenoh
sidecar, the writer's Python never holds the GIL of the process that receives updates
(measured: with the log in the sidecar, update transit p90 0.65 ms, p99 2-3 ms), and the
sidecar can run with real-time priority without starving the sim of CPU.

The virtual clock feeds the same process through the same block (`LogFeed`), so its run
does not wait on the writer either, only on a full ring.

If the process that feeds it dies, even by SIGKILL, the writer notices, writes what is
there and closes the log.
"""

from __future__ import annotations

import atexit
import contextlib
import gc
import json
import os
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from haptic_local_model.haptic_server.mailbox import (
    C_CLOSED,
    C_EVT_HEAD,
    C_LOG_DONE,
    C_LOG_FAILED,
    C_LOG_READY,
    C_TICK_HEAD,
    C_TICK_LOGGED,
    C_TICK_LOST,
    C_UPD_HEAD,
    C_UPD_LOGGED,
    C_UPD_READ,
    C_WALL_START,
    MAILBOX_SLOTS,
    RING_TICKS,
    SLOT_BYTES,
    SharedBlock,
)
from haptic_local_model.haptic_server.model import TICK_DTYPE
from haptic_local_model.shared.memory import FloodTrim
from haptic_local_model.shared.protocol.layout import PUBLISH_TIME_AT, PUBLISH_TIME_END
from haptic_local_model.shared.timing import avoid_cpu

if TYPE_CHECKING:
    from haptic_local_model.haptic_server.log import LogWriter
    from haptic_local_model.haptic_server.view_board import ViewBoard

#: how often the writer looks for rows: for a real-time loop (its ring holds 16 s; each wake
#: costs the machine, and at 10 kHz a writer that never idles would wake 2000 times a
#: second), and for a virtual clock, which waits on it when the ring is full
REALTIME_POLL_S = 0.005
FEED_POLL_S = 0.0005
FLUSH_EVERY_S = 0.2  # and flushes the file this often: a crash loses at most that much
LOG_NICENESS = 5  # the writer yields the CPU to the sim and the I/O sidecar


class BlockChild:
    """A helper process on a shared block: `python -m MODULE CONFIG.json` (so a caller's
    script is not imported again, as multiprocessing's spawn would), its config (with the
    block's name and our pid) in a temporary file removed when it is joined."""

    def __init__(self, module: str, shm_name: str, config: dict[str, Any]) -> None:
        with tempfile.NamedTemporaryFile("w", suffix=".json", delete=False) as fh:
            json.dump({"shm_name": shm_name, "parent_pid": os.getpid(), **config}, fh)
        self._config_path = fh.name
        self._proc = subprocess.Popen([sys.executable, "-m", module, fh.name])

    @property
    def alive(self) -> bool:
        return self._proc.poll() is None

    def join(self, timeout_s: float) -> None:
        """Wait for its exit (after C_CLOSED); terminate it if it does not."""
        try:
            self._proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self._proc.terminate()
            self._proc.wait(5.0)
        finally:
            with contextlib.suppress(OSError):
                os.unlink(self._config_path)


class LogStartError(RuntimeError):
    """The log writer could not open its file (or died before it had): why, if it said."""

    def __init__(self, path: str, why: str) -> None:
        super().__init__(f"the log writer did not start ({path})" + (f": {why}" if why else ""))


class LogProcess(BlockChild):
    """Starts the writer on a shared block and (unless `wait` is False: then wait_ready)
    waits until its file is open."""

    def __init__(
        self,
        shm_name: str,
        block: SharedBlock,
        config: dict[str, Any],
        wait: bool = True,
    ) -> None:
        self.block = block
        self._path = config["log_path"]
        super().__init__("haptic_local_model.haptic_server.logger", shm_name, config)
        if wait:
            self.wait_ready()

    def wait_ready(self, timeout_s: float = 60.0) -> None:
        """Return once the writer has opened its file; raise if it died or did not."""
        end = time.monotonic() + timeout_s
        while self.block.ctl[C_LOG_READY] == 0:
            if self._proc.poll() is not None or time.monotonic() > end:
                self.join(0.0)
                raise LogStartError(self._path, self.block.log_failure)
            time.sleep(0.01)

    def wait_closed(self, timeout_s: float) -> bool:
        """Wait (after C_CLOSED) until the writer has closed its file; False if it died first
        or did not within the timeout. Its exit is reaped later (atexit)."""
        end = time.monotonic() + timeout_s
        while self.block.ctl[C_LOG_DONE] == 0 and self.alive and time.monotonic() < end:
            time.sleep(0.0005)
        atexit.register(self.join, 10.0)
        return bool(self.block.ctl[C_LOG_DONE])


def main(argv: list[str] | None = None) -> int:
    """`python -m haptic_local_model.haptic_server.logger CONFIG.json`: the writer process
    (LogProcess)."""
    args = sys.argv[1:] if argv is None else argv
    config = json.loads(Path(args[0]).read_text())
    _logger_main(config["shm_name"], config, int(config["parent_pid"]))
    # the log is closed and on disk: skip the interpreter's teardown (numba's, the SDK's:
    # ~40 ms that a short virtual-clock run would wait for)
    os._exit(0)


def _logger_main(shm_name: str, config: dict[str, Any], parent_pid: int) -> None:
    """Write what the block holds until it is closed and drained, or its feeder dies."""
    from haptic_local_model.haptic_server.log import LogWriter

    terminated = threading.Event()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the feeder decides when the log ends
    signal.signal(signal.SIGTERM, lambda *_: terminated.set())
    with contextlib.suppress(OSError):
        os.nice(LOG_NICENESS)
    avoid_cpu(config.get("loop_cpu"))  # the real-time loop's CPU is its own
    block = SharedBlock.attach(shm_name)
    shm = block.shm
    ctl = block.ctl
    try:
        log = LogWriter(config["log_path"], config["metadata"])
    except Exception as exc:  # its folder cannot be made, no permission: the start stops
        block.fail_log(_io_error(exc, Path(config["log_path"])))  # the server says it, once
        block.release()
        shm.close()
        sys.exit(1)
    drain = LogDrain(
        block, log, int(config["wall_start_ns"]), int(config.get("update_time_offset_ns", 0)),
        int(config.get("tick_period_ns", 0)),
    )  # fmt: skip
    if config.get("view_board"):  # the sim's world, as the live view gets it
        from haptic_local_model.haptic_server.view_board import ViewBoard

        drain.board = ViewBoard.attach(config["view_board"])
    poll_s = float(config.get("poll_s", REALTIME_POLL_S))
    _load_decoder()
    gc.collect()
    gc.freeze()
    ctl[C_LOG_READY] = 1
    failed = False
    trim = FloodTrim()  # a flood of updates, each logged: its memory back after it

    def updates() -> int:
        return int(ctl[C_UPD_HEAD])

    try:
        while True:
            closing = ctl[C_CLOSED] == 1 or os.getppid() != parent_pid or terminated.is_set()
            head = int(ctl[C_TICK_HEAD])  # first: see LogDrain.drain
            now = time.monotonic()
            drain.drain(head, now)
            trim.after(now, updates)
            if closing and int(ctl[C_TICK_HEAD]) == drain.tick_tail and drain.drained_updates():
                break
            if not closing:
                time.sleep(poll_s)
    except Exception as exc:
        # a full disk, an I/O error: logging stops (the loop and the networking go on), the
        # file keeps what was written (read it with the streaming reader; haptic-replay
        # --recover makes it an indexed file again)
        failed = True
        error = _io_error(exc, Path(config["log_path"]))
        block.fail_log(f"{config['log_path']}: {error}")
        print(f"log writer: logging stopped: {config['log_path']}: {error}", file=sys.stderr)
    finally:
        with contextlib.suppress(Exception):  # a failed writer cannot write its footer
            log.close()
        ctl[C_LOG_DONE] = 1
        if drain.board is not None:
            drain.board.close()
        block.release()
        shm.close()
    if failed:
        os._exit(1)


#: a log's disk with less free than this when its writer fails is full (the MCAP library
#: reports ENOSPC in its own words)
FULL_DISK_BYTES = 1 << 20


def _io_error(exc: BaseException, path: Path) -> str:
    """The root cause of a writer's error: the OSError under the MCAP library's, if any; a
    full disk said so."""
    seen: BaseException | None = exc
    while seen is not None:
        if isinstance(seen, OSError):
            return str(seen)
        seen = seen.__cause__ or seen.__context__
    text = f"{type(exc).__name__}: {exc}"
    with contextlib.suppress(OSError):
        if shutil.disk_usage(path.parent).free < FULL_DISK_BYTES:
            return f"no space left on the device ({text})"
    return text


def _load_decoder() -> None:
    """Load the update parser's kernel now (from numba's cache: ~0.3 s), not at the first
    update, so a writer that is ready keeps up from the start."""
    from haptic_local_model.shared.protocol.update import MessageError, decode_update

    with contextlib.suppress(MessageError):
        decode_update(bytes(8))


class LogDrain:
    """What has been written to the MCAP log so far, and the writing of the rest."""

    def __init__(
        self,
        block: SharedBlock,
        log: LogWriter,
        wall_start_ns: int,
        update_offset_ns: int = 0,
        period_ns: int = 0,
    ) -> None:
        """A virtual clock's ticks (period_ns 0) are logged at wall_start_ns + their time t,
        its updates at their receive time plus `update_offset_ns` (they are received at
        virtual times from 0; its log starts at the run's wall-clock start). A real-time
        loop's (period_ns its tick period) at their deadlines on the wall clock, from its own
        start (the block's C_WALL_START, once it has started): its t is the sum of clamped
        dts and falls behind the wall clock at every stall, while its updates are logged at
        the wall-clock time the sidecar received them."""
        from haptic_local_model.haptic_server.foxglove_view import ViewFrames, log_message
        from haptic_local_model.haptic_server.log import (
            update_record,  # the writer's imports, not the loop's
        )
        from haptic_local_model.shared.protocol.codes import reason_tag

        self.block, self.log, self.wall_start_ns = block, log, wall_start_ns
        self.update_offset_ns = update_offset_ns
        self.deadlines = TickDeadlines(period_ns) if period_ns > 0 else None
        self._record, self._reason = update_record, reason_tag
        self.view = ViewFrames(log.scene_text)  # Foxglove's channels, at VIEW_HZ of log time
        self._log_message = log_message
        self.view_failed = ""  # why the Foxglove channels stopped (they never stop the log)
        self.tick_tail = 0
        self.upd_logged = 0
        self.evt_tail = 0
        self.last_flush = time.monotonic()
        self.board: ViewBoard | None = None  # with --view: the sim's world messages
        self.world_seen = 0

    def drained_updates(self) -> bool:
        ctl = self.block.ctl
        return self.upd_logged == int(ctl[C_UPD_READ]) and self.evt_tail == int(ctl[C_EVT_HEAD])

    def drain(self, head: int, now: float) -> None:
        """Write the updates, events and tick rows produced so far (ticks below `head`, read
        before everything else): every update and event of a tick below it is already in
        the mailbox / ring and is written before that tick's row, so a file cut anywhere
        holds all the updates of every complete tick it holds (replay)."""
        block, log, ctl = self.block, self.log, self.block.ctl
        if self.board is not None:  # filed under the tick they arrived at, before its row
            messages, self.world_seen = self.board.read_since(self.world_seen)
            for tick, raw in messages:
                log.world(tick, raw, time.time_ns())
        read = int(ctl[C_UPD_READ])
        evt_head = int(ctl[C_EVT_HEAD])
        while self.upd_logged < read:
            slot = self.upd_logged % MAILBOX_SLOTS
            n = int(block.update_len[slot])
            code = int(block.update_verdict[slot])
            raw = block.updates[slot, : min(abs(n), SLOT_BYTES)].tobytes()
            recv_ns = int(block.update_recv_ns[slot])
            age_ms = (recv_ns - _publish_time_ns(raw)) / 1e6
            reason = "" if code == 0 else self._reason(code)
            rec = self._record(
                int(block.update_tick[slot]), raw, reason, age_ms,
                float(block.update_latency_s[slot]), abs(n),
            )  # fmt: skip
            log.update(rec, recv_ns + self.update_offset_ns)
            self._view(self.view.set_update, raw, code == 0 and n > 0)
            self.upd_logged += 1
            ctl[C_UPD_LOGGED] = self.upd_logged
        lost, self.evt_tail = block.skip_overwritten(self.evt_tail, evt_head)
        if lost:  # never silently: the log and the summary say how many
            tick = block.event_at(self.evt_tail)[0]
            log.event(
                tick, "events_lost", f"{lost} events overwritten before logged", time.time_ns()
            )
        while self.evt_tail < evt_head:
            tick, kind, detail = block.event_at(self.evt_tail)
            now_ns = time.time_ns()
            log.event(tick, kind, detail, now_ns)
            self._view(self._view_log, tick, kind, detail, now_ns)
            self.evt_tail += 1
        if ctl[C_WALL_START]:  # the loop's own start: ticks count from it, not from ours
            self.wall_start_ns = int(ctl[C_WALL_START])
        if head - self.tick_tail > RING_TICKS:
            ctl[C_TICK_LOST] += head - self.tick_tail - RING_TICKS
            if self.deadlines is not None:
                self.deadlines.skip(head - self.tick_tail - RING_TICKS)
            self.tick_tail = head - RING_TICKS
        while self.tick_tail < head:  # in runs of the ring, one copy each
            at = self.tick_tail % RING_TICKS
            n = min(head - self.tick_tail, RING_TICKS - at)
            rows = block.ticks[at : at + n]
            data = rows.tobytes()
            if self.deadlines is None:
                times = (self.wall_start_ns + (rows["t"] * 1e9).astype(np.int64)).tolist()
            else:
                times = self.deadlines.of(rows["lateness_us"], self.wall_start_ns)
            size = rows.dtype.itemsize
            view = self.view
            for i, log_ns in enumerate(times):
                log.tick(data[i * size : (i + 1) * size], log_ns)
                if view.due(log_ns):
                    self._view(self._view_frame, rows[i], log_ns)
            self.tick_tail += n
            ctl[C_TICK_LOGGED] = self.tick_tail
        if now - self.last_flush > FLUSH_EVERY_S:
            log.flush()
            self.last_flush = now

    def _view(self, call: Any, *args: Any) -> None:
        """Run a Foxglove-channel step; if it fails, say why once and write no more of them:
        the project's own channels, which replay needs, go on."""
        if self.view_failed:
            return
        try:
            call(*args)
        except Exception as exc:
            self.view_failed = f"{type(exc).__name__}: {exc}"
            print(f"log writer: Foxglove channels stopped: {self.view_failed}", file=sys.stderr)

    def _view_log(self, tick: int, kind: str, detail: str, now_ns: int) -> None:
        self.log.view_log(self._log_message(tick, kind, detail, now_ns), now_ns)

    def _view_frame(self, row: np.void, log_ns: int) -> None:
        """Foxglove's transforms and scene for one tick."""
        transforms, scene = self.view.frame(row, log_ns)
        self.log.view_transforms(transforms, log_ns)
        self.log.view_scene(scene, log_ns)


class TickDeadlines:
    """A real-time loop's tick deadlines, from its start, rebuilt from the rows' lateness
    by the loop's own rule (haptic_server.paced.open_tick_at): a tick starts its lateness
    after its deadline; one later than a whole period restarts the deadlines from its start;
    the next deadline is a period on."""

    def __init__(self, period_ns: int) -> None:
        self.period_ns = period_ns
        self.next_ns = period_ns  # the first tick's deadline: a period after the start

    def of(self, lateness_us: np.ndarray, wall_start_ns: int) -> list[int]:
        """The wall-clock deadlines of the next rows, given their lateness."""
        period, out = self.period_ns, []
        deadline = self.next_ns
        for late in np.round(lateness_us * 1e3).astype(np.int64).tolist():
            out.append(wall_start_ns + deadline)
            deadline = (deadline + late if late > period else deadline) + period
        self.next_ns = deadline
        return out

    def skip(self, ticks: int) -> None:
        """Rows lost before they were logged: their deadlines as if none overran."""
        self.next_ns += ticks * self.period_ns


def _publish_time_ns(raw: bytes) -> int:
    """The publish time in an update's header (0 if the message is too short to have one)."""
    return (
        int(struct.unpack_from("<q", raw, PUBLISH_TIME_AT)[0])
        if len(raw) >= PUBLISH_TIME_END
        else 0
    )


_ROW = np.dtype((np.void, TICK_DTYPE.itemsize))


class LogFeed:
    """The virtual clock's side of a log writer process: it fills a shared block as the
    real-time loop and its sidecar would (every update installed at its tick, every tick
    row), waiting for room when the writer is behind, so nothing is lost."""

    def __init__(self, path: Path | str, metadata: dict[str, dict[str, str]]) -> None:
        start_ns = time.time_ns()
        self.block = SharedBlock.create()
        self._shm = self.block.shm
        config = {
            "log_path": str(path),
            "metadata": metadata,
            "wall_start_ns": start_ns,  # log times from the run's wall-clock start
            "update_time_offset_ns": start_ns,
            "poll_s": FEED_POLL_S,
        }
        try:
            self._writer = LogProcess(self._shm.name, self.block, config)
        except BaseException:
            self._release()
            raise

    def update(self, tick: int, raw: bytes, time_ns: int) -> None:
        """An update installed at `tick`, received (and published) at `time_ns`."""
        block = self.block
        while not block.post_update(raw, time_ns, logging=True):
            self._wait()
        slot = int(block.ctl[C_UPD_READ]) % MAILBOX_SLOTS
        block.update_verdict[slot] = 0
        block.update_tick[slot] = tick
        block.update_install_ns[slot] = time_ns
        block.update_latency_s[slot] = 0.0
        block.ctl[C_UPD_READ] += 1

    def ticks(self, rows: np.ndarray) -> None:
        """Tick rows (TICK_DTYPE), in order, after the updates installed at them."""
        ctl = self.block.ctl
        # rows as opaque records: numpy copies a structured array field by field (19 us for
        # 17 rows), a void view as one block (1.4 us)
        ring = self.block.ticks.view(_ROW)
        rows = rows.view(_ROW)
        done = 0
        while done < len(rows):
            head = int(ctl[C_TICK_HEAD])
            room = RING_TICKS - (head - int(ctl[C_TICK_LOGGED]))
            if room <= 0:
                self._wait()
                continue
            at = head % RING_TICKS
            n = min(len(rows) - done, room, RING_TICKS - at)
            ring[at : at + n] = rows[done : done + n]
            ctl[C_TICK_HEAD] = head + n
            done += n

    def close(self, timeout_s: float = 60.0) -> None:
        """Let the writer write what remains and close the file."""
        self.block.ctl[C_CLOSED] = 1
        closed = self._writer.wait_closed(timeout_s)
        failed = int(self.block.ctl[C_LOG_FAILED]) or not closed
        self._release()
        if failed:
            raise RuntimeError("the log writer failed (its error is printed above)")

    def _wait(self) -> None:
        if not self._writer.alive or self.block.ctl[C_LOG_FAILED]:
            raise RuntimeError("the log writer stopped (its error is printed above)")
        time.sleep(0.0005)

    def _release(self) -> None:
        self.block.release()
        self._shm.close()
        self._shm.unlink()


if __name__ == "__main__":
    sys.exit(main())

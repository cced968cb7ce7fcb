"""Compile every numba kernel into the on-disk cache (`make warm`), so servers start fast.

    python -m haptic_local_model.haptic_server.harness.warmup [--quiet] [--jobs 2] [--demo]

Progress goes to stderr: a line per group of kernels (what, how long; one at a time, also
whether it compiled or loaded from the cache) and the total; `--quiet` prints nothing.
`--jobs 2` compiles in two processes at once (`make warm`: on two cores it takes about
two thirds of the time). `warm_all()` prints only if given a stream.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import os
import queue
import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any, TextIO

import numba

from haptic_local_model.device_models.registry import (
    installed_models,
    load_device,
    load_simulated_device,
)
from haptic_local_model.haptic_server.engine import HapticEngine
from haptic_local_model.haptic_server.hand_grasp_ports import HandGraspRun
from haptic_local_model.haptic_server.hand_ports import HandPortRun
from haptic_local_model.haptic_server.harness.virtual import run_virtual_named
from haptic_local_model.haptic_server.harness.warm_marks import (
    ALL_WARMED,
    Run,
    mark_used,
    mark_warmed,
    prune_builds,
    run_key,
)
from haptic_local_model.haptic_server.mailbox import compile_loop_kernels
from haptic_local_model.haptic_server.realtime import compile_realtime_kernels
from haptic_local_model.haptic_server.shared_world import SharedWorld
from haptic_local_model.haptic_server.stages.tick import rendering_tick
from haptic_local_model.haptic_server.station import Station
from haptic_local_model.haptic_server.world import compile_paced
from haptic_local_model.haptic_server.world_runs import port_scene
from haptic_local_model.shared import numba_caches
from haptic_local_model.shared.config import load_scene, load_user
from haptic_local_model.shared.net.stations import load_station_network
from haptic_local_model.shared.port_config import load_hand_scene, load_port_scene
from haptic_local_model.shared.protocol.update import UpdateParser
from haptic_local_model.sim_server.world import warm_kernels as warm_sim_kernels

#: a god-object scene: each device model's step for that method is compiled on it
GOD_SCENE = "god_rotating_box"
#: (scene, user, seconds) run with the ideal device: every rendering stage and the sim
SCENE_RUNS = (
    ("free_box", "waypoints", 1.0), ("testbed", "swing", 1.0), ("linkage_distal", "push_04n", 1.0),
    ("god_rotating_box", "press_down", 1.0), ("coaster_loop", "push_car", 1.0),
)  # fmt: skip


def built_in_models() -> list[str]:
    """The configs of the project's own device models. A plug-in's are not warmed here: its
    driver may open hardware when built; the haptic server warms the loop it runs."""
    return [
        m.model.config
        for m in installed_models()
        if m.built_in and m.model is not None and m.model.simulated
    ]


def warm_runs() -> list[tuple[str, str, str, float]]:
    """The virtual-clock runs that compile everything: (scene, device config, user, s).
    Every registered device model runs the FOH scene and a god-object's, so its kernels
    for either rendering method (a step is compiled per method) are in the cache."""
    runs = [(scene, "ideal", user, s) for scene, user, s in SCENE_RUNS]
    for config in built_in_models():
        runs += [("maglev_scoop", config, "scoop", 0.3), (GOD_SCENE, config, "press_down", 0.3)]
    return runs


def _run_virtual(runs: list[tuple[str, str, str, float]]) -> None:
    for scene, device, user, seconds in runs:
        run_virtual_named(scene, device, user, seconds)


def _loop_kernels(configs: list[str] | None = None) -> None:
    """The real-time loop's kernels, per device model (every built-in one by default), and
    the update's parser as its log writer calls it."""
    for config in built_in_models() if configs is None else configs:
        for scene in ("testbed", GOD_SCENE):  # either rendering method's loop
            engine = HapticEngine(load_scene(scene), load_device(config), load_user("swing"))
            compile_loop_kernels(engine)
            compile_realtime_kernels(engine)
    UpdateParser().parse(bytes(8))


def _station_kernels() -> None:
    """The shared world's tick and a station's, per device model (docs/stations.md)."""
    scene = load_port_scene("grasp_vertical")
    network = load_station_network("stations_loopback", "world")
    SharedWorld(scene, network, 1).warm()
    SharedWorld(load_hand_scene("hand_grasp"), network, 1).warm()  # two hands
    for config in built_in_models():
        device = load_simulated_device(config)
        Station(scene, network, "left", device, load_user("squeeze_left_2n"), 1).warm()
    hands, glove_user = load_hand_scene("hand_grasp"), load_user("hand_grasp_left")
    Station(hands, network, "left", device, glove_user, 1).warm()  # a hand's: its glove


def _hand_port_kernels() -> None:
    """A hand scene's port per device model, and two hands on a box per pair of them
    (docs/grasp.md)."""
    models = built_in_models()
    for config in models:
        HandPortRun(load_hand_scene("hand_press"), load_simulated_device(config)).run(0.002)
    grasp = load_hand_scene("hand_grasp")
    for pair in itertools.product(models, repeat=2):
        HandGraspRun(grasp, [load_simulated_device(c) for c in pair]).run(0.002)


def _paced_kernels() -> None:
    """The real-time runner's compiled loop of each port world kind, each device model on
    every port (`haptic-run --scene NAME --device MODEL`)."""
    for config in built_in_models():
        for scene in ("box_push", "grasp_vertical", "hand_press", "hand_grasp"):
            compile_paced(port_scene(scene, [config], None).world())


def _port_kernels() -> None:
    _station_kernels()
    _hand_port_kernels()
    _paced_kernels()


#: `--demo`: the kernels of `make demo`'s run (haptic-run's defaults) and nothing else
DEMO_RUN: Run = ("testbed", "ideal", "swing", 1.0)


def _engine(run: Run, real: bool = False) -> HapticEngine:
    """An engine of the run's scene, device and user (its device as a server loads it with
    `real`, else the simulated model), for compiling on."""
    device = load_device(run[1]) if real else load_simulated_device(run[1])
    return HapticEngine(load_scene(run[0]), device, load_user(run[2]))


def _method_tick(run: Run) -> None:
    """The run's rendering method's tick (stages.tick.rendering_tick on the engine's method
    marker: the god-object's or the local model's, the only one its step calls) compiled on
    the run's records, not run."""
    engine = _engine(run)
    marker = engine.recs[-1]
    rendering_tick.compile(tuple(numba.typeof(r) for r in (engine.model, engine.data, marker)))


def _updates_lane(run: Run) -> None:
    """The sim's kernels, the update's parser and install (and the parser called from
    Python, as the log writer decodes each update); then the run on the virtual clock (what
    is left: its burst, over the step the other lane compiled by then)."""
    warm_sim_kernels(load_scene(run[0]))
    _engine(run).receive(bytes(8))  # the parser and the install route (rejected: too short)
    UpdateParser().parse(bytes(8))  # the parser as the log writer calls it, from Python
    _run_virtual([run])


def _loop_lane(run: Run) -> None:
    """The rendering method's tick, the engine's step around it, the real-time loop's
    mailbox and ring, and the real-time loop (its compiled paced loop over the local
    model's kind, the device's physics in it)."""
    _method_tick(run)
    engine = _engine(run)
    engine.clock[0]["ready"] = 1  # the stages run on the empty model
    engine.tick(engine.dt_nominal)
    compile_loop_kernels(_engine(run, real=True))
    compile_realtime_kernels(_engine(run, real=True))


def run_groups(run: Run) -> list[tuple[str, Callable[[], None]]]:
    """One run's kernels in two groups of about the same compiling time, so that on two
    cores (LANES) neither waits for, or compiles again, what the other compiles first: the
    sim, the update's parser and install (then the virtual run, whose step the other has
    compiled by then); the method's tick, the engine's step, the mailbox and the real-time
    loop. One after the other, the same kernels."""
    scene, device = Path(run[0]).stem, Path(run[1]).stem
    return [
        (f"sim and update kernels, {scene} scene", partial(_updates_lane, run)),
        (f"rendering and real-time loop kernels: {scene} scene, {device} device",
         partial(_loop_lane, run)),
    ]  # fmt: skip


def warm_groups(run: Run | None = None) -> list[tuple[str, Callable[[], None]]]:
    """What warm_all compiles, in groups: (a description, the call that compiles it). The
    first scene compiles most of the sim and the rendering stages, the others what they add.
    With `run`, only that run's (run_groups)."""
    if run is not None:
        return run_groups(run)
    runs = warm_runs()
    scenes, devices = runs[: len(SCENE_RUNS)], runs[len(SCENE_RUNS) :]
    groups: list[tuple[str, Callable[[], None]]] = [
        (f"sim + rendering kernels, {run[0]} scene", partial(_run_virtual, [run])) for run in scenes
    ]
    groups.append(
        (
            f"device kernels: {', '.join(r[1] for r in devices)} ({devices[0][0]} scene)",
            partial(_run_virtual, devices),
        )
    )
    groups.append(
        (f"real-time loop kernels: {len(built_in_models())} device models", _loop_kernels)
    )
    groups.append(("port kernels: the shared world, a station, the hand scenes", _port_kernels))
    return groups


def _cached_kernels(cache: Path) -> dict[Path, int]:
    """The compiled kernels (numba's .nbc files) in `cache`, with their mtimes."""
    if not cache.is_dir():
        return {}
    files = {}
    for f in cache.rglob("*.nbc"):
        with contextlib.suppress(OSError):  # another process replaced it meanwhile
            files[f] = f.stat().st_mtime_ns
    return files


#: the groups (by index into warm_groups()) each worker of a parallel warm-up compiles: the
#: sim's, the devices' and the real-time loop's in one (the loop's reuse the sim's rendering
#: kernels), the ports' in the other; the kernels both need are compiled by both
LANES = (lambda i, n: i < n - 1, lambda i, n: i == n - 1)


def warm_all(out: TextIO | None = None, jobs: int = 1, run: Run | None = None) -> float:
    """Compile (or load) every kernel; returns the seconds it took. With `out`, a line per
    group (what, how long, compiled or loaded) and the total are written to it. With jobs
    2, the groups compile in two processes at once (LANES), each group's line as it ends.
    With `run`, only that run's kernels (run_groups); without, every group, and the cache
    is marked as warmed for every run (runs_warmed)."""
    cache = Path(os.environ["NUMBA_CACHE_DIR"])  # set by `shared` on import, or by the user

    def say(text: str, end: str = "\n") -> None:
        if out is not None:
            out.write(text + end)
            out.flush()

    say(f"warming numba kernels (cache: {cache})")
    started, before = time.perf_counter(), _cached_kernels(cache)
    if jobs > 1:
        _warm_lanes(say, run)
    else:
        for what, warm in warm_groups(run):
            say(f"  {what} ...", end="")
            t0, group_before = time.perf_counter(), _cached_kernels(cache)
            warm()
            written = _written(group_before, cache)
            how = f"compiled, {written} cached" if written else "loaded from the cache"
            say(f" {time.perf_counter() - t0:.1f} s ({how})")
    total = time.perf_counter() - started
    mark_warmed(cache, ALL_WARMED if run is None else run_key(run))
    mark_used(cache)
    written = _written(before, cache)
    how = f"{written} kernels compiled" if written else "all loaded from the cache"
    say(f"numba kernels ready in {total:.1f} s ({how})")
    if written:  # a new build's cache: the old builds' beyond what prune_builds keeps go
        removed = prune_builds(cache, numba_caches())
        if removed:
            mb = sum(size for _, size in removed) / 1e6
            say(f"removed {len(removed)} older builds' caches ({mb:.0f} MB) from {cache.parent}")
    return total


def _written(before: dict[Path, int], cache: Path) -> int:
    return sum(before.get(f) != m for f, m in _cached_kernels(cache).items())


def _warm_lane(lane: int, done: Any, run: Run | None) -> None:
    """One worker of a parallel warm-up: its groups, each reported (index, seconds) on `done`."""
    groups = warm_groups(run)
    for i, (_, warm) in enumerate(groups):
        if LANES[lane](i, len(groups)):
            t0 = time.perf_counter()
            warm()
            done.put((i, time.perf_counter() - t0))


def _warm_lanes(say: Callable[..., None], run: Run | None) -> None:
    """The groups in two processes at once; a line per group as it ends."""
    import multiprocessing as mp

    groups = warm_groups(run)
    ctx = mp.get_context("spawn")
    done = ctx.Queue()
    workers = [ctx.Process(target=_warm_lane, args=(k, done, run)) for k in range(len(LANES))]
    for w in workers:
        w.start()
    try:
        for _ in range(len(groups)):
            while True:
                try:
                    i, seconds = done.get(timeout=1.0)
                    break
                except queue.Empty:
                    failed = [w for w in workers if w.exitcode not in (None, 0)]
                    if failed:
                        code = failed[0].exitcode
                        raise RuntimeError(f"a warm-up worker failed (exit {code})") from None
            say(f"  {groups[i][0]} ... {seconds:.1f} s")
    finally:
        for w in workers:
            w.join(timeout=5.0)
            if w.is_alive():
                w.kill()
                w.join()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m haptic_local_model.haptic_server.harness.warmup",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--quiet", "-q", action="store_true", help="print nothing")
    parser.add_argument(
        "--jobs", "-j", type=int, default=1, choices=(1, 2),
        help="compile in this many processes at once (make warm: 2)",
    )  # fmt: skip
    parser.add_argument(
        "--demo", action="store_true",
        help="only the kernels of make demo's run (haptic-run's defaults), not every feature's",
    )  # fmt: skip
    args = parser.parse_args(argv)
    warm_all(None if args.quiet else sys.stderr, args.jobs, DEMO_RUN if args.demo else None)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Touch your own pymunk world: the one module a user imports from (docs/touch-your-world.md).

    import pymunk
    from haptic_local_model import api

    space = pymunk.Space()                      # the user's own world, in metres and kilograms
    ...                                         # their bodies and shapes
    finger = pymunk.Body(1.0, 1.0e-3)           # 1 kg, 1e-3 kg m^2: the device's own order
    space.add(finger, pymunk.Circle(finger, 0.01))
    run = api.run_offline(space, finger, seconds=2.0, log="touch.mcap")
    print(run.wrench_command[:, :2].max(axis=0))  # N, the force the device rendered

`run_offline` renders the user's space on the virtual clock with a simulated device and user:
each sim step the library drives the held body toward the haptic proxy and steps the user's
space (one compiled call: the proxy's pushes reach their bodies through the held body's
contacts), then builds the local model of the held body's neighbourhood from the space with
the sim's own compiled builder. The run is deterministic, and its log replays bit for bit
with `haptic-replay` (or `replays_identically`). Everything here is plain Python and numpy
arrays: no records, no numba types.

What a space may hold that is not rendered raises `UnsupportedSpaceError` or warns with
`SpaceWarning`, naming the body, shape or constraint and what is rendered instead.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pymunk

from haptic_local_model.device_models.registry import device_config, load_simulated_device
from haptic_local_model.haptic_server.harness.live_space import LiveSpace
from haptic_local_model.haptic_server.harness.log_arrays import LogArrays, Table, read_arrays
from haptic_local_model.haptic_server.harness.replay import replay
from haptic_local_model.haptic_server.harness.virtual import run_virtual, warm_virtual
from haptic_local_model.haptic_server.log import read_log
from haptic_local_model.shared.config import Material, load_user, resolve
from haptic_local_model.sim_server.space_units import Units, scale_space
from haptic_local_model.sim_server.user_space import (
    DEFAULT_CONTACT,
    SpaceWarning,
    UnsupportedSpaceError,
    UserSpaceWorld,
    check_space,
)

__all__ = [
    "DEFAULT_CONTACT",
    "LiveRun",
    "LogArrays",
    "Material",
    "OfflineRun",
    "SpaceWarning",
    "Table",
    "Touch",
    "TouchOptions",
    "Units",
    "UnsupportedSpaceError",
    "check_space",
    "read_arrays",
    "replays_identically",
    "run_live",
    "run_offline",
    "scale_space",
    "scene_file",
    "touch",
]


@dataclass(frozen=True)
class TouchOptions:
    """How a user's space is rendered.

    rate_hz: sim steps per second (each step is `substeps` pymunk steps of the user's space);
    contact: the stiffness and damping of every contact (friction and restitution are each
    touched shape's own pymunk values); margin_m: how far from the held body a neighbour is
    sent; after_step: the user's own code of a step of their loop, called after each step
    with the space's time in seconds."""

    rate_hz: float = 60.0
    substeps: int = 10
    contact: Material = DEFAULT_CONTACT
    margin_m: float = 0.02
    after_step: Callable[[float], None] | None = field(default=None, compare=False)


@dataclass(frozen=True)
class OfflineRun:
    """What an offline run rendered, one row per haptic tick (arrays, SI units).

    times_s: (n,) s; device_pose: (n, 3) m, m, rad (world frame); proxy_pose: (n, 3) the held
    body's operational point on the haptic side's proxy; wrench_command: (n, 3) N, N, N m,
    what the device was commanded; n_contacts: (n,) contacts in the installed local model;
    faults: (n,) the loop's fault code (0: none). updates: local models sent; refused:
    those the haptic side refused, by reason (a held body driven beyond the scene's speed
    bounds); speedup: simulated s per wall s; log_path: the MCAP log, if one was written."""

    times_s: np.ndarray
    device_pose: np.ndarray
    proxy_pose: np.ndarray
    wrench_command: np.ndarray
    n_contacts: np.ndarray
    faults: np.ndarray
    updates: int
    speedup: float
    log_path: Path | None
    refused: dict[str, int]


def run_offline(
    space: pymunk.Space,
    tool: pymunk.Body,
    seconds: float,
    *,
    device: str = "ideal",
    user: str = "swing",
    log: Path | str | None = None,
    options: TouchOptions | None = None,
) -> OfflineRun:
    """Hold `tool` (a dynamic body of `space`) with a simulated `device` moved by a simulated
    `user` (shipped names or paths of TOML files) for `seconds` on the virtual clock; log to
    `log` (MCAP) if given. The space is stepped: at the end it holds the run's last state."""
    opts = options or TouchOptions()
    world = UserSpaceWorld(
        space, tool, opts.rate_hz, opts.substeps, opts.contact, opts.margin_m, opts.after_step
    )
    user_config = load_user(user)
    configs = {
        "scene": world.text,
        "device": device_config(device).read_text(),
        "user": resolve("users", user).read_text(),
    }
    warm_virtual(world.scene, load_simulated_device(device), user_config)
    result = run_virtual(
        world.scene, load_simulated_device(device), user_config, seconds, log, configs, world
    )
    rows = result.ticks
    return OfflineRun(
        times_s=rows["t"].copy(),
        device_pose=rows["device_pose"].copy(),
        proxy_pose=rows["vm_pose"].copy(),
        wrench_command=rows["wrench_command"].copy(),
        n_contacts=rows["n_contacts"].astype(np.int64),
        faults=rows["fault"].astype(np.int64),
        updates=result.updates,
        speedup=result.speedup,
        log_path=result.log_path,
        refused=dict(result.refused),
    )


@dataclass(frozen=True)
class LiveRun:
    """What a live run rendered, from the haptic server's summary (haptic-run's figures).

    ticks: haptic ticks run; tick_rate_hz: their rate; update_age_ms: the local models' age
    at install (publish -> installed, ms) as {"p50", "p99", "max"}; updates_installed, and
    updates_rejected by reason; watchdog_trips; sim_steps and sim_overruns: the user's
    space's steps and those that started late; log_path: the MCAP log, if one was written
    (`read_arrays(log_path)` has every tick); summary: the whole summary."""

    ticks: int
    tick_rate_hz: float
    update_age_ms: dict[str, float]
    updates_installed: int
    updates_rejected: dict[str, int]
    watchdog_trips: int
    sim_steps: int
    sim_overruns: int
    log_path: Path | None
    summary: dict[str, object]

    def report(self) -> str:
        """One line of the run's figures (fault ticks from the log, if one was written)."""
        age = self.update_age_ms
        faults = "?"
        if self.log_path is not None:
            faults = str(int(np.count_nonzero(read_arrays(self.log_path).ticks["fault"])))
        return (
            f"live: {self.ticks} ticks at {self.tick_rate_hz:.1f} Hz, update age p50 "
            f"{age.get('p50', float('nan')):.2f} ms p99 {age.get('p99', float('nan')):.2f} ms, "
            f"{self.updates_installed} local models installed, rejected {self.updates_rejected}"
            f", watchdog trips {self.watchdog_trips}, sim overruns {self.sim_overruns}/"
            f"{self.sim_steps}, fault ticks {faults}"
        )


class Touch:
    """A user's space held live while the user's own loop runs: `with api.touch(space, tool)
    as hand:` then, each pass of their loop, `hand.step()` in place of `space.step(dt)`. A
    step waits for its deadline (`options.rate_hz`: the user's loop is paced by it), steps
    the space over the coming period in `options.substeps` pymunk steps with `tool` driven
    toward the haptic proxy, and publishes its local model; it returns the space's time (s).
    A loop slower than the period is counted as overruns (`result.sim_overruns`), not
    caught up. After the `with`, `result` holds the run's figures (`LiveRun`)."""

    def __init__(self, live: LiveSpace, log: Path | str | None) -> None:
        self._live, self._log = live, log
        self.result: LiveRun | None = None

    def __enter__(self) -> Touch:
        try:
            self._live.open()
        except BaseException:
            self._live.close()
            raise
        return self

    def step(self) -> float:
        return self._live.step()

    def __exit__(self, *_: object) -> None:
        s = self._live.close()
        sim = s.get("sim") or {}
        self.result = LiveRun(
            ticks=int(s.get("ticks", 0)),
            tick_rate_hz=float(s.get("tick_rate_hz", 0.0)),
            update_age_ms=dict(s.get("update_age_ms") or {}),
            updates_installed=int(s.get("updates_installed", 0)),
            updates_rejected=dict(s.get("updates_rejected") or {}),
            watchdog_trips=int(s.get("watchdog_trips", 0)),
            sim_steps=int(sim.get("steps", 0)),
            sim_overruns=int(sim.get("overruns", 0)),
            log_path=Path(self._log) if self._log is not None else None,
            summary=s,
        )


def touch(
    space: pymunk.Space,
    tool: pymunk.Body,
    *,
    device: str = "ideal",
    user: str = "swing",
    log: Path | str | None = None,
    options: TouchOptions | None = None,
    network: str = "loopback",
    start_server: bool = True,
) -> Touch:
    """Hold `tool` live, the user's loop stepping the space (`Touch`). With `start_server`
    (the default) the haptic server (the same process as `haptic-run`'s) is started on
    `device` (a simulated one moved by the simulated `user`) over the `network` on a free
    port, logging to `log` if given, and stopped at the end. Without it, the haptic server
    the user runs is reached over `network` (default: this host's authenticated loopback
    one): start it with the space's scene, `haptic-server --scene FILE --device NAME`, FILE
    written by `scene_file` with the same options, NAME any device model, a real one
    included (`device`, `user` and `log` are then that server's business)."""
    opts = options or TouchOptions()
    world_options = (opts.rate_hz, opts.substeps, opts.contact, opts.margin_m, opts.after_step)
    live = LiveSpace(space, tool, world_options, device, user, log, network, start_server)
    return Touch(live, log if start_server else None)


def scene_file(
    space: pymunk.Space, tool: pymunk.Body, path: Path | str, options: TouchOptions | None = None
) -> Path:
    """Write the scene `space` is rendered with, holding `tool` (its materials, held body or
    chain, rates and bounds), to `path` (TOML): for a haptic server the user starts
    (`haptic-server --scene PATH`) that `touch(..., start_server=False)` then reaches, with
    the same `options`. Returns the path."""
    opts = options or TouchOptions()
    world = UserSpaceWorld(space, tool, opts.rate_hz, opts.substeps, opts.contact, opts.margin_m)
    out = Path(path)
    out.write_text(world.text)
    return out


def run_live(
    space: pymunk.Space,
    tool: pymunk.Body,
    seconds: float,
    *,
    device: str = "ideal",
    user: str = "swing",
    log: Path | str | None = None,
    options: TouchOptions | None = None,
    network: str = "loopback",
) -> LiveRun:
    """Hold `tool` live for `seconds` of wall time, the library's loop stepping the space
    (`touch` with a loop of `step()` only; `options.after_step` is the user's code of a
    step): start the haptic server on `device` (a simulated one moved by the simulated
    `user`) over the `network` on a free port, stop it at the end (its log, if `log`,
    replays with `haptic-replay`)."""
    with touch(space, tool, device=device, user=user, log=log, options=options,
               network=network) as hand:  # fmt: skip
        steps = max(1, round(seconds * (options or TouchOptions()).rate_hz))
        for _ in range(steps):
            hand.step()
    assert hand.result is not None  # set by the with's exit
    return hand.result


def replays_identically(log: Path | str) -> bool:
    """Whether the haptic side of a logged run, re-run from the log's own updates and
    configs, gives every tick row bit for bit (what `haptic-replay LOG` checks)."""
    return replay(read_log(Path(log))).identical

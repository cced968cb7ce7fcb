"""Deterministic virtual-clock mode: the sim and the haptic engine in one process.

The same SimWorld and HapticEngine as the real-time servers run on a simulated clock: the
sim is stepped whenever the haptic time reaches its next period, its update goes through
the same encode/decode path as over Zenoh, and is installed at that tick. No threads, no
wall clock: two runs give identical logs, faster than real time (DESIGN §1).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from haptic_local_model.device_models.base import SimulatedDevice
from haptic_local_model.device_models.registry import device_config, load_simulated_device
from haptic_local_model.haptic_server.engine import HapticEngine
from haptic_local_model.haptic_server.engine import warm_kernels as warm_engine_kernels
from haptic_local_model.haptic_server.log import run_metadata
from haptic_local_model.haptic_server.logger import LogFeed
from haptic_local_model.haptic_server.model import TICK_DTYPE
from haptic_local_model.haptic_server.supervisor import InstallOnly, supervise
from haptic_local_model.shared.config import (
    SceneConfig,
    UserConfig,
    load_scene,
    load_user,
    resolve,
    scene_text,
)
from haptic_local_model.shared.protocol.codes import Method, Reason
from haptic_local_model.shared.protocol.proxy import ShapeImpulses, TrainState
from haptic_local_model.sim_server.user_space import UserSpaceWorld
from haptic_local_model.sim_server.world import SimWorld, ToolTarget
from haptic_local_model.sim_server.world import warm_kernels as warm_sim_kernels

VIRTUAL_EPOCH = 1


@dataclass
class VirtualResult:
    """What a virtual-clock run produced."""

    ticks: np.ndarray  # TICK_DTYPE records of every tick
    updates: int
    world: SimWorld | UserSpaceWorld  # the sim's world at the end (bodies, tool)
    stage_ns: dict[str, int]  # total time spent in each stage (sim_step, local_model, ...)
    update_bytes: list[int]  # size of every update
    svd_steps: int  # sim steps that ran the SVD of J_h (0 for a free body)
    wall_s: float
    sim_s: float
    log_path: Path | None
    load_s: float = 0.0  # kernels loaded before the run (run_virtual_named), not in wall_s
    setup_s: float = 0.0  # the world, the engine and the log writer made, not in wall_s
    # the sim's own updates the haptic side refused, by reason: only ever beyond the scene's
    # envelope (a tool the sim let run away after the guard tripped), never malformed
    refused: dict[str, int] = dataclasses.field(default_factory=dict)

    @property
    def speedup(self) -> float:
        return self.sim_s / self.wall_s if self.wall_s > 0 else float("inf")


def run_virtual(
    scene: SceneConfig,
    device: SimulatedDevice,
    user: UserConfig,
    duration_s: float,
    log_path: Path | str | None = None,
    configs: dict[str, str] | None = None,
    world: SimWorld | UserSpaceWorld | None = None,
) -> VirtualResult:
    """Run `duration_s` of simulated time; returns every tick record (and logs if asked).

    world: the sim's world of `scene` (default: the scene's own, SimWorld(scene); a user's
    space, UserSpaceWorld, with its own scene)."""
    entered = time.perf_counter()
    world = SimWorld(scene) if world is None else world
    engine = HapticEngine(scene, device, user)
    dt = engine.dt_nominal
    n_ticks = round(duration_s / dt)
    rows = np.zeros(n_ticks, TICK_DTYPE)
    rows.fill(0)  # the pages mapped now, before the clock starts (np.zeros maps them lazily)
    log = LogFeed(log_path, run_metadata(configs or {}, {"clock": "virtual"})) if log_path else None
    sim_period = 1.0 / scene.sim_rate_hz
    next_sim_t = 0.0
    seq = 0
    coupled = engine.method == Method.VIRTUAL_COUPLING_FOH
    stage = dict.fromkeys(("sim_step", "local_model", "install", "tick"), 0)
    sizes: list[int] = []
    refused: dict[str, int] = {}
    svd_steps = 0
    runs_svd = world.stats.svd  # a linkage's local model has resisted directions to find
    clock = time.perf_counter_ns
    started = time.perf_counter()
    impulses_from = 0  # the ticks whose impulses on shapes the sim has applied
    try:
        k = 0
        while k < n_ticks:
            t = k * dt
            if t >= next_sim_t - 1e-12:
                t0 = clock()
                # every step covers the coming period [seq P, (seq + 1) P] of the one clock:
                # the first from rest (the real sim has no proxy state yet), the others with
                # the impulses of the ticks since the last step, as the real sim gets them
                target = _target(engine, coupled, rows[impulses_from:k]) if seq > 0 else None
                world.step(target)
                impulses_from = k
                # the world now holds at world.time: that far ahead of this tick (the phase
                # between the sim's period and the ticks included)
                lead = world.time - t
                t1 = clock()
                t_ns = round(t * 1e9)  # published (and received) at the virtual time
                raw = world.local_model_bytes(VIRTUAL_EPOCH, seq, t_ns, lead)  # built, encoded
                svd_steps += runs_svd
                t2 = clock()
                supervise(engine, InstallOnly(partial(_install_own, engine, raw, refused)))
                t3 = clock()
                stage["sim_step"] += t1 - t0
                stage["local_model"] += t2 - t1
                stage["install"] += t3 - t2
                sizes.append(len(raw))
                if log is not None:
                    log.update(k, raw, t_ns)
                engine.set_update(seq, 0.0)
                seq += 1
                next_sim_t += sim_period
            # the ticks up to the next sim step, in one compiled burst
            stop = min(n_ticks, _next_step_tick(k + 1, dt, next_sim_t))
            t5 = clock()
            engine.run_ticks(dt, rows, k, stop)
            stage["tick"] += clock() - t5
            if log is not None:
                log.ticks(rows[k:stop])
            k = stop
    finally:
        if log is not None:
            log.close()
    wall = time.perf_counter() - started
    return VirtualResult(
        rows, seq, world, stage, sizes, svd_steps, wall, n_ticks * dt,
        Path(log_path) if log_path else None, setup_s=started - entered, refused=refused,
    )  # fmt: skip


def _next_step_tick(k: int, dt: float, next_sim_t: float) -> int:
    """The first tick from k at which the sim steps (k * dt reaches next_sim_t, as above)."""
    guess = max(k, math.ceil((next_sim_t - 1e-12) / dt) - 1)
    while guess * dt < next_sim_t - 1e-12:
        guess += 1
    while guess > k and (guess - 1) * dt >= next_sim_t - 1e-12:
        guess -= 1
    return guess


#: why the haptic side may refuse the sim's own update: its tool beyond the scene's envelope
#: (it followed a proxy the guard stopped); any other reason is a bug of the sim or the codec
ENVELOPE_REASONS = (Reason.IMPLAUSIBLE.tag, Reason.JUMP.tag)


def _install_own(engine: HapticEngine, raw: bytes, refused: dict[str, int]) -> int:
    """Install the sim's own update; one beyond the scene's envelope is counted in
    `refused`, any other refusal raises (a bug)."""
    reason = engine.receive(raw)
    if not reason:
        return 1
    if reason not in ENVELOPE_REASONS:
        raise RuntimeError(f"the sim's own update was rejected: {reason}")
    refused[reason] = refused.get(reason, 0) + 1
    return 0


def _target(engine: HapticEngine, coupled: bool, ticks: np.ndarray | None = None) -> ToolTarget:
    """The proxy state the real sim would receive: it holds its tool (fresh = False) while
    the haptic side is in (or ramping to or from) its safe state; under god_object, with the
    impulses on shapes over `ticks` (tick rows: those since the sim's last step); with the
    haptic side's mechanism state at this tick (a scene with one: the sim starts its step
    from it, as from a proxy state of age 0)."""
    q, qd = engine.proxy_pose()
    pose, twist = engine.device_world_pose()
    r = engine.row[0]
    fresh = float(r["safe"]) == 0.0
    impulses = ShapeImpulses.none()
    if engine.method == Method.GOD_OBJECT and ticks is not None:
        impulses = ShapeImpulses.of_ticks(
            ticks["god_env_key"], ticks["god_env_arm"], ticks["god_env_force"], ticks["dt"]
        )
    return ToolTarget(
        q=q, qd=qd, device_pose=pose, device_twist=twist, coupled_to_device=coupled, fresh=fresh,
        impulses=impulses, train=TrainState.of_row(r),
    )  # fmt: skip


def run_virtual_named(
    scene: str,
    device: str,
    user: str,
    duration_s: float,
    log_path: Path | str | None = None,
    haptic_rate_hz: float | None = None,
) -> VirtualResult:
    """Load configs by name or path and run the virtual clock (at `haptic_rate_hz` instead
    of the scene's, if given). Every kernel is loaded from numba's cache (or compiled) first,
    on spare copies, so the run's speed is its own; the time that took is `load_s`."""
    # loaded (and checked: a ConfigError names the file and key) before their texts are read
    scene_config, user_config = load_scene(scene, haptic_rate_hz), load_user(user)
    load_simulated_device(device)
    configs = {
        "scene": scene_text(resolve("scenes", scene), haptic_rate_hz),
        "device": device_config(device).read_text(),
        "user": resolve("users", user).read_text(),
    }
    started = time.perf_counter()
    warm_virtual(scene_config, load_simulated_device(device), user_config)
    load_s = time.perf_counter() - started
    result = run_virtual(
        scene_config, load_simulated_device(device), user_config, duration_s, log_path, configs
    )
    return dataclasses.replace(result, load_s=load_s)


def warm_virtual(scene: SceneConfig, device: SimulatedDevice, user: UserConfig) -> None:
    """Load every kernel a virtual-clock run calls, on a spare world, engine and `device`."""
    warm_sim_kernels(scene)
    engine = warm_engine_kernels(scene, device, user)  # a tick's and an install's
    engine.run_ticks(engine.dt_nominal, np.zeros(1, TICK_DTYPE), 0, 1)  # the burst's

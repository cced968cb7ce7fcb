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
from haptic_local_model.haptic_server.world import run_ticks
from haptic_local_model.haptic_server.world import run_virtual as run_virtual_world
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


class SimFeed:
    """The sim's steps and updates as a single-device world's feed (world.Feed): before each
    tick at which the haptic time reaches the sim's next period, the sim steps over the
    coming period from the proxy state it would receive, and its update goes through the
    same encode/decode path as over Zenoh and is installed; the log gets the ticks before
    it, then the update."""

    def __init__(self, world: SimWorld | UserSpaceWorld, engine: HapticEngine,
                 log: LogFeed | None) -> None:  # fmt: skip
        self.world, self.engine, self.log = world, engine, log
        self.sim_period = 1.0 / engine.scene.sim_rate_hz
        self.next_sim_t = 0.0
        self.seq = 0
        self.coupled = engine.method == Method.VIRTUAL_COUPLING_FOH
        self.stage = dict.fromkeys(("sim_step", "local_model", "install"), 0)
        self.sizes: list[int] = []
        self.refused: dict[str, int] = {}
        self.svd_steps = 0
        self.logged = 0  # the ticks logged (and whose impulses on shapes the sim applied)
        self.log_ns = 0  # writing the log: no stage's

    def _log_ticks(self, rows: np.ndarray) -> None:
        if self.log is not None:
            t0 = time.perf_counter_ns()
            self.log.ticks(rows)
            self.log_ns += time.perf_counter_ns() - t0

    def __call__(self, k: int, rows: np.ndarray) -> int:
        dt, clock = self.engine.dt_nominal, time.perf_counter_ns
        t = k * dt
        if t >= self.next_sim_t - 1e-12:
            self._log_ticks(rows[self.logged : k])
            t0 = clock()
            # every step covers the coming period [seq P, (seq + 1) P] of the one clock: the
            # first from rest (the real sim has no proxy state yet), the others with the
            # impulses of the ticks since the last step, as the real sim gets them
            seq, engine = self.seq, self.engine
            target = _target(engine, self.coupled, rows[self.logged : k]) if seq > 0 else None
            self.world.step(target)
            self.logged = k
            # the world now holds at world.time: that far ahead of this tick (the phase
            # between the sim's period and the ticks included)
            lead = self.world.time - t
            t1 = clock()
            t_ns = round(t * 1e9)  # published (and received) at the virtual time
            raw = self.world.local_model_bytes(VIRTUAL_EPOCH, seq, t_ns, lead)  # built, encoded
            self.svd_steps += self.world.stats.svd  # a linkage's has resisted directions to find
            t2 = clock()
            supervise(engine, InstallOnly(partial(_install_own, engine, raw, self.refused)))
            self.stage["sim_step"] += t1 - t0
            self.stage["local_model"] += t2 - t1
            t3 = clock()
            self.stage["install"] += t3 - t2
            self.sizes.append(len(raw))
            if self.log is not None:
                self.log.update(k, raw, t_ns)
                self.log_ns += clock() - t3
            engine.set_update(seq, 0.0)
            self.seq += 1
            self.next_sim_t += self.sim_period
        return _next_step_tick(k + 1, dt, self.next_sim_t)  # the ticks to it in one burst

    def close(self, rows: np.ndarray) -> None:
        """The ticks after the last update logged, and the log closed."""
        if self.log is not None:
            self.log.ticks(rows[self.logged :])
            self.log.close()


def run_virtual(
    scene: SceneConfig,
    device: SimulatedDevice,
    user: UserConfig,
    duration_s: float,
    log_path: Path | str | None = None,
    configs: dict[str, str] | None = None,
    world: SimWorld | UserSpaceWorld | None = None,
) -> VirtualResult:
    """Run `duration_s` of simulated time; returns every tick record (and logs if asked): the
    one virtual-clock runner (world.run_virtual) on the engine, the sim its feed.

    world: the sim's world of `scene` (default: the scene's own, SimWorld(scene); a user's
    space, UserSpaceWorld, with its own scene)."""
    entered = time.perf_counter()
    world = SimWorld(scene) if world is None else world
    engine = HapticEngine(scene, device, user)
    log = LogFeed(log_path, run_metadata(configs or {}, {"clock": "virtual"})) if log_path else None
    feed = SimFeed(world, engine, log)
    started = time.perf_counter()
    rows = np.zeros(0, TICK_DTYPE)
    try:
        rows, wall = run_virtual_world(engine, duration_s, feed)
    finally:
        if log is not None:
            feed.close(rows)
    # the ticks' time: the runner's outside its feed's stages and the log's writing
    fed = sum(feed.stage.values()) + feed.log_ns
    stage = {**feed.stage, "tick": max(0, round(wall * 1e9) - fed)}
    sim_s = len(rows) * engine.dt_nominal
    return VirtualResult(
        rows, feed.seq, world, stage, feed.sizes, feed.svd_steps, wall, sim_s,
        Path(log_path) if log_path else None, setup_s=started - entered, refused=feed.refused,
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
    run_ticks(engine, np.zeros(1, TICK_DTYPE), 0, 1)  # the burst's

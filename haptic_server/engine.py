"""The haptic side without a clock or a network: install updates, run ticks.

`HapticEngine` owns the preallocated records the kernels work on, the device and the
simulated user. The real-time server, the virtual clock and `haptic-replay` all drive this
same object, so a replay of a log runs exactly the code that produced it.
"""

from __future__ import annotations

import itertools
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from haptic_local_model.device_models.base import (
    Device,
    SimulatedDevice,
    world_limits,
    world_map_of,
)
from haptic_local_model.device_models.common import refill_noise
from haptic_local_model.haptic_server.log import TICK_SCHEMA_NAME, TICK_TOPIC
from haptic_local_model.haptic_server.model import (
    CLOCK_DTYPE,
    DATA_DTYPE,
    DEVICE_IO_DTYPE,
    INSTALL_DTYPE,
    MODEL_DTYPE,
    TICK_DTYPE,
    envelope_record,
    god_record,
    params_record,
    set_guard,
)
from haptic_local_model.haptic_server.simulated import run_ticks, simulated_tick
from haptic_local_model.haptic_server.stages.finger import restart_finger
from haptic_local_model.haptic_server.stages.install import (
    DEFAULT_MAX_AGE_S,
    DEFAULT_MAX_SKEW_S,
    EPOCH_LAW_LIVE,
    accept_update,
)
from haptic_local_model.haptic_server.stages.tick import (
    engine_step,
    method_marker,
    store_applied,
)
from haptic_local_model.haptic_server.stages.train import restart_train, train_model
from haptic_local_model.haptic_server.users import USER_GIVEN, USER_POINTER, user_record
from haptic_local_model.haptic_server.world import WorldKind
from haptic_local_model.shared.config import ConfigError, SceneConfig, UserConfig
from haptic_local_model.shared.kinematics import (
    MAX_DOF,
    fastest_spin,
    link_frames,
    point_jacobian,
    point_on_link,
)
from haptic_local_model.shared.linalg import min_norm_least_squares
from haptic_local_model.shared.protocol.codes import Fault, Method, Reason, reason_tag
from haptic_local_model.shared.protocol.layout import DEFAULT_LIMITS, limits_record
from haptic_local_model.shared.protocol.update import MAX_UPDATE_BYTES

CONTACT_MATCH_RADIUS_M = 2.0e-3  # a contact keeps its state if its tool point moved less
#: the receive buffer: the largest valid update (12 DOF, 64 contacts, 64 shapes)
RECEIVE_BUFFER_BYTES = MAX_UPDATE_BYTES

#: A single device on a sim's world (a local model or a god-object) as a world kind: its
#: rows are the ticks' rows; its log replays with the sim's updates it holds, through
#: `haptic-replay` (harness/replay.py), not from the rows alone (no `replay` of rows).
LOCAL_MODEL_KIND = WorldKind(
    "local_model", TICK_TOPIC, TICK_SCHEMA_NAME, TICK_DTYPE, SceneConfig, 1, None
)


@dataclass
class EngineCounters:
    """What the engine has installed, rejected and why (logged and summarised).

    Installs and rejections are counted in the install record (`installed`, and
    `reject_counts` by verdict code), which the server's mailbox kernel increments in place:
    no Python per message.
    """

    install: np.ndarray
    epochs: int = 0
    reinitialisations: int = 0

    @property
    def installed(self) -> int:
        return int(self.install[0]["installed"])

    @property
    def reject_counts(self) -> np.ndarray:
        return self.install[0]["reject_counts"]

    @property
    def rejected(self) -> int:
        return int(self.reject_counts.sum())

    @property
    def rejected_by_reason(self) -> dict[str, int]:
        by_reason: dict[str, int] = {}
        for code in np.flatnonzero(self.reject_counts):
            reason = reason_tag(int(code))
            by_reason[reason] = by_reason.get(reason, 0) + int(self.reject_counts[code])
        return by_reason


def install_record() -> np.ndarray:
    """An empty install record: nothing installed, default message limits."""
    rec = np.zeros(1, INSTALL_DTYPE)
    rec[0]["epoch"] = -1
    rec[0]["seq"] = -1
    rec[0]["match_radius_m"] = CONTACT_MATCH_RADIUS_M
    rec[0]["limits"] = limits_record(DEFAULT_LIMITS)
    rec[0]["epoch_law"] = EPOCH_LAW_LIVE
    rec[0]["max_age_s"] = DEFAULT_MAX_AGE_S
    rec[0]["max_skew_s"] = DEFAULT_MAX_SKEW_S
    return rec


class HapticEngine:
    """Local model + device control around a device and a simulated user (DESIGN §4).

    It owns the records the kernels work on (haptic_server.model): `model` (installed local
    models and gains), `data` (proxy, contact state, scratch, the log row), `io` (the device
    side), `clock` (what the loop measured) and `install` (order and verdict counters)."""

    def __init__(
        self,
        scene: SceneConfig,
        device: Device | SimulatedDevice,
        user: UserConfig,
        safe_ramp_s: float = 0.05,
    ) -> None:
        self.scene = scene
        self.device = device
        # a hardware driver has a real hand on it: no simulated user, no physics to advance
        self.sim_device = device if isinstance(device, SimulatedDevice) else None
        self.dt_nominal = 1.0 / scene.haptic_rate_hz
        limits = device.limits()
        if scene.haptic_rate_hz > limits.max_rate_hz:
            raise ConfigError(
                f"scene {scene.name!r} on device {device.name!r}",
                "haptic_rate_hz",
                f"{scene.haptic_rate_hz:g} Hz exceeds the device's max_rate_hz "
                f"{limits.max_rate_hz:g} Hz",
            )
        # the device's own map (shared: rate control moves its offset), or scale 1 + offset
        self.world_map = world_map_of(device).record
        self.model = np.zeros(1, MODEL_DTYPE)
        self.data = np.zeros(1, DATA_DTYPE)
        self.io = np.zeros(1, DEVICE_IO_DTYPE)
        self.clock = np.zeros(1, CLOCK_DTYPE)
        self.install = install_record()
        self.io[0]["max_wrench"] = limits.max_wrench
        self.model["params"] = params_record(
            scene.rendering,
            self.io[0]["max_wrench"],
            device.rendering,
            safe_ramp_s,
            self.world_map,
        )
        self.model["god"] = god_record(scene, self.model["params"][0]["max_wrench"])
        self.model["train"] = train_model(scene)
        # what the scene allows: checked at every install, guarded at every tick
        self.install[0]["envelope"] = envelope_record(scene)
        set_guard(self.model["params"], scene)
        # views of the records, for the Python side and tests
        self.params = self.model["params"]
        self.slots = self.model["slots"][0]
        self.state = self.data["state"]
        self.scratch = self.data["scratch"]
        self.row = self.data["row"]
        self.world_sensors = self.data[0]["sensors"]
        self.hand_measured = self.data[0]["hand_measured"]
        self.sensors = self.io[0]["sensors"]
        self.hand = self.io[0]["hand"]
        self._command = self.io[0]["command"]
        self.method = Method(int(self.params[0]["method"]))
        self.ready = False
        self.user = user_record(user)  # its script starts (start_s) at the first update
        self._given_user = user_record(user)  # a replay's hand: set in io.hand each tick
        self._given_user[0]["kind"] = USER_GIVEN
        # a hand that follows a pointer: its targets arrive through the real-time server's
        # I/O sidecar (share_user); anywhere else it holds where it took hold
        self.follows_pointer = bool(self.user[0]["kind"] == USER_POINTER)
        # the compiled step's records; the last, the method as a type, picks its tick
        self.recs = (
            self.model, self.data, self.io, self.world_map, self.clock, method_marker(self.method)
        )  # fmt: skip
        self.loop_recs = (*self.recs, self.install)  # and the install's: the loop's kernels'
        self._true_pose = np.zeros(3)
        self._true_twist = np.zeros(3)
        self.counters = EngineCounters(self.install)
        self.buffer = np.zeros(RECEIVE_BUFFER_BYTES, np.uint8)  # 8-byte aligned
        # one-element views of the fields the Python side writes on install ticks: an
        # ndarray item costs ~0.1 us where a field of a record scalar costs ~0.5 us
        self._clock_seq = self.clock["update_seq"]
        self._clock_age = self.clock["update_age_ms"]
        self._clock_ready = self.clock["ready"]
        self._new_epoch = self.install["new_epoch"]
        self._follow = self.install["follow"]
        self._clock_seq[0] = self._update_seq = -1
        self._update_age_ms = 0.0
        self._install_ticks: deque[int] = deque(maxlen=4)  # FOH: arrival ticks of updates
        self.state[0]["safe"] = 1.0
        self.state[0]["safe_target"] = 1.0
        self._stale = False
        self.stale = False  # the watchdog fired: the next installed update re-initialises

    # --- updates ------------------------------------------------------------------------

    def receive(self, raw: bytes, latency_s: float = 0.0) -> str:
        """Validate and install an update's bytes, taken latency_s after its publication
        (the receiver's clock minus its publish time); returns "" or the rejection reason."""
        n = len(raw)
        if n > self.buffer.shape[0]:
            self.counters.reject_counts[Reason.SIZE] += 1
            return Reason.SIZE.tag
        self.buffer[:n] = np.frombuffer(raw, np.uint8)
        code = self.receive_buffer(self.buffer, n, latency_s)
        return "" if code == 0 else reason_tag(code)

    def receive_buffer(self, buf: np.ndarray, nbytes: int, latency_s: float = 0.0) -> int:
        """Validate and install the update in an 8-byte aligned uint8 buffer; 0 or a reason code.

        One numba call parses, validates, checks the epoch and sequence order (DESIGN §3)
        and installs: the newest model becomes slot 0 and the previous one slot 1,
        cross-faded over blend_ms (DESIGN §4.4); contacts keep their state by key. The
        real-time server does the same from its mailbox (`haptic_server.mailbox`,
        `take_updates`), then calls `installed`.
        """
        god = self.recs[-1]
        code = int(accept_update(buf, nbytes, latency_s, self.model, self.data, self.install, god))
        if code:
            self.counters.reject_counts[code] += 1
            return code
        self.installed()
        return 0

    def installed(self) -> None:
        """The Python side of an install, after `accept_update` installed a model: mark the
        engine ready, re-initialise on a new epoch or after the watchdog, advance the FOH
        setpoint. The server's mailbox kernel calls for it only when one of those applies
        (`follow`, or a new epoch); for any other install it does nothing."""
        self.ready = True
        self._clock_ready[0] = 1
        new_epoch = bool(self._new_epoch[0])
        if new_epoch:
            self.counters.epochs += 1
            self._install_ticks.clear()
        if new_epoch or self.needs_reinit:
            # a restarted sim, the same sim after an outage (it has moved its tool to rest
            # while the proxy went on), or a fault the guard caught: start again from the
            # sim's state
            self._reinitialise(self.slots[0], first=new_epoch and self.counters.epochs == 1)
        self.stale = False
        if self.method == Method.VIRTUAL_COUPLING_FOH:
            self._install_ticks.append(self.tick_index)
            self._advance_foh(self.slots[0]["tool_pose"])

    def set_admission(
        self, max_age_s: float, max_skew_s: float, epoch_law: int = EPOCH_LAW_LIVE
    ) -> None:
        """How updates are admitted by time and epoch (haptic_server.stages.install): the
        network's max_update_age_ms and clock_skew_ms, or a replayed release's law."""
        ins = self.install[0]
        ins["max_age_s"], ins["max_skew_s"], ins["epoch_law"] = max_age_s, max_skew_s, epoch_law

    def check_plausibility(self, on: bool) -> None:
        """Whether updates are checked against the scene (haptic_server/stages/plausible.py):
        always in a run; off only for tests of the kernels on hand-made models and for logs of
        a release before the check."""
        self.install[0]["envelope"]["enabled"] = 1 if on else 0

    def guard(self, on: bool) -> None:
        """Whether the loop's runaway guard and passivity observer run (stages/safety.py):
        always in a run; off only for logs of a release before them."""
        self.params[0]["guard"] = 1 if on else 0

    def unguarded(self) -> HapticEngine:
        """No plausibility check and no guard: for tests and benchmarks of the kernels on
        hand-made models (a tool that is not the scene's, speeds beyond its envelope).
        Returns the engine."""
        self.check_plausibility(False)
        self.guard(False)
        return self

    @property
    def tick_index(self) -> int:
        """Ticks run so far (the clock record's count)."""
        return int(self.clock[0]["tick"])

    @property
    def time(self) -> float:
        """The clock record's time: the sum of the ticks' dt (s)."""
        return float(self.clock[0]["t"])

    @property
    def simulated(self) -> bool:
        """The device's physics runs here, held by a simulated hand (not a hardware driver)."""
        return self.sim_device is not None

    @property
    def faulted(self) -> bool:
        """The loop's guard or NaN check sent the device safe (state.fault): with the guard on,
        the next installed update re-initialises the proxy (a release before it stayed safe
        until the watchdog or a new epoch)."""
        return int(self.state[0]["fault"]) != 0 and int(self.params[0]["guard"]) == 1

    @property
    def needs_reinit(self) -> bool:
        """The next installed update re-initialises the proxy: after the watchdog or a fault."""
        return self._stale or self.faulted

    @property
    def stale(self) -> bool:
        """The watchdog fired: the next installed update re-initialises the proxy."""
        return self._stale

    @stale.setter
    def stale(self, value: bool) -> None:
        self._stale = value
        self.install[0]["stale"] = 1 if value else 0
        foh = self.method == Method.VIRTUAL_COUPLING_FOH
        self._follow[0] = 1 if (value or foh) else 0

    @property
    def epoch(self) -> int:
        return int(self.install[0]["epoch"])

    @property
    def last_seq(self) -> int:
        return int(self.install[0]["seq"])

    @property
    def offset(self) -> np.ndarray:
        """The device-to-world map's offset (world pose of the device's origin), a copy."""
        return self.world_map[0]["offset"].copy()

    def _reinitialise(self, m: np.void, first: bool) -> None:
        """Start (or restart) from the sim's tool state; the device is mapped onto the VM so
        the coupling starts at rest, and forces fade in from the safe state. The model from
        before is dropped (no cross-fade from a stale geometry).

        The map's offset is anchored from the device's measured pose (what a real driver
        reports): world = offset + scale * measured pose lands on the target.
        """
        st = self.state[0]
        self.slots[1]["valid"] = 0
        st["blend"] = 1.0
        st["q"] = m["q"]
        st["qd"] = m["qd"]
        st["fault"] = Fault.NONE
        st["port_energy"] = 0.0  # the passivity observer starts afresh
        st["device_energy"] = -1.0
        st["last_command"] = 0.0
        # the impact ledger's offset is against the old proxy and device: it starts afresh
        # (law 3 only: logs of the earlier laws replay with the carry they kept)
        if int(self.params[0]["impulse_law"]) == 3:
            st["impulse_carry"] = 0.0
        st["impulse_prepaid"] = 0.0
        st["impact_offset"] = 0.0
        st["impact_offset_rate"] = 0.0
        st["foh_goal"] = m["tool_pose"]
        st["foh_steps_left"] = 0
        if self.method == Method.GOD_OBJECT:
            restart_finger(self.data[0], float(m["q"][0]), float(m["q"][1]))
        # a train starts where the sim has it (the install checked it is this scene's)
        m0 = self.model[0]
        restart_train(m0["train"], self.data[0]["train"], float(m["avar_s"]), float(m["avar_sd"]))
        if first and self.sim_device is not None:
            # a simulated device starts at its home pose, offset from the VM as the scene says
            self.sim_device.reset(np.zeros(3))
            target = m["tool_pose"] + np.array(self.scene.initial_device_offset)
        else:
            target = m["tool_pose"].copy()  # the device stays where it is: map it onto the tool
        self.device.read(self.sensors)
        wm = self.world_map[0]
        wm["offset"] = target - wm["scale"] * self.sensors[0]["pose"]
        world_twist = wm["scale"] * self.sensors[0]["twist"]
        st["prev_device_twist"] = world_twist
        if not first:
            self.counters.reinitialisations += 1
            # the sim held its tool while the haptic side was silent, but the hand did not
            # stop: the proxy takes the device's velocity, so the coupling resumes at rest
            st["qd"] = self._bounded(m, self._joint_velocity(m, world_twist))
        st["safe_target"] = 0.0
        if first:
            # the simulated hand's waypoints are relative to where the device starts; a later
            # re-initialisation moves the world, not the hand
            if self.sim_device is not None:
                self.sim_device.true_state(self._true_pose, self._true_twist)
                self.user[0]["start_pose"] = self._true_pose
            self.user[0]["start_s"] = self.time
            st["safe"] = 0.0  # everything starts at rest: no force to fade in

    @staticmethod
    def _joint_velocity(m: np.void, twist: np.ndarray) -> np.ndarray:
        """The q velocity whose operational-point twist is closest to `twist` (the minimum
        norm least squares solution through J_h at the model's q, in a fixed-order kernel:
        a replay of a re-initialisation gives the same bits on any CPU, which LAPACK does not)."""
        d = int(m["dof"])
        frame_pos = np.zeros((MAX_DOF, 2))
        frame_angle = np.zeros(MAX_DOF)
        point = np.zeros(2)
        jac = np.zeros((3, MAX_DOF))
        link = int(m["op_link"])
        link_frames(m, m["q"], d, frame_pos, frame_angle)
        point_on_link(frame_pos, frame_angle, link, m["op_point"], point)
        point_jacobian(m, frame_pos, d, link, point[0], point[1], jac)
        qd = np.zeros(MAX_DOF)
        min_norm_least_squares(jac, 3, d, twist, qd)
        return qd

    def _bounded(self, m: np.void, qd: np.ndarray) -> np.ndarray:
        """A re-initialised proxy's joint velocity within half the guard's bounds: near a
        singularity the least-squares solve can ask for any joint speed (138 rad/s was seen at
        a folded arm), which the sim's tool would then follow. Scaled as a whole, so the
        direction of motion is kept. Unchanged with the guard off (logs before 0.4)."""
        p = self.params[0]
        if int(p["guard"]) == 0:
            return qd
        d = int(m["dof"])
        spin = float(fastest_spin(m["joint_types"][:d], m["parents"][:d], qd[:d]))
        energy = 0.5 * float(qd[:d] @ m["mass"][:d, :d] @ qd[:d])
        scale = 1.0
        if spin > 0.5 * p["guard_max_angular_speed"]:
            scale = 0.5 * float(p["guard_max_angular_speed"]) / spin
        if energy * scale**2 > 0.25 * p["guard_max_energy"]:
            scale = min(scale, 0.5 * float(np.sqrt(p["guard_max_energy"] / energy)))
        return qd * scale

    def _advance_foh(self, target: np.ndarray) -> None:
        """Seed 002's setpoint interpolation: move toward the sim's newest tool pose over the
        mean of the last three update intervals, in ticks as they arrived (first-order
        hold), or jump to it (zero-order hold)."""
        st = self.state[0]
        ticks = self._install_ticks
        if int(self.params[0]["foh_interpolate"]) == 0 or len(ticks) < 2:
            st["foh_goal"] = target
            st["foh_steps_left"] = 0
            return
        last = list(ticks)[-4:]  # ticks are integers: the mean is exact (as numpy's was)
        intervals = [b - a for a, b in itertools.pairwise(last)]
        steps = max(1, round(sum(intervals) / len(intervals)))
        st["foh_step"] = (target - st["foh_goal"]) / steps
        st["foh_steps_left"] = steps

    # --- ticks --------------------------------------------------------------------------

    def set_safe(self, safe: bool) -> None:
        """Ramp to (or back from) the safe state: damping only (watchdog, shutdown)."""
        self.state[0]["safe_target"] = 1.0 if safe else 0.0

    def set_stale(self) -> None:
        """The watchdog fired (no valid update for watchdog_ms): ramp to the safe state; the
        next update installed re-initialises the proxy from the sim's state, same epoch or not."""
        self.set_safe(True)
        self.stale = True

    def share_user(self, slot: np.ndarray) -> None:
        """Move the simulated user into `slot` (a USER_DTYPE[1] in the block shared with the
        I/O sidecar, which writes a pointer's targets there); the engine uses it from now on."""
        slot[0] = self.user[0]
        self.user = slot

    def tick(
        self,
        dt: float,
        lateness_us: float = 0.0,
        work_us: float = 0.0,
        update_seq: int = -1,
        update_age_ms: float = 0.0,
        hand: np.ndarray | None = None,
    ) -> np.ndarray:
        """One tick: user -> device sensors -> local model + control -> device. Returns the row.

        The timing arguments only go into the log row (the real-time server measures them).
        `hand`, if given, is the hand's wrench this tick instead of the simulated user's
        (a replay feeds the logged one). A simulated device runs the whole tick in one
        compiled call (haptic_server.simulated); a hardware driver is read and commanded
        around the engine step.
        """
        if update_seq != self._update_seq or update_age_ms != self._update_age_ms:
            self.set_update(update_seq, update_age_ms)
        sim = self.sim_device
        if sim is None:
            dev = self.device
            dev.read(self.sensors)
            engine_step(self.recs, dt, lateness_us, work_us)
            store_applied(self.world_map, dev.command(self._command), self.data)
            return self.row
        user = self.user
        if hand is not None:
            self.hand[:] = hand  # replay: the recorded hand
            user = self._given_user
        if not simulated_tick(self.recs, sim.records, user, dt, lateness_us, work_us):
            refill_noise(sim.noise, sim.records, dt)  # raises if a block cannot cover dt
            simulated_tick(self.recs, sim.records, user, dt, lateness_us, work_us)
        return self.row

    def loop_recs_copy(self) -> tuple[Any, ...]:
        """A copy of each record of `loop_recs` (the method marker as it is: a type), to
        compile the loop's kernels on without touching the engine's."""
        marker = self.recs[-1]
        return (*(r.copy() for r in self.recs[:-1]), marker, self.install.copy())

    def set_update(self, seq: int, age_ms: float) -> None:
        """The newest installed update's seq and age, for the rows of the ticks that follow."""
        self._clock_seq[0] = self._update_seq = seq
        self._clock_age[0] = self._update_age_ms = age_ms

    # --- the World protocol (haptic_server/world.py), with a simulated device -----------
    @property
    def kind(self) -> WorldKind:
        return LOCAL_MODEL_KIND

    @property
    def devices(self) -> Sequence[SimulatedDevice]:
        return [self._simulated()]

    @property
    def period_s(self) -> float:
        return self.dt_nominal

    def burst(self, rows: np.ndarray, start: int, stop: int) -> int:
        """Ticks start..stop-1 of the simulated device and user in one compiled call, row k
        into rows[k]; the first tick not run (earlier than stop when the device's noise
        block needs a refill). A sim's updates are installed between bursts (receive)."""
        return run_ticks(self.recs, self._simulated().records, self.user, self.dt_nominal,
                         rows, start, stop)  # fmt: skip

    def limits(self) -> list[list[float]]:
        return [[float(v) for v in world_limits(self.device)]]

    def summary_lines(self, rows: np.ndarray, wall_s: float) -> list[str]:
        last = rows[-min(len(rows), round(self.scene.haptic_rate_hz)) :]
        cmd = last["wrench_command"][:, :2]
        return [
            f"{len(rows)} ticks, {len(rows) * self.dt_nominal:.3f} s in {wall_s:.2f} s of wall "
            f"time; mean command over the last second ({cmd[:, 0].mean():+.3f}, "
            f"{cmd[:, 1].mean():+.3f}) N"
        ]

    def _simulated(self) -> SimulatedDevice:
        if self.sim_device is None:
            raise TypeError(f"a world's ticks need a simulated device, not {self.device.name!r}")
        return self.sim_device

    def proxy_pose(self) -> tuple[np.ndarray, np.ndarray]:
        d = int(self.slots[0]["dof"])
        st = self.state[0]
        return st["q"][:d].copy(), st["qd"][:d].copy()

    def device_world_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The device's measured pose and twist in the world frame at the last tick: what the
        real-time server publishes to the sim (ProxyState)."""
        ws = self.world_sensors[0]
        return ws["pose"].copy(), ws["twist"].copy()


def warm_kernels(
    scene: SceneConfig, device: Device | SimulatedDevice, user: UserConfig
) -> HapticEngine:
    """Compile (or load from numba's cache) every kernel of a tick and of an install for
    these configs, on a throwaway engine with an empty model: no sim, no pymunk. Returns
    that engine (ready), for callers with kernels of their own to load on it."""
    engine = HapticEngine(scene, device, user)
    engine.receive(bytes(8))  # the parser and the install route (rejected: too short)
    engine.clock[0]["ready"] = 1  # run the stages on the empty model
    engine.tick(engine.dt_nominal)
    # what a re-initialisation calls from Python (the first install's among them: loading a
    # kernel from the cache on its first call costs milliseconds, in the loop otherwise)
    engine.device.read(engine.sensors)
    if engine.sim_device is not None:
        engine.sim_device.true_state(np.zeros(3), np.zeros(3))
        engine.sim_device.reset(np.zeros(3))
        engine.sim_device.safe_stop()  # the loop's at the run's end (compiled then otherwise)
    engine._joint_velocity(engine.slots[0], np.zeros(3))
    min_norm_least_squares(np.eye(3, MAX_DOF), 3, 3, np.zeros(3), np.zeros(MAX_DOF))
    restart_finger(engine.data[0], 0.0, 0.0)  # a god-object's re-initialisation
    restart_train(engine.model[0]["train"], engine.data[0]["train"], 0.0, 0.0)  # a train's
    return engine

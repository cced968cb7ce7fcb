"""A hand scene's port (DESIGN-WAVE2 §7, docs/grasp.md): the mass-spring hand driven by a
simulated device and glove, on a virtual clock.

Each tick, in one compiled call: the user's hand on the device's true state; the device's
reading mapped to the world is the tracked palm (pose and twist: a reading that is not
finite cuts the palm's drives for the tick, haptic_server/stages/hand.py); the user's
`finger_angles` are the glove's (interpolated, with their slopes as rates); the hand's tick;
the palm's command mapped back to the device, clipped at its limits, and the device's
physics. The glove's torques (gated for a tendon glove) are logged: the simulated glove has
no actuators of its own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from haptic_local_model.device_models.base import (
    SENSOR_DTYPE,
    SimulatedDevice,
    world_limits,
    world_map_of,
)
from haptic_local_model.device_models.kernels import (
    device_noise_ready,
)
from haptic_local_model.device_models.registry import load_simulated_device
from haptic_local_model.device_models.world_map import (
    MAP_DTYPE,
)
from haptic_local_model.haptic_server.paced import kind_kernel, never_asks, paced_entry, paced_ticks
from haptic_local_model.haptic_server.port_scene import MAX_GLOVE_ROWS, glove_script
from haptic_local_model.haptic_server.stages.cosim import body_core
from haptic_local_model.haptic_server.stages.hand import glove_at, hand_records, hand_tick
from haptic_local_model.haptic_server.stages.port_io import (
    drive_device,
    push_stretch,
    read_device,
    rest_device,
)
from haptic_local_model.haptic_server.users import USER_DTYPE
from haptic_local_model.haptic_server.world import Compiled, WorldKind, compiled_burst, run_virtual
from haptic_local_model.shared.config import UserConfig, load_user
from haptic_local_model.shared.kinematics import MAX_DOF
from haptic_local_model.shared.port_config import HandSceneConfig, HandTable
from haptic_local_model.shared.protocol.station import vec3

F8 = np.float64
I8 = np.int64

HAND_IO_DTYPE = np.dtype(
    [
        ("t", F8),
        ("sensors", SENSOR_DTYPE, (1,)),
        ("world", SENSOR_DTYPE, (1,)),
        ("hand", F8, (3,)),  # the user's wrench on the device
        ("out", F8, (3,)),  # the device's command, device frame
        ("limits", F8, (3,)),
        ("user", USER_DTYPE, (1,)),
        ("map", MAP_DTYPE, (1,)),
        ("glove", F8, (MAX_GLOVE_ROWS, MAX_DOF - 2)),  # the script: t, then the angles
        ("n_glove", I8),
        ("glove_fed", I8),  # 1: the tracked fingers are fed (a station's glove), not scripted
    ]
)

#: One tick of a hand scene (world frame unless said).
HAND_ROW_DTYPE = np.dtype(
    [
        ("t", F8),
        ("target", F8, (MAX_DOF,)),  # the tracked hand: the device's palm, the glove
        ("target_rate", F8, (MAX_DOF,)),
        ("q", F8, (MAX_DOF,)),
        ("qd", F8, (MAX_DOF,)),
        ("command", F8, (3,)),  # the palm's, world frame
        ("out", F8, (3,)),  # the device's, device frame
        ("hand_wrench", F8, (3,)),  # the user's on the device, device frame
        ("glove_torque", F8, (MAX_DOF,)),
        ("glove_ungated", F8, (MAX_DOF,)),
        ("contact_force", F8, (2,)),
        ("penetration", F8),
        ("n_contacts", I8),
        ("invalid", I8),
        ("singular", I8),
        ("device_fault", I8),
    ]
)
#: the row fields a replay recomputes from the logged targets
HAND_REPLAYED = ("q", "qd", "command", "glove_torque", "glove_ungated", "contact_force",
                 "penetration", "n_contacts", "invalid", "singular")  # fmt: skip


@njit(cache=True)
def _row(d, io, r):
    r.t = io.t
    for a in range(MAX_DOF):
        r.target[a] = d.target[a]
        r.target_rate[a] = d.target_rate[a]
        r.q[a] = d.q[a]
        r.qd[a] = d.qd[a]
        r.glove_torque[a] = d.glove_torque[a]
        r.glove_ungated[a] = d.glove_ungated[a]
    for c in range(3):
        r.command[c] = d.command[c]
        r.out[c] = io.out[c]
        r.hand_wrench[c] = io.hand[c]
    r.contact_force[0] = d.contact_force[0]
    r.contact_force[1] = d.contact_force[1]
    r.penetration = d.penetration
    r.n_contacts = d.n_contacts
    r.invalid = d.invalid
    r.singular = d.singular
    r.device_fault = io.sensors[0].fault


@njit(cache=True)
def track_hand(m, d, s, dev):
    """The user's hand on the device's true state; the device's world-mapped reading is
    the tracked palm (pose, twist as the rate), the glove script the fingers."""
    n = m.dof
    read_device(s.user, s.t, dev, s.hand, s.sensors, s.map, s.world)
    for c in range(3):
        d.target[c] = s.world[0].pose[c]
        d.target_rate[c] = s.world[0].twist[c]
    glove_at(s.glove, s.n_glove, s.t, n - 3, d.target[3:n], d.target_rate[3:n])


@njit(cache=True)
def drive_hand(d, s, dev):
    """The palm's command to the device, mapped, clipped at its limits; its physics."""
    drive_device(s.map, d.command, s.limits, s.out, dev, d.dt, s.hand, s.sensors)


@njit(cache=True)
def run_hand_port_ticks(chain, model, data, io, dev, rows, start, stop):
    """Ticks start..stop-1 (module docstring), row k into rows[k]. Returns the first tick
    not run: stop, or earlier when the device's noise block needs a refill."""
    d = data[0]
    s = io[0]
    for k in range(start, stop):
        if not device_noise_ready(dev, d.dt):
            return k
        track_hand(model[0], d, s, dev)
        hand_tick(chain, model, data)
        drive_hand(d, s, dev)
        _row(d, s, rows[k])
        s.t += d.dt
    return stop


@kind_kernel
def hand_burst(w, rows, start, stop):
    """run_hand_port_ticks over the world's records (its chain, model, data, I/O, the
    device's): the kind's compiled ticks as the runners call them (world.Compiled)."""
    return run_hand_port_ticks(w[0], w[1], w[2], w[3], w[4], rows, start, stop)


@paced_entry(never_asks, hand_burst)
def hand_paced(w, rows, loop, windows, ts):
    """The real-time runner's compiled loop over hand_burst (haptic_server.paced)."""
    return paced_ticks(never_asks, hand_burst, w, rows, loop, windows, ts)


def _walls(scene: HandSceneConfig) -> list[tuple[np.ndarray, float, tuple[float, float, float]]]:
    out = []
    for b in scene.walls:
        v, rounding = body_core(b)
        out.append((v, rounding, (b.position[0], b.position[1], b.angle)))
    return out


def scene_contact(scene: HandSceneConfig) -> tuple[float, float, float, float]:
    """(stiffness, damping, friction, tangential stiffness) of every contact of the scene."""
    c = scene.contact
    return (c.stiffness_n_per_m, c.damping_ns_per_m, c.friction,
            c.friction_stiffness_ratio * c.stiffness_n_per_m)  # fmt: skip


def port_hand_records(
    scene: HandSceneConfig, limits: tuple[float, float, float], p: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Port p's hand's (chain, model, data) at its pose, its palm's rates a device's
    estimate (not differenced: haptic_server/stages/hand.py, `measured_palm`); `limits`:
    the device's, world frame. The run's and the replay's."""
    spec = scene.hand_of(p)
    chain, model, data = hand_records(spec, _walls(scene), scene_contact(scene), spec.pose,
                                      limits, scene.period_s, gravity=scene.gravity)  # fmt: skip
    model[0]["measured_palm"] = 1
    return chain, model, data


@dataclass
class HandPortResult:
    rows: np.ndarray
    wall_s: float


def port_io(
    s: np.ndarray, device: SimulatedDevice, user: UserConfig, spec: HandTable
) -> tuple[float, float, float]:
    """Fill a port's HAND_IO_DTYPE record `s` for this device, user and hand (map, limits,
    the glove's script); the device's limits in the world frame."""
    s["map"][0] = world_map_of(device).record[0]
    s["limits"] = device.limits().max_wrench
    rest = [a for f in spec.fingers for a in f.rest]
    glove = glove_script(user, rest)
    s["glove"][: len(glove), : glove.shape[1]] = glove
    s["n_glove"] = len(glove)
    return vec3(world_limits(device))


def place_device(
    s: np.ndarray,
    device: SimulatedDevice,
    user: UserConfig,
    spec: HandTable,
    start: tuple[float, float, float],
) -> None:
    """The device at rest at `start`, its map putting it where the palm's springs are in
    equilibrium with its hand's constant push at the palm's pose (the tracked palm inside
    the grasp by push / k), its user's script starting there."""
    wm = s["map"][0]
    anchor = np.asarray(spec.pose, F8) + push_stretch(user.wrench, wm, spec.palm_spring)
    s["user"][0] = rest_device(device, user, wm, start, anchor)
    s["map"][0] = wm


class HandPortRun:
    """A hand scene with its device and user, ready to run."""

    def __init__(
        self,
        scene: HandSceneConfig,
        device: SimulatedDevice | None = None,
        user: UserConfig | None = None,
    ) -> None:
        self.scene = scene
        self.kind = HAND_KIND
        self.period_s = scene.period_s
        port = scene.ports[0]
        self.device = device or load_simulated_device(port.device)
        self.devices = [self.device]
        self.user = user or load_user(port.user)
        self.spec = scene.hand_of(0)
        self.io = np.zeros(1, HAND_IO_DTYPE)
        limits = port_io(self.io[0], self.device, self.user, self.spec)
        self.chain, self.model, self.data = port_hand_records(scene, limits)
        place_device(self.io[0], self.device, self.user, self.spec, port.device_start)

    @property
    def compiled(self) -> Compiled:
        """The compiled ticks (hand_burst, hand_paced) and the records they take."""
        records = (self.chain, self.model, self.data, self.io, self.device.records)
        return Compiled(hand_burst, hand_paced, records)

    def burst(self, rows: np.ndarray, start: int, stop: int) -> int:
        """The World protocol's compiled ticks (hand_burst)."""
        return compiled_burst(self, rows, start, stop)

    def limits(self) -> list[list[float]]:
        return [list(map(float, self.model[0]["max_wrench"]))]

    def run(self, duration_s: float) -> HandPortResult:
        return HandPortResult(*run_virtual(self, duration_s))

    def summary_lines(self, rows: np.ndarray, wall_s: float) -> list[str]:
        last = rows[-min(len(rows), round(self.scene.haptic_rate_hz)) :]
        cmd, wall = last["command"][:, :2], last["contact_force"]
        return [
            f"{len(rows)} ticks in {wall_s:.2f} s of wall time",
            f"port {self.scene.ports[0].name} ({self.device.name}, {self.user.name}): mean "
            f"command over the last second ({cmd[:, 0].mean():+.3f}, {cmd[:, 1].mean():+.3f}) "
            f"N, the walls' force on the hand ({wall[:, 0].mean():+.3f}, "
            f"{wall[:, 1].mean():+.3f}) N",
            f"steps held {rows['singular'][-1]}, readings or commands not finite "
            f"{rows['invalid'][-1]}",
        ]


def replay_hand_rows(scene: HandSceneConfig, limits: tuple[float, float, float],
                     rows: np.ndarray) -> tuple[int, int | None]:  # fmt: skip
    """Re-run the hand on the rows' tracked hand (the device's palm, the glove); (ticks
    compared, the first tick whose outputs differ in any bit, or None)."""
    chain, model, data = port_hand_records(scene, limits)
    d = data[0]
    for k, row in enumerate(rows):
        d["target"] = row["target"]
        d["target_rate"] = row["target_rate"]
        hand_tick(chain, model, data)
        for name in HAND_REPLAYED:
            if np.asarray(d[name]).tobytes() != np.asarray(row[name]).tobytes():
                return k + 1, k
    return len(rows), None


#: a mass-spring hand that one device drives (`/ports/hand_tick`)
HAND_KIND = WorldKind(
    name="hand", topic="/ports/hand_tick", schema="haptic_server/HandPortTick",
    rows=HAND_ROW_DTYPE, scene=HandSceneConfig, ports=1,
    replay=lambda scene, limits, rows: replay_hand_rows(scene, limits[0], rows),
)  # fmt: skip

"""Two hands in ports holding one box (`hand_grasp`; DESIGN-WAVE2 §7 V5.5 with devices,
docs/grasp.md), on a virtual clock.

Each port is a simulated device, its map, its user (the hand holding the device and
wearing the glove) and a mass-spring hand. Each tick, in one compiled call: each user's
hand on its device's true state; each device's world-mapped reading is its hand's tracked
palm, each user's `finger_angles` its glove (`hand_ports.track_hand`); both hands and the
box in one implicit step (`stages/hand_grasp.grasp_tick`); each palm's command mapped back
to its device, clipped at its limits, and the device's physics. The log replays bit for bit
from the tracked hands it records.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from haptic_local_model.device_models.base import SimulatedDevice
from haptic_local_model.device_models.kernels import device_noise_ready
from haptic_local_model.device_models.registry import load_simulated_device
from haptic_local_model.haptic_server.hand_ports import (
    HAND_IO_DTYPE,
    drive_hand,
    place_device,
    port_hand_records,
    port_io,
    scene_contact,
    track_hand,
)
from haptic_local_model.haptic_server.paced import kind_kernel, never_asks, paced_entry, paced_ticks
from haptic_local_model.haptic_server.stages.hand_grasp import (
    MAX_HANDS,
    grasp_records,
    grasp_tick,
)
from haptic_local_model.haptic_server.world import (
    Compiled,
    WorldKind,
    compiled_burst,
    run_ticks,
    run_virtual,
)
from haptic_local_model.shared.config import UserConfig, load_user
from haptic_local_model.shared.kinematics import MAX_DOF
from haptic_local_model.shared.port_config import HandSceneConfig

F8 = np.float64
I8 = np.int64

#: One tick of two hands on one box (world frame unless said); per hand, in port order.
HAND_GRASP_ROW_DTYPE = np.dtype(
    [
        ("t", F8),
        ("target", F8, (MAX_HANDS, MAX_DOF)),  # the tracked hands: the devices, the gloves
        ("target_rate", F8, (MAX_HANDS, MAX_DOF)),
        ("q", F8, (MAX_HANDS, MAX_DOF)),
        ("qd", F8, (MAX_HANDS, MAX_DOF)),
        ("command", F8, (MAX_HANDS, 3)),  # each palm's, world frame
        ("out", F8, (MAX_HANDS, 3)),  # each device's, device frame
        ("hand_wrench", F8, (MAX_HANDS, 3)),  # each user's on its device, device frame
        ("glove_torque", F8, (MAX_HANDS, MAX_DOF)),
        ("glove_ungated", F8, (MAX_HANDS, MAX_DOF)),
        ("wall_force", F8, (MAX_HANDS, 2)),  # the static walls' on each hand
        ("invalid", I8, (MAX_HANDS,)),
        ("device_fault", I8, (MAX_HANDS,)),
        ("box_q", F8, (3,)),
        ("box_qd", F8, (3,)),
        ("box_force", F8, (3,)),  # the hands' mean force and torque on the box
        ("hand_box_force", F8, (MAX_HANDS, 3)),  # each hand's (torque about the box's COM)
        ("n_contacts", I8),  # hand-box contacts
        ("singular", I8),  # steps held (not finite after the sub-steps), the grasp's
    ]
)
#: the row fields a replay recomputes from the logged tracked hands
HAND_GRASP_REPLAYED = ("q", "qd", "command", "glove_torque", "glove_ungated", "wall_force",
                       "invalid", "box_q", "box_qd", "box_force", "hand_box_force",
                       "n_contacts", "singular")  # fmt: skip


@njit(cache=True)
def hand_grasp_row(hds, gd, io, r):
    """The tick's outputs into the row r (io: each port's device I/O; io[0].t the time)."""
    r.t = io[0].t
    for i in range(MAX_HANDS):
        d = hds[i][0]
        s = io[i]
        for a in range(MAX_DOF):
            r.target[i, a] = d.target[a]
            r.target_rate[i, a] = d.target_rate[a]
            r.q[i, a] = d.q[a]
            r.qd[i, a] = d.qd[a]
            r.glove_torque[i, a] = d.glove_torque[a]
            r.glove_ungated[i, a] = d.glove_ungated[a]
        for c in range(3):
            r.command[i, c] = d.command[c]
            r.out[i, c] = s.out[c]
            r.hand_wrench[i, c] = s.hand[c]
        r.wall_force[i, 0] = d.contact_force[0]
        r.wall_force[i, 1] = d.contact_force[1]
        r.invalid[i] = d.invalid
        r.device_fault[i] = s.sensors[0].fault
    for c in range(3):
        r.box_q[c] = gd.q_box[c]
        r.box_qd[c] = gd.qd_box[c]
        r.box_force[c] = gd.box_force[c]
        for i in range(MAX_HANDS):
            r.hand_box_force[i, c] = gd.hand_box_force[i, c]
    r.n_contacts = gd.n_contacts
    r.singular = gd.singular


@njit(cache=True)
def run_hand_grasp_ticks(grasp, io, devices, rows, start, stop):
    """Ticks start..stop-1 (module docstring), row k into rows[k]; grasp: (chains, models,
    datas, grasp model, grasp data) as `grasp_port_records` makes them; devices: both
    devices' records. Returns the first tick not run: stop, or earlier when a device's
    noise block needs a refill."""
    chains, hms, hds, gmodel, gdata = grasp
    dev0, dev1 = devices
    gd = gdata[0]
    dt = gd.dt
    for k in range(start, stop):
        if not device_noise_ready(dev0, dt) or not device_noise_ready(dev1, dt):
            return k
        track_hand(hms[0][0], hds[0][0], io[0], dev0)
        track_hand(hms[1][0], hds[1][0], io[1], dev1)
        grasp_tick(chains, hms, hds, gmodel, gdata)
        drive_hand(hds[0][0], io[0], dev0)
        drive_hand(hds[1][0], io[1], dev1)
        hand_grasp_row(hds, gd, io, rows[k])
        io[0].t += dt
        io[1].t += dt
    return stop


@kind_kernel
def hand_grasp_burst(w, rows, start, stop):
    """run_hand_grasp_ticks over the world's records ((chains, models, datas, grasp model,
    grasp data), both ports' I/O, both devices'): the kind's compiled ticks as the runners
    call them (world.Compiled)."""
    return run_hand_grasp_ticks(w[0], w[1], w[2], rows, start, stop)


@paced_entry(never_asks, hand_grasp_burst)
def hand_grasp_paced(w, rows, loop, windows, ts):
    """The real-time runner's compiled loop over hand_grasp_burst (haptic_server.paced)."""
    return paced_ticks(never_asks, hand_grasp_burst, w, rows, loop, windows, ts)


def grasp_port_records(
    scene: HandSceneConfig, limits: list[tuple[float, float, float]]
) -> tuple[tuple, tuple, tuple, np.ndarray, np.ndarray]:
    """Both hands (each at its pose, its device's world-frame `limits`) and the box:
    (chains, models, datas, grasp model, grasp data). The run's and the replay's."""
    box = scene.box
    if box is None or len(scene.ports) != MAX_HANDS:
        raise ValueError(f"{scene.name}: not a two-hand scene with a box")
    hands = [port_hand_records(scene, limits[p], p) for p in range(MAX_HANDS)]
    gm, gd = grasp_records(hands, box.size, box.mass, (*box.position, box.angle),
                           scene_contact(scene), scene.range_m)  # fmt: skip
    chains, models, datas = zip(*hands, strict=True)
    return tuple(chains), tuple(models), tuple(datas), gm, gd


@dataclass
class HandGraspResult:
    rows: np.ndarray
    wall_s: float


class HandGraspRun:
    """A two-hand scene with its devices and users, ready to run."""

    def __init__(
        self,
        scene: HandSceneConfig,
        devices: list[SimulatedDevice] | None = None,
        users: list[UserConfig] | None = None,
    ) -> None:
        self.scene = scene
        self.kind = HAND_GRASP_KIND
        self.period_s = scene.period_s
        self.devices = devices or [load_simulated_device(p.device) for p in scene.ports]
        self.users = users or [load_user(p.user) for p in scene.ports]
        self.specs = [scene.hand_of(p) for p in range(len(scene.ports))]
        self.io = np.zeros(MAX_HANDS, HAND_IO_DTYPE)
        world_limits = [
            port_io(self.io[p], dev, user, spec)
            for p, (dev, user, spec) in enumerate(
                zip(self.devices, self.users, self.specs, strict=True)
            )
        ]
        self.chains, self.models, self.datas, self.gmodel, self.gdata = grasp_port_records(
            scene, world_limits
        )
        for p, port in enumerate(scene.ports):
            place_device(self.io[p], self.devices[p], self.users[p], self.specs[p],
                         port.device_start)  # fmt: skip

    @property
    def compiled(self) -> Compiled:
        """The compiled ticks (hand_grasp_burst, hand_grasp_paced) and the records they
        take."""
        grasp = (self.chains, self.models, self.datas, self.gmodel, self.gdata)
        d0, d1 = self.devices
        return Compiled(hand_grasp_burst, hand_grasp_paced,
                        (grasp, self.io, (d0.records, d1.records)))  # fmt: skip

    def burst(self, rows: np.ndarray, start: int, stop: int) -> int:
        """The World protocol's compiled ticks (hand_grasp_burst)."""
        return compiled_burst(self, rows, start, stop)

    def ticks(self, rows: np.ndarray, start: int, stop: int) -> int:
        """Ticks start..stop-1 into rows (refilling the devices' noise as they need)."""
        return run_ticks(self, rows, start, stop)

    def limits(self) -> list[list[float]]:
        return [list(map(float, m[0]["max_wrench"])) for m in self.models]

    def run(self, duration_s: float) -> HandGraspResult:
        return HandGraspResult(*run_virtual(self, duration_s))

    def summary_lines(self, rows: np.ndarray, wall_s: float) -> list[str]:
        last = rows[-min(len(rows), round(self.scene.haptic_rate_hz)) :]
        lines = [f"{len(rows)} ticks in {wall_s:.2f} s of wall time"]
        for p, port in enumerate(self.scene.ports):
            cmd = last["command"][:, p, :2]
            lines.append(
                f"port {port.name} ({self.devices[p].name}, {self.users[p].name}): mean command "
                f"over the last second ({cmd[:, 0].mean():+.3f}, {cmd[:, 1].mean():+.3f}) N; "
                f"readings or commands not finite {rows['invalid'][-1, p]}"
            )
        q = rows["box_q"]
        lines.append(
            f"box: moved ({(q[-1, 0] - q[0, 0]) * 1e3:+.3f}, {(q[-1, 1] - q[0, 1]) * 1e3:+.3f}) "
            f"mm, turned {q[-1, 2] - q[0, 2]:+.4f} rad; hand-box contacts at the end "
            f"{rows['n_contacts'][-1]}, steps held {rows['singular'][-1]}"
        )
        return lines


def replay_hand_grasp_rows(
    scene: HandSceneConfig, limits: list[tuple[float, float, float]], rows: np.ndarray
) -> tuple[int, int | None]:
    """Re-run both hands and the box on the rows' tracked hands; (ticks compared, the first
    tick whose outputs differ in any bit, or None)."""
    chains, models, datas, gm, gd = grasp_port_records(scene, limits)
    out = np.zeros(1, HAND_GRASP_ROW_DTYPE)
    io = np.zeros(MAX_HANDS, HAND_IO_DTYPE)
    for k, row in enumerate(rows):
        for i in range(MAX_HANDS):
            datas[i][0]["target"] = row["target"][i]
            datas[i][0]["target_rate"] = row["target_rate"][i]
        grasp_tick(chains, models, datas, gm, gd)
        hand_grasp_row(datas, gd[0], io, out[0])
        for name in HAND_GRASP_REPLAYED:
            if out[0][name].tobytes() != np.asarray(row[name]).tobytes():
                return k + 1, k
    return len(rows), None


#: two mass-spring hands in ports holding one box (`/ports/hand_grasp_tick`; also the shared
#: world's log of a two-hand scene)
HAND_GRASP_KIND = WorldKind(
    name="hand_grasp", topic="/ports/hand_grasp_tick", schema="haptic_server/HandGraspTick",
    rows=HAND_GRASP_ROW_DTYPE, scene=HandSceneConfig, ports=2, replay=replay_hand_grasp_rows,
)  # fmt: skip

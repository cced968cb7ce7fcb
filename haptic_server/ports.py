"""Two ports on one co-simulated world: a `World` (DESIGN-WAVE2 §2 C3, §6).

Each port is a simulated device, its device-to-world map and its simulated user (the hand
that holds the device); both devices couple to their tools in one co-simulation
(`haptic_server/stages/cosim.py`). A tick, in one compiled call for both ports: each
hand on its device's true state, each device's reading mapped to the world, the
co-simulation, each command mapped back, clipped at the device's limits and held over the
device's physics. No sim process and no wire: this is the 1 kHz local model of a grasp and
its devices, run by haptic_server.world on the virtual clock (as fast as it computes,
`python -m haptic_local_model.benchmarks.grasp`) or in real time (`haptic-run`).
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
from haptic_local_model.haptic_server.stages.cosim import (
    MAX_COSIM_BODIES,
    MAX_COSIM_DOF,
    carry_sim_bodies,
    cosim_order,
    cosim_records,
    cosim_tick,
    sim_bodies_of,
)
from haptic_local_model.haptic_server.stages.port_io import (
    drive_device,
    push_stretch,
    read_device,
    rest_device,
)
from haptic_local_model.haptic_server.users import USER_DTYPE
from haptic_local_model.haptic_server.world import Compiled, WorldKind, compiled_burst, run_virtual
from haptic_local_model.shared.config import UserConfig, load_user
from haptic_local_model.shared.port_config import MAX_PORTS, MAX_SIM_BODIES, PortSceneConfig

F8 = np.float64
I8 = np.int64

#: The I/O of both ports: what the devices read, the world frame, the hands, the maps.
PORT_IO_DTYPE = np.dtype(
    [
        ("t", F8),
        ("sensors", SENSOR_DTYPE, (MAX_PORTS,)),  # device frame
        ("world", SENSOR_DTYPE, (MAX_PORTS,)),  # the same reading in the world frame
        ("hand", F8, (MAX_PORTS, 3)),  # each hand's true wrench on its device
        ("out", F8, (MAX_PORTS, 3)),  # each device's command, device frame
        ("limits", F8, (MAX_PORTS, 3)),  # each device's max_wrench, device frame
        ("users", USER_DTYPE, (MAX_PORTS,)),
        ("maps", MAP_DTYPE, (MAX_PORTS,)),
    ]
)

#: One tick of a port run (world frame).
PORT_ROW_DTYPE = np.dtype(
    [
        ("t", F8),
        ("q", F8, (MAX_COSIM_DOF,)),
        ("qd", F8, (MAX_COSIM_DOF,)),
        ("device_pose", F8, (MAX_PORTS, 3)),  # measured
        ("device_twist", F8, (MAX_PORTS, 3)),
        ("hand_wrench", F8, (MAX_PORTS, 3)),  # device frame (scale 1 maps: the world's)
        ("command", F8, (MAX_PORTS, 3)),
        ("body_force", F8, (MAX_COSIM_BODIES, 3)),  # contact wrench on each body
        ("n_contacts", I8),
        ("penetration", F8),
        ("invalid", I8),
        ("singular", I8),
        ("device_fault", I8, (MAX_PORTS,)),
        ("collisions", I8),  # colliding contacts resolved by impulses, since the start
        # the sim's bodies as the tick met them (pose, twist): inputs, as the devices are
        ("sim_bodies", F8, (MAX_SIM_BODIES, 6)),
        ("sim_wrench", F8, (MAX_COSIM_BODIES, 3)),  # the sim's bodies' on each body (input)
    ]
)


@njit(cache=True)
def port_in(cd, io, p, dev):
    """Port p's hand on its device, then the device's reading in the world frame."""
    read_device(io.users[p : p + 1], io.t, dev, io.hand[p], io.sensors[p : p + 1],
                io.maps[p : p + 1], io.world[p : p + 1])  # fmt: skip
    for c in range(3):
        cd.device_pose[p, c] = io.world[p].pose[c]
        cd.device_twist[p, c] = io.world[p].twist[c]


@njit(cache=True)
def port_out(cd, io, p, dev):
    """Port p's command to its device, clipped at its limits, and the device's physics."""
    drive_device(io.maps[p : p + 1], cd.command[p], io.limits[p], io.out[p], dev, cd.dt,
                 io.hand[p], io.sensors[p : p + 1])  # fmt: skip


@njit(cache=True)
def cosim_row(m, cd, r):
    """The co-simulation's tick into the row r (PORT_ROW_DTYPE): its state and outputs, the
    devices' world-frame readings and the sim's bodies it met. The port worlds' rows and the
    shared world's."""
    for a in range(MAX_COSIM_DOF):
        r.q[a] = cd.q[a]
        r.qd[a] = cd.qd[a]
    for p in range(MAX_PORTS):
        for c in range(3):
            r.device_pose[p, c] = cd.device_pose[p, c]
            r.device_twist[p, c] = cd.device_twist[p, c]
            r.command[p, c] = cd.command[p, c]
    for e in range(MAX_COSIM_BODIES):
        for c in range(3):
            r.body_force[e, c] = cd.body_force[e, c]
            r.sim_wrench[e, c] = cd.sim_wrench[e, c]
    r.n_contacts = cd.n_contacts
    r.penetration = cd.penetration
    r.invalid = cd.invalid
    r.singular = cd.singular
    r.collisions = cd.collisions
    sim_bodies_of(m, cd, r.sim_bodies)


@njit(cache=True)
def port_row(m, cd, io, r):
    """The tick into the row r, with what only a port world sees: the time, each hand's
    wrench and each device's fault (a port the scene does not have: zeros)."""
    r.t = io.t
    cosim_row(m, cd, r)
    for p in range(MAX_PORTS):
        r.device_fault[p] = io.sensors[p].fault
        for c in range(3):
            r.hand_wrench[p, c] = io.hand[p, c]


@njit(cache=True)
def run_port_ticks(cosim, data, io, devices, rows, start, stop):
    """Ticks start..stop-1, row k into rows[k]; devices: the ports' devices' records, port
    p's at p (one port or two, maybe of different models). Returns the first tick not run:
    stop, or earlier when a device's noise block needs a refill (the caller refills and
    calls again). The devices are taken out of their tuple once, before the ticks: taken
    out every tick, each of their arrays' reference counts went up and down every tick
    (0.3 µs a tick on grasp_vertical)."""
    cd = data[0]
    s = io[0]
    two = len(devices) == 2  # known when compiled: the branches below fold away
    first, last = devices[0], devices[-1]  # one port: both are its device
    for k in range(start, stop):
        if not device_noise_ready(first, cd.dt) or (two and not device_noise_ready(last, cd.dt)):
            return k
        port_in(cd, s, 0, first)
        if two:
            port_in(cd, s, 1, last)
        cosim_tick(cosim, data)
        port_out(cd, s, 0, first)
        if two:
            port_out(cd, s, 1, last)
        port_row(cosim[0], cd, s, rows[k])
        s.t += cd.dt
    return stop


@kind_kernel
def port_burst(w, rows, start, stop):
    """run_port_ticks over the world's records (its model, data, I/O, both devices'): the
    kind's compiled ticks as the runners call them (world.Compiled)."""
    return run_port_ticks(w[0], w[1], w[2], (w[3], w[4]), rows, start, stop)


@paced_entry(never_asks, port_burst)
def port_paced(w, rows, loop, windows, ts):
    """The real-time runner's compiled loop over port_burst (haptic_server.paced)."""
    return paced_ticks(never_asks, port_burst, w, rows, loop, windows, ts)


@dataclass
class PortResult:
    """What a port run produced."""

    rows: np.ndarray  # PORT_ROW_DTYPE, one per tick
    model: np.ndarray  # the co-simulation's COSIM_DTYPE record
    order: list[str]  # the co-simulated bodies in q's order
    wall_s: float

    def body(self, name: str) -> int:
        """The index of a co-simulated body (its q columns are 3 i .. 3 i + 2)."""
        return self.order.index(name)


class PortRun:
    """A port scene with its devices and users, ready to run (one tick or many): a World."""

    def __init__(
        self,
        scene: PortSceneConfig,
        devices: list[SimulatedDevice] | None = None,
        users: list[UserConfig] | None = None,
    ) -> None:
        self.scene = scene
        self.kind = PORT_KIND
        self.period_s = scene.period_s
        self.devices = devices or [load_simulated_device(p.device) for p in scene.ports]
        self.users = users or [load_user(p.user) for p in scene.ports]
        io = np.zeros(1, PORT_IO_DTYPE)
        self.io = io
        limits = []
        for p, dev in enumerate(self.devices):
            io[0]["maps"][p] = world_map_of(dev).record[0]
            io[0]["limits"][p] = dev.limits().max_wrench
            limits.append(tuple(world_limits(dev)))
        self.model, self.data = cosim_records(scene, limits)
        self.order = cosim_order(scene)
        for p, port in enumerate(scene.ports):
            self._place(p, port.device_start)

    def _place(self, p: int, start: tuple[float, float, float]) -> None:
        """Device p at rest at its start pose, its map putting it where the coupling is
        in equilibrium with its hand's constant push, its hand's script starting there."""
        io = self.io[0]
        wm = io["maps"][p]
        tool = self.data[0]["q"][3 * self.model[0]["port_tool"][p] :][:3]
        kc = self.model[0]["coupling_stiffness"][p]
        anchor = tool + push_stretch(self.users[p].wrench, wm, kc)
        u = rest_device(self.devices[p], self.users[p], wm, start, anchor)
        u["start_s"] = 0.0
        io["users"][p] = u
        io["maps"][p] = wm

    @property
    def compiled(self) -> Compiled:
        """The compiled ticks (port_burst, port_paced) and the records they take."""
        d0, d1 = self.devices
        return Compiled(port_burst, port_paced,
                        (self.model, self.data, self.io, d0.records, d1.records))  # fmt: skip

    def burst(self, rows: np.ndarray, start: int, stop: int) -> int:
        """The World protocol's compiled ticks (port_burst)."""
        return compiled_burst(self, rows, start, stop)

    def limits(self) -> list[list[float]]:
        return [list(map(float, w)) for w in self.model[0]["max_wrench"][: len(self.devices)]]

    def run(self, duration_s: float) -> PortResult:
        """Run `duration_s` of virtual time; every tick's row."""
        rows, wall_s = run_virtual(self, duration_s)
        return PortResult(rows, self.model, self.order, wall_s)

    def summary_lines(self, rows: np.ndarray, wall_s: float) -> list[str]:
        last = rows[-min(len(rows), round(self.scene.haptic_rate_hz)) :]
        lines = [
            f"{len(rows)} ticks, {len(rows) * self.period_s:.3f} s in {wall_s:.2f} s of wall time"
        ]
        for p, port in enumerate(self.scene.ports):
            cmd = last["command"][:, p, :2]
            lines.append(
                f"port {port.name} ({self.devices[p].name}, {self.users[p].name}): mean command "
                f"over the last second ({cmd[:, 0].mean():+.3f}, {cmd[:, 1].mean():+.3f}) N"
            )
        for i, name in enumerate(self.order):
            q = rows["q"][:, 3 * i : 3 * i + 3]
            dx, dy = (q[-1, 0] - q[0, 0]) * 1e3, (q[-1, 1] - q[0, 1]) * 1e3
            lines.append(f"{name}: moved ({dx:+.3f}, {dy:+.3f}) mm, turned "
                         f"{q[-1, 2] - q[0, 2]:+.4f} rad")  # fmt: skip
        lines.append(
            f"contacts at the end {rows['n_contacts'][-1]}, commands not finite (zeroed) "
            f"{rows['invalid'][-1]}, steps held {rows['singular'][-1]}"
        )
        return lines


def run_ports(
    scene: PortSceneConfig,
    duration_s: float,
    devices: list[SimulatedDevice] | None = None,
    users: list[UserConfig] | None = None,
) -> PortResult:
    """A port scene's run on the virtual clock (module docstring)."""
    return PortRun(scene, devices, users).run(duration_s)


#: the row fields a replay recomputes (the rest are its inputs or the devices' own)
REPLAYED = ("q", "qd", "command", "body_force", "n_contacts", "penetration", "invalid", "singular",
            "collisions")  # fmt: skip


def replay_rows(
    scene: PortSceneConfig, limits: list[tuple[float, float, float]], rows: np.ndarray
) -> tuple[int, int | None]:
    """Re-run the co-simulation on the rows' device readings (and the sim's bodies as each
    tick met them); (ticks compared, the first tick whose outputs differ in any bit, or
    None)."""
    model, data = cosim_records(scene, limits)
    d = data[0]
    for k, row in enumerate(rows):
        d["device_pose"] = row["device_pose"]
        d["device_twist"] = row["device_twist"]
        if scene.sim_bodies:
            carry_sim_bodies(model, data, row["sim_bodies"], 0.0)
            d["sim_wrench"] = row["sim_wrench"]
        cosim_tick(model, data)
        for name in REPLAYED:
            if np.asarray(d[name]).tobytes() != np.asarray(row[name]).tobytes():
                return k + 1, k
    return len(rows), None


#: devices on a co-simulated world (`/ports/tick`; also the shared world's log)
PORT_KIND = WorldKind(
    name="ports", topic="/ports/tick", schema="haptic_server/PortTick", rows=PORT_ROW_DTYPE,
    scene=PortSceneConfig, ports=None, replay=replay_rows,
)  # fmt: skip

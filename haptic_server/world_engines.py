"""What a shared world (haptic_server/shared_world.py) integrates at the haptic rate, and
what a station renders against: a port scene's co-simulation (two tools and the object,
haptic_server/stages/cosim.py) or two mass-spring hands holding a box (`hand_grasp`,
haptic_server/stages/hand_grasp.py).

Each tick is one compiled call (`cosim_world_step`, `hand_world_step`): the ports' states
and the devices they feed (haptic_server/stages/world_ports.py), the engine's tick, each
port's ToolState and the tick's row.

Either way each port's station is coupled to a tool by a spring-damper of the port's gains,
F = K (x_tool - x_dev) + B (v_tool - v_dev): for a co-simulated tool, its coupling; for a
hand, its palm spring (the palm's command is the spring's reaction, the same law, with the
palm as the tool and the device as the tracked palm). A hand's glove is the port's scene
user's `finger_angles`, evaluated by the world, until its station sends its own (a hand's
station sends its user's glove with its device).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from haptic_local_model.haptic_server.hand_grasp_ports import (
    HAND_GRASP_ROW_DTYPE,
    grasp_port_records,
    hand_grasp_row,
)
from haptic_local_model.haptic_server.hand_ports import HAND_IO_DTYPE
from haptic_local_model.haptic_server.port_scene import glove_script
from haptic_local_model.haptic_server.ports import PORT_ROW_DTYPE, cosim_row
from haptic_local_model.haptic_server.stages.cosim import (
    MAX_COSIM_BODIES,
    carry_sim_bodies,
    cosim_order,
    cosim_records,
    cosim_tick,
    coupling_reaction,
    drain_impulse,
)
from haptic_local_model.haptic_server.stages.hand import glove_at
from haptic_local_model.haptic_server.stages.hand_grasp import MAX_HANDS, grasp_tick
from haptic_local_model.haptic_server.stages.world_ports import (
    COUPLED,
    GLOVE_HOLD,
    GLOVE_TAKE_START,
    fill_tool,
    observe_axis,
    port_passivity,
    step_ports,
    warm_records,
)
from haptic_local_model.shared.config import UserConfig
from haptic_local_model.shared.port_config import (
    MAX_SIM_BODIES,
    HandSceneConfig,
    PortSceneConfig,
)
from haptic_local_model.shared.protocol.station import GLOVE, Vec3

F8 = np.float64


@njit(cache=True)
def world_row(model, data, rows, k, t, lowest):
    """The co-simulation's tick into rows[k] (PORT_ROW_DTYPE; hand wrench and faults: 0, the
    world does not see them), and each body's lowest height so far into `lowest`. Arrays
    and an index, not records: a call with records costs about 5 us more from Python."""
    cd = data[0]
    row = rows[k]
    for e in range(MAX_COSIM_BODIES):
        lowest[e] = min(lowest[e], cd.q[3 * e + 1])
    row.t = t
    cosim_row(model[0], cd, row)


@njit(cache=True)
def hand_world_row(hds, gdata, io, rows, k, t, lowest):
    """Both hands' and the box's tick into rows[k] (HAND_GRASP_ROW_DTYPE; the devices'
    fields 0: the world does not see them), and the palms' and the box's lowest height so
    far into `lowest`. Arrays and an index, not records (as `world_row`)."""
    gd = gdata[0]
    io[0].t = t
    hand_grasp_row(hds, gd, io, rows[k])
    for i in range(MAX_HANDS):
        lowest[i] = min(lowest[i], hds[i][0].q[1])
    lowest[MAX_HANDS] = min(lowest[MAX_HANDS], gd.q_box[1])


@njit(cache=True)
def hand_world_tick(grasp, io, t):
    """Each hand's glove at t (its port's script in io[p]) into its tracked fingers, then
    both hands and the box (grasp: `grasp_port_records`' tuple); the palms' tracked poses
    are fed before."""
    chains, hms, hds, gmodel, gdata = grasp
    for i in range(MAX_HANDS):
        d = hds[i][0]
        n = hms[i][0].dof
        s = io[i]
        if s.glove_fed == 0:  # else its station's, fed before
            glove_at(s.glove, s.n_glove, t, n - 3, d.target[3:n], d.target_rate[3:n])
    grasp_tick(chains, hms, hds, gmodel, gdata)


@njit(cache=True)
def cosim_world_step(model, data, ports, clock, events, tools, rows, lowest):
    """One tick of a port scene's world: the ports' states and the devices they feed
    (step_ports), the co-simulation, each port's ToolState (tools) and the tick's row."""
    c = clock[0]
    step_ports(ports, clock, events)
    m, d = model[0], data[0]
    for p in range(c.n_ports):
        i = 3 * m.port_tool[p]
        port_passivity(ports[p], c, m.coupling_stiffness[p], m.coupling_damping[p],
                       d.q[i : i + 3], d.qd[i : i + 3])  # fmt: skip
        for a in range(3):
            d.device_pose[p, a] = ports[p].fed_pose[a]
            d.device_twist[p, a] = ports[p].fed_twist[a]
    cosim_tick(model, data)
    o = c.object
    for p in range(c.n_ports):
        i = 3 * m.port_tool[p]
        for a in range(3):  # the coupling's force on the tool over the step
            observe_axis(ports[p], a, -coupling_reaction(m, d, p, a), d.qd[i + a], c.dt)
        fill_tool(
            tools, p, ports[p], c, d.q[i : i + 3], d.qd[i : i + 3], d.q[o : o + 3], d.qd[o : o + 3]
        )
    world_row(model, data, rows, c.k, c.t, lowest)


@njit(cache=True)
def _feed_glove(ps, d, n, s):
    """Hand d's glove this tick (n: its dof): its angles kept when its port couples; held
    where they are, at rest, when the port leaves COUPLED; the station's blended in from the
    kept ones over the ramp (as the pose) while COUPLED. s: its port's glove script's record
    (glove_fed: the script no longer drives it)."""
    if ps.glove_act == GLOVE_TAKE_START:
        for j in range(n - 3):
            ps.glove_start[j] = d.target[3 + j]
    elif ps.glove_act == GLOVE_HOLD:
        for j in range(n - 3):
            d.target_rate[3 + j] = 0.0
        s.glove_fed = 1
    if ps.state == COUPLED and ps.flags & GLOVE:
        for j in range(n - 3):
            g0 = ps.glove_start[j]
            d.target[3 + j] = g0 + ps.blend * (ps.glove[j] - g0)
            d.target_rate[3 + j] = ps.blend * ps.glove_rate[j]
        s.glove_fed = 1


@njit(cache=True)
def hand_world_step(grasp, io, ports, clock, events, tools, rows, lowest):
    """One tick of two hands' world: the ports' states and the palms and gloves they feed,
    both hands and the box (hand_world_tick), each port's ToolState (its palm) and the row."""
    c = clock[0]
    step_ports(ports, clock, events)
    hms, hds, gdata = grasp[1], grasp[2], grasp[4]
    for p in range(c.n_ports):
        ps, d = ports[p], hds[p][0]
        for a in range(3):
            d.target[a] = ps.fed_pose[a]
            d.target_rate[a] = ps.fed_twist[a]
        _feed_glove(ps, d, hms[p][0].dof, io[p])
    hand_world_tick(grasp, io, c.t)
    gd = gdata[0]
    for p in range(c.n_ports):
        d = hds[p][0]
        fill_tool(tools, p, ports[p], c, d.q, d.qd, gd.q_box, gd.qd_box)
    hand_world_row(hds, gdata, io, rows, c.k, c.t, lowest)


class CosimWorld:
    """A port scene's co-simulation: the tools and the object."""

    rows_dtype = PORT_ROW_DTYPE

    def __init__(self, scene: PortSceneConfig, limits: list[Vec3]) -> None:
        self.scene, self.limits = scene, limits
        self.model, self.data = cosim_records(scene, limits)
        self.names = cosim_order(scene)
        m, d = self.model[0], self.data[0]
        self.dt = float(d["dt"])
        self._tools = [3 * int(m["port_tool"][p]) for p in range(len(scene.ports))]
        # the first body that is not a tool (the tools come first), else the first tool: the
        # body whose pose each ToolState carries
        self.object_dof = 3 * len(scene.ports) if len(self.names) > len(scene.ports) else 0
        self.lowest = np.full(MAX_COSIM_BODIES, np.inf)

    def step(self, ports: np.ndarray, clock: np.ndarray, events: np.ndarray,
             tools: np.ndarray, rows: np.ndarray) -> None:  # fmt: skip
        """One tick (cosim_world_step): the ports' records in, the tools' and rows[k] out."""
        cosim_world_step(self.model, self.data, ports, clock, events, tools, rows, self.lowest)

    def glove(self, p: int) -> np.ndarray | None:
        return None  # a tool has no glove

    def tool(self, p: int) -> tuple[np.ndarray, np.ndarray]:
        i = self._tools[p]
        d = self.data[0]
        return d["q"][i : i + 3], d["qd"][i : i + 3]

    def poses(self) -> np.ndarray:
        """Every body's pose (n x 3), in `names`' order."""
        return self.data[0]["q"][: 3 * len(self.names)].reshape(-1, 3).copy()

    def steps_held(self) -> int:
        return int(self.data[0]["singular"])

    def range_returns(self) -> dict[str, int]:
        """Objects put back at their start after leaving the scene's range, and the ticks
        one waited there for its start to be clear (stages/cosim.py, step 5)."""
        d = self.data[0]
        return {"resets": int(d["resets"]), "parked_ticks": int(d["parked"])}

    def warm(self) -> None:
        model, data = cosim_records(self.scene, self.limits)
        carry_sim_bodies(model, data, np.zeros((MAX_SIM_BODIES, 6)), 0.0)  # a sim's bodies
        drain_impulse(model, data, np.zeros((MAX_COSIM_BODIES, 3)), np.zeros((MAX_COSIM_BODIES, 3)))
        ports, clock, events, tools = warm_records(len(self.scene.ports))
        rows = np.zeros(1, PORT_ROW_DTYPE)
        cosim_world_step(model, data, ports, clock, events, tools, rows, np.zeros(MAX_COSIM_BODIES))


class HandGraspWorld:
    """Two mass-spring hands holding a box (`hand_grasp`); each port's tool is its palm."""

    rows_dtype = HAND_GRASP_ROW_DTYPE

    def __init__(self, scene: HandSceneConfig, limits: list[Vec3], users: list[UserConfig]) -> None:
        self.scene, self.limits = scene, limits
        self.grasp = grasp_port_records(scene, limits)
        self.names = [*(p.tool for p in scene.ports), "box"]
        self.dt = scene.period_s
        self._datas = self.grasp[2]
        self._gd = self.grasp[4]
        # a world sees no device (those fields stay 0); each hand's glove script is its
        # port's scene user's
        self._io = np.zeros(MAX_HANDS, HAND_IO_DTYPE)
        for p, user in enumerate(users):
            spec = scene.hand_of(p)
            script = glove_script(user, [a for f in spec.fingers for a in f.rest])
            self._io[p]["glove"][: len(script), : script.shape[1]] = script
            self._io[p]["n_glove"] = len(script)
        self.lowest = np.full(len(self.names), np.inf)

    object_dof = 0  # a ToolState carries the box's pose (not a co-simulation's dof)

    def step(self, ports: np.ndarray, clock: np.ndarray, events: np.ndarray,
             tools: np.ndarray, rows: np.ndarray) -> None:  # fmt: skip
        """One tick (hand_world_step): the ports' records in, the tools' and rows[k] out."""
        hand_world_step(self.grasp, self._io, ports, clock, events, tools, rows, self.lowest)

    def glove(self, p: int) -> np.ndarray | None:
        """Hand p's glove angles as the last tick took them."""
        n = int(self.grasp[1][p][0]["dof"])
        return np.array(self._datas[p][0]["target"][3:n])

    def tool(self, p: int) -> tuple[np.ndarray, np.ndarray]:
        d = self._datas[p][0]
        return d["q"][:3], d["qd"][:3]

    def poses(self) -> np.ndarray:
        return np.array([*(d[0]["q"][:3] for d in self._datas), self._gd[0]["q_box"]])

    def steps_held(self) -> int:
        return int(self._gd[0]["singular"])

    def range_returns(self) -> dict[str, int]:
        """The box put back at its start after leaving the range, and the ticks it waited
        (stages/hand_grasp.py, keep_box_in_range)."""
        gd = self._gd[0]
        return {"resets": int(gd["resets"]), "parked_ticks": int(gd["parked"])}

    def warm(self) -> None:
        grasp = grasp_port_records(self.scene, self.limits)
        ports, clock, events, tools = warm_records(len(self.scene.ports))
        rows = np.zeros(1, HAND_GRASP_ROW_DTYPE)
        hand_world_step(grasp, self._io.copy(), ports, clock, events, tools, rows, np.zeros(3))


WorldEngine = CosimWorld | HandGraspWorld


def world_engine(
    scene: PortSceneConfig | HandSceneConfig, limits: list[Vec3], users: list[UserConfig]
) -> WorldEngine:
    """The engine a shared world runs for this scene."""
    if isinstance(scene, HandSceneConfig):
        if len(scene.ports) != MAX_HANDS:
            raise ValueError("a shared world of hands needs two hands on a box (hand_grasp)")
        return HandGraspWorld(scene, limits, users)
    return CosimWorld(scene, limits)

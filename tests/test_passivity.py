"""The port links' passivity observers and controllers (docs/stations.md, "Passivity"):
each end's closed form on one tick, and the energies carried by the messages.

The link holds energy E_station + E_world (each end's net work on its coupling, the other's
as its messages said). A tick whose output would leave it below zero is damped by
alpha = deficit / (v^2 dt), so that after the tick the link holds exactly zero (unless
alpha is at its cap); a tick that takes energy in, or finds enough held, is not touched.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from haptic_local_model.benchmarks import station_links
from haptic_local_model.benchmarks.impair import Impairment
from haptic_local_model.benchmarks.stations import PORTS, netns_unavailable
from haptic_local_model.device_models.registry import load_simulated_device
from haptic_local_model.haptic_server.physics.passivity import PC_MAX_OVER_B
from haptic_local_model.haptic_server.stages.station import (
    STATION_DTYPE,
    STATION_ROW_DTYPE,
    _passivity,
)
from haptic_local_model.haptic_server.stages.station_link import station_link, take_tool
from haptic_local_model.haptic_server.stages.world_ports import (
    COUPLED,
    HELD_STATE,
    port_links,
    port_passivity,
    world_clock,
)
from haptic_local_model.haptic_server.station import Station, passivity_summary
from haptic_local_model.shared.config import load_user
from haptic_local_model.shared.net.stations import load_station_network
from haptic_local_model.shared.port_config import load_port_scene
from haptic_local_model.shared.protocol.station import (
    DeviceState,
    ToolState,
    decode_device,
    decode_tool,
    encode_device,
    encode_tool,
)

DT = 1e-3
#: energies here are of order 1e-5 J; the closed forms hold to rounding
ENERGY_TOL_J = 1e-15


def _station(passivity: int, budget: float, coupling: float, v: float) -> np.ndarray:
    st = np.zeros(1, STATION_DTYPE)
    s = st[0]
    s["dt"], s["gain"], s["passivity"] = DT, 1.0, passivity
    s["pc_max"] = (200.0, 200.0, 0.05)
    s["budget"][0] = budget
    s["coupling"][0] = coupling
    s["world"][0]["twist"][0] = v
    return st


def test_the_station_damps_an_output_the_link_does_not_hold_down_to_exactly_none() -> None:
    # the coupling would give the device 2 N x 10 mm/s x 1 ms = 20 uJ; the world's end put
    # in 15 uJ: alpha = 5 uJ / (1e-4 x 1e-3) = 50 N s/m, the force 2 - 0.5 = 1.5 N
    st = _station(1, 15e-6, 2.0, 0.01)
    _passivity(st[0])
    s = st[0]
    assert s["pc_damping"][0] == pytest.approx(50.0, rel=1e-9)
    assert s["coupling"][0] == pytest.approx(1.5, rel=1e-9)
    assert abs(s["energy"][0] + s["budget"][0]) < ENERGY_TOL_J  # the link holds none


def test_the_station_damps_at_most_its_cap_and_leaves_inflow_and_an_observer_alone() -> None:
    st = _station(1, 0.0, 2.0, 0.01)  # nothing held: alpha would be 200 N s/m, the cap
    st[0]["pc_max"][0] = 100.0
    _passivity(st[0])
    assert st[0]["pc_damping"][0] == 100.0 and st[0]["coupling"][0] == pytest.approx(1.0)
    inflow = _station(1, 0.0, 2.0, -0.01)  # the device pushes against the coupling
    _passivity(inflow[0])
    assert inflow[0]["pc_damping"][0] == 0.0 and inflow[0]["coupling"][0] == 2.0
    assert inflow[0]["energy"][0] == pytest.approx(2.0 * 0.01 * DT, rel=1e-12)
    observer = _station(0, 0.0, 2.0, 0.01)  # passivity off: counted, not damped
    _passivity(observer[0])
    assert observer[0]["coupling"][0] == 2.0
    assert observer[0]["energy"][0] == pytest.approx(-2.0 * 0.01 * DT, rel=1e-12)


def _port(state: int, budget: float) -> np.ndarray:
    ports = port_links(1)
    ps = ports[0]
    ps["state"] = state
    ps["budget"][0] = budget
    ps["fed_pose"][0] = 0.001  # 1 mm ahead of the tool: 2 N at 2 kN/m
    return ports


@pytest.mark.parametrize("passivity", [0, 1])
def test_the_world_damps_through_this_ticks_pose_fed_only(passivity: int) -> None:
    k, b = np.array([2000.0, 2000.0, 0.5]), np.array([40.0, 40.0, 0.01])
    q, qd = np.zeros(3), np.array([0.01, 0.0, 0.0])  # the tool moving with the force
    clock = world_clock(1, DT, 100.0, 40.0)
    clock[0]["passivity"] = passivity
    ports = _port(COUPLED, 5e-6)
    port_passivity(ports[0], clock[0], k, b, q, qd)
    ps = ports[0]
    # F = 2000 x 1 mm + 40 x (0 - 10 mm/s) = 1.6 N; out = 16 uJ, held 5 uJ: deficit 11 uJ
    alpha = 11e-6 / (1e-4 * DT)
    if passivity == 0:
        assert ps["pc_damping"][0] == 0.0 and ps["fed_pose"][0] == 0.001
        return
    assert ps["pc_damping"][0] == pytest.approx(min(alpha, PC_MAX_OVER_B * 40.0), rel=1e-9)
    force = k[0] * (ps["fed_pose"][0] - q[0]) + b[0] * (ps["fed_twist"][0] - qd[0])
    assert force == pytest.approx(1.6 - ps["pc_damping"][0] * qd[0], rel=1e-9)
    assert ps["fed_twist"][0] == 0.0  # the twist fed is the device's: no drift is made
    if alpha < PC_MAX_OVER_B * 40.0:
        assert abs(ps["budget"][0] - force * qd[0] * DT) < ENERGY_TOL_J


def test_the_world_leaves_a_port_it_holds_alone() -> None:
    ports = _port(HELD_STATE, 0.0)
    clock = world_clock(1, DT, 100.0, 40.0)
    clock[0]["passivity"] = 1
    port_passivity(ports[0], clock[0], np.full(3, 2000.0), np.full(3, 40.0), np.zeros(3),
                   np.array([0.01, 0.0, 0.0]))  # fmt: skip
    assert ports[0]["fed_pose"][0] == 0.001 and ports[0]["pc_damping"][0] == 0.0


def test_the_energies_ride_the_messages_signed() -> None:
    e = (0.25, -1.5, 3e-9)
    dev = DeviceState(0, 1, 2, 3, (0.0,) * 3, (0.0,) * 3, energy=e)
    assert decode_device(encode_device(dev), 0).energy == e
    tool = ToolState(0, 1, 2, 3, *[(0.0,) * 3] * 5, energy=e)
    assert decode_tool(encode_tool(tool), 0).energy == e


def test_a_stations_budget_counts_from_each_worlds_first_tool_state_and_carries_on() -> None:
    scene = load_port_scene("grasp_vertical")
    network = load_station_network("stations_loopback", "left")
    device, user = load_simulated_device("maglev"), load_user("squeeze_left_2n")
    station = Station(scene, network, "left", device, user, 10)
    st, link = station.station, station_link()

    def tool(epoch: int, seq: int, energy: float) -> bytes:
        return encode_tool(ToolState(0, epoch, seq, 0, *[(0.0,) * 3] * 5,
                                     energy=(energy, 0.0, 0.0)))  # fmt: skip

    take_tool(st, link, 0, 1, tool(5, 1, 0.7))  # a world's count before this station: not its
    assert st[0]["budget"][0] == 0.0
    take_tool(st, link, 0, 2, tool(5, 2, 0.9))
    assert st[0]["budget"][0] == pytest.approx(0.2)
    silent = round(st[0]["watchdog_s"] * 1e9) + 10
    take_tool(st, link, 0, silent, tool(6, 1, -0.4))  # a new world: the budget carries on
    assert st[0]["budget"][0] == pytest.approx(0.2)
    take_tool(st, link, 0, silent + 1, tool(6, 2, -0.1))
    assert st[0]["budget"][0] == pytest.approx(0.5)


def test_a_stations_summary_says_when_its_controller_softened_it() -> None:
    """The ticks any axis was damped (the union over x, y and the angle), their share and
    the largest damping per axis; nothing for a run with no rows."""
    rows = np.zeros(10, STATION_ROW_DTYPE)
    rows["pc_damping"][[1, 2, 3], 0] = (5.0, 50.0, 20.0)
    rows["pc_damping"][[3, 7], 2] = (0.01, 0.02)
    got = passivity_summary(rows)
    assert got == {"damped_ticks": 4, "damped_share": 0.4, "max_damping": [50.0, 0.0, 0.02]}
    none = passivity_summary(rows[:0])
    assert none == {"damped_ticks": 0, "damped_share": 0.0, "max_damping": [0.0, 0.0, 0.0]}


#: issue 46's bounds: energy out of a port over the run, the force above 5 Hz over the
#: unimpaired run's, the box's drift, the felt stiffness over the unimpaired run's (at 50 ms),
#: the station's drift from the world after pressing and releasing
ENERGY_OUT_J = 0.05
OSCILLATION_RATIO = 3.0
BOX_DRIFT_MM = 2.0
FELT_SHARE = 0.8
STATION_DRIFT_MM = 1.0
PRESS_RUN_S = 14.0  # one press (5-12 s) and the rest after it (station_links.REST_S)


@pytest.mark.processes
def test_at_50_ms_and_5_percent_loss_no_port_gives_out_energy_nor_oscillates(
    tmp_path: Path,
) -> None:
    """grasp_vertical at two stations over the UDP network, each link 50 ms ± 10 ms one way
    with 5 % loss through the forwarder, the passivity controllers and the stations' local
    model on, the users pressing their pads into the box and releasing: no port gives out
    more than ENERGY_OUT_J, the force above 5 Hz is within OSCILLATION_RATIO of the same run
    unimpaired (the reference, run first), the box's drift within BOX_DRIFT_MM, each
    station's felt stiffness at least FELT_SHARE of the unimpaired run's, and each station
    and the world no further apart after the release than before the press than
    STATION_DRIFT_MM (issue 46's done-when 1-3 at its reduced point). The stations hold
    their devices until they join (docs/stations.md, "The join"), so the grip survives it
    (before the hold the box left the grip within 0.3 s of the join, and this test was an
    xfail)."""
    reason = netns_unavailable()
    if reason:
        pytest.skip(reason)
    runs = {}
    for name, imp in (("0 ms", Impairment(0.0, 0.0, 0.0)), ("50 ms", Impairment(0.05, 0.01, 0.05))):
        folder = tmp_path / name.replace(" ", "")
        folder.mkdir()
        runs[name] = station_links.run(
            PRESS_RUN_S, imp, folder, "stations_three_hosts_udp", "tdpa", press=True
        )
        f = runs[name]
        assert f["left_over"] == [] and set(f["exit_codes"].values()) == {0}, f
    bad, ref = runs["50 ms"], runs["0 ms"]
    for p in PORTS:
        assert bad[p]["energy_out_j"] <= ENERGY_OUT_J, bad[p]
    ratio = max(bad[p]["rms_above_5hz_n"] / ref[p]["rms_above_5hz_n"] for p in PORTS)
    figures = (f"force above 5 Hz {ratio:.1f}x the unimpaired run's; the box moved "
               f"{bad['box_moved_mm']:.1f} mm (sank {bad['box_sank_mm']:.1f})")  # fmt: skip
    assert ratio <= OSCILLATION_RATIO, figures
    assert bad["box_moved_mm"] <= BOX_DRIFT_MM, figures
    for p in PORTS:
        felt = bad[p]["felt"]["n_per_m"] / ref[p]["felt"]["n_per_m"]
        assert felt >= FELT_SHARE, (p, bad[p]["felt"], ref[p]["felt"])
        assert bad[p]["drift"]["drift_mm"] <= STATION_DRIFT_MM, (p, bad[p]["drift"])

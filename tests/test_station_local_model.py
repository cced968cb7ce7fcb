"""The station's local model (docs/stations.md, "The local model at the station"): its law on
records, against closed forms. `grasp_vertical`'s left pad (6 x 30 mm) against its box
(40 x 20 mm): the coupling K = 2000 N/m in series with the world's contact on the pad's
face, two points of 15 kN/m, k_s = 2000 x 30000 / 32000 = 1875 N/m along the normal.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from haptic_local_model.device_models.registry import load_simulated_device
from haptic_local_model.haptic_server.stages.station import _local_contact, pad_depth
from haptic_local_model.haptic_server.stages.station_link import take_tool
from haptic_local_model.haptic_server.station import Station
from haptic_local_model.haptic_server.station_records import (
    CONTACT_FADE_S,
    OBJECT_TAU_S,
    StationSetup,
    local_geometry,
    station_record,
)
from haptic_local_model.shared.config import load_user
from haptic_local_model.shared.net.stations import load_station_network
from haptic_local_model.shared.port_config import load_hand_scene, load_port_scene
from haptic_local_model.shared.protocol.station import INDEXED, ToolState, encode_tool

K_SERIES = 2000.0 * 30000.0 / (2000.0 + 30000.0)  # N/m
#: the left pad's centre at first touch of the box's left side (box half 20 mm, pad 3 mm)
TOUCH_X = -0.023
#: the geometry's sums and products are exact to a few ulps of a millimetre
DEPTH_TOL_M = 1e-15


def _station(local_model: bool = True) -> np.ndarray:
    scene = load_port_scene("grasp_vertical")
    setup = StationSetup(scene, 0, load_simulated_device("maglev"), load_user("squeeze_left_2n"),
                         0.1, 0.04, True, local_model)  # fmt: skip
    st = station_record(setup)
    s = st[0]
    s["fresh"], s["damping_gain"], s["gain"] = 1, 1.0, 1.0
    s["object_pose"] = (0.0, 0.0, 0.0)
    return st


def _at(st: np.ndarray, x: float, y: float = 0.0, coupling=(2.0, 0.5, 0.01), w: float = 1.0):
    s = st[0]
    s["world"][0]["pose"] = (x, y, 0.0)
    s["coupling"] = coupling
    s["contact_w"] = w
    _local_contact(s, 0.0)
    return s


def test_the_geometry_comes_from_the_scene() -> None:
    pad, box, k_c = local_geometry(load_port_scene("grasp_vertical"), 1)
    assert pad.tolist() == [0.003, 0.015] and box.tolist() == [0.02, 0.01] and k_c == 30000.0
    assert local_geometry(load_hand_scene("hand_grasp"), 0) is None


@pytest.mark.parametrize("depth_mm", [0.1, 1.0, 3.0])
def test_in_contact_the_normal_force_is_the_series_stiffness_times_the_penetration(
    depth_mm: float,
) -> None:
    st = _station()
    d = depth_mm / 1e3
    s = _at(st, TOUCH_X + d)
    assert abs(s["depth"] - d) < DEPTH_TOL_M
    assert s["normal"].tolist() == [-1.0, 0.0]  # from the box to the left pad
    assert s["local_force"][0] == pytest.approx(-K_SERIES * d, rel=1e-12)
    # the coupling's normal part replaced by the local contact, its tangent and torque kept
    assert s["coupling"][0] == pytest.approx(-K_SERIES * d, rel=1e-12)
    assert s["coupling"][1] == 0.5 and s["coupling"][2] == 0.01


def test_out_of_contact_it_renders_nothing_and_leaves_the_coupling_bit_for_bit() -> None:
    st = _station()
    s = _at(st, TOUCH_X - 1e-4, w=0.0)
    assert s["depth"] == 0.0 and s["local_force"].tolist() == [0.0, 0.0, 0.0]
    assert s["coupling"].tolist() == [2.0, 0.5, 0.01] and s["contact_w"] == 0.0
    off = _station(local_model=False)
    s = _at(off, TOUCH_X + 1e-3, w=0.0)  # deep in, but the station has no local model
    assert s["coupling"].tolist() == [2.0, 0.5, 0.01] and s["local_force"][0] == 0.0
    for name, value in (("fresh", 0), ("damping_gain", 0.5), ("cut", 1)):  # safe, braking, cut
        st = _station()
        st[0][name] = value
        s = _at(st, TOUCH_X + 1e-3)
        assert s["coupling"].tolist() == [2.0, 0.5, 0.01] and s["contact_w"] == 0.0, name


def test_it_never_pulls() -> None:
    """Over a seeded cloud of pad poses around the box (turned too): the local force points
    from the box to the pad (n . (pad - box) >= 0) and is zero when they are apart."""
    rng = np.random.default_rng(46)
    st = _station()
    s = st[0]
    s["object_pose"] = (0.001, -0.002, 0.3)
    touched = 0
    for x, y, a in rng.uniform((-0.04, -0.03, -math.pi), (0.04, 0.03, math.pi), (2000, 3)):
        s["world"][0]["pose"] = (x, y, a)
        s["coupling"] = (0.0, 0.0, 0.0)
        s["contact_w"] = 1.0
        _local_contact(s, 0.0)
        f = s["local_force"]
        apart = (x - 0.001) * f[0] + (y + 0.002) * f[1]
        assert apart >= 0.0
        assert (s["depth"] > 0.0) == (f[0] != 0.0 or f[1] != 0.0)
        touched += s["depth"] > 0.0
    assert 100 < touched < 1900  # the cloud has both sides of the contact


def test_a_turned_box_and_its_twist_carried_for_the_age() -> None:
    st = _station()
    s = st[0]
    s["object_pose"] = (0.0, 0.0, math.pi / 2)  # turned: its 20 mm side faces the pad
    assert abs(pad_depth(s, -0.013 + 5e-4, 0.0, 0.0, 0.0) - 5e-4) < DEPTH_TOL_M
    s["object_pose"] = (0.0, 0.0, 0.0)
    s["object_twist"] = (-0.1, 0.0, 0.0)  # moving towards the pad at 0.1 m/s for 5 ms
    assert abs(pad_depth(s, TOUCH_X, 0.0, 0.0, 0.005) - 5e-4) < DEPTH_TOL_M


def test_it_fades_in_and_out_over_the_fade() -> None:
    st = _station()
    s = st[0]
    d, ticks = 1e-3, round(CONTACT_FADE_S / float(s["dt"]))
    local = -K_SERIES * d
    for k in range(1, ticks + 1):  # contact begins: w rises by dt / fade a tick
        s = _at(st, TOUCH_X + d, w=float(s["contact_w"]))
        w = min(1.0, k / ticks)
        assert s["contact_w"] == pytest.approx(w, abs=1e-12)
        assert s["coupling"][0] == pytest.approx((1 - w) * 2.0 + w * local, rel=1e-9)
    assert s["contact_w"] == 1.0
    for k in range(1, ticks + 1):  # contact ends: the coupling's normal part comes back
        s = _at(st, TOUCH_X - 1e-4, w=float(s["contact_w"]))
        w = max(0.0, 1.0 - k / ticks)
        assert s["contact_w"] == pytest.approx(w, abs=1e-12)
        assert s["coupling"][0] == pytest.approx((1 - w) * 2.0, rel=1e-9)
        assert s["coupling"][1] == 0.5
    assert s["contact_w"] == 0.0


def test_an_indexed_tool_state_renders_the_stretch_not_the_devices_motion() -> None:
    """While the world re-indexes the port (INDEXED) the tool is where the device was when
    the world took it (`device_pose`) plus the coupling's stretch: the station's spring is
    K x that stretch, whatever its device did over the round trip; a coupled ToolState of
    the same poses is rendered against the device as it is now."""
    network = load_station_network("stations_loopback", "left")
    scene = load_port_scene("grasp_vertical")
    sta = Station(scene, network, "left", load_simulated_device("ideal"),
                  load_user("squeeze_left_2n"), 10)  # fmt: skip
    now = 10**12
    x_dev = float(sta.station[0]["world"][0]["pose"][0])
    was = (x_dev - 0.010, 0.0, 0.0)  # the device 10 mm back, a round trip ago
    stretch = 0.001  # the anchor 1 mm into the box: 2 N at 2 kN/m
    tool = (was[0] + stretch, 0.0, 0.0)
    for seq, flags in ((1, INDEXED), (2, 0)):
        m = ToolState(0, 1, seq, 0, tool, (0.0, 0.0, 0.0), (2000.0, 2000.0, 0.5),
                      (40.0, 40.0, 0.01), (0.0, 0.0, 0.0), flags, device_pose=was)  # fmt: skip
        take_tool(sta.station, sta.link, 0, now, encode_tool(m))
        sta.step(now, seq)
        s = sta.station[0]
        x_now = float(s["world"][0]["pose"][0])
        want = stretch if flags else tool[0] - x_now
        assert s["indexed"] == (1 if flags else 0)
        assert s["spring"][0] == pytest.approx(2000.0 * want, rel=1e-9, abs=1e-12), flags
        now += 1_000_000


def test_no_local_contact_while_the_world_re_indexes() -> None:
    """INDEXED, the object's pose is relative to where the device was a round trip ago, not
    where it is: the local model stays off and the coupling is rendered whole."""
    st = _station()
    st[0]["indexed"] = 1
    s = _at(st, TOUCH_X + 1e-3)
    assert s["contact_w"] == 0.0 and s["coupling"].tolist() == [2.0, 0.5, 0.01]


def test_the_couplings_damping_along_the_normal_comes_with_it_and_never_pulls() -> None:
    """B_n = 40 N s/m times the depth's rate: the pad moving in at 10 mm/s adds 0.4 N; moving
    out faster than the spring's push over B clips at zero, never a pull."""
    d = 1e-3
    for v_in, want in ((0.01, K_SERIES * d + 40.0 * 0.01), (-0.1, 0.0)):
        st = _station()
        st[0]["world"][0]["twist"] = (v_in, 0.0, 0.0)  # +x: the left pad into the box
        s = _at(st, TOUCH_X + d)
        assert -s["local_force"][0] == pytest.approx(want, rel=1e-12, abs=1e-15), v_in


def test_the_object_is_rendered_low_passed_from_where_it_was_when_contact_began() -> None:
    """The local contact renders the object where the world last sent it, low-passed with
    OBJECT_TAU_S (pose and twist): taken as it is on the first tick of contact; a reported
    step of 0.5 mm away from the pad is followed as 1 - (1 - dt/tau)^n, and the force with
    it, k_s (d - seen); leaving contact (a tick not fresh) drops what it had seen."""
    st = _station()
    s = st[0]
    d, step, dt = 1e-3, 5e-4, float(s["dt"])
    assert s["object_tau"] == OBJECT_TAU_S
    s = _at(st, TOUCH_X + d)
    assert s["object_seen"].tolist() == [0.0, 0.0, 0.0] and s["depth"] == pytest.approx(d)
    s["object_pose"][0] = step  # the box reported 0.5 mm further from the left pad
    for n in range(1, 101):
        s = _at(st, TOUCH_X + d)
        seen = step * (1.0 - (1.0 - dt / OBJECT_TAU_S) ** n)
        assert s["object_seen"][0] == pytest.approx(seen, rel=1e-9)
        assert s["local_force"][0] == pytest.approx(-K_SERIES * (d - seen), rel=1e-9)
    s["fresh"] = 0
    _at(st, TOUCH_X + d)
    s["fresh"] = 1
    s = _at(st, TOUCH_X + d)  # back in contact: the object as it is
    assert s["object_seen"][0] == step and s["depth"] == pytest.approx(d - step)

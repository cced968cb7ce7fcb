"""A station's compiled link (haptic_server/stages/station_link.py) against the reference it
replaces in the loop: shared/protocol/station.py's `decode_tool` for what a station takes,
`decode_device` for what it sends; and the station's order rule for ToolStates."""

from __future__ import annotations

import math
import struct
import time
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from haptic_local_model.device_models.registry import load_simulated_device
from haptic_local_model.haptic_server.stages.station_link import (
    station_link,
    station_log,
    station_step,
    take_tool,
)
from haptic_local_model.haptic_server.station import Station
from haptic_local_model.haptic_server.stations_cli import _scene
from haptic_local_model.shared.config import load_user
from haptic_local_model.shared.net.stations import load_station_network
from haptic_local_model.shared.port_config import load_port_scene
from haptic_local_model.shared.protocol.station import (
    CUT,
    GLOVE,
    REASONS,
    SAFE,
    STATION_VERSION,
    ToolState,
    decode_device,
    decode_tool,
    encode_tool,
)
from haptic_local_model.shared.protocol.station_codec import (
    TOOL_BYTES,
    TOOL_FLOATS,
    tool_refusal,
)
from haptic_local_model.shared.protocol.update import MessageError

EDGES = [0.0, -0.0, -1e-300, 99.999, 100.0, 100.0001, -1000.0, 1000.5, 1e7, 1.0000001e7,
         math.inf, -math.inf, math.nan]  # fmt: skip


def _station(scene: Any = None, port: str = "left", user: str | None = None) -> Station:
    scene = scene or load_port_scene("grasp_vertical")
    network = load_station_network("stations_loopback", port)
    spec = next(p for p in scene.ports if p.name == port)
    dev = load_simulated_device("ideal")
    return Station(scene, network, port, dev, load_user(user or spec.user), 10)


def _reference(raw: bytes, p: int) -> tuple[str | None, ToolState | None]:
    try:
        return None, decode_tool(raw, p)
    except MessageError as exc:
        return exc.reason, None


@st.composite
def _tool_messages(draw: Any) -> tuple[bytes, int]:
    """A ToolState's bytes as a world sends them, or mangled (as test_world_ports' devices)."""
    p = draw(st.integers(0, 1))
    f = draw(st.lists(st.one_of(st.sampled_from(EDGES), st.floats(-200.0, 200.0)),
                      min_size=TOOL_FLOATS, max_size=TOOL_FLOATS))  # fmt: skip
    flags = draw(st.sampled_from([0, 1, 2, 3, 1 << 31]))
    version = draw(st.sampled_from([STATION_VERSION, STATION_VERSION - 1]))
    raw = struct.pack(f"<4sHHQQq{TOOL_FLOATS}dI", b"HSTL", version, draw(st.integers(0, 2)),
                      draw(st.integers(0, 2**64 - 1)), draw(st.integers(0, 2**64 - 1)), 0,
                      *f, flags)  # fmt: skip
    mangle = draw(st.sampled_from(["none", "byte", "cut", "pad"]))
    if mangle == "byte":
        i = draw(st.integers(0, len(raw) - 1))
        raw = raw[:i] + bytes([draw(st.integers(0, 255))]) + raw[i + 1 :]
    elif mangle == "cut":
        raw = raw[: draw(st.integers(0, len(raw) - 1))]
    elif mangle == "pad":
        raw = raw + bytes(draw(st.integers(1, 9)))
    return raw, p


@pytest.mark.slow
@settings(max_examples=2000, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_tool_messages())
def test_the_compiled_tool_check_refuses_as_decode_tool(message: tuple[bytes, int]) -> None:
    raw, p = message
    reason, _ = _reference(raw, p)
    code = tool_refusal(raw, p)
    assert (REASONS[code] if code >= 0 else None) == reason


ONE_OF_EACH = {  # a ToolState each reason refuses
    "size": [b"HSTL", encode_tool(ToolState(0, 1, 1, 0, (0, 0, 0), (0, 0, 0), (1, 1, 1),
                                            (1, 1, 1), (0, 0, 0))) + b"\0"],
    "magic": [b"HSDV" + bytes(TOOL_BYTES - 4)],
    "port": [encode_tool(ToolState(1, 1, 1, 0, (0, 0, 0), (0, 0, 0), (1, 1, 1), (1, 1, 1),
                                   (0, 0, 0)))],
    "value": [encode_tool(ToolState(0, 1, 1, 0, (0, 0, 0), (0, 0, 0), (1, -1e-9, 1), (1, 1, 1),
                                    (0, 0, 0))),
              encode_tool(ToolState(0, 1, 1, 0, (0, 0, 0), (0, 0, 0), (1, 1, 1), (1, 1, 1),
                                    (0, 100.5, 0))),
              encode_tool(ToolState(0, 1, 1, 0, (0, 0, 0), (0, 0, 0), (1, 1, 1), (1, 1.1e7, 1),
                                    (0, 0, 0)))],
    "flags": [encode_tool(ToolState(0, 1, 1, 0, (0, 0, 0), (0, 0, 0), (1, 1, 1), (1, 1, 1),
                                    (0, 0, 0), 4))],
}  # fmt: skip


def _tool(twist: Any = (0, 0, 0), k: Any = (1, 1, 1), b: Any = (1, 1, 1),
          obj: Any = (0, 0, 0)) -> bytes:  # fmt: skip
    return encode_tool(ToolState(0, 1, 1, 0, (0, 0, 0), twist, k, b, obj))


def test_each_reason_refuses_its_tool_state() -> None:
    for reason, raws in ONE_OF_EACH.items():
        for raw in raws:
            assert _reference(raw, 0)[0] == reason
            assert REASONS[tool_refusal(raw, 0)] == reason, (reason, raw)
    # each field at its own limit: a twist beyond 1000, a damping below zero; a negative
    # object pose is a pose, not a gain
    for raw in (_tool(twist=(0, 1000.5, 0)), _tool(b=(1, 1, -1e-12)), _tool(k=(0, 1e7 * 1.01, 0))):
        assert _reference(raw, 0)[0] == "value" and REASONS[tool_refusal(raw, 0)] == "value"
    for raw in (_tool(obj=(-99.0, -5.0, -3.0)), _tool(twist=(-1000.0, 1000.0, 0)),
                _tool(k=(1e7, 0, -0.0), b=(0, 1e7, 0))):  # fmt: skip
        assert _reference(raw, 0)[0] is None and tool_refusal(raw, 0) == -1


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(
    st.tuples(*[st.floats(-100.0, 100.0)] * 3), st.tuples(*[st.floats(-1000.0, 1000.0)] * 3),
    st.tuples(*[st.floats(0.0, 1e7)] * 3), st.tuples(*[st.floats(0.0, 1e7)] * 3),
    st.integers(0, 1), st.integers(0, 2**64 - 1),
)  # fmt: skip
def test_a_valid_tool_state_is_taken_field_by_field(
    pose: Any, twist: Any, k: Any, b: Any, held: int, seq: int
) -> None:
    station = _station().station
    link = station_link()
    m = ToolState(0, 3, seq, 0, pose, twist, k, b, (0.0, 0.0, 0.0), held)
    take_tool(station, link, 0, 5, encode_tool(m))
    s = station[0]
    assert link[0]["received"] == 1 and int(link[0]["seq"]) == seq
    assert tuple(s["tool_pose"]) == pose and tuple(s["tool_twist"]) == twist
    assert tuple(s["stiffness"]) == k and tuple(s["damping"]) == b
    assert s["have_tool"] == 1 and s["held"] == held


def test_tool_states_are_taken_in_order_and_another_world_only_after_silence() -> None:
    """Within the world's epoch a ToolState must be newer; another epoch (a world restarted)
    is refused while the taken one is current (younger than the watchdog, 100 ms), taken
    after; each refusal counted by reason and nothing of it taken."""
    station = _station().station
    link = station_link()

    def tool(epoch: int, seq: int, x: float) -> bytes:
        return encode_tool(ToolState(0, epoch, seq, 0, (x, 0, 0), (0, 0, 0), (1, 1, 1),
                                     (1, 1, 1), (0, 0, 0)))  # fmt: skip

    ms = 1_000_000
    steps = [(0, tool(7, 5, 0.1), "taken"), (1 * ms, tool(7, 5, 0.2), "stale"),
             (2 * ms, tool(7, 4, 0.3), "stale"), (3 * ms, tool(8, 1, 0.4), "other_epoch"),
             (4 * ms, tool(7, 6, 0.5), "taken"), (103 * ms, tool(8, 2, 0.6), "other_epoch"),
             (105 * ms, tool(8, 3, 0.7), "taken"),
             (106 * ms, tool(7, 7, 0.8), "other_epoch")]  # fmt: skip
    want: dict[str, int] = {}
    x_taken = None
    for now, raw, outcome in steps:
        take_tool(station, link, 0, now, raw)
        if outcome == "taken":
            x_taken = struct.unpack_from("<d", raw, 32)[0]
        else:
            want[outcome] = want.get(outcome, 0) + 1
        got = {r: int(n) for r, n in zip(REASONS, link[0]["reasons"], strict=True) if n}
        assert got == want, (now, outcome)
        assert station[0]["tool_pose"][0] == x_taken
    assert int(link[0]["epoch"]) == 8 and link[0]["received"] == 3
    # a batch (one tick's messages): the current world's newest, then another world's: refused
    take_tool(station, link, 0, 107 * ms, tool(8, 4, 0.9))
    take_tool(station, link, 0, 107 * ms, tool(9, 1, 1.0))
    assert (
        station[0]["tool_pose"][0] == 0.9 and link[0]["reasons"][REASONS.index("other_epoch")] == 4
    )


def test_silent_tool_states_age_the_tool_into_the_watchdog_and_the_safe_state(ring: Any) -> None:
    """One ToolState, then none: the tool ages a tick at a time (the station's watchdog, 100 ms,
    fires at the tick it is 100 ms old), the station ramps to the safe state over 40 ms and says
    SAFE; the ramp counts one safe entry; each row logs the loop's figures and the counters."""
    sta = _station()
    now = 10**12
    rows = sta.rows = np.zeros(200, sta.rows.dtype)
    w = sta.station[0]["world"][0]
    raw = encode_tool(ToolState(0, 1, 1, 0, tuple(w["pose"]), (0, 0, 0), (1, 1, 1), (1, 1, 1),
                                (0, 0, 0)))  # fmt: skip
    sta.receive(ring([raw, b"junk"]), now)
    for k in range(200):
        t_ns = now + k * 10**6
        station_step(sta.station, sta.device.records, sta.link, sta.message, sta._glove,
                     t_ns, 0, k)  # fmt: skip
        station_log(sta.station, sta.link, rows, k, t_ns, 7000, 30000)
    assert np.allclose(rows["tool_age"], np.arange(200) * 1e-3, rtol=0, atol=1e-12)
    wd = int(np.argmax(rows["fresh"] == 0))
    assert rows["fresh"][:wd].all() and not rows["fresh"][wd:].any() and wd == 100
    safe = int(np.argmax(rows["gain"] == 0.0))
    assert 30 <= safe - wd <= 40 and sta.link[0]["safe_entries"] == 1
    assert decode_device(sta.message.tobytes(), 0).flags == SAFE
    assert rows["wall_ns"][5] == now + 5 * 10**6 and rows["late_us"][5] == 7.0
    assert rows["work_us"][5] == 30.0 and (rows["received"] == 1).all()
    assert (rows["rejected"] == 1).all() and sta.reasons() == {"size": 1}


def test_the_station_sends_its_device_as_decode_device_reads_it() -> None:
    """A tick's DeviceState: the device's pose and twist in the world, SAFE until tool states
    are fresh, the tick's seq and time; CUT with zeros when the reading is not finite."""
    sta = _station()
    link, msg = sta.link, sta.message
    now = time.perf_counter_ns()
    station_step(sta.station, sta.device.records, link, msg, sta._glove, now, 123, 9)
    m = decode_device(msg.tobytes(), 0)
    w = sta.station[0]["world"][0]
    assert (m.seq, m.publish_time_ns, m.epoch) == (9, 123, sta.epoch)
    assert m.flags == SAFE and m.pose == tuple(w["pose"]) and m.twist == tuple(w["twist"])
    tool = encode_tool(ToolState(0, 1, 1, 0, tuple(w["pose"]), (0, 0, 0), (1, 1, 1), (1, 1, 1),
                                 (0, 0, 0)))  # fmt: skip
    take_tool(sta.station, link, 0, now, tool)
    station_step(sta.station, sta.device.records, link, msg, sta._glove, now + 10**6, 124, 10)
    assert decode_device(msg.tobytes(), 0).flags == 0  # fresh: rendering the coupling
    sta.station[0]["map"][0]["offset"][0] = np.nan  # a reading that is not finite
    station_step(sta.station, sta.device.records, link, msg, sta._glove, now + 2 * 10**6, 125, 11)
    m = decode_device(msg.tobytes(), 0)
    assert m.flags == CUT and m.pose == (0.0, 0.0, 0.0) and m.twist == (0.0, 0.0, 0.0)


def test_a_hands_station_sends_its_users_glove_on_its_own_clock() -> None:
    """hand_grasp with a user whose glove moves (hand_press_wall's script): the glove's angles
    and rates from the script at the time since the station's first tick (its own clock),
    GLOVE set, the unused joints zero."""
    from haptic_local_model.haptic_server.stages.hand import glove_at

    scene, _ = _scene("hand_grasp")
    sta = _station(scene, scene.ports[0].name, "hand_press_wall")
    script = sta._glove
    n = script.shape[1] - 1
    assert len(script) > 1 and n > 0
    now = 10**12
    for dt_s in (0.0, 1.7, 2.0, 5.0):  # held, ramping (rate 0.3 rad/s), ramping, held
        t_ns = now + round(dt_s * 1e9)
        station_step(sta.station, sta.device.records, sta.link, sta.message, script, t_ns, 0, 0)
        m = decode_device(sta.message.tobytes(), 0)
        angle, rate = np.zeros(n), np.zeros(n)
        glove_at(script, len(script), (t_ns - now) / 1e9, n, angle, rate)
        assert m.flags & GLOVE and m.glove[:n] == tuple(angle) and m.glove_rate[:n] == tuple(rate)
        assert not any(m.glove[n:]) and not any(m.glove_rate[n:])
        assert any(m.glove[:n])  # written: the script's angles are not all zero
        if 1.5 < dt_s < 2.5:  # the script's second segment: 0.3 rad over 1 s
            assert math.isclose(m.glove_rate[0], 0.3, rel_tol=1e-12)

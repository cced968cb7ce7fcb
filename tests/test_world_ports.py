"""The shared world's compiled ports (haptic_server/stages/world_ports.py) against the
reference they replace in the loop: shared/protocol/station.py's `decode_device` and
`order_refusal`, and `decode_tool` for what the world publishes.

The compiled take must refuse exactly the messages the reference refuses, for the same
reason, and take the same fields from the rest; over a sequence of messages it must refuse
by order as `order_refusal` does with its silence rule.
"""

from __future__ import annotations

import dataclasses
import math
import struct
import time
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from haptic_local_model.haptic_server.shared_world import SharedWorld
from haptic_local_model.haptic_server.stages.world_ports import (
    EXTRAPOLATE_S,
    port_links,
    take_device,
    world_clock,
)
from haptic_local_model.haptic_server.world_engines import CosimWorld
from haptic_local_model.shared.net.stations import load_station_network
from haptic_local_model.shared.port_config import load_port_scene
from haptic_local_model.shared.protocol.station import (
    HELD,
    MAX_GLOVE_JOINTS,
    REASONS,
    SAFE,
    DeviceState,
    decode_device,
    decode_tool,
    encode_device,
    order_refusal,
)
from haptic_local_model.shared.protocol.station_codec import (
    DEVICE_BYTES,
    device_refusal,
)
from haptic_local_model.shared.protocol.update import MessageError

J = MAX_GLOVE_JOINTS
EDGES = [0.0, -0.0, 1e-300, 99.999, 100.0, 100.0001, -1000.0, 1000.5, 6.28, 6.3,
         math.inf, -math.inf, math.nan]  # fmt: skip


def _reference(raw: bytes, p: int) -> tuple[str | None, DeviceState | None]:
    try:
        return None, decode_device(raw, p)
    except MessageError as exc:
        return exc.reason, None


def _floats(n: int) -> Any:
    return st.lists(
        st.one_of(st.sampled_from(EDGES), st.floats(-200.0, 200.0)), min_size=n, max_size=n
    )


@st.composite
def _messages(draw: Any) -> tuple[bytes, int]:
    """A DeviceState's bytes as a station would send them, or mangled: another port, a
    value at or beyond its limit, unknown flags, a byte changed, truncated, padded."""
    p = draw(st.integers(0, 1))
    f = draw(_floats(6 + 2 * J))
    flags = draw(st.sampled_from([0, 1, 2, 3, 4, 5, 7, 8, 1 << 31]))
    epoch, seq = draw(st.integers(0, 2**64 - 1)), draw(st.integers(0, 2**64 - 1))
    raw = struct.pack(f"<4sHHQQq{6 + 2 * J}dI", b"HSDV", 2, draw(st.integers(0, 2)), epoch,
                      seq, 0, *f, flags)  # fmt: skip
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
@given(_messages())
def test_the_compiled_take_refuses_as_the_reference_and_takes_its_fields(
    message: tuple[bytes, int],
) -> None:
    raw, p = message
    reason, m = _reference(raw, p)
    code = device_refusal(raw, p)
    assert (REASONS[code] if code >= 0 else None) == reason
    ports, clock = port_links(2), world_clock(2, 1e-3, 50.0, 100.0)
    take_device(ports, clock, p, raw)
    ps = ports[p]
    if m is None:
        assert ps["received"] == 0 and ps["rejected"] == 1
        assert ps["reasons"][REASONS.index(reason or "")] == 1
        return
    assert ps["received"] == 1 and ps["rejected"] == 0 and len(raw) == DEVICE_BYTES
    assert (int(ps["epoch"]), int(ps["seq"]), int(ps["flags"])) == (m.epoch, m.seq, m.flags)
    taken = np.concatenate([ps["pose"], ps["twist"], ps["glove"], ps["glove_rate"]])
    sent = np.array([*m.pose, *m.twist, *m.glove, *m.glove_rate])
    assert np.array_equal(taken, sent)  # bit for bit (-0.0 == 0.0 aside)


@pytest.mark.slow
@settings(max_examples=500, deadline=None)
@given(
    st.integers(0, 1),
    st.integers(0, 2**64 - 1),
    st.integers(0, 2**64 - 1),
    st.lists(st.floats(-100.0, 100.0), min_size=3, max_size=3),
    st.lists(st.floats(-1000.0, 1000.0), min_size=3, max_size=3),
    st.lists(st.floats(-6.28, 6.28), min_size=J, max_size=J),
    st.lists(st.floats(-1000.0, 1000.0), min_size=J, max_size=J),
    st.integers(0, 7),
)
def test_a_valid_message_is_taken_field_by_field(
    p: int, epoch: int, seq: int, pose: list[float], twist: list[float],
    glove: list[float], rate: list[float], flags: int,
) -> None:  # fmt: skip
    """Messages a station sends (every field within its limit, the epoch and seq over all of
    uint64): each field taken as the reference decodes it."""
    m = DeviceState(p, epoch, seq, 7, tuple(pose), tuple(twist), flags, tuple(glove), tuple(rate))  # type: ignore[arg-type]
    raw = encode_device(m)
    assert decode_device(raw, p) == m and device_refusal(raw, p) == -1
    ports, clock = port_links(2), world_clock(2, 1e-3, 50.0, 100.0)
    take_device(ports, clock, p, raw)
    ps = ports[p]
    assert (int(ps["epoch"]), int(ps["seq"]), int(ps["flags"])) == (epoch, seq, flags)
    for field, sent in (("pose", pose), ("twist", twist), ("glove", glove), ("glove_rate", rate)):
        assert ps[field].tolist() == sent, field


def _device(p: int = 0, **fields: Any) -> bytes:
    m = DeviceState(p, 1, 1, 0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    return encode_device(dataclasses.replace(m, **fields))


ONE_OF_EACH = {  # a message each reason refuses (the hypothesis above may miss one)
    "size": [b"HSDV", _device() + b"\0", _device()[:-1]],
    "magic": [b"HSTL" + _device()[4:]],
    "version": [_device()[:4] + b"\x01\x00" + _device()[6:]],
    "port": [_device(1)],
    "value": [_device(pose=(100.5, 0, 0)), _device(twist=(0, 0, math.nan)),
              _device(glove=(0.0,) * (J - 1) + (-6.3,)), _device(glove_rate=(0.0, math.inf))],
    "flags": [_device(flags=8), _device(flags=1 << 31)],
}  # fmt: skip


def test_each_reason_refuses_its_message() -> None:
    for reason, raws in ONE_OF_EACH.items():
        for raw in raws:
            assert _reference(raw, 0)[0] == reason
            assert REASONS[device_refusal(raw, 0)] == reason, (reason, raw)
    assert device_refusal(_device(pose=(100.0, -100.0, 6.0), flags=7), 0) == -1


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 3), st.integers(0, 6), st.integers(0, 80)),
                min_size=1, max_size=30))  # fmt: skip
def test_messages_are_taken_in_order_as_order_refusal_says(
    sequence: list[tuple[int, int, int]],
) -> None:
    """(epoch, seq, ms since the last message) in turn: the compiled take refuses what
    order_refusal refuses (stale in an epoch; another epoch unless the taken one has been
    silent for the watchdog, 50 ms), and counts it by its reason."""
    ports, clock = port_links(1), world_clock(1, 1e-3, 50.0, 100.0)
    last: DeviceState | None = None
    rx_ns = now_ns = 1_000_000_000
    want: dict[str, int] = {}
    for epoch, seq, gap_ms in sequence:
        now_ns += gap_ms * 1_000_000
        clock[0]["now_ns"] = now_ns
        m = DeviceState(0, epoch, seq, 0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        silent = last is None or (now_ns - rx_ns) / 1e6 > 50.0
        why = order_refusal(last, epoch, seq, silent)
        if why is None:
            last, rx_ns = m, now_ns
        else:
            want[why] = want.get(why, 0) + 1
        take_device(ports, clock, 0, encode_device(m))
    got = {r: int(n) for r, n in zip(REASONS, ports[0]["reasons"], strict=True) if n}
    assert got == want
    assert last is not None and int(ports[0]["epoch"]) == last.epoch
    assert int(ports[0]["seq"]) == last.seq and int(ports[0]["rx_ns"]) == rx_ns


def test_the_world_publishes_each_tool_in_its_stations_frame(ring: Any) -> None:
    """A ToolState as decode_tool reads it: the tool's pose less the port's offset (its angle
    wrapped to (-pi, pi]), its twist, the object's pose likewise and its twist, the tick's
    seq; HELD while the port is held, not once it is coupled."""
    scene = load_port_scene("grasp_vertical")
    world = SharedWorld(scene, load_station_network("stations_loopback", "world"), 10)
    now = time.perf_counter_ns()
    world.step(now, 0.0, 5)
    for p in range(2):
        tool = decode_tool(world.tools[p : p + 1].tobytes(), p)
        q, qd = world.engine.tool(p)
        assert tool.held and tool.seq == 5 and tool.epoch == world.epoch
        assert np.array_equal(tool.pose, q) and np.array_equal(tool.twist, qd)
        assert np.array_equal(tool.object_pose, world.engine.poses()[2])
    x = -0.3  # the device 0.3 m left of the anchor, turned by 2 pi - 0.1 (wraps to -0.1)
    for seq, flags in ((1, SAFE), (2, 0)):  # indexed, then coupled
        pose = (x, 0.0, 2 * math.pi - 0.1)
        raw = encode_device(DeviceState(0, 9, seq, 0, pose, (0.0, 0.0, 0.0), flags))
        world.receive(0, ring([raw]), now)
        world.step(now, 0.0, 5 + seq)
        held = decode_tool(world.tools[0:1].tobytes(), 0).held
        assert world.state(0) == ("indexing" if flags else "coupled") and not held
    tool = decode_tool(world.tools[0:1].tobytes(), 0)
    q, _ = world.engine.tool(0)
    offset = world.ports[0]["offset"]
    assert world.state(0) == "coupled" and not tool.flags & HELD
    assert offset[0] == world.ports[0]["anchor"][0] - x
    assert tool.pose[0] == q[0] - offset[0] and tool.pose[1] == q[1] - offset[1]
    unwrapped = q[2] - offset[2]  # about 2 pi - 0.1: the anchor's angle is about 0
    assert unwrapped > math.pi
    assert tool.pose[2] == math.atan2(math.sin(unwrapped), math.cos(unwrapped))
    # the object likewise in the station's frame (its local model), its twist as it is
    box = world.engine.poses()[2]
    assert tool.object_pose[:2] == (box[0] - offset[0], box[1] - offset[1])
    box_angle = box[2] - offset[2]
    assert tool.object_pose[2] == math.atan2(math.sin(box_angle), math.cos(box_angle))
    assert np.array_equal(tool.object_twist, world.engine.data[0]["qd"][6:9])


def test_a_coupled_device_is_carried_on_by_its_twist_for_at_most_the_cap(ring: Any) -> None:
    """COUPLED, the fed pose blends from the anchor to the device as last seen, re-indexed and
    carried on by its twist for its age up to EXTRAPOLATE_S (not beyond); the fed twist is
    the device's times the blend."""
    scene = load_port_scene("grasp_vertical")
    # the fed pose, not the passivity controller (the station here sends no energy)
    network = dataclasses.replace(load_station_network("stations_loopback", "world"),
                                  passivity="off")  # fmt: skip
    world = SharedWorld(scene, network, 10)
    now = time.perf_counter_ns()
    twist = (0.3, -0.2, 1.5)
    for seq, flags in ((1, SAFE), (2, 0)):
        raw = encode_device(DeviceState(0, 9, seq, 0, (0.01, 0.02, 0.1), twist, flags))
        world.receive(0, ring([raw]), now)
        world.step(now, 0.0, seq)
    ps = world.ports[0]
    seen = np.array((0.01, 0.02, 0.1)) + ps["offset"]
    for age_ms, carried_s in ((0.0, 0.0), (2.0, 0.002), (4.0, 0.004), (9.0, EXTRAPOLATE_S)):
        start, blend0 = ps["start"].copy(), float(ps["blend"])
        world.step(now + round(age_ms * 1e6), 0.0, 3)
        blend = float(ps["blend"])
        assert blend == min(1.0, blend0 + 1e-3 / (world.network.safe_ramp_ms / 1e3))
        live = seen + np.array(twist) * carried_s
        assert np.allclose(ps["fed_pose"], start + blend * (live - start), rtol=0, atol=1e-15)
        assert np.allclose(ps["fed_twist"], blend * np.array(twist), rtol=0, atol=1e-15)
        assert isinstance(world.engine, CosimWorld)
        fed = world.engine.data[0]
        assert np.array_equal(fed["device_pose"][0], ps["fed_pose"])

"""Wire format: round trips, a golden file that pins the bytes, and rejection of bad input."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from haptic_local_model.shared.protocol.proxy import (
    MAX_IMPULSES,
    ShapeImpulses,
    decode_proxy,
    encode_proxy,
)
from haptic_local_model.shared.protocol.update import (
    AvarState,
    ChainTable,
    ContactSet,
    LocalModelUpdate,
    MessageError,
    contact_rows,
    decode_update,
    encode_update,
)
from haptic_local_model.shared.shapes import Motion, ShapeKind, set_core, shape_array

GOLDEN = Path(__file__).parent / "golden" / "update_v3_linkage.bin"
GOLDEN_SHAPES = Path(__file__).parent / "golden" / "update_v3_shapes.bin"
GOLDEN_CHAINS = Path(__file__).parent / "golden" / "update_v3_chains.bin"
GOLDEN_AVARS = Path(__file__).parent / "golden" / "update_v3_avars.bin"
GOLDEN_V2 = Path(__file__).parent / "golden" / "update_v2_linkage.bin"  # releases 0.2-0.5
GOLDEN_V1 = Path(__file__).parent / "golden" / "update_v1_linkage.bin"  # release 0.1


def sample_update(n_contacts: int = 2, resisted: bool = True) -> LocalModelUpdate:
    """A 3-link update with gravity, resisted directions and contacts."""
    rng = np.random.default_rng(7)
    a = rng.normal(size=(3, 3))
    rows, floats = contact_rows(n_contacts)
    for i in range(n_contacts):
        r = rows[i]
        r["tool"], r["env"], r["normal"] = (0.01 * i, 0.002), (0.1, -0.05 * i), (0.0, 1.0)
        r["env_velocity"], r["friction"], r["restitution"] = (0.01, 0.0), 0.3, 0.1
        r["stiffness"], r["damping"], r["tangential_stiffness"] = 15000.0, 20.0, 15000.0
    return LocalModelUpdate(
        epoch=1234567890123, seq=42, sim_time=1.25, publish_time_ns=987654321,
        joint_types=np.zeros(3, np.int64), lengths=np.array([0.042, 0.042, 0.03]),
        base=np.array([0.0, 0.01]), base_angle=0.0, op_link=2, op_point=np.array([0.015, 0.0]),
        q=np.array([0.1, 0.2, -0.3]), qd=np.array([0.0, 0.5, -0.1]),
        mass_matrix=a @ a.T + 3 * np.eye(3), lambda_inv=np.eye(3) * 0.5,
        tool_pose=np.array([0.1, 0.05, 0.0]), gravity=np.array([0.1, 0.2, 0.3]),
        velocity_torque=np.array([1e-3, -2e-3, 5e-4]),
        resisted=np.array([[0.6, 0.8, 0.0]]) if resisted else None, characteristic_length=0.05,
        contacts=ContactSet(np.arange(n_contacts) % 3, np.arange(n_contacts) + 100, floats),
        tool_touching=True,
    )  # fmt: skip


def sample_shapes() -> np.ndarray:
    """One shape of each kind, with every field set."""
    shapes = shape_array(3)
    set_core(shapes[0], ShapeKind.CIRCLE, [[0.001, -0.002]], 0.004)
    set_core(shapes[1], ShapeKind.SEGMENT, [[-0.02, 0.0], [0.02, 0.001]], 0.0005)
    set_core(shapes[2], ShapeKind.POLYGON, [[-0.02, -0.01], [0.02, -0.01], [0.0, 0.015]], 0.0)
    for k, s in enumerate(shapes):
        s["key"], s["generation"], s["motion"] = 10 + k, k, int(Motion.SCREW) * (k == 2)
        s["pose"], s["twist"] = (0.01 * k, -0.02, 0.3 * k), (0.05, -0.01 * k, 2.0 * k)
        s["static_friction"], s["friction"] = 0.5, 0.4
    return shapes


def sample_with_shapes() -> LocalModelUpdate:
    return LocalModelUpdate(**{**sample_update().__dict__, "shapes": sample_shapes()})


def sample_with_chains() -> LocalModelUpdate:
    """The sample as a tree of two chains and a shape: the held finger (joints 0-1, the
    tool) and a free branch's joint 2 on a base of its own (an object)."""
    chains = ChainTable(
        parents=np.array([-1, 0, -1]), first=np.array([0, 2]), kind=np.array([0, 1]),
        port=np.array([0, -1]), bases=np.array([[0.1, -0.2, 0.3]]),
    )  # fmt: skip
    fields = {**sample_update().__dict__, "op_link": 1, "chains": chains}
    return LocalModelUpdate(**{**fields, "shapes": sample_shapes()[:1]})


def sample_with_avars() -> LocalModelUpdate:
    """The sample with a train of two cars (DESIGN-WAVE2 §5): the AVARS trailer, a world
    shape and one on car 1, posed by the train (motion 3)."""
    shapes = sample_shapes()[1:]
    shapes[1]["owner"], shapes[1]["motion"] = 1, int(Motion.TRACK)
    avars = AvarState(static_id=123456789, cars=2, s=0.25, sd=-1.5)
    return LocalModelUpdate(**{**sample_update().__dict__, "avars": avars, "shapes": shapes})


def assert_same(a: LocalModelUpdate, b: LocalModelUpdate) -> None:
    for name in (
        "epoch",
        "seq",
        "sim_time",
        "publish_time_ns",
        "base_angle",
        "op_link",
        "characteristic_length",
        "tool_touching",
    ):
        assert getattr(a, name) == getattr(b, name), name
    for name in (
        "joint_types",
        "lengths",
        "base",
        "op_point",
        "q",
        "qd",
        "mass_matrix",
        "lambda_inv",
        "tool_pose",
        "gravity",
        "resisted",
    ):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    np.testing.assert_array_equal(a.contacts.floats, b.contacts.floats)
    np.testing.assert_array_equal(a.contacts.link, b.contacts.link)
    np.testing.assert_array_equal(a.contacts.key, b.contacts.key)
    assert (a.shapes is None) == (b.shapes is None)
    if a.shapes is not None and b.shapes is not None:
        assert a.shapes.tobytes() == b.shapes.tobytes()
    assert a.avars == b.avars
    assert (a.chains is None) == (b.chains is None)
    if a.chains is not None and b.chains is not None:
        for name in ("parents", "first", "kind", "port", "bases"):
            np.testing.assert_array_equal(getattr(a.chains, name), getattr(b.chains, name))


def test_update_round_trip_exact() -> None:
    u = sample_update()
    assert_same(decode_update(encode_update(u)), u)


def test_update_without_optional_sections() -> None:
    u = sample_update(n_contacts=0, resisted=False)
    u = LocalModelUpdate(**{**u.__dict__, "gravity": None, "velocity_torque": None})
    raw = encode_update(u)
    back = decode_update(raw)
    assert back.gravity is None and back.resisted is None and back.contacts.count == 0
    assert back.velocity_torque is None
    assert len(raw) < len(encode_update(sample_update()))  # left out, not zero-filled


def test_golden_file_pins_the_wire_format() -> None:
    raw = encode_update(sample_update())
    if not GOLDEN.exists():  # written once; a change of the format must change PROTOCOL_VERSION
        GOLDEN.write_bytes(raw)
    assert raw == GOLDEN.read_bytes()
    assert_same(decode_update(GOLDEN.read_bytes()), sample_update())


def test_shapes_round_trip_and_golden_file() -> None:
    """Version 3's SHAPES trailer: every field survives, the bound is derived, and the bytes
    are pinned (written once)."""
    raw = encode_update(sample_with_shapes())
    assert raw == GOLDEN_SHAPES.read_bytes()  # a change of the format must change the version
    back = decode_update(raw)
    assert_same(back, sample_with_shapes())
    assert encode_update(back) == raw


def test_chains_round_trip_and_golden_file() -> None:
    """The CHAINS trailer (DESIGN-WAVE2 C1, C4) before the SHAPES one: every field survives,
    the parsed record carries the tree, and the bytes are pinned. A serial update leaves it
    out, and parses as one chain with parents[i] = i - 1."""
    from haptic_local_model.shared.protocol.update import UpdateParser

    raw = encode_update(sample_with_chains())
    assert raw == GOLDEN_CHAINS.read_bytes()  # a change of the format must change the version
    back = decode_update(raw)
    assert_same(back, sample_with_chains())
    assert encode_update(back) == raw
    parser = UpdateParser()
    assert parser.parse(raw) == 0
    m = parser.out[0]
    assert m["n_chains"] == 2 and list(m["parents"][:3]) == [-1, 0, -1]
    np.testing.assert_array_equal(m["chain_base"][1], [0.1, -0.2, 0.3])
    assert parser.parse(encode_update(sample_update())) == 0
    assert m["n_chains"] == 1 and list(m["parents"][:3]) == [-1, 0, 1] and not m["has_chains"]


def test_avars_round_trip_and_golden_file() -> None:
    """The AVARS trailer (DESIGN-WAVE2 §5) between CHAINS and SHAPES: every field survives,
    a car's shape keeps its owner, and the bytes are pinned (the compiled encoder's too)."""
    raw = encode_update(sample_with_avars())
    assert raw == GOLDEN_AVARS.read_bytes()
    back = decode_update(raw)
    assert_same(back, sample_with_avars())
    assert back.shapes is not None and list(back.shapes["owner"]) == [-1, 1]
    assert encode_update(back) == raw
    assert _encoded_from_record(raw) == raw


def test_version_2_still_parses() -> None:
    """Logs of releases 0.2-0.5 carry version-2 updates (no shapes): they decode to the same
    model as today's encoding of it."""
    assert struct.unpack_from("<H", GOLDEN_V2.read_bytes(), 4)[0] == 2
    assert_same(decode_update(GOLDEN_V2.read_bytes()), sample_update())


def test_version_1_still_parses_with_the_stick_stiffness_of_its_day() -> None:
    """Logs of the last release carry version-1 updates (no tangential stiffness column): they
    decode, with K_t = K_c, to the same model as today's encoding of it."""
    assert struct.unpack_from("<H", GOLDEN_V1.read_bytes(), 4)[0] == 1
    assert_same(decode_update(GOLDEN_V1.read_bytes()), sample_update())


def _corrupt_float(raw: bytes, value: float, index_from_end: int) -> bytes:
    b = bytearray(raw)
    struct.pack_into("<d", b, len(b) - 8 * index_from_end, value)
    return bytes(b)


@pytest.mark.parametrize(
    ("mutate", "reason"),
    [
        (lambda r: r[:20], "short"),
        (lambda r: b"XXXX" + r[4:], "magic"),
        (lambda r: r[:4] + struct.pack("<H", 99) + r[6:], "version"),
        (lambda r: r + b"\0" * 8, "size"),
        (lambda r: _corrupt_float(r, float("nan"), 3), "nonfinite"),
        (lambda r: _corrupt_float(r, float("inf"), 30), "nonfinite"),
        (lambda r: _corrupt_float(r, -5.0, 2), "contact"),  # negative stiffness
        (lambda r: _corrupt_float(r, 0.5, 8), "contact"),  # normal no longer unit
        # a flag bit the protocol does not define (it passed the parser up to 0.9, and was
        # refused only later as `jump`)
        (
            lambda r: r[:6] + struct.pack("<H", struct.unpack_from("<H", r, 6)[0] | 128) + r[8:],
            "flags",
        ),
    ],
)
def test_bad_updates_are_rejected_with_a_reason(mutate: object, reason: str) -> None:
    raw = encode_update(sample_update())
    with pytest.raises(MessageError) as err:
        decode_update(mutate(raw))  # type: ignore[operator]
    assert err.value.reason == reason


def test_mass_matrix_must_be_spd_and_symmetric() -> None:
    u = sample_update()
    not_spd = LocalModelUpdate(**{**u.__dict__, "mass_matrix": -np.eye(3)})
    with pytest.raises(MessageError, match="mass_matrix"):
        decode_update(encode_update(not_spd))
    m = u.mass_matrix.copy()
    m[0, 1] += 1.0
    with pytest.raises(MessageError, match="mass_matrix"):
        decode_update(encode_update(LocalModelUpdate(**{**u.__dict__, "mass_matrix": m})))


def test_proxy_round_trip_and_rejection() -> None:
    """The one encoder (from a tick row) and the decoder agree; a NaN is rejected."""
    from haptic_local_model.haptic_server.model import TICK_DTYPE

    row = np.zeros(1, TICK_DTYPE)
    r = row[0]
    r["dof"], r["update_epoch"], r["update_seq"], r["tick"], r["t"] = 3, 5, 9, 1000, 1.0
    r["safe"] = 0.5
    r["proxy_q"][:3] = [0.1, 0.2, 0.3]
    r["device_pose"] = [0.0, 1.0, 2.0]
    r["device_twist"] = np.ones(3)
    raw = encode_proxy(row, 2, publish_time_ns=11)
    back = decode_proxy(raw)
    assert back.safe_state and back.valid and back.tick == 1000 and back.method == 2
    assert (back.epoch, back.update_seq, back.publish_time_ns) == (5, 9, 11)
    np.testing.assert_array_equal(back.q, [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(back.device_twist, np.ones(3))
    with pytest.raises(MessageError, match="nonfinite"):  # the twist's last, before n, span
        decode_proxy(_corrupt_float(raw, float("nan"), 4))  # and the train count
    assert back.impulses.count == 0  # not a god-object: no impulses on shapes
    r["dt"] = 1e-3
    r["god_env_key"] = [7, -1]
    r["god_env_point"] = [[0.01, 0.02], [0.0, 0.0]]
    r["god_env_arm"] = [[0.004, 0.0], [0.0, 0.0]]
    r["god_env_force"] = [[-1.5, 0.25], [0.0, 0.0]]
    god = decode_proxy(encode_proxy(row, 4, publish_time_ns=11))
    np.testing.assert_array_equal(god.impulses.keys, [7])  # this tick's force x its dt
    np.testing.assert_array_equal(god.impulses.points, [[0.004, 0.0]])  # the arm
    np.testing.assert_allclose(god.impulses.impulses, [[-1.5e-3, 0.25e-3]], rtol=1e-15)
    assert decode_proxy(encode_proxy(row, 2, publish_time_ns=11)).impulses.count == 0
    raw_god = encode_proxy(row, 4, publish_time_ns=11)
    assert god.impulses.span_s == 1e-3  # the tick's dt
    bad = bytearray(raw_god)
    struct.pack_into("<q", bad, len(bad) - 48, -5)  # the key (before the train count)
    with pytest.raises(MessageError, match="env"):
        decode_proxy(bytes(bad))
    bad = bytearray(raw_god)
    struct.pack_into("<q", bad, len(bad) - 64, MAX_IMPULSES + 1)  # the count
    with pytest.raises(MessageError, match="env"):
        decode_proxy(bytes(bad))
    bad = bytearray(raw_god)
    struct.pack_into("<d", bad, len(bad) - 56, -1e-3)  # the span
    with pytest.raises(MessageError, match="env"):
        decode_proxy(bytes(bad))
    with pytest.raises(MessageError, match="magnitude"):  # an impulse of 1e9 N s on a shape
        decode_proxy(_corrupt_float(raw_god, 1e9, 2))
    with pytest.raises(MessageError, match="size"):
        decode_proxy(raw_god[:-8])
    # version 6: the train the haptic side integrates, which the sim poses its cars by
    assert god.train is None
    r["avar_cars"], r["avar_static_id"], r["avar_s"], r["avar_sd"] = 3, 77, 0.25, -1.5
    train = decode_proxy(encode_proxy(row, 4, publish_time_ns=11)).train
    assert train is not None and (train.static_id, train.s, train.sd) == (77, 0.25, -1.5)
    raw_train = encode_proxy(row, 4, publish_time_ns=11)
    with pytest.raises(MessageError, match="nonfinite"):
        decode_proxy(_corrupt_float(raw_train, float("nan"), 1))
    with pytest.raises(MessageError, match="train"):
        decode_proxy(_corrupt_float(raw_train, 1e9, 2))
    bad = bytearray(raw_train)
    struct.pack_into("<q", bad, len(bad) - 32, 2)  # two trains
    with pytest.raises(MessageError, match="train"):
        decode_proxy(bytes(bad))
    with pytest.raises(MessageError, match="size"):
        decode_proxy(raw_train[:-8])


def cross2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The planar cross product a x b (z), over the last axis."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def test_impulses_over_ticks_sum_per_shape_and_keep_the_moment() -> None:
    """DESIGN-WAVE2 C4: the ticks between two proxy states give, per shape key, the sum of
    force x dt at a point on its line of action with the parts' moment (a finger sliding
    round a pebble pushes it through its centre, and so does the sum); merging two intervals
    is the same as taking them at once; two shapes in one tick are kept apart."""
    rng = np.random.default_rng(3)
    n = 9
    keys = np.where(rng.uniform(size=(n, 2)) < 0.7, rng.integers(0, 3, (n, 2)), -1)
    keys[:, 1] = np.where(keys[:, 1] == keys[:, 0], -1, keys[:, 1])
    points = rng.uniform(-0.1, 0.1, (n, 2, 2))
    forces = rng.uniform(-2, 2, (n, 2, 2))
    dt = rng.uniform(0.9e-3, 1.1e-3, n)
    whole = ShapeImpulses.of_ticks(keys, points, forces, dt)
    for j, key in enumerate(whole.keys):
        on = keys == key
        impulse = (forces[on] * np.broadcast_to(dt[:, None], keys.shape)[on][:, None]).sum(0)
        np.testing.assert_allclose(whole.impulses[j], impulse, rtol=1e-12)
        parts = forces[on] * np.broadcast_to(dt[:, None], keys.shape)[on][:, None]
        moment = cross2(points[on], parts).sum()  # about the origin: the parts' and the sum's
        np.testing.assert_allclose(cross2(whole.points[j], whole.impulses[j]), moment, atol=1e-15)
    halves = ShapeImpulses.of_ticks(keys[:4], points[:4], forces[:4], dt[:4]).merged(
        ShapeImpulses.of_ticks(keys[4:], points[4:], forces[4:], dt[4:])
    )
    np.testing.assert_array_equal(halves.keys, whole.keys)
    assert halves.span_s == pytest.approx(whole.span_s) == pytest.approx(dt.sum())
    np.testing.assert_allclose(halves.impulses, whole.impulses, rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(
        cross2(halves.points, halves.impulses), cross2(whole.points, whole.impulses),
        atol=1e-15,
    )  # fmt: skip
    centre, turn = np.array([1.0, 2.0]), np.linspace(0.0, 1.0, 17)
    rim = centre + 0.004 * np.column_stack([np.cos(turn), np.sin(turn)])
    slide = ShapeImpulses.of_ticks(
        np.full((17, 1), 5), rim[:, None], (centre - rim)[:, None] * 500, np.full(17, 1e-3)
    )  # radial pushes round a pebble: no torque about its centre
    assert abs(cross2(slide.points[0] - centre, slide.impulses[0])) < 1e-15
    assert ShapeImpulses.of_ticks(-np.ones((3, 2)), points[:3], forces[:3], dt[:3]).count == 0
    many = ShapeImpulses.of_ticks(
        np.arange(40).reshape(20, 2), points[:1].repeat(20, 0), np.ones((20, 2, 2)),
        np.linspace(1e-3, 2e-3, 20),  # the later ticks the larger impulses
    )  # fmt: skip
    assert many.count == MAX_IMPULSES  # the largest kept (a stalled I/O process only)
    assert set(many.keys.tolist()) == set(range(40 - MAX_IMPULSES, 40))


def test_proxy_of_an_engine_tick_carries_its_state() -> None:
    """What the sidecar publishes from the loop's newest row is the engine's proxy and device."""
    from haptic_local_model.device_models.registry import load_device
    from haptic_local_model.haptic_server.engine import HapticEngine
    from haptic_local_model.shared.config import load_scene, load_user
    from haptic_local_model.sim_server.world import SimWorld

    scene = load_scene("free_box")
    engine = HapticEngine(scene, load_device("ideal"), load_user("constant_push"))
    assert engine.receive(encode_update(SimWorld(scene).local_model(7, 0, 0))) == ""
    for _ in range(5):
        row = engine.tick(1e-3, update_seq=0)
    back = decode_proxy(encode_proxy(row, engine.method))
    assert (back.epoch, back.update_seq, back.tick, back.method) == (7, 0, 4, 0)
    assert back.valid and back.haptic_time == row[0]["t"]
    np.testing.assert_array_equal(back.q, engine.state[0]["q"][:3])
    np.testing.assert_array_equal(back.qd, engine.state[0]["qd"][:3])
    np.testing.assert_array_equal(back.device_pose, engine.world_sensors[0]["pose"])


def test_derived_offsets_follow_the_table() -> None:
    """Everything derived from shared/protocol/layout.py agrees with it: contact columns are
    contiguous in table order, the row dtype has their widths, the header offsets add up to
    the struct, and the encoder's output has exactly update_size() bytes."""
    from haptic_local_model.shared.protocol import layout

    at = 0
    for column in layout.CONTACT_COLUMNS:
        assert layout.CONTACT_AT[column.name] == at
        assert layout.CONTACT_ROW_DTYPE.fields[column.name][1] == 8 * at
        at += column.width
    assert at == layout.CONTACT_FLOATS == layout.CONTACT_ROW_DTYPE.itemsize // 8
    assert layout.contact_floats(1) == layout.CONTACT_FLOATS_V1 < layout.CONTACT_FLOATS
    offsets = [layout.HEADER_AT[f.name] for f in layout.HEADER]
    assert offsets == sorted(offsets) and offsets[0] == 0
    assert layout.HEADER_STRUCT.size == layout.HEADER_BYTES
    for n_contacts, resisted in ((0, False), (2, True), (5, True)):
        u = sample_update(n_contacts, resisted)
        j = 0 if u.resisted is None else len(u.resisted)
        assert len(encode_update(u)) == layout.update_size(u.dof, j, n_contacts, u.flags)
    u = sample_with_shapes()
    assert len(encode_update(u)) == layout.update_size(3, 1, 2, u.flags, n_shapes=3)


def _encoded_from_record(raw: bytes) -> bytes:
    """The sim's compiled encoder run on the record the parser fills from `raw`."""
    from haptic_local_model.shared.protocol.update import UpdateParser, encode_record

    parser = UpdateParser()
    assert parser.parse(raw) == 0
    buf = np.zeros(len(raw) + 64, np.uint8)
    return buf[: encode_record(parser.out, buf)].tobytes()


@pytest.mark.parametrize(("n_contacts", "optional"), [(0, False), (2, True), (64, True)])
def test_compiled_encoder_writes_the_bytes_of_the_reference_encoder(
    n_contacts: int, optional: bool
) -> None:
    """encode_record (the sim's, compiled) gives encode_update's bytes: the golden update,
    and updates with and without the flagged sections."""
    assert _encoded_from_record(GOLDEN.read_bytes()) == GOLDEN.read_bytes()
    assert _encoded_from_record(GOLDEN_SHAPES.read_bytes()) == GOLDEN_SHAPES.read_bytes()
    assert _encoded_from_record(GOLDEN_CHAINS.read_bytes()) == GOLDEN_CHAINS.read_bytes()
    u = sample_update(n_contacts=n_contacts, resisted=optional)
    if not optional:
        u = LocalModelUpdate(**{**u.__dict__, "gravity": None, "velocity_torque": None})
    raw = encode_update(u)
    assert _encoded_from_record(raw) == raw


def test_the_sims_bytes_are_its_dataclass_encoded() -> None:
    """SimWorld.local_model_bytes and encode_update of SimWorld.local_model agree, in a scene
    with contacts, gravity and resisted directions."""
    from haptic_local_model.shared.config import load_scene
    from haptic_local_model.sim_server.world import SimWorld

    for scene in ("wall_slide", "linkage_middle", "testbed_free_tool"):
        world = SimWorld(load_scene(scene))
        for seq in range(3):
            world.step(None)
            raw = world.local_model_bytes(3, seq, 123, 0.01)
            assert raw == encode_update(world.local_model(3, seq, 123, 0.01)), scene

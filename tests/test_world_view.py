"""The sim's world for the live view: its messages (shared/protocol/world_view.py), what the
sim sends (sim_server/world_view.py), the board that carries them to the view
(haptic_server/view_board.py) and what the view draws or refuses (haptic_server/view_world.py)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from haptic_local_model.haptic_server.view_board import BOARD_SLOTS, SLOT_BYTES, ViewBoard
from haptic_local_model.haptic_server.view_world import WorldLayer, _strips, world_vertices
from haptic_local_model.shared.config import load_scene
from haptic_local_model.shared.protocol.update import MessageError
from haptic_local_model.shared.protocol.world_view import (
    HEADER_DTYPE,
    ROLE_DYNAMIC,
    ROLE_KINEMATIC,
    SHAPES_PERIOD_S,
    WorldPoses,
    WorldShapes,
    decode_world,
    encode_poses,
    encode_shapes,
)
from haptic_local_model.sim_server.world import SimWorld
from haptic_local_model.sim_server.world_view import WorldViewSource

EPOCH = 77
F4_M = 1e-6  # poses travel as float32: a few tenths of a micrometre at 0.1 m
PERIOD_S = 1.0 / 30.0


@pytest.fixture(scope="module")
def testbed() -> tuple[SimWorld, WorldViewSource]:
    world = SimWorld(load_scene("testbed"))
    source = WorldViewSource(world.space, world.body_names, world.tool_bodies, EPOCH, 30.0)
    return world, source


def _by_name(shapes: WorldShapes) -> dict[str, int]:
    return {bytes(b["name"]).decode(): i for i, b in enumerate(shapes.bodies)}


def test_every_body_of_the_testbed_is_sent_with_its_role_and_pose(testbed: Any) -> None:
    world, source = testbed
    for _ in range(5):
        world.step(None)
    shapes_raw, poses_raw = source.due(100.0, 0.5)
    shapes, poses = decode_world(shapes_raw), decode_world(poses_raw)
    assert isinstance(shapes, WorldShapes) and isinstance(poses, WorldPoses)
    assert shapes.epoch == poses.epoch == EPOCH and poses.layout == shapes.layout
    names = _by_name(shapes)
    assert shapes.bodies["role"][names["block"]] == ROLE_DYNAMIC
    assert shapes.bodies["role"][names["shuttle"]] == ROLE_KINEMATIC
    for name, body in (("block", None), ("shuttle", None)):
        body = next(b for b, n in world.body_names.items() if n == name)
        pose = poses.poses[names[name]]
        assert math.hypot(pose["x"] - body.position.x, pose["y"] - body.position.y) < F4_M
        # the box's corners, moved by the pose, are centred on the body (an invariant)
        corners = world_vertices(shapes, poses)[shapes.shapes["body"] == names[name]][0, :4]
        assert np.allclose(corners.mean(axis=0), tuple(body.position), atol=F4_M)
    # every shape of the space is sent, once
    assert len(shapes.shapes) == len(world.space.shapes)


def test_shapes_once_then_poses_at_the_rate(testbed: Any) -> None:
    _world, _ = testbed
    source = WorldViewSource(_world.space, _world.body_names, _world.tool_bodies, EPOCH, 30.0)
    kinds = []
    for k in range(int(2.5 / 0.001)):  # a step every millisecond for 2.5 s
        kinds += [decode_world(m).__class__.__name__ for m in source.due(k * 0.001, 0.0)]
    poses, shapes = kinds.count("WorldPoses"), kinds.count("WorldShapes")
    assert abs(poses - 2.5 / PERIOD_S) <= 1
    assert shapes == 1 + int(2.5 / SHAPES_PERIOD_S)  # the first, then one a second


def _header_of(raw: bytes) -> np.ndarray:
    return np.frombuffer(raw, HEADER_DTYPE, 1).copy()


@pytest.mark.parametrize(
    ("mangle", "reason"),
    [
        (lambda raw: raw[:20], "size"),
        (lambda raw: b"XXXX" + raw[4:], "magic"),
        (lambda raw: raw[:-1], "size"),
        (lambda raw: raw + b"\0", "size"),
    ],
)
def test_a_malformed_message_is_refused_by_reason(testbed: Any, mangle: Any, reason: str) -> None:
    _, poses_raw = WorldViewSource(*_args(testbed)).due(0.0, 0.0)
    with pytest.raises(MessageError) as err:
        decode_world(mangle(poses_raw))
    assert err.value.reason == reason


def _args(testbed: Any) -> tuple[Any, ...]:
    world, _ = testbed
    return world.space, world.body_names, world.tool_bodies, EPOCH, 30.0


def test_a_pose_out_of_bounds_or_a_forged_layout_is_refused(testbed: Any) -> None:
    shapes_raw, poses_raw = WorldViewSource(*_args(testbed)).due(0.0, 0.0)
    poses = decode_world(poses_raw)
    assert isinstance(poses, WorldPoses)
    bad = poses.poses.copy()
    bad[0]["x"] = np.nan
    with pytest.raises(MessageError, match="finite"):
        decode_world(encode_poses(WorldPoses(EPOCH, poses.layout, 0.0, bad)))
    shapes = decode_world(shapes_raw)
    assert isinstance(shapes, WorldShapes)
    negative = shapes.shapes.copy()
    negative[0]["radius"] = -0.01
    with pytest.raises(MessageError, match="negative radius"):
        decode_world(encode_shapes(WorldShapes(EPOCH, shapes.layout, 0.0, shapes.bodies, negative)))
    forged = bytearray(shapes_raw)
    forged[-4:] = np.float32(0.5).tobytes()  # a vertex moved, the layout id kept
    with pytest.raises(MessageError) as err:
        decode_world(bytes(forged))
    assert err.value.reason == "layout"


class _Log:
    def __init__(self) -> None:
        self.paths: list[str] = []

    def __call__(self, path: str, archetype: Any, static: bool = False) -> None:
        self.paths.append(path)


def test_the_layer_draws_the_installed_epoch_and_counts_the_rest(testbed: Any) -> None:
    shapes_raw, poses_raw = WorldViewSource(*_args(testbed)).due(0.0, 0.0)
    foreign_shapes, foreign_poses = WorldViewSource(*_args(testbed)[:3], EPOCH + 1, 30.0).due(
        0.0, 0.0
    )
    log = _Log()
    layer = WorldLayer(log)
    layer.take(poses_raw, EPOCH)  # poses before their shapes: nothing to draw them with
    layer.take(b"\x00" * 7, EPOCH)
    layer.take(foreign_shapes, EPOCH)
    layer.take(shapes_raw, EPOCH)
    layer.take(foreign_poses, EPOCH)
    layer.take(poses_raw, EPOCH)
    assert layer.refused == {"layout": 1, "size": 1, "epoch": 2}
    assert layer.drawn == 1
    assert "world/bodies/moving" in log.paths and "world/bodies/static" in log.paths
    layer.take(poses_raw, EPOCH)  # the walls once per layout
    assert log.paths.count("world/bodies/static") == 1 and layer.drawn == 2


def test_the_strips_are_the_bodies_where_the_sim_has_them(testbed: Any) -> None:
    world, _ = testbed
    shapes_raw, poses_raw = WorldViewSource(*_args(testbed)).due(0.0, 0.0)
    shapes, poses = decode_world(shapes_raw), decode_world(poses_raw)
    assert isinstance(shapes, WorldShapes) and isinstance(poses, WorldPoses)
    moving = shapes.bodies["role"][shapes.shapes["body"]] != 0
    strips, _radii, _colors, labels = _strips(shapes, world_vertices(shapes, poses), moving)
    block = next(b for b, n in world.body_names.items() if n == "block")
    outline = np.array(strips[labels.index("block")])
    assert len(outline) == 5 and np.allclose(outline[0], outline[-1])  # a closed box
    assert np.allclose(outline[:4].mean(axis=0), tuple(block.position), atol=F4_M)


def test_the_board_keeps_the_newest_messages_and_counts_the_too_long() -> None:
    board = ViewBoard.create()
    try:
        reader = ViewBoard.attach(board.name, own_tracker=False)  # this process made it
        for i in range(BOARD_SLOTS + 3):
            assert board.post(bytes([i]) * (i + 1), tick=100 + i)
        messages, seen = reader.read_since(0)
        assert seen == BOARD_SLOTS + 3
        # the oldest overwritten; the slot the writer would take next is not read
        assert [t for t, _ in messages] == [100 + i for i in range(4, BOARD_SLOTS + 3)]
        assert all(raw == bytes([t - 100]) * (t - 99) for t, raw in messages)
        assert not board.post(b"\0" * (SLOT_BYTES + 1), tick=0)
        assert int(board.ctl[1]) == 1 and reader.read_since(seen)[0] == []
        reader.close()
    finally:
        board.close()

"""The port view's pieces without a browser (haptic_server/port_view.py): the newest
finished row of the shared rows, and a box's outline at a pose."""

from __future__ import annotations

import math

import numpy as np
import pytest

from haptic_local_model.haptic_server.port_view import PortRows, box_outline
from haptic_local_model.haptic_server.ports import PORT_ROW_DTYPE
from haptic_local_model.shared.config import BodySpec


def test_newest_is_the_row_before_the_last_written() -> None:
    shared = PortRows(10, PORT_ROW_DTYPE)
    try:
        assert shared.newest() == -1
        shared.rows["t"][:1] = 0.001  # the first tick written, maybe not finished
        assert shared.newest() == -1
        shared.rows["t"][:4] = np.arange(1, 5) * 1e-3
        assert shared.newest() == 2
    finally:
        shared.close(unlink=True)


def test_newest_follows_a_ring_past_its_wrap() -> None:
    """The shared world's and a station's rows are a ring: past its end the newest finished
    row is the one before the latest time, wherever it lies."""
    shared = PortRows(5, PORT_ROW_DTYPE)
    try:
        shared.rows["t"][:] = [6e-3, 7e-3, 3e-3, 4e-3, 5e-3]  # 7 written: row 1 the latest
        assert shared.newest() == 0
        shared.rows["t"][0] = 8e-3  # row 0 the latest: the one before is the ring's last
        assert shared.newest() == 4
    finally:
        shared.close(unlink=True)


def test_box_outline_is_the_box_turned_and_moved() -> None:
    body = BodySpec(name="box", kind="dynamic", shape="box", material="pad", size=(0.04, 0.02))
    strip = np.array(box_outline(body, 0.1, -0.2, math.pi / 2))
    assert strip.shape == (5, 2) and np.allclose(strip[0], strip[-1])
    # a quarter turn: the 4 cm side along y, centred on the pose
    assert np.ptp(strip[:, 0]) == pytest.approx(0.02) and np.ptp(strip[:, 1]) == pytest.approx(0.04)
    assert strip[:4].mean(axis=0) == pytest.approx([0.1, -0.2])


def test_a_hands_drawing_is_its_chains_link_frames() -> None:
    """hand_strips against the hand's own chain through shared.kinematics.link_frames (the
    compiled kinematics the hand steps with), at seeded random joint coordinates: the palm's
    centre and angle, each phalanx's joint and the finger's tip."""
    from haptic_local_model.haptic_server.port_view import hand_strips
    from haptic_local_model.haptic_server.stages.hand import hand_chain
    from haptic_local_model.haptic_server.world_runs import port_scene
    from haptic_local_model.shared.kinematics import MAX_DOF, link_frames
    from haptic_local_model.shared.port_config import HandSceneConfig

    scene = port_scene("hand_grasp", None, None).config
    assert isinstance(scene, HandSceneConfig)
    hand = scene.hand_of(1)
    chain = hand_chain(hand)[0]
    rng = np.random.default_rng(51)
    pos, ang = np.zeros((MAX_DOF, 2)), np.zeros(MAX_DOF)
    for _ in range(20):
        q = np.zeros(MAX_DOF)
        q[: hand.dof] = rng.uniform(-1.0, 1.0, hand.dof) * np.r_[0.05, 0.05, [3.0] * (hand.dof - 2)]
        link_frames(chain, q, hand.dof, pos, ang)
        palm, fingers = hand_strips(hand, q)
        assert np.mean(palm[:4], axis=0) == pytest.approx(pos[2], abs=1e-12)
        edge = np.subtract(palm[1], palm[0])  # the palm's width, along its angle
        assert math.atan2(edge[1], edge[0]) == pytest.approx(ang[2], abs=1e-12)
        for i, finger in enumerate(fingers):
            j1, j2 = 3 + 2 * i, 4 + 2 * i
            assert finger[1] == pytest.approx(tuple(pos[j2]), abs=1e-12)
            tip = pos[j2] + hand.fingers[i].lengths[1] * np.array(
                [np.cos(ang[j2]), np.sin(ang[j2])]
            )
            assert finger[2] == pytest.approx(tuple(tip), abs=1e-12)
            assert finger[0] == pytest.approx(tuple(pos[j1]), abs=1e-12)


def test_the_port_view_draws_every_world_kind_haptic_run_runs() -> None:
    from haptic_local_model.haptic_server.port_view import viewed_kinds
    from haptic_local_model.haptic_server.world_runs import WORLD_KINDS

    assert viewed_kinds() == WORLD_KINDS

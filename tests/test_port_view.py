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


def test_box_outline_is_the_box_turned_and_moved() -> None:
    body = BodySpec(name="box", kind="dynamic", shape="box", material="pad", size=(0.04, 0.02))
    strip = np.array(box_outline(body, 0.1, -0.2, math.pi / 2))
    assert strip.shape == (5, 2) and np.allclose(strip[0], strip[-1])
    # a quarter turn: the 4 cm side along y, centred on the pose
    assert np.ptp(strip[:, 0]) == pytest.approx(0.02) and np.ptp(strip[:, 1]) == pytest.approx(0.04)
    assert strip[:4].mean(axis=0) == pytest.approx([0.1, -0.2])


def test_a_world_the_port_view_does_not_draw_is_refused_by_name() -> None:
    from haptic_local_model.haptic_server.live_view import ViewAddress
    from haptic_local_model.haptic_server.world_runs import port_scene, run_port_scene
    from haptic_local_model.shared.config import ConfigError

    with pytest.raises(ConfigError, match="hand_grasp"):
        run_port_scene(port_scene("hand_grasp", None, None), 1.0, "real", None, ViewAddress())

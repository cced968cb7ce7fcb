"""Moving worlds on the one clock (issue 47), graded against the motion laws on the haptic
side's clock, not against the shapes it rendered (benchmarks/moving_world.py prints the same
figures at 30, 60 and 120 Hz): a stuck finger rides a platform and a belt, a held finger is
never inside a wall approaching at 0.05 or 0.5 m/s nor inside a spinning box, and sliding on
a moving surface feels mu_k (kinetic friction in the surface's frame)."""

from __future__ import annotations

import pytest

from haptic_local_model.benchmarks.moving_world import (
    DEPTH_TARGET_M,
    MU_REL_TARGET,
    SLIP_TARGET_M,
    approaching_wall,
    rotating_box,
    sliding,
    stuck,
)


@pytest.mark.parametrize("kind", ["platform", "belt"])
def test_a_stuck_finger_rides_the_surface(kind: str) -> None:
    case = stuck(kind)
    assert case.figure <= SLIP_TARGET_M, case


@pytest.mark.parametrize("speed", [0.05, 0.5])
def test_a_held_finger_is_never_inside_an_approaching_wall(speed: float) -> None:
    case = approaching_wall(speed)
    assert "0 ticks" not in case.detail, "the wall never reached the finger"
    assert case.figure <= DEPTH_TARGET_M, case


def test_a_held_finger_is_never_inside_a_spinning_box() -> None:
    case = rotating_box()
    assert case.figure <= DEPTH_TARGET_M, case


@pytest.mark.parametrize("kind", ["belt", "platform"])
def test_sliding_on_a_moving_surface_feels_mu_k(kind: str) -> None:
    case = sliding(kind)
    assert case.figure <= MU_REL_TARGET, case

"""Seed 001's testbed with a free tool: pushing a free block, ramming a wall (issue 3)."""

from __future__ import annotations

import numpy as np

from haptic_local_model.haptic_server.harness.virtual import run_virtual_named
from haptic_local_model.shared.config import load_scene, load_user

WALL_FACE_Y = -0.145  # inner face of the bottom wall (segment at -0.15, radius 5 mm)
TOOL_HALF_HEIGHT = 0.015
RAM_SPEED = 0.5  # issue 3: pushing into a wall at 0.5 m/s never passes through
K_WALL = 15000.0
SIM_SLOP_M = 5e-4  # pymunk's own contact slop and solver penetration in the sim's tool


def test_the_tool_pushes_a_free_block_which_moves_in_pymunk() -> None:
    result = run_virtual_named("testbed_free_tool", "ideal", "push_block", 3.0)
    block = next(b for b in result.world.space.bodies if b.mass == 0.3)
    moved = block.position.x - 0.04
    assert moved > 0.03, f"block moved {moved * 1e3:.1f} mm"
    ticks = result.ticks
    assert ticks["n_active"].max() >= 1  # the user felt the block through the local model
    assert np.abs(ticks["contact_force_world"][:, 0]).max() > 0.1


def test_ramming_a_wall_at_half_a_metre_per_second_never_passes_through() -> None:
    result = run_virtual_named("testbed_free_tool", "ideal", "ram_wall", 1.5)
    ticks = result.ticks
    approach = -ticks["vm_twist"][:, 1].min()
    assert approach >= RAM_SPEED, f"approached at only {approach:.2f} m/s"
    user = load_user("ram_wall")
    worst_depth = max(user.max_wrench[:2]) / K_WALL  # the hand's whole force on the wall
    bottom = ticks["vm_pose"][:, 1] - TOOL_HALF_HEIGHT
    assert bottom.min() > WALL_FACE_Y - worst_depth - 1e-4
    assert ticks["n_colliding"].max() >= 1  # the impact was resolved by an impulse
    sim_tool = result.world.tool_bodies[0].position
    assert sim_tool.y - TOOL_HALF_HEIGHT > WALL_FACE_Y - worst_depth - SIM_SLOP_M
    assert load_scene("testbed_free_tool").tool.neighbourhood_margin_m > RAM_SPEED / 60.0

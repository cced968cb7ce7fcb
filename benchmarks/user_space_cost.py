"""What building the local model costs in a user's own pymunk space of 1000 shapes, against
our `crowd` scene's (issue 44, done-when 3: at most 1.2 x).

Our side: the crowd scene's world (a thousand pebbles, a spatial hash), its plough moved into
the pebbles. The user's: a plain pymunk.Space as a user writes it (pymunk's default broad
phase, no sleeping): the same thousand circles on the same grid, four walls and a box tool
at the same place, touched through haptic_local_model.api's world. Each repeat times
`--builds` local models (built and encoded) of each, interleaved; prints the medians of the
per-build times (µs) and their ratio. The first repeat loads the kernels and is not counted.

    python -m haptic_local_model.benchmarks.user_space_cost [--repeats 15] [--builds 200]
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings

import numpy as np
import pymunk

from haptic_local_model.shared.config import load_scene
from haptic_local_model.sim_server.user_space import UserSpaceWorld
from haptic_local_model.sim_server.world import SimWorld

TARGET_RATIO = 1.2
TOOL_AT = (0.0, 0.0)  # among the pebbles: a neighbourhood of a dozen or so


def user_space(scene_world: SimWorld) -> tuple[pymunk.Space, pymunk.Body]:
    """A plain space holding the crowd world's pebbles (positions, radii, frictions), walls
    and a box tool as a user would build them."""
    space = pymunk.Space()
    space.collision_slop = 1.0e-4
    for body in scene_world.space.bodies:
        for shape in body.shapes:
            if shape.space is None or body in scene_world.tool_bodies:
                continue
            if isinstance(shape, pymunk.Circle) and body.body_type == pymunk.Body.DYNAMIC:
                b = pymunk.Body(body.mass, body.moment)
                b.position = body.position
                s: pymunk.Shape = pymunk.Circle(b, shape.radius)
                s.friction = shape.friction
                space.add(b, s)
    for a, b in (((-0.2, -0.2), (0.2, -0.2)), ((0.2, -0.2), (0.2, 0.2)),
                 ((0.2, 0.2), (-0.2, 0.2)), ((-0.2, 0.2), (-0.2, -0.2))):  # fmt: skip
        wall = pymunk.Segment(space.static_body, a, b, 0.005)
        wall.friction = 0.2
        space.add(wall)
    tool = pymunk.Body(0.5, pymunk.moment_for_box(0.5, (0.04, 0.015)))
    tool.position = TOOL_AT
    space.add(tool, pymunk.Poly.create_box(tool, (0.04, 0.015)))
    return space, tool


def _per_build_us(world: SimWorld | UserSpaceWorld, builds: int) -> float:
    started = time.perf_counter_ns()
    for seq in range(builds):
        world.local_model_bytes(1, seq, 0)
    return (time.perf_counter_ns() - started) / builds / 1e3


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--builds", type=int, default=200)
    args = parser.parse_args(argv)
    ours = SimWorld(load_scene("crowd"))
    ours.set_tool_state(np.array([*TOOL_AT, 0.0]), np.zeros(3))
    space, tool = user_space(ours)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        theirs = UserSpaceWorld(space, tool, margin_m=ours.scene.tool.neighbourhood_margin_m)
    crowd, user = [], []
    for r in range(args.repeats + 1):
        c, u = _per_build_us(ours, args.builds), _per_build_us(theirs, args.builds)
        if r:
            crowd.append(c)
            user.append(u)
    n_ours, n_theirs = ours.stats.contacts_sent, theirs.stats.contacts_sent
    print(f"shapes: crowd {len(ours.space.shapes)}, user space {len(space.shapes)}")
    print(f"contacts sent: crowd {n_ours}, user space {n_theirs}")
    mc, mu = float(np.median(crowd)), float(np.median(user))
    print(
        f"local model per build, median of {args.repeats} x {args.builds}: crowd {mc:.1f} µs "
        f"(min {min(crowd):.1f}, max {max(crowd):.1f}), user space {mu:.1f} µs "
        f"(min {min(user):.1f}, max {max(user):.1f}); ratio {mu / mc:.2f} "
        f"(target <= {TARGET_RATIO})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""pymunk's `box2d_vertical_stack` example, touchable: its space in pixels, and a disc the hand
holds in it.

The space-building code is the example's own (`pymunk.examples.box2d_vertical_stack`,
`create_world`: five columns of ten 20-pixel boxes of mass 10 beside a wall, gravity -900),
unchanged, in pixels, without its pyglet window. The lines that make it touchable are marked
`# touchable` (7 lines): the import, the units of the example's space (a pixel a millimetre,
a mass of 10 a tenth of a kilogram) and the call that rescales it to SI, the held disc (three
lines) beside the first column, and `run_offline`. The `push_block` user pushes it 12 cm into
the stack. Run it:

    python examples/touch_vertical_stack.py --seconds 5 --log runs/stack.mcap
    python examples/touch_vertical_stack.py --live --seconds 10 --log runs/live.mcap
    haptic-replay runs/stack.mcap
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
import pymunk
from pymunk import Vec2d

from haptic_local_model import api  # touchable


def create_world() -> pymunk.Space:
    """The example's `create_world`, its space in pixels."""
    space = pymunk.Space()
    space.gravity = Vec2d(0.0, -900.0)
    space.sleep_time_threshold = 0.3

    static_lines = [
        pymunk.Segment(space.static_body, Vec2d(20, 55), Vec2d(600, 55), 1),
        pymunk.Segment(space.static_body, Vec2d(550, 55), Vec2d(550, 400), 1),
    ]
    for line in static_lines:
        line.friction = 0.3
    space.add(*static_lines)

    for x in range(5):
        for y in range(10):
            size = 20
            mass = 10.0
            moment = pymunk.moment_for_box(mass, (size, size))
            body = pymunk.Body(mass, moment)
            body.position = Vec2d(300 + x * 50, 105 + y * (size + 0.1))
            shape = pymunk.Poly.create_box(body, (size, size))
            shape.friction = 0.3
            space.add(body, shape)
    return space


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--device", default="ideal")
    parser.add_argument("--user", default="push_block")
    parser.add_argument("--log", default=None, help="write the run to this MCAP file")
    parser.add_argument("--live", action="store_true", help="in real time: the haptic server")
    args = parser.parse_args(argv)
    space = create_world()
    units = api.Units(metres_per_unit=1.0e-3, kg_per_unit=0.01)  # touchable
    api.scale_space(space, units)  # touchable: the space in metres and kilograms
    hand = pymunk.Body(1.0, 1.0e-3)  # touchable: 1 kg, 1e-3 kg m^2 (the ideal device's)
    hand.position = (0.26, 0.115)  # touchable: 2 cm left of the first column, in metres
    space.add(hand, pymunk.Circle(hand, 0.01))  # touchable
    if args.live:  # the same space, touched in real time (api.run_live)
        live = api.run_live(
            space, hand, args.seconds, device=args.device, user=args.user, log=args.log
        )
        print(live.report())
        return 0
    run = api.run_offline(  # touchable: one call
        space, hand, args.seconds, device=args.device, user=args.user, log=args.log
    )
    force = np.hypot(run.wrench_command[:, 0], run.wrench_command[:, 1])
    touching = float(np.mean(run.n_contacts > 0))
    moved = max(abs(b.position.x - x) for b, x in zip(space.bodies, _start_x(), strict=False))
    print(
        f"{args.seconds:g} s at {run.speedup:.0f}x real time: {run.updates} local models, "
        f"touching {100 * touching:.0f} % of ticks, peak force {force.max():.2f} N, "
        f"faults {int(np.count_nonzero(run.faults))}, boxes moved up to {1000 * moved:.0f} mm"
    )
    return 0


def _start_x() -> list[float]:
    """Each box's starting x in metres (the example's order)."""
    return [(300 + x * 50) * 1.0e-3 for x in range(5) for _ in range(10)]


if __name__ == "__main__":
    sys.exit(main())

"""pymunk's `box2d_pyramid` example, touchable: its space in pixels, and a disc the hand holds
in it.

The space-building code is the example's own (`pymunk.examples.box2d_pyramid`,
`PyramidDemo.__init__`: a pyramid of 325 boxes of 20 pixels and mass 1 on a ground segment,
gravity -900), unchanged, in pixels, without its pygame window. The lines that make it
touchable are marked `# touchable` (7 lines): the import, the units of the example's space (a
pixel a millimetre, a mass of 1 a tenth of a kilogram) and the call that rescales it to SI, the
held disc (three lines) at the pyramid's left foot, and `run_offline`. The `push_block` user
pushes it 12 cm into the pyramid. Run it:

    python examples/touch_pyramid.py --seconds 5 --log runs/pyramid.mcap
    python examples/touch_pyramid.py --live --seconds 10 --log runs/live.mcap
    haptic-replay runs/pyramid.mcap
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
import pymunk
from pymunk import Vec2d

from haptic_local_model import api  # touchable


def create_space() -> pymunk.Space:
    """The example's space (`PyramidDemo.__init__`), in pixels."""
    space = pymunk.Space()
    space.gravity = (0.0, -900.0)
    space.sleep_time_threshold = 0.3
    ### ground
    shape = pymunk.Segment(space.static_body, (5, 100), (595, 100), 1.0)
    shape.friction = 1.0
    space.add(shape)

    ### pyramid
    x = Vec2d(-270, 7.5) + Vec2d(300, 100)
    y = Vec2d(0, 0)
    deltaX = Vec2d(0.5625, 1.1) * 20
    deltaY = Vec2d(1.125, 0.0) * 20

    for i in range(25):
        y = Vec2d(*x)
        for _j in range(i, 25):
            size = 10
            points = [(-size, -size), (-size, size), (size, size), (size, -size)]
            mass = 1.0
            moment = pymunk.moment_for_poly(mass, points, (0, 0))
            body = pymunk.Body(mass, moment)
            body.position = y
            shape = pymunk.Poly(body, points)
            shape.friction = 1
            space.add(body, shape)

            y += deltaY

        x += deltaX
    return space


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--device", default="ideal")
    parser.add_argument("--user", default="push_block")
    parser.add_argument("--log", default=None, help="write the run to this MCAP file")
    parser.add_argument("--live", action="store_true", help="in real time: the haptic server")
    args = parser.parse_args(argv)
    space = create_space()
    units = api.Units(metres_per_unit=1.0e-3, kg_per_unit=0.1)  # touchable
    api.scale_space(space, units)  # touchable: the space in metres and kilograms
    hand = pymunk.Body(1.0, 1.0e-3)  # touchable: 1 kg, 1e-3 kg m^2 (the ideal device's)
    hand.position = (0.0, 0.1175)  # touchable: 1 cm left of the bottom row, in metres
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
    print(
        f"{args.seconds:g} s at {run.speedup:.0f}x real time: {run.updates} local models, "
        f"touching {100 * touching:.0f} % of ticks, peak force {force.max():.2f} N, "
        f"faults {int(np.count_nonzero(run.faults))}, "
        f"{len(space.shapes)} shapes, hand at x {1000 * hand.position.x:.0f} mm"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())

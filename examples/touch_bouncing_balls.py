"""pymunk's `bouncing_balls` example, touchable: its space, and a disc the hand holds in it.

The space and its loop are the example's own (`pymunk.examples.bouncing_balls`: an L-shaped
static platform; a ball of elasticity 0.95 and friction 0.9 dropped every 100 steps at a
random x, the first after 10; balls that fall off removed), without its pygame window and in
SI units: 1 pixel = 1 mm, y up (y_m = (600 - y_px) / 1000), its 10-unit balls 0.1 kg, its
gravity 900 px/s^2 = 0.9 m/s^2, its random x from a seeded generator (a run is repeatable).

The lines that make it touchable are marked `# touchable` (6 lines). Run it:

    python examples/touch_bouncing_balls.py --seconds 5 --log runs/balls.mcap
    python examples/touch_bouncing_balls.py --live --seconds 10 --log runs/live.mcap
    haptic-replay runs/balls.mcap
"""

from __future__ import annotations

import argparse
import random
import sys

import numpy as np
import pymunk

from haptic_local_model import api  # touchable

BALL_MASS_KG, BALL_RADIUS_M = 0.1, 0.025


def build_space() -> pymunk.Space:
    """The example's space: the platform (`_add_static_scenery`)."""
    space = pymunk.Space()
    space.gravity = (0.0, -0.9)
    space.collision_slop = 1.0e-4  # pymunk's default (0.1) is for pixels
    lines = [
        pymunk.Segment(space.static_body, (0.111, 0.280), (0.407, 0.246), 0.0),
        pymunk.Segment(space.static_body, (0.407, 0.246), (0.407, 0.343), 0.0),
    ]
    for line in lines:
        line.elasticity = 0.95
        line.friction = 0.9
    space.add(*lines)
    return space


class Balls:
    """The example's `_update_balls`, once a step: a ball every 100 steps, the fallen removed."""

    def __init__(self, space: pymunk.Space, seed: int = 0) -> None:
        self.space, self.random = space, random.Random(seed)
        self.balls: list[pymunk.Circle] = []
        self.ticks_to_next_ball = 10

    def update(self, _t: float = 0.0) -> None:
        self.ticks_to_next_ball -= 1
        if self.ticks_to_next_ball <= 0:
            self.create_ball()
            self.ticks_to_next_ball = 100
        for ball in [b for b in self.balls if b.body.position.y < 0.1]:
            self.space.remove(ball, ball.body)
            self.balls.remove(ball)

    def create_ball(self) -> None:
        moment = pymunk.moment_for_circle(BALL_MASS_KG, 0, BALL_RADIUS_M, (0, 0))
        body = pymunk.Body(BALL_MASS_KG, moment)
        body.position = self.random.randint(115, 350) / 1000.0, 0.400
        shape = pymunk.Circle(body, BALL_RADIUS_M, (0, 0))
        shape.elasticity = 0.95
        shape.friction = 0.9
        self.space.add(body, shape)
        self.balls.append(shape)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--device", default="ideal")
    parser.add_argument("--user", default="swing")
    parser.add_argument("--log", default=None, help="write the run to this MCAP file")
    parser.add_argument("--live", action="store_true", help="in real time: the haptic server")
    args = parser.parse_args(argv)
    space = build_space()
    balls = Balls(space)
    hand = pymunk.Body(1.0, 1.0e-3)  # touchable: 1 kg, 1e-3 kg m^2 (the ideal device's)
    hand.position = (0.25, 0.33)  # touchable
    space.add(hand, pymunk.Circle(hand, 0.01))  # touchable
    each_step = api.TouchOptions(after_step=balls.update)  # touchable: the example's loop
    if args.live:  # the same space, touched in real time (api.run_live)
        live = api.run_live(
            space,
            hand,
            args.seconds,
            device=args.device,
            user=args.user,
            log=args.log,
            options=each_step,
        )
        print(live.report())
        return 0
    run = api.run_offline(  # touchable
        space,
        hand,
        args.seconds,
        device=args.device,
        user=args.user,
        log=args.log,
        options=each_step,
    )
    force = np.hypot(run.wrench_command[:, 0], run.wrench_command[:, 1])
    touching = float(np.mean(run.n_contacts > 0))
    print(
        f"{args.seconds:g} s at {run.speedup:.0f}x real time: {run.updates} local models, "
        f"touching {100 * touching:.0f} % of ticks, peak force {force.max():.2f} N, "
        f"faults {int(np.count_nonzero(run.faults))}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Notebook-style: touch a pymunk space offline, then plot from its log the force the device
rendered against the user's push.

Run it whole (`python examples/plot_touch_force.py --out runs/touch_force.png`), or cell by
cell (`# %%`) in an editor that runs cells. The space is a wall 4 cm to the right of a held
disc; the simulated `push_block` user drags its hand 12 cm to the right on a 150 N/m spring,
so while the disc rests on the wall the device holds the user's whole spring force:
F = -150 N/m x (x_hand - x_device). The script prints the rendered force against that.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # a file, no window: this also runs on a machine without a display
import matplotlib.pyplot as plt
import numpy as np
import pymunk

from haptic_local_model import api

USER_STIFFNESS = 150.0  # N/m: configs/users/push_block.toml, whose hand moves along x
USER_PATH = ((0.0, 0.2, 1.7), (0.0, 0.0, 0.12))  # its waypoints: times (s), x (m)


# %% your space: a wall, and the disc the hand holds (SI units)
def make_space() -> tuple[pymunk.Space, pymunk.Body]:
    space = pymunk.Space()
    space.collision_slop = 1e-4  # pymunk's default 0.1 assumes pixels
    wall = pymunk.Segment(space.static_body, (0.05, -0.1), (0.05, 0.1), 0.005)
    wall.friction = 0.4
    space.add(wall)
    hand = pymunk.Body(1.0, 1.0e-3)  # 1 kg, 1e-3 kg m^2: the device's own order
    space.add(hand, pymunk.Circle(hand, 0.01))
    return space, hand


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--out", type=Path, default=Path("runs/touch_force.png"))
    args = parser.parse_args(argv)

    # %% run it on the virtual clock, logged
    space, hand = make_space()
    log = Path(tempfile.mkdtemp(prefix="touch-force-")) / "touch.mcap"
    api.run_offline(space, hand, args.seconds, user="push_block", log=log)

    # %% the log as arrays by field, with units
    ticks = api.read_arrays(log).ticks
    t = ticks["t"]  # s
    force = ticks["wrench_command"][:, 0]  # N, what the device was commanded along x
    x_device = ticks["device_pose"][:, 0]  # m
    hand_x = np.interp(t, *USER_PATH)  # where the user's hand is
    pushed = -USER_STIFFNESS * (hand_x - x_device)  # its spring, which a resting device holds

    # %% the force against time, and the user's spring it holds once resting on the wall
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.plot(t, force, label="device command x (N)")
    ax.plot(t, pushed, "--", label="the user's spring, -150 N/m x (x_hand - x_device)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("force (N)")
    ax.legend()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=120, bbox_inches="tight")
    plt.close(fig)

    # %% the last half second: the rendered force against the user's spring
    rest = t >= t[-1] - 0.5
    print(f"rendered {force[rest].mean():+.3f} N, the user's spring {pushed[rest].mean():+.3f} N"
          f" over the last 0.5 s; plot: {args.out}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())

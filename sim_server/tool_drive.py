"""The tool's drive toward the haptic side's target, for any space the sim steps: the
records `step_world` reads (the target, the kinematic bodies, its scratch) and one period
from a ToolTarget. The scene's world (world.py) and a user's own space (user_space.py)
both drive their tools through it (the compiled step: drive.py)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from haptic_local_model.sim_server.drive import (
    DRIVE_REST,
    TARGET_DTYPE,
    drive_work,
    set_target,
    step_world,
)

if TYPE_CHECKING:
    from haptic_local_model.sim_server.world import ToolTarget


class ToolDrive:
    """The drive's records: a TARGET_DTYPE[1] target, the kinematic bodies
    (KINEMATIC_DTYPE[k]) it moves and its scratch, with the scene's train (None: none)."""

    def __init__(self, kinematic: np.ndarray, train: np.ndarray | None = None) -> None:
        self.target = np.zeros(1, TARGET_DTYPE)
        self.kinematic = kinematic
        self.work = drive_work(train)

    def aim(self, target: ToolTarget | None, mode: int) -> bool:
        """The next period's target: `target` in `mode` (DRIVE_PROXY, DRIVE_DEVICE) if it is
        fresh, else the tool held at rest. True: a fresh target was taken."""
        if target is None or not target.fresh:
            self.target[0]["mode"] = DRIVE_REST
            return False
        set_target(self.target, mode, target.q, target.qd, target.device_pose, target.device_twist)
        return True

    def step(
        self, tool: np.ndarray, chain: np.ndarray, time: float, period: float, substeps: int
    ) -> None:
        """One period of `substeps` steps of the tool's space from `time` (one compiled call)."""
        step_world(tool, self.target, chain, self.kinematic, time, period, substeps, self.work)

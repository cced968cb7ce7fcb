"""The sim refuses proxy states it could not have caused (docs/security.md).

The sim drives its tool toward the proxy the haptic server reports. A proxy state that
jumps farther than the tool could move would make the drive fling the tool, and the sim
would then publish updates the haptic server must refuse. A decoded, well-formed proxy state
is taken only if its proxy (and, for virtual_coupling_foh, its device) lies within reach:

- of the previous proxy state taken: the scene's speed bound times the time between them
  (haptic clock, at most the time between their receipts plus a publish period), or
- of the sim's own tool as the update the haptic side last installed left it: the speed
  bound times the time since that update's publication (the re-initialisation after a
  watchdog trip or a new haptic server lands there),

and if it moves no faster than the scene allows (the operational point's speed and every
link's spin, the bounds of the scene's [safety] table, as the haptic side checks updates).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from haptic_local_model.shared.config import SceneConfig
from haptic_local_model.shared.kinematics import (
    MAX_DOF,
    fastest_spin,
    link_frames,
    point_jacobian,
    point_on_link,
)
from haptic_local_model.shared.protocol.proxy import ProxyState
from haptic_local_model.shared.tool_chain import tool_bounds, tool_chain

#: published updates whose tool pose the sim remembers (4 s at 60 Hz)
REMEMBERED_UPDATES = 256
#: slack on every reach (m, rad): rounding, and the operational point's own extent
REACH_SLACK = 2.0e-3
#: a proxy's time may run ahead of the receipts by at most this (s): one publish period of
#: the slowest proxy rate plus jitter
TIME_SLACK_S = 0.05


@dataclass
class Taken:
    """The last proxy state taken: its operational point and device pose, its times."""

    pose: np.ndarray
    device_pose: np.ndarray
    haptic_time: float
    received_ns: int


class ProxyCheck:
    """The scene's reach, the sim's recent tool poses, and the last proxy state taken."""

    def __init__(self, scene: SceneConfig) -> None:
        self._chain = tool_chain(scene)
        bounds = tool_bounds(scene)  # the proxy's: the haptic side's guard trips beyond them
        self.max_speed, self.max_spin = bounds.speed, bounds.spin
        self._published: OrderedDict[int, tuple[np.ndarray, int]] = OrderedDict()
        self._taken: Taken | None = None
        self._frame_pos = np.zeros((MAX_DOF, 2))
        self._frame_angle = np.zeros(MAX_DOF)
        self._jac = np.zeros((3, MAX_DOF))
        self._point = np.zeros(2)
        self.refused = 0

    def published(self, seq: int, tool_pose: np.ndarray, publish_ns: int) -> None:
        """The sim published update `seq` with its tool's operational point at tool_pose."""
        self._published[seq] = (np.array(tool_pose, dtype=float), publish_ns)
        while len(self._published) > REMEMBERED_UPDATES:
            self._published.popitem(last=False)

    def restart(self) -> None:
        """A new epoch: nothing taken yet, nothing published."""
        self._published.clear()
        self._taken = None

    def take(self, proxy: ProxyState, now_ns: int) -> bool:
        """True if the proxy state is one the sim could have caused (and remember it)."""
        d = self._chain.dof
        if proxy.q.shape[0] != d:
            return self._refuse()
        pose, twist = self._operational(proxy.q, proxy.qd)
        if math.hypot(twist[0], twist[1]) > self.max_speed or self._spin(proxy.qd) > self.max_spin:
            return self._refuse()
        if not (self._near_taken(proxy, pose, now_ns) or self._near_update(proxy, pose, now_ns)):
            return self._refuse()
        self._taken = Taken(pose, proxy.device_pose.copy(), proxy.haptic_time, now_ns)
        return True

    def _refuse(self) -> bool:
        self.refused += 1
        return False

    def _within(self, a: np.ndarray, b: np.ndarray, dt: float) -> bool:
        moved = math.hypot(a[0] - b[0], a[1] - b[1])
        turned = abs(a[2] - b[2])
        return (
            moved <= self.max_speed * dt + REACH_SLACK
            and turned <= self.max_spin * dt + REACH_SLACK
        )

    def _near_taken(self, proxy: ProxyState, pose: np.ndarray, now_ns: int) -> bool:
        taken = self._taken
        if taken is None:
            return False
        dt = proxy.haptic_time - taken.haptic_time
        if not 0.0 <= dt <= (now_ns - taken.received_ns) / 1e9 + TIME_SLACK_S:
            return False
        return self._within(pose, taken.pose, dt) and self._within(
            proxy.device_pose, taken.device_pose, dt
        )

    def _near_update(self, proxy: ProxyState, pose: np.ndarray, now_ns: int) -> bool:
        known = self._published.get(proxy.update_seq)
        if known is None:
            return False
        tool_pose, publish_ns = known
        return self._within(pose, tool_pose, max(0.0, (now_ns - publish_ns) / 1e9))

    def _operational(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = self._chain.chain[0]
        d = self._chain.dof
        qq = np.zeros(MAX_DOF)
        qq[:d] = q
        link_frames(c, qq, d, self._frame_pos, self._frame_angle)
        link = self._chain.op_link
        point_on_link(self._frame_pos, self._frame_angle, link, self._chain.op_point, self._point)
        point_jacobian(c, self._frame_pos, d, link, self._point[0], self._point[1], self._jac)
        pose = np.array([self._point[0], self._point[1], self._frame_angle[link]])
        return pose, self._jac[:, :d] @ qd

    def _spin(self, qd: np.ndarray) -> float:
        c = self._chain.chain[0]
        return float(fastest_spin(c["joint_types"][: qd.shape[0]], c["parents"][: qd.shape[0]], qd))

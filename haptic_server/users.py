"""Simulated users ("hands", DESIGN §5): a constant wrench, a spring-damper hand that
follows waypoints relative to where the device started, or one that follows a pointer (a
mouse or a gamepad through `haptic-pointer`): its newest target, relative to the same start.

A pointer's target is written by the I/O sidecar (another process) into this record, which
then lives in the loop's shared block (haptic_server.mailbox): into the slot of `targets`
the loop is not reading, then `target_index` flips to it. A read mixes two targets only if
two posts land within the loop's read of three floats (posts come at most every input
frame, a millisecond or more apart); even then the hand's force stays clipped."""

from __future__ import annotations

import numpy as np
from numba import njit

from haptic_local_model.shared.config import UserConfig

MAX_WAYPOINTS = 64
USER_CONSTANT = 0
USER_WAYPOINTS = 1
USER_GIVEN = 2  # the hand's wrench is set from outside each tick (a replay's logged hand)
USER_POINTER = 3  # the hand follows the newest pointer target (targets[target_index])
KINDS = {"constant_wrench": USER_CONSTANT, "waypoints": USER_WAYPOINTS, "pointer": USER_POINTER}

USER_DTYPE = np.dtype(
    [
        ("kind", np.int64),
        ("wrench", np.float64, (3,)),
        ("stiffness", np.float64, (3,)),
        ("damping", np.float64, (3,)),
        ("max_wrench", np.float64, (3,)),
        ("n_waypoints", np.int64),
        ("waypoints", np.float64, (MAX_WAYPOINTS, 4)),  # t, dx, dy, dtheta
        ("start_pose", np.float64, (3,)),
        ("start_s", np.float64),  # the clock's time when the script starts
        ("device_pose", np.float64, (3,)),  # what the hand holds: the device's true pose
        ("device_twist", np.float64, (3,)),  # and twist, this tick
        ("target_index", np.int64),  # the slot of `targets` to read (pointer)
        ("targets", np.float64, (2, 3)),  # dx, dy, dtheta from start_pose (pointer)
    ]
)


def user_record(config: UserConfig) -> np.ndarray:
    """The user as a kernel record; waypoints beyond MAX_WAYPOINTS are rejected."""
    if len(config.waypoints) > MAX_WAYPOINTS:
        raise ValueError(f"waypoints: at most {MAX_WAYPOINTS} supported")
    rec = np.zeros(1, USER_DTYPE)
    u = rec[0]
    u["kind"] = KINDS[config.kind]
    u["wrench"] = config.wrench
    u["stiffness"] = config.stiffness
    u["damping"] = config.damping
    u["max_wrench"] = config.max_wrench
    u["n_waypoints"] = len(config.waypoints)
    if config.waypoints:
        u["waypoints"][: len(config.waypoints)] = np.array(config.waypoints)
    return rec


@njit(cache=True)
def hand_wrench(user, t, pose, twist, out):
    """The hand's wrench on the device at time t for the device's true pose and twist."""
    u = user[0]
    if u.kind == USER_GIVEN:
        return
    if u.kind == USER_CONSTANT:
        for c in range(3):
            out[c] = u.wrench[c]
        return
    if u.kind == USER_POINTER:
        target = u.targets[u.target_index]
        for c in range(3):
            out[c] = _pull(u, c, target[c], pose, twist)
        return
    n = u.n_waypoints
    wp = u.waypoints
    k = 0
    while k + 1 < n and wp[k + 1, 0] <= t:
        k += 1
    for c in range(3):
        if t <= wp[0, 0] or k + 1 >= n:
            target = wp[k, c + 1] if t > wp[0, 0] else wp[0, c + 1]
        else:
            s = (t - wp[k, 0]) / (wp[k + 1, 0] - wp[k, 0])
            target = wp[k, c + 1] + s * (wp[k + 1, c + 1] - wp[k, c + 1])
        out[c] = _pull(u, c, target, pose, twist)


@njit(cache=True, inline="always")
def _pull(u, c, target, pose, twist):
    """The hand's spring-damper toward start + target on axis c, with its constant push
    (`wrench`: a hand that presses while it holds, a grasp's squeeze), clipped at its limit."""
    f = u.stiffness[c] * (u.start_pose[c] + target - pose[c]) - u.damping[c] * twist[c]
    if u.wrench[c] != 0.0:  # a hand with no push keeps the bits it always had (-0.0)
        f += u.wrench[c]
    return min(u.max_wrench[c], max(-u.max_wrench[c], f))

"""The virtual tool as the sim's kernels see it: its pymunk bodies, its chain, its parameters.

One record (`TOOL_DTYPE`) for the drive (sim_server/drive.py) and the local model
(sim_server/local_model.py), filled once when the world is built; `tool_state` reads the
tool's configuration back from Chipmunk (DESIGN §2: q = the pose of a free body, or the joint
angles of a linkage).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from haptic_local_model.shared.kinematics import MAX_DOF
from haptic_local_model.sim_server import chipmunk as cp

TOOL_BODY, TOOL_LINKAGE = 0, 1

I8, F8 = np.int64, np.float64

TOOL_DTYPE = np.dtype(
    [
        ("space", I8),  # cpSpace*
        ("kind", I8),  # TOOL_BODY or TOOL_LINKAGE
        ("dof", I8),
        ("bodies", I8, (MAX_DOF,)),  # cpBody* of the tool's bodies (one for a free body)
        ("gravity", F8, (2,)),  # m/s^2
        ("base_angle", F8),  # rad, of a linkage
        ("parents", I8, (MAX_DOF,)),  # the link each link hangs from, -1 the base
        ("op_link", I8),
        ("op_point", F8, (2,)),  # m, in the operational link's frame
        ("bandwidth_hz", F8),  # tracking bandwidth of the drive
        ("foh_stiffness", F8, (3,)),  # virtual_coupling_foh's K_spring
        ("foh_damping", F8, (3,)),  # and K_damp
        ("foh_relative", F8),  # 1: K_damp on the tool's velocity relative to the device's
        ("characteristic_length", F8),  # m: scales J_h's angular row before the SVD
        ("rank_tolerance", F8),  # relative to the largest singular value
        ("margin", F8),  # m: the neighbourhood margin
    ]
)


@njit(cache=True)
def tool_state(tool, q, qd):
    """The tool's q and qd read back from its pymunk bodies (a linkage's joint angles are the
    differences of its links' absolute angles and its parents', a root's from the base)."""
    t = tool[0]
    if t.kind == TOOL_BODY:
        b = t.bodies[0]
        q[0], q[1] = cp.body_position(b)
        q[2] = cp.body_angle(b)
        qd[0], qd[1] = cp.body_velocity(b)
        qd[2] = cp.body_angular_velocity(b)
        return
    for i in range(t.dof):
        up = t.parents[i]
        prev_angle = t.base_angle
        prev_rate = 0.0
        if 0 <= up < i:
            prev_angle = cp.body_angle(t.bodies[up])
            prev_rate = cp.body_angular_velocity(t.bodies[up])
        q[i] = cp.body_angle(t.bodies[i]) - prev_angle
        qd[i] = cp.body_angular_velocity(t.bodies[i]) - prev_rate

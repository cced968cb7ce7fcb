"""Array layouts of the haptic side: the installed local model, gains, state, scratch, log row.

Each is a numpy structured dtype; the loop holds one preallocated 1-element array of each
and the numba kernels read and write their fields in place (MJX-style static model and
mutable data). Sizes are fixed by MAX_DOF and MAX_CONTACTS so nothing is allocated per tick.
"""

from __future__ import annotations

import numpy as np

from device_models.base import AUX_SIZE
from shared.kinematics import MAX_DOF
from shared.wire import LOCAL_MODEL_DTYPE, MAX_CONTACTS

F8 = np.float64
I8 = np.int64

# Rendering methods (DESIGN §4), as stored in PARAMS_DTYPE.method.
METHOD_LOCAL_MODEL = 0
METHOD_IMPEDANCE_ONLY = 1
METHOD_VIRTUAL_COUPLING = 2
METHOD_VIRTUAL_COUPLING_FOH = 3
METHOD_IDS = {
    "local_model": METHOD_LOCAL_MODEL,
    "impedance_only": METHOD_IMPEDANCE_ONLY,
    "virtual_coupling": METHOD_VIRTUAL_COUPLING,
    "virtual_coupling_foh": METHOD_VIRTUAL_COUPLING_FOH,
}

# Fault codes written by the kernels into STATE_DTYPE.fault (and the log).
FAULT_NONE = 0
FAULT_NONFINITE = 1  # a NaN/Inf appeared in the command or the proxy: safe state at once

#: One installed local model (an update converted at the boundary), plus its contact state.
SLOT_DTYPE = LOCAL_MODEL_DTYPE

#: Gains and switches of the rendering (from the scene's [rendering] and the device limits).
PARAMS_DTYPE = np.dtype(
    [
        ("method", I8),
        ("coordination_stiffness", F8, (3,)),  # K_pc
        ("coordination_damping", F8, (3,)),  # B_pc
        ("penalty_stiffness", F8),  # k_j per unit device mass
        ("penalty_damping", F8),  # b_j
        ("desired_damping", F8, (3,)),  # b_d
        ("desired_stiffness", F8, (3,)),  # k_d
        ("impulses", I8),
        ("collision_speed", F8),
        ("friction_stiffness_ratio", F8),
        ("blend_s", F8),
        ("vc_stiffness", F8, (3,)),
        ("vc_damping", F8, (3,)),
        ("foh_stiffness", F8, (3,)),  # K_p of seed 002
        ("foh_damping", F8, (3,)),  # K_v
        ("foh_interpolate", I8),  # 1: first-order hold, 0: zero-order hold of the setpoint
        ("foh_gravity", F8, (3,)),  # f_g of seed 002 (world frame), added in every FOH tick
        ("safe_damping", F8, (3,)),  # the safe state: damping only
        ("safe_ramp_s", F8),
        ("max_wrench", F8, (3,)),  # device limits in the world frame: never exceeded
    ]
)

#: The proxy and everything the kernels carry from tick to tick.
STATE_DTYPE = np.dtype(
    [
        ("q", F8, (MAX_DOF,)),
        ("qd", F8, (MAX_DOF,)),
        ("blend", F8),  # weight of the newest slot, 0 -> 1 over blend_s after an install
        ("safe", F8),  # 0 normal ... 1 safe state (damping only)
        ("safe_target", F8),
        ("fault", I8),
        ("prev_device_twist", F8, (3,)),  # to predict the device's motion over a step
        ("impulse_carry", F8, (3,)),  # impulse (N s) held back by the device limits
        ("foh_goal", F8, (3,)),
        ("foh_step", F8, (3,)),
        ("foh_steps_left", I8),
    ]
)

#: Scratch space so the kernels never allocate.
SCRATCH_DTYPE = np.dtype(
    [
        ("frame_pos", F8, (MAX_DOF, 2)),
        ("frame_angle", F8, (MAX_DOF,)),
        ("jac_hand", F8, (3, MAX_DOF)),
        ("jac_point", F8, (3, MAX_DOF)),
        ("point", F8, (2,)),
        ("mass", F8, (MAX_DOF, MAX_DOF)),
        ("chol", F8, (MAX_DOF, MAX_DOF)),
        ("system", F8, (MAX_DOF, MAX_DOF)),
        ("stiff_q", F8, (MAX_DOF, MAX_DOF)),
        ("damp_q", F8, (MAX_DOF, MAX_DOF)),
        ("tau_contact", F8, (MAX_DOF,)),
        ("stiff_rel", F8, (MAX_DOF,)),  # sum J^T K v_rel of the contact springs
        ("tau_total", F8, (MAX_DOF,)),
        ("impulse_q", F8, (MAX_DOF,)),
        ("vec_a", F8, (MAX_DOF,)),
        ("vec_b", F8, (MAX_DOF,)),
        ("minv_jt", F8, (MAX_DOF, 3)),  # D^-1 J_h^T
        ("lambda_inv", F8, (3, 3)),
        ("n_colliding", I8),
        ("coll_rows", F8, (MAX_CONTACTS, MAX_DOF)),  # n_i^T J_c,i
        ("coll_target", F8, (MAX_CONTACTS,)),
        ("coll_index", I8, (MAX_CONTACTS,)),
        ("nnls_a", F8, (MAX_CONTACTS, MAX_CONTACTS)),
        ("nnls_lambda", F8, (MAX_CONTACTS,)),
        ("nnls_z", F8, (MAX_CONTACTS,)),
        ("nnls_w", F8, (MAX_CONTACTS,)),
        ("nnls_passive", I8, (MAX_CONTACTS,)),
        ("nnls_m", F8, (MAX_CONTACTS, MAX_CONTACTS)),
        ("nnls_rhs", F8, (MAX_CONTACTS,)),
        ("nnls_chol", F8, (MAX_CONTACTS, MAX_CONTACTS)),
        ("contact_force", F8, (2,)),  # world force of all contacts on the proxy this tick
    ]
)

#: One haptic tick as logged (ros1msg-compatible packed layout; docs/log-format.md).
TICK_DTYPE = np.dtype(
    [
        ("tick", np.uint64),
        ("t", F8),  # s since the loop started (virtual or wall clock)
        ("dt", F8),  # the step used this tick, s
        ("lateness_us", F8),
        ("work_us", F8),  # compute time of the previous tick
        ("update_epoch", np.int64),  # epoch of the newest installed update
        ("update_seq", np.int64),  # seq of the newest installed update (-1: none)
        ("dof", np.int32),  # entries of proxy_q / proxy_qd in use
        ("update_age_ms", F8),  # publish -> install latency of the newest update
        ("device_pose", F8, (3,)),  # measured, world frame
        ("device_twist", F8, (3,)),
        ("vm_pose", F8, (3,)),  # operational point on the VM (proxy)
        ("vm_twist", F8, (3,)),
        ("proxy_q", F8, (MAX_DOF,)),
        ("proxy_qd", F8, (MAX_DOF,)),
        ("hand_wrench", F8, (3,)),  # the simulated user's true wrench on the device
        ("hand_wrench_measured", F8, (3,)),
        ("f_user", F8, (3,)),  # (M_d L^-1 - I) F_h
        ("f_contact", F8, (3,)),  # M_d J_h D^-1 tau_c (penalty + friction contacts)
        ("f_impulse", F8, (3,)),  # M_d J_h D^-1 P_cs / dt
        ("f_bias", F8, (3,)),  # -M_d J_h D^-1 (G + C qd), the frozen bias torques
        ("f_penalty", F8, (3,)),  # joint-constraint penalties (seed 000 eq 17)
        ("f_coordination", F8, (3,)),  # M_d L^-1 F_c, or the coupling force
        ("f_damping", F8, (3,)),  # (C_d - M_d L^-1 b_d) xd - M_d L^-1 k_d x
        ("wrench_command", F8, (3,)),  # u after the safe-state blend and the limits
        ("wrench_applied", F8, (3,)),  # what the device reports it applied
        ("contact_force_world", F8, (3,)),  # sum of contact forces on the proxy (fx, fy, 0)
        ("n_contacts", np.int32),  # contacts in the installed model
        ("n_active", np.int32),  # in penetration this tick
        ("n_colliding", np.int32),  # resolved by impulse this tick
        ("n_resisted", np.int32),  # j
        ("contact_stage", np.uint8),  # 1 if the contact stage did work
        ("safe", F8),  # safe-state blend 0..1
        ("fault", np.int32),
        ("device_fault", np.int32),
        ("device_aux", F8, (AUX_SIZE,)),  # device-specific readings (the device's aux_names)
        ("world_offset", F8, (3,)),  # device-to-world map offset (moves under rate control)
    ]
)

"""The haptic side's records: the static model of a tick, its mutable data, the device I/O,
the clock, the install state, and the packer that turns configs into them.

MJX-style (`mjx/_src/types.py`): `MODEL_DTYPE` holds what a tick only reads (the installed
local models and the gains), `DATA_DTYPE` what it reads and writes (proxy state, per-contact
state, scratch, the log row). The loop holds one preallocated 1-element array of each and the
stage kernels (`haptic_server.stages`) work on their fields in place; sizes are fixed by
MAX_DOF and MAX_CONTACTS, so nothing is allocated per tick. `params_record` is the one place
where configs become kernel records.
"""

from __future__ import annotations

import numpy as np

from haptic_local_model.device_models.base import AUX_SIZE, SENSOR_DTYPE, DeviceRenderingSpec
from haptic_local_model.haptic_server.stages.god_object import (
    BLEND_DTYPE,
    GOD_DATA_DTYPE,
    GOD_PARAMS_DTYPE,
    GeometryBlend,
    god_params,
)
from haptic_local_model.haptic_server.stages.train import TRAIN_DATA_DTYPE, TRAIN_MODEL_DTYPE
from haptic_local_model.shared.config import RenderingSpec, SceneConfig
from haptic_local_model.shared.kinematics import CHAIN_DTYPE, MAX_DOF
from haptic_local_model.shared.protocol.codes import Method
from haptic_local_model.shared.protocol.layout import LIMITS_DTYPE, LOCAL_MODEL_DTYPE, MAX_CONTACTS
from haptic_local_model.shared.tool_chain import tool_bounds, tool_chain

F8 = np.float64
I8 = np.int64
REASON_CODES = 32  # verdict codes (shared.protocol.codes.Reason) are below this

#: One installed local model: the wire fields as parsed (the per-contact state the haptic
#: side keeps from tick to tick is CONTACT_STATE_DTYPE, beside it in DATA_DTYPE).
SLOT_DTYPE = LOCAL_MODEL_DTYPE

#: Gains and switches of the rendering (from the scene's [rendering] and the device limits).
PARAMS_DTYPE = np.dtype(
    [
        ("method", I8),  # shared.protocol.codes.Method
        ("coupling_stiffness", F8, (3,)),  # the device-proxy spring: K_pc, B_pc of the
        ("coupling_damping", F8, (3,)),  # four-channel coupling, or the virtual coupling's
        ("integrate_proxy", I8),  # 0 for FOH: the sim's tool is the VM, no proxy dynamics
        ("penalty_stiffness", F8),  # k_j per unit device mass
        ("penalty_damping", F8),  # b_j
        ("desired_damping", F8, (3,)),  # b_d
        ("desired_stiffness", F8, (3,)),  # k_d
        ("jdot_qd", I8),  # 1: M_d J_h_dot qd in the control law (DESIGN §4.3)
        ("impulses", I8),  # 1: colliding contacts are resolved by impulses (never for FOH)
        ("collision_speed", F8),
        ("impulse_law", I8),  # 3: 2 + the device's impact ledger; 2: forces after impulses,
        # device-aware carry; 1: version 0.1
        ("blend_s", F8),
        ("foh_stiffness", F8, (3,)),  # K_p of seed 002
        ("foh_damping", F8, (3,)),  # K_v
        ("foh_interpolate", I8),  # 1: first-order hold, 0: zero-order hold of the setpoint
        ("foh_free_space", I8),  # 1: the FOH spring also while the tool touches nothing
        ("foh_gravity", F8, (3,)),  # f_g of seed 002 (world frame), added in every FOH tick
        ("safe_damping", F8, (3,)),  # the safe state: damping only
        ("safe_ramp_s", F8),
        ("max_wrench", F8, (3,)),  # device limits in the world frame: never exceeded
        ("guard", I8),  # 1: the runaway guard and the passivity observer (stages/safety.py)
        ("guard_max_speed", F8),  # m/s: the proxy's operational point (the scene's envelope)
        ("guard_max_angular_speed", F8),  # rad/s: any link of the proxy
        ("guard_max_energy", F8),  # J: the proxy's kinetic energy
        ("passivity_window_s", F8),  # the observer forgets energy over this time constant
        ("passivity_limit_j", F8),  # energy the device port may give out within the window
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
        ("fault", I8),  # shared.protocol.codes.Fault
        ("prev_device_twist", F8, (3,)),  # to predict the device's motion over a step
        ("impulse_carry", F8, (3,)),  # impulse (N s) held back by the device limits
        # impulse_law 3 (stages/control.py impact_ledger): the device's share of a predicted
        # impact's impulse delivered before it (N s), and the reference deviation of the
        # device from the path an unlimited device would take: offset D (m) and the
        # velocity the ledger no longer holds (m/s), returned by feedforward
        ("impulse_prepaid", F8, (3,)),
        ("impact_offset", F8, (3,)),
        ("impact_offset_rate", F8, (3,)),
        ("foh_goal", F8, (3,)),
        ("foh_step", F8, (3,)),
        ("foh_steps_left", I8),
        ("last_command", F8, (3,)),  # the wrench commanded last tick (world frame)
        ("port_energy", F8),  # the passivity observer: energy the device gave the hand (J)
        ("device_energy", F8),  # the device's kinetic energy last tick (J)
    ]
)

#: The haptic side's state of one installed model's contacts (one per slot).
CONTACT_STATE_DTYPE = np.dtype(
    [
        ("age_s", F8),  # time since the model's state held (negative at install): contacts
        # move with their environment velocity by it
        ("in_contact", I8, (MAX_CONTACTS,)),  # in penetration last tick
        ("stick", F8, (MAX_CONTACTS,)),  # tangential stick displacement (m)
        # the depth not rendered (m): set at install to how far the carry back drew a contact
        # not in contact before toward the tool (stages/install.py, carried_in); it only
        # shrinks with the depth (stages/contacts.py)
        ("offset", F8, (MAX_CONTACTS,)),
    ]
)

#: Scratch space so the kernels never allocate; each field has one meaning.
SCRATCH_DTYPE = np.dtype(
    [
        ("alpha", F8),  # weight of the newest slot this tick (1: no cross-fade)
        ("frame_pos", F8, (MAX_DOF, 2)),  # joint positions of the proxy
        ("frame_angle", F8, (MAX_DOF,)),
        ("op_point", F8, (2,)),  # the operational point (world)
        ("jac_hand", F8, (3, MAX_DOF)),  # J_h at the proxy
        ("x_vm", F8, (3,)),  # operational-point pose of the VM
        ("xd_vm", F8, (3,)),  # J_h qd
        ("contact_point", F8, (2,)),
        ("jac_point", F8, (3, MAX_DOF)),  # J_c at a contact point
        ("mass", F8, (MAX_DOF, MAX_DOF)),  # D^, cross-faded
        ("mass_chol", F8, (MAX_DOF, MAX_DOF)),  # its Cholesky factor
        ("mass_ok", I8),  # D^ is positive definite
        ("tau_bias", F8, (MAX_DOF,)),  # -(G^ + C^ qd), cross-faded
        ("tau_contact", F8, (MAX_DOF,)),  # sum J_c^T F of penalty + friction
        ("contact_stiffness_q", F8, (MAX_DOF, MAX_DOF)),  # sum J^T K J of the contact springs
        ("contact_damping_q", F8, (MAX_DOF, MAX_DOF)),  # sum J^T B J
        ("contact_stiff_vrel", F8, (MAX_DOF,)),  # sum J^T K v_rel (the implicit correction)
        ("contact_force", F8, (2,)),  # world force of all contacts on the proxy this tick
        # J, this tick: the work the touched shapes' own motion did on the proxy (contact
        # forces and impulses along the shapes' velocities): the passivity observer's budget
        # for a moving world, as the god-object's env_work
        ("env_work", F8),
        ("n_active", I8),  # contacts of the newest model in penetration
        ("penetration", F8),  # the deepest of them (m, >= 0)
        ("contact_ran", I8),  # the contact stage did work
        ("n_colliding", I8),
        ("coll_rows", F8, (MAX_CONTACTS, MAX_DOF)),  # n_i^T J_c,i
        ("coll_target", F8, (MAX_CONTACTS,)),  # v+ - v-
        ("coll_index", I8, (MAX_CONTACTS,)),
        ("coll_row", F8, (MAX_DOF,)),  # one row of J_n, then D^-1 of it
        ("coll_minv_row", F8, (MAX_DOF,)),
        ("coll_a", F8, (MAX_CONTACTS, MAX_CONTACTS)),  # J_n D^-1 J_n^T
        ("coll_lambda", F8, (MAX_CONTACTS,)),  # the impulses, N s (physics.impulses)
        ("impulse_q", F8, (MAX_DOF,)),  # P_cs = J_n^T lambda
        ("contact_eta", F8, (MAX_CONTACTS,)),  # each contact's time to collide (predict_impact)
        ("impact_eta", F8),  # s to the nearest predicted collision (inf: none; impulse_law 3)
        ("impulse_pred_q", F8, (MAX_DOF,)),  # its predicted P_cs
        ("impulse_dqd", F8, (MAX_DOF,)),  # D^-1 P_cs
        ("jac_row", F8, (MAX_DOF,)),  # a row of J_h, then D^-1 of it
        ("minv_jac_row", F8, (MAX_DOF,)),
        ("minv_jt", F8, (MAX_DOF, 3)),  # D^-1 J_h^T
        ("lambda_inv", F8, (3, 3)),  # J_h D^-1 J_h^T
        ("a_task", F8, (3, 3)),  # M_d Lambda^-1
        ("e", F8, (3,)),  # x_vm - x_h
        ("ed", F8, (3,)),  # xd_vm - xd_h
        ("f_coupling", F8, (3,)),  # K e + B ed of the device-proxy spring
        ("pull", F8, (3,)),  # task-space force on the proxy from the hand and the coupling
        ("n_resisted", I8),
        ("acc_contact", F8, (3,)),  # J_h D^-1 tau_c
        ("acc_bias", F8, (3,)),  # J_h D^-1 tau_bias (+ J_h_dot qd)
        ("jdot_qd", F8, (3,)),  # J_h_dot qd at the proxy: the operational point's bias acceleration
        ("acc_impulse", F8, (3,)),  # J_h D^-1 P_cs / dt
        ("damping_task", F8, (3,)),  # b_d xd_h + k_d x_h
        ("penalty_task", F8, (3,)),  # sum P (k_j e + b_j ed) over the resisted directions
        ("hand_acc", F8, (3,)),  # the device's acceleration over the last tick
        ("device_twist_eff", F8, (3,)),  # its twist as if the carried impulse were delivered
        ("inertia_chol", F8, (3, 3)),  # Cholesky factor of M_d (the carry's velocity)
        ("carry_velocity", F8, (3,)),  # M_d^-1 impulse_carry
        ("device_pose_eff", F8, (3,)),  # its pose less the impact offset (impulse_law 3)
        ("offset_velocity", F8, (3,)),  # twist - device_twist_eff (impulse_law 3)
        ("prepay_task", F8, (3,)),  # M_d J_h D^-1 of the predicted P_cs (N s), then its force
        ("proxy_damping", F8, (MAX_DOF, MAX_DOF)),  # its B: contacts' + J_h^T (B_c + dt K_c) J_h
        ("proxy_system", F8, (MAX_DOF, MAX_DOF)),  # D + dt B + dt^2 K of the proxy step
        ("proxy_chol", F8, (MAX_DOF, MAX_DOF)),
        ("proxy_rhs", F8, (MAX_DOF,)),  # f, then h f (physics.implicit.implicit_solve)
        ("proxy_dqd", F8, (MAX_DOF,)),
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
        ("penetration", F8),  # the deepest penetration of the newest model this tick (m)
        ("n_colliding", np.int32),  # resolved by impulse this tick
        ("n_resisted", np.int32),  # j
        ("contact_stage", np.uint8),  # 1 if the contact stage did work
        ("safe", F8),  # safe-state blend 0..1
        ("fault", np.int32),
        ("device_fault", np.int32),
        ("device_aux", F8, (AUX_SIZE,)),  # device-specific readings (the device's aux_names)
        ("world_offset", F8, (3,)),  # device-to-world map offset (moves under rate control)
        ("port_energy", F8),  # the passivity observer: energy the device gave the hand (J)
        # the god_object method (stages/finger.py; zero under the other methods)
        ("god_proxy", F8, (2,)),  # the god-object proxy p (world)
        ("god_contact", np.int32),  # 0 free, 1 slide, 2 stick
        ("god_active", np.int32),  # touching obstacles (0..2)
        ("god_pop", np.uint8),  # 1 on the tick of a pop-through
        ("god_pops", np.int32),  # pop-throughs so far
        ("god_substeps", np.int32),
        ("god_capped", np.uint8),  # 1: an obstacle was faster than max_substeps can follow
        ("n_shapes", np.int32),  # local shapes in the installed model
        ("god_env_key", np.int64, (2,)),  # the shapes it touches (-1: none) ...
        ("god_env_point", F8, (2, 2)),  # ... the points where it touches them (world) ...
        ("god_env_arm", F8, (2, 2)),  # ... those less each shape's centre (world axes) ...
        ("god_env_force", F8, (2, 2)),  # ... and the force on each, N (the sim applies it)
        ("god_blend", F8),  # a two-proxy blend's weight of the new geometry, 0 < s <= 1; 0: none
        # a train of cars (stages/train.py; zero without one): its animation variable
        ("avar_cars", np.int32),  # cars of the scene's train (0: none)
        ("avar_static_id", I8),  # its track's static id (shared/protocol/static.py)
        ("avar_s", F8),  # the lead car's arc length, m
        ("avar_sd", F8),  # its rate, m/s
        ("avar_force", F8),  # Q, the finger's generalised force on the train this tick, N
        ("avar_energy", F8),  # the train's energy, J
        ("avar_work", F8),  # the finger's work on the train so far, J
        ("avar_events", np.int32),  # kinks crossed and bumper hits so far
        ("avar_singular", np.int32),  # steps whose M_q was regularised so far (a singular J)
    ]
)


#: What a tick only reads: the two installed models (0 newest, 1 fading out), the gains, the
#: god-object's parameters (the god_object method) and the scene's train (stages/train.py).
MODEL_DTYPE = np.dtype(
    [
        ("slots", SLOT_DTYPE, (2,)),
        ("params", PARAMS_DTYPE),
        ("god", GOD_PARAMS_DTYPE),
        ("train", TRAIN_MODEL_DTYPE),
    ]
)

#: What a tick reads and writes.
DATA_DTYPE = np.dtype(
    [
        ("dt", F8),  # the step of this tick, s
        ("state", STATE_DTYPE),
        ("contacts", CONTACT_STATE_DTYPE, (2,)),  # of slots 0 and 1
        ("sensors", SENSOR_DTYPE, (1,)),  # the device reading in the world frame
        ("hand_measured", F8, (3,)),  # the measured hand wrench, world frame
        ("scratch", SCRATCH_DTYPE),
        ("row", TICK_DTYPE),
        ("god", GOD_DATA_DTYPE),  # the god-object proxy (the god_object method)
        ("god_blend", BLEND_DTYPE),  # its two-proxy blend, and what it renders
        ("train", TRAIN_DATA_DTYPE),  # the scene's train (stages/train.py)
    ]
)

#: The device side of a tick, in the device's frame.
DEVICE_IO_DTYPE = np.dtype(
    [
        ("sensors", SENSOR_DTYPE, (1,)),  # what the device read
        ("hand", F8, (3,)),  # the (simulated or logged) hand's true wrench
        ("command", F8, (3,)),  # the wrench to command
        ("max_wrench", F8, (3,)),  # the device's own limits (the driver clips there too)
    ]
)

#: The tick counter, the time and the newest install, as the log row reports them. The
#: kernels advance tick and t; the install route (or a replay) sets the update fields. The
#: loop's own measurements of a tick (dt, lateness, work) are engine_step's arguments.
CLOCK_DTYPE = np.dtype(
    [
        ("tick", I8),
        ("t", F8),  # s since the loop started
        ("update_seq", I8),  # seq of the newest installed update (-1: none)
        ("update_age_ms", F8),  # its publish -> install latency
        ("ready", I8),  # a model is installed
    ]
)

#: the sim and the haptic side compute D, G, Lambda^-1 and the tool pose by the same code from
#: the same numbers: they agree to rounding, and a relative difference beyond this is another
#: model (haptic_server/stages/plausible.py)
PLAUSIBILITY_TOLERANCE = 1.0e-6

#: What the scene allows an update to say (haptic_server/stages/plausible.py): its tool's
#: chain, to recompute D, G, C qd, Lambda^-1 and the tool pose at the update's own q, and the
#: scene's bounds on speeds, energy and contact materials; with the check's scratch.
ENVELOPE_DTYPE = np.dtype(
    [
        ("enabled", I8),  # 0: no plausibility check (kernel tests, logs before 0.4)
        ("chain", CHAIN_DTYPE, (1,)),  # the scene's tool (shared/tool_chain.py)
        ("op_link", I8),
        ("op_point", F8, (2,)),
        ("gravity", F8, (2,)),
        ("linkage", I8),  # 1: a linkage (C qd and resisted directions are sent)
        ("characteristic_length", F8),
        ("rank_tolerance", F8),
        ("outline_a", F8, (MAX_DOF, 2)),  # each link's shape inside a capsule a-b of radius r
        ("outline_b", F8, (MAX_DOF, 2)),
        ("outline_radius", F8, (MAX_DOF,)),
        ("max_speed", F8),  # m/s: the operational point
        ("max_angular_speed", F8),  # rad/s: any link
        ("max_energy", F8),  # J: the tool's kinetic energy
        ("max_stiffness", F8),  # the scene's materials
        ("max_tangential_stiffness", F8),
        ("max_damping", F8),
        ("max_friction", F8),
        ("max_restitution", F8),
        ("max_env_speed", F8),  # m/s: an environment point
        ("max_penetration", F8),  # m: a contact at the sim's own tool state
        ("sim_period_s", F8),
        ("tolerance", F8),  # relative: sim and haptic side compute the same terms
        # each figure of the last check over its bound (stages/plausible.py RATIO_*): how
        # close a plausible update came (benchmarks/envelope.py reports them)
        ("ratios", F8, (8,)),
        ("frame_pos", F8, (MAX_DOF, 2)),  # scratch from here on
        ("frame_angle", F8, (MAX_DOF,)),
        ("jac", F8, (3, MAX_DOF)),
        ("point", F8, (2,)),
        ("mass", F8, (MAX_DOF, MAX_DOF)),
        ("gravity_q", F8, (MAX_DOF,)),
        ("velocity_torque", F8, (MAX_DOF,)),
        ("mass_plus", F8, (MAX_DOF, MAX_DOF)),
        ("mass_minus", F8, (MAX_DOF, MAX_DOF)),
        ("q_step", F8, (MAX_DOF,)),
        ("gravity_step", F8, (MAX_DOF,)),
        ("chol", F8, (MAX_DOF, MAX_DOF)),
        ("column", F8, (MAX_DOF,)),
        ("gram", F8, (3, 3)),
        ("eigenvalues", F8, (3,)),
        ("eigenvectors", F8, (3, 3)),
    ]
)

#: The install state: the order of installed updates, the verdict counters, the parser's
#: buffers (DESIGN §3: an older epoch or a repeated sequence number is rejected).
INSTALL_DTYPE = np.dtype(
    [
        ("epoch", I8),  # of the installed model (-1: none yet)
        ("seq", I8),
        ("ready", I8),
        ("new_epoch", I8),  # the last install began a new epoch
        ("installed", I8),  # installs so far
        ("follow", I8),  # every install needs the engine's Python side (stale, FOH)
        ("stale", I8),  # the watchdog fired: the next good update may begin any epoch
        # the sim's liveliness (the I/O sidecar): while `bound`, only `owner`'s epoch installs
        ("bound", I8),
        ("owner", I8),
        ("epoch_law", I8),  # EPOCH_LAW_*: how epochs and times are admitted
        ("max_age_s", F8),  # an update older than this when taken is late
        ("max_skew_s", F8),  # a publish time (or epoch) this far ahead of the clock is forged
        ("match_radius_m", F8),  # a contact keeps its state if its tool point moved less
        ("reject_counts", I8, (REASON_CODES,)),  # rejections by verdict code
        ("parsed", LOCAL_MODEL_DTYPE, (1,)),
        ("limits", LIMITS_DTYPE, (1,)),
        ("parse_scratch", F8, (MAX_DOF, MAX_DOF)),
        ("envelope", ENVELOPE_DTYPE, (1,)),
    ]
)


#: [rendering] impulse_law -> the kernels' code (stages/control.py, contacts.py, safety.py)
IMPULSE_LAWS = {"0.1": 1, "0.2": 2, "0.13": 3}


def params_record(
    rendering: RenderingSpec,
    max_wrench: np.ndarray,
    device_rendering: DeviceRenderingSpec | None = None,
    safe_ramp_s: float = 0.05,
    world_map: np.ndarray | None = None,
) -> np.ndarray:
    """The gains as a kernel record (DESIGN §4, §6), in the world frame.

    The scene gives the rendering gains; the device (its `[rendering]` table, in its own
    frame) gives the FOH servo gains, f_g and the safe damping, and its limits `max_wrench`.
    Through a map of scale s and force scale f_s, device wrenches divide by f_s s and
    stiffnesses and dampings by f_s s^2 (F_dev = f_s s F_world, x_world = s x_dev + offset).
    The method's choices are made here, once: which spring couples the proxy to the device,
    whether the proxy is integrated, whether collisions are resolved by impulses.
    """
    dev = device_rendering or DeviceRenderingSpec()
    scale, force_scale = np.ones(3), 1.0
    if world_map is not None:
        scale, force_scale = world_map[0]["scale"].copy(), float(world_map[0]["force_scale"])
    per_wrench = 1.0 / (force_scale * scale)
    per_gain = per_wrench / scale
    method = Method.from_tag(rendering.method)
    rec = np.zeros(1, PARAMS_DTYPE)
    p = rec[0]
    p["method"] = method
    coupled = method == Method.VIRTUAL_COUPLING
    p["coupling_stiffness"] = (
        rendering.virtual_coupling_stiffness if coupled else rendering.coordination_stiffness
    )
    p["coupling_damping"] = (
        rendering.virtual_coupling_damping if coupled else rendering.coordination_damping
    )
    p["integrate_proxy"] = 0 if method == Method.VIRTUAL_COUPLING_FOH else 1
    p["penalty_stiffness"] = rendering.penalty_stiffness
    p["penalty_damping"] = rendering.penalty_damping
    p["desired_damping"] = rendering.desired_damping
    p["desired_stiffness"] = rendering.desired_stiffness
    p["jdot_qd"] = 1 if rendering.jdot_qd else 0
    p["impulses"] = 1 if rendering.impulses and method != Method.VIRTUAL_COUPLING_FOH else 0
    p["collision_speed"] = rendering.collision_speed_m_per_s
    p["impulse_law"] = IMPULSE_LAWS[rendering.impulse_law]
    p["blend_s"] = rendering.blend_ms / 1000.0
    p["foh_stiffness"] = np.array(dev.foh_stiffness) * per_gain
    p["foh_damping"] = np.array(dev.foh_damping) * per_gain
    p["foh_interpolate"] = 1 if dev.setpoint_hold == "first_order" else 0
    p["foh_free_space"] = 1 if rendering.foh_free_space_force else 0
    p["foh_gravity"] = np.array(dev.gravity_feedforward) * per_wrench
    p["safe_damping"] = np.array(dev.safe_damping) * per_gain
    p["safe_ramp_s"] = safe_ramp_s
    p["max_wrench"] = np.asarray(max_wrench, dtype=np.float64) * per_wrench
    return rec


def god_record(scene: SceneConfig, max_wrench_world: np.ndarray) -> np.ndarray:
    """The god-object's parameters (GOD_PARAMS_DTYPE[1]) of a god_object scene: the disc's
    radius, the coupling, and the force bound (the device's smaller planar limit, world
    frame); zeros for the other methods."""
    if scene.rendering.method != "god_object":
        return np.zeros(1, GOD_PARAMS_DTYPE)
    r = scene.rendering
    return god_params(
        scene.tool_body.radius, r.god_object_stiffness, r.god_object_damping,
        max_substeps=r.max_substeps, pop_ramp_s=r.pop_ramp_ms / 1e3,
        max_force=float(min(max_wrench_world[0], max_wrench_world[1])),
        blend_s=r.blend_ms / 1e3, geometry_blend=GeometryBlend[r.geometry_blend.upper()],
        node_period_s=min((1.0 / m.publish_hz for m in scene.deformables), default=0.0),
    )  # fmt: skip


def envelope_record(scene: SceneConfig) -> np.ndarray:
    """What the scene allows an update to say (ENVELOPE_DTYPE[1], enabled): its tool's chain
    (shared/tool_chain.py, as the sim builds it), the speeds and energy of its tool
    (tool_bounds, with the margin of a tool that tracks the proxy) and its materials."""
    tool = tool_chain(scene)
    safety = scene.safety
    rec = np.zeros(1, ENVELOPE_DTYPE)
    e = rec[0]
    d = tool.dof
    e["enabled"] = 1
    e["chain"] = tool.chain
    e["op_link"] = tool.op_link
    e["op_point"] = tool.op_point
    e["gravity"] = tool.gravity
    e["linkage"] = 1 if tool.kind == "linkage" else 0
    e["characteristic_length"] = scene.tool.characteristic_length_m
    e["rank_tolerance"] = scene.tool.rank_tolerance
    e["outline_a"][:d] = tool.outline_a
    e["outline_b"][:d] = tool.outline_b
    e["outline_radius"][:d] = tool.outline_radius
    bounds = tool_bounds(scene).tracking()  # the sim's tool follows the proxy, overshooting
    e["max_speed"] = bounds.speed
    e["max_angular_speed"] = bounds.spin
    e["max_energy"] = bounds.energy
    materials = scene.materials.values()
    e["max_stiffness"] = max(m.stiffness_n_per_m for m in materials)
    e["max_tangential_stiffness"] = max(m.tangential_stiffness for m in materials)
    e["max_damping"] = max(m.damping_ns_per_m for m in materials)
    e["max_friction"] = max(m.friction for m in materials)
    e["max_restitution"] = max(m.restitution for m in materials)
    e["max_env_speed"] = 2.0 * bounds.speed
    e["max_penetration"] = safety.max_penetration_m
    e["sim_period_s"] = 1.0 / scene.sim_rate_hz
    e["tolerance"] = PLAUSIBILITY_TOLERANCE
    return rec


def set_guard(params: np.ndarray, scene: SceneConfig) -> None:
    """The runaway guard's and passivity observer's bounds (PARAMS_DTYPE fields): the proxy's
    (shared/tool_chain.py tool_bounds) and the scene's [safety] table; on."""
    p = params[0]
    bounds = tool_bounds(scene)
    p["guard"] = 1
    p["guard_max_speed"] = bounds.speed
    p["guard_max_angular_speed"] = bounds.spin
    p["guard_max_energy"] = bounds.energy
    p["passivity_window_s"] = scene.safety.passivity_window_s
    p["passivity_limit_j"] = scene.safety.passivity_limit_j

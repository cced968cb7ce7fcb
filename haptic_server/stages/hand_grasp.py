"""Two mass-spring hands holding one box, in one implicit step (DESIGN-WAVE2 §7, V5.5).

Each hand is `stages/hand.py`'s: its tracked palm and glove, its drives, D(q), G(q), C qd and
its walls' contacts, computed by that module's kernels into its own record. This module
adds what couples them: a free box (x, y, theta; D exact), the contacts of every shaped
link of either hand with the box (both sides in q: the rows are n^T (J_link - J_box)), and
one linearly implicit theta-step over the whole of q = (q_hand_0, q_hand_1, q_box), so the
squeeze is as implicit as each hand's own drives. A tick whose sub-step turns any joint of
either hand by more than the hands' MAX_TURN, or fails, runs again in 4, 16, 64 sub-steps.
After the tick, a box beyond the scene's range is put back at its start at rest once no
link of either hand reaches it there, held at rest at the range until then (`keep_box_in_
range`; the port scenes' rule, stages/cosim.py step 5).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from haptic_local_model.haptic_server.physics.implicit import (
    implicit_advance,
    implicit_solve,
    implicit_system,
    subtract_stiffness_velocity,
)
from haptic_local_model.haptic_server.stages.hand import (
    MAX_SUBSTEPS,
    MAX_TURN,
    PALM,
    begin_substeps,
    copy_state,
    finish_substep,
    hand_outputs,
    hit_force,
    hit_rows,
    hit_stiffness,
    link_core,
    link_vertex_hit,
    prepare_substep,
    restore_tick,
    save_tick,
    shape_vertex_hit,
    tracked_inputs,
)
from haptic_local_model.shared.kinematics import MAX_DOF, point_jacobian, point_velocity

F8 = np.float64
I8 = np.int64
MAX_HANDS = 2
MAX_SYS = MAX_HANDS * MAX_DOF + 3
ROWS = MAX_DOF + 3  # one contact's columns: a hand's and the box's

GRASP_DTYPE = np.dtype(
    [
        ("n_hands", I8),
        ("offset", I8, (MAX_HANDS,)),  # each hand's first column in q
        ("box", I8),  # the box's first column
        ("n", I8),
        ("box_mass", F8),
        ("box_inertia", F8),
        ("box_vertices", F8, (4, 2)),
        ("gravity", F8, (2,)),
        ("stiffness", F8),
        ("damping", F8),
        ("friction", F8),
        ("tangential_stiffness", F8),
        ("theta", F8),
        ("range_m", F8),  # a box beyond it returns to its start (keep_box_in_range)
        ("box_start", F8, (3,)),
    ]
)

GRASP_DATA_DTYPE = np.dtype(
    [
        ("dt", F8),
        ("h", F8),
        ("n_sub", I8),
        ("q_box", F8, (3,)),
        ("qd_box", F8, (3,)),
        ("box_tick", F8, (6,)),
        ("box_before", F8, (3,)),
        ("f_box", F8, (3,)),
        ("box_force", F8, (3,)),  # the hands' mean force and torque on the box this tick
        ("hand_box_force", F8, (MAX_HANDS, 3)),  # each hand's share of box_force
        ("n_contacts", I8),  # hand-box contacts, the tick's last sub-step
        ("stick", F8, (MAX_HANDS, MAX_DOF, 2, 4)),
        ("touching", I8, (MAX_HANDS, MAX_DOF, 2, 4)),
        ("stick_tick", F8, (MAX_HANDS, MAX_DOF, 2, 4)),
        ("touching_tick", I8, (MAX_HANDS, MAX_DOF, 2, 4)),
        ("singular", I8),
        ("singular_tick", I8),
        ("resets", I8),  # the box put back at its start after leaving the range
        ("parked", I8),  # ticks it waited, out of range, for its start to be clear
        ("turn", F8),
        # the hand-box contacts' stiffness and damping over all of q, then (solve_all) the
        # hands' own blocks added: the step's K and B
        ("kg", F8, (MAX_SYS, MAX_SYS)),
        ("bg", F8, (MAX_SYS, MAX_SYS)),
        # D over all of q: the hands' blocks and the box's diagonal, written each step; the
        # rest is zero from the record's making on (solve_all does not clear it)
        ("mass_all", F8, (MAX_SYS, MAX_SYS)),
        ("f_all", F8, (MAX_SYS,)),  # the step's force over all of q
        ("system", F8, (MAX_SYS, MAX_SYS)),
        ("chol", F8, (MAX_SYS, MAX_SYS)),
        ("rhs", F8, (MAX_SYS,)),
        ("dqd", F8, (MAX_SYS,)),
        ("qd_all", F8, (MAX_SYS,)),
        ("cols", I8, (ROWS,)),
        ("jn", F8, (ROWS,)),
        ("jt", F8, (ROWS,)),
        ("pose_b", F8, (3,)),
    ]
)


def grasp_records(
    hands: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
    box_size: tuple[float, float],
    box_mass: float,
    box_pose: tuple[float, float, float],
    contact: tuple[float, float, float, float],
    range_m: float = 10.0,
) -> tuple[np.ndarray, np.ndarray]:
    """The coupling's model and data for these hands (each `hand_records`' (chain, model,
    data), in this order) and the box; contact: (stiffness, damping, friction, tangential
    stiffness); range_m: the scene's (keep_box_in_range). The step's dt, theta and gravity
    are the hands' own, which must agree."""
    models = [h[1][0] for h in hands]
    datas = [h[2][0] for h in hands]
    for key, values in (
        ("theta", [float(m["theta"]) for m in models]),
        ("dt", [float(d["dt"]) for d in datas]),
        ("gravity", [tuple(m["gravity"]) for m in models]),
    ):
        if len(set(values)) != 1:
            raise ValueError(f"{key}: the hands differ ({values})")
    dofs = [int(m["dof"]) for m in models]
    model = np.zeros(1, GRASP_DTYPE)
    data = np.zeros(1, GRASP_DATA_DTYPE)
    m = model[0]
    m["n_hands"] = len(dofs)
    m["offset"][: len(dofs)] = np.cumsum([0, *dofs[:-1]])
    m["box"] = sum(dofs)
    m["n"] = m["box"] + 3
    w, h = box_size
    m["box_mass"] = box_mass
    m["box_inertia"] = box_mass * (w * w + h * h) / 12.0
    m["box_vertices"] = [(-w / 2, -h / 2), (w / 2, -h / 2), (w / 2, h / 2), (-w / 2, h / 2)]
    m["gravity"] = models[0]["gravity"]
    m["stiffness"], m["damping"], m["friction"], m["tangential_stiffness"] = contact
    m["theta"] = models[0]["theta"]
    data[0]["dt"] = datas[0]["dt"]
    data[0]["q_box"] = box_pose
    m["box_start"] = box_pose
    m["range_m"] = range_m
    return model, data


@njit(cache=True)
def box_contact(chain, hm, hd, gm, gd, hand, key):
    """The contact in hd.hit (point, depth, the normal pushing the hand out of the box)
    between a hand's link and the box, key = (link, side, vertex): penalty, stick-spring
    friction, the forces on both, and the stiffness of its rows n^T (J_link - J_box) over
    all of q."""
    link, side, v = key
    c = chain[0]
    px = hd.hit[0]
    py = hd.hit[1]
    nx = hd.hit[3]
    ny = hd.hit[4]
    tx = -ny
    ty = nx
    vhx, vhy = point_velocity(c, hd.frame_pos, link, px, py, hd.qd)
    rx = px - gd.q_box[0]
    ry = py - gd.q_box[1]
    w = gd.qd_box[2]
    rvx = vhx - (gd.qd_box[0] - w * ry)
    rvy = vhy - (gd.qd_box[1] + w * rx)
    at = (hand, link, side, v)
    fx, fy, f_n, sticking = hit_force(gm, hd.hit, rvx, rvy, gd.touching, gd.stick, at, gd.h)
    n = hm.dof
    point_jacobian(c, hd.frame_pos, n, link, px, py, hd.jac)
    o = gm.offset[hand]
    for a in range(n):
        gd.cols[a] = o + a
    hit_rows(hd.jac, n, hd.hit, fx, fy, hd.f, gd.jn, gd.jt)
    torque = rx * fy - ry * fx
    gd.f_box[0] -= fx
    gd.f_box[1] -= fy
    gd.f_box[2] -= torque
    gd.box_force[0] -= fx / gd.n_sub
    gd.box_force[1] -= fy / gd.n_sub
    gd.box_force[2] -= torque / gd.n_sub
    gd.hand_box_force[hand, 0] -= fx / gd.n_sub
    gd.hand_box_force[hand, 1] -= fy / gd.n_sub
    gd.hand_box_force[hand, 2] -= torque / gd.n_sub
    b0 = gm.box
    for k in range(3):
        gd.cols[n + k] = b0 + k
    gd.jn[n] = -nx
    gd.jn[n + 1] = -ny
    gd.jn[n + 2] = -(rx * ny - ry * nx)
    gd.jt[n] = -tx
    gd.jt[n + 1] = -ty
    gd.jt[n + 2] = -(rx * ty - ry * tx)
    gd.n_contacts += 1
    if f_n > 0.0:  # at the step's end, as a hand's own contacts
        hit_stiffness(gm, sticking, gd.kg, gd.bg, gd.cols, gd.jn, gd.jt, n + 3)


@njit(cache=True)
def link_box_contacts(chain, hm, hd, gm, gd, hand, link):
    """Side 0: the link's core vertices in the box; side 1: the box's corners in the link's
    rounded core."""
    n_core, rounding = link_core(chain, hm, hd, link)
    for k in range(3):
        gd.pose_b[k] = gd.q_box[k]
    box = gm.box_vertices
    for v in range(n_core):
        if link_vertex_hit(hd, link, v, rounding, box, 4, 0.0, gd.pose_b):
            box_contact(chain, hm, hd, gm, gd, hand, (link, 0, v))
        else:
            gd.touching[hand, link, 0, v] = 0
    for v in range(4):
        if shape_vertex_hit(hd, link, n_core, rounding, box, v, 0.0, gd.pose_b):
            box_contact(chain, hm, hd, gm, gd, hand, (link, 1, v))
        else:
            gd.touching[hand, link, 1, v] = 0


@njit(cache=True)
def solve_all(hms, hds, gm, gd):
    """The theta-step over q = (hands, box): each hand's block from its own record (drives,
    walls, D, G, C qd), the box's, and the hand-box contacts' over all of q. A step that is
    not finite holds everything where it was, at rest (counted); returns whether it held."""
    n = gm.n
    h = gd.h
    th = gm.theta
    for i in range(gm.n_hands):
        hm = hms[i][0]
        hd = hds[i][0]
        o = gm.offset[i]
        for a in range(hm.dof):
            gd.f_all[o + a] = hd.f[a] - hd.gravity_q[a] - hd.coriolis[a] + hd.extra[a]
            gd.qd_all[o + a] = hd.qd[a]
            for b in range(hm.dof):
                gd.mass_all[o + a, o + b] = hd.mass[a, b]
                gd.bg[o + a, o + b] += hd.b[a, b]
                gd.kg[o + a, o + b] += hd.k[a, b]
    b0 = gm.box
    for k in range(3):
        mass = gm.box_inertia if k == 2 else gm.box_mass
        grav = gm.gravity[k] * gm.box_mass if k < 2 else 0.0
        gd.mass_all[b0 + k, b0 + k] = mass
        gd.f_all[b0 + k] = gd.f_box[k] + grav
        gd.qd_all[b0 + k] = gd.qd_box[k]
        gd.box_before[k] = gd.q_box[k]
    subtract_stiffness_velocity(gd.f_all, gd.kg, gd.qd_all, th * h, n)
    implicit_system(gd.system, gd.mass_all, gd.bg, gd.kg, th * h, n)
    if not implicit_solve(gd.system, gd.chol, gd.f_all, h, gd.rhs, gd.dqd, n):
        gd.singular += 1
        for k in range(3):
            gd.qd_box[k] = 0.0
        for i in range(gm.n_hands):
            hd = hds[i][0]
            hd.singular += 1
            for a in range(hms[i][0].dof):
                hd.qd[a] = 0.0
        return False
    for i in range(gm.n_hands):
        hd = hds[i][0]
        o = gm.offset[i]
        implicit_advance(hd.q, hd.qd, gd.dqd[o:], h, th, hms[i][0].dof)
    implicit_advance(gd.q_box, gd.qd_box, gd.dqd[b0:], h, th, 3)
    return True


@njit(cache=True)
def grasp_substeps(chains, hms, hds, gm, gd, n_sub):
    """The tick in n_sub sub-steps; the largest turn of one sub-step, of any joint of
    either hand or of the box, into gd.turn (inf if a step failed)."""
    gd.h = gd.dt / n_sub
    gd.n_sub = n_sub
    gd.turn = 0.0
    for k in range(3):
        gd.box_force[k] = 0.0
        for i in range(MAX_HANDS):
            gd.hand_box_force[i, k] = 0.0
    for i in range(gm.n_hands):
        begin_substeps(hms[i][0], hds[i][0], n_sub)
    n = gm.n
    for sub in range(n_sub):
        for i in range(n):
            for j in range(n):
                gd.kg[i, j] = 0.0
                gd.bg[i, j] = 0.0
        for k in range(3):
            gd.f_box[k] = 0.0
        gd.n_contacts = 0
        for i in range(gm.n_hands):
            hm = hms[i][0]
            hd = hds[i][0]
            prepare_substep(chains[i], hm, hd, sub)
            for link in range(PALM, hm.dof):
                link_box_contacts(chains[i], hm, hd, gm, gd, i, link)
        ok = solve_all(hms, hds, gm, gd)
        for i in range(gm.n_hands):
            hd = hds[i][0]
            finish_substep(hms[i][0], hd)
            if not hd.turn <= gd.turn:
                gd.turn = hd.turn
        box_turn = abs(gd.q_box[2] - gd.box_before[2])
        if not box_turn <= gd.turn:
            gd.turn = box_turn
        if not ok:
            gd.turn = math.inf


@njit(cache=True)
def grasp_tick(chains, hms, hds, gmodel, gdata):
    """One tick of both hands and the box: each hand's tracked palm and glove in its record
    (target, target_rate); each hand's command and glove torques are left in its record,
    the hands' force on the box in gdata.box_force."""
    gm = gmodel[0]
    gd = gdata[0]
    for i in range(gm.n_hands):
        tracked_inputs(hms[i][0], hds[i][0])
        save_tick(hms[i][0], hds[i][0])
    live = (gd.q_box, gd.qd_box, gd.stick, gd.touching)
    kept = (gd.box_tick[:3], gd.box_tick[3:], gd.stick_tick, gd.touching_tick)
    copy_state(3, live, kept)
    gd.singular_tick = gd.singular
    n_sub = 1
    while True:
        grasp_substeps(chains, hms, hds, gm, gd, n_sub)
        if gd.turn <= MAX_TURN or n_sub >= MAX_SUBSTEPS:
            break
        for i in range(gm.n_hands):
            restore_tick(hms[i][0], hds[i][0])
        copy_state(3, kept, live)
        gd.singular = gd.singular_tick
        n_sub *= 4
    for i in range(gm.n_hands):
        hd = hds[i][0]
        if n_sub > 1:
            hd.substepped += 1
        hand_outputs(hms[i][0], hd)
    keep_box_in_range(chains, hms, hds, gm, gd)


@njit(cache=True)
def _box_start_clear(chains, hms, hds, gm):
    """No shaped link of either hand (its frame's reach: the palm's corners, a phalanx's
    length and radius) comes within the box's half diagonal of the box's start."""
    bx, by = gm.box_start[0], gm.box_start[1]
    half = math.hypot(gm.box_vertices[2, 0], gm.box_vertices[2, 1])
    for i in range(gm.n_hands):
        hm, hd = hms[i][0], hds[i][0]
        for link in range(PALM, hm.dof):
            if link == PALM:
                reach = 0.0
                for v in range(4):
                    reach = max(reach, math.hypot(hm.palm_vertices[v, 0], hm.palm_vertices[v, 1]))
            else:
                reach = chains[i][0].lengths[link] + hm.radius[link]
            gap = math.hypot(hd.frame_pos[link, 0] - bx, hd.frame_pos[link, 1] - by)
            if gap <= half + reach:
                return False
    return True


@njit(cache=True, inline="always")
def keep_box_in_range(chains, hms, hds, gm, gd):
    """A box beyond the range (|x| or |y| > range_m) back at its start at rest, its contacts
    forgotten, when no hand is there; else held at rest clamped to the range."""
    r = gm.range_m
    if abs(gd.q_box[0]) <= r and abs(gd.q_box[1]) <= r:
        return
    if _box_start_clear(chains, hms, hds, gm):
        for k in range(3):
            gd.q_box[k] = gm.box_start[k]
        gd.stick[:] = 0.0
        gd.touching[:] = 0
        gd.resets += 1
    else:
        gd.q_box[0] = min(r, max(-r, gd.q_box[0]))
        gd.q_box[1] = min(r, max(-r, gd.q_box[1]))
        gd.parked += 1
    for k in range(3):
        gd.qd_box[k] = 0.0


@njit(cache=True)
def run_grasp(chains, hms, hds, gmodel, gdata, out):
    """Ticks k = 0 .. len(out) - 1 with the tracked hands where their records hold them;
    out[k] = box pose (3), the hands' force on the box (3), palm 0 and palm 1 poses (3 each),
    hand-box contacts (1), palm 0 and palm 1 commands (3 each)."""
    gd = gdata[0]
    for k in range(out.shape[0]):
        grasp_tick(chains, hms, hds, gmodel, gdata)
        for c in range(3):
            out[k, c] = gd.q_box[c]
            out[k, 3 + c] = gd.box_force[c]
            out[k, 6 + c] = hds[0][0].q[c]
            out[k, 9 + c] = hds[1][0].q[c]
            out[k, 13 + c] = hds[0][0].command[c]
            out[k, 16 + c] = hds[1][0].command[c]
        out[k, 12] = gd.n_contacts

"""SOFA's haptic rendering as SOFA writes it, for hapticbench (benchmarks/hapticbench.py):
the last constraint problem re-solved between frames (`LCPForceFeedback`).

**How SOFA does it** (sofa-framework/sofa, Sofa/Component/Haptics/.../LCPForceFeedback.inl
and Sofa/framework/Helper/.../LCPcalc.cpp): at the end of every simulation step
(`handleEvent` on AnimateEndEvent) the component keeps the step's constraint problem (the
compliance W in constraint space, the free violations Dfree, the last solution f), the
constraint Jacobian rows on the instrument's DOFs and the instrument's free position. Each
haptic tick (`computeForce`, ~1 kHz) it takes the device's displacement dx from that free
position (translation only: `derivRotations` defaults to false), adds J dx to Dfree, re-solves
the problem with `nlcp_gaussseidelTimed` (Gauss-Seidel over 3-row contact blocks, Coulomb
cones projected radially, warm-started from the last f: `useInitialF = true`) with
tolerance `cp->tolerance * 0.001`, at most `solverMaxIt` = 100 iterations and a 0.8 ms
`solverTimeout`, restores Dfree and sends `forceCoef` J^T f as the force.

**Here**: the case's pymunk world at the scene's sim rate (60 Hz, the slide's 30 Hz), its
tool pulled to the device's pose by seed 002's coupling spring and damper (the scene's
`foh_spring_*`, with the substeps that spring needs to be stable in pymunk, doubled until
the tool stays within bounds), which stands for SOFA's instrument tied to the device by a
spring: 1540 substeps a frame for the walls' 0.5 kg rectangle at 60 Hz, 3079 for the
slide's box at 30 Hz, 167 for the linkage's held 1 kg link (SOFA's implicit step needs
none; pymunk's explicit spring does). After each frame the problem is built from the
contacts pymunk reports on the tool's operational body (the last substep's
`contact_point_set`), two rows per contact point (2-D: normal and tangent), in the
operational point's coordinates (x, y, angle):

- Dfree: each point's gap plus pymunk's `collision_slop` (pymunk holds a resting contact at
  -slop, its zero violation), 0 along the tangent;
- W: what stands for SOFA's implicit-Euler compliance over one frame T, H (M/T^2 + B/T +
  K)^-1 H^T, with M the tool's operational-space mass (J D^-1 J^T inverted, from the chain's
  D(q): a body's mass and moment at the held point, a linkage's whole chain), K and B the
  coupling spring's gains; plus T^2 H_b M_b^-1 H_b^T for a dynamic body the tool touches;
- mu: pymunk's friction of the contact (the product of the two shapes', the tool's is 1);
- f: solved at the frame as SOFA's constraint solver solves it (GAUSS_SEIDEL_TOLERANCE,
  1000 iterations: the LCPConstraintSolver of SOFA's own LCPForceFeedback test scene,
  Sofa/Component/Haptics/tests/scenes/ToolvsFloorCollision_test.scn), then warm-started.

Each 1 ms tick: dx = the device's pose less the tool's at the frame (angle 0), the problem
re-solved with tolerance 1e-6 * 1e-3 = 1e-9 m and at most 100 iterations, the force
FORCE_COEF H^T f (x and y: `computeForce` of a Rigid3 instrument returns no torque).
FORCE_COEF is the component's default, 0.03 (SOFA's shipped scenes set 5e-5 to 1.0: a
conversion of the scene's units and a scaling of the problem's stiffness to what the device
renders). W's inverse here is about B/T + K = 7e5 N/m (seed 002's gains at 60 Hz), 0.03 of
it 2e4 N/m, near the walls' 15 kN/m; 1.0 (SOFA's own test scene) would render the
constraint force itself, 47 times stiffer than the walls.

Left out of SOFA's version: the timeout (it reads the wall clock; here every run is the
same, the iteration cap bounds the work); the rest of the scene's constraint problem (SOFA
re-solves every constraint of the step, here only the tool's contacts: a block the tool
pushes has its mass in W but not its own contacts); contacts of a linkage's other links and
the joints (the LCP solver's problem holds unilateral contacts only: a mechanism the tool
holds is not felt, as with the Isaac Lab way); SOFA's alarm distance (a contact not in the
frame's problem is not felt before the next frame). Pymunk's contacts are rigid: a scene's
material stiffness is not rendered, the hand feels FORCE_COEF / W; and the force has no
damping term (SOFA's has none either: a device pressed on a wall rings until its own or
the hand's damping stops it). The Gauss-Seidel is written in Python,
as the other peers are, not compiled: its cost is counted as it is.

Not rendered (NotApplicableError, with the reason): two devices (the grasp), a scene driven
along a track or crank (the coaster, the crank, the Ferris wheel: the haptic side's
animation variables), and a tool too light for the coupling's spring (a god-object's point:
more substeps a frame than a scene may take).
"""

from __future__ import annotations

import math
import time

import numpy as np

from haptic_local_model.benchmarks import front
from haptic_local_model.benchmarks.peers import ToolPoint
from haptic_local_model.benchmarks.suite_records import Case, MethodRun, NotApplicableError
from haptic_local_model.device_models.base import world_map_of
from haptic_local_model.device_models.registry import load_device
from haptic_local_model.haptic_server.model import TICK_DTYPE
from haptic_local_model.haptic_server.users import hand_wrench, user_record
from haptic_local_model.shared.config import SceneConfig, load_scene, load_user
from haptic_local_model.sim_server.world import SimWorld, ToolTarget

#: LCPForceFeedback's `forceCoef` default (LCPForceFeedback.inl: initData(&d_forceCoef, 0.03))
FORCE_COEF = 0.03
#: LCPForceFeedback's `solverMaxIt` default: the haptic re-solve's iteration cap
HAPTIC_MAX_IT = 100
#: the scene's LCPConstraintSolver (ToolvsFloorCollision_test.scn: tolerance="0.000001"
#: maxIt="1000"); the haptic re-solve uses cp->tolerance * 0.001
GAUSS_SEIDEL_TOLERANCE = 1e-6
SIM_MAX_IT = 1000
HAPTIC_TOLERANCE = GAUSS_SEIDEL_TOLERANCE * 1e-3
#: the coupling's substeps are doubled up to this factor until the tool stays in bounds
MAX_SUBSTEP_FACTOR = 64
#: the most substeps a scene may take (SceneConfig's bound on sim_substeps)
MAX_SIM_SUBSTEPS = 100_000
#: the tool's speed (m/s) past which a frame is taken as pymunk's coupling blowing up
#: (the protocol's MessageLimits bound on velocities, shared/config.py)
RUNAWAY_SPEED = 100.0
SOFA_LCP = "the last contact problem re-solved every 1 ms (SOFA's LCPForceFeedback way)"


def gauss_seidel(
    d_free: np.ndarray, w: np.ndarray, mu: np.ndarray, f: np.ndarray, tol: float, max_it: int
) -> int:
    """`nlcp_gaussseidel` of SOFA's LCPcalc.cpp in 2-D: contact c has rows 2c (normal) and
    2c + 1 (tangent); find f with d = d_free + W f, 0 <= f_n perp d_n >= 0 and |f_t| <= mu
    f_n (stick: d_t = 0; slip: f_t on the cone against d_t). `f` is the warm start and the
    result (in place). Per block, SOFA's GS_State: f_n from the normal row alone, then f_t
    from the tangent row, clipped to the cone. Stops when the sum over contacts of how much
    each block's violation moved falls below `tol`; returns the iterations run."""
    n = len(d_free) // 2
    rows = w.tolist()
    dfree, force, mus = d_free.tolist(), f.tolist(), mu.tolist()
    it = 0
    while it < max_it:
        it += 1
        error = 0.0
        for c in range(n):
            i, j = 2 * c, 2 * c + 1
            fn0, ft0 = force[i], force[j]
            force[i] = force[j] = 0.0
            wi, wj = rows[i], rows[j]
            dn = dfree[i] + sum(a * b for a, b in zip(wi, force, strict=True))
            dt = dfree[j] + sum(a * b for a, b in zip(wj, force, strict=True))
            wnn, wnt, wtt = wi[i], wi[j], wj[j]
            before_n = dn + wnn * fn0 + wnt * ft0
            before_t = dt + wnt * fn0 + wtt * ft0
            fn = fn0 - before_n / wnn
            ft = 0.0
            if fn < 0.0:
                fn = 0.0
            else:
                ft = ft0 - (wnt * fn + wtt * ft0 + dt) / wtt if wtt > 0.0 else 0.0
                if abs(ft) > mus[c] * fn:
                    ft = math.copysign(mus[c] * fn, ft)
                dn += wnn * fn + wnt * ft
                dt += wnt * fn + wtt * ft
            force[i], force[j] = fn, ft
            error += math.hypot(dn - before_n, dt - before_t)
        if error < tol:
            break
    f[:] = force
    return it


def operational_compliance(
    inverse_mass: np.ndarray, stiffness: np.ndarray, damping: np.ndarray, period: float
) -> np.ndarray:
    """(M/T^2 + B/T + K)^-1 for the tool's operational-space mass M = inverse_mass^-1 and
    the coupling's diagonal K, B: implicit Euler's compliance over one step T, as SOFA's
    constraint correction gives it. Written T^2 Minv (I + T^2 S Minv)^-1 with S = B/T + K,
    which holds where M is singular (a linkage at a singularity: Minv loses rank)."""
    s = np.diag(np.asarray(damping) / period + np.asarray(stiffness))
    t2 = period * period
    return t2 * inverse_mass @ np.linalg.inv(np.eye(3) + t2 * s @ inverse_mass)


def _cross(r: np.ndarray, v: np.ndarray) -> float:
    return float(r[0] * v[1] - r[1] * v[0])


class ContactProblem:
    """The frame's constraint problem on the tool (SOFA's mCP, mConstraints and mVal): the
    rows H in the operational point's coordinates, Dfree, W, mu, the solution f, and the
    tool's pose it was taken at."""

    def __init__(self) -> None:
        self.h = np.zeros((0, 3))
        self.d_free, self.w = np.zeros(0), np.zeros((0, 0))
        self.mu, self.f = np.zeros(0), np.zeros(0)
        self.pose = np.zeros(3)

    def force(self, device_pose: np.ndarray, out: np.ndarray) -> None:
        """LCPForceFeedback::doComputeForce: Dfree + H dx re-solved, FORCE_COEF H^T f."""
        if not len(self.f):
            out[:] = 0.0
            return
        dx = device_pose - self.pose
        dx[2] = 0.0  # derivRotations = false
        gauss_seidel(self.d_free + self.h @ dx, self.w, self.mu, self.f,
                     HAPTIC_TOLERANCE, HAPTIC_MAX_IT)  # fmt: skip
        wrench = FORCE_COEF * (self.h.T @ self.f)
        out[:2] = wrench[:2]


def contact_problem(world: SimWorld, tool: ToolPoint, pose: np.ndarray) -> ContactProblem:
    """The frame's problem from the contacts pymunk reports on the tool's operational body
    (module docstring), solved as the sim's constraint solver would."""
    problem = ContactProblem()
    problem.pose = pose.copy()
    rows, gaps, mus, others = [], [], [], []
    links = set(world.tool_bodies)
    slop = world.space.collision_slop

    def add(arbiter: object) -> None:
        a, b = arbiter.bodies  # type: ignore[attr-defined]
        other = b if a is tool.body else a
        if other in links:  # another link of the tool's own chain: not a contact row
            return
        points = arbiter.contact_point_set  # type: ignore[attr-defined]
        # pymunk's normal points from the first body to the second: n opens the gap
        sign = -1.0 if a is tool.body else 1.0
        normal = sign * np.array([points.normal.x, points.normal.y])
        tangent = np.array([-normal[1], normal[0]])
        for p in points.points:
            on_tool = p.point_a if a is tool.body else p.point_b
            r = np.array([on_tool.x, on_tool.y]) - pose[:2]
            rows.append((normal, tangent, r))
            gaps.append(p.distance + slop)
            mus.append(arbiter.friction)  # type: ignore[attr-defined]
            others.append((other, np.array([on_tool.x, on_tool.y])))

    tool.body.each_arbiter(add)
    if not rows:
        return problem
    k = len(rows)
    h = np.zeros((2 * k, 3))
    for c, (normal, tangent, r) in enumerate(rows):
        h[2 * c] = (normal[0], normal[1], _cross(r, normal))
        h[2 * c + 1] = (tangent[0], tangent[1], _cross(r, tangent))
    q, _ = world.tool_state()
    mass, _, jac = world.dynamics_terms(q)
    inverse_mass = jac @ np.linalg.solve(mass, jac.T)
    gains = world.scene.rendering
    w_op = operational_compliance(
        inverse_mass, np.array(gains.foh_spring_stiffness), np.array(gains.foh_spring_damping),
        world.period,
    )  # fmt: skip
    w = h @ w_op @ h.T + _others_compliance(rows, others, world.period)
    problem.h, problem.w = h, w
    problem.d_free = np.zeros(2 * k)
    problem.d_free[0::2] = gaps
    problem.mu, problem.f = np.array(mus), np.zeros(2 * k)
    gauss_seidel(problem.d_free, w, problem.mu, problem.f, GAUSS_SEIDEL_TOLERANCE, SIM_MAX_IT)
    return problem


def _others_compliance(rows: list, others: list, period: float) -> np.ndarray:
    """T^2 H_b M_b^-1 H_b^T of the dynamic bodies the tool touches (a static or kinematic
    one adds nothing): the rows as they move that body, at its centre of gravity."""
    k = len(rows)
    w = np.zeros((2 * k, 2 * k))
    jac = np.zeros((2 * k, 3))
    for c, ((normal, tangent, _), (body, point)) in enumerate(zip(rows, others, strict=True)):
        if body.body_type != body.DYNAMIC:
            continue
        centre = body.local_to_world(body.center_of_gravity)
        r = point - np.array([centre.x, centre.y])
        for row, axis in ((2 * c, normal), (2 * c + 1, tangent)):
            jac[row] = (-axis[0], -axis[1], -_cross(r, axis))
    for body in {id(b): b for b, _ in others if b.body_type == b.DYNAMIC}.values():
        mine = np.array([[2 * c, 2 * c + 1] for c, (b, _) in enumerate(others) if b is body])
        mine = mine.ravel()
        inv = np.diag([1.0 / body.mass, 1.0 / body.mass, 1.0 / body.moment])
        w[np.ix_(mine, mine)] += period * period * jac[mine] @ inv @ jac[mine].T
    return w


def sofa_lcp(case: Case) -> MethodRun:
    """The case rendered SOFA's LCPForceFeedback way (module docstring): with the coupling's
    substeps doubled until pymunk's tool stays within bounds."""
    if case.ports != 1:
        raise NotApplicableError(
            "one instrument's constraint problem: LCPForceFeedback displaces the rows of one"
            " device's instrument, and the grasp's two devices on one box would each need"
            " theirs re-solved with the other's displacement"
        )
    scene = load_scene(case.scene)
    if not isinstance(scene, SceneConfig) or scene.tool.kind not in ("body", "linkage"):
        raise NotApplicableError("a scene of one held body or linkage in pymunk only")
    if scene.cars or scene.crank is not None or scene.avar_tree is not None:
        raise NotApplicableError(
            "a mechanism driven along its track or crank (the haptic side's animation"
            " variables): its constraint is not a contact, which the LCP of contacts does"
            " not hold"
        )
    needed = front.coupling_substeps_needed(scene, scene.sim_rate_hz)
    if needed > MAX_SIM_SUBSTEPS:
        raise NotApplicableError(
            f"a tool pymunk cannot hold on the coupling's spring: {needed} substeps a frame"
            f" at {scene.sim_rate_hz:g} Hz, above the sim's {MAX_SIM_SUBSTEPS}"
        )
    factor = 1
    while True:
        # the coupling as a virtual coupling has it: its damper on the relative velocity
        configured = front.configure(scene, "vc_foh", scene.sim_rate_hz, factor)
        try:
            return _run(case, configured)
        except RuntimeError:
            if factor >= MAX_SUBSTEP_FACTOR or 2 * factor * needed > MAX_SIM_SUBSTEPS:
                raise
            factor *= 2


def _run(case: Case, scene: SceneConfig) -> MethodRun:
    world = SimWorld(scene)
    tool = ToolPoint(world)
    substeps = world.substeps
    device = load_device(case.device)
    if not np.all(world_map_of(device).record[0]["scale"] == 1.0):
        raise ValueError(f"sofa_lcp: device {case.device!r} maps with a scale; only 1 is supported")
    user = user_record(load_user(case.user))
    start, _ = tool.state()
    device.reset(np.zeros(3))
    user[0]["start_pose"] = start
    sim_hz, haptic_hz = scene.sim_rate_hz, scene.haptic_rate_hz
    n = round(case.seconds * haptic_hz)
    ticks = np.zeros(n, TICK_DTYPE)
    dt = 1.0 / haptic_hz
    pose, twist, hand = np.zeros(3), np.zeros(3), np.zeros(3)
    feedback, command = np.zeros(2), np.zeros(3)
    problem = ContactProblem()
    frames, sim_ns, tick_ns = 0, 0, 0
    for i in range(n):
        t0 = time.perf_counter_ns()
        device.true_state(pose, twist)
        world_pose = pose + start
        if i * sim_hz >= frames * haptic_hz:  # a frame: the tool pulled to the device
            q, qd = world.tool_state()
            world.step(ToolTarget(q, qd, world_pose, twist.copy(), True, True))
            frames += 1
            tool_pose, tool_twist = tool.state()
            if not np.all(np.isfinite(tool_pose)) or np.hypot(*tool_twist[:2]) > RUNAWAY_SPEED:
                raise RuntimeError(f"sofa_lcp: the tool ran away with {substeps} substeps")
            problem = contact_problem(world, tool, tool_pose)
        t1 = time.perf_counter_ns()
        problem.force(world_pose, feedback)
        command[:2] = feedback
        applied = device.command(command)
        hand_wrench(user, i * dt, world_pose, twist, hand)
        device.sense_hand(hand)
        device.advance(dt, hand)
        row = ticks[i]
        row["t"], row["dt"] = i * dt, dt
        row["device_pose"], row["device_twist"] = world_pose, twist
        row["wrench_command"] = applied
        row["contact_force_world"][:2] = feedback
        sim_ns += t1 - t0
        tick_ns += time.perf_counter_ns() - t1
    cost = 1e3 * (sim_ns + tick_ns) / 1e9 / case.seconds
    return MethodRun(ticks, scene, cost, sim_hz, substeps)

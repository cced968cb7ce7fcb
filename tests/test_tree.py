"""Tree and multi-chain kinematics (DESIGN-WAVE2 C1) against independent references.

The kernels (shared/kinematics.py: Jacobians by ancestry, D(q) as a sum over links) are
checked against the tree RNEA of shared/reference.py (Newton-Euler over the same tree, a
different algorithm) and against finite differences of their own forward kinematics; the
sim's pymunk tree against the chain; the scene `linkage_tree` end to end (sim in pymunk, the
update over the wire with its CHAINS trailer, the haptic loop) against the reference's
solution of the same tree under the same push.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from conftest import haptic_run, write_network_file

from haptic_local_model.benchmarks.linkage import (
    chain_spec,
    reference_error,
    reference_error_mm,
    run,
    with_method,
)
from haptic_local_model.haptic_server.harness.replay import replay
from haptic_local_model.haptic_server.log import read_log
from haptic_local_model.shared.config import load_scene
from haptic_local_model.shared.kinematics import (
    CHAIN_OBJECT,
    PRISMATIC_X,
    PRISMATIC_Y,
    REVOLUTE,
    chain_record,
    fastest_spin,
    link_frames,
    link_spin,
    mass_matrix_and_gravity,
    point_bias_acceleration,
    point_jacobian,
    point_on_link,
)
from haptic_local_model.shared.protocol.update import UpdateParser
from haptic_local_model.shared.reference import (
    ChainSpec,
    Hold,
    bias_forces,
    mass_matrix,
    point_pose,
    simulate,
)
from haptic_local_model.shared.reference import point_jacobian as reference_jacobian
from haptic_local_model.sim_server.world import SimWorld, ToolTarget

FD_STEP = 1e-6
FD_TOL = 1e-7  # central differences, h = 1e-6, on 0.1 m lever arms: O(h^2) ~ 1e-13 + round-off
VM_RMS_MM = 2.0  # issue 4's bound for the held linkages, here for the tree
#: trees of up to six links: parents, every one before its child
TREES = [(-1, 0, 0), (-1, 0, 1, 1, 0), (-1, -1, 0, 1), (-1, 0, 0, 2, 2, 1)]


def tree_spec(parents: tuple[int, ...], seed: int) -> ChainSpec:
    rng = np.random.default_rng(seed)
    n = len(parents)
    return ChainSpec(
        base=(0.01, -0.02), lengths=tuple(rng.uniform(0.02, 0.06, n)),
        masses=tuple(rng.uniform(0.2, 2.0, n)), inertias=tuple(rng.uniform(1e-4, 1e-2, n)),
        com_offsets=tuple(map(tuple, rng.uniform(-0.01, 0.03, (n, 2)))),
        gravity=(0.0, -9.81), base_angle=0.3, parents=parents,
    )  # fmt: skip


def tree_record(spec: ChainSpec) -> np.ndarray:
    n = spec.n
    return chain_record(
        np.full(n, REVOLUTE, np.int64), np.array(spec.lengths), np.array(spec.base),
        spec.base_angle, np.array(spec.masses), np.array(spec.inertias),
        np.array(spec.com_offsets), np.array([spec.parent(i) for i in range(n)]),
    )  # fmt: skip


def kernel_pose(chain: np.ndarray, q: np.ndarray, link: int, r: np.ndarray) -> np.ndarray:
    n = len(q)
    pos, ang, out = np.zeros((n, 2)), np.zeros(n), np.zeros(2)
    link_frames(chain[0], q, n, pos, ang)
    point_on_link(pos, ang, link, r, out)
    return np.array([out[0], out[1], ang[link]])


@pytest.mark.parametrize("parents", TREES)
def test_tree_jacobians_match_the_reference_and_finite_differences(
    parents: tuple[int, ...],
) -> None:
    """Column j of a point's Jacobian is non-zero only for the joints that move its link, and
    equals the reference's and the central differences of the kernels' own poses."""
    spec = tree_spec(parents, 1)
    chain = tree_record(spec)
    n = spec.n
    rng = np.random.default_rng(2)
    for _ in range(5):
        q = rng.uniform(-np.pi, np.pi, n)
        for link in range(n):
            r = rng.normal(scale=0.01, size=2)
            np.testing.assert_allclose(
                kernel_pose(chain, q, link, r), point_pose(spec, q, link, r), atol=1e-15
            )
            pos, ang, jac = np.zeros((n, 2)), np.zeros(n), np.zeros((3, n))
            link_frames(chain[0], q, n, pos, ang)
            p = kernel_pose(chain, q, link, r)
            point_jacobian(chain[0], pos, n, link, p[0], p[1], jac)
            np.testing.assert_allclose(jac, reference_jacobian(spec, q, link, r), atol=1e-15)
            for j in range(n):
                dq = np.zeros(n)
                dq[j] = FD_STEP
                fd = kernel_pose(chain, q + dq, link, r) - kernel_pose(chain, q - dq, link, r)
                np.testing.assert_allclose(jac[:, j], fd / (2 * FD_STEP), atol=FD_TOL)
            assert (jac[:, [j not in spec.moved_by(link) for j in range(n)]] == 0).all()


@pytest.mark.parametrize("parents", TREES)
def test_tree_mass_matrix_and_gravity_match_the_tree_rnea(parents: tuple[int, ...]) -> None:
    """D(q) and G(q) by the Jacobian sum against Newton-Euler over the tree; C(q, qd) qd's
    input, the same D, is checked by the J_dot qd test below."""
    spec = tree_spec(parents, 3)
    chain = tree_record(spec)
    n = spec.n
    rng = np.random.default_rng(4)
    work = (np.zeros((n, 2)), np.zeros(n), np.zeros((3, n)))
    for _ in range(10):
        q = rng.uniform(-np.pi, np.pi, n)
        d, g = np.zeros((n, n)), np.zeros(n)
        mass_matrix_and_gravity(chain, np.array(spec.gravity), q, work, d, g)
        np.testing.assert_allclose(d, mass_matrix(spec, q), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(g, bias_forces(spec, q, np.zeros(n)), rtol=1e-12, atol=1e-12)
        # the serial reading of the same links is another mechanism: the check can fail
        serial = dataclasses.replace(spec, parents=())
        assert np.abs(mass_matrix(serial, q) - d).max() > 1e-3 * np.abs(d).max()


@pytest.mark.parametrize("parents", TREES)
def test_tree_bias_acceleration_is_the_points_acceleration_at_zero_qdd(
    parents: tuple[int, ...],
) -> None:
    """J_dot qd of a point on each link: the second derivative of its pose along q + qd s
    (fourth-order central differences of the reference's forward kinematics)."""
    spec = tree_spec(parents, 5)
    chain = tree_record(spec)
    n = spec.n
    rng = np.random.default_rng(6)
    h = 1e-3
    for _ in range(4):
        q, qd = rng.uniform(-np.pi, np.pi, n), rng.uniform(-3.0, 3.0, n)
        for link in range(n):
            r = rng.normal(scale=0.01, size=2)
            pos, ang, out = np.zeros((n, 2)), np.zeros(n), np.zeros(3)
            link_frames(chain[0], q, n, pos, ang)
            p = kernel_pose(chain, q, link, r)
            point_bias_acceleration(chain[0], pos, n, link, p[0], p[1], qd, out)
            f = [point_pose(spec, q + k * h * qd, link, r) for k in (-2, -1, 0, 1, 2)]
            second = (-f[0] + 16 * f[1] - 30 * f[2] + 16 * f[3] - f[4]) / (12 * h * h)
            np.testing.assert_allclose(out[:2], second[:2], atol=1e-6)


def test_several_chains_are_independent_blocks_on_their_own_bases() -> None:
    """The extended configuration: a two-link tool (chain 0) and a free body (chain 1, an
    object at its own base). Frames of chain 1 start at its base; D is block diagonal with
    each chain's own D; a point of one chain has zero Jacobian columns for the other."""
    tool = tree_spec((-1, 0), 7)
    body_types = [PRISMATIC_X, PRISMATIC_Y, REVOLUTE]
    chain = chain_record(
        np.array([REVOLUTE, REVOLUTE, *body_types]), np.array([*tool.lengths, 0.0, 0.0, 0.0]),
        np.array(tool.base), tool.base_angle, np.array([*tool.masses, 0.0, 0.0, 0.5]),
        np.array([*tool.inertias, 0.0, 0.0, 2e-3]),
        np.array([*tool.com_offsets, (0, 0), (0, 0), (0.01, 0.0)]), np.array([-1, 0, -1, 2, 3]),
    )  # fmt: skip
    c = chain[0]
    c["n_chains"] = 2
    c["chain_first"][1] = 2
    c["chain_kind"][1] = CHAIN_OBJECT
    c["chain_port"][1] = -1
    c["chain_base"][1] = (0.2, 0.1, 0.4)
    q = np.array([0.3, -0.5, 0.01, -0.02, 0.7])
    pos, ang = np.zeros((5, 2)), np.zeros(5)
    link_frames(c, q, 5, pos, ang)
    np.testing.assert_allclose(pos[4], [0.21, 0.08], atol=1e-15)
    assert ang[4] == pytest.approx(0.4 + 0.7)
    d, g = np.zeros((5, 5)), np.zeros(5)
    mass_matrix_and_gravity(chain, np.array([0.0, -9.81]), q, (pos, ang, np.zeros((3, 5))), d, g)
    np.testing.assert_allclose(d[:2, :2], mass_matrix(tool, q[:2]), rtol=1e-12)
    assert (d[:2, 2:] == 0).all() and (d[2:, :2] == 0).all()
    body = d[2:, 2:]  # a free body: m on x, y; I + m r^2 about its frame's origin
    r = 0.01 * np.array([np.cos(1.1), np.sin(1.1)])
    np.testing.assert_allclose(body[:2, :2], 0.5 * np.eye(2), atol=1e-15)
    np.testing.assert_allclose(body[2, 2], 2e-3 + 0.5 * 0.01**2, rtol=1e-12)
    np.testing.assert_allclose(body[:2, 2], 0.5 * np.array([-r[1], r[0]]), atol=1e-15)
    assert g[4] == pytest.approx(0.5 * 9.81 * r[0])
    jac = np.zeros((3, 5))
    point_jacobian(c, pos, 5, 1, pos[1, 0], pos[1, 1], jac)
    assert (jac[:, 2:] == 0).all() and (jac[:, :2] != 0).any()
    point_jacobian(c, pos, 5, 4, pos[4, 0], pos[4, 1], jac)
    assert (jac[:, :2] == 0).all()
    qd = np.array([1.0, 2.0, 0.0, 0.0, -4.0])
    assert link_spin(c, qd, 1) == 3.0 and link_spin(c, qd, 4) == -4.0
    assert fastest_spin(c["joint_types"][:5], c["parents"][:5], qd) == 4.0


def test_the_sims_pymunk_tree_is_the_chain() -> None:
    """linkage_tree in pymunk: its pivots join each link to its parent's tip, its state reads
    back as set, and the update it publishes carries the tree (a CHAINS trailer) that the
    haptic side parses back."""
    scene = load_scene("linkage_tree")
    world = SimWorld(scene)
    q, qd = np.array([0.3, -0.8, 0.9]), np.array([2.0, -3.0, 4.0])
    world.set_tool_state(q, qd)
    q_back, qd_back = world.tool_state()
    np.testing.assert_allclose(q_back, q, atol=1e-15)
    np.testing.assert_allclose(qd_back, qd, atol=1e-14)
    tool = set(world.tool_bodies)
    pivots = [j for j in world.space.constraints if j.b in tool]
    assert len(pivots) == 3
    for j in pivots:
        a = j.a.local_to_world(j.anchor_a)
        b = j.b.local_to_world(j.anchor_b)
        assert np.hypot(a[0] - b[0], a[1] - b[1]) < 1e-15
    mass, _, _ = world.dynamics_terms(q)
    np.testing.assert_allclose(mass, mass_matrix(chain_spec(scene), q), rtol=1e-12)
    parser = UpdateParser()
    assert parser.parse(world.local_model_bytes(1, 0, 0, 0.0)) == 0
    m = parser.out[0]
    assert m["has_chains"] == 1 and list(m["parents"][:3]) == [-1, 0, 0]


def test_the_tree_vm_follows_the_independent_reference() -> None:
    """linkage_tree end to end (pymunk, the wire, the haptic loop at 1 kHz): the VM under
    the 0.4 N push against the tree RNEA solved by solve_ivp, the device starting on the
    operational point. The same run against the serial reading of its links fails by far."""
    scene = load_scene("linkage_tree")
    err = reference_error(scene, 5.0, 60.0)
    assert err["rms_mm"] < VM_RMS_MM, err
    start_on_point = dataclasses.replace(scene, initial_device_offset=(0.0, 0.0, 0.0))
    ticks = run(with_method(start_on_point, "local_model"), 5.0)
    serial = dataclasses.replace(
        start_on_point,
        linkages=tuple(dataclasses.replace(lk, parents=()) for lk in scene.linkages),
    )
    wrong = reference_error_mm(serial, ticks, 5.0)
    wrong_rms = float(np.sqrt(np.mean(wrong**2)))  # 3.4 mm against 0.07 mm
    assert wrong_rms > VM_RMS_MM and wrong_rms > 10 * err["rms_mm"]


@pytest.mark.parametrize("scene", ["linkage_middle", "linkage_tree"])
def test_the_sims_pymunk_linkage_moves_as_the_reference(scene: str) -> None:
    """The sim's linkage, released in pymunk at 2-4 rad/s with no drive, against the RNEA
    reference of its chain over 0.3 s: the pivots sit at the joints and the centres of
    gravity where the chain has them. (Before 0.7, a link's position was set before its angle
    and Chipmunk moved its origin off the joint: 64 mrad and 11% of the energy lost here.)"""
    s = load_scene(scene)
    world = SimWorld(s)
    q0, qd0 = np.array([0.3, -0.8, 0.9]), np.array([2.0, -3.0, 4.0])
    world.set_tool_state(q0, qd0)
    world.space.iterations = 30
    period, steps = 1e-4, 3000
    for _ in range(steps):
        world.space.step(period)
    q, qd = world.tool_state()
    spec = chain_spec(s)
    t_end = period * steps
    ref = simulate(spec, q0, qd0, Hold(np.zeros(3), 1, np.zeros(2)), t_end, np.array([t_end]))
    assert np.abs(q - ref.q[-1]).max() < 2e-3  # rad; pymunk's pivots are iterative
    energy = 0.5 * qd @ mass_matrix(spec, q) @ qd
    assert energy == pytest.approx(0.5 * qd0 @ mass_matrix(spec, q0) @ qd0, rel=1e-3)


@pytest.mark.processes
def test_the_tree_runs_in_real_time_over_zenoh_and_replays_exactly(tmp_path: Path) -> None:
    """linkage_tree as a user runs it: both servers as processes over Zenoh on loopback for
    10 s with the ideal device of seed 000. Every update's tree passes the haptic side's
    check against the scene (D, G, C qd, J_h at the update's q), the branch swings, the VM
    stays on the hand, and the log replays bit for bit."""
    network_file = write_network_file(tmp_path / "net.toml")
    log_path = tmp_path / "run.mcap"
    summary = haptic_run(
        network_file, log_path, tmp_path / "summary.json",
        scene="linkage_tree", device="ideal_identity", user="push_04n", seconds=10.0,
    )  # fmt: skip
    assert set(summary["rejected_by_reason"] or {}) <= {"late"}, summary
    log = read_log(log_path)
    ready = log.ticks[log.ticks["update_seq"] >= 0]
    assert len(ready) >= 0.95 * 10_000
    assert (ready["fault"] == 0).all() and np.isfinite(log.ticks["wrench_command"]).all()
    assert np.ptp(ready["proxy_q"][:, 2]) > 0.2  # rad: the branch swung (0.45 here)
    drift = np.hypot(*(ready["device_pose"][:, :2] - ready["vm_pose"][:, :2]).T)
    assert drift[len(drift) // 2 :].max() < 2e-3  # m: the hand holds the finger
    result = replay(log)
    assert result.identical, result.differing
    assert result.updates_replayed == len(log.updates) > 0


def test_the_sims_drive_turns_a_branch_without_moving_its_siblings() -> None:
    """The sim's computed-torque drive of linkage_tree toward a goal that moves only the
    branch's joint: each joint's reaction goes to the link it hangs from, so the arm and the
    finger stay put (1.4e-5 rad after a step). With the reaction on the link before it in
    the numbering (the serial rule), the finger took it: 29 mrad."""
    world = SimWorld(load_scene("linkage_tree"))
    q0, _ = world.tool_state()
    goal = q0 + np.array([0.0, 0.0, 0.2])
    world.step(
        ToolTarget(
            q=goal, qd=np.zeros(3), device_pose=np.zeros(3), device_twist=np.zeros(3),
            coupled_to_device=False, fresh=True,
        )
    )  # fmt: skip
    q, _ = world.tool_state()
    assert q[2] - q0[2] > 0.03  # the branch turned toward its goal
    assert np.abs(q[:2] - q0[:2]).max() < 1e-4


def test_the_sim_keeps_at_most_half_a_step_of_impulses() -> None:
    """SimWorld's share of the impulses it holds: a step covering 20 ms of haptic time at
    60 Hz keeps 3.3 ms for the next; a 200 ms backlog (a stall) is let out at once but for
    half a step; every impulse is applied exactly once."""
    from haptic_local_model.shared.protocol.proxy import ShapeImpulses

    world = SimWorld(load_scene("god_slabs"))
    period = world.period

    def received(span: float) -> ToolTarget:
        return ToolTarget(
            q=np.zeros(3), qd=np.zeros(3), device_pose=np.zeros(3), device_twist=np.zeros(3),
            coupled_to_device=False, fresh=False,
            impulses=ShapeImpulses(np.array([3]), np.zeros((1, 2)), np.array([[span, 0.0]]), span),
        )  # fmt: skip

    given = applied = 0.0
    for span in (0.020, 0.016, 0.020, 0.200, 0.016, 0.0, 0.0):
        given += span
        out = world._deliver(received(span))
        applied += float(out.impulses[:, 0].sum())
        kept = world.pending_impulses.span_s
        assert kept <= 0.5 * period + 1e-12
    assert applied == pytest.approx(given - float(world.pending_impulses.impulses[:, 0].sum()))
    assert world.pending_impulses.count == 0  # two empty steps drained it

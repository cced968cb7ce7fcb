"""The contact model of seed 001 §3.2 against closed forms: impulses, penalty, friction."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from haptic_local_model.device_models.ideal import IdealDevice, IdealDeviceConfig
from haptic_local_model.haptic_server.engine import HapticEngine
from haptic_local_model.shared.config import UserConfig, load_scene
from haptic_local_model.shared.kinematics import free_body_chain
from haptic_local_model.shared.protocol.layout import CONTACT_FLOATS
from haptic_local_model.shared.protocol.update import ContactSet, LocalModelUpdate, encode_update

MASS, INERTIA = 2.0, 0.01  # a free body (kg, kg m^2)
K_TINY = 1e-9  # contact stiffness small enough that the penalty adds nothing in one tick
EXACT = 1e-12  # impulses are solved exactly when the contacts are independent


def contact_row(
    tool_point, env_point, normal, restitution, friction=0.0, stiffness=K_TINY, damping=0.0,
    env_velocity=(0.0, 0.0),
):  # fmt: skip
    """A contact row in wire order (shared.protocol.layout.CONTACT_COLUMNS); the stick
    stiffness of friction equals the normal stiffness."""
    return [
        *tool_point, *env_point, *normal, *env_velocity, friction, restitution, stiffness,
        damping, stiffness,
    ]  # fmt: skip


def engine_with(q, qd, rows, impulses=True, mass=MASS, inertia=INERTIA, lead_s=0.0) -> HapticEngine:
    """A free body (mass, inertia) at q moving at qd with the given contacts, its state
    holding lead_s after publication; no coupling, no hand force."""
    scene = load_scene("free_box")
    rendering = dataclasses.replace(
        scene.rendering, coordination_stiffness=(0.0, 0.0, 0.0),
        coordination_damping=(0.0, 0.0, 0.0), impulses=impulses, blend_ms=0.0,
    )  # fmt: skip
    scene = dataclasses.replace(scene, rendering=rendering)
    device = IdealDevice(IdealDeviceConfig(inertia=(1.0, 1.0, 1.0), max_wrench=(1e4, 1e4, 1e3)))
    engine = HapticEngine(scene, device, UserConfig(name="none", kind="constant_wrench"))
    engine.unguarded()  # a hand-made model
    jt, lengths = free_body_chain()
    n = len(rows)
    update = LocalModelUpdate(
        epoch=1, seq=0, sim_time=0.0, publish_time_ns=0, joint_types=jt, lengths=lengths,
        base=np.zeros(2), base_angle=0.0, op_link=2, op_point=np.zeros(2), q=np.array(q, float),
        qd=np.array(qd, float), mass_matrix=np.diag([mass, mass, inertia]),
        lambda_inv=np.diag([1 / mass, 1 / mass, 1 / inertia]), tool_pose=np.array(q, float),
        gravity=None, velocity_torque=None, resisted=None, characteristic_length=0.05,
        contacts=ContactSet(np.full(n, 2), np.arange(n), np.reshape(rows, (n, CONTACT_FLOATS))),
        tool_touching=True, state_lead_s=lead_s,
    )  # fmt: skip
    assert engine.receive(encode_update(update)) == ""
    return engine


def after_one_tick(engine: HapticEngine) -> tuple[np.ndarray, np.ndarray]:
    row = engine.tick(1e-3)[0]
    return row["proxy_qd"][:3].copy(), row


@pytest.mark.parametrize("e", [0.0, 0.5, 1.0])
def test_head_on_impact_reverses_normal_velocity_by_restitution(e: float) -> None:
    """A face hitting a wall through the centre line: v+ = -e v-, no rotation (Poisson)."""
    v_minus = -0.5
    eng = engine_with(
        [0.0, 0.0, 0.0],
        [v_minus, 0.0, 0.0],
        [contact_row((-0.03, 0.0), (-0.03, 0.0), (1.0, 0.0), e)],
    )
    qd, row = after_one_tick(eng)
    assert row["n_colliding"] == 1
    np.testing.assert_allclose(qd, [-e * v_minus, 0.0, 0.0], atol=EXACT)


@pytest.mark.parametrize("e", [0.0, 0.8])
def test_corner_with_two_contacts_resolves_both_together(e: float) -> None:
    """A box moving into a corner (walls with normals +x and +y through its centre lines)."""
    v = np.array([-0.3, -0.4, 0.0])
    rows = [
        contact_row((-0.03, 0.0), (-0.03, 0.0), (1.0, 0.0), e),
        contact_row((0.0, -0.02), (0.0, -0.02), (0.0, 1.0), e),
    ]
    qd, row = after_one_tick(engine_with([0.0, 0.0, 0.0], v, rows))
    assert row["n_colliding"] == 2
    np.testing.assert_allclose(qd, [-e * v[0], -e * v[1], 0.0], atol=EXACT)


def test_one_contact_keeps_what_it_does_not_resist_and_conserves_momentum() -> None:
    """A corner of a spinning, sliding box hits a wall (normal +x): fewer contacts than DOF.

    The impulse acts along the normal only: tangential momentum is unchanged, the change of
    linear momentum equals the impulse, the change of angular momentum equals r x impulse,
    and the contact point leaves with -e times its approach speed.
    """
    e = 0.3
    r = np.array([-0.03, -0.02])  # contact point relative to the COM (body at angle 0)
    v = np.array([-0.5, 0.2, 0.3])
    qd, row = after_one_tick(engine_with([0.0, 0.0, 0.0], v, [contact_row(r, r, (1.0, 0.0), e)]))
    assert row["n_colliding"] == 1
    dv = qd - v
    impulse = MASS * dv[:2]
    assert abs(impulse[1]) < EXACT and impulse[0] > 0  # along the normal, pushing out
    np.testing.assert_allclose(INERTIA * dv[2], r[0] * impulse[1] - r[1] * impulse[0], atol=EXACT)
    point_vx = lambda w: w[0] - w[2] * r[1]  # noqa: E731 - velocity of the contact point along x
    np.testing.assert_allclose(point_vx(qd), -e * point_vx(v), atol=EXACT)


def test_impulse_rendered_to_the_user_over_one_tick() -> None:
    """The felt impulse force is M_d J_h D^-1 P_cs / dt (DESIGN §4.1): here M_d = I, J_h = I."""
    v_minus = -0.5
    eng = engine_with(
        [0.0, 0.0, 0.0],
        [v_minus, 0.0, 0.0],
        [contact_row((-0.03, 0.0), (-0.03, 0.0), (1.0, 0.0), 0.0)],
    )
    qd, row = after_one_tick(eng)
    dt = 1e-3
    np.testing.assert_allclose(row["f_impulse"], (qd - np.array([v_minus, 0, 0])) / dt, rtol=1e-12)


def test_no_impulse_without_approach_or_when_disabled() -> None:
    rows = [contact_row((-0.03, 0.0), (-0.03, 0.0), (1.0, 0.0), 0.5)]
    _, row = after_one_tick(engine_with([0.0, 0.0, 0.0], [0.2, 0.0, 0.0], rows))  # separating
    assert row["n_colliding"] == 0
    qd, row = after_one_tick(engine_with([0.0, 0.0, 0.0], [-0.5, 0.0, 0.0], rows, impulses=False))
    assert row["n_colliding"] == 0 and qd[0] < 0


def test_penalty_force_closed_form() -> None:
    """Continuous contact: F = K (-gap) - B v_n along the normal (seed 001 eq 8)."""
    k, b = 15000.0, 20.0
    depth, v_n = 1e-4, -0.01
    rows = [
        contact_row((-0.03, 0.0), (-0.03 + depth, 0.0), (1.0, 0.0), 0.0, stiffness=k, damping=b)
    ]
    eng = engine_with([0.0, 0.0, 0.0], [v_n, 0.0, 0.0], rows, impulses=False)
    _, row = after_one_tick(eng)
    np.testing.assert_allclose(
        row["contact_force_world"][:2], [k * depth - b * v_n, 0.0], rtol=1e-12
    )


def test_coulomb_friction_sticks_then_slips() -> None:
    """Sliding contact: the tangential force never exceeds mu f_n; a slow tangential motion
    sticks (spring-like, below the cone), a fast one slips at exactly mu f_n."""
    k, mu, depth = 15000.0, 0.4, 1e-3
    f_n = k * depth
    rows = [
        contact_row((0.0, -0.02), (0.0, -0.02 + depth), (0.0, 1.0), 0.0, friction=mu, stiffness=k)
    ]
    eng = engine_with([0.0, 0.0, 0.0], [1e-4, 0.0, 0.0], rows, impulses=False)  # creeping
    _, row = after_one_tick(eng)
    f_t = row["contact_force_world"][0]
    assert -mu * f_n < f_t < 0  # sticking: opposes the motion, inside the cone
    eng = engine_with([0.0, 0.0, 0.0], [0.5, 0.0, 0.0], rows, impulses=False)  # sliding fast
    _, row = after_one_tick(eng)
    np.testing.assert_allclose(row["contact_force_world"][:2], [-mu * f_n, f_n], rtol=1e-9)


K_DEEP, LEAD_S = 15000.0, 0.01  # N/m; the state holds 10 ms after publication (age -10 ms)


@pytest.mark.parametrize(("speed", "rendered"), [(1.0, 0.0), (0.3, 0.005), (0.0, 0.008)])
def test_a_contact_the_install_carried_into_the_proxy_renders_only_what_it_was_not(
    speed: float, rendered: float
) -> None:
    """A new contact 8 mm deep at the proxy once its wall, leaving the tool at `speed`, is
    carried back the 10 ms to now: of the depth, the carry's speed x 10 ms (all of it at
    1 m/s, 3 mm at 0.3 m/s, none for a still wall) was drawn by the install and is not
    rendered (install.carried_in); the rest is, F = K (depth - carry). At the wall's
    state the tool is 2 mm clear of it at 1 m/s (the case of a ball the sim's hand struck)."""
    depth = 0.008
    at_state = depth - speed * LEAD_S  # how deep the tool is at the time the state holds
    rows = [
        contact_row(
            (-0.03, 0.0), (-0.03 + at_state, 0.0), (1.0, 0.0), 0.0, stiffness=K_DEEP,
            env_velocity=(-speed, 0.0),
        )
    ]  # fmt: skip
    _, row = after_one_tick(engine_with([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], rows, lead_s=LEAD_S))
    np.testing.assert_allclose(row["penetration"], depth, rtol=1e-9)  # the geometry's depth
    np.testing.assert_allclose(row["contact_force_world"][:2], [K_DEEP * rendered, 0.0], atol=1e-9)


def test_a_carried_contact_gives_back_no_energy_as_its_wall_leaves() -> None:
    """The 1 m/s wall of the test above, over 20 ticks: its depth shrinks at 1 mm a tick and
    the depth not rendered with it, so the free body, at rest, is never pushed (the whole
    depth rendered would push it with K d^2 / 2v = 0.48 N s: to 0.24 m/s, 0.06 J from
    nothing)."""
    rows = [
        contact_row(
            (-0.03, 0.0), (-0.03 - 0.002, 0.0), (1.0, 0.0), 0.0, stiffness=K_DEEP,
            env_velocity=(-1.0, 0.0),
        )
    ]  # fmt: skip
    eng = engine_with([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], rows, lead_s=LEAD_S)
    for _ in range(20):
        qd, row = after_one_tick(eng)
        assert row["contact_force_world"][0] == 0.0
    np.testing.assert_array_equal(qd, [0.0, 0.0, 0.0])
    assert row["n_active"] == 0  # the wall has left the tool: 8 mm in 10 ms at 1 m/s, + 2 mm

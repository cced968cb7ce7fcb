"""The mass-spring hand (DESIGN-WAVE2 §7; haptic_server/stages/hand.py) against closed
forms: V5.1-V5.4 (benchmarks/hand.py), the tree's D(q) in the loop, the corrected spring
signs, the glove's gate, and a NaN target."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from haptic_local_model.benchmarks.hand import (
    CONTACT,
    LIMITS,
    _crossed,
    fingertip_press,
    free_space,
    implicit_sweep,
    post_sweeps,
    press,
    two_hands_hold,
    two_hands_twist,
)
from haptic_local_model.haptic_server.stages.hand import hand_chain, hand_records, hand_tick
from haptic_local_model.shared.config import ConfigError, load_config_text
from haptic_local_model.shared.kinematics import MAX_DOF
from haptic_local_model.shared.port_config import FingerSpec, HandSpec


def test_v5_1_free_space_tracking_matches_the_closed_form():
    r = free_space()
    assert abs(r["sine_error_fraction"]) <= 0.02
    assert abs(r["ramp_relative_m"]) <= 1e-6
    assert r["ramp_absolute_m"] == pytest.approx(r["ramp_absolute_expected_m"], rel=0.01)


def test_v5_2_a_palm_pressed_into_a_floor_settles_at_the_series_springs_closed_form():
    r = press()
    assert abs(r["separation_error_fraction"]) <= 0.01
    assert abs(r["force_error_fraction"]) <= 0.01


def test_v5_2_a_fingertip_pressed_on_a_post_deflects_its_joints_by_tau_over_k():
    """The post's force and the resting joints against scipy's static equilibrium of the
    same springs and contact; the joints' deflections against -tau / k_j; and no tick-to-tick
    chatter at rest (with contacts at theta of the step, a 4 g phalanx on a 15 kN/m post
    flipped in and out of contact every tick, 8e-5 rad, twice the mean force each time in)."""
    for flex in (0.005, 0.02, 0.05):
        r = fingertip_press(flex)
        assert r["reference_residual"] < 1e-9
        assert r["force_error_fraction"] <= 1e-6, r
        assert r["reference_deflection_error_fraction"] <= 1e-6, r
        assert r["tau_over_k_error_fraction"] <= 0.01, r
        assert r["settled_cycle_rad"] <= 1e-12, r
        assert min(r["deflection_rad"]) > 0.0, r  # the post holds both joints back


def test_v5_3_drives_far_above_the_explicit_limit_only_lose_energy():
    for row in implicit_sweep((1.0, 100.0)):
        assert row["held_steps"] == 0, row
        assert row["largest_rise_j"] <= 1e-12, row
        assert row["energy_last_j"] < 1e-6 * row["energy_first_j"], row


def test_v5_4_a_fingertip_swept_at_1_m_s_never_passes_a_2_mm_post():
    r = post_sweeps(trials=200)
    assert r["passed_through"] == 0
    assert r["deepest_m"] < 0.5 * r["combined_radius_m"]


def test_a_post_crossing_a_phalanx_between_two_ticks_counts_as_passed():
    """The pass-through test itself: a straight finger whose palm jumps 2 mm past a post
    on its first phalanx's line counts; one that stops 0.5 mm short does not."""
    spec = HandSpec(fingers=(FingerSpec(rest=(0.0, 0.0)),))
    chain = hand_chain(spec)
    post = (0.03, 0.001)  # 10 mm along the first phalanx, 1 mm above its line
    rows = np.zeros((2, MAX_DOF))
    rows[1, 1] = 0.002
    assert _crossed(chain, rows, post, spec.dof)
    rows[1, 1] = 0.0005
    assert not _crossed(chain, rows, post, spec.dof)


def test_the_springs_pull_the_proxy_toward_the_tracked_hand():
    """Seed 004's eqs 4.2-4.3 push the proxy away; here one step toward a target 1 mm to
    the right and 0.1 rad more flexed moves the palm right and the joint up, and the
    user feels the reactions (the device pulled left)."""
    chain, model, data = hand_records(HandSpec(), [], CONTACT, (0.0, 0.0, 0.0), LIMITS, 0.001)
    d = data[0]
    d["target"][0] = 0.001
    d["target"][3] += 0.1
    q0 = d["q"].copy()
    hand_tick(chain, model, data)
    assert d["q"][0] > q0[0] and d["q"][3] > q0[3]
    assert d["command"][0] < 0.0
    assert d["glove_ungated"][3] < 0.0


def test_a_unilateral_glove_only_holds_a_finger_back():
    """Finger 0 flexes positively: a proxy finger blocked short of the tracked angle is
    felt (the glove resists the flexion); one pushed past it is not (a tendon cannot pull
    the finger closed). A bilateral glove renders both."""
    for glove, felt_past in (("unilateral", False), ("bilateral", True)):
        spec = HandSpec(glove=glove)
        chain, model, data = hand_records(spec, [], CONTACT, (0.0, 0.0, 0.0), LIMITS, 0.001)
        d = data[0]
        d["target"][3] += 0.2  # tracked more flexed: the proxy lags, the glove resists
        hand_tick(chain, model, data)
        assert d["glove_torque"][3] < 0.0
        d["target"][3] -= 0.4  # tracked less flexed than the proxy
        for _ in range(3):
            hand_tick(chain, model, data)
        assert d["glove_ungated"][3] > 0.0
        assert (d["glove_torque"][3] != 0.0) == felt_past


def test_the_hands_inertia_is_the_tree_s_at_its_configuration():
    """A unit force on the palm's x at rest, no springs, fingers straight along x: every
    phalanx rides along (the force runs through their free joints), so the palm
    accelerates at 1 / (the whole hand's mass)."""
    straight = FingerSpec(rest=(0.0, 0.0))
    spec = HandSpec(palm_spring=(0.0, 0.0, 0.0), palm_damping=(0.0,) * 3, joint_spring=0.0,
                    joint_damping=0.0, fingers=(straight, straight))  # fmt: skip
    chain, model, data = hand_records(spec, [], CONTACT, (0.0, 0.0, 0.0), LIMITS, 0.001)
    d = data[0]
    mass = spec.palm_mass + sum(sum(f.masses) for f in spec.fingers)
    # a force along x through the tracked-palm channel: a spring 1 N/m, target 1 m ahead
    model[0]["spring"][0] = 1.0
    d["target"][0] = 1.0
    hand_tick(chain, model, data)
    assert d["qd"][0] / 0.001 == pytest.approx(1.0 / mass, rel=1e-3)


def test_a_target_that_is_not_finite_never_reaches_the_device():
    chain, model, data = hand_records(HandSpec(), [], CONTACT, (0.0, 0.0, 0.0), LIMITS, 0.001)
    d = data[0]
    d["target"][0] = 0.001  # a 0.5 N pull along x
    d["target"][1] = math.nan
    hand_tick(chain, model, data)
    assert np.all(np.isfinite(d["command"])) and np.all(np.isfinite(d["q"]))
    assert d["command"][1] == 0.0 and d["command"][0] < -0.4  # y cut, x rendered
    assert d["invalid"] == 1 and d["singular"] == 0
    d["target"][1] = 0.0
    hand_tick(chain, model, data)
    assert d["invalid"] == 1 and np.all(np.isfinite(d["command"]))


def test_a_bad_hand_table_names_its_key():
    with pytest.raises(ConfigError) as err:
        load_config_text(HandSpec, 'glove = "tendon"', "hand.toml")
    assert "hand.toml" in str(err.value) and "glove" in str(err.value)
    with pytest.raises(ConfigError) as err:
        load_config_text(HandSpec, "[[fingers]]\nradius = -1.0", "hand.toml")
    assert "fingers[0].radius" in str(err.value)


def test_a_finger_spec_is_a_dataclass_the_loader_takes():
    spec = load_config_text(HandSpec, "[[fingers]]\nlengths = [0.03, 0.02]", "hand.toml")
    assert spec.fingers == (dataclasses.replace(FingerSpec(), lengths=(0.03, 0.02)),)


def test_v5_5_two_hands_hold_the_box_as_in_v4_1():
    r = two_hands_hold()
    assert r["contacts_tracked"] == 4 and r["contacts_at_hold"] == 4
    assert r["slip_max_m"] <= 0.1e-3
    assert r["balance_max_fraction"] <= 0.01
    assert r["contact_losses"] == 0 and r["held_steps"] == 0
    assert abs(r["box_drop_m"]) < 1e-5


def test_two_hands_squeezing_below_the_cone_let_the_box_fall():
    """0.4 N a side holds 2 mu N = 0.4 N of the box's 0.98 N: it slides out of the grip."""
    r = two_hands_hold(duration_s=0.5, squeeze_n=0.4)
    assert r["box_drop_m"] > 0.005


def test_two_hands_twist_the_box_with_the_line_through_their_palms():
    r = two_hands_twist()
    assert r["held_steps"] == 0
    assert r["box_angle_rad"] > 0.03
    assert r["box_angle_rad"] == pytest.approx(r["palm_line_rad"], abs=0.002)

"""A user's own pymunk space, touchable (issue 44): the public API, the checks of what a space
may hold, the one local-model builder, and an offline run that replays bit for bit."""

from __future__ import annotations

import importlib.util
import math
import warnings
from pathlib import Path

import numpy as np
import pymunk
import pytest

from haptic_local_model import api
from haptic_local_model.benchmarks.user_chain import plain_arm
from haptic_local_model.shared.config import load_scene
from haptic_local_model.shared.protocol.layout import MAX_CONTACTS
from haptic_local_model.shared.protocol.update import decode_update
from haptic_local_model.sim_server.user_space import UserSpaceWorld
from haptic_local_model.sim_server.world import SimWorld

#: the held finger: heavy enough for the coordination coupling's default gains (a body of at
#: least 0.07 kg and 3.75e-4 kg m^2 at 1 kHz: lighter ones are softened, with a warning)
RADIUS_M, MASS_KG, MOMENT_KG_M2 = 0.01, 0.1, 5e-4


def _finger(space: pymunk.Space, at: tuple[float, float] = (0.0, 0.0)) -> pymunk.Body:
    body = pymunk.Body(MASS_KG, MOMENT_KG_M2)
    body.position = at
    space.add(body, pymunk.Circle(body, RADIUS_M))
    return body


def _wall_space() -> tuple[pymunk.Space, pymunk.Body, pymunk.Segment]:
    """A finger 5 mm from a static wall (x = 0.015 plus its 5 mm half-thickness)."""
    space = pymunk.Space()
    wall = pymunk.Segment(space.static_body, (0.02, -0.1), (0.02, 0.1), 0.005)
    wall.friction, wall.elasticity = 0.4, 0.3
    space.add(wall)
    return space, _finger(space), wall


# --- what a space may hold ------------------------------------------------------------------


def test_the_api_exposes_no_records_or_numba_types() -> None:
    """Every public name is a class, a function, or a Material: no numpy structured dtype,
    no numba dispatcher."""
    for name in api.__all__:
        obj = getattr(api, name)
        assert not isinstance(obj, np.ndarray | np.dtype), name
        assert "numba" not in type(obj).__module__, name


@pytest.mark.parametrize("kind", [pymunk.Body.STATIC, pymunk.Body.KINEMATIC])
def test_a_static_or_kinematic_tool_is_refused_by_name(kind: int) -> None:
    space = pymunk.Space()
    body = pymunk.Body(body_type=kind)
    space.add(body, pymunk.Circle(body, RADIUS_M))
    word = "static" if kind == pymunk.Body.STATIC else "kinematic"
    with pytest.raises(api.UnsupportedSpaceError, match=rf"tool Body #0 is {word}: a hand"):
        api.check_space(space, body)


def test_a_tool_of_zero_mass_is_refused() -> None:
    space = pymunk.Space()
    body = pymunk.Body()  # mass from shapes' densities: none given
    space.add(body, pymunk.Circle(body, RADIUS_M))
    with pytest.raises(api.UnsupportedSpaceError, match=r"has mass 0\.0: the tool needs"):
        api.check_space(space, body)


def test_a_tool_of_zero_radius_is_refused() -> None:
    space = pymunk.Space()
    body = pymunk.Body(MASS_KG, 1e-6)
    space.add(body, pymunk.Circle(body, 0.0))
    with pytest.raises(api.UnsupportedSpaceError, match=r"tool shape Circle #0 .* zero size"):
        api.check_space(space, body)


def test_a_world_shape_of_zero_radius_warns_it_is_a_point() -> None:
    space = pymunk.Space()
    space.add(pymunk.Circle(space.static_body, 0.0, (0.05, 0.0)))
    tool = _finger(space)
    with pytest.warns(api.SpaceWarning, match=r"shape Circle #0 .* zero size: rendered as a point"):
        api.check_space(space, tool)


def test_nan_positions_are_refused_by_body() -> None:
    space = pymunk.Space()
    tool = _finger(space)
    other = pymunk.Body(1.0, 1.0)
    other.position = (math.nan, 0.0)
    space.add(other, pymunk.Circle(other, 0.01))
    with pytest.raises(api.UnsupportedSpaceError, match=r"Body #1: .* not finite"):
        api.check_space(space, tool)


def test_a_spring_on_the_tool_warns_it_is_not_felt() -> None:
    space = pymunk.Space()
    tool = _finger(space)
    space.add(pymunk.DampedSpring(space.static_body, tool, (0, 0), (0, 0), 0.0, 10.0, 1.0))
    with pytest.warns(api.SpaceWarning, match=r"DampedSpring #0 on the tool: not rendered"):
        api.check_space(space, tool)


def test_a_pin_joint_on_the_tool_is_refused_by_name() -> None:
    space = pymunk.Space()
    tool = _finger(space)
    space.add(pymunk.PinJoint(space.static_body, tool, (0.05, 0.0), (0.0, 0.0)))
    with pytest.raises(api.UnsupportedSpaceError, match=r"PinJoint #0 joins the held body"):
        api.check_space(space, tool)


def test_a_link_pivoted_off_its_origin_is_refused() -> None:
    space = pymunk.Space()
    tool = _finger(space)
    space.add(pymunk.PivotJoint(space.static_body, tool, (0.0, 0.0), (0.01, 0.0)))
    with pytest.raises(api.UnsupportedSpaceError, match=r"a link's origin must be its pivot"):
        api.check_space(space, tool)


def test_a_held_chain_builds_our_linkage_scenes_model() -> None:
    """Seed 000's three-link arm (linkage_distal) in a plain space, its distal link held: the
    same D, G, Λ⁻¹, resisted directions, q and tool pose as the scene's own world builds
    (the same kernels over the same numbers, to rounding)."""
    scene = load_scene("linkage_distal")
    ours = SimWorld(scene)
    ours.model.build()
    space = pymunk.Space()
    arm = plain_arm(space, scene.tool_linkage)
    theirs = UserSpaceWorld(space, arm[scene.tool.link])
    theirs.model.build()
    a, b = ours.model.record[0], theirs.model.record[0]
    assert int(b["dof"]) == 3 and theirs.stats.svd
    for f in ("q", "mass", "gravity", "lambda_inv", "tool_pose", "lengths", "parents"):
        np.testing.assert_allclose(b[f], a[f], rtol=1e-9, atol=1e-12, err_msg=f)
    assert int(a["n_resisted"]) == int(b["n_resisted"])


def test_a_sensor_is_not_rendered_and_says_so() -> None:
    space, tool, wall = _wall_space()
    wall.sensor = True
    with pytest.warns(api.SpaceWarning, match=r"Segment #0 .* is a sensor: not rendered"):
        assert api.check_space(space, tool) == []


def test_a_tool_off_its_centre_of_gravity_is_refused() -> None:
    space = pymunk.Space()
    tool = _finger(space)
    tool.center_of_gravity = (0.01, 0.0)
    with pytest.raises(api.UnsupportedSpaceError, match=r"centre of gravity at \(0\.01, 0\.0\)"):
        api.check_space(space, tool)


# --- the one builder ------------------------------------------------------------------------


def test_the_local_model_is_the_walls_gap_and_the_shapes_own_friction() -> None:
    """The finger 5 mm from the wall's face: one contact, gap 5 mm (closed form), normal
    -x (from the wall to the tool), the wall's friction and restitution, D = diag(m, m, I)."""
    space, tool, _ = _wall_space()
    world = UserSpaceWorld(space, tool)
    world.model.build()
    m = world.model.record[0]
    assert int(m["n_contacts"]) == 1
    gap = m["c_normal"][0] @ (
        _tool_point_world(tool, m["c_tool"][0]) - m["c_env"][0]
    )  # n . (tool - env)
    assert gap == pytest.approx(0.015 - 0.01 - 0.0, abs=1e-9)  # wall face 0.015, finger 0.01
    np.testing.assert_allclose(m["c_normal"][0], [-1.0, 0.0], atol=1e-12)
    assert float(m["c_friction"][0]) == pytest.approx(0.4)
    assert float(m["c_restitution"][0]) == pytest.approx(0.3)
    np.testing.assert_allclose(np.diag(m["mass"][:3, :3]), [MASS_KG, MASS_KG, MOMENT_KG_M2])


def _tool_point_world(body: pymunk.Body, local: np.ndarray) -> np.ndarray:
    return np.array(body.local_to_world(tuple(local)))


def test_a_scene_world_and_a_user_space_build_the_same_model() -> None:
    """The testbed_free_tool scene's world, and a plain space holding the same bodies as a
    user would build them: the same contacts (gaps, normals, frictions) from the one
    builder. The user's space is the scene world's own space, its tool named by body."""
    scene = load_scene("testbed_free_tool")
    ours = SimWorld(scene)
    ours.set_tool_state(np.array([-0.01, 0.0, 0.0]), np.zeros(3))  # 5 mm from the block
    ours.model.build()
    # the scene's own rotational coupling is softer than a user space's default (the box's
    # 1.04e-4 kg m^2 is below the default's 3.75e-4): softened, and said so
    with pytest.warns(api.SpaceWarning, match=r"at least 0.000375 kg m\^2\): its coupling"):
        theirs = UserSpaceWorld(
            ours.space, ours.tool_bodies[0], margin_m=scene.tool.neighbourhood_margin_m
        )
    theirs.model.build()
    a, b = ours.model.record[0], theirs.model.record[0]
    n = int(a["n_contacts"])
    assert n == int(b["n_contacts"]) and n > 0
    fields = ("c_tool", "c_env", "c_normal", "c_link", "c_friction", "c_stiffness", "mass")
    for f in (*fields, "tool_pose"):
        np.testing.assert_array_equal(
            a[f][:n] if f.startswith("c_") else a[f], b[f][:n] if f.startswith("c_") else b[f]
        )


# --- offline --------------------------------------------------------------------------------


def test_a_held_body_too_light_for_the_coordination_coupling_is_softened_not_chattering() -> None:
    """A 50 g disc alone in the space, moved by the hand at 8 cm/s: with the default
    coordination gains its proxy step is unstable (K dt^2 + 2 B dt = 0.14 > 2 m = 0.1) and
    the ideal device was commanded +-50 N tick by tick, with no fault. The gains are
    softened to 80 % of the bound, with a warning naming the body: the device follows the
    proxy (within a micron) and, at constant speed, needs no force."""
    space = pymunk.Space()
    tool = pymunk.Body(0.05, pymunk.moment_for_circle(0.05, 0.0, RADIUS_M))
    space.add(tool, pymunk.Circle(tool, RADIUS_M))
    with pytest.warns(api.SpaceWarning, match=r"Body #0: the held body \(0.05 kg.*softened"):
        run = api.run_offline(space, tool, 2.0, user="push_block")
    cruise = (run.times_s > 0.5) & (run.times_s < 1.5)  # the hand at 8 cm/s
    assert not run.faults.any() and run.n_contacts.max() == 0
    assert np.abs(run.wrench_command[cruise, :2]).max() < 0.05  # was 50 N
    assert np.abs(run.proxy_pose[:, :2] - run.device_pose[:, :2]).max() < 1e-5
    assert abs(run.device_pose[-1, 0] - 0.12) < 1e-3  # the hand's 12 cm, followed


@pytest.mark.slow
def test_an_offline_run_touches_the_space_and_replays_bit_for_bit(tmp_path: Path) -> None:
    """A finger pushed into a free ball on the virtual clock: the ball moves (the proxy's
    pushes reach the user's body), no fault, and the log replays identically."""
    space = pymunk.Space()
    ball = pymunk.Body(0.2, pymunk.moment_for_circle(0.2, 0.0, 0.02))
    ball.position = (0.04, 0.0)
    space.add(ball, pymunk.Circle(ball, 0.02))
    tool = _finger(space)
    log = tmp_path / "touch.mcap"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing in this space is rendered differently
        run = api.run_offline(space, tool, 3.0, user="push_block", log=log)
    assert run.updates == 3 * 60
    assert not run.faults.any()
    assert run.n_contacts.max() >= 1
    assert ball.position.x > 0.04 + 0.005, ball.position  # pushed at least 5 mm
    assert api.replays_identically(log)


@pytest.mark.slow
@pytest.mark.parametrize("gap_m", [0.017, 0.025, 0.03])
def test_a_ball_the_hand_strikes_gives_the_device_no_energy(tmp_path: Path, gap_m: float) -> None:
    """The hand driven down at 0.5 m/s (ram_wall) onto a free ball gap_m below it, no
    gravity, on the virtual clock. The sim's hand strikes it within a step and it leaves at
    its new velocity; the update carries it back to the tick's time along that velocity,
    11-25 mm into the proxy (the geometry's penetration). That depth is not rendered
    (stages/install.py carried_in): the passivity observer never trips. Rendered, its
    spring gave the device 0.52-2.2 J and tripped the observer (5-11 fault ticks at these
    gaps), as pymunk's bouncing balls did live; the log replays bit for bit."""
    space = pymunk.Space()
    space.collision_slop = 1e-4
    tool = pymunk.Body(1.0, 1.0e-3)  # the ideal device's, as in the bouncing balls example
    space.add(tool, pymunk.Circle(tool, RADIUS_M))
    ball = pymunk.Body(0.1, pymunk.moment_for_circle(0.1, 0.0, 0.025))
    ball.position = (0.0, -(RADIUS_M + 0.025 + gap_m))
    shape = pymunk.Circle(ball, 0.025)
    shape.elasticity = 0.95
    space.add(ball, shape)
    log = tmp_path / "strike.mcap"
    run = api.run_offline(space, tool, 1.0, user="ram_wall", log=log)
    ticks = api.read_arrays(log).ticks.rows
    assert ticks["penetration"].max() > 0.01  # the carry drew the struck ball into the proxy
    assert ball.velocity.y < -0.5, ball.velocity  # struck: it left the hand
    assert not run.faults.any(), np.unique(run.faults)
    assert api.replays_identically(log)


# --- the examples ---------------------------------------------------------------------------

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


@pytest.mark.slow
def test_the_bouncing_balls_example_runs_offline_and_replays_identically(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """examples/touch_bouncing_balls.py as a user runs it: 3 s on the virtual clock with the
    ideal device and the swing user; the disc touches the platform or a ball, no fault, and
    its log replays bit for bit (so the README's example cannot rot)."""
    example = load_example("touch_bouncing_balls")
    log = tmp_path / "balls.mcap"
    assert example.main(["--seconds", "3", "--log", str(log)]) == 0
    out = capsys.readouterr().out
    assert "180 local models" in out and "faults 0" in out, out
    touching = int(out.split("touching ")[1].split(" %")[0])
    assert touching > 0, out
    assert api.replays_identically(log)


@pytest.mark.slow
def test_a_hundred_thousand_shapes_under_the_tool_give_a_bounded_finite_model() -> None:
    """100,000 small discs, a few thousand of them overlapping the held disc: the model keeps
    the nearest MAX_CONTACTS, counts the overlaps it dropped, and its bytes decode with the
    protocol's validating parser (every number finite)."""
    space = pymunk.Space()
    rng = np.random.default_rng(0)
    for x, y in rng.uniform(-0.05, 0.05, (100_000, 2)):
        space.add(pymunk.Circle(space.static_body, 0.001, (float(x), float(y))))
    tool = pymunk.Body(1.0, 1.0e-3)
    space.add(tool, pymunk.Circle(tool, RADIUS_M))
    world = UserSpaceWorld(space, tool)
    update = decode_update(world.local_model_bytes(1, 0, 0))
    assert update.contacts.count == MAX_CONTACTS
    assert np.isfinite(update.contacts.floats).all()
    assert world.stats.hits_dropped > 0


def test_a_shape_added_or_removed_later_is_seen_at_the_next_local_model() -> None:
    """A wall added 5 mm from the finger after the start is one contact in the next local
    model, its friction clipped to the scene's material (the highest of the space's shapes
    at the start, 0.4 here); removed, it is gone again."""
    space, tool, _ = _wall_space()
    tool.position = (-0.1, 0.0)  # away from the first wall
    world = UserSpaceWorld(space, tool)
    world.local_model_bytes(1, 0, 0)
    assert world.stats.contacts_sent == 0
    late = pymunk.Segment(space.static_body, (-0.075, -0.1), (-0.075, 0.1), 0.005)
    late.friction = 0.9
    space.add(late)
    world.local_model_bytes(1, 1, 0)
    m = world.model.record[0]
    assert world.stats.contacts_sent == 1
    assert float(m["c_friction"][0]) == pytest.approx(0.4)
    space.remove(late)
    world.local_model_bytes(1, 2, 0)
    assert world.stats.contacts_sent == 0


@pytest.mark.slow
def test_a_held_chain_runs_offline_and_replays_bit_for_bit(tmp_path: Path) -> None:
    """linkage_distal's arm in a plain space, its distal link held by the swing user for 3 s:
    every update installed (none refused by the scene's checks), no fault, replay identical."""
    scene = load_scene("linkage_distal")
    space = pymunk.Space()
    arm = plain_arm(space, scene.tool_linkage)
    log = tmp_path / "arm.mcap"
    run = api.run_offline(space, arm[scene.tool.link], 3.0, log=log)
    assert run.updates == 3 * 60 and run.refused == {}
    assert not run.faults.any()
    assert api.replays_identically(log)


def load_example(name: str):  # type: ignore[no-untyped-def]
    """examples/<name>.py as a module (the examples are scripts, not a package)."""
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    assert spec is not None and spec.loader is not None
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    return example


@pytest.mark.slow
@pytest.mark.parametrize("name", ["touch_vertical_stack", "touch_pyramid"])
def test_a_pixel_example_runs_offline_in_si_and_replays_identically(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str
) -> None:
    """pymunk's box2d_vertical_stack and box2d_pyramid, their spaces built in pixels and
    rescaled by api.scale_space: 3 s on the virtual clock, the push_block user pushing the
    disc into the boxes; no fault, the log replays bit for bit, and the push is felt (the
    stack gives way: a box moves; the pyramid holds: the disc stops short of the user's 12 cm
    and the device commands the user's push back)."""
    example = load_example(name)
    log = tmp_path / f"{name}.mcap"
    assert example.main(["--seconds", "3", "--log", str(log)]) == 0
    out = capsys.readouterr().out
    assert "180 local models" in out and "faults 0" in out, out
    assert api.replays_identically(log)
    ticks = api.read_arrays(log).ticks
    assert ticks["n_active"].max() > 0, out  # in contact with a box
    if name == "touch_vertical_stack":
        assert int(out.split("boxes moved up to ")[1].split(" mm")[0]) > 5, out
    else:
        travel = ticks["device_pose"][-1, 0] - ticks["device_pose"][0, 0]
        assert 0.0 < travel < 0.05, out
        # push_block's 150 N/m over the rest of its 12 cm: the pyramid pushes back that much
        expected = 150.0 * (0.12 - travel)
        assert ticks["wrench_command"][-1, 0] == pytest.approx(-expected, rel=0.05), out


@pytest.mark.slow
def test_the_notebook_style_script_plots_the_force_that_holds_the_users_push(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """examples/plot_touch_force.py: the plot is written, and the force rendered once the disc
    rests on the wall is the closed form of the user's 150 N/m spring held by a 15 kN/m
    contact: F = 150 (0.12 - 0.035 - F/K), F = 12.75 / (1 + 150/K) N (0.035 m: the wall's
    face 0.045 less the disc's radius)."""
    example = load_example("plot_touch_force")
    out_png = tmp_path / "force.png"
    assert example.main(["--out", str(out_png)]) == 0
    assert out_png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    out = capsys.readouterr().out
    rendered = float(out.split("rendered ")[1].split(" N")[0])
    held = 150.0 * (0.12 - 0.035) / (1.0 + 150.0 / api.DEFAULT_CONTACT.stiffness_n_per_m)
    assert rendered == pytest.approx(-held, rel=1e-3), out


def test_a_sim_server_over_a_users_space_sums_up_its_run() -> None:
    """The sim server's summary over a user's space (as `touch` runs it): its figures, and
    no god-object shapes clamped (a user's space has none; a clean-clone CI once found the
    summary reading them from a world that has no such attribute, and every live run of a
    user's space failed at its end)."""
    from haptic_local_model.shared.net.config import NetworkConfig
    from haptic_local_model.sim_server.server import SimServer

    space, tool, _ = _wall_space()
    world = UserSpaceWorld(space, tool)
    summary = SimServer(world.scene, NetworkConfig(), world=world).summary()
    assert summary["steps"] == 0 and summary["twists_clamped"] == 0

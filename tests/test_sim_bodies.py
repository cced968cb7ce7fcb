"""The sim's bodies in the co-simulation (DESIGN-WAVE2 §6): walls whose pose and twist come
from the sim each tick, met at 1 kHz by the co-simulated bodies with the wall's velocity in
the contact (friction, damping and the first-touch impulse), the wall's mass infinite."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from haptic_local_model.haptic_server.stages.cosim import (
    MAX_COSIM_BODIES,
    carry_sim_bodies,
    cosim_records,
    cosim_tick,
)
from haptic_local_model.shared.config import BodySpec, ConfigError, load_config_text, resolve
from haptic_local_model.shared.port_config import MAX_SIM_BODIES, PortSceneConfig, load_port_scene

LIMITS = [(50.0, 50.0, 6.0), (50.0, 50.0, 6.0)]


@pytest.fixture(scope="module")
def scene() -> PortSceneConfig:
    return load_port_scene("grasp_vertical")


def _with_sim_body(
    scene: PortSceneConfig, body: BodySpec, gravity, walls: tuple[BodySpec, ...] = ()
) -> PortSceneConfig:
    """The scene's couplings cut, its pads put far out of reach (x = -/+0.9 m), `walls`
    added, and `body` the sim's."""
    ports = tuple(
        dataclasses.replace(p, coupling_stiffness=(0.0,) * 3, coupling_damping=(0.0,) * 3)
        for p in scene.ports
    )
    bodies = []
    for b in scene.bodies:
        if b.name.startswith("pad"):
            b = dataclasses.replace(b, position=(0.9 if "right" in b.name else -0.9, 0.0))
        bodies.append(b)
    return dataclasses.replace(
        scene,
        ports=ports,
        bodies=(*bodies, *walls, body),
        sim_bodies=(body.name,),
        sim_contact="shape",
        gravity=gravity,
    )


def _sample(pose, twist) -> np.ndarray:
    s = np.zeros((MAX_SIM_BODIES, 6))
    s[0, :3], s[0, 3:] = pose, twist
    return s


def test_a_box_on_a_moving_belt_is_dragged_at_mu_g_until_it_moves_with_it(scene):
    """A belt (a sim body, 0.4 m wide) under the resting box moves at 0.1 m/s from t = 0,
    its pose carried on by its twist from one sample. Friction drags the box at mu g
    (4.905 m/s^2) until it moves with the belt (v / mu g = 20.4 ms), then it rides along:
    the belt's velocity is in the stick spring's slip and the contact's damping."""
    v, mu, g = 0.1, scene.contact.friction, 9.81
    belt = BodySpec(name="belt", kind="dynamic", shape="box", material="wall",
                    size=(0.4, 0.02), position=(0.0, -0.02), mass=1.0)  # fmt: skip
    sc = _with_sim_body(scene, belt, (0.0, -g))
    model, data = cosim_records(sc, LIMITS)
    box = 3 * len(sc.ports)
    sample = _sample((0.0, -0.02, 0.0), (0.0, 0.0, 0.0))
    for _ in range(300):  # settle on the belt at rest
        carry_sim_bodies(model, data, sample, 0.0)
        cosim_tick(model, data)
    assert abs(data[0]["qd"][box]) < 1e-9
    sample = _sample((0.0, -0.02, 0.0), (v, 0.0, 0.0))
    dt = float(data[0]["dt"])
    vx = []
    for k in range(100):
        carry_sim_bodies(model, data, sample, k * dt)
        cosim_tick(model, data)
        vx.append(float(data[0]["qd"][box]))
    vx = np.array(vx)
    sliding = np.arange(2, 17)  # well inside the 20.4 ms the drag takes
    slope = np.polyfit(sliding * dt, vx[sliding], 1)[0]
    assert slope == pytest.approx(mu * g, rel=0.03)
    # the stick spring's transient (548 rad/s, damped) is over by 45 ms; without the
    # wall's motion in the implicit step the box rode in a limit cycle, 0.088 to 0.102 m/s
    assert np.all(vx[45:] == pytest.approx(v, rel=1e-3))
    # the stick springs catch it with an overshoot (their damping ratio is 0.55): 4.2 %
    assert vx.max() < 1.05 * v
    assert abs(data[0]["qd"][box + 1]) < 1e-4  # nothing lifts it off the belt


def test_a_wall_moving_into_a_free_box_leaves_it_at_the_wall_s_speed(scene):
    """g = 0: a sim body (a 30 mm disc, infinite mass to the co-simulation) meets the box
    at 0.2 m/s. The first-touch impulse (e = 0) takes the wall's velocity: after it, the box
    moves at the wall's speed along the normal, to 1e-9. Without the wall's twist in the
    contact it would stay at rest (a static wall approaches nothing)."""
    v = 0.2
    disc = BodySpec(name="pusher", kind="dynamic", shape="circle", material="wall",
                    radius=0.015, position=(-0.2, 0.0), mass=1.0)  # fmt: skip
    sc = _with_sim_body(scene, disc, (0.0, 0.0))
    model, data = cosim_records(sc, LIMITS)
    box = 3 * len(sc.ports)
    dt = float(data[0]["dt"])
    # its edge reaches the box's left face (x = -0.02) half a tick's travel into tick 20
    x0 = -0.02 - 0.015 - (20 - 0.5) * v * dt
    sample = _sample((x0, 0.0, 0.0), (v, 0.0, 0.0))
    for k in range(20):  # tick k meets the disc at x0 + (k + 1) v dt
        assert data[0]["collisions"] == 0 and data[0]["qd"][box] == 0.0
        carry_sim_bodies(model, data, sample, (k + 1) * dt)
        cosim_tick(model, data)
    assert data[0]["collisions"] == 1
    assert data[0]["qd"][box] == pytest.approx(v, abs=1e-9)
    assert data[0]["qd"][box + 1] == pytest.approx(0.0, abs=1e-9)  # through the centre
    assert data[0]["qd"][box + 2] == pytest.approx(0.0, abs=1e-9)


def test_a_wall_pushing_the_box_along_a_floor_meets_its_friction(scene):
    """The box on a static floor, a sim body (a 30 mm disc: its centre is a vertex pressing
    into the box, the moving wall's side first in the contact) pushing it along at 0.1 m/s
    against the floor's friction: the box slides with the disc, steadily, the disc's
    contact as deep as the friction asks. The moving wall's springs in the implicit step
    (`_wall_motion`) make it so: without them the contact sinks 0.13 mm."""
    v, g = 0.1, 9.81
    floor = BodySpec(name="floor", kind="static", shape="segment", material="wall",
                     a=(-0.5, -0.015), b=(0.5, -0.015), radius=0.005)  # fmt: skip
    disc = BodySpec(name="pusher", kind="dynamic", shape="circle", material="wall",
                    radius=0.015, position=(-0.2, 0.0), mass=1.0)  # fmt: skip
    sc = _with_sim_body(scene, disc, (0.0, -g), (floor,))
    model, data = cosim_records(sc, LIMITS)
    box = 3 * len(sc.ports)
    dt = float(data[0]["dt"])
    x0 = -0.02 - 0.015 + 0.0001  # 0.1 mm into the box's left face
    vx = []
    for k in range(600):
        xd = x0 + v * k * dt
        carry_sim_bodies(model, data, _sample((xd, 0.0, 0.0), (v, 0.0, 0.0)), 0.0)
        cosim_tick(model, data)
        vx.append(float(data[0]["qd"][box]))
    vx = np.array(vx[300:])
    assert np.all(vx == pytest.approx(v, rel=1e-3))
    assert np.ptp(vx) < 1e-6  # steady: no limit cycle
    # the disc's push is the floor's friction, mu (m g - F_t), F_t the vertical stick force
    # the disc's contact takes (statically indeterminate, |F_t| <= mu f_n): its depth is
    # within mu m g / (1 +- mu^2) / k. Without the wall's motion in the step it is 0.13 mm.
    d = data[0]
    disc_element = MAX_COSIM_BODIES + int(model[0]["n_static"]) - 1
    (h,) = [h for h in range(d["n_hits"]) if d["hit_of"][h, 0] == disc_element]
    mu, k, w = scene.contact.friction, scene.contact.stiffness_n_per_m, 0.1 * g
    assert mu * w / (1 + mu**2) / k < d["hits"][h, 2] < mu * w / (1 - mu**2) / k


def test_the_sim_bodies_are_walls_after_the_static_ones(scene):
    """q holds the co-simulated bodies only; a sim body is the last wall, at its start pose
    and at rest until the sim moves it."""
    disc = BodySpec(name="ball", kind="dynamic", shape="circle", material="wall",
                    radius=0.01, position=(0.0, 0.05), velocity=(1.0, 0.0), mass=0.02)  # fmt: skip
    sc = dataclasses.replace(scene, bodies=(*scene.bodies, disc), sim_bodies=("ball",))
    model, data = cosim_records(sc, LIMITS)
    m, d = model[0], data[0]
    assert m["n_bodies"] == 3 and m["n_static"] == 1 and m["n_sim"] == 1
    assert list(d["wall_pose"][0]) == [0.0, 0.05, 0.0]
    assert not d["wall_twist"].any()
    assert m["rounding"][MAX_COSIM_BODIES] == 0.01


BAD = [
    ('sim_bodies = ["pad_left"]', "sim_bodies[0]"),  # a port's tool
    ('sim_bodies = ["nothing"]', "sim_bodies[0]"),
    ('sim_bodies = ["box", "box"]', "sim_bodies"),
]


@pytest.mark.parametrize(("line", "key"), BAD)
def test_a_bad_sim_body_names_its_key(line, key):
    text = resolve("ports", "grasp_vertical").read_text()
    head, _, rest = text.partition("[contact]")
    with pytest.raises(ConfigError) as err:
        load_config_text(PortSceneConfig, head + line + "\n[contact]" + rest, "scene.toml")
    assert err.value.key == key

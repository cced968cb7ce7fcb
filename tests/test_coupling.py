"""The sim side of virtual_coupling_foh: the substeps the stiff tool-device coupling needs in
pymunk (shared/coupling.py), checked against the map's eigenvalues and against pymunk."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pymunk
import pytest

from haptic_local_model.shared import coupling
from haptic_local_model.shared.config import ConfigError, SceneConfig, load_dataclass, load_scene
from haptic_local_model.sim_server.world import SimWorld, ToolTarget

SCENES = Path(__file__).resolve().parent.parent / "configs" / "scenes"
#: The tool settles on a fixed device pose: the spring's steady error is zero, the slow pole
#: K / B = 10/s leaves 1 mm * e^-20 after 2 s; pymunk's own round-off is ~1e-12 m.
SETTLED_M = 1e-7
SETTLED_RAD = 1e-6


def semi_implicit_radius(mass: float, stiffness: float, damping: float, h: float) -> float:
    """Spectral radius of one semi-implicit Euler step of m xdd = -K x - B xd."""
    a = np.array(
        [
            [1.0 - h * h * stiffness / mass, h * (1.0 - h * damping / mass)],
            [-h * stiffness / mass, 1.0 - h * damping / mass],
        ]
    )
    return float(np.max(np.abs(np.linalg.eigvals(a))))


@pytest.mark.parametrize(
    "mass, stiffness, damping",
    [(3.0, 1e5, 1e4), (6.5e-3, 800.0, 20.0), (0.5, 1e5, 0.0), (1.0, 0.0, 50.0), (2.0, 1e3, 1.0)],
)
def test_step_limit_is_where_the_semi_implicit_map_turns_unstable(
    mass: float, stiffness: float, damping: float
) -> None:
    h_max = coupling.stable_step_limit(mass, stiffness, damping)
    assert semi_implicit_radius(mass, stiffness, damping, 0.999 * h_max) <= 1.0 + 1e-12
    assert semi_implicit_radius(mass, stiffness, damping, 1.001 * h_max) > 1.0


def test_moments_match_pymunks() -> None:
    assert coupling.box_moment(3.0, 0.16, 0.02) == pytest.approx(
        pymunk.moment_for_box(3.0, (0.16, 0.02)), rel=1e-12
    )
    assert coupling.circle_moment(2.0, 0.05) == pytest.approx(
        pymunk.moment_for_circle(2.0, 0.0, 0.05), rel=1e-12
    )
    a, b = (0.01, -0.02), (0.09, 0.03)
    assert coupling.segment_moment(1.5, a, b, 0.004) == pytest.approx(
        pymunk.moment_for_segment(1.5, a, b, 0.004), rel=1e-12
    )


def test_scene_loader_names_the_substeps_a_coupled_tool_needs(tmp_path: Path) -> None:
    path = SCENES / "maglev_scoop.toml"
    data = tomllib.loads(path.read_text())
    data["sim_substeps"] = 100
    with pytest.raises(ConfigError) as err:
        load_dataclass(SceneConfig, data, str(path))
    message = str(err.value)
    assert "sim_substeps" in message and ">= 112" in message and "scoop" in message
    data["rendering"]["method"] = "local_model"  # no coupling: no such requirement
    load_dataclass(SceneConfig, data, str(path))


def coupled_world(substeps: int) -> tuple[SimWorld, ToolTarget]:
    world = SimWorld(load_scene("maglev_scoop"))
    world.substeps = substeps  # past the loader's check, to see the instability
    target = ToolTarget(
        q=np.zeros(3), qd=np.zeros(3), device_pose=np.array([0.001, 0.0008, 0.01]),
        device_twist=np.zeros(3), coupled_to_device=True, fresh=True,
    )  # fmt: skip
    return world, target


def test_coupled_tool_settles_on_the_device_at_the_scenes_substeps() -> None:
    world, target = coupled_world(load_scene("maglev_scoop").sim_substeps)
    for _ in range(60):  # 2 s at 30 Hz
        world.step(target)
    q, _ = world.tool_state()
    np.testing.assert_allclose(q[:2], target.device_pose[:2], atol=SETTLED_M)
    assert abs(q[2] - target.device_pose[2]) < SETTLED_RAD


@pytest.mark.parametrize("fraction, stable", [(0.9, True), (1.1, False)])
def test_pymunk_turns_unstable_at_the_derived_step_limit(fraction: float, stable: bool) -> None:
    """The limit is sharp in pymunk itself: 10 % inside it the tool still converges, 10 %
    beyond it the tool flies off within 10 sim periods."""
    scene = load_scene("maglev_scoop")
    body = scene.tool_body
    moment = coupling.box_moment(body.mass, *body.size)
    _, h_max = coupling.coupling_substeps(
        scene.sim_rate_hz, body.mass, moment, scene.tool.point,
        scene.rendering.foh_spring_stiffness, scene.rendering.foh_spring_damping,
    )  # fmt: skip
    per_period = 1.0 / (scene.sim_rate_hz * fraction * h_max)
    world, target = coupled_world(math.ceil(per_period) if stable else math.floor(per_period))
    for _ in range(10):
        world.step(target)
    q, _ = world.tool_state()
    error = np.abs(q[:2] - target.device_pose[:2])
    if stable:
        assert np.all(error < 1e-4)  # on its way: 1 mm * e^(-10/s * 0.33 s) = 0.04 mm
    else:
        assert not np.all(error < 1.0)  # metres away, or not finite

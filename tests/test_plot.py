"""`haptic-replay --plot`: the path panel draws the scene's static bodies (from the scene text
the log carries), one patch per body, at their place and size, on equal axes."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib.patches import Circle, Polygon, Rectangle

from haptic_local_model.haptic_server.harness.plot import plot_run, run_figure
from haptic_local_model.haptic_server.log import LogContents
from haptic_local_model.haptic_server.model import TICK_DTYPE
from haptic_local_model.shared.config import SceneConfig, load_config_text

REPO = Path(__file__).resolve().parent.parent
#: a box turned by 30 degrees, a circle, and a dynamic body that is not drawn (the sim's)
EXTRA_BODIES = """
[[bodies]]
name = "post"
kind = "static"
shape = "box"
size = [0.02, 0.01]
position = [-0.04, 0.03]
angle = 0.5235987755982988
material = "wall"

[[bodies]]
name = "pillar"
kind = "static"
shape = "circle"
radius = 0.008
position = [0.0, -0.05]
material = "wall"

[[bodies]]
name = "puck"
kind = "dynamic"
shape = "circle"
radius = 0.01
position = [0.02, 0.02]
material = "tool"
"""


def _log(scene_text: str | None, n: int = 500) -> LogContents:
    """A run's log as read_log returns it: a hand moving 20 mm along x, the VM a little
    behind, every tick after the first update; the scene text in the metadata."""
    ticks = np.zeros(n, TICK_DTYPE)
    ticks["tick"] = np.arange(n)
    ticks["t"] = ticks["tick"] * 1e-3
    ticks["dt"] = 1e-3
    ticks["update_seq"] = np.arange(n) // 17
    ticks["device_pose"][:, 0] = np.linspace(0.0, 0.02, n)
    ticks["vm_pose"][:, 0] = np.linspace(0.0, 0.019, n)
    configs = {"scene": scene_text} if scene_text is not None else {}
    return LogContents(ticks, [], [], {"configs": configs}, True)


@pytest.fixture
def figures() -> Iterator[list[Any]]:
    import matplotlib.pyplot as plt

    made: list[Any] = []
    yield made
    for fig in made:
        plt.close(fig)


def _path_panel(log: LogContents, figures: list[Any]) -> Any:
    fig = run_figure(log)
    figures.append(fig)
    ax = fig.axes[0]
    assert ax.get_title() == "trajectories in the plane"
    return ax


def _statics(ax: Any) -> dict[str, Any]:
    return {p.get_gid(): p for p in ax.patches if p.get_gid()}


@pytest.mark.processes
def test_one_patch_per_static_body_at_its_place_and_size(figures: list[Any]) -> None:
    text = (REPO / "configs" / "scenes" / "wall_push.toml").read_text() + EXTRA_BODIES
    scene = load_config_text(SceneConfig, text, "test scene")
    static = {b.name: b for b in scene.bodies if b.kind == "static"}
    assert set(static) == {"wall", "post", "pillar"}
    ax = _path_panel(_log(text), figures)
    patches = _statics(ax)
    assert set(patches) == set(static)  # the dynamic bodies are not drawn
    assert len(ax.patches) == len(static)
    assert ax.get_aspect() == 1.0  # equal scale on x and y

    def inside(patch: Any, x_m: float, y_m: float) -> bool:
        """Whether the point (in m) is inside the patch as drawn (data coordinates: mm)."""
        to_data = patch.get_patch_transform()
        return bool(patch.get_path().contains_point((x_m * 1e3, y_m * 1e3), to_data))

    wall = patches["wall"]  # a segment 0.2 m long and 1 cm thick at x = 55 mm
    assert isinstance(wall, Polygon)
    assert inside(wall, 0.055, -0.1) and inside(wall, 0.055, 0.1) and inside(wall, 0.059, 0.0)
    assert not inside(wall, 0.061, 0.0) and not inside(wall, 0.055, 0.106)

    post = patches["post"]  # 20 x 10 mm, turned 30 degrees about its centre
    assert isinstance(post, Rectangle)
    c, s = math.cos(math.pi / 6), math.sin(math.pi / 6)
    assert inside(post, -0.04 + 0.0095 * c, 0.03 + 0.0095 * s)  # along its turned long side
    assert not inside(post, -0.04 + 0.0095, 0.03 - 0.0045)  # where an unturned corner would be

    pillar = patches["pillar"]
    assert isinstance(pillar, Circle)
    assert pillar.center == pytest.approx((0.0, -50.0)) and pillar.radius == pytest.approx(8.0)

    labels = ax.get_legend_handles_labels()[1]
    assert labels.count("static bodies") == 1  # one legend entry for all of them


@pytest.mark.processes
def test_the_shipped_demo_scene_draws_its_walls(figures: list[Any]) -> None:
    text = (REPO / "configs" / "scenes" / "testbed.toml").read_text()
    scene = load_config_text(SceneConfig, text, "testbed")
    walls = {b.name for b in scene.bodies if b.kind == "static"}
    assert len(walls) == 4
    ax = _path_panel(_log(text), figures)
    assert set(_statics(ax)) == walls
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    assert x0 < -95 and x1 > 95 and y0 < -95 and y1 > 95  # the whole enclosure is in view


@pytest.mark.processes
@pytest.mark.parametrize("scene_text", [None, "", "not = [toml"])
def test_no_or_a_bad_scene_text_plots_the_paths_alone(
    figures: list[Any], scene_text: str | None
) -> None:
    ax = _path_panel(_log(scene_text), figures)
    assert not ax.patches
    assert len(ax.lines) >= 2  # hand and VM


@pytest.mark.processes
def test_a_long_floor_does_not_shrink_the_path_to_a_dot(figures: list[Any]) -> None:
    text = (REPO / "configs" / "scenes" / "maglev_scoop.toml").read_text()
    ax = _path_panel(_log(text), figures)
    assert _statics(ax)
    x0, x1 = ax.get_xlim()
    assert x1 - x0 < 300  # mm: the floor is 800 mm long, the path 20 mm


@pytest.mark.processes
def test_plot_run_writes_the_figure(tmp_path: Path) -> None:
    text = (REPO / "configs" / "scenes" / "testbed.toml").read_text()
    out = plot_run(_log(text), tmp_path / "sub" / "run.png")
    assert out.stat().st_size > 10_000

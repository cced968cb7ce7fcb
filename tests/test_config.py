"""Bad configs stop the program with exit code 2 and a message naming the file and the key."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from haptic_local_model.shared.config import ConfigError, load_scene, load_user

REPO = Path(__file__).resolve().parent.parent
GOOD_SCENE = (REPO / "configs/scenes/free_box.toml").read_text()


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "scene.toml"
    p.write_text(text)
    return p


def test_shipped_configs_load() -> None:
    for path in sorted((REPO / "configs/scenes").glob("*.toml")):
        assert load_scene(str(path)).name == path.stem
    for path in sorted((REPO / "configs/users").glob("*.toml")):
        load_user(str(path))


def test_unknown_key_is_named(tmp_path: Path) -> None:
    p = _write(tmp_path, GOOD_SCENE.replace("[rendering]\n", "[rendering]\nstiffnes = 3.0\n"))
    with pytest.raises(ConfigError) as err:
        load_scene(str(p))
    assert err.value.source == str(p) and err.value.key == "rendering.stiffnes"
    assert "unknown key" in err.value.problem


def test_wrong_type_is_named(tmp_path: Path) -> None:
    p = _write(tmp_path, GOOD_SCENE.replace("sim_rate_hz = 60.0", 'sim_rate_hz = "fast"'))
    with pytest.raises(ConfigError) as err:
        load_scene(str(p))
    assert err.value.key == "sim_rate_hz" and "expected float" in err.value.problem


def test_nested_list_entry_is_named(tmp_path: Path) -> None:
    p = _write(tmp_path, GOOD_SCENE.replace("size = [0.06, 0.04]", "size = [0.06]"))
    with pytest.raises(ConfigError) as err:
        load_scene(str(p))
    assert err.value.key == "bodies[0].size"


def test_missing_key_and_bad_value(tmp_path: Path) -> None:
    p = _write(tmp_path, GOOD_SCENE.replace('name = "free_box"\n', ""))
    with pytest.raises(ConfigError) as err:
        load_scene(str(p))
    assert err.value.key == "name" and "missing" in err.value.problem
    p = _write(tmp_path, GOOD_SCENE.replace("sim_rate_hz = 60.0", "sim_rate_hz = 5000.0"))
    with pytest.raises(ConfigError) as err:
        load_scene(str(p))
    assert err.value.key == "sim_rate_hz"


@pytest.mark.parametrize(
    ("table", "line"),
    [
        ("devices/ideal.toml", "max_wrench = [nan, 50.0, 5.0]"),
        ("devices/ideal.toml", "max_wrench = [inf, 50.0, 5.0]"),
        ("devices/maglev.toml", "max_wrench = [50.0, 50.0, -inf]"),
        ("scenes/free_box.toml", "haptic_rate_hz = nan"),
    ],
)
def test_nan_and_inf_are_rejected_with_file_and_key(tmp_path: Path, table: str, line: str) -> None:
    """TOML can spell nan and inf; no limit, gain or rate may be either (a NaN force limit
    would pass every `min()` check and command NaN)."""
    from haptic_local_model.device_models.registry import load_device

    key = line.split(" = ")[0]
    text = (REPO / "configs" / table).read_text()
    lines = [
        line if raw.split(" = ")[0] == key else raw for raw in text.splitlines()
    ]  # the first table with the key is the one that holds it in these files
    path = tmp_path / Path(table).name
    path.write_text("\n".join(lines) + "\n")
    assert line in path.read_text()
    loader = load_device if table.startswith("devices") else load_scene
    with pytest.raises(ConfigError) as err:
        loader(str(path))
    assert key in err.value.key, err.value  # e.g. actuators.max_wrench[2]
    assert "finite" in err.value.problem and str(path) in str(err.value)


@pytest.mark.processes
@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--scene", "does_not_exist"], "does_not_exist.toml: file: file not found"),
        (["--scene", "{bad}"], "key 'rendering.stiffnes': unknown key"),
        (["--device", "{bad_device}"], "key 'inertia[0]': expected float"),
    ],
)
def test_cli_exits_2_naming_file_and_key(tmp_path: Path, args: list[str], needle: str) -> None:
    bad = _write(tmp_path, GOOD_SCENE.replace("[rendering]\n", "[rendering]\nstiffnes = 3.0\n"))
    bad_device = tmp_path / "dev.toml"
    bad_device.write_text('model = "ideal"\ninertia = ["heavy", 1.0, 1.0]\n')
    argv = [a.replace("{bad}", str(bad)).replace("{bad_device}", str(bad_device)) for a in args]
    res = subprocess.run(
        [sys.executable, "-m", "haptic_local_model.haptic_server.harness.run", "--duration",
        "1", "--no-log", *argv],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert res.returncode == 2, res.stderr
    assert needle.replace("{bad}", str(bad)) in res.stderr


CROWD = """
[[crowds]]
name = "pebble"
count = {count}
shape = "circle"
radius = 0.004
material = "wall"
region = [[-0.05, -0.05], [0.05, 0.05]]
spacing_m = {spacing}
jitter_m = 0.001
"""


@pytest.mark.parametrize(
    ("count", "spacing", "key", "problem"),
    [
        (500, 0.011, "crowds[0].count", "do not fit the region"),
        (10, 0.009, "crowds[0].spacing_m", "overlapping"),
    ],
)
def test_a_crowd_that_cannot_be_built_is_named(
    tmp_path: Path, count: int, spacing: float, key: str, problem: str
) -> None:
    path = _write(tmp_path, GOOD_SCENE + CROWD.format(count=count, spacing=spacing))
    with pytest.raises(ConfigError) as err:
        load_scene(str(path))
    assert err.value.key == key and problem in err.value.problem, err.value


def test_a_crowd_is_a_grid_of_separate_bodies_the_same_every_time(tmp_path: Path) -> None:
    path = _write(tmp_path, GOOD_SCENE + CROWD.format(count=80, spacing=0.011))
    scene = load_scene(str(path))
    bodies = [b for b in scene.all_bodies if b.name.startswith("pebble_")]
    assert len(bodies) == 80 and bodies == [
        b for b in load_scene(str(path)).all_bodies if b.name.startswith("pebble_")
    ]
    xy = [b.position for b in bodies]
    gaps = [
        ((xa - xb) ** 2 + (ya - yb) ** 2) ** 0.5 for i, (xa, ya) in enumerate(xy)
        for xb, yb in xy[i + 1 :]
    ]  # fmt: skip
    assert min(gaps) > 2 * 0.004  # no two overlap
    assert all(-0.051 <= x <= 0.051 and -0.051 <= y <= 0.051 for x, y in xy)

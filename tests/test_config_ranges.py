"""Every number of every shipped config set to NaN, +-inf, 0, -1 and 1e12, one at a time.

Each is either refused with a one-line ConfigError naming the file and the key (or the key it
must agree with), by the loader or when the device is built, or, if taken, shown harmless:
0.3 s of the virtual clock with it (the scene with the ideal device and the default user,
the device or user on the default scene) in which every update the sim publishes is valid
and the device is commanded only finite wrenches within its limit. Safety-relevant keys (the
watchdog, the ramp, force limits, rates) must refuse every one of these values.
"""

from __future__ import annotations

import copy
import importlib
import math
import shutil
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import tomli_w

from haptic_local_model.device_models.registry import load_device, load_simulated_device
from haptic_local_model.haptic_server.harness.virtual import run_virtual
from haptic_local_model.shared.config import CONFIG_ROOT, ConfigError, load_scene, load_user
from haptic_local_model.shared.net.config import load_network

BAD = {"nan": math.nan, "inf": math.inf, "-inf": -math.inf, "0": 0.0, "-1": -1.0, "1e12": 1e12}
HARMLESS_S = 0.3
DEFAULT_SCENE, DEFAULT_USER = "testbed", "swing"
#: keys whose every bad value must be refused (the rest may be taken if harmless)
SAFETY_KEYS = {
    "network": ("watchdog_ms", "safe_ramp_ms", "proxy_publish_hz", "max_update_age_ms"),
    "devices": ("max_wrench", "max_rate_hz", "torque_limit_nm"),
    "scenes": ("haptic_rate_hz", "sim_rate_hz"),
}
LOADERS = {"scenes": load_scene, "users": load_user, "devices": load_device}


def numbers(d: Any, path: tuple[Any, ...] = ()) -> Iterator[tuple[tuple[Any, ...], Any]]:
    """(path, value) of every number in a TOML document (list entries too)."""
    if isinstance(d, dict):
        for k, v in d.items():
            yield from numbers(v, (*path, k))
    elif isinstance(d, list):
        for i, x in enumerate(d):
            yield from numbers(x, (*path, i))
    elif isinstance(d, int | float) and not isinstance(d, bool):
        yield path, d


def cases() -> Iterator[Any]:
    for kind in ("network", *LOADERS):
        for f in sorted((CONFIG_ROOT / kind).glob("*.toml")):
            for path, _ in numbers(tomllib.loads(f.read_text())):
                yield pytest.param(kind, f.name, path, id=f"{kind}/{f.stem}:{_key(path)}")


def _key(path: tuple[Any, ...]) -> str:
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else p)
    return out


def with_value(data: dict[str, Any], path: tuple[Any, ...], value: float) -> dict[str, Any]:
    out = copy.deepcopy(data)
    node = out
    for p in path[:-1]:
        node = node[p]
    old = node[path[-1]]
    node[path[-1]] = int(value) if isinstance(old, int) and math.isfinite(value) else value
    return out


def harmless(kind: str, path: Path) -> None:
    """0.3 s of the virtual clock with the config at `path`: the sim's every update valid
    (run_virtual raises otherwise), finite wrenches within the device's limit. A value that
    drives the tool beyond the scene's [safety] envelope (a hand's 1e12 N m on a light tool)
    may have some of the sim's updates refused as beyond it, but only after the loop's guard
    sent the device safe by itself, or (virtual_coupling_foh, whose sim couples its tool to
    the device) because the device, started far off, flung the sim's tool."""
    scene = load_scene(str(path) if kind == "scenes" else DEFAULT_SCENE)
    user = load_user(str(path) if kind == "users" else DEFAULT_USER)
    device = load_simulated_device(str(path) if kind == "devices" else "ideal")
    result = run_virtual(scene, device, user, HARMLESS_S)
    limit = np.asarray(device.limits().max_wrench)
    command = result.ticks["wrench_command"]
    assert np.isfinite(command).all(), "a non-finite command"
    assert (np.abs(command) <= limit * (1 + 1e-12)).all(), "a command beyond the limit"
    if result.refused and scene.rendering.method != "virtual_coupling_foh":
        assert (result.ticks["fault"] != 0).any(), f"refused {result.refused} without a trip"


@pytest.mark.parametrize(("kind", "name", "path"), list(cases()))
def test_every_number_refused_by_file_and_key_or_harmless(
    tmp_path: Path, kind: str, name: str, path: tuple[Any, ...]
) -> None:
    data = tomllib.loads((CONFIG_ROOT / kind / name).read_text())
    key = _key(path)
    safety = any(str(p) in SAFETY_KEYS.get(kind, ()) for p in path)
    taken: list[str] = []
    shutil.copytree(CONFIG_ROOT / "credentials", tmp_path / "credentials")  # relative paths
    (tmp_path / kind).mkdir()
    for label, value in BAD.items():
        file = tmp_path / kind / f"{label}-{name}"
        file.write_text(tomli_w.dumps(with_value(data, path, value)))
        try:
            load_network(str(file)) if kind == "network" else LOADERS[kind](str(file))
            if kind == "devices":
                load_simulated_device(str(file))
        except ConfigError as exc:
            message = str(exc)
            assert "\n" not in message
            assert str(file) in message, message
            # the key itself, or the one it must agree with (a cross-field check)
            assert "key '" in message, f"{key} = {label}: {message}"
            continue
        assert not safety, f"{key} = {label} taken: a safety-relevant key"
        taken.append(label)
        if kind != "network":
            harmless(kind, file)


#: each console script's numeric arguments, and the values they may take of BAD
CLI_NUMBERS = [
    ("haptic_local_model.haptic_server.cli", "--duration", ()),
    ("haptic_local_model.haptic_server.cli", "--haptic-rate", ()),
    ("haptic_local_model.sim_server.cli", "--duration", ()),
    ("haptic_local_model.haptic_server.harness.run", "--duration", ()),
    ("haptic_local_model.haptic_server.harness.run", "--haptic-rate", ()),
    ("haptic_local_model.haptic_server.harness.soak", "--minutes", ()),
    ("haptic_local_model.haptic_server.harness.soak", "--segment-s", ()),
    ("haptic_local_model.haptic_server.harness.replay", "--view-seconds", ()),
    (
        "haptic_local_model.haptic_server.harness.replay",
        "--view-speed",
        ("0",),
    ),  # 0: draw all at once
]


@pytest.mark.parametrize(("module", "flag", "allowed"), CLI_NUMBERS)
def test_every_numeric_argument_refuses_bad_numbers_in_one_line(
    capsys: pytest.CaptureFixture[str], module: str, flag: str, allowed: tuple[str, ...]
) -> None:
    main = importlib.import_module(module).main
    extra = ["log.mcap"] if module.endswith("replay") else []
    for label in BAD:
        if label in allowed:
            continue
        with pytest.raises(SystemExit) as exc:
            main([*extra, f"{flag}={label}"])  # = : argparse reads "-1" as a flag otherwise
        assert exc.value.code == 2, f"{module} {flag} {label}"
        err = capsys.readouterr().err.strip().splitlines()
        assert "Traceback" not in "\n".join(err)
        assert flag in err[-1] and "must be a finite number" in err[-1], err[-1]


def test_a_log_directory_and_a_garbage_endpoint_are_refused_by_name(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for module in (
        "haptic_local_model.haptic_server.cli",
        "haptic_local_model.haptic_server.harness.run",
    ):
        with pytest.raises(SystemExit) as exc:
            importlib.import_module(module).main(["--log", str(tmp_path)])
        assert exc.value.code == 2
        assert "argument --log" in capsys.readouterr().err.strip().splitlines()[-1]
    net = tmp_path / "net.toml"
    net.write_text('namespace = "x"\n[haptic]\nlisten = ["garbage"]\n')
    with pytest.raises(ConfigError, match=r"key 'haptic.listen\[0\]'.*not a Zenoh endpoint"):
        load_network(str(net))


@pytest.mark.parametrize(
    ("name", "stiffness", "damping", "key"),
    [
        ("god_object", 1e12, 2.0, "god_object_stiffness"),  # it loaded with damping raised
        ("god_object", 1e12, 5e8, "god_object_stiffness"),  # to match K dt / 2 (issue 48)
        ("god_object", 1e6, 1e6, "god_object_damping"),
        ("virtual_coupling", 5e8, 3.0, "virtual_coupling_stiffness"),
        ("coordination", 100.0, 3e5, "coordination_damping"),
    ],
)
def test_a_gain_no_device_could_render_stably_is_refused_by_its_key(
    name: str, stiffness: float, damping: float, key: str
) -> None:
    """The device-side spring-dampers must satisfy K dt^2 + 2 B dt < 4 m on the heaviest
    device admitted (SceneConfig._check_gains); a scene file past it is refused naming the
    file and the key, and the shipped scenes are within it."""
    import dataclasses

    scene = load_scene("god_testbed")
    dims = 2 if name == "god_object" else 3
    change = {f"{name}_stiffness": (stiffness,) * dims, f"{name}_damping": (damping,) * dims}
    with pytest.raises(ValueError, match=f"rendering.{key}: .* gives [KB] <"):
        dataclasses.replace(scene, rendering=dataclasses.replace(scene.rendering, **change))


@pytest.mark.parametrize(
    ("mass", "moment", "refused"),
    [
        (0.065, 5e-4, r"coordination_damping: \(100, 70\) on axis 0 .* 'rectangle' of 0.065 kg"),
        (0.072, 5e-4, None),  # quiet on the ideal device (0.065 kg: +-50 N a tick, no fault)
        (0.5, 1.1e-5, None),
        (0.5, 1e-5, r"coordination_damping: \(0.05, 0.01\) on axis 2 .* 1e-05 kg m\^2"),
    ],
)
def test_a_held_body_too_light_for_the_coordination_coupling_is_refused_by_its_key(
    mass: float, moment: float, refused: str | None
) -> None:
    """The coordination coupling acts on the proxy, a copy of the held body: K dt^2 + 2 B dt
    < 2 m on each axis (SceneConfig._check_coordination). wall_push's gains at 1 kHz: a body
    of at least 0.0701 kg, and 1.0025e-5 kg m^2 about its centre (its own rotational
    gains); refused by the key, naming the body."""
    import dataclasses

    scene = load_scene("wall_push")
    bodies = tuple(
        dataclasses.replace(b, mass=mass, moment_kg_m2=moment) if b.name == scene.tool.name else b
        for b in scene.bodies
    )
    if refused is None:
        assert dataclasses.replace(scene, bodies=bodies).tool_body.mass == mass  # loads
        return
    with pytest.raises(ValueError, match=f"rendering.{refused}"):
        dataclasses.replace(scene, bodies=bodies)

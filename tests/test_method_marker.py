"""The rendering method is a type of the compiled step, not a branch taken at each tick
(stages.tick.method_marker): the engine's records end with a marker, None for the local
model and True for the god-object, and numba compiles into a step only its own method's
tick (chosen on the marker's type as it types the step) and, for the local model, no shape
install of the god-object's. Checked in a process of its own on an empty numba cache, by
the kernels that cache holds after one step of each method."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from haptic_local_model.device_models.registry import load_simulated_device
from haptic_local_model.haptic_server.engine import HapticEngine
from haptic_local_model.haptic_server.stages.tick import method_marker
from haptic_local_model.shared.config import load_scene, load_user, shipped
from haptic_local_model.shared.protocol.codes import Method


@pytest.mark.parametrize("scene", sorted(shipped("scenes")))
def test_every_scenes_engine_carries_its_methods_marker(scene: str) -> None:
    engine = HapticEngine(load_scene(scene), load_simulated_device("ideal"), load_user("swing"))
    marker = engine.recs[-1]
    assert marker is method_marker(engine.method)
    assert (marker is None) == (engine.method != Method.GOD_OBJECT)
    assert engine.loop_recs == (*engine.recs, engine.install)


# an engine's step (simulated_tick -> engine_step -> rendering_tick -> its tick), compiled
# on an empty cache; then the cache's kernel files, one name a line
_COMPILE_STEP = """
from pathlib import Path
import os, sys
from haptic_local_model.device_models.registry import load_simulated_device
from haptic_local_model.haptic_server.engine import HapticEngine
from haptic_local_model.shared.config import load_scene, load_user
engine = HapticEngine(load_scene(sys.argv[1]), load_simulated_device("ideal"), load_user("swing"))
engine.clock[0]["ready"] = 1
engine.tick(engine.dt_nominal)
for f in Path(os.environ["NUMBA_CACHE_DIR"]).rglob("*.nbi"):
    print(f.name)
"""
_GOD_OBJECT_CODE = ("finger.", "god_object.", "train.", "tick.finger_tick")


def _step_kernels(scene: str, cache: Path) -> set[str]:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    res = subprocess.run(
        [sys.executable, "-c", _COMPILE_STEP, scene], env=env, capture_output=True, text=True,
        timeout=300,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    return {name.split("-")[0] for name in res.stdout.split()}


@pytest.mark.slow
def test_a_local_model_step_compiles_no_god_object_code(tmp_path: Path) -> None:
    kernels = _step_kernels("testbed", tmp_path)
    assert {"tick.engine_step", "tick.rendering_tick", "tick.haptic_tick"} <= kernels
    god = sorted(k for k in kernels if k.startswith(_GOD_OBJECT_CODE))
    assert not god, god


@pytest.mark.slow
def test_a_god_object_step_compiles_no_local_model_tick(tmp_path: Path) -> None:
    """The god-object's step holds its tick (finger_tick, the god-object's stage) and not
    the local model's: 37 s of compiling on an empty cache before the choice was made in
    typing, 25 s after (one run each on a quiet 2-core machine)."""
    kernels = _step_kernels("god_rotating_box", tmp_path)
    assert {"tick.engine_step", "tick.rendering_tick", "tick.finger_tick"} <= kernels
    assert "god_object.god_object_step" in kernels
    assert "tick.haptic_tick" not in kernels

"""The rendering method is a type of the compiled step, not a branch taken at each tick
(stages.tick.method_marker): the engine's records end with a marker, None for the local
model and True for the god-object, and numba prunes the god-object's tick and shape install
from a local-model step before it types it. A local-model run compiles no god-object code:
checked in a process of its own on an empty numba cache, by the kernels that cache holds
after it. (A god-object step still holds the local model's tick: not pruned, never run.)"""

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


# a local-model engine's step (simulated_tick -> engine_step -> rendering_tick -> its tick),
# compiled on an empty cache; then the cache's kernel files, one name a line
_COMPILE_LOCAL_STEP = """
from pathlib import Path
import os
from haptic_local_model.device_models.registry import load_simulated_device
from haptic_local_model.haptic_server.engine import HapticEngine
from haptic_local_model.shared.config import load_scene, load_user
engine = HapticEngine(load_scene("testbed"), load_simulated_device("ideal"), load_user("swing"))
engine.clock[0]["ready"] = 1
engine.tick(engine.dt_nominal)
for f in Path(os.environ["NUMBA_CACHE_DIR"]).rglob("*.nbi"):
    print(f.name)
"""


@pytest.mark.slow
def test_a_local_model_step_compiles_no_god_object_code(tmp_path: Path) -> None:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    res = subprocess.run(
        [sys.executable, "-c", _COMPILE_LOCAL_STEP], env=env, capture_output=True, text=True,
        timeout=300,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    kernels = {name.split("-")[0] for name in res.stdout.split()}
    assert {"tick.engine_step", "tick.rendering_tick", "tick.haptic_tick"} <= kernels
    god = sorted(k for k in kernels if k.startswith(("finger.", "god_object.", "train.")))
    assert "tick.finger_tick" not in kernels and not god, god

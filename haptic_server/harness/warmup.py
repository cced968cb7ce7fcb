"""Compile every numba kernel into the on-disk cache (`make warm`), so servers start fast."""

from __future__ import annotations

import time

from device_models.registry import DEVICE_MODELS, load_device
from haptic_server.engine import HapticEngine
from haptic_server.harness.virtual import run_virtual_named
from haptic_server.mailbox import compile_loop_kernels
from haptic_server.realtime import compile_realtime_kernels
from shared.config import load_scene, load_user

#: (scene, user, seconds) run with the ideal device: every rendering stage and the sim
SCENE_RUNS = (("free_box", "waypoints", 1.0), ("testbed", "swing", 1.0),
              ("linkage_distal", "push_04n", 1.0))  # fmt: skip


def warm_runs() -> list[tuple[str, str, str, float]]:
    """The virtual-clock runs that compile everything: (scene, device config, user, s).
    Every registered device model runs the FOH scene, so its kernels are in the cache."""
    runs = [(scene, "ideal", user, s) for scene, user, s in SCENE_RUNS]
    runs += [("maglev_scoop", model.config, "scoop", 0.3) for model in DEVICE_MODELS.values()]
    return runs


def main() -> None:
    started = time.perf_counter()
    for scene, device, user, seconds in warm_runs():
        run_virtual_named(scene, device, user, seconds)
    for model in DEVICE_MODELS.values():  # the real-time loop's kernels, per device model
        engine = HapticEngine(load_scene("testbed"), load_device(model.config), load_user("swing"))
        compile_loop_kernels(engine)
        compile_realtime_kernels(engine)
    print(f"numba kernels ready in {time.perf_counter() - started:.1f} s")


if __name__ == "__main__":
    main()

"""Compile every numba kernel into the on-disk cache (`make warm`), so servers start fast."""

from __future__ import annotations

import time

from device_models.registry import DEVICE_MODELS, load_device
from haptic_server.harness.virtual import run_virtual_named


def main() -> None:
    started = time.perf_counter()
    for device in DEVICE_MODELS:
        load_device(device)
    for scene, user in (
        ("free_box", "waypoints"),
        ("testbed", "swing"),
        ("linkage_distal", "push_04n"),
    ):
        run_virtual_named(scene, "ideal", user, 1.0)
    for device in ("ideal", "twin_pantograph", "maglev"):  # FOH and each device's kernels
        run_virtual_named("maglev_scoop", device, "scoop", 0.3)
    print(f"numba kernels ready in {time.perf_counter() - started:.1f} s")


if __name__ == "__main__":
    main()

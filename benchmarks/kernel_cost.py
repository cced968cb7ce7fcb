"""Cost of the local-model kernel per tick against the number of contacts.

A free body resting on 1..32 penetrating contacts (continuous contact: penalty, damping and
friction every tick), timed two ways: the kernel alone, run N times inside one compiled
loop (its own cost), and one Python call per tick (what the real-time loop pays). Compile
time is reported apart; figures are medians and p99 over repeats. Then the god-object's
cost with 1, 16 and 64 local shapes (benchmarks/god_object.py).

    python -m haptic_local_model.benchmarks.kernel_cost [--ticks 20000]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time

import numpy as np
from numba import njit

from haptic_local_model.benchmarks import god_object
from haptic_local_model.device_models.ideal import IdealDevice, IdealDeviceConfig
from haptic_local_model.haptic_server.engine import HapticEngine
from haptic_local_model.haptic_server.stages.tick import haptic_tick
from haptic_local_model.shared.config import UserConfig, load_scene
from haptic_local_model.shared.kinematics import free_body_chain
from haptic_local_model.shared.protocol.update import (
    ContactSet,
    LocalModelUpdate,
    contact_rows,
    encode_update,
)

TARGET_US = 5.0  # the target for the local-model kernel with 16 contacts


def engine_with_contacts(n: int, press_n: float = 1.0, depth_m: float = 1e-4) -> HapticEngine:
    """A box pressed depth_m into n contact points along a floor by a hand pushing press_n
    down (and 0.5 N sideways); one fixed synthetic local model, no sim."""
    scene = load_scene("free_box")
    scene = dataclasses.replace(scene, rendering=dataclasses.replace(scene.rendering, blend_ms=0.0))
    device = IdealDevice(IdealDeviceConfig())
    engine = HapticEngine(
        scene, device, UserConfig(name="push", kind="constant_wrench", wrench=(0.5, -press_n, 0.0))
    ).unguarded()  # a hand-made model
    jt, lengths = free_body_chain()
    xs = np.linspace(-0.03, 0.03, n)
    floor = -0.02 + depth_m
    rows, floats = contact_rows(n)
    for i, x in enumerate(xs):
        rows[i]["tool"], rows[i]["env"], rows[i]["normal"] = (x, -0.02), (x, floor), (0.0, 1.0)
        rows[i]["friction"], rows[i]["stiffness"], rows[i]["damping"] = 0.3, 15000.0 / n, 20.0 / n
        rows[i]["tangential_stiffness"] = 15000.0 / n
    update = LocalModelUpdate(
        epoch=1, seq=0, sim_time=0.0, publish_time_ns=0, joint_types=jt, lengths=lengths,
        base=np.zeros(2), base_angle=0.0, op_link=2, op_point=np.zeros(2), q=np.zeros(3),
        qd=np.zeros(3), mass_matrix=np.diag([1.0, 1.0, 4.3e-4]), lambda_inv=np.eye(3),
        tool_pose=np.zeros(3), gravity=None, velocity_torque=None, resisted=None,
        characteristic_length=0.05,
        contacts=ContactSet(np.full(n, 2), np.arange(n), floats), tool_touching=True,
    )  # fmt: skip
    assert engine.receive(encode_update(update)) == ""
    return engine


@njit(cache=True)
def _run(model, data, n):
    for _ in range(n):
        haptic_tick(model, data)


def kernel_us(engine: HapticEngine, ticks: int) -> float:
    e = engine
    e.tick(1e-3)
    _run(e.model, e.data, 10)
    start = time.perf_counter_ns()
    _run(e.model, e.data, ticks)
    return (time.perf_counter_ns() - start) / ticks / 1e3


def python_call_us(engine: HapticEngine, ticks: int) -> np.ndarray:
    e = engine
    out = np.zeros(ticks)
    for i in range(ticks):
        t0 = time.perf_counter_ns()
        haptic_tick(e.model, e.data)
        out[i] = (time.perf_counter_ns() - t0) / 1e3
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--ticks", type=int, default=20000)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    warm = engine_with_contacts(1)
    warm.tick(1e-3)  # data.dt is the tick's step from here on
    _run(warm.model, warm.data, 1)
    print(f"compile / cache load: {time.perf_counter() - t0:.2f} s")
    head = ("contacts", "active", "kernel us/tick", "max", "py call p50", "p99")
    print("".join(f"{h:>15}" for h in head) + "   (kernel: median of repeats)")
    result = {}
    for n in (0, 1, 4, 8, 16, 32):
        eng = engine_with_contacts(max(n, 1)) if n else engine_with_contacts(1)
        if n == 0:
            eng.slots[0]["n_contacts"] = 0
        reps = [kernel_us(eng, args.ticks) for _ in range(args.repeats)]
        calls = python_call_us(eng, args.ticks)
        active = int(eng.row[0]["n_active"])
        result[n] = float(np.median(reps))
        row = (
            n,
            active,
            np.median(reps),
            max(reps),
            np.percentile(calls, 50),
            np.percentile(calls, 99),
        )
        print("".join(f"{v:>15.2f}" if isinstance(v, float) else f"{v:>15}" for v in row))
    verdict = "meets" if result[16] <= TARGET_US else "misses"
    print(f"\n16 contacts: {result[16]:.2f} us per tick ({verdict} the {TARGET_US} us target)\n")
    god_object.report_cost(args.ticks)
    return 0


if __name__ == "__main__":
    sys.exit(main())

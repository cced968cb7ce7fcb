"""hapticbench's stable stiffness (benchmarks/hapticbench.py): for each method and haptic
rate, the stiffest wall it renders without giving the hand energy.

The wall is `wall_push` (a 2 N push into a wall, the ideal device) with the wall's and the
tool's stiffness K and the scene's haptic rate changed, written as a scene file and given
to the method as any case is (a plug-in renders it with no change). At each rate K steps
up a log grid (x GRID_FACTOR from K_LOW) to the first wall that is not stable, then bisects
log K between it and the grid point below. A wall is stable when the run completes (no
error, nothing non-finite), the device's actuators took net energy from the hand over the
run (port energy <= 0: benchmarks/stability.py's criterion, the wall's net work on the
device) and the device never goes STRAYED_M into the wall and comes to rest (its depth varies by less than
RESTS_M over the run's last STEADY_S: no limit cycle) (Isaac Lab's 2 N clip lets the 2 N push through
any wall).

Beside the largest stable K, the stiffness the hand felt there: the push over the device's
mean depth in the wall over the run's last STEADY_S (None if it is not in the wall then). A method whose contact is pymunk's (the
virtual couplings, Isaac Lab's) does not render the wall's K at all (pymunk's contacts are
rigid); what the hand feels is its coupling's stiffness, and the table says so through it.
"""

from __future__ import annotations

import math
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from haptic_local_model.benchmarks.suite_metrics import port_metrics
from haptic_local_model.benchmarks.suite_records import Case, MethodRun, NotApplicableError
from haptic_local_model.benchmarks.wall_push import device_depth
from haptic_local_model.shared.config import CONFIG_ROOT

RATES_HZ = (250.0, 500.0, 1000.0)
K_LOW, K_HIGH = 1e3, 1.6384e7  # N/m: the grid K_LOW * 2^n up to K_HIGH (2^14 K_LOW)
GRID_FACTOR = 2.0
BISECTIONS = 3  # log K between the grid's last stable and first unstable: to 9 %
SECONDS = 4.0
STEADY_S = 0.5  # the felt stiffness: over the run's last STEADY_S
PUSH_N = 2.0  # configs/users/push_2n.toml
STRAYED_M = 0.02
RESTS_M = 5e-4  # a stable wall holds the pushed device: its depth varies less over STEADY_S
SCENE = "wall_push"


@dataclass(frozen=True)
class Probe:
    stiffness: float
    stable: bool
    felt_n_per_m: float  # the push over the device's steady depth (nan if not stable)
    passivity_margin_j: float


def wall_case(stiffness: float, rate_hz: float, folder: Path) -> Case:
    """wall_push with the wall's and the tool's K and the haptic rate changed, as a file."""
    text = (CONFIG_ROOT / "scenes" / f"{SCENE}.toml").read_text()
    text, n = re.subn(r"^stiffness_n_per_m = .*$", f"stiffness_n_per_m = {stiffness!r}", text,
                      flags=re.MULTILINE)  # fmt: skip
    assert n == 2, "wall_push's two materials"
    text = re.sub(r"^haptic_rate_hz = .*$", f"haptic_rate_hz = {rate_hz!r}", text, flags=re.M)
    path = folder / f"{SCENE}_k{stiffness:.0f}_r{rate_hz:.0f}.toml"
    path.write_text(text)
    return Case(f"stiffness {stiffness:g} N/m at {rate_hz:g} Hz", str(path), "ideal", "push_2n",
                SECONDS, "stable: port energy <= 0, bounded", "port_energy_j")  # fmt: skip


def probe(run: Any, stiffness: float, rate_hz: float, folder: Path) -> Probe:
    """One wall rendered by a method's run function: stable or not (module docstring)."""
    case = wall_case(stiffness, rate_hz, folder)
    try:
        result: MethodRun = run(case)
    except NotApplicableError:
        raise
    except Exception:  # a run that fails (a sim out of its bounds) is unstable
        return Probe(stiffness, False, math.nan, math.nan)
    ticks = result.ticks
    finite = all(np.isfinite(ticks[k]).all() for k in ("device_pose", "wrench_command"))
    if not finite:
        return Probe(stiffness, False, math.nan, math.nan)
    depth = device_depth(ticks)
    energy = port_metrics(ticks, 0.2, case.device)
    last = depth[ticks["t"] >= ticks["t"][-1] - STEADY_S]
    rests = float(np.ptp(last)) < RESTS_M
    stable = energy["port_energy_j"] <= 0.0 and float(depth.max()) < STRAYED_M and rests
    steady = last.mean()
    felt = PUSH_N / float(steady) if stable and steady > 0 else math.nan
    return Probe(stiffness, stable, felt, energy["passivity_margin_j"])


def stable_stiffness(run: Any, rate_hz: float, folder: Path) -> dict[str, Any]:
    """The largest stable K at `rate_hz` (None if even K_LOW is not; K_HIGH is the top of
    the search), the stiffness felt there and the probes' count."""
    probes = []
    k = K_LOW
    last: Probe | None = None
    while k <= K_HIGH * (1 + 1e-9):
        p = probe(run, k, rate_hz, folder)
        probes.append(p)
        if not p.stable:
            break
        last, k = p, k * GRID_FACTOR
    else:
        assert last is not None
        return _found(last, len(probes), capped=True)
    if last is None:
        return {"stable_to_n_per_m": None, "felt_n_per_m": None, "capped": False,
                "probes": len(probes)}  # fmt: skip
    lo, hi = last.stiffness, probes[-1].stiffness
    for _ in range(BISECTIONS):
        mid = math.sqrt(lo * hi)
        p = probe(run, mid, rate_hz, folder)
        probes.append(p)
        if p.stable:
            last, lo = p, mid
        else:
            hi = mid
    return _found(last, len(probes), capped=False)


def _found(p: Probe, count: int, capped: bool) -> dict[str, Any]:
    return {
        "stable_to_n_per_m": p.stiffness,
        "felt_n_per_m": None if math.isnan(p.felt_n_per_m) else p.felt_n_per_m,
        "capped": capped,
        "probes": count,
    }


def stiffness_rows(methods: list[Any], rates: tuple[float, ...] = RATES_HZ) -> list[dict]:
    """Every method's stable stiffness at every rate: the result's `stable_stiffness`."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="hapticbench-walls-") as tmp:
        for method in methods:
            for rate in rates:
                try:
                    found = stable_stiffness(method.run, rate, Path(tmp))
                except NotApplicableError as why:
                    rows.append({"method": method.name, "rate_hz": rate,
                                 "not_applicable": str(why)})  # fmt: skip
                    continue
                rows.append({"method": method.name, "rate_hz": rate, **found})
    return rows

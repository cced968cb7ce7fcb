"""Per-tick cost of this build beside an earlier one, in one run, interleaved.

Checks out BASE (a git revision) into a temporary worktree and runs, alternately in the base
tree and in this one, (1) `benchmarks.kernel_cost` (the tick kernel alone and one Python call
per tick, 0..32 contacts) and (2) a real-time run of the two servers (`haptic-run`, `--scene`
(default testbed), default device, with the MCAP log), from which the loop's work per tick is read. With
--stations, instead: `loop_timing --stations` once per repeat in each tree (a shared world and
two stations on loopback, every shipped port scene), the world's and the stations' work per
tick read. With --ports, instead: one tick's cost in grasp_vertical, grasp_clutter and
hand_grasp (each tick one call of the world's compiled ticks, timed inside compiled code),
for a base that did not run those scenes in one real-time process. The order
alternates between repeats so slow spells of a shared host hit both builds; every figure is
the median over repeats. With --fresh-caches each build compiles into a new, empty numba
cache of its own, filled by its warm-up (as a user's first run fills it), instead of the
cache its checkout has already filled (this one's: `make check`'s and every test's).

    python -m haptic_local_model.benchmarks.compare_builds [--base 2ccdfb6] [--repeat 5] [--seconds 10]
        [--scene testbed] [--loop-only]
    python -m haptic_local_model.benchmarks.compare_builds --stations [--base REV] [--repeat 3]
    python -m haptic_local_model.benchmarks.compare_builds --ports [--base REV] [--repeat 3]
        [--fresh-caches]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from haptic_local_model.benchmarks.loop_timing import work_split
from haptic_local_model.haptic_server.log import read_ticks

REPO_ROOT = Path(__file__).resolve().parent.parent
CONTACTS = (0, 1, 4, 8, 16, 32)


def checkout(rev: str) -> Path:
    """A detached worktree of `rev` (reused if it is there already)."""
    sha = subprocess.run(
        ["git", "rev-parse", "--short", rev], cwd=REPO_ROOT, check=True, capture_output=True,
        text=True,
    ).stdout.strip()  # fmt: skip
    tree = Path(tempfile.gettempdir()) / f"hlm-build-{sha}"
    if not (tree / "shared").is_dir():
        subprocess.run(
            ["git", "worktree", "add", "--detach", "--force", str(tree), sha],
            cwd=REPO_ROOT, check=True, capture_output=True,
        )  # fmt: skip
    return tree


_PACKAGES = ("shared", "sim_server", "haptic_server", "device_models", "benchmarks")
#: a tree -> the numba cache it compiles into (--fresh-caches); absent: its own default
CACHES: dict[Path, Path] = {}
_NAMESPACE = "haptic_local_model"


def _namespaced(tree: Path) -> bool:
    """Builds from 0.4 on install their packages under haptic_local_model (pyproject.toml)."""
    return f'"{_NAMESPACE}.shared" = "shared"' in (tree / "pyproject.toml").read_text()


def _env(tree: Path) -> dict[str, str]:
    """The tree's packages shadow the installed ones: the tree itself on the path for a build
    with top-level packages, a tree of links named as the install names them otherwise."""
    env = dict(os.environ)
    root = tree
    if _namespaced(tree):
        root = tree / "build" / "compare"
        (root / _NAMESPACE).mkdir(parents=True, exist_ok=True)
        for package in _PACKAGES:
            link = root / _NAMESPACE / package
            if not link.is_symlink():
                link.symlink_to(tree / package)
    env["PYTHONPATH"] = str(root)
    # each tree keeps its own cache, and names its own cache locator (a build before
    # shared/numba_cache.py cannot import this one's: its warm-up would fail)
    env.pop("NUMBA_CACHE_DIR", None)
    env.pop("NUMBA_CACHE_LOCATOR_CLASSES", None)
    if tree in CACHES:
        env["NUMBA_CACHE_DIR"] = str(CACHES[tree])
    return env


def _module(tree: Path, *candidates: str) -> str:
    """The first of `candidates` (a path under the tree, dotted) that the tree has, named as
    the tree imports it."""
    found = next(
        (c for c in candidates if (tree / Path(*c.split("."))).with_suffix(".py").exists()),
        candidates[-1],
    )
    return f"{_NAMESPACE}.{found}" if _namespaced(tree) else found


def warm(tree: Path) -> None:
    module = _module(tree, "haptic_server.harness.warmup", "haptic_server.warmup")
    subprocess.run(
        [sys.executable, "-m", module], cwd=tree, env=_env(tree), check=True,
        capture_output=True,
    )  # fmt: skip


def kernel_cost(tree: Path, ticks: int) -> dict[int, dict[str, float]]:
    """kernel_cost's table: contacts -> kernel us/tick (median of its repeats), call p50/p99."""
    out = subprocess.run(
        [sys.executable, "-m", _module(tree, "benchmarks.kernel_cost"), "--ticks", str(ticks), "--repeats", "3"],
        cwd=tree, env=_env(tree), check=True, capture_output=True, text=True,
    ).stdout  # fmt: skip
    table: dict[int, dict[str, float]] = {}
    for line in out.splitlines():
        cells = line.split()
        if len(cells) == 6 and cells[0].isdigit():
            kernel, _, p50, p99 = (float(c) for c in cells[2:])
            table[int(cells[0])] = {"kernel_us": kernel, "call_p50_us": p50, "call_p99_us": p99}
    return table


def loop_work(tree: Path, seconds: float, scene: str = "testbed") -> dict[str, float]:
    """Work per tick and lateness of a real-time run of `scene` (the default device), log on;
    work also split into ticks that installed an update and the others (from the run's
    log)."""
    module = _module(tree, "haptic_server.harness.run", "haptic_server.run")
    with tempfile.TemporaryDirectory() as tmp:
        summary = Path(tmp) / "summary.json"
        subprocess.run(
            [
                sys.executable, "-m", module, "--scene", scene, "--duration", str(seconds),
                "--log", str(Path(tmp) / "run.mcap"), "--summary-json", str(summary),
            ],
            cwd=tree, env=_env(tree), check=True, stdout=subprocess.DEVNULL,
        )  # fmt: skip
        s: dict[str, Any] = json.loads(summary.read_text())
        split = work_split(read_ticks(Path(tmp) / "run.mcap"))
    return {
        "work_p50_us": s["work_us"]["p50"],
        "work_p99_us": s["work_us"]["p99"],
        "lateness_p99_us": s["lateness_us"]["p99"],
        "update_ticks_p50_us": split["update_ticks"]["p50"],
        "update_ticks_p99_us": split["update_ticks"]["p99"],
        "other_ticks_p50_us": split["other_ticks"]["p50"],
        "other_ticks_p99_us": split["other_ticks"]["p99"],
    }


def stations_work(tree: Path, seconds: float) -> dict[str, float]:
    """The world's and the stations' work per tick p50 and p99 (the stations': the larger of
    the two) in one `loop_timing --stations` run, per scene."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "stations.json"
        subprocess.run(
            [sys.executable, "-m", _module(tree, "benchmarks.loop_timing"), "--stations",
             "--seconds", str(seconds), "--repeat", "1", "--json", str(out)],
            cwd=tree, env=_env(tree), check=True, stdout=subprocess.DEVNULL,
        )  # fmt: skip
        runs = json.loads(out.read_text())["runs"]
    figures: dict[str, float] = {}
    for scene, (run,) in runs.items():
        for pct in ("p50", "p99"):
            figures[f"{scene} {pct}"] = float(run["world"]["work_us"][pct])
        for pct in ("p50", "p99"):
            figures[f"{scene} stations {pct}"] = max(
                float(run[p]["work_us"][pct]) for p in ("left", "right")
            )
    return figures


_PORT_TICKS = """
import json
import numpy as np
from numba import njit
from {ns}benchmarks.grasp import squeeze_users
from {ns}device_models.common import refill_noise
from {ns}device_models.registry import load_simulated_device
from {ns}haptic_server import hand_grasp_ports, ports
from {ns}shared.clock import monotonic_ns
from {ns}shared.port_config import load_hand_scene, load_port_scene


@njit
def timed(tick, head, rows, start, ns, ts):
    # each tick its own call of the world's compiled ticks, timed inside compiled code
    for k in range(start, rows.shape[0]):
        t0 = monotonic_ns(ts)
        done = tick(*head, rows, k, k + 1)
        ns[k] = monotonic_ns(ts) - t0
        if done == k:
            return k
    return rows.shape[0]


def cost(run, rows_dtype, period_s, ticks):
    tick, head = ticks_of(run)
    rows = np.zeros(ticks, rows_dtype)
    ns, ts = np.zeros(ticks, np.int64), np.zeros(2, np.int64)
    k = 0  # (timed compiles at its first call, before its clock runs)
    while k < ticks:
        k = timed(tick, head, rows, k, ns, ts)
        if k < ticks:  # a device's noise ran out: refill, and time that tick again
            for dev in run.devices:
                refill_noise(dev.noise, dev.records, period_s)
    us = ns[100:] / 1e3
    return float(np.percentile(us, 50)), float(np.percentile(us, 99))


def ticks_of(run):
    # this build's compiled ticks and their records: the World's (Compiled), or before
    # there was one, the function the benchmarks called
    if hasattr(run, "compiled"):
        return run.compiled.burst, (run.compiled.records,)
    d = tuple(dev.records for dev in run.devices)
    if isinstance(run, ports.PortRun):
        return ports.run_port_ticks, (run.model, run.data, run.io) + d
    grasp = (run.chains, run.models, run.datas, run.gmodel, run.gdata)
    return hand_grasp_ports.run_hand_grasp_ticks, (grasp, run.io, d)


out = {{}}
for scene in ("grasp_vertical", "grasp_clutter"):
    config = load_port_scene(scene)
    run = ports.PortRun(config, users=squeeze_users(config, 2.0))
    figures = cost(run, ports.PORT_ROW_DTYPE, config.period_s, 20000)
    out[scene + " p50"], out[scene + " p99"] = figures
config = load_hand_scene("hand_grasp")
run = hand_grasp_ports.HandGraspRun(config, [load_simulated_device("maglev") for _ in "lr"])
figures = cost(run, hand_grasp_ports.HAND_GRASP_ROW_DTYPE, config.period_s, 5200)
out["hand_grasp p50"], out["hand_grasp p99"] = figures
print(json.dumps(out))
"""


def port_ticks(tree: Path, seconds: float) -> dict[str, float]:
    """One tick of both ports of grasp_vertical and grasp_clutter (the co-simulation and two
    maglev models squeezing 2 N: 20000 ticks) and of hand_grasp (both hands and the box, two
    maglevs: 5200 ticks), each tick its own call of the world's compiled ticks timed inside
    compiled code (clock_gettime around it: what the real-time loop pays, without Python's
    call): p50 and p99 (µs), the first 100 ticks left out. `seconds` is not used."""
    code = _PORT_TICKS.format(ns=f"{_NAMESPACE}." if _namespaced(tree) else "")
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=tree, env=_env(tree), check=True,
        capture_output=True, text=True,
    ).stdout  # fmt: skip
    figures: dict[str, float] = json.loads(out.splitlines()[-1])
    return figures


def _median(runs: list[dict[str, float]]) -> dict[str, float]:
    return {k: float(np.median([r[k] for r in runs])) for k in runs[0]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--base", default="2ccdfb6", help="git revision to compare with")
    parser.add_argument("--repeat", type=int, default=5, help="interleaved repetitions")
    parser.add_argument("--seconds", type=float, default=10.0, help="length of each real run")
    parser.add_argument("--ticks", type=int, default=20000, help="ticks per kernel timing")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--loop-only", action="store_true", help="skip kernel_cost")
    parser.add_argument("--scene", default="testbed", help="the real-time runs' scene")
    parser.add_argument("--stations", action="store_true", help="instead: the shared world's work")
    parser.add_argument(
        "--ports", action="store_true", help="instead: a tick's cost in the port and hand scenes"
    )
    parser.add_argument(
        "--fresh-caches", action="store_true", help="each build on a new, empty numba cache"
    )
    args = parser.parse_args(argv)
    trees = {"base": checkout(args.base), "this": REPO_ROOT}
    if not args.fresh_caches:
        return _run(trees, args)
    with tempfile.TemporaryDirectory(prefix="hlm-compare-caches-") as caches:
        CACHES.update({tree: Path(caches) / name for name, tree in trees.items()})
        return _run(trees, args)


def _run(trees: dict[str, Path], args: argparse.Namespace) -> int:
    """Warm both trees, then the comparison `args` asks for."""
    for tree in trees.values():
        warm(tree)
    if args.stations:
        return _compare(trees, args, stations_work, f"of {args.seconds:g} s")
    if args.ports:
        return _compare(
            trees, args, port_ticks, "(each tick a compiled call, timed in compiled code)"
        )
    kernels: dict[str, list[dict[int, dict[str, float]]]] = {k: [] for k in trees}
    loops: dict[str, list[dict[str, float]]] = {k: [] for k in trees}
    for i in range(args.repeat):
        order = list(trees) if i % 2 == 0 else list(reversed(trees))
        for name in order:
            if not args.loop_only:
                kernels[name].append(kernel_cost(trees[name], args.ticks))
            loops[name].append(loop_work(trees[name], args.seconds, args.scene))
            print(f"  {name}: {loops[name][-1]}", file=sys.stderr)
        print(f"repeat {i + 1}/{args.repeat} done", file=sys.stderr)
    result: dict[str, Any] = {
        "base": args.base, "repeat": args.repeat, "kernel": {}, "loop": {}, "loop_runs": loops,
    }  # fmt: skip
    print(f"medians of {args.repeat} interleaved repeats; base = {args.base}")
    print(f"{'contacts':>8} {'kernel us base':>15} {'this':>8} {'call p50 base':>14} {'this':>8}")
    for n in CONTACTS if not args.loop_only else ():
        row = {name: _median([run[n] for run in kernels[name]]) for name in trees}
        result["kernel"][n] = row
        print(
            f"{n:>8} {row['base']['kernel_us']:>15.3f} {row['this']['kernel_us']:>8.3f}"
            f" {row['base']['call_p50_us']:>14.2f} {row['this']['call_p50_us']:>8.2f}"
        )
    for name in trees:
        result["loop"][name] = _median(loops[name])
    b, t = result["loop"]["base"], result["loop"]["this"]
    print(f"\n{'real-time run, log on':<24}{'base':>10}{'this':>10}")
    for key in b:
        print(f"{key:<24}{b[key]:>10.1f}{t[key]:>10.1f}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=2))
    return 0


def _compare(trees: dict[str, Path], args: argparse.Namespace, measure: Any, what: str) -> int:
    """`measure(tree, seconds)` in each tree, interleaved, `--repeat` times: the medians."""
    runs: dict[str, list[dict[str, float]]] = {k: [] for k in trees}
    for i in range(args.repeat):
        for name in list(trees) if i % 2 == 0 else list(reversed(trees)):
            runs[name].append(measure(trees[name], args.seconds))
            print(f"  {name}: {runs[name][-1]}", file=sys.stderr)
    medians = {name: _median(runs[name]) for name in trees}
    print(
        f"work per tick (us), medians of {args.repeat} interleaved runs {what}; base = {args.base}"
    )
    print(f"{'scene':<24}{'base':>10}{'this':>10}")
    for key in medians["base"]:
        print(
            f"{key:<24}{medians['base'][key]:>10.1f}{medians['this'].get(key, float('nan')):>10.1f}"
        )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"base": args.base, "runs": runs, "medians": medians}))
    return 0


if __name__ == "__main__":
    sys.exit(main())

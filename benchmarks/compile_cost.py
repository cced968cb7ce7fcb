"""Where a cold start's compile time goes: per kernel, per compiler pass, per LLVM level.

For each `--opt` level (numba's NUMBA_OPT, 3 by default), one process on a fresh, empty
numba cache compiles a run's kernels as the warm-up does (harness.warmup.run_groups: its two
groups, the sim's and the update's kernels, then the rendering and real-time loop's), one
group after the other so that every second is attributed, and records numba's compile
events (numba.core.event: "numba:compile", one a kernel compiled, and "numba:run_pass",
one a compiler pass). A kernel's or a pass's own time
is its events' time less that of the compiles nested in it (numba compiles a callee while
it types its caller), so the figures add up to the compiling wall time. It prints each
level's wall time per group, the kernels with the most time of their own and the passes'
totals (typing, lowering, inlining, LLVM's optimising and linking, the time outside any
pass).

    python -m haptic_local_model.benchmarks.compile_cost [--scene testbed] [--device ideal]
        [--user swing] [--opt 3 1] [--top 20] [--json F]

Each level compiles everything afresh (about 2.5 minutes a level on one core of a quiet
2-core machine, the demo's kernels).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

#: the passes grouped as the report prints them, by numba's pass names (the rest: "other")
PASS_GROUPS = {
    "typing": ("nopython_type_inference", "partial_type_inference", "nopython_rewrites"),
    "lowering": ("native_lowering", "nopython_backend"),
    "LLVM (optimising, linking, emitting)": ("llvm",),
    "inlining": ("inline_inlinables", "inline_closure_likes", "inline_overloads"),
}


class _Attribution:
    """numba's compile and pass events, nested: each event's own time (less the events
    nested in it), a pass's also counted to the kernel it compiles."""

    def __init__(self, clock: Callable[[], float] = time.perf_counter) -> None:
        self._clock = clock
        self.kernels: dict[str, float] = defaultdict(float)
        self.passes: dict[str, float] = defaultdict(float)
        self.outside_passes = 0.0
        self.compiled = 0
        self._stack: list[list[Any]] = []  # [kind, name, start, its children's time]

    def on_start(self, kind: str, name: str) -> None:
        self._stack.append([kind, name, self._clock(), 0.0])

    def on_end(self) -> None:
        kind, name, start, children = self._stack.pop()
        total = self._clock() - start
        own = total - children
        if self._stack:
            self._stack[-1][3] += total
        if kind == "compile":
            self.kernels[name] += own
            self.outside_passes += own
            self.compiled += 1
            return
        self.passes[name] += own
        kernel = next((f[1] for f in reversed(self._stack) if f[0] == "compile"), None)
        if kernel is not None:
            self.kernels[kernel] += own


def _listen(attribution: _Attribution) -> None:
    from numba.core import event

    class Listener(event.Listener):
        def on_start(self, ev: Any) -> None:
            if ev.kind == "numba:compile":
                fn = ev.data["dispatcher"].py_func
                attribution.on_start("compile", f"{fn.__module__.rsplit('.', 1)[-1]}.{fn.__name__}")
            elif ev.kind == "numba:llvm_lock":  # LLVM at work (optimising, linking, emitting)
                attribution.on_start("pass", "llvm")
            else:
                attribution.on_start("pass", ev.data["name"])

        def on_end(self, ev: Any) -> None:
            attribution.on_end()

    for kind in ("numba:compile", "numba:run_pass", "numba:llvm_lock"):
        event.register(kind, Listener())


def _pass_groups(passes: dict[str, float]) -> dict[str, float]:
    grouped: dict[str, float] = defaultdict(float)
    for name, seconds in passes.items():
        base = name.split(" [", 1)[0]  # numba names a pass "name [the function's name]"
        group = next((g for g, names in PASS_GROUPS.items() if base in names), "other")
        grouped[group] += seconds
    return dict(grouped)


def _child(run: tuple[str, str, str, float], top: int) -> dict[str, Any]:
    """In the measuring process: compile the run's groups, one after the other."""
    attribution = _Attribution()
    _listen(attribution)
    from haptic_local_model.haptic_server.harness import warmup

    groups: dict[str, float] = {}
    started = time.perf_counter()
    for what, compile_group in warmup.run_groups(run):
        t = time.perf_counter()
        compile_group()
        groups[what] = round(time.perf_counter() - t, 1)
    wall = time.perf_counter() - started
    own = sum(attribution.kernels.values())
    ranked = sorted(attribution.kernels.items(), key=lambda kv: -kv[1])
    return {
        "wall_s": round(wall, 1),
        "groups_s": groups,
        "kernels_compiled": attribution.compiled,
        "compiling_s": round(own, 1),  # the kernels' own times, summed: compiling's wall
        "passes_s": {k: round(v, 1) for k, v in _pass_groups(attribution.passes).items()},
        "outside_passes_s": round(attribution.outside_passes, 1),
        "top_kernels_s": [[name, round(s, 2)] for name, s in ranked[:top]],
    }


def _measure(opt: str, run: tuple[str, str, str, float], top: int) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="compile_cost_") as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache, "NUMBA_OPT": opt}
        argv = [sys.executable, "-m", __spec__.name if __spec__ else __name__, "--child",
                "--scene", run[0], "--device", run[1], "--user", run[2], "--top", str(top)]  # fmt: skip
        res = subprocess.run(argv, env=env, capture_output=True, text=True, check=False)
    if res.returncode != 0:
        raise RuntimeError(f"compile_cost at NUMBA_OPT={opt} failed: {res.stderr[-2000:]}")
    figures: dict[str, Any] = json.loads(res.stdout.strip().splitlines()[-1])
    return figures


def _report(results: dict[str, dict[str, Any]], top: int) -> str:
    lines = []
    for opt, r in results.items():
        groups = ", ".join(f"{k} {v} s" for k, v in r["groups_s"].items())
        passes = ", ".join(f"{k} {v} s" for k, v in sorted(r["passes_s"].items()))
        lines += [
            f"NUMBA_OPT={opt}: {r['wall_s']} s, {r['kernels_compiled']} kernels compiled ({groups})",
            f"  compiling {r['compiling_s']} s: {passes}, outside passes {r['outside_passes_s']} s",
            f"  the {top} kernels with the most time of their own (s):",
        ]
        lines += [f"    {s:7.2f}  {name}" for name, s in r["top_kernels_s"][:top]]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--scene", default="testbed")
    parser.add_argument("--device", default="ideal")
    parser.add_argument("--user", default="swing")
    parser.add_argument("--opt", nargs="+", default=["3"], help="numba's NUMBA_OPT levels")
    parser.add_argument("--top", type=int, default=20)
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    run = (args.scene, args.device, args.user, 1.0)
    if args.child:
        print(json.dumps(_child(run, args.top)))
        return 0
    results = {opt: _measure(opt, run, args.top) for opt in args.opt}
    print(_report(results, args.top))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"run": list(run), "levels": results}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

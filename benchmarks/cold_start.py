"""Time to first force on a fresh machine, as a newcomer meets it (issue 45):

1. a clean clone of this checkout's HEAD, a fresh numba cache and no pip or uv cache:
   `make demo` (the venv, its install (uv, else pip), the demo's kernels, 10 s of the two
   servers, the replay and its plot), wall clock, and its parts as it prints them;
2. a second clone in another directory, the same cache: `make demo` again, and how many
   kernels its warm-up compiled (none, if the cache is keyed by the sources and not by the
   checkout's path);
3. `pip install .` (not editable) into a fresh venv, then, from another directory on
   another fresh cache, the first `haptic-run --duration 5`: its wall clock beyond the
   install, and its watchdog trips (a cold first run must not look like a fault).

    python -m haptic_local_model.benchmarks.cold_start [--out docs/bench/cold_start]

Needs git, make, python3 with venv and the package index (it installs from it, uncached,
as a fresh machine does). It takes about five minutes; run it on a quiet machine.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent


def _timed(cmd: list[str], cwd: Path, env: dict[str, str], log: Path) -> tuple[float, str]:
    """Run `cmd` in `cwd` with `env`, its output into `log`: (wall seconds, the output);
    a failure raises, naming the command and where its output is."""
    started = time.perf_counter()
    res = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - started
    log.write_text(res.stdout + res.stderr)
    if res.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} in {cwd} failed ({res.returncode}): see {log}")
    return wall, res.stdout + res.stderr


def _env(cache: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("VIRTUAL_ENV", "PYTHON"))}
    env["PATH"] = ":".join(p for p in env["PATH"].split(":") if ".venv" not in p)
    env.update(NUMBA_CACHE_DIR=str(cache), PIP_NO_CACHE_DIR="1", UV_NO_CACHE="1")
    return env


def _kernels(output: str) -> int:
    """The kernels a warm-up compiled, from its last line (0: all loaded)."""
    found = re.findall(r"numba kernels ready in [\d.]+ s \((\d+) kernels compiled\)", output)
    return int(found[-1]) if found else 0


def _parts(output: str) -> dict[str, float]:
    """The warm-up's own figures: each group's seconds and the total."""
    parts = {
        m[0].strip(): float(m[1]) for m in re.findall(r"^ +(.+?) \.\.\. ([\d.]+) s", output, re.M)
    }
    total = re.findall(r"numba kernels ready in ([\d.]+) s", output)
    if total:
        parts["warm-up total"] = float(total[-1])
    return parts


def _demo(work: Path, name: str, cache: Path, logs: Path) -> dict[str, Any]:
    clone = work / name
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    wall, out = _timed(["make", "demo"], clone, _env(cache), logs / f"{name}-make-demo.log")
    return {"wall_s": round(wall, 1), "kernels_compiled": _kernels(out), "parts_s": _parts(out)}


def _installed_first_run(work: Path, logs: Path) -> dict[str, Any]:
    venv, cache, run_dir = work / "venv", work / "cache-installed", work / "elsewhere"
    run_dir.mkdir()
    env = _env(cache)
    subprocess.run(["python3", "-m", "venv", str(venv)], check=True)
    install, _ = _timed([str(venv / "bin/pip"), "install", "-q", str(ROOT)], work, env,
                        logs / "pip-install.log")  # fmt: skip
    summary = run_dir / "summary.json"
    first, out = _timed(
        [str(venv / "bin/haptic-run"), "--duration", "5", "--summary-json", str(summary)],
        run_dir, env, logs / "first-haptic-run.log",
    )  # fmt: skip
    s = json.loads(summary.read_text())
    return {
        "pip_install_s": round(install, 1),
        "first_run_s": round(first, 1),
        "kernels_compiled": _kernels(out),
        "watchdog_trips": s["watchdog_trips"],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("docs/bench/cold_start"),
                        help="where the JSON and the logs go (default: docs/bench/cold_start)")  # fmt: skip
    args = parser.parse_args(argv)
    if not (ROOT / ".git").exists():
        parser.error(f"{ROOT} is not a git checkout: run it from the project's clone")
    logs = args.out / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="cold-start-") as tmp:
        work = Path(tmp)
        cache = work / "cache"
        first = _demo(work, "first-clone", cache, logs)
        second = _demo(work, "second-clone", cache, logs)
        installed = _installed_first_run(work, logs)
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, check=True,
                          capture_output=True, text=True).stdout.strip()  # fmt: skip
    result = {"build": head, "cpus": os.cpu_count(), "make_demo_fresh": first,
              "make_demo_second_clone": second, "installed": installed}  # fmt: skip
    (args.out / "cold_start.json").write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Which runs the numba cache holds compiled: the marks a warm-up leaves in it.

`make warm` marks every run (ALL_WARMED); a warm-up of one run (`make warm-demo`,
haptic-run's first run of a scene and device) marks that run. haptic-run checks the marks
before it starts anything, so this module imports neither numba nor a kernel's module: a
run whose kernels are cached starts its servers a second sooner.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
from pathlib import Path

#: one run's kernels: (scene, device, user, seconds of the virtual run that compiles them)
Run = tuple[str, str, str, float]
#: what make warm leaves in the cache once every group is compiled
ALL_WARMED = "all"


def run_key(run: Run) -> str:
    """A run's name in the cache's list of warmed runs (its configs, as given)."""
    return hashlib.sha1("\0".join(run[:3]).encode()).hexdigest()[:16]


def mark_warmed(cache: Path, key: str) -> None:
    """Mark `key` (run_key, or ALL_WARMED) compiled in `cache`."""
    with contextlib.suppress(OSError):  # a read-only cache: the next run checks again
        (cache / "warmed").mkdir(parents=True, exist_ok=True)
        (cache / "warmed" / key).touch()


def runs_warmed(run: Run) -> bool:
    """Whether the cache (NUMBA_CACHE_DIR, set when `haptic_local_model.shared` is
    imported) holds `run`'s kernels: make warm has compiled every group, or a warm-up of this
    run has (haptic-run's first-run check)."""
    marks = Path(os.environ["NUMBA_CACHE_DIR"]) / "warmed"
    return (marks / ALL_WARMED).exists() or (marks / run_key(run)).exists()

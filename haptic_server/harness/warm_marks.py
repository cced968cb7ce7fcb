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
import re
import shutil
import time
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
    run has (haptic-run's first-run check). Marks the cache used (prune_builds)."""
    cache = Path(os.environ["NUMBA_CACHE_DIR"])
    mark_used(cache)
    marks = cache / "warmed"
    return (marks / ALL_WARMED).exists() or (marks / run_key(run)).exists()


#: Each build of the sources has its own cache (~150 MB; a change to a kernel's module makes a
#: new build): besides the one in use, a warm-up that compiled keeps the KEEP_BUILDS most
#: recently used and none unused for longer than MAX_UNUSED_DAYS.
KEEP_BUILDS = 4
MAX_UNUSED_DAYS = 14.0
_BUILD_NAME = re.compile(r"[0-9a-f]{12}")  # shared.source_hash()


def mark_used(cache: Path) -> None:
    """Note that a run used `cache` now (haptic-run's check, every warm-up)."""
    with contextlib.suppress(OSError):  # a read-only or not yet made cache
        (cache / "used").touch()


def _last_used(build: Path) -> float:
    """When a build's cache was last used: its `used` mark, else its own time (s, epoch)."""
    for path in (build / "used", build):
        with contextlib.suppress(OSError):
            return path.stat().st_mtime
    return 0.0


def prune_builds(cache: Path, root: Path, now: float | None = None) -> list[tuple[Path, int]]:
    """Remove the other builds' caches in `root` (the project's own numba folder, named by
    their source hash) beyond the KEEP_BUILDS most recently used, or unused for
    MAX_UNUSED_DAYS; never `cache`, and nothing when `cache` is not in `root` (a
    NUMBA_CACHE_DIR of the user's). Returns (folder, bytes) of each removed."""
    if cache.parent != root:
        return []
    now = time.time() if now is None else now
    others = sorted(
        ((_last_used(p), p) for p in root.iterdir()
         if p != cache and p.is_dir() and _BUILD_NAME.fullmatch(p.name)),
        reverse=True,
    )  # fmt: skip
    removed = []
    for rank, (used, build) in enumerate(others):
        if rank < KEEP_BUILDS and now - used <= MAX_UNUSED_DAYS * 86400:
            continue
        size = sum(f.stat().st_size for f in build.rglob("*") if f.is_file())
        shutil.rmtree(build, ignore_errors=True)
        if not build.exists():
            removed.append((build, size))
    return removed

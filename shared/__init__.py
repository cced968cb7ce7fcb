"""Code shared by the sim and the haptic server: config, messages, kinematics, timing.

Importing this package (every package of the project does, first) points numba's on-disk
cache at a directory named by a hash of the project's sources, in the user's cache directory
(`~/.cache/haptic-local-model/numba/<hash>` on Linux; NUMBA_CACHE_DIR overrides it): numba
does not notice that a kernel's callee in another module changed, so without this a stale
compiled kernel could outlive a code change. An install never writes into its own tree. Within
that directory a kernel is cached by its module's place in the project, not by the checkout's
path (shared/numba_cache.py), so another clone or an installed wheel loads what one compiled.
"""

import hashlib
import os
from pathlib import Path

__version__ = "0.13.0"

_ROOT = Path(__file__).resolve().parent.parent
_PACKAGES = ("shared", "haptic_server", "sim_server", "device_models", "benchmarks")


#: What a module of numba kernels says: njit, or the decorators of a paced world kind's
#: kernels and entry point (haptic_server.paced), which a module may use without njit.
_KERNEL_MARKS = (b"njit", b"kind_kernel", b"paced_entry")


def _source_hash() -> str:
    """Hash of the modules that hold numba kernels (numba tracks each file on its own)."""
    digest = hashlib.sha1()
    for package in _PACKAGES:
        for path in sorted((_ROOT / package).rglob("*.py")):
            text = path.read_bytes()
            if any(mark in text for mark in _KERNEL_MARKS):
                digest.update(path.relative_to(_ROOT).as_posix().encode())
                digest.update(text)
    return digest.hexdigest()[:12]


def source_hash() -> str:
    """The hash of the project's sources: it names the numba cache, and the build a log was
    recorded with (a replay is exact only on the same build)."""
    return _source_hash()


def cache_dir() -> Path:
    """The project's directory in the user's cache (platformdirs)."""
    from platformdirs import user_cache_path

    return user_cache_path("haptic-local-model", appauthor=False)


def numba_caches() -> Path:
    """Where the project's numba caches are by default: one folder per build of the sources,
    named by source_hash() (a warm-up prunes the old ones: harness.warm_marks.prune_builds)."""
    return cache_dir() / "numba"


if "NUMBA_CACHE_DIR" not in os.environ:
    os.environ["NUMBA_CACHE_DIR"] = str(numba_caches() / _source_hash())
# the project's kernels cached by their place in the project, not by the checkout's path:
# another clone or an installed wheel of the same sources loads them (shared/numba_cache.py)
NUMBA_CACHE_LOCATORS = (  # the project's, then numba's own, in numba's order
    "haptic_local_model.shared.numba_cache.ProjectCacheLocator,UserProvidedCacheLocator,"
    "InTreeCacheLocator,UserWideCacheLocator,IPythonCacheLocator,ZipCacheLocator"
)
os.environ.setdefault("NUMBA_CACHE_LOCATOR_CLASSES", NUMBA_CACHE_LOCATORS)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # 3x3 algebra: no BLAS thread pools

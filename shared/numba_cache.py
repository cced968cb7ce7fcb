"""Where numba caches the project's kernels: by their module's place in the project, not by
the absolute path of the checkout, so a second clone or an installed wheel loads what another
compiled.

numba's own locator for NUMBA_CACHE_DIR names a module's cache directory by a hash of the
module's absolute directory: the same sources in another checkout (or in site-packages)
compile again. This one names it by the module's directory relative to the project's package
root. What makes reuse safe is numba's own check and the project's: each cache index keeps
the content hash of its source file (numba >= 0.68), and loads nothing for a file that
differs; the whole cache directory is named by the hash of every kernel source
(`haptic_local_model.shared`), since numba does not notice that a callee in another module
changed. `shared/__init__.py` puts this locator first through numba's
NUMBA_CACHE_LOCATOR_CLASSES; functions outside the project go to numba's own locators.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from numba.core import config
from numba.core.caching import UserProvidedCacheLocator

from haptic_local_model.shared import NUMBA_CACHE_LOCATORS

ROOT = Path(__file__).resolve().parent.parent  # the project's package root (shared/..)

LOCATORS = NUMBA_CACHE_LOCATORS  # what shared/__init__ gives numba, this locator first


def project_subpath(py_file: str | os.PathLike[str]) -> str | None:
    """The cache directory's name for a module of the project (its package directory inside
    the project, e.g. `project_haptic_server_stages`); None for a file outside it."""
    try:
        rel = Path(py_file).resolve().parent.relative_to(ROOT)
    except ValueError:
        return None
    return "_".join(("project", *rel.parts))


class ProjectCacheLocator(UserProvidedCacheLocator):
    """numba's NUMBA_CACHE_DIR locator, with the module's place in the project as its
    directory (module docstring)."""

    def __init__(self, py_func: Any, py_file: str) -> None:
        super().__init__(py_func, py_file)
        subpath = project_subpath(py_file)
        assert subpath is not None  # from_function keeps to the project's files
        self._cache_path = os.path.join(config.CACHE_DIR, subpath)  # type: ignore[attr-defined]

    @classmethod
    def from_function(cls, py_func: Any, py_file: str) -> ProjectCacheLocator | None:
        if project_subpath(py_file) is None:
            return None  # not the project's: numba's own locators decide
        return super().from_function(py_func, py_file)

"""The numba cache is keyed by the sources, not by the checkout's path
(haptic_local_model.shared.numba_cache): the same module in another clone, or installed,
finds the same cache directory and the same source stamp, so numba loads what the first
compiled; a changed module does not match."""

from __future__ import annotations

import shutil
from pathlib import Path

import numba.core.config
import pytest

from haptic_local_model.haptic_server import paced
from haptic_local_model.shared import numba_cache
from haptic_local_model.shared.numba_cache import LOCATORS, ProjectCacheLocator, project_subpath

KERNEL = paced.open_tick  # any of the project's cached kernels


def _clone(tmp_path: Path, name: str) -> tuple[Path, Path]:
    """The kernel's module copied into a checkout of its own: (its root, the copy)."""
    root = tmp_path / name
    source = Path(KERNEL.py_func.__code__.co_filename)
    copy = root / source.relative_to(numba_cache.ROOT)
    copy.parent.mkdir(parents=True)
    shutil.copy2(source, copy)
    return root, copy


def test_the_project_locator_is_numbas_first() -> None:
    """Importing the project set NUMBA_CACHE_LOCATOR_CLASSES before numba read its config,
    and the project's kernels are cached through it."""
    assert numba.core.config.CACHE_LOCATOR_CLASSES == LOCATORS
    locator = KERNEL._cache._impl.locator
    assert isinstance(locator, ProjectCacheLocator)
    assert Path(locator.get_cache_path()) == Path(
        numba.core.config.CACHE_DIR, "project_haptic_server"
    )


def test_another_clone_finds_the_same_directory_and_stamp(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    here = ProjectCacheLocator.from_function(KERNEL.py_func, KERNEL.py_func.__code__.co_filename)
    assert here is not None
    root, copy = _clone(tmp_path, "clone")
    monkeypatch.setattr(numba_cache, "ROOT", root)
    there = ProjectCacheLocator.from_function(KERNEL.py_func, str(copy))
    assert there is not None
    assert there.get_cache_path() == here.get_cache_path()
    assert there.get_source_stamp() == here.get_source_stamp()
    copy.write_text(copy.read_text() + "\n# changed\n")  # a different source: no match
    changed = ProjectCacheLocator.from_function(KERNEL.py_func, str(copy))
    assert changed is not None and changed.get_source_stamp() != here.get_source_stamp()


def test_a_file_outside_the_project_is_left_to_numba(tmp_path: Path) -> None:
    outside = tmp_path / "user_code.py"
    outside.write_text("x = 1\n")
    assert project_subpath(outside) is None
    assert ProjectCacheLocator.from_function(KERNEL.py_func, str(outside)) is None
    assert project_subpath(numba_cache.ROOT / "haptic_server/stages/tick.py") == (
        "project_haptic_server_stages"
    )

"""paced.PacedEntry: a kind's entry point is compiled without numba's reference counting,
and a function numba compiles from inside it inherits that; one that allocates then fails
to compile (the control below). So the entry point compiles its kind's kernels on their own
first (with NRT, and with them what they call) and then only calls them: a burst whose
callee allocates runs."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit
from numba.core.errors import TypingError

from haptic_local_model.haptic_server.paced import (
    RETURNED_DONE,
    PacedEntry,
    loop_record,
    never_asks,
    paced_ticks,
)

TICKS = 5


@njit
def _allocates(k):
    """Allocates, as the install path's eigen-solver does."""
    return np.ones(k + 1).sum() + k


def _kind_burst(allocates):  # type: ignore[no-untyped-def]
    """A kind's burst whose callee, `allocates`, allocates."""

    @njit(inline="always")
    def burst(w, rows, start, stop):
        for k in range(start, stop):
            rows[k] = allocates(k) + w[0][0]
        return stop

    return burst


_burst = _kind_burst(_allocates)
# the control's own callee and burst, so that nothing of it is compiled before its test
_burst_unprimed = _kind_burst(njit(_allocates.py_func))


def _paced(w, rows, loop, windows, ts):
    return paced_ticks(never_asks, _burst, w, rows, loop, windows, ts)


@njit(_nrt=False)
def _paced_unprimed(w, rows, loop, windows, ts):
    return paced_ticks(never_asks, _burst_unprimed, w, rows, loop, windows, ts)


def _run(entry) -> tuple[int, np.ndarray]:  # type: ignore[no-untyped-def]
    loop = loop_record(1, (1e6, 1e6), 1)  # deadlines 1 ns apart: no waiting
    loop[0]["stop_tick"] = TICKS
    loop[0]["return_at_ns"] = np.iinfo(np.int64).max  # back to Python only when done
    rows = np.zeros(TICKS)
    windows = (np.zeros(8), np.zeros(8), np.zeros(8), np.zeros(3))
    status = entry((np.full(1, 10.0),), rows, loop, windows, np.zeros(2, np.int64))
    return int(status), rows


def test_a_burst_whose_callee_allocates_runs_in_the_entry_point_without_nrt():
    status, rows = _run(PacedEntry(_paced, never_asks, _burst, cache=False))
    assert status == RETURNED_DONE
    np.testing.assert_array_equal(rows, [2 * k + 1 + 10.0 for k in range(TICKS)])


def test_unprimed_the_same_entry_point_does_not_compile():
    with pytest.raises(TypingError, match="Only accept returning of array"):  # np.ones
        _run(_paced_unprimed)

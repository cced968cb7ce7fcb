"""The monotonic and wall clocks, and a sleep-then-spin wait, callable from numba kernels.

`clock_gettime` and `clock_nanosleep` are called as external C symbols (numba intrinsics,
resolved from the C library at load time), so the kernels that use them cache like any
other. CLOCK_MONOTONIC is what `time.perf_counter_ns` reads on Linux, so deadlines computed
in Python and in a kernel are the same numbers; CLOCK_REALTIME is `time.time_ns`.
Each call takes a 2-element int64 scratch array (a struct timespec) from its caller.
"""

from __future__ import annotations

from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

CLOCK_REALTIME = 0
CLOCK_MONOTONIC = 1
TIMER_ABSTIME = 1

_I32 = ir.IntType(32)
_PTR = ir.IntType(8).as_pointer()


@intrinsic
def _clock_gettime(typingctx, clock_id, timespec):
    sig = types.int32(types.int32, types.voidptr)

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(_I32, [_I32, _PTR])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "clock_gettime")
        return builder.call(fn, args)

    return sig, codegen


@intrinsic
def _clock_nanosleep(typingctx, clock_id, flags, request, remain):
    sig = types.int32(types.int32, types.int32, types.voidptr, types.voidptr)

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(_I32, [_I32, _I32, _PTR, _PTR])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "clock_nanosleep")
        return builder.call(fn, args)

    return sig, codegen


@njit(cache=True)
def monotonic_ns(ts):
    """time.perf_counter_ns(), from a kernel (ts: int64[2] scratch)."""
    _clock_gettime(types.int32(CLOCK_MONOTONIC), ts.ctypes)  # type: ignore[call-arg]
    return ts[0] * 1_000_000_000 + ts[1]


@njit(cache=True)
def realtime_ns(ts):
    """time.time_ns(), from a kernel (ts: int64[2] scratch)."""
    _clock_gettime(types.int32(CLOCK_REALTIME), ts.ctypes)  # type: ignore[call-arg]
    return ts[0] * 1_000_000_000 + ts[1]


@njit(cache=True)
def wait_until_ns(ts, deadline_ns, spin_ns):
    """shared.timing.wait_until in a kernel: sleep (absolute, on the monotonic clock) until
    spin_ns before the deadline, then spin; returns the monotonic time at exit."""
    wake = deadline_ns - spin_ns
    if wake - monotonic_ns(ts) > 0:
        ts[0] = wake // 1_000_000_000
        ts[1] = wake % 1_000_000_000
        flags = types.int32(TIMER_ABSTIME)
        _clock_nanosleep(types.int32(CLOCK_MONOTONIC), flags, ts.ctypes, 0)  # type: ignore[call-arg]
    now = monotonic_ns(ts)
    while now < deadline_ns:
        now = monotonic_ns(ts)
    return now

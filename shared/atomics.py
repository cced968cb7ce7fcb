"""Ordered loads and stores of int64 words in memory another process shares (numba).

A compiled loop that polls a counter in shared memory must read it afresh each time: to
the compiler a plain array read that nothing in the loop writes may be hoisted out of the
loop, and a plain write may be delayed or moved before the data it publishes. These are
LLVM atomic accesses (acquire loads, release stores): each is a real access, in order.
"""

from __future__ import annotations

from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic


def _item_pointer(context, builder, arrty, arr, index):
    ary = context.make_array(arrty)(context, builder, arr)
    return cgutils.get_item_pointer(context, builder, arrty, ary, [index], wraparound=False)


@intrinsic
def _load_acquire(typingctx, arr, index):
    """arr[index] (int64 array), read from memory now; later reads stay after it."""
    if not (isinstance(arr, types.Array) and arr.dtype == types.int64):
        return None
    sig = types.int64(arr, types.intp)

    def codegen(context, builder, signature, args):
        arrty = signature.args[0]
        idx = context.cast(builder, args[1], signature.args[1], types.intp)
        ptr = _item_pointer(context, builder, arrty, args[0], idx)
        return builder.load_atomic(ptr, "acquire", 8)

    return sig, codegen


@intrinsic
def _store_release(typingctx, arr, index, value):
    """arr[index] = value (int64 array), written now; earlier writes land before it."""
    if not (isinstance(arr, types.Array) and arr.dtype == types.int64):
        return None
    sig = types.void(arr, types.intp, types.int64)

    def codegen(context, builder, signature, args):
        arrty = signature.args[0]
        idx = context.cast(builder, args[1], signature.args[1], types.intp)
        val = context.cast(builder, args[2], signature.args[2], types.int64)
        ptr = _item_pointer(context, builder, arrty, args[0], idx)
        builder.store_atomic(val, ptr, "release", 8)
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True, inline="always")
def load_acquire(arr, index):
    """arr[index] (int64 array), read from memory now; later reads stay after it."""
    return _load_acquire(arr, index)  # type: ignore[call-arg]


@njit(cache=True, inline="always")
def store_release(arr, index, value):
    """arr[index] = value (int64 array), written now; earlier writes land before it."""
    _store_release(arr, index, value)  # type: ignore[call-arg]

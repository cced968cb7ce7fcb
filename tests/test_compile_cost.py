"""benchmarks/compile_cost.py's attribution of numba's nested compile events: each kernel's
and each pass's own time, a callee's compile taken out of its caller's pass, and every
second counted once (the figures add up to the compiling's wall time)."""

from __future__ import annotations

from haptic_local_model.benchmarks import compile_cost


def test_nested_compiles_are_counted_once_each_to_their_own_kernel() -> None:
    clock = iter([0.0, 1.0, 2.0, 3.0, 4.5, 5.0, 7.0, 7.5, 9.0, 10.0, 13.0, 14.0])
    a = compile_cost._Attribution(lambda: next(clock))
    a.on_start("compile", "caller")  # 0
    a.on_start("pass", "nopython_type_inference [caller]")  # 1
    a.on_start("compile", "callee")  # 2: compiled while its caller is typed
    a.on_start("pass", "native_lowering [callee]")  # 3
    a.on_start("pass", "llvm")  # 4.5
    a.on_end()  # 5: llvm 0.5
    a.on_end()  # 7: the callee's lowering 4.0 - 0.5 = 3.5
    a.on_end()  # 7.5: the callee 5.5 in all, 1.5 outside its passes
    a.on_end()  # 9: the caller's typing 8 - 5.5 = 2.5
    a.on_start("pass", "native_lowering [caller]")  # 10
    a.on_end()  # 13: 3
    a.on_end()  # 14: the caller 14 in all: 14 - 5.5 - 2.5 - 3 = 3 outside its passes
    assert a.compiled == 2
    assert a.kernels == {"callee": 5.5, "caller": 8.5}
    assert sum(a.kernels.values()) == 14.0
    assert a.outside_passes == 3.0 + 1.5
    assert compile_cost._pass_groups(a.passes) == {
        "typing": 2.5,
        "lowering": 6.5,
        "LLVM (optimising, linking, emitting)": 0.5,
    }

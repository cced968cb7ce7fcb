"""pymunk's C core (Munk2D, a Chipmunk2D) called from numba kernels.

pymunk reaches Chipmunk through cffi, one Python call per property: a sim step that drives
its tool at every substep spends most of its time there, not in the physics (testbed:
2.7 us of `cpSpaceStep` a substep against ~25 us of Python around it). These intrinsics call
the same C functions of the same loaded library from compiled code, so a whole sim step, or
a neighbourhood query, is one call from Python.

Each intrinsic declares its C function by name; the symbols resolve, when a kernel is
compiled or loaded from numba's cache, in pymunk's own extension module (loaded here with
`load_library_permanently`: the same library, so the pointers pymunk hands out are valid).
Pointers are passed as int64 (`body_ptr`, `shape_ptr`, `space_ptr`). A `cpVect` is two
doubles: passed by value as two double arguments and returned as a pair, which is how the
System V x86-64 and the AAPCS64 calling conventions pass a struct of two doubles (not
Windows x64, which passes it by reference): `check_platform` refuses the others.
"""

from __future__ import annotations

import platform
import sys
from typing import Any

import llvmlite.binding as llvm
import pymunk
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic
from pymunk import _chipmunk

SUPPORTED_MACHINES = ("x86_64", "amd64", "aarch64", "arm64")


def check_platform() -> None:
    """Raise if cpVect's calling convention here is not the one the intrinsics assume."""
    machine = platform.machine().lower()
    if sys.platform == "win32" or machine not in SUPPORTED_MACHINES:
        raise RuntimeError(
            f"the compiled sim calls Chipmunk with the System V / AAPCS64 convention for "
            f"cpVect; {sys.platform}/{machine} is not supported"
        )


check_platform()
llvm.load_library_permanently(_chipmunk.__file__)

_D = ir.DoubleType()
_P = ir.IntType(8).as_pointer()
_I64 = ir.IntType(64)
_VEC = ir.LiteralStructType([_D, _D])
_VEC_NB = types.UniTuple(types.float64, 2)
#: result kinds: (numba type, LLVM type)
_RESULTS = {
    "void": (types.void, ir.VoidType()),
    "double": (types.float64, _D),
    "vect": (_VEC_NB, _VEC),
    "ptr": (types.int64, _P),
    "int": (types.int32, ir.IntType(32)),
    "bool": (types.uint8, ir.IntType(8)),
}


def _c_function(name: str, result: str, pattern: str) -> Any:
    """An intrinsic calling C function `name`: `pattern` spells its arguments, 'p' a pointer
    (an int64 in numba), 'd' a double; `result` is a key of _RESULTS (a 'vect' comes back
    as a (x, y) tuple)."""
    nb_result, ll_result = _RESULTS[result]
    nb_args = [types.int64 if c == "p" else types.float64 for c in pattern]
    ll_args = [_P if c == "p" else _D for c in pattern]
    signature = nb_result(*nb_args)

    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        fn = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(ll_result, ll_args), name
        )
        values = [
            builder.inttoptr(a, _P) if c == "p" else a for a, c in zip(args, pattern, strict=True)
        ]
        out = builder.call(fn, values)
        if result == "void":
            return context.get_dummy_value()
        if result == "vect":
            x, y = builder.extract_value(out, 0), builder.extract_value(out, 1)
            return context.make_tuple(builder, nb_result, [x, y])
        if result == "ptr":
            return builder.ptrtoint(out, _I64)
        return out

    typer = _TYPERS[len(pattern)](lambda: (signature, codegen))
    typer.__name__ = name
    return intrinsic(typer)


def _typer_1(result: Any) -> Any:
    return lambda typingctx, a: result()


def _typer_2(result: Any) -> Any:
    return lambda typingctx, a, b: result()


def _typer_3(result: Any) -> Any:
    return lambda typingctx, a, b, c: result()


def _typer_4(result: Any) -> Any:
    return lambda typingctx, a, b, c, d: result()


def _typer_5(result: Any) -> Any:
    return lambda typingctx, a, b, c, d, e: result()


#: numba folds an intrinsic's arguments by its typing function's parameters: one per arity
_TYPERS = {1: _typer_1, 2: _typer_2, 3: _typer_3, 4: _typer_4, 5: _typer_5}


space_step = _c_function("cpSpaceStep", "void", "pd")
space_shape_query = _c_function("cpSpaceShapeQuery", "bool", "pppp")
body_position = _c_function("cpBodyGetPosition", "vect", "p")
body_velocity = _c_function("cpBodyGetVelocity", "vect", "p")
body_center_of_gravity = _c_function("cpBodyGetCenterOfGravity", "vect", "p")
body_angle = _c_function("cpBodyGetAngle", "double", "p")
body_angular_velocity = _c_function("cpBodyGetAngularVelocity", "double", "p")
body_torque = _c_function("cpBodyGetTorque", "double", "p")
body_mass = _c_function("cpBodyGetMass", "double", "p")
body_moment = _c_function("cpBodyGetMoment", "double", "p")
body_type = _c_function("cpBodyGetType", "int", "p")
body_set_torque = _c_function("cpBodySetTorque", "void", "pd")
body_set_velocity = _c_function("cpBodySetVelocity", "void", "pdd")
body_set_angular_velocity = _c_function("cpBodySetAngularVelocity", "void", "pd")
body_activate = _c_function("cpBodyActivate", "void", "p")
body_apply_force_at_world_point = _c_function("cpBodyApplyForceAtWorldPoint", "void", "pdddd")
body_local_to_world = _c_function("cpBodyLocalToWorld", "vect", "pdd")
body_world_to_local = _c_function("cpBodyWorldToLocal", "vect", "pdd")
body_velocity_at_world_point = _c_function("cpBodyGetVelocityAtWorldPoint", "vect", "pdd")
body_update_velocity = _c_function("cpBodyUpdateVelocity", "void", "pdddd")
shape_body = _c_function("cpShapeGetBody", "ptr", "p")

BODY_DYNAMIC, BODY_KINEMATIC, BODY_STATIC = 0, 1, 2  # cpBodyType


def body_ptr(body: pymunk.Body) -> int:
    """The cpBody* of a pymunk body, as an int for the kernels (valid while it lives)."""
    return int(_chipmunk.ffi.cast("uintptr_t", body._body))


def shape_ptr(shape: pymunk.Shape) -> int:
    """The cpShape* of a pymunk shape, as an int for the kernels (valid while it lives)."""
    return int(_chipmunk.ffi.cast("uintptr_t", shape._shape))


def space_ptr(space: pymunk.Space) -> int:
    """The cpSpace* of a pymunk space, as an int for the kernels (valid while it lives)."""
    return int(_chipmunk.ffi.cast("uintptr_t", space._space))


def set_velocity_function(body: pymunk.Body, address: int) -> None:
    """Make the C function at `address` (a numba cfunc of cpBodyVelocityFunc's signature:
    body, gravity (two doubles), damping, dt) update `body`'s velocity in every step, in
    place of pymunk's Python callback. The caller keeps the cfunc alive."""
    fn = _chipmunk.ffi.cast("cpBodyVelocityFunc", address)
    _chipmunk.lib.cpBodySetVelocityUpdateFunc(body._body, fn)

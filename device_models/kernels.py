"""One compiled interface over every simulated device model, so a whole tick (the hand, the
device, the engine) runs in one numba call.

A simulated device hands the engine its records as one tuple, `DeviceRecords`:
(params, state, work, normals, noise_index) — its parameter and state records, its scratch
record, its block of standard normals and the index of the next unused one (a 1-element
int64 array the Python side shares). A model registers its kernels for its params dtype
(`register_model`); the functions below (`device_read`, `device_command`, ...) are numba
overloads that pick a model's kernels by the type of `params`, at compile time: a compiled
caller is specialised per model, with no branch and no Python at run time.

The kernels a model registers, all over its own records:

- `read(params, state, sensors)`: the newest reading into a SENSOR_DTYPE record
- `command(params, state, wrench)`: hold a wrench (the model saturates it)
- `applied(state)`: the wrench the device applies, a view into `state`
- `advance(params, state, work, dt, hand, normals, noise_index)`: the physics over dt under
  the held command and the hand's true wrench, reading normals from `noise_index`
- `noise_needed(params, dt)`: how many normals `advance` reads for this dt
- `true_state(state, pose, twist)`: the true (noise-free) pose and twist
- `sense_hand(state, hand)`: the hand's true wrench this tick, as the handle feels it

A model module defines its kernels under these names and registers them with
`register_model(PARAMS_DTYPE, globals())`, which finds them by name; a module whose state
holds `pose` and `twist` (or `hand_wrench`) may leave `true_state` (or `sense_hand`) out and
get `copy_pose_twist` (or `sense_hand_wrench`) below.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from typing import Any

import numba
import numpy as np
from numba import njit
from numba.extending import overload

Kernel = Callable[..., Any]

#: What a simulated device hands the compiled tick: (params, state, work, normals,
#: noise_index), each a numpy array (records of one element; normals 1-D float64;
#: noise_index int64[1]).
DeviceRecords = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


@njit(cache=True)
def copy_pose_twist(state, pose, twist):
    """The `true_state` of a model whose state holds the true `pose` and `twist`."""
    st = state[0]
    for c in range(3):
        pose[c] = st.pose[c]
        twist[c] = st.twist[c]


@njit(cache=True)
def sense_hand_wrench(state, hand_wrench):
    """The `sense_hand` of a model whose state holds `hand_wrench`: the hand's true wrench
    this tick."""
    for c in range(3):
        state[0].hand_wrench[c] = hand_wrench[c]


@dataclass(frozen=True)
class ModelKernels:
    """A device model's kernels (see the module docstring for their signatures)."""

    read: Kernel
    command: Kernel
    applied: Kernel
    advance: Kernel
    noise_needed: Kernel
    true_state: Kernel = copy_pose_twist
    sense_hand: Kernel = sense_hand_wrench


_MODELS: dict[Any, ModelKernels] = {}


def register_model(params_dtype: np.dtype, namespace: Mapping[str, Any]) -> ModelKernels:
    """Make a model's kernels the ones the overloads below pick for `params_dtype`, and return
    them: the functions of `namespace` (the model module's globals()) named as the fields of
    ModelKernels, the defaults for the roles it leaves out."""
    roles = {f.name: namespace[f.name] for f in fields(ModelKernels) if f.name in namespace}
    kernels = ModelKernels(**roles)
    _MODELS[numba.from_dtype(params_dtype)] = kernels
    return kernels


def _model_of(dev: Any) -> ModelKernels:
    """The registered kernels for a DeviceRecords tuple's numba type."""
    record = dev.types[0].dtype
    try:
        return _MODELS[record]
    except KeyError:
        raise numba.core.errors.TypingError(
            f"no device model registered for params {record}"
        ) from None


# Plain-Python stand-ins: numba compiles the overloads below in their place.
def device_read(dev: DeviceRecords, sensors: np.ndarray) -> None:
    raise NotImplementedError("compiled only")


def device_command(dev: DeviceRecords, wrench: np.ndarray) -> None:
    raise NotImplementedError("compiled only")


def device_applied(dev: DeviceRecords) -> np.ndarray:
    raise NotImplementedError("compiled only")


def device_advance(dev: DeviceRecords, dt: float, hand: np.ndarray) -> None:
    raise NotImplementedError("compiled only")


def device_noise_ready(dev: DeviceRecords, dt: float) -> bool:
    raise NotImplementedError("compiled only")


def device_true_state(dev: DeviceRecords, pose: np.ndarray, twist: np.ndarray) -> None:
    raise NotImplementedError("compiled only")


def device_sense_hand(dev: DeviceRecords, hand: np.ndarray) -> None:
    raise NotImplementedError("compiled only")


@overload(device_read)
def _read(dev, sensors):
    read = _model_of(dev).read
    return lambda dev, sensors: read(dev[0], dev[1], sensors)


@overload(device_command)
def _command(dev, wrench):
    command = _model_of(dev).command
    return lambda dev, wrench: command(dev[0], dev[1], wrench)


@overload(device_applied)
def _applied(dev):
    applied = _model_of(dev).applied
    return lambda dev: applied(dev[1])


@overload(device_noise_ready)
def _noise_ready(dev, dt):
    """Whether the normals left in the block cover this dt's advance (else the Python side
    refills the block first, as NoiseBuffer.reserve does)."""
    needed = _model_of(dev).noise_needed
    return lambda dev, dt: dev[4][0] + needed(dev[0], dt) <= dev[3].shape[0]


@overload(device_advance)
def _advance(dev, dt, hand):
    model = _model_of(dev)
    advance, needed = model.advance, model.noise_needed

    def impl(dev, dt, hand):
        start = dev[4][0]
        dev[4][0] = start + needed(dev[0], dt)
        advance(dev[0], dev[1], dev[2], dt, hand, dev[3], start)

    return impl


@overload(device_true_state)
def _true_state(dev, pose, twist):
    true_state = _model_of(dev).true_state
    return lambda dev, pose, twist: true_state(dev[1], pose, twist)


@overload(device_sense_hand)
def _sense_hand(dev, hand):
    sense_hand = _model_of(dev).sense_hand
    return lambda dev, hand: sense_hand(dev[1], hand)


@njit(cache=True)
def advance_device(dev, dt, hand):
    """device_advance, callable from Python (KernelDevice.advance)."""
    device_advance(dev, dt, hand)


@njit(cache=True)
def noise_ready(dev, dt):
    """device_noise_ready, callable from Python."""
    return device_noise_ready(dev, dt)

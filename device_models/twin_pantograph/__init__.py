"""Simulated twin-pantograph haptic device (seed 001 §4, DESIGN §5).

Two five-bar pantographs, each with two base-mounted motors, hold the two ends of a rigid
handle bar: a planar 3-DOF device (handle centre x, y and angle theta) with 4 motors.

Conventions (device frame; origin = handle home pose):
- Motors 0, 1 form pantograph A, whose end point holds handle end a = c - (L/2) u(theta);
  motors 2, 3 form pantograph B holding end b = c + (L/2) u(theta), u = (cos, sin).
- elbow_sign[i] = +1 puts motor i's elbow counter-clockwise of the ray from its base point
  to its end point, -1 clockwise (the IK branch). assembly_sign[k] = +1 puts pantograph k's
  end point left of the ray from its first elbow to its second (the FK branch).
- Jm = d(motor angles)/d(handle pose), 4 x 3. By virtual work (massless, frictionless
  links) the handle wrench of motor torques tau is W = A tau with A = Jm^T (3 x 4).

Kinetic energy is exact for rigid links with their centre of mass at the link midpoint:
rotor + proximal link about the motor axis, each distal link as a rigid body (mass at its
midpoint, inertia about it), the handle bar (joint masses lumped into it). Per-tick work is
in numba kernels over the preallocated records PARAMS_DTYPE, STATE_DTYPE and WORK_DTYPE.

Modules: config (constants, records, config sections, pack_parameters), kinematics,
dynamics, torques (redundancy resolution), device (tick kernels and the device class); the
package names the config, the records and the device, the kernels are imported from their
modules.
"""

from haptic_local_model.device_models.base import DeviceModel
from haptic_local_model.device_models.common import FAULT_INVALID_COMMAND
from haptic_local_model.device_models.twin_pantograph.config import (
    PARAMS_DTYPE,
    STATE_DTYPE,
    WORK_DTYPE,
    FrictionSection,
    SimulationSection,
    TwinPantographConfig,
    pack_parameters,
)
from haptic_local_model.device_models.twin_pantograph.device import AUX_NAMES, TwinPantograph

#: The entry point of this model (pyproject.toml, group haptic_local_model.devices).
MODEL = DeviceModel(
    TwinPantographConfig,
    TwinPantograph,
    "twin_pantograph",
    "seed 001's twin five-bar planar device: 4 motors, encoders, friction",
)

__all__ = [
    "AUX_NAMES",
    "FAULT_INVALID_COMMAND",
    "MODEL",
    "PARAMS_DTYPE",
    "STATE_DTYPE",
    "WORK_DTYPE",
    "FrictionSection",
    "SimulationSection",
    "TwinPantograph",
    "TwinPantographConfig",
    "pack_parameters",
]

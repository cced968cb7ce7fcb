"""A port's device and its simulated user around a compiled tick: the hand on the device's
true state and the device's reading in the world frame before it, the command to the device
and the device's physics after it. The two-port co-simulation (haptic_server/ports.py), a
hand scene's port (haptic_server/hand_ports.py) and a station (stages/station.py: its
reading only; its command blends the coupling with the safe state itself)."""

from __future__ import annotations

import numpy as np
from numba import njit

from haptic_local_model.device_models.base import SimulatedDevice
from haptic_local_model.device_models.kernels import (
    device_advance,
    device_command,
    device_read,
    device_sense_hand,
    device_true_state,
)
from haptic_local_model.device_models.world_map import (
    map_command_to_device,
    map_rate_step,
    map_sensors_to_world,
)
from haptic_local_model.haptic_server.users import hand_wrench, user_record
from haptic_local_model.shared.config import UserConfig


@njit(cache=True)
def read_device(users, t, dev, hand, sensors, maps, world):
    """The user (users[0]) on the device's true state at time t, its wrench into `hand`;
    the device's reading into sensors[0] and, mapped to the world, into world[0]."""
    u = users[0]
    device_true_state(dev, u.device_pose, u.device_twist)
    hand_wrench(users, t - u.start_s, u.device_pose, u.device_twist, hand)
    device_sense_hand(dev, hand)
    device_read(dev, sensors)
    map_sensors_to_world(maps, sensors, world)


@njit(cache=True)
def drive_device(maps, command, limits, out, dev, dt, hand, sensors):
    """The world-frame command to the device (mapped, clipped at its limits, into `out`),
    the device's physics over dt under the hand's wrench, the map's rate control."""
    map_command_to_device(maps, command, limits, out)
    device_command(dev, out)
    device_advance(dev, dt, hand)
    map_rate_step(maps, sensors[0].pose, dt)


def push_stretch(wrench: object, world_map: np.ndarray, stiffness: object) -> np.ndarray:
    """How far a spring of `stiffness` (world frame, per axis; 0: none) stretches under a
    hand's constant `wrench` on its device, mapped to the world by `world_map` (a MAP_DTYPE
    record): where a port's device starts so its coupling balances its user's push."""
    push = np.asarray(wrench, np.float64) / (world_map["force_scale"] * world_map["scale"])
    k = np.asarray(stiffness, np.float64)
    return np.divide(push, k, out=np.zeros(3), where=k > 0)


def rest_device(
    device: SimulatedDevice,
    user: UserConfig,
    world_map: np.ndarray,
    start: tuple[float, float, float],
    anchor: np.ndarray,
) -> np.ndarray:
    """The device at rest at `start`, its map (`world_map`, a MAP_DTYPE record, set in
    place) putting it at `anchor` in the world: a port's tool plus its spring's stretch
    under the user's push (push_stretch), or a station's tool. Returns its user's record
    (USER_DTYPE), the script starting there."""
    device.reset(np.array(start, np.float64))
    pose, twist = np.zeros(3), np.zeros(3)
    device.true_state(pose, twist)
    u = user_record(user)[0]
    u["start_pose"] = pose
    world_map["offset"] = anchor - world_map["scale"] * pose
    return u

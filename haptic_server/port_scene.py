"""What the port worlds, the shared world and a haptic station read off a port scene: where
each port's tool starts, each port's coupling gains, and a user's glove script. A station (a
process on another host) takes these from here, not from the world's engines.
"""

from __future__ import annotations

import numpy as np

from haptic_local_model.haptic_server.stages.cosim import cosim_records
from haptic_local_model.shared.config import ConfigError, UserConfig, load_user, resolve
from haptic_local_model.shared.port_config import HandSceneConfig, PortSceneConfig
from haptic_local_model.shared.protocol.station import Vec3

F8 = np.float64
MAX_GLOVE_ROWS = 64  # a glove script's rows (as a user's waypoints)


def tool_start(scene: PortSceneConfig | HandSceneConfig, p: int) -> np.ndarray:
    """Where port p's tool starts in the world: its co-simulated body, or its hand's palm."""
    if isinstance(scene, HandSceneConfig):
        return np.array(scene.hand_of(p).pose, F8)
    _, data = cosim_records(scene, [(1.0, 1.0, 1.0)] * len(scene.ports))
    return np.array(data[0]["q"][3 * p : 3 * p + 3])


def port_gains(scene: PortSceneConfig | HandSceneConfig, p: int) -> tuple[Vec3, Vec3]:
    """Port p's coupling (stiffness, damping): its co-simulation's, or its palm springs."""
    if isinstance(scene, HandSceneConfig):
        hand = scene.hand_of(p)
        return hand.palm_spring, hand.palm_damping
    port = scene.ports[p]
    return port.coupling_stiffness, port.coupling_damping


def glove_script(user: UserConfig, rest: list[float]) -> np.ndarray:
    """The user's finger_angles as rows (t, a_1, ..., a_n) for the hand's n joints; without
    any, the fingers' rest angles held."""
    if not user.finger_angles:
        return np.array([[0.0, *rest]], F8)
    if len(user.finger_angles) > MAX_GLOVE_ROWS:
        raise ValueError(f"finger_angles: at most {MAX_GLOVE_ROWS} rows")
    rows = np.array(user.finger_angles, F8)
    if rows.shape[1] != 1 + len(rest):
        raise ValueError(
            f"finger_angles: {rows.shape[1] - 1} angles a row, the hand has {len(rest)} joints"
        )
    return rows


def load_glove_users(scene: HandSceneConfig, names: list[str]) -> list[UserConfig]:
    """Each port's user by name, its glove script checked against its port's hand; a
    script that does not fit is named by the user's file and key."""
    users = []
    for p, name in enumerate(names):
        user = load_user(name)
        rest = [a for f in scene.hand_of(p).fingers for a in f.rest]
        try:
            glove_script(user, rest)
        except ValueError as exc:
            key, _, problem = str(exc).partition(": ")
            raise ConfigError(str(resolve("users", name)), key, problem) from None
        users.append(user)
    return users

"""A haptic station's records, built from its scene, port, device and user, and the replay of
its log: the station's loop (haptic_server/station.py) and `haptic-replay` build them here.

A station's tick is a function of its device and user (both simulated, seeded), the scene's
coupling and what the world sent it. Its log's rows hold, each tick, the tool state the tick
rendered against (pose, twist, gains, whether held) and its age; the metadata holds the
scene's, device's and user's files and the station's watchdog and ramp. The replay rebuilds
the station, runs its tick on the logged tool states and compares every output bit for bit.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from haptic_local_model.device_models.base import SimulatedDevice, world_map_of
from haptic_local_model.device_models.common import refill_noise
from haptic_local_model.device_models.kernels import noise_ready
from haptic_local_model.device_models.registry import device_from_text
from haptic_local_model.haptic_server.physics.passivity import PC_MAX_OVER_B
from haptic_local_model.haptic_server.port_scene import port_gains, tool_start
from haptic_local_model.haptic_server.stages.port_io import rest_device
from haptic_local_model.haptic_server.stages.station import (
    STATION_DTYPE,
    STATION_ROW_DTYPE,
    station_row,
    station_tick,
)
from haptic_local_model.shared.config import (
    ConfigError,
    UserConfig,
    load_config_text,
    parse_toml_text,
)
from haptic_local_model.shared.port_config import HandSceneConfig, PortSceneConfig, is_hand_scene

STATION_TOPIC = "/station/tick"
STATION_SCHEMA = "haptic_server/StationTick"
#: the tool is carried on by its twist for at most this long: a few of the world's periods
#: and a network hop; an older tool state is rendered where it was (DeviceState likewise)
EXTRAPOLATE_S = 0.005
#: what a tick renders against, as the loop set it: logged each tick, fed back by the replay
TOOL_INPUTS = ("have_tool", "held", "tool_age", "tool_pose", "tool_twist", "stiffness", "damping",
               "budget", "object_pose", "object_twist", "indexed", "device_echo")  # fmt: skip
#: what a tick computes from them: compared bit for bit by the replay
REPLAYED = ("pose", "twist", "hand", "coupling", "spring", "out", "gain", "fresh", "cut",
            "invalid", "fault", "energy", "pc_damping", "contact_w", "depth",
            "local_force", "hold_force")  # fmt: skip
#: the local model's blend between the coupling's normal and the local contact: a few ticks
#: (a step of the whole squeeze in one tick is what the fade is for)
CONTACT_FADE_S = 0.005
#: the local contact renders the object low-passed with this time constant (stages/station.py
#: _see_object: the object's reported motion, the devices' own a round trip late, rang at
#: 150 ms one way; a model of the common mode decays at every round trip to 360 ms with it)
OBJECT_TAU_S = 0.05
#: a pad's flat face on the object's flat side touches at two points (the world's contact
#: per point is the scene's `contact.stiffness_n_per_m`): k_c = 2 k_point
FACE_POINTS = 2


@dataclass(frozen=True)
class StationSetup:
    """What a station is built from (its log's metadata holds all of it)."""

    scene: PortSceneConfig | HandSceneConfig
    index: int  # its port's
    device: SimulatedDevice
    user: UserConfig
    watchdog_s: float  # the station network's watchdog and safe ramp
    ramp_s: float
    passivity: bool = False  # its passivity controller acts (a port scene's, "tdpa")
    local_model: bool = False  # it renders its pad's contact with the object (local_geometry)


def local_geometry(scene: PortSceneConfig | HandSceneConfig, index: int) -> tuple | None:
    """The local model's geometry for port `index`: (its tool's half extents, the object's,
    the world's contact stiffness on a pad's face), or None where it has none: a hand scene,
    a scene without an object beside its tools, or a tool or object that is not a box."""
    if not isinstance(scene, PortSceneConfig):
        return None
    order = scene.cosim_order()
    if len(order) <= len(scene.ports):
        return None
    tool, obj = scene.body(scene.ports[index].tool), scene.body(order[len(scene.ports)])
    if tool.shape != "box" or obj.shape != "box":
        return None
    k_c = FACE_POINTS * scene.contact.stiffness_n_per_m
    return np.asarray(tool.size) / 2.0, np.asarray(obj.size) / 2.0, k_c


def station_record(setup: StationSetup) -> np.ndarray:
    """The station's STATION_DTYPE record, its device placed at the port's start."""
    scene, device = setup.scene, setup.device
    stiffness, damping = port_gains(scene, setup.index)
    st = np.zeros(1, STATION_DTYPE)
    s = st[0]
    s["dt"] = scene.period_s
    s["watchdog_s"] = setup.watchdog_s
    s["ramp_s"] = setup.ramp_s
    s["limits"] = device.limits().max_wrench
    s["stiffness"] = stiffness
    s["damping"] = damping
    s["max_stiffness"] = stiffness
    s["max_damping"] = damping
    s["extrapolate_s"] = EXTRAPOLATE_S
    s["passivity"] = int(setup.passivity)
    s["pc_max"] = PC_MAX_OVER_B * np.asarray(damping, np.float64)
    s["map"][0] = world_map_of(device).record[0]
    s["fade_s"] = CONTACT_FADE_S
    s["object_tau"] = OBJECT_TAU_S
    geometry = local_geometry(scene, setup.index) if setup.local_model else None
    if geometry is not None:
        s["local_model"] = 1
        s["pad_half"], s["object_half"], s["contact_stiffness"] = geometry
    place_station(st, setup)
    return st


def place_station(station: np.ndarray, setup: StationSetup) -> None:
    """The device at rest at its port's start, mapped onto its tool (the world re-indexes it
    when it joins, so this only makes the log's frame the world's at the start)."""
    s = station[0]
    tool = tool_start(setup.scene, setup.index)
    wm = s["map"][0]
    start = setup.scene.ports[setup.index].device_start
    s["user"][0] = rest_device(setup.device, setup.user, wm, start, tool)
    s["map"][0] = wm
    s["tool_pose"] = tool


def station_metadata(setup: StationSetup, texts: dict[str, str]) -> dict[str, str]:
    """The log's `station` metadata: the port, the watchdog and the ramp, and the scene's,
    device's and user's files (`texts`: ports, device, user) the replay rebuilds it from."""
    return {
        "port": setup.scene.ports[setup.index].name,
        "watchdog_s": json.dumps(setup.watchdog_s),
        "ramp_s": json.dumps(setup.ramp_s),
        "passivity": json.dumps(setup.passivity),
        "local_model": json.dumps(setup.local_model),
        **{f"{key}_toml": text for key, text in texts.items()},
    }


def setup_from_log(path: Path, metadata: dict[str, dict[str, str]]) -> StationSetup:
    """The station a log's metadata describes; what is missing or wrong is named."""
    meta = metadata.get("station", {})
    missing = [k for k in ("port", "watchdog_s", "ramp_s", "ports_toml", "device_toml",
                           "user_toml") if k not in meta]  # fmt: skip
    if missing:
        raise ConfigError(str(path), f"station.{missing[0]}", "missing: not a station's "
                          "log of this release")  # fmt: skip
    where = f"{path} (its scene)"
    text = meta["ports_toml"]
    scene_type = HandSceneConfig if is_hand_scene(parse_toml_text(text, where)) else PortSceneConfig
    scene: PortSceneConfig | HandSceneConfig = load_config_text(scene_type, text, where)
    names = [p.name for p in scene.ports]
    if meta["port"] not in names:
        raise ConfigError(str(path), "station.port", f"{meta['port']!r} is not a port")
    device = device_from_text(meta["device_toml"], f"{path} (its device)", simulated_only=True)
    if not isinstance(device, SimulatedDevice):
        raise ConfigError(str(path), "station.device_toml", "not a simulated device")
    user = load_config_text(UserConfig, meta["user_toml"], f"{path} (its user)")
    seconds = []
    for key in ("watchdog_s", "ramp_s"):
        try:
            seconds.append(float(json.loads(meta[key])))
        except (ValueError, TypeError):
            raise ConfigError(str(path), f"station.{key}", "not a number") from None
        if not seconds[-1] > 0.0:
            raise ConfigError(str(path), f"station.{key}", "not a positive number of seconds")
    passivity = meta.get("passivity", "false") == "true"  # before issue 46: none
    local_model = meta.get("local_model", "false") == "true"  # before its local model: none
    return StationSetup(scene, names.index(meta["port"]), device, user, seconds[0], seconds[1],
                        passivity, local_model)  # fmt: skip


def replay_station_rows(setup: StationSetup, rows: np.ndarray) -> tuple[int, int | None]:
    """Re-run the station's ticks on the rows' tool states; (ticks compared, the first tick
    whose outputs differ in any bit, or None)."""
    station = station_record(setup)
    s = station[0]
    dev, noise = setup.device.records, setup.device.noise
    dt = float(s["dt"])
    out = np.zeros(1, STATION_ROW_DTYPE)
    for k, row in enumerate(rows):
        if not noise_ready(dev, dt):  # where the loop refilled: the same seeded draws
            refill_noise(noise, dev, dt)
        for name in TOOL_INPUTS:
            s[name] = row[name]
        station_tick(station, dev)
        station_row(station, out, 0, s["sensors"][0]["fault"])
        for name in REPLAYED:
            if np.asarray(out[0][name]).tobytes() != np.asarray(row[name]).tobytes():
                return k + 1, k
    return len(rows), None

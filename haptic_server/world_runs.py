"""A port scene (two devices on one co-simulated world, a mass-spring hand that a device
drives, two hands on a box; docs/grasp.md) as a world in this process: built from its scene
file, run on either clock with its simulated devices, logged and replayed bit for bit.
`haptic-run --scene grasp_vertical` and `haptic-replay LOG` come here for port scenes and
their logs; the shared world (`haptic-world`) writes the same logs.

    haptic-run --scene grasp_vertical --device maglev --duration 5 --log runs/grasp.mcap
    haptic-run --scene hand_grasp --clock virtual --duration 5 --log runs/hands.mcap
    haptic-replay runs/grasp.mcap

The log holds every tick's row (the world kind's topic, ros1 with a ros1msg schema generated
from its row dtype, like the haptic server's `/haptic/tick`) and, as metadata, the port
scene's text, the devices' limits and the users. It is written to a temporary file beside the
target and renamed when complete, so a log that exists is whole. The replay rebuilds the
world from the metadata, feeds it each tick's logged inputs (the devices' readings in the
world frame, the tracked hands, the sim's bodies) and compares every output of the tick with
the logged row, bit for bit: the log holds all the world's inputs, and the world is a
function of them.
"""

from __future__ import annotations

import json
import math
import os
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from mcap.records import Channel

from haptic_local_model.device_models.registry import load_simulated_device
from haptic_local_model.haptic_server.hand_grasp_ports import HAND_GRASP_KIND, HandGraspRun
from haptic_local_model.haptic_server.hand_ports import HAND_KIND, HandPortRun
from haptic_local_model.haptic_server.log import (
    head_records,
    read_metadata,
    read_topic_rows,
    whole_log_metadata,
    write_rows_log,
)
from haptic_local_model.haptic_server.one_port import OnePortRun
from haptic_local_model.haptic_server.port_scene import load_glove_users
from haptic_local_model.haptic_server.ports import PORT_KIND, PortRun
from haptic_local_model.haptic_server.stages.station import STATION_ROW_DTYPE
from haptic_local_model.haptic_server.station_records import (
    STATION_TOPIC,
    replay_station_rows,
    setup_from_log,
)
from haptic_local_model.haptic_server.world import PortWorld, WorldKind, run_real_time, run_virtual
from haptic_local_model.shared import __version__
from haptic_local_model.shared.config import (
    ConfigError,
    is_config_path,
    load_config_text,
    load_user,
    parse_toml_text,
    resolve,
)
from haptic_local_model.shared.memory import available_bytes
from haptic_local_model.shared.port_config import HandSceneConfig, PortSceneConfig, is_hand_scene

if TYPE_CHECKING:
    from haptic_local_model.haptic_server.view_address import ViewAddress

PORT_TICK_TOPIC = PORT_KIND.topic
HAND_TICK_TOPIC = HAND_KIND.topic
HAND_GRASP_TOPIC = HAND_GRASP_KIND.topic


def write_port_log(path: Path, rows: np.ndarray, metadata: dict[str, dict[str, str]]) -> None:
    """Every row and the metadata, into a temporary file renamed to `path` when whole (and
    removed if the writing fails)."""
    write_rows_log(path, rows, PORT_KIND.topic, PORT_KIND.schema, metadata)


def read_port_log(
    path: Path,
    topic: str = PORT_KIND.topic,
    dtype: np.dtype = PORT_KIND.rows,
) -> tuple[np.ndarray, dict[str, dict[str, str]]]:
    """The rows (on `topic`, of `dtype`) and metadata of a whole port log; a file that is
    not one, or is cut short, is refused by name."""
    metadata = whole_log_metadata(path)
    rows = read_topic_rows(path, topic, dtype)
    if not len(rows):
        raise ConfigError(str(path), topic, "no port ticks: not a port world's log")
    try:
        expected = int(metadata["run"]["ticks"])
    except (KeyError, ValueError):
        raise ConfigError(str(path), "run.ticks", "missing: not a whole port world's log") from None
    if "ports" not in metadata.get("configs", {}):
        raise ConfigError(str(path), "configs.ports", "the port scene is missing")
    if len(rows) != expected:
        raise ConfigError(str(path), "run.ticks", f"{len(rows)} ticks logged, {expected} run")
    return rows, metadata


def _limits(path: Path, metadata: dict[str, dict[str, str]]) -> list[tuple[float, float, float]]:
    try:
        limits = [
            (float(a), float(b), float(c))
            for a, b, c in json.loads(metadata["limits"]["max_wrench"])
        ]
    except (KeyError, ValueError, TypeError):
        limits = []
    if not limits or not all(math.isfinite(v) and v > 0.0 for lim in limits for v in lim):
        raise ConfigError(
            str(path), "limits.max_wrench", "missing, or not 3 positive numbers a port"
        )
    return limits


#: every world kind that runs in this process with its devices, by its log's topic
WORLD_KINDS = {kind.topic: kind for kind in (PORT_KIND, HAND_KIND, HAND_GRASP_KIND)}


def is_port_scene(ref: str) -> bool:
    """A scene reference names a port scene: a shipped one in configs/ports, or a file whose
    table declares ports."""
    if not is_config_path(ref):
        return resolve("ports", ref).is_file()
    path = Path(ref)
    if not path.is_file():
        return False
    try:
        return "ports" in tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError):
        return False


@dataclass(frozen=True)
class PortScene:
    """A port scene as read once: its text (the log keeps it), its config, and the names of
    its devices and users (the scene's, or the command line's)."""

    text: str
    config: PortSceneConfig | HandSceneConfig
    devices: list[str]
    users: list[str]

    def world(self) -> PortWorld:
        """The scene's world with its devices and users, at their start."""
        sim = [load_simulated_device(name) for name in self.devices]
        scene = self.config
        if isinstance(scene, HandSceneConfig):
            users = load_glove_users(scene, self.users)
            if len(scene.ports) == 1:
                return HandPortRun(scene, sim[0], users[0])
            return HandGraspRun(scene, sim, users)
        run = OnePortRun if len(scene.ports) == 1 else PortRun
        return run(scene, sim, [load_user(name) for name in self.users])


def port_scene(ref: str, devices: list[str] | None, users: list[str] | None) -> PortScene:
    """Read a port scene, its devices and users one per port: one name given for every
    port, one per port, or the scene's."""
    path = resolve("ports", ref)
    if not path.is_file():
        raise ConfigError(str(path), "scene", "no such file")
    text = path.read_text()  # read once: the log holds the scene the run ran
    data = parse_toml_text(text, str(path))
    scene_type = HandSceneConfig if is_hand_scene(data) else PortSceneConfig
    scene = load_config_text(scene_type, text, str(path))
    return PortScene(
        text, scene,
        _per_port(devices, [p.device for p in scene.ports], "--device"),
        _per_port(users, [p.user for p in scene.ports], "--user"),
    )  # fmt: skip


def run_port_scene(
    scene: PortScene,
    duration_s: float,
    clock: str,
    log: Path | None,
    view: ViewAddress | None = None,
) -> dict[str, Any]:
    """Run a port scene's world on the virtual clock or in real time, print what it did,
    write its log; the run's figures. With `view` (real time only), a live view of its
    bodies and devices (port_view.py)."""
    world = scene.world()
    ticks = round(duration_s / world.period_s)
    if ticks < 1:
        raise ConfigError("--duration", "--duration", "shorter than one tick")
    _check_rows_fit(world, ticks, copies=1 if view is None else 2)
    print(f"{world.kind.name} world, {len(world.devices)} simulated device(s): loading its "
          f"kernels (a first run compiles them, about 30 s on 2 cores, into "
          f"{os.environ.get('NUMBA_CACHE_DIR', 'the numba cache')})", file=sys.stderr)  # fmt: skip
    if clock == "virtual":
        rows, wall_s = run_virtual(world, duration_s)
        figures: dict[str, Any] = {"ticks": len(rows), "wall_s": wall_s}
    elif view is not None:
        rows, figures = _run_viewed(scene, world, duration_s, view)
        wall_s = figures["wall_s"]
    else:
        rows, figures = run_real_time(world, scene.world(), duration_s)
        wall_s = figures["wall_s"]
    figures["world"] = world.kind.name
    if len(rows):
        print("\n".join(world.summary_lines(rows, wall_s)))
    if log is not None:
        write_rows_log(log, rows, world.kind.topic, world.kind.schema, {
            "configs": {"ports": scene.text, "devices": json.dumps(scene.devices),
                        "users": json.dumps(scene.users)},
            "limits": {"max_wrench": json.dumps(world.limits())},
            "run": {"version": __version__, "duration_s": str(duration_s),
                    "ticks": str(len(rows)), "kind": world.kind.name, "clock": clock},
        })  # fmt: skip
        print(f"log: {log}")
    return figures


#: a run's rows may take this share of the memory available when it starts; the rest is the
#: run's own and the machine's
ROWS_SHARE = 0.75


def _check_rows_fit(world: PortWorld, ticks: int, copies: int) -> None:
    """Refuse, before anything runs, a run whose rows do not fit in memory: a port world's
    run holds every tick's row until it ends (a live view's run holds them twice: in shared
    memory and the copy logged), and a run that outgrew the machine would be killed midway
    with nothing logged."""
    row = world.kind.rows.itemsize
    need, available = ticks * row * copies, available_bytes()
    if need > ROWS_SHARE * available:
        hz = 1.0 / world.period_s
        raise ConfigError("--duration", "--duration", (
            f"{ticks * world.period_s:g} s of {world.kind.name} rows take {need / 1e9:.1f} GB "
            f"({row} B a tick at {hz:g} Hz{', twice with --view' if copies > 1 else ''}, held "
            f"until the run ends) and {available / 1e9:.1f} GB is available: at most "
            f"{ROWS_SHARE * available / (row * copies * hz):.1f} s here"))  # fmt: skip


def _run_viewed(
    scene: PortScene, world: PortWorld, duration_s: float, view: ViewAddress
) -> tuple[np.ndarray, dict[str, Any]]:
    """run_real_time with the rows in shared memory and the port view reading them."""
    from haptic_local_model.haptic_server.port_view import PortRows, PortViewProcess
    from haptic_local_model.shared.timing import loop_cpu

    shared = PortRows(round(duration_s / world.period_s), world.kind.rows)
    child = PortViewProcess(shared, {
        "bind": view.bind, "web_port": view.web_port, "grpc_port": view.grpc_port,
        "scene_text": scene.text, "topic": world.kind.topic, "loop_cpu": loop_cpu(),
    })  # fmt: skip
    try:
        rows, figures = run_real_time(world, scene.world(), duration_s, rows=shared.rows)
        return rows.copy(), figures
    finally:
        child.stop()
        shared.close(unlink=True)


def _rows_topic(path: Path) -> str | None:
    """The topic of a world's or a station's rows in a log, told by its channels (None:
    neither). That channel comes before its first row."""
    for record in head_records(path):
        if isinstance(record, Channel) and (
            record.topic in WORLD_KINDS or record.topic == STATION_TOPIC
        ):
            return str(record.topic)
    return None


def log_kind(path: Path) -> WorldKind | None:
    """The world kind whose rows a log holds (None: none of a world)."""
    return WORLD_KINDS.get(_rows_topic(path) or "")


def is_port_log(path: Path) -> bool:
    """A log of a port world or of a station, whole or cut short: its rows' channel, or its
    port scene (the metadata, written first, survives where the rows' first chunk was cut)."""
    return _rows_topic(path) is not None or "ports" in read_metadata(path).get("configs", {})


def replay_log(path: Path) -> tuple[int, int | None]:
    """Re-run a port world's or a station's log (told by its topic); (ticks compared, the
    first tick whose outputs differ in any bit, or None)."""
    topic = _rows_topic(path)  # the channels read once
    if topic == STATION_TOPIC:
        rows, metadata = read_port_log(path, STATION_TOPIC, STATION_ROW_DTYPE)
        return replay_station_rows(setup_from_log(path, metadata), rows)
    kind = WORLD_KINDS.get(topic or "", PORT_KIND)  # not one: read_port_log says why
    rows, metadata = read_port_log(path, kind.topic, kind.rows)
    scene = load_config_text(kind.scene, metadata["configs"]["ports"], f"{path} (its scene)")
    limits = _limits(path, metadata)
    ports = kind.ports or len(scene.ports)
    if len(limits) != ports or len(scene.ports) != ports:
        found = f"{len(limits)} limits for {len(scene.ports)} ports"
        raise ConfigError(str(path), "limits.max_wrench", found)
    assert kind.replay is not None  # every kind of WORLD_KINDS replays from its rows
    return kind.replay(scene, limits, rows)


def replay_main(path: Path) -> int:
    """`haptic-replay` of a port world's or a station's log: 0 when bit-exact, 1 when it differs."""
    ticks, first = replay_log(path)
    if first is None:
        print(f"replayed {ticks} ticks of {path}: bit-exact")
        return 0
    print(f"replay of {path} differs from the log at tick {first}", file=sys.stderr)
    return 1


def _per_port(given: list[str] | None, defaults: list[str], flag: str) -> list[str]:
    """One name for both ports, one per port, or the scene's."""
    if not given:
        return defaults
    if len(given) == 1:
        return given * len(defaults)
    if len(given) != len(defaults):
        raise ConfigError(
            flag, flag, f"give one, or one per port ({len(defaults)}), not {len(given)}"
        )
    return given

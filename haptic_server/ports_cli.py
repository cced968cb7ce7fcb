"""`haptic-ports`: a port scene (two devices on one co-simulated world, or a hand scene: a
mass-spring hand whose palm a device drives; docs/grasp.md) on the virtual clock, its MCAP
log, and the log's bit-exact replay.

    haptic-ports --scene grasp_vertical --device maglev --device twin_pantograph \\
        --duration 5 --log runs/grasp.mcap
    haptic-ports --replay runs/grasp.mcap

The log holds every tick's row (`/ports/tick`, ros1 with a ros1msg schema generated from
PORT_ROW_DTYPE, like the haptic server's `/haptic/tick`) and, as metadata, the port scene's
text, the devices' limits and the users. It is written to a temporary file beside the
target and renamed when complete, so a log that exists is whole. The replay rebuilds the
co-simulation from the metadata, feeds it each tick's logged device readings (world frame)
and compares every output of the tick with the logged row, bit for bit: the log holds all
the co-simulation's inputs, and the co-simulation is a function of them.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np
from mcap.writer import Writer

from haptic_local_model.device_models.registry import load_simulated_device
from haptic_local_model.haptic_server.hand_grasp_ports import (
    HAND_GRASP_ROW_DTYPE,
    HandGraspRun,
    replay_hand_grasp_rows,
)
from haptic_local_model.haptic_server.hand_ports import (
    HAND_ROW_DTYPE,
    HandPortRun,
    load_glove_users,
    replay_hand_rows,
)
from haptic_local_model.haptic_server.log import (
    _iter_messages,
    is_indexed,
    read_metadata,
    ros1msg_schema,
)
from haptic_local_model.haptic_server.ports import PORT_ROW_DTYPE, PortRun
from haptic_local_model.haptic_server.stages.cosim import (
    carry_sim_bodies,
    cosim_records,
    cosim_tick,
)
from haptic_local_model.shared import __version__
from haptic_local_model.shared.cli import EXIT_CONFIG, add_version, log_file, run_main, seconds
from haptic_local_model.shared.config import (
    ConfigError,
    load_config_text,
    load_user,
    parse_toml_text,
    resolve,
    shipped,
)
from haptic_local_model.shared.port_config import HandSceneConfig, PortSceneConfig, is_hand_scene

PORT_TICK_TOPIC = "/ports/tick"
PORT_TICK_SCHEMA = "haptic_server/PortTick"
HAND_TICK_TOPIC = "/ports/hand_tick"
HAND_TICK_SCHEMA = "haptic_server/HandPortTick"
HAND_GRASP_TOPIC = "/ports/hand_grasp_tick"
HAND_GRASP_SCHEMA = "haptic_server/HandGraspTick"
#: the row fields a replay recomputes (the rest are its inputs or the devices' own)
REPLAYED = ("q", "qd", "command", "body_force", "n_contacts", "penetration", "invalid", "singular",
            "collisions")  # fmt: skip


def write_port_log(path: Path, rows: np.ndarray, metadata: dict[str, dict[str, str]]) -> None:
    """Every row and the metadata, into a temporary file renamed to `path` when whole (and
    removed if the writing fails)."""
    write_rows_log(path, rows, PORT_TICK_TOPIC, PORT_TICK_SCHEMA, metadata)


def write_rows_log(
    path: Path, rows: np.ndarray, topic: str, schema_name: str, metadata: dict[str, dict[str, str]]
) -> None:
    """Rows of a record dtype (one message each on `topic`, a ros1msg schema from the dtype)
    and the metadata, into a temporary file renamed to `path` when whole (removed if the
    writing fails)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    part = path.with_name(path.name + ".part")
    try:
        with part.open("wb") as fh:
            writer = Writer(fh)
            writer.start(profile="", library=f"haptic-local-model {__version__}")
            schema = writer.register_schema(
                name=schema_name, encoding="ros1msg", data=ros1msg_schema(rows.dtype).encode()
            )
            channel = writer.register_channel(topic, message_encoding="ros1", schema_id=schema)
            for name, data in metadata.items():
                writer.add_metadata(name, data)
            for k, row in enumerate(rows):
                t_ns = round(float(row["t"]) * 1e9)
                writer.add_message(channel, log_time=t_ns, data=row.tobytes(),
                                   publish_time=t_ns, sequence=k)  # fmt: skip
            writer.finish()
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(part, path)
    except BaseException:
        part.unlink(missing_ok=True)
        raise


MCAP_MAGIC = b"\x89MCAP0\r\n"


def read_port_log(
    path: Path,
    topic: str = PORT_TICK_TOPIC,
    dtype: np.dtype = PORT_ROW_DTYPE,
) -> tuple[np.ndarray, dict[str, dict[str, str]]]:
    """The rows (on `topic`, of `dtype`) and metadata of a whole port log; a file that is
    not one, or is cut short, is refused by name."""
    if not path.is_file():
        raise ConfigError(str(path), "log", "no such file")
    with path.open("rb") as fh:
        if fh.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise ConfigError(str(path), "log", "not an MCAP file")
    if not is_indexed(path):
        raise ConfigError(str(path), "log", "cut short (no summary): the run did not finish it")
    chunks = []
    schema_text = None
    for name, data, schema in _iter_messages(path):
        if name == topic:
            chunks.append(data)
            schema_text = schema.data.decode() if schema else None
    metadata = read_metadata(path)
    if not chunks:
        raise ConfigError(str(path), topic, "no port ticks: not a haptic-ports log")
    if schema_text != ros1msg_schema(dtype):
        raise ConfigError(str(path), topic, "rows of another layout (another release)")
    if any(len(c) != dtype.itemsize for c in chunks):
        raise ConfigError(str(path), topic, "a row of the wrong size")
    rows = np.frombuffer(b"".join(chunks), dtype)
    try:
        expected = int(metadata["run"]["ticks"])
    except (KeyError, ValueError):
        raise ConfigError(str(path), "run.ticks", "missing: not a whole haptic-ports log") from None
    if "ports" not in metadata.get("configs", {}):
        raise ConfigError(str(path), "configs.ports", "the port scene is missing")
    if len(rows) != expected:
        raise ConfigError(str(path), "run.ticks", f"{len(rows)} ticks logged, {expected} run")
    return rows, metadata


def replay_rows(
    scene: PortSceneConfig, limits: list[tuple[float, float, float]], rows: np.ndarray
) -> tuple[int, int | None]:
    """Re-run the co-simulation on the rows' device readings (and the sim's bodies as each
    tick met them); (ticks compared, the first tick whose outputs differ in any bit, or
    None)."""
    model, data = cosim_records(scene, limits)
    d = data[0]
    for k, row in enumerate(rows):
        d["device_pose"] = row["device_pose"]
        d["device_twist"] = row["device_twist"]
        if scene.sim_bodies:
            carry_sim_bodies(model, data, row["sim_bodies"], 0.0)
            d["sim_wrench"] = row["sim_wrench"]
        cosim_tick(model, data)
        for name in REPLAYED:
            if np.asarray(d[name]).tobytes() != np.asarray(row[name]).tobytes():
                return k + 1, k
    return len(rows), None


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


def replay_log(path: Path) -> tuple[int, int | None]:
    """Re-run a port log (two ports on a co-simulated box, a hand scene's port, or two
    hands on a box), told by its topic."""
    topics = (
        {topic for topic, _, _ in _iter_messages(path)}
        if path.is_file() and is_indexed(path)
        else set()
    )
    for topic, dtype, ports, replay in (
        (HAND_TICK_TOPIC, HAND_ROW_DTYPE, 1, lambda sc, lim, r: replay_hand_rows(sc, lim[0], r)),
        (HAND_GRASP_TOPIC, HAND_GRASP_ROW_DTYPE, 2, replay_hand_grasp_rows),
    ):
        if topic not in topics:
            continue
        rows, metadata = read_port_log(path, topic, dtype)
        hand_scene = load_config_text(
            HandSceneConfig, metadata["configs"]["ports"], f"{path} (its hand scene)"
        )
        limits = _limits(path, metadata)
        if len(limits) != ports or len(hand_scene.ports) != ports:
            found = f"{len(limits)} limits for {len(hand_scene.ports)} ports"
            raise ConfigError(str(path), "limits.max_wrench", found)
        return replay(hand_scene, limits, rows)
    rows, metadata = read_port_log(path)
    scene = load_config_text(
        PortSceneConfig, metadata["configs"]["ports"], f"{path} (its port scene)"
    )
    limits = _limits(path, metadata)
    if len(limits) != len(scene.ports):
        raise ConfigError(
            str(path), "limits.max_wrench", f"{len(limits)} limits for {len(scene.ports)} ports"
        )
    return replay_rows(scene, limits, rows)


def run_hands_cli(args: argparse.Namespace, text: str, source: str) -> int:
    """A hand scene (one port and a mass-spring hand, or two hands on a box): run,
    summary, log."""
    scene = load_config_text(HandSceneConfig, text, source)
    if round(args.duration * scene.haptic_rate_hz) < 1:
        raise ConfigError("--duration", "--duration", "shorter than one tick")
    devices = _per_port(args.device, [p.device for p in scene.ports], "--device")
    users = _per_port(args.user, [p.user for p in scene.ports], "--user")
    user_configs = load_glove_users(scene, users)
    sim = [load_simulated_device(name) for name in devices]
    run: HandPortRun | HandGraspRun = (
        HandPortRun(scene, sim[0], user_configs[0])
        if len(scene.ports) == 1
        else HandGraspRun(scene, sim, user_configs)
    )
    result = run.run(args.duration)
    rows = result.rows
    print("\n".join(_hands_summary(scene, run, rows, result.wall_s, users)))
    if args.log is not None:
        if isinstance(run, HandPortRun):
            limits = [list(map(float, run.model[0]["max_wrench"]))]
            topic, schema = HAND_TICK_TOPIC, HAND_TICK_SCHEMA
        else:
            limits = [list(map(float, m[0]["max_wrench"])) for m in run.models]
            topic, schema = HAND_GRASP_TOPIC, HAND_GRASP_SCHEMA
        write_rows_log(args.log, rows, topic, schema, {
            "configs": {"ports": text, "devices": json.dumps(devices),
                        "users": json.dumps(users)},
            "limits": {"max_wrench": json.dumps(limits)},
            "run": {"version": __version__, "duration_s": str(args.duration),
                    "ticks": str(len(rows)), "kind": "hand"},
        })  # fmt: skip
        print(f"log: {args.log}")
    return 0


def _hands_summary(scene: HandSceneConfig, run: HandPortRun | HandGraspRun, rows: np.ndarray,
                   wall_s: float, users: list[str]) -> list[str]:  # fmt: skip
    last = rows[-min(len(rows), round(scene.haptic_rate_hz)) :]
    lines = [f"{len(rows)} ticks in {wall_s:.2f} s of wall time"]
    if isinstance(run, HandPortRun):
        cmd, wall = last["command"][:, :2], last["contact_force"]
        lines.append(
            f"port {scene.ports[0].name} ({run.device.name}, {users[0]}): mean command over "
            f"the last second ({cmd[:, 0].mean():+.3f}, {cmd[:, 1].mean():+.3f}) N, the walls' "
            f"force on the hand ({wall[:, 0].mean():+.3f}, {wall[:, 1].mean():+.3f}) N"
        )
        lines.append(f"steps held {rows['singular'][-1]}, readings or commands not finite "
                     f"{rows['invalid'][-1]}")  # fmt: skip
        return lines
    for p, port in enumerate(scene.ports):
        cmd = last["command"][:, p, :2]
        lines.append(
            f"port {port.name} ({run.devices[p].name}, {users[p]}): mean command over the "
            f"last second ({cmd[:, 0].mean():+.3f}, {cmd[:, 1].mean():+.3f}) N; readings or "
            f"commands not finite {rows['invalid'][-1, p]}"
        )
    q = rows["box_q"]
    lines.append(
        f"box: moved ({(q[-1, 0] - q[0, 0]) * 1e3:+.3f}, {(q[-1, 1] - q[0, 1]) * 1e3:+.3f}) mm, "
        f"turned {q[-1, 2] - q[0, 2]:+.4f} rad; hand-box contacts at the end "
        f"{rows['n_contacts'][-1]}, steps held {rows['singular'][-1]}"
    )
    return lines


def _summary(run: PortRun, rows: np.ndarray, wall_s: float) -> list[str]:
    last = rows[-min(len(rows), round(run.scene.haptic_rate_hz)) :]
    lines = [
        f"{len(rows)} ticks, {rows['t'][-1] + float(run.data[0]['dt']):.3f} s in {wall_s:.2f} s "
        f"of wall time",
    ]
    for p, port in enumerate(run.scene.ports):
        cmd = last["command"][:, p, :2]
        lines.append(
            f"port {port.name} ({run.devices[p].name}, {run.users[p].name}): mean command over "
            f"the last second ({cmd[:, 0].mean():+.3f}, {cmd[:, 1].mean():+.3f}) N"
        )
    for i, name in enumerate(run.order):
        q = rows["q"][:, 3 * i : 3 * i + 3]
        dx, dy, turn = (q[-1, 0] - q[0, 0]) * 1e3, (q[-1, 1] - q[0, 1]) * 1e3, q[-1, 2] - q[0, 2]
        lines.append(f"{name}: moved ({dx:+.3f}, {dy:+.3f}) mm, turned {turn:+.4f} rad")
    lines.append(
        f"contacts at the end {rows['n_contacts'][-1]}, commands not finite (zeroed) "
        f"{rows['invalid'][-1]}, steps held {rows['singular'][-1]}"
    )
    return lines


def run_ports_cli(args: argparse.Namespace) -> int:
    path = resolve("ports", args.scene)
    if not path.is_file():
        raise ConfigError(str(path), "scene", "no such file")
    text = path.read_text()  # read once: the log holds the scene the run ran
    if is_hand_scene(parse_toml_text(text, str(path))):
        return run_hands_cli(args, text, str(path))
    scene = load_config_text(PortSceneConfig, text, str(path))
    if round(args.duration * scene.haptic_rate_hz) < 1:
        raise ConfigError("--duration", "--duration", "shorter than one tick")
    devices = _per_port(args.device, [p.device for p in scene.ports], "--device")
    users = _per_port(args.user, [p.user for p in scene.ports], "--user")
    sim = [load_simulated_device(name) for name in devices]
    user_configs = [load_user(name) for name in users]
    run = PortRun(scene, sim, user_configs)
    entered = time.perf_counter()
    result = run.run(args.duration)
    wall = time.perf_counter() - entered
    print("\n".join(_summary(run, result.rows, wall)))
    if args.log is not None:
        limits = [list(map(float, run.model[0]["max_wrench"][p])) for p in range(len(sim))]
        metadata = {
            "configs": {
                "ports": text,
                "devices": json.dumps(devices),
                "users": json.dumps(users),
            },
            "limits": {"max_wrench": json.dumps(limits)},
            "run": {
                "version": __version__,
                "duration_s": str(args.duration),
                "ticks": str(len(result.rows)),
            },
        }
        write_port_log(args.log, result.rows, metadata)
        print(f"log: {args.log}")
    return 0


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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="haptic-ports", description=__doc__.split("\n\n")[0])
    add_version(parser)
    parser.add_argument(
        "--scene", default="grasp_vertical", help="port scene in configs/ports or a path"
    )
    parser.add_argument(
        "--device", action="append", help="a device for both ports, or give it twice (one per port)"
    )
    parser.add_argument("--user", action="append", help="a user for both ports, or give it twice")
    parser.add_argument("--duration", type=seconds, default=5.0, help="virtual seconds (default 5)")
    parser.add_argument("--log", type=log_file, default=None, metavar="OUT.mcap")
    parser.add_argument(
        "--replay",
        type=Path,
        default=None,
        metavar="LOG.mcap",
        help="re-run a log's co-simulation and compare it bit for bit",
    )
    parser.add_argument("--list", action="store_true", help="the shipped port scenes")
    args = parser.parse_args(argv)
    if args.list:
        for name, text in shipped("ports").items():
            print(f"{name}  {text}")
        return 0
    if args.replay is not None:
        return run_main(lambda: _replay(args.replay))
    return run_main(lambda: run_ports_cli(args))


def _replay(path: Path) -> int:
    ticks, first = replay_log(path)
    if first is None:
        print(f"replayed {ticks} ticks of {path}: bit-exact")
        return 0
    print(f"replay of {path} differs from the log at tick {first}", file=sys.stderr)
    return 1


__all__ = [
    "EXIT_CONFIG",
    "main",
    "read_port_log",
    "replay_rows",
    "write_port_log",
    "write_rows_log",
]


if __name__ == "__main__":
    sys.exit(main())

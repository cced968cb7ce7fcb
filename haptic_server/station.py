"""A haptic station: one port's device and user, coupled to its tool in a shared world that
`haptic-world` co-simulates, over a Zenoh router (docs/stations.md).

Each tick (wall-clock paced at the scene's haptic rate): take each ToolState waiting (a
malformed one is refused and counted), run the compiled tick (haptic_server/stages/station.py:
the device, its user, the coupling rendered against the tool carried on by its twist, the
watchdog's ramp to the safe state), publish the device's state. The taking, the tick, the
DeviceState and the row are compiled (haptic_server/stages/station_link.py): the loop's
Python is its Zenoh calls and the device's noise refills. The rows stay in memory and are
written to MCAP when the run ends (`--log`: a temporary file renamed when whole), and
`haptic-replay` re-runs them (haptic_server/station_records.py).
"""

from __future__ import annotations

import copy
import time
from pathlib import Path
from typing import Any

import numpy as np

from haptic_local_model.device_models.base import SimulatedDevice
from haptic_local_model.device_models.common import refill_noise
from haptic_local_model.device_models.kernels import noise_ready
from haptic_local_model.haptic_server.log import rows_in_order, write_rows_log
from haptic_local_model.haptic_server.port_scene import glove_script
from haptic_local_model.haptic_server.stages.station import STATION_ROW_DTYPE
from haptic_local_model.haptic_server.stages.station_link import (
    station_link,
    station_log,
    station_step,
    take_tool,
)
from haptic_local_model.haptic_server.station_records import (
    STATION_SCHEMA,
    STATION_TOPIC,
    StationSetup,
    station_metadata,
    station_record,
)
from haptic_local_model.shared import __version__
from haptic_local_model.shared.config import UserConfig
from haptic_local_model.shared.net.stations import (
    StateRoute,
    StationNetworkConfig,
    open_client,
    port_keys,
)
from haptic_local_model.shared.port_config import HandSceneConfig, PortSceneConfig
from haptic_local_model.shared.protocol.station import TOOL_RECORD, device_record
from haptic_local_model.shared.protocol.station_codec import reason_counts
from haptic_local_model.shared.timing import Pacer, SampleWindow, enter_loop

TOOL_RING = 64  # tool states kept between two ticks: a stalled tick's worth and more
SPIN_NS = 100_000  # the wait's last 0.1 ms spins (several loops share two cores)
MAX_LOG_S = 600.0  # the rows of at most this long stay in memory (--log: --duration <= this)
RING_S = 60.0  # without --log: the last this long (the summary's figures)
#: The station says it softened (docs/stations.md, "Passivity"): its passivity controller
#: damped its device on at least SOFTENED_SHARE of the ticks of the last SOFTEN_WINDOW_S
#: (the link gave out more than it held, often: what the station renders is no longer the
#: coupling but the controller's damping); it says it is restored once that share is at
#: most RESTORED_SHARE.
SOFTEN_WINDOW_S = 0.5
SOFTENED_SHARE = 0.2
RESTORED_SHARE = 0.05


class Softening:
    """Whether a station's passivity controller is softening it, over a sliding window of
    its ticks (one bit a tick, O(1) a tick): the `softened` and `restored` events."""

    def __init__(self, window: int) -> None:
        self.damped = np.zeros(window, np.bool_)
        self.count = 0  # damped ticks in the window
        self.ticks = 0
        self.on = False
        self.events: list[dict[str, Any]] = []

    def add(self, damped: bool, t_s: float, damping: np.ndarray) -> dict[str, Any] | None:
        """This tick: damped or not, at `t_s` of the run, with the controller's damping per
        axis; the event it makes, if any (kept in `events` too)."""
        i = self.ticks % len(self.damped)
        self.count += int(damped) - int(self.damped[i])
        self.damped[i] = damped
        self.ticks += 1
        if self.ticks < len(self.damped):
            return None  # not a whole window yet
        share = self.count / len(self.damped)
        if not self.on and share >= SOFTENED_SHARE:
            self.on = True
        elif self.on and share <= RESTORED_SHARE:
            self.on = False
        else:
            return None
        event = {"event": "softened" if self.on else "restored", "t_s": round(t_s, 3),
                 "damped_share": round(share, 3),
                 "damping": [round(float(d), 3) for d in damping]}  # fmt: skip
        self.events.append(event)
        return event


class Station:
    """One station's records, ready to run (module docstring)."""

    def __init__(
        self,
        scene: PortSceneConfig | HandSceneConfig,
        network: StationNetworkConfig,
        port: str,
        device: SimulatedDevice,
        user: UserConfig,
        max_rows: int,
    ) -> None:
        names = [p.name for p in scene.ports]
        if port not in names:
            raise ValueError(f"port: {port!r} is not one of the scene's ({', '.join(names)})")
        self.scene, self.network, self.port, self.device = scene, network, port, device
        self.index = names.index(port)
        self.user = user
        # a hand's palm is not yet observed at the world (its engine has no controller)
        passivity = network.passivity == "tdpa" and isinstance(scene, PortSceneConfig)
        self.setup = StationSetup(scene, self.index, device, user, network.watchdog_ms / 1e3,
                                  network.safe_ramp_ms / 1e3, passivity,
                                  network.local_model)  # fmt: skip
        self.station = station_record(self.setup)
        self._records, self._dt = device.records, float(self.station[0]["dt"])  # per tick
        self.rows = np.zeros(max_rows, STATION_ROW_DTYPE)
        self.rows.view(np.uint8)[:] = 0  # every page touched now, not in the loop
        self.n_rows = 0
        self.link = station_link()  # STATION_LINK_DTYPE: the ToolStates taken, the counters
        self.refills = 0
        self.work_us = SampleWindow(100_000)
        self.pacer = Pacer(round(scene.period_s * 1e9), SPIN_NS, None)
        self.softening = Softening(max(1, round(SOFTEN_WINDOW_S / scene.period_s)))
        self.on_event: Any = None  # called with each softening event (haptic-station: emit)
        self.epoch = time.time_ns()
        self.message = device_record(self.index, self.epoch)  # the tick's DeviceState
        self._stop = False
        self.route: StateRoute | None = None  # its link's routes, while it runs
        # a hand's station sends its user's glove (finger_angles on its own clock)
        self._glove = np.zeros((0, 1))
        if isinstance(scene, HandSceneConfig):
            rest = [a for f in scene.hand_of(self.index).fingers for a in f.rest]
            self._glove = glove_script(user, rest)
        self.link[0]["n_glove"] = len(self._glove)

    def request_stop(self, *_: object) -> None:
        self._stop = True

    def receive(self, sub: Any, now_ns: int) -> None:
        """Every ToolState waiting, oldest first: each taken or refused and counted
        (station_link.take_tool)."""
        while (sample := sub.try_recv()) is not None:
            self.take(sample.payload.to_bytes(), now_ns)

    def take(self, raw: bytes, now_ns: int) -> None:
        """One ToolState received at now_ns, taken or refused and counted."""
        take_tool(self.station, self.link, self.index, now_ns, raw)

    def reasons(self) -> dict[str, int]:
        """The refused ToolStates, by reason (those that happened)."""
        return reason_counts(self.link[0]["reasons"])

    def run(self, duration_s: float | None, ready: Any = None) -> dict[str, Any]:
        device_key, tool_key = port_keys(self.network.namespace, self.port)
        session = open_client(self.network.station(self.port))
        route = StateRoute(
            session, (tool_key, device_key), TOOL_RING, self.network.state_reliability
        )
        self.route = route
        pacer = Pacer(round(float(self.station[0]["dt"]) * 1e9), SPIN_NS, duration_s)
        self.pacer = pacer
        enter_loop(self.warm, ready)

        link = self.link[0]

        def taken() -> int:  # the tool states taken or refused so far (route.check)
            return int(link["received"] + link["rejected"])

        def tick(now: int, seq: int) -> None:
            self.receive(route.sub, now)
            self.step(now, seq)
            route.pub.put(self.message.tobytes())
            self.log(now, pacer.late_ns)
            route.check(now, taken)

        with session:  # closed however the loop ends
            pacer.run(tick, lambda: self._stop)
        return self.summary()

    def step(self, now_ns: int, seq: int) -> None:
        """One tick at now_ns (the loop's clock) on the tool states taken: the device's noise
        refilled if the tick needs it, the compiled tick, the DeviceState in `message`."""
        dev, dt = self._records, self._dt
        if not noise_ready(dev, dt):
            refill_noise(self.device.noise, dev, dt)
            self.refills += 1
        station_step(self.station, dev, self.link, self.message, self._glove, now_ns,
                     time.time_ns(), seq)  # fmt: skip

    def log(self, now_ns: int, late_ns: int) -> None:
        """The tick's row (the ring's next), with its work since now_ns."""
        work_ns = time.perf_counter_ns() - now_ns
        self.work_us.add(work_ns / 1e3)
        k = self.n_rows % len(self.rows)
        station_log(self.station, self.link, self.rows, k, now_ns, late_ns, work_ns)
        self.n_rows += 1
        damping = self.rows[k]["pc_damping"]
        event = self.softening.add(bool(damping.any()), self.n_rows * self._dt, damping)
        if event is not None and self.on_event is not None:
            self.on_event(event)  # rare (a transition), after the tick's DeviceState went out

    def warm(self) -> None:
        """Compile (or load) the tick on spare records and a spare device before the loop
        (the device's own noise is drawn from its start, as the replay draws it)."""
        spare, link, device = self.station.copy(), self.link.copy(), copy.deepcopy(self.device)
        tool = np.zeros(1, TOOL_RECORD)  # a ToolState refused (the wrong magic): not taken
        take_tool(spare, link, self.index, 0, tool.tobytes())
        station_step(spare, device.records, link, self.message.copy(), self._glove, 0, 0, 0)
        station_log(spare, link, np.zeros(1, STATION_ROW_DTYPE), 0, 0, 0, 0)

    def logged_rows(self) -> np.ndarray:
        return rows_in_order(self.rows, self.n_rows)

    def write_log(self, path: Path, texts: dict[str, str]) -> None:
        """The rows and what replays them (the scene's, device's and user's files, `texts`:
        ports, device, user), into a temporary file renamed to `path` when whole."""
        rows = self.logged_rows()
        write_rows_log(path, rows, STATION_TOPIC, STATION_SCHEMA, {
            "configs": {"ports": texts["ports"], "port": self.port, "device": self.device.name,
                        "user": self.user.name},
            "station": station_metadata(self.setup, texts),
            "run": {"version": __version__, "ticks": str(len(rows)), "kind": "haptic-station"},
        })  # fmt: skip

    def summary(self) -> dict[str, Any]:
        rows = self.logged_rows()
        c = self.link[0]
        return {
            "port": self.port,
            "device": self.device.name,
            "user": self.user.name,
            "ticks": self.n_rows,
            **self.pacer.figures(),
            "work_us": self.work_us.percentiles(50, 99, 99.9),
            "noise_refills": self.refills,
            "tool_states_received": int(c["received"]),
            "tool_states_rejected": int(c["rejected"]),
            "rejected_by_reason": self.reasons(),
            "safe_entries": int(c["safe_entries"]),
            "commands_invalid": int(self.station[0]["invalid"]),
            # ticks it stayed safe for a tool state far from the squeeze it left (_rejoins)
            "rejoin_waits": int(self.station[0]["rejoin_waits"]),
            # ticks it braked its device, back from safe, before it coupled (_brakes)
            "rejoin_brakes": int(self.station[0]["rejoin_brakes"]),
            # the pad's contact with the object rendered here (0: it has none, or it is off)
            "local_model": int(self.station[0]["local_model"]),
            "mean_command_last_s": (
                rows["out"][-min(len(rows), 1000) :].mean(axis=0).tolist() if len(rows) else []
            ),
            "passivity": {**passivity_summary(rows), "events": self.softening.events},
            "routes_redeclared": dict(self.route.redeclared) if self.route else {},
            "epoch": self.epoch,
        }


def passivity_summary(rows: np.ndarray) -> dict[str, Any]:
    """What the station's passivity controller did over the rows kept (docs/stations.md,
    "Passivity"): the ticks it damped the device (its link would have given out energy it
    did not hold: the station softened), their share, and its largest damping per axis."""
    damped = (rows["pc_damping"] > 0.0).any(axis=1) if len(rows) else np.zeros(0, bool)
    return {
        "damped_ticks": int(damped.sum()),
        "damped_share": round(float(damped.mean()), 6) if len(rows) else 0.0,
        "max_damping": rows["pc_damping"].max(axis=0).tolist() if len(rows) else [0.0] * 3,
    }

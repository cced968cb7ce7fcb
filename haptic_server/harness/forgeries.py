"""Forged local models for the plausibility check and the loop's guard (tests, benchmarks,
the soak), and a forger that publishes one with the sim's credentials.

Each forgery takes a real update of the scene's sim (its own tool state, so everything else
in it is consistent and plausible) and changes what an attacker with the sim's credentials
would change, as the issue's attacks and the validator's bounds suggest. `EXPECTED` says
what the haptic server must make of each: refused with a reason, or installed and
neutralised by the loop's guard ("guard").
"""

from __future__ import annotations

import base64
import dataclasses
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from haptic_local_model.shared.config import SceneConfig
from haptic_local_model.shared.net.config import NetworkConfig
from haptic_local_model.shared.protocol.codes import Fault
from haptic_local_model.shared.protocol.layout import CONTACT_FLOATS
from haptic_local_model.shared.protocol.proxy import ProxyState, decode_proxy
from haptic_local_model.shared.protocol.update import (
    ContactSet,
    LocalModelUpdate,
    contact_rows,
    encode_update,
)

Forgery = Callable[[LocalModelUpdate, SceneConfig], LocalModelUpdate]


def _with_contact(u: LocalModelUpdate, depth: float, **columns: float) -> LocalModelUpdate:
    """u with one contact more: at the operational point, `depth` inside a wall whose
    outward normal points along -x of the world (columns override the material)."""
    rows, floats = contact_rows(1)
    link = u.op_link
    rows[0]["tool"] = u.op_point
    x, y = u.tool_pose[0], u.tool_pose[1]
    rows[0]["env"] = (x - depth, y)  # the wall's surface: the tool point is depth beyond it
    rows[0]["normal"] = (-1.0, 0.0)
    rows[0]["friction"] = columns.get("friction", 0.0)
    rows[0]["restitution"] = 0.0
    rows[0]["stiffness"] = columns.get("stiffness", 15000.0)
    rows[0]["damping"] = columns.get("damping", 0.0)
    rows[0]["tangential_stiffness"] = columns.get("stiffness", 15000.0)
    rows[0]["env_velocity"] = (columns.get("env_speed", 0.0), 0.0)
    old = u.contacts
    contacts = ContactSet(
        np.concatenate([old.link, [link]]).astype(np.int64),
        np.concatenate([old.key, [10**6]]).astype(np.int64),
        np.concatenate([old.floats.reshape(-1, CONTACT_FLOATS), floats]),
    )
    return dataclasses.replace(u, contacts=contacts, tool_touching=True)


def stiff_contact(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """The issue's: a contact of stiffness 1e8 N/m with mu = 10, 1 mm deep."""
    return _with_contact(u, 1e-3, stiffness=1e8, friction=10.0)


def tiny_mass(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """The issue's: D = 1e-6 I (with the Lambda^-1 it implies, to look consistent)."""
    d = u.dof
    return dataclasses.replace(u, mass_matrix=1e-6 * np.eye(d), lambda_inv=u.lambda_inv * 1e6)


def fast_joints(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """The issue's: joint velocities of 100 rad/s."""
    return dataclasses.replace(u, qd=np.full(u.dof, 100.0))


def heavy_gravity(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """The issue's: gravity torques of 1e4."""
    return dataclasses.replace(u, gravity=np.full(u.dof, 1e4))


def flipped_lambda(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """The issue's: a Lambda^-1 of the opposite sign to J D^-1 J^T."""
    return dataclasses.replace(u, lambda_inv=-u.lambda_inv)


def deep_contact(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """At the envelope's edge: a contact of the scene's stiffest material, 95 % of
    max_penetration_m deep. Plausible, so installed: the guard must stop what it does."""
    stiffest = max(m.stiffness_n_per_m for m in scene.materials.values())
    return _with_contact(u, 0.95 * scene.safety.max_penetration_m, stiffness=stiffest)


def fast_wall(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """A wall point moving at 50 m/s."""
    return _with_contact(u, 0.0, env_speed=50.0)


def teleport(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """The tool moved far since the last update (the first joint turned by 2.5 rad, or a
    free body 0.3 m along x), every field as the sim computes it there."""
    from haptic_local_model.sim_server.world import SimWorld

    world = SimWorld(scene)
    q = u.q.copy()
    q[0] += 2.5 if scene.tool.kind == "linkage" else 0.3
    world.set_tool_state(q, u.qd)
    world.time = u.sim_time
    moved = world.local_model(u.epoch, u.seq, u.publish_time_ns, u.state_lead_s)
    return dataclasses.replace(moved, contacts=ContactSet.empty(), tool_touching=False)


def other_tool(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """A longer first link than the scene's."""
    lengths = u.lengths.copy()
    lengths[0] += 0.05 if scene.tool.kind == "linkage" else 0.0
    base = u.base + (0.0 if scene.tool.kind == "linkage" else 0.05)
    return dataclasses.replace(u, lengths=lengths, base=base)


def seq_ahead(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """A sequence number 1000 ahead (it would lock the sim's own updates out)."""
    return dataclasses.replace(u, seq=u.seq + 1000)


def forged_velocity_torque(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """C(q, qd) qd of 100 N m on every joint (a linkage's)."""
    return dataclasses.replace(u, velocity_torque=np.full(u.dof, 100.0))


def resisted_everywhere(u: LocalModelUpdate, scene: SceneConfig) -> LocalModelUpdate:
    """Every direction resisted, away from any singularity (a linkage's)."""
    return dataclasses.replace(u, resisted=np.eye(3))


FORGERIES: dict[str, Forgery] = {
    "stiff_contact": stiff_contact,
    "tiny_mass": tiny_mass,
    "fast_joints": fast_joints,
    "heavy_gravity": heavy_gravity,
    "flipped_lambda": flipped_lambda,
    "deep_contact": deep_contact,
    "fast_wall": fast_wall,
    "teleport": teleport,
    "other_tool": other_tool,
    "seq_ahead": seq_ahead,
    "forged_velocity_torque": forged_velocity_torque,
    "resisted_everywhere": resisted_everywhere,
}

#: what the haptic server makes of each (a linkage scene's; "guard": installed, neutralised)
EXPECTED = {
    "stiff_contact": "implausible",
    "tiny_mass": "inconsistent",
    "fast_joints": "implausible",
    "heavy_gravity": "inconsistent",
    "flipped_lambda": "inconsistent",
    "deep_contact": "guard",
    "fast_wall": "implausible",
    "teleport": "jump",
    "other_tool": "inconsistent",
    "seq_ahead": "jump",
    "forged_velocity_torque": "inconsistent",
    "resisted_everywhere": "inconsistent",
}


class Forger:
    """A peer holding the sim's credentials (a compromised sim host): it follows the proxy
    states the haptic server publishes and, on demand, publishes a forgery of the update the
    sim would send next, built from the proxy's own state (so everything else in it is
    consistent and plausible), in the sim's epoch."""

    def __init__(self, network: NetworkConfig, scene: SceneConfig, epoch: int) -> None:
        from haptic_local_model.shared.net.config import EndpointSpec
        from haptic_local_model.shared.net.transport import keys, open_session
        from haptic_local_model.sim_server.world import SimWorld

        self.scene, self.epoch = scene, epoch
        sim = network.sim
        spec = EndpointSpec(connect=sim.connect, user=sim.user, password_file=sim.password_file)
        self._session = open_session(spec)
        k = keys(network.namespace)
        self._publisher = self._session.declare_publisher(k.update)
        self._newest: ProxyState | None = None
        self._cond = threading.Condition()
        self._sub = self._session.declare_subscriber(k.proxy, self._receive)
        # made (and its kernels loaded) now: a forgery must go out within one sim period
        self._world = SimWorld(scene)
        self._world.local_model(epoch, 0, 0)

    def _receive(self, sample: Any) -> None:
        proxy = decode_proxy(sample.payload.to_bytes())
        with self._cond:
            self._newest = proxy
            self._cond.notify_all()

    def next_rendering(self, timeout_s: float = 30.0) -> ProxyState:
        """The next proxy state published from now on that renders the sim's epoch."""
        end = time.monotonic() + timeout_s
        with self._cond:
            self._newest = None
            while True:
                p = self._newest
                if p is not None and p.epoch == self.epoch and p.valid and not p.safe_state:
                    return p
                if not self._cond.wait(max(0.0, end - time.monotonic())):
                    raise RuntimeError("the haptic server does not render the sim's model")

    def forge(self, name: str) -> bytes:
        """Publish forgery `name` of the sim's update three ahead; returns its bytes."""
        proxy = self.next_rendering()
        world = self._world
        world.set_tool_state(proxy.q, proxy.qd)
        # the sim's next ones may be on their way already (a loaded host delays the forger by
        # a period or two: at + 2 the sim's update of that seq came first, `sequence`); at
        # most + 3, the sequence's rate the jump check allows one period after the last
        seq = proxy.update_seq + 3
        # the sim's time as the sim stamps update seq: the end of its step, (seq + 1) periods
        # (one period less, the sim's own update seq - 1, installed first on a loaded host,
        # held the same time, and the forgery was refused as a jump, not judged for itself)
        world.time = (seq + 1) * world.period
        update = FORGERIES[name](world.local_model(self.epoch, seq, 0), self.scene)
        # stamped as it goes out, as the sim stamps: building a forgery (teleport makes a world)
        # may take longer on a loaded host than max_update_age_ms, and "late" is not its point
        raw = encode_update(dataclasses.replace(update, publish_time_ns=time.time_ns()))
        self._publisher.put(raw)
        return raw

    def close(self) -> None:
        self._sub.undeclare()
        self._session.close()


# --- what a forgery did, from the haptic server's log ---------------------------------------

WINDOW_S = 0.6  # what a forgery did is judged over this long after it
LIMIT_MS, RESUME_MS = 50.0, 200.0  # at most at the device's limit; rendering back after a trip


@dataclass
class AttackResult:
    forgery: str
    verdict: str  # "installed" or the reason it was refused ("lost": it never arrived)
    at_limit_ms: float  # ticks at the device's limit in the window, as ms
    tripped: str  # the guard's fault ("" none)
    resumed_ms: float  # from the sim's first good update after the trip to normal rendering
    own_refused: int  # the sim's own updates refused in the window (but a displaced one)
    arrived: bool  # the forgery reached the haptic server at all

    def meets_targets(self) -> bool:
        expected = EXPECTED[self.forgery]
        if expected == "guard":
            verdict_ok = self.verdict == "installed"
        else:
            verdict_ok = self.verdict not in ("installed", "lost")
        return (
            self.arrived and verdict_ok and self.at_limit_ms <= LIMIT_MS
            and self.resumed_ms <= RESUME_MS and self.own_refused == 0
        )  # fmt: skip


def measure(
    forgery: str, log: Path, raw: bytes, max_wrench: tuple[float, float, float]
) -> AttackResult:
    """The forgery's verdict and what followed it over WINDOW_S, from the haptic server's log:
    time at the device's limit on any axis, the guard's trip and how long after the sim's next
    good update rendering was normal again (not safe, no fault), the sim's own updates refused
    (an installed forgery takes its sequence number: the sim's updates up to it that arrive
    after it are refused as out of order, displaced, not refused because of what it said)."""
    from haptic_local_model.haptic_server.log import UPDATE_TOPIC, read_json_topic, read_ticks

    records = read_json_topic(log, UPDATE_TOPIC)
    forged = [r for r in records if base64.b64decode(r["raw_b64"]) == raw]
    ticks = read_ticks(log)
    if not forged:
        return AttackResult(forgery, "lost", 0.0, "", 0.0, 0, False)
    rec = forged[0]
    verdict = "installed" if rec["installed"] else rec["reason"]
    start = int(rec["tick"])
    dt = float(np.median(ticks["dt"]))
    window = ticks[(ticks["tick"] >= start) & (ticks["tick"] < start + round(WINDOW_S / dt))]
    limit = np.asarray(max_wrench) * (1 - 1e-9)
    at_limit = int((np.abs(window["wrench_command"]) >= limit).any(axis=1).sum())
    faults = np.flatnonzero(window["fault"] != 0)
    own = [r for r in records if r is not rec and "seq" in r and r.get("epoch") == rec.get("epoch")]
    own_in_window = [r for r in own if start <= int(r["tick"]) < start + len(window)]
    tripped, resumed_ms = "", 0.0
    if faults.size:
        trip_tick = int(window["tick"][faults[0]])
        tripped = Fault(int(window["fault"][faults[0]])).name.lower()
        good = [int(r["tick"]) for r in own_in_window if r["installed"] and r["tick"] > trip_tick]
        resumed_ms = float("inf")
        if good:
            after = window[window["tick"] >= good[0]]
            normal = np.flatnonzero((after["safe"] == 0.0) & (after["fault"] == 0))
            if normal.size:
                resumed_ms = float(normal[0]) * dt * 1e3
    refused = [
        r for r in own_in_window
        if not r["installed"] and not (rec["installed"] and r["reason"] == "sequence"
                                       and r["seq"] <= rec["seq"])
    ]  # fmt: skip
    return AttackResult(
        forgery, verdict, at_limit * dt * 1e3, tripped, resumed_ms, len(refused), True
    )

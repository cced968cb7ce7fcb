"""The hardware behind the fake vendor bindings (tests/test_hardware_adapters.py).

Each fake (HaplyHardwareAPI, forcedimension_core, pyOpenHaptics) exposes the maker's call
names and units at the boundary the adapters use, and moves one `FakeHandle`: a 0.2 kg
handle in 3D with viscous friction (FAKE_VENDOR_MASS, FAKE_VENDOR_FRICTION), pushed by a
constant hand force and by the commanded force, integrated over the wall time between calls.
It records what the adapter asked: the calls in order, every force with its time, the forces
that were not finite or beyond the device's limit, and whether the device was closed. The
record is JSON, written to $FAKE_VENDOR_RECORD when the device is closed and again at exit,
so a test in another process reads it. Settings from the environment (a test sets them for
the server it starts):

- FAKE_VENDOR_RECORD: where to write the record
- FAKE_VENDOR_HAND: "fx,fy,fz", the hand's force (N, the vendor's frame)
- FAKE_VENDOR_START: "x,y,z", the handle's start (m, the vendor's frame)
- FAKE_VENDOR_LIMIT: the device's force limit (N): forces beyond it are counted
- FAKE_VENDOR_RAISE_AT: the force command, counted from the first that is not zero, at
  which the binding fails, once
- FAKE_VENDOR_CALIBRATED: "0" for a device that needs calibrating
- FAKE_VENDOR_RUNTIME: "0": the vendor's runtime is not installed (importing the binding's
  modules that load it raises what the real one raises: OSError for a missing library)
- FAKE_VENDOR_DEVICES: how many devices are attached (default 1; 0: none is found)
- FAKE_VENDOR_FROZEN: "1": the readings never change (a device whose pose is stuck)
- FAKE_VENDOR_FORCE_SIGN: "-1": the device pushes against the commanded force
- FAKE_VENDOR_FORCE_SCALE: the device renders this times the commanded force (default 1:
  a device whose force is mis-scaled, 0.3 or 3)
- FAKE_VENDOR_MASS: the handle's mass (kg, default 0.2) and FAKE_VENDOR_FRICTION its viscous
  friction (N s/m, default 1.0); the device doctor's tests set the config's
  [planar].apparent_mass_kg and a friction of the same time constant (0.2 s)
- FAKE_VENDOR_CLOSE_FAIL: "1": the binding's closing call fails (the safe stop cannot finish)
- FAKE_VENDOR_PLANE: "x,z": the device axes (with sign) that are really the scene's +x and +y:
  where `user_moves` moves the handle (default "x,y")
- FAKE_VENDOR_READ_FAIL_AT: the reading (counted from 1) at which the binding fails, once

The device doctor's tests play the user with `HANDLE.user_moves("x")`: the handle moves
along the scene's +x (the device axis FAKE_VENDOR_PLANE names) as a hand would.
"""

from __future__ import annotations

import atexit
import itertools
import json
import math
import os
import time
from typing import Any

MASS_KG = 0.2
FRICTION_NS_PER_M = 1.0
MAX_STEP_S = 0.005
USER_MOVE_M = 0.02  # a user asked to move the handle moves it this far ...
USER_MOVE_S = 0.15  # ... over this long
AXES = {"x": 0, "y": 1, "z": 2}


def runtime(library: str) -> None:
    """What loading the vendor's runtime does when it is not installed (FAKE_VENDOR_RUNTIME)."""
    if os.environ.get("FAKE_VENDOR_RUNTIME", "1") == "0":
        raise OSError(f"{library}: cannot open shared object file: No such file or directory")


def attached() -> int:
    """How many devices are attached (FAKE_VENDOR_DEVICES)."""
    return int(os.environ.get("FAKE_VENDOR_DEVICES", "1"))


def _vector(name: str, default: str = "0,0,0") -> list[float]:
    return [float(v) for v in os.environ.get(name, default).split(",")]


class FakeHandle:
    """The fake device's physics and its record of every call."""

    def __init__(self, vendor: str) -> None:
        self.vendor = vendor
        self.position = _vector("FAKE_VENDOR_START")
        self.velocity = [0.0, 0.0, 0.0]
        self.hand = _vector("FAKE_VENDOR_HAND")
        self.limit = float(os.environ.get("FAKE_VENDOR_LIMIT", "inf"))
        self.raise_at = int(os.environ.get("FAKE_VENDOR_RAISE_AT", "-1"))
        self.calibrated = os.environ.get("FAKE_VENDOR_CALIBRATED", "1") == "1"
        self.frozen = os.environ.get("FAKE_VENDOR_FROZEN", "0") == "1"
        self.force_sign = float(os.environ.get("FAKE_VENDOR_FORCE_SIGN", "1"))
        self.force_sign *= float(os.environ.get("FAKE_VENDOR_FORCE_SCALE", "1"))
        self.mass = float(os.environ.get("FAKE_VENDOR_MASS", str(MASS_KG)))
        self.friction = float(os.environ.get("FAKE_VENDOR_FRICTION", str(FRICTION_NS_PER_M)))
        self.close_fails = os.environ.get("FAKE_VENDOR_CLOSE_FAIL", "0") == "1"
        self.plane = os.environ.get("FAKE_VENDOR_PLANE", "x,y").split(",")
        self.read_fail_at = int(os.environ.get("FAKE_VENDOR_READ_FAIL_AT", "-1"))
        self.reads = 0
        self._moving: tuple[int, float, float] | None = None  # axis, velocity, time left (s)
        self.force = [0.0, 0.0, 0.0]
        self.first_push = -1  # the index of the first force that was not zero
        self.calls: list[str] = []  # in order; a repeat of the previous call is not listed
        self.counts: dict[str, int] = {}
        self.forces: list[tuple[float, ...]] = []  # (t ns, f N, the velocity then m/s)
        self.not_finite = 0
        self.over_limit = 0
        self.closed = False
        self._last_ns = time.monotonic_ns()
        atexit.register(self.write)

    def call(self, name: str) -> None:
        self.counts[name] = self.counts.get(name, 0) + 1
        if not self.calls or self.calls[-1] != name:
            self.calls.append(name)
        if self.closed and name not in ("close", "stop"):
            raise RuntimeError(f"{self.vendor}: {name} called after the device was closed")

    def user_moves(self, scene_axis: str) -> None:
        """A user moves the handle USER_MOVE_M along the scene's +x or +y ("x", "y"), that is
        along the device axis FAKE_VENDOR_PLANE names for it, over USER_MOVE_S of the handle's
        own time (the readings' steps, each at most MAX_STEP_S): a test process starved of the
        CPU for longer than the move still sees the whole move, as a real hand would make it,
        not a move cut short by the wall clock."""
        text = self.plane[0 if scene_axis == "x" else 1]
        sign = -1.0 if text.startswith("-") else 1.0
        speed = sign * USER_MOVE_M / USER_MOVE_S
        self._moving = (AXES[text.lstrip("+-")], speed, USER_MOVE_S)

    def advance(self) -> None:
        """Move the handle over the wall time since the last call (a reading)."""
        self.reads += 1
        if self.reads == self.read_fail_at:
            raise RuntimeError(
                f"{self.vendor}: the device stopped answering (reading {self.reads})"
            )
        now = time.monotonic_ns()
        dt = min((now - self._last_ns) * 1e-9, MAX_STEP_S)
        self._last_ns = now
        if self.frozen:
            return
        if self._moving is not None:  # the user's hand leads: it sets the velocity
            axis, speed, left = self._moving  # the hand stops on the reading after its move
            self.velocity[axis] = speed * min(dt, left) / dt if left > 0 and dt > 0 else 0.0
            self._moving = (axis, speed, max(0.0, left - dt)) if left > 0 else None
        for i in range(3):
            f = self.hand[i] + self.force_sign * self.force[i]
            self.velocity[i] += dt * (f - self.friction * self.velocity[i]) / self.mass
            self.position[i] += dt * self.velocity[i]

    def command(self, force: Any) -> None:
        """A force (N, the vendor's frame) held from now on."""
        f = [float(force[0]), float(force[1]), float(force[2])]
        if self.first_push < 0 and any(abs(v) > 1e-3 for v in f):
            self.first_push = len(self.forces)
        pushed = len(self.forces) - self.first_push if self.first_push >= 0 else -1
        if pushed >= 0 and pushed == self.raise_at:  # once: the glitch passes, zero lands
            self.raise_at = -1
            raise RuntimeError(f"{self.vendor}: the device stopped answering")
        if not all(math.isfinite(v) for v in f):
            self.not_finite += 1
            f = [0.0, 0.0, 0.0]  # what a careful firmware would do; the test counts it
        if math.sqrt(sum(v * v for v in f)) > self.limit * (1 + 1e-9):
            self.over_limit += 1
        self.advance()
        self.force = f
        self.forces.append((time.monotonic_ns(), *f, *self.velocity))

    def close(self) -> None:
        self.force = [0.0, 0.0, 0.0]
        self.closed = True
        self.write()

    def write(self) -> None:
        path = os.environ.get("FAKE_VENDOR_RECORD")
        if not path:
            return
        t = [f[0] for f in self.forces]
        gaps = sorted((b - a) * 1e-6 for a, b in itertools.pairwise(t))

        def pct(p: float) -> float:
            return gaps[min(len(gaps) - 1, int(p / 100 * len(gaps)))] if gaps else math.nan

        record = {
            "vendor": self.vendor,
            "calls": self.calls[:200],
            "last_calls": self.calls[-10:],
            "counts": self.counts,
            "n_forces": len(self.forces),
            "last_force": list(self.forces[-1][1:4]) if self.forces else None,
            "max_abs_force": max((max(map(abs, f[1:4])) for f in self.forces), default=0.0),
            "max_force_norm": max(
                (math.sqrt(sum(v * v for v in f[1:4])) for f in self.forces), default=0.0
            ),
            "pushed_before_failure": self.first_push >= 0,
            "not_finite": self.not_finite,
            "over_limit": self.over_limit,
            "closed": self.closed,
            "gap_ms_p50": pct(50),
            "gap_ms_p99": pct(99),
            "forces": [list(f) for f in self.forces[-20000:]],  # t, fx, fy, fz, vx, vy, vz
            "position": self.position,
        }
        tmp = f"{path}.tmp"
        with open(tmp, "w") as out:
            json.dump(record, out)
        os.replace(tmp, path)


HANDLE: FakeHandle | None = None


def handle(vendor: str) -> FakeHandle:
    """The one handle of this process (a new one for each device opened)."""
    global HANDLE
    HANDLE = FakeHandle(vendor)
    return HANDLE

"""`haptic-stability`: numerical stability on stiff and extreme cases.

Three parts, written to --out as markdown + PNG (./runs/stability by default; the committed
report: docs/stability):

1. The sampled virtual wall against Colgate's passivity bound b > K T / 2 + |B|: a device
   (mass m, physical damping b) hits a wall F = -K x - B v rendered with a zero-order hold
   at period T (the worst-case period measured on this machine). For each (b, B) the
   stiffness is bisected for the boundary between energy-dissipating and energy-generating
   contact (passivity observer: the wall's net work on the device over a run that starts
   and ends out of contact), and compared with K_bound = 2 (b - |B|) / T.
2. This engine's wall against the same bound at each haptic rate (`--rates`, default 1, 4
   and 10 kHz): one wall contact installed in the real HapticEngine (a synthetic local-model
   update, no sim), rendered by its compiled tick against the ideal device with physical
   damping b, integrated in substeps under the held command. The stiffness is searched for
   the smallest one at which a contact gives the device energy, and compared with
   2 (b - |B|) / T at the nominal period (virtual time); docs/stability/wall_vs_rate.png.
   The method that puts a sampled wall at the device port is the virtual coupling with the
   tool pinned to the wall (`wall_engine` says why); the default local-model method is
   measured too, and has no such bound.
3. The local model's stability map in the virtual clock, one axis at a time (and the
   god-object's coupling gains K_vc x B_vc at 1 and 4 kHz, its finger pushed into a floor): contact
   stiffness 1e2..1e6 N/m and damping, tool masses and inertias over six decades, haptic
   time steps, exactly at and near singular configurations, 32+ simultaneous contacts,
   impact speeds up to 2 m/s, user forces up to the device limits. Each case is classified
   stable / unstable by a passivity observer at the user's port (the energy stored in what
   is rendered, the VM's kinetic energy, never above the hand's work on the device:
   `classify`) and by bounded state; every case is also checked for NaN/Inf reaching the
   device (the guards must prevent it).

    haptic-stability [--quick] [--out docs/stability] [--rates 1000 4000 10000]
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from haptic_local_model.benchmarks.kernel_cost import engine_with_contacts
from haptic_local_model.device_models.ideal import IdealDevice, IdealDeviceConfig
from haptic_local_model.haptic_server.engine import HapticEngine
from haptic_local_model.haptic_server.harness.virtual import run_virtual
from haptic_local_model.haptic_server.world import run_ticks
from haptic_local_model.shared.cli import add_version
from haptic_local_model.shared.config import (
    SceneConfig,
    UserConfig,
    load_scene,
    load_user,
    softened_coordination,
)
from haptic_local_model.shared.kinematics import free_body_chain
from haptic_local_model.shared.protocol.layout import DEFAULT_LIMITS
from haptic_local_model.shared.protocol.update import (
    ContactSet,
    LocalModelUpdate,
    contact_rows,
    encode_update,
)
from haptic_local_model.sim_server.world import SimWorld

WORST_PERIOD_S = 1.0e-3 + 60e-6  # 1 kHz plus the p99.9 lateness measured by loop_timing
DEVICE_MASS = 0.5  # kg, the sampled-wall device
ENERGY_TOL_J = 1e-6  # net work below this counts as no generation (round-off)
DEVICE_LIMIT_N = IdealDeviceConfig().max_wrench[0]
SATURATION_FRACTION = 0.999
PASSIVITY_TOL_J = 1e-3  # the device may hold this much more than the user put in (noise)
BOUNDED_M = 1.0  # a stable case never leaves +-1 m


# --- 1. sampled wall ----------------------------------------------------------------------


@njit(cache=True)
def sampled_wall_energy(k, b_wall, b_device, mass, period, v0, n_periods, substeps):
    """Energy gained by a damped mass over one contact with a zero-order-hold wall (J).

    The mass (physical damping b) enters the wall at v0; the wall force -K x - B v (x > 0
    inside, v by backward difference of the samples) is computed each period and held; the
    motion is integrated with `substeps` per period until the mass leaves the wall. Returns
    (kinetic + wall energy) at exit minus at entry: > 0 means the contact generated energy,
    which Colgate's condition b > K T / 2 + |B| rules out.
    """
    x = 0.0
    v = v0
    h = period / substeps
    x_prev = x
    entry = 0.5 * mass * v0 * v0
    for _ in range(n_periods):
        v_est = (x - x_prev) / period
        x_prev = x
        force = -k * x - b_wall * v_est if x > 0.0 else 0.0
        for _ in range(substeps):
            a = (force - b_device * v) / mass
            v_new = v + h * a
            x += h * 0.5 * (v + v_new)
            v = v_new
        if x < 0.0 and v < 0.0:
            return 0.5 * mass * v * v - entry
        if abs(x) > 1e3:
            return 1e9
    stored = 0.5 * k * x * x if x > 0.0 else 0.0
    return 0.5 * mass * v * v + stored - entry


def sampled_wall_boundary(
    b_device: float, b_wall: float, period: float, lo: float = 1.0, hi: float = 1e8, steps: int = 40
) -> float:
    """The smallest stiffness whose wall generates energy (bisection on log K in [lo, hi])."""

    def generates(k: float) -> bool:
        # work can only be negative for a passive wall: the mass arrives with its kinetic
        # energy and leaves with less
        gained = sampled_wall_energy(k, b_wall, b_device, DEVICE_MASS, period, 0.05, 200000, 20)
        return gained > ENERGY_TOL_J

    return bisect_log(generates, lo, hi, steps)


def bisect_log(generates: Callable[[float], bool], lo: float, hi: float, steps: int) -> float:
    """The boundary between stiffnesses that do not generate energy (lo) and do (hi), by
    `steps` bisections of log K; the geometric middle of the last bracket."""
    for _ in range(steps):
        mid = math.sqrt(lo * hi)
        if generates(mid):
            hi = mid
        else:
            lo = mid
    return math.sqrt(lo * hi)


def colgate_bound(b_device: float, b_wall: float, period: float) -> float:
    """K below which b > K T / 2 + |B| holds (Colgate and Schenkel)."""
    return 2.0 * (b_device - abs(b_wall)) / period


# --- 2. this engine's wall, by haptic rate ---------------------------------------------------

RATES_HZ = (1000.0, 4000.0, 10000.0)
COUPLED = "virtual_coupling"  # the device feels a sampled spring on its own pose (wall_engine)
LOCAL_MODEL = "local_model"  # the default method: the device feels the proxy's contact force
WALL_DEVICE_DAMPING = (5.0, 20.0)  # b of the device, N s/m
WALL_DAMPED = (20.0, 5.0)  # (b, B): the one row with wall damping
ENTRY_SPEED = 0.05  # m/s toward the wall, no hand on the device
#: where in a tick the device crosses the surface (fraction of a tick after a sample); just
#: after a sample is the worst case (the wall's onset is latest), so it is always included
ENTRY_PHASES = (0.01, 0.25, 0.5, 0.75)
PINNING_STIFFNESS = DEFAULT_LIMITS.max_stiffness_n_per_m  # the contact holding the tool, N/m
LIGHT_TOOL = 1e-4  # tool mass / device mass under the coupling: the tool stores no energy
DEVICE_INERTIA = 1e-3  # kg m^2, the handle's (no rotation is excited)
DEVICE_SUBSTEPS = 64  # semi-implicit Euler steps per tick: a phase lead of 1/128 tick
WALL_LIMIT_N = 1e4  # device and engine force limit: the wall is never clipped
SETTLE_TICKS = 4  # the coupled exit is read this many ticks after the tool leaves the wall
LOCAL_SETTLE_S = 0.05  # local model: the exit is read when device and proxy move together
GAIN_TOL = 1e-6  # a relative energy gain above this is generation (round-off is ~1e-12)
GRID_FACTOR = 2.0  # the search steps up a log grid to the first generating stiffness ...
BISECTIONS = 12  # ... then bisects log K between it and the grid point below (0.02 %)


@dataclass(frozen=True)
class EngineWall:
    """One row of the table: the measured boundary of the engine's wall against the bound."""

    method: str
    rate_hz: float
    b_device: float
    b_wall: float
    k_max: float  # N/m, the stiffness the device feels at the boundary (inf: none found)
    bound: float  # N/m, Colgate's 2 (b - |B|) / T

    @property
    def ratio(self) -> float:
        return self.k_max / self.bound if self.bound > 0 else math.inf


@functools.cache
def _free_box() -> SceneConfig:
    return load_scene("free_box")


def _engine_wall_scene(method: str, rate_hz: float, stiffness: float, b_wall: float) -> SceneConfig:
    """free_box's rendering, no cross-fade, no impulses (a penalty wall, not a collision)."""
    base = _free_box()
    r = dataclasses.replace(base.rendering, method=method, blend_ms=0.0, impulses=False)
    if method == COUPLED:
        r = dataclasses.replace(
            r,
            virtual_coupling_stiffness=(stiffness, stiffness, r.virtual_coupling_stiffness[2]),
            virtual_coupling_damping=(b_wall, b_wall, r.virtual_coupling_damping[2]),
        )
    return dataclasses.replace(base, rendering=r, haptic_rate_hz=rate_hz)


def felt_stiffness(method: str, stiffness: float) -> float:
    """The stiffness the device feels: under the coupling, K_vc in series with the pinning
    contact; under the local model, the contact's own."""
    if method == COUPLED:
        return stiffness * PINNING_STIFFNESS / (stiffness + PINNING_STIFFNESS)
    return stiffness


def wall_engine(
    method: str, rate_hz: float, stiffness: float, b_wall: float, b_device: float, phase: float
) -> HapticEngine:
    """The real engine with one wall contact (a synthetic update, installed as
    benchmarks.kernel_cost.engine_with_contacts does), the device and the tool moving at
    ENTRY_SPEED toward a wall `phase` of a tick's travel ahead; no hand on the device.

    In this engine a contact's stiffness acts on the proxy, which the proxy step integrates
    linearly implicitly; no method samples the wall at the device's pose. The one spring the
    device's own sampled pose drives, held until the next tick, is the virtual coupling
    F = K_vc (x_VM - x_h) + B_vc (xd_VM - xd_h). So `COUPLED` renders the wall as
    that coupling (K_vc = stiffness, B_vc = b_wall) to a light tool (LIGHT_TOOL of the
    device's mass) that a contact of PINNING_STIFFNESS holds on the surface: while the
    device is inside, it feels a plain sampled wall of `felt_stiffness` (Colgate's virtual
    wall). `LOCAL_MODEL` is the default method with M_d equal to the tool's inertia and the
    device started on the proxy, so the command carries the proxy's contact force 1:1.
    """
    coupled = method == COUPLED
    tool = LIGHT_TOOL if coupled else 1.0
    scene = _engine_wall_scene(method, rate_hz, stiffness, b_wall)
    device = IdealDevice(
        IdealDeviceConfig(
            inertia=(DEVICE_MASS, DEVICE_MASS, DEVICE_INERTIA),
            max_wrench=(WALL_LIMIT_N, WALL_LIMIT_N, WALL_LIMIT_N / 10),  # torques: unused
            viscous_damping=(b_device, b_device, 0.0),
            substeps=DEVICE_SUBSTEPS,
        )
    )
    engine = HapticEngine(scene, device, UserConfig(name="none", kind="constant_wrench"))
    engine.unguarded()  # a hand-made model: the rendering's own stability, not the guard's
    jt, lengths = free_body_chain()
    surface = phase * ENTRY_SPEED / rate_hz
    rows, floats = contact_rows(1)
    rows[0]["tool"], rows[0]["env"], rows[0]["normal"] = (0.0, 0.0), (surface, 0.0), (-1.0, 0.0)
    rows[0]["stiffness"] = PINNING_STIFFNESS if coupled else stiffness
    rows[0]["damping"] = 0.0 if coupled else b_wall
    rows[0]["tangential_stiffness"] = rows[0]["stiffness"]
    inertia = np.array([DEVICE_MASS, DEVICE_MASS, DEVICE_INERTIA]) * tool
    update = LocalModelUpdate(
        epoch=1, seq=0, sim_time=0.0, publish_time_ns=0, joint_types=jt, lengths=lengths,
        base=np.zeros(2), base_angle=0.0, op_link=2, op_point=np.zeros(2), q=np.zeros(3),
        qd=np.array([ENTRY_SPEED, 0.0, 0.0]), mass_matrix=np.diag(inertia),
        lambda_inv=np.diag(1.0 / inertia), tool_pose=np.zeros(3), gravity=None,
        velocity_torque=None, resisted=None, characteristic_length=0.05,
        contacts=ContactSet(np.full(1, 2), np.arange(1), floats), tool_touching=False,
    )  # fmt: skip
    assert engine.receive(encode_update(update)) == ""
    # the install put the device at rest on the tool: it moves with the tool from here
    device.state[0]["twist"][0] = ENTRY_SPEED
    engine.state[0]["prev_device_twist"][0] = ENTRY_SPEED
    return engine


def wall_bounce_gain(
    method: str, rate_hz: float, stiffness: float, b_wall: float, b_device: float, phase: float
) -> float:
    """Energy one contact gives the device, relative to what it brought: (v_out/v_in)^2 - 1.

    v_in and v_out are the device's speeds at the wall surface going in and coming out. With
    no hand, 1/2 m (v_out^2 - v_in^2) is the controller's net work on the device over the
    contact less what the device's damping dissipated meanwhile; Colgate's b > K T/2 + |B|
    is the condition for it never to be positive. Both are read out of contact and carried
    to the surface along the free damped flight (m dv = -b v dt: dv = -(b/m) dx, exact);
    the exit is read once the coupling has let go (SETTLE_TICKS after the tool leaves the
    wall). Under the local model (b = 0 only: its coupling to the undamped proxy acts in
    free flight too) it is read LOCAL_SETTLE_S later, when device and proxy move together.
    """
    engine = wall_engine(method, rate_hz, stiffness, b_wall, b_device, phase)
    period = 1.0 / rate_hz
    contact_s = math.pi * math.sqrt(DEVICE_MASS / felt_stiffness(method, stiffness))
    settle_s = LOCAL_SETTLE_S if method == LOCAL_MODEL else 0.0
    ticks = int((3.0 * contact_s + settle_s) / period) + 10 * SETTLE_TICKS
    rows = np.zeros(ticks, engine.row.dtype)
    run_ticks(engine, rows, 0, ticks)
    inside = np.flatnonzero(rows["n_active"] > 0)
    if inside.size == 0:
        raise RuntimeError(f"the device never reached the wall ({method}, K={stiffness:g})")
    after = ticks - 1 if method == LOCAL_MODEL else inside[-1] + 1 + SETTLE_TICKS
    if after >= ticks or rows["n_active"][after] > 0:
        return -1.0  # still inside: the wall kept the device (it gave nothing back)
    x = float(rows["device_pose"][after, 0])
    v = float(rows["device_twist"][after, 0])
    if not (math.isfinite(x) and math.isfinite(v)):
        return math.inf
    if v >= 0.0:
        return -1.0  # not coming back out: the contact absorbed its energy
    surface = phase * ENTRY_SPEED * period
    slowing = b_device / DEVICE_MASS
    v_in = ENTRY_SPEED - slowing * surface
    v_out = -v + slowing * (surface - x)
    return (v_out / v_in) ** 2 - 1.0


def wall_generates(
    method: str, rate_hz: float, stiffness: float, b_wall: float, b_device: float
) -> bool:
    """Some contact at this stiffness gives the device energy (any of ENTRY_PHASES)."""
    return any(
        wall_bounce_gain(method, rate_hz, stiffness, b_wall, b_device, phase) > GAIN_TOL
        for phase in ENTRY_PHASES
    )


def engine_wall_boundary(
    method: str, rate_hz: float, b_device: float, b_wall: float, k_range: tuple[float, float]
) -> float:
    """The smallest stiffness whose contacts generate energy: the first generating point of
    a log grid over k_range (factor GRID_FACTOR), refined by BISECTIONS bisections of log K
    against the grid point below it. Returns the felt stiffness (felt_stiffness); k_range[0]
    if that already generates, inf if nothing in the range does."""

    def generates(k: float) -> bool:
        return wall_generates(method, rate_hz, k, b_wall, b_device)

    lo, top = k_range
    if generates(lo):
        return felt_stiffness(method, lo)
    while True:
        if lo >= top:
            return math.inf
        hi = min(lo * GRID_FACTOR, top)
        if generates(hi):
            break
        lo = hi
    return felt_stiffness(method, bisect_log(generates, lo, hi, BISECTIONS))


def engine_wall_table(rates: Sequence[float], quick: bool) -> list[EngineWall]:
    """The engine's boundary at each rate: the coupled wall for each b (B = 0) and for
    WALL_DAMPED, searched over 1/8..8 times the bound; the local model with b = 0 (bound 0)
    over 1 kN/m up to the protocol's largest contact stiffness."""
    cases = [(b, 0.0) for b in (WALL_DEVICE_DAMPING[:1] if quick else WALL_DEVICE_DAMPING)]
    if not quick:
        cases.append(WALL_DAMPED)
    out = []
    for rate in rates:
        for b_device, b_wall in cases:
            bound = colgate_bound(b_device, b_wall, 1.0 / rate)
            k_max = engine_wall_boundary(COUPLED, rate, b_device, b_wall, (bound / 8, bound * 8))
            out.append(EngineWall(COUPLED, rate, b_device, b_wall, k_max, bound))
        top = DEFAULT_LIMITS.max_stiffness_n_per_m
        k_local = engine_wall_boundary(LOCAL_MODEL, rate, 0.0, 0.0, (1e3, top))
        out.append(EngineWall(LOCAL_MODEL, rate, 0.0, 0.0, k_local, 0.0))
    return out


def _rate_ratios(rows: list[EngineWall]) -> list[str]:
    """K_max at each rate over K_max at the lowest, for each (b, B) of the coupled wall."""
    out = []
    for b_device, b_wall in sorted({(r.b_device, r.b_wall) for r in rows if r.method == COUPLED}):
        pts = sorted(
            (
                r
                for r in rows
                if r.method == COUPLED and (r.b_device, r.b_wall) == (b_device, b_wall)
            ),
            key=lambda r: r.rate_hz,
        )
        first = pts[0]
        for r in pts[1:]:
            out.append(
                f"- b = {b_device:g}, B = {b_wall:g}: K_max({r.rate_hz:g} Hz) / "
                f"K_max({first.rate_hz:g} Hz) = {r.k_max / first.k_max:.3f} "
                f"(bound: {r.rate_hz / first.rate_hz:.3g})"
            )
    return out


WALL_METHOD_TEXT = f"""\
**What is measured.** No sim: one synthetic local-model update with one wall contact is
installed in the real `HapticEngine` (as `benchmarks/kernel_cost.py`'s
`engine_with_contacts` does), and the engine's compiled tick (contacts, proxy step, control,
safety, the device's zero-order hold) renders it at the nominal period T = 1/rate (virtual
time) against the ideal device with physical viscous damping b (`viscous_damping`),
integrated in {DEVICE_SUBSTEPS} semi-implicit Euler substeps per tick under the held command:
the continuous, damped plant of Colgate's condition b > K T / 2 + |B|. The device
({DEVICE_MASS:g} kg) and the tool move at {ENTRY_SPEED:g} m/s toward the wall, no hand on the
device, and cross its surface at {", ".join(f"{p:g}" for p in ENTRY_PHASES)} of a tick after
a sample. The energy at the device port over one contact is
1/2 m (v_out^2 - v_in^2) = (the controller's net work on the device) - (what b dissipated),
with v_in, v_out the device's speeds at the surface, read out of contact and carried to the
surface along the free damped flight (dv = -(b/m) dx); the exit is read {SETTLE_TICKS} ticks
after the tool leaves the wall, once the coupling has let go. K_max is the smallest stiffness
at which some contact gains energy (more than {GAIN_TOL:g} of what it brought): the first
generating point of a factor-{GRID_FACTOR:g} log grid, refined by {BISECTIONS} bisections of
log K. The bound is 2 (b - |B|) / T.

**Which wall.** In this engine a contact's stiffness acts on the proxy (the VM), which the
proxy step integrates linearly implicitly; no method evaluates the wall at the device's
sampled pose. The one spring driven by the device's own sampled pose and held until the next
tick is the virtual coupling F = K_vc (x_VM - x_h) + B_vc (xd_VM - xd_h). So the wall is
rendered by `virtual_coupling` to a light tool ({LIGHT_TOOL:g} of the device's mass: it
stores no energy) that a contact of {PINNING_STIFFNESS:.0e} N/m (the protocol's largest) holds
on the surface: while the device is inside, it feels a plain sampled wall of stiffness
K = K_vc K_c / (K_vc + K_c) (the table's K; at most 0.5 % below K_vc here) and damping
B = B_vc. That is Colgate's virtual wall, and it is what bounds the stiffest wall a device
can feel through the coupling. The default method, `local_model` (M_d equal to the tool's
inertia, the device started on the proxy, so the command carries the proxy's contact force
1:1), is measured too, with b = 0, where the bound allows no stiffness at all.
"""

WALL_FINDINGS_TEXT = """\
**Findings.**

- *B = 0.* The coupled wall's K_max follows the bound at every rate and grows as 1/T (the
  ratios above). It lies a little below the bound, most at low rate and high b, i.e. at
  large omega T = sqrt(2 b T / m) (at the boundary): the wall's onset is one tick late. The
  contact is detected on the proxy at the first tick after the tool crossed the surface,
  and the proxy is held on the surface only from that tick's step, so on its first tick
  inside the device feels no force where a plain zero-order-hold wall already pushes: it
  goes deeper and is pushed out with the energy it would have lost in that tick. The
  release is one tick late too (the proxy leaves the surface one step after the device, so
  the coupling pulls the device back for a tick), which dissipates and offsets part of it.
  The worst case is a crossing just after a sample; the effect shrinks as omega T does.
  (Part 1's stand-alone wall, which pushes from the first sample inside, lies on or above
  the bound.)
- *B > 0.* The bound 2 (b - |B|) / T is conservative here (the ratios of the B > 0 rows,
  and K_max / (2 b / T) above): its |B| term charges a wall damping computed from the backward
  difference of sampled positions (Colgate and Schenkel); this engine damps with the
  device's sensed twist (xd_h, which the ideal device reports exactly) and the proxy's
  velocity, and that damping did not use up the device's b: K_max stays at or above
  2 b / T. Not a failure of the bound (it is sufficient), but it is not what limits this
  wall.
- *The default local model renders no sampled wall at the device*, so Colgate's bound does
  not limit it: with b = 0 it is passive up to K_max T^2 / m of about one (the table), far
  above any 2 b / T of a real device, and K_max grows with the square of the rate, not
  with the rate. The device receives the proxy's contact force, and the proxy's implicit
  contact step dissipates (the tick's force is the one at the end of the step), so the
  device is handed the momentum of a dissipative bounce. That fails when K T^2 / m
  approaches one: the implicit step then damps the proxy so hard that it lingers inside the
  wall for a few ticks, and the device, pushed all that time by the force of the proxy's
  penetration (held for each whole tick), leaves faster than it came. The local model's
  limit is set by the proxy step and the tool's mass, not by the device's damping.
"""


def engine_wall_lines(rows: list[EngineWall], command: str) -> list[str]:
    """The report's section on the engine's wall: how, the table, the rate ratios, why."""
    lines = [
        "## This engine's wall vs haptic rate: Colgate's bound b > K T / 2 + |B|",
        "",
        f"`{command}` (the nominal period at each rate; plot: `wall_vs_rate.png`).",
        "",
        WALL_METHOD_TEXT,
        "| rendering | rate (Hz) | b (N s/m) | B (N s/m) | measured K_max (N/m) "
        "| bound 2(b-|B|)/T (N/m) | ratio | K_max T^2/m |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        coupled = r.method == COUPLED
        ratio = f"{r.ratio:.3f}" if math.isfinite(r.ratio) else "-"
        scaled = "-" if coupled else f"{r.k_max / (r.rate_hz**2 * DEVICE_MASS):.3g}"
        k_max = f"{r.k_max:.0f}" if math.isfinite(r.k_max) else "none up to 1e8"
        lines.append(
            f"| {'coupled wall' if coupled else 'local model'} | {r.rate_hz:g} | {r.b_device:g} "
            f"| {r.b_wall:g} | {k_max} | {r.bound:.0f} | {ratio} | {scaled} |"
        )
    lines += ["", "Growth with the rate (coupled wall):", "", *_rate_ratios(rows), ""]
    damped = [r for r in rows if r.method == COUPLED and r.b_wall != 0.0]
    if damped:
        lines.append("With B > 0, K_max / (2 b / T), the bound without its |B| term:")
        lines.append("")
        for r in damped:
            lines.append(
                f"- {r.rate_hz:g} Hz, b = {r.b_device:g}, B = {r.b_wall:g}: "
                f"{r.k_max / colgate_bound(r.b_device, 0.0, 1.0 / r.rate_hz):.3f}"
            )
        lines.append("")
    lines.append(WALL_FINDINGS_TEXT)
    return lines


# --- 3. the local model's map -------------------------------------------------------------


@dataclass
class Case:
    axis: str
    label: str
    stable: bool
    finite: bool
    energy_excess_j: float  # max over time of device kinetic energy - the user's work
    max_abs_pose: float
    faults: int
    note: str = ""


def proxy_kinetic(ticks: np.ndarray, scene: SceneConfig) -> np.ndarray:
    """Kinetic energy of the rendered VM, 1/2 qd^T D(q) qd, at every tick."""
    world = SimWorld(scene)
    d = world.dof
    out = np.zeros(ticks.shape[0])
    mass = None
    for k in range(ticks.shape[0]):
        q = ticks["proxy_q"][k, :d]
        if mass is None or scene.tool.kind == "linkage":
            mass = world.dynamics_terms(np.nan_to_num(q))[0]
        qd = np.nan_to_num(ticks["proxy_qd"][k, :d])
        out[k] = 0.5 * qd @ mass @ qd
    return out


def classify(axis: str, label: str, ticks: np.ndarray, rendered_energy: np.ndarray) -> Case:
    """Stable: finite at the device, bounded, and passive at the user's port.

    Passivity observer: the hand's work on the device, W(t) = sum F_h . v dt, must always
    cover the energy stored in what is rendered (the VM's kinetic energy): a passive
    rendering stores or dissipates what the user puts in and cannot give back more. (The
    controller's own work is not the test: making a heavy device feel like a light VM takes
    positive work in free motion.)
    """
    command = ticks["wrench_command"]
    finite = bool(np.isfinite(command).all())
    v = np.nan_to_num(ticks["device_twist"])
    dt = np.nan_to_num(ticks["dt"])
    user_work = np.cumsum(np.sum(np.nan_to_num(ticks["hand_wrench"]) * v, axis=1) * dt)
    stored = rendered_energy - rendered_energy[0] if ticks.size else rendered_energy
    excess = float(np.max(stored - user_work)) if ticks.size else 0.0
    pose = float(np.nanmax(np.abs(ticks["device_pose"][:, :2]))) if ticks.size else 0.0
    at_limit = np.abs(command[:, :2]) >= SATURATION_FRACTION * DEVICE_LIMIT_N
    saturated = float(np.mean(np.any(at_limit, axis=1)))
    stable = finite and pose < BOUNDED_M and excess < PASSIVITY_TOL_J
    note = f"at the device force limit {saturated:.0%} of the time" if saturated > 0.001 else ""
    return Case(axis, label, stable, finite, excess, pose, int((ticks["fault"] != 0).sum()), note)


def _wall_scene(
    k: float, b: float, mass: float = 0.5, rate_hz: float = 1000.0, v0: float = 0.0
) -> SceneConfig:
    scene = load_scene("wall_push")
    materials = {
        name: dataclasses.replace(m, stiffness_n_per_m=k, damping_ns_per_m=b)
        for name, m in scene.materials.items()
    }
    bodies = tuple(
        dataclasses.replace(body, mass=mass, velocity=(v0, 0.0))
        if body.name == "rectangle"
        else body
        for body in scene.bodies
    )
    try:
        return dataclasses.replace(
            scene, materials=materials, bodies=bodies, haptic_rate_hz=rate_hz
        )
    except ValueError:  # a held body too light for the coordination coupling's gains
        held = next(b for b in bodies if b.name == "rectangle")
        r = scene.rendering
        ks, bs, _ = softened_coordination(
            (r.coordination_stiffness, r.coordination_damping), held.mass, held.moment, rate_hz
        )
        rendering = dataclasses.replace(
            r, coordination_stiffness=tuple(ks), coordination_damping=tuple(bs)
        )
        return dataclasses.replace(
            scene, materials=materials, bodies=bodies, haptic_rate_hz=rate_hz, rendering=rendering
        )


def _run(
    scene: SceneConfig, user: UserConfig, seconds: float, device: IdealDevice | None = None
) -> np.ndarray:
    dev = device or IdealDevice(IdealDeviceConfig())
    return run_virtual(scene, dev, user, seconds).ticks


def _push(newtons: float) -> UserConfig:
    return UserConfig(name=f"push_{newtons}", kind="constant_wrench", wrench=(newtons, 0.0, 0.0))


def many_contacts_case(n: int, seconds: float = 1.0) -> np.ndarray:
    """A box pressed onto n contact points (no sim: a fixed synthetic local model)."""
    engine = engine_with_contacts(n, press_n=5.0, depth_m=0.0)
    out = np.zeros(int(seconds * 1000), engine.row.dtype)
    for k in range(out.shape[0]):
        out[k] = engine.tick(1e-3)[0]
    return out


def _case(
    axis: str,
    label: str,
    scene: SceneConfig,
    user: UserConfig,
    seconds: float,
    device: IdealDevice | None = None,
) -> Case:
    ticks = _run(scene, user, seconds, device)
    return classify(axis, label, ticks, proxy_kinetic(ticks, scene))


def god_wall_scene(stiffness: float, damping: float, rate_hz: float = 1000.0) -> SceneConfig:
    """god_slabs without its ceiling: a god-object finger on a static floor, its coupling
    K_vc = stiffness, B_vc = damping, at rate_hz."""
    scene = load_scene("god_slabs")
    rendering = dataclasses.replace(
        scene.rendering,
        god_object_stiffness=(stiffness, stiffness),
        god_object_damping=(damping, damping),
    )
    bodies = tuple(b for b in scene.bodies if b.name != "ceiling")
    return dataclasses.replace(scene, rendering=rendering, bodies=bodies, haptic_rate_hz=rate_hz)


def god_object_map(quick: bool) -> list[Case]:
    """The god-object's coupling gains (DESIGN-WAVE2 §11): K_vc over four decades, B_vc from
    the loader's minimum K_vc dt / 2 up, at 1 and 4 kHz, the finger pushed into a floor by
    2 N (and by 20 N). Not covered: a push the coupling cannot hold within the device's force
    limit (the clipped spring stores energy it never renders, which this classification
    would count)."""
    cases: list[Case] = []
    seconds = 0.6 if quick else 1.5
    down = UserConfig(name="press_2n", kind="constant_wrench", wrench=(0.0, -2.0, 0.0))
    for rate in (1000.0,) if quick else (1000.0, 4000.0):
        for k in (1e2, 1e4) if quick else (1e2, 1e3, 1e4, 1e5):
            for factor in (1.0, 20.0) if quick else (1.0, 4.0, 20.0):
                b = factor * 0.5 * k / rate
                label = f"K={k:.0e} B={b:.3g} ({factor:g} x K dt/2) at {rate / 1e3:g} kHz"
                cases.append(_god_case(label, god_wall_scene(k, b, rate), down, seconds))
    hard = UserConfig(name="press_20n", kind="constant_wrench", wrench=(0.0, -20.0, 0.0))
    cases.append(_god_case("K=1e+04 B=5, 20 N push", god_wall_scene(1e4, 5.0), hard, seconds))
    return cases


def _god_case(label: str, scene: SceneConfig, user: UserConfig, seconds: float) -> Case:
    """A god-object run, classified with what it stores: the proxy's kinetic energy and the
    coupling spring's 1/2 K |p - x_h|^2 as far as it is rendered (not in the safe state)."""
    ticks = _run(scene, user, seconds)
    k = np.array(scene.rendering.god_object_stiffness)
    stretch = ticks["god_proxy"] - ticks["device_pose"][:, :2]
    spring = 0.5 * np.sum(k * np.nan_to_num(stretch) ** 2, axis=1) * (1.0 - ticks["safe"])
    return classify("god-object coupling", label, ticks, proxy_kinetic(ticks, scene) + spring)


def local_model_map(quick: bool) -> list[Case]:
    cases: list[Case] = []
    seconds = 0.6 if quick else 1.5
    push = _push(2.0)
    push_scene = load_scene("wall_push")
    for k in (1e2, 1e4, 1e6) if quick else (1e2, 1e3, 1e4, 1e5, 1e6):
        for b in (20.0,) if quick else (0.0, 20.0, 300.0):
            cases.append(
                _case(
                    "contact stiffness / damping",
                    f"K={k:.0e} B={b:g}",
                    _wall_scene(k, b),
                    push,
                    seconds,
                )
            )
    for mass in (1e-3, 1.0, 1e3) if quick else (1e-3, 1e-2, 1e-1, 1.0, 1e1, 1e2, 1e3):
        scene = _wall_scene(15000.0, 20.0, mass=mass)
        soft = scene.rendering.coordination_stiffness != push_scene.rendering.coordination_stiffness
        label = f"m={mass:g} kg" + (" (coordination softened)" if soft else "")
        cases.append(_case("tool mass (6 decades)", label, scene, push, seconds))
    for rate in (250.0, 1000.0) if quick else (250.0, 500.0, 1000.0, 2000.0, 4000.0):
        cases.append(
            _case(
                "haptic time step",
                f"dt={1e3 / rate:g} ms",
                _wall_scene(15000.0, 20.0, rate_hz=rate),
                push,
                seconds,
            )
        )
    for v0 in (2.0,) if quick else (0.1, 0.5, 1.0, 2.0):
        cases.append(
            _case("impact speed", f"v={v0:g} m/s", _wall_scene(15000.0, 20.0, v0=v0), push, seconds)
        )
    # up to 90% of the device limit: at the limit itself the device cannot hold any wall (the
    # hand overpowers it; the command stays clipped, tested in tests/test_stability.py)
    for force in (45.0,) if quick else (1.0, 10.0, 25.0, 45.0):
        cases.append(
            _case("user force", f"F={force:g} N", _wall_scene(15000.0, 20.0), _push(force), seconds)
        )
    free = load_scene("free_box")
    for n in (32,) if quick else (16, 32, 48):
        ticks = many_contacts_case(n, seconds)
        cases.append(classify("simultaneous contacts", f"n={n}", ticks, proxy_kinetic(ticks, free)))
    distal = load_scene("linkage_distal")
    for q2 in (0.0,) if quick else (0.0, 1e-6, 0.05):
        arm = dataclasses.replace(distal.tool_linkage, initial_angles=(0.3, q2, 0.4))
        scene = dataclasses.replace(distal, linkages=(arm,))
        device = IdealDevice(IdealDeviceConfig(inertia=(1.0, 1.0, 1.0)))
        cases.append(
            _case(
                "singular configuration",
                f"q2={q2:g}",
                scene,
                load_user("push_04n"),
                seconds,
                device,
            )
        )
    return cases


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="haptic-stability",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_version(parser)
    parser.add_argument("--quick", action="store_true", help="a fast subset of every axis")
    parser.add_argument(
        "--out", type=Path, default=Path("runs/stability"),
        help="report directory (default ./runs/stability; the project's own: docs/stability)",
    )  # fmt: skip
    parser.add_argument(
        "--period-s", type=float, default=WORST_PERIOD_S, help="worst-case haptic period"
    )
    parser.add_argument(
        "--rates",
        type=float,
        nargs="+",
        default=list(RATES_HZ),
        metavar="HZ",
        help="haptic rates of the engine's wall (part 2)",
    )
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    given = sys.argv[1:] if argv is None else argv
    command = " ".join(["haptic-stability", *given])
    lines = ["# Stability report", "", f"Worst-case period T = {args.period_s * 1e6:.0f} us.", ""]
    lines += [
        "## Sampled wall vs Colgate's bound b > K T / 2 + |B|",
        "",
        "| b (N s/m) | B (N s/m) | measured K boundary (N/m) | bound 2(b-|B|)/T (N/m) | ratio |",
        "|---|---|---|---|---|",
    ]
    walls = []
    for b_device in (1.0, 5.0, 20.0):
        for b_wall in (0.0, 0.5):
            if b_wall >= b_device:
                continue
            measured = sampled_wall_boundary(b_device, b_wall, args.period_s)
            bound = colgate_bound(b_device, b_wall, args.period_s)
            walls.append((b_device, b_wall, measured, bound))
            ratio = measured / bound
            lines.append(
                f"| {b_device:g} | {b_wall:g} | {measured:.0f} | {bound:.0f} | {ratio:.3f} |"
            )
    engine_walls = engine_wall_table(args.rates, args.quick)
    lines += ["", *engine_wall_lines(engine_walls, command)]
    cases = local_model_map(args.quick) + god_object_map(args.quick)
    lines += [
        "",
        "## The local model's and the god-object's stability map",
        "",
        "| axis | case | stable | finite at the device | energy excess (J) | max |pose| (m) "
        "| fault ticks | note |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for c in cases:
        lines.append(
            f"| {c.axis} | {c.label} | {'yes' if c.stable else 'NO'} "
            f"| {'yes' if c.finite else 'NO'} | {c.energy_excess_j:.3g} | {c.max_abs_pose:.3g} "
            f"| {c.faults} | {c.note} |"
        )
    (args.out / "report.md").write_text("\n".join(lines) + "\n")
    _plot_walls(walls, args.out / "sampled_wall.png")
    _plot_wall_vs_rate(engine_walls, args.out / "wall_vs_rate.png")
    print("\n".join(lines))
    bad = [c for c in cases if not c.finite]
    return 1 if bad else 0


def _plot_walls(walls: list[tuple[float, float, float, float]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for b_device, b_wall, measured, bound in walls:
        ax.loglog(bound, measured, "o", label=f"b={b_device:g}, B={b_wall:g}")
    lim = [min(w[3] for w in walls) * 0.5, max(w[3] for w in walls) * 2]
    ax.plot(lim, lim, "k--", lw=0.8, label="measured = bound")
    ax.fill_between(
        lim, [0.8 * v for v in lim], [1.2 * v for v in lim], color="0.9", label="within 20%"
    )
    ax.set_xlabel("Colgate bound 2(b-|B|)/T (N/m)")
    ax.set_ylabel("measured stability boundary (N/m)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def _plot_wall_vs_rate(rows: list[EngineWall], path: Path) -> None:
    """K_max against the rate, log-log: the coupled wall's measured points and Colgate's
    bound 2 (b - |B|) / T for each (b, B), the local model's points (bound 0)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    rates = np.array(sorted({r.rate_hz for r in rows}))
    line = np.geomspace(rates.min() * 0.8, rates.max() * 1.25, 50)
    series = sorted({(r.b_device, r.b_wall) for r in rows if r.method == COUPLED})
    for i, (b_device, b_wall) in enumerate(series):
        color = f"C{i}"
        pts = [
            r for r in rows if r.method == COUPLED and (r.b_device, r.b_wall) == (b_device, b_wall)
        ]
        bound = 2.0 * (b_device - abs(b_wall)) * line
        ax.loglog(
            line,
            bound,
            "--",
            color=color,
            lw=1.0,
            label=f"bound 2(b-|B|)/T, b={b_device:g}, B={b_wall:g}",
        )
        if b_wall == 0.0:
            ax.fill_between(line, 0.75 * bound, 1.25 * bound, color=color, alpha=0.12, lw=0)
        ax.loglog([r.rate_hz for r in pts], [r.k_max for r in pts], "o", color=color, label=f"measured, coupled wall, b={b_device:g}, B={b_wall:g}")  # fmt: skip
    local = [r for r in rows if r.method == LOCAL_MODEL and math.isfinite(r.k_max)]
    if local:
        ax.loglog([r.rate_hz for r in local], [r.k_max for r in local], "s", mfc="none", color="k", label="measured, local model, b=0 (bound 0)")  # fmt: skip
    ax.set_xlabel("haptic rate 1/T (Hz)")
    ax.set_ylabel("largest passive wall stiffness K_max (N/m)")
    ax.set_title("This engine's wall vs rate (shaded: bound +-25%)", fontsize=9)
    ax.legend(fontsize=6.5, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


if __name__ == "__main__":
    sys.exit(main())

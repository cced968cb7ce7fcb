"""Seed 003's animation-variable linkages against independent references (DESIGN-WAVE2 §5).

The avar kernels (shared/track.py, shared/avar.py, shared/crank.py) at the haptic loop's
1 kHz, RK4, on the validation cases of DESIGN-WAVE2 §5:

- V3.1 the free-running loop (ellipse 60 x 40 mm, 50 g, I = 2e-6 kg m^2, from the bottom at
  1.5 m/s): one car against Lagrange's equation in the ellipse's native parameter, three
  cars (20 mm apart) against the arc-length Lagrangian with closed-form geometry, both by
  DOP853 (shared/reference_avar.py): track-point error over 10 s, |dE| / E0 over 60 s;
- V3.2 a clothoid ramp (line, clothoid 0 -> 6 1/m, arc, clothoid back, line): the largest
  per-tick change of the track's force on the middle car, against the step m v^2 kappa of
  the same ramp built with line-arc joins;
- V3.3 seed 003's eq 8 as printed (the unweighted pseudo-inverse) on V3.1's car;
- V3.5 a polyline valley (C0 knots): the energy lost at each knot against the plastic
  projection's closed form, and whether the energy ever rises;
- V3.6 a slider-crank through both dead centres, driven by the crank angle (no flag, no
  NaN) and by the slider position (refused at load unless allowed; flagged, no NaN);
- the cost of one RK4 step of a three-car train (the 1 kHz loop's share).

    python -m haptic_local_model.benchmarks.coaster [--json out.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import math
import sys
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from haptic_local_model.device_models.registry import load_device
from haptic_local_model.haptic_server.harness.virtual import VirtualResult, run_virtual
from haptic_local_model.shared.avar import (
    avar_state,
    track_force,
    train_accel,
    train_energy,
    train_record,
    train_step,
)
from haptic_local_model.shared.config import SceneConfig, load_scene, load_user
from haptic_local_model.shared.crank import (
    CrankDriver,
    check_conditioning,
    conditioning,
    crank_energy,
    crank_record,
    crank_step,
)
from haptic_local_model.shared.mechanism import mechanism_record, moved, point_rate
from haptic_local_model.shared.reference_avar import (
    Ellipse,
    crank_reference_mass,
    ellipse_car,
    ellipse_car_seed_form,
    ellipse_train,
)
from haptic_local_model.shared.track import Segment, TrackSpec, tabulate, track_point

DT = 1.0e-3  # the haptic loop's period
GRAVITY = (0.0, -9.81)
LOOP = Ellipse(a=0.06, b=0.04, mass=0.05, inertia=2.0e-6, gravity=GRAVITY)
LOOP_SPEED = 1.5  # m/s at the bottom
SPACING = 0.02  # m between cars
#: the clothoid ramp (V3.2): lines at +-0.4 rad joined through clothoids 0 -> 6 1/m
RAMP_KAPPA = 6.0
RAMP_CLOTHOID_M = 0.12
RAMP_HEADING = 0.4
RAMP_LINE_M = 0.05
#: the polyline valley (V3.5): two kinks of 0.4 rad
VALLEY_TURN = 0.4
VALLEY_LINES_M = (0.06, 0.04, 0.06)
#: the slider-crank (V3.6)
CRANK = dict(crank_length=0.02, rod_length=0.06, crank_mass=0.02, rod_mass=0.03, slider_mass=0.05)
CRANK_SPEED = 60.0  # rad/s: enough to turn against gravity


def loop_spec() -> TrackSpec:
    return TrackSpec(center=(0.0, 0.0), semi_axes=(LOOP.a, LOOP.b))


def ramp_spec(clothoids: bool = True) -> TrackSpec:
    """The V3.2 valley: with clothoid transitions (C2), or the same arc met by lines (C1)."""
    turn = 2.0 * RAMP_HEADING
    if clothoids:
        bend: tuple[Segment, ...] = (
            Segment.clothoid(RAMP_CLOTHOID_M, 0.0, RAMP_KAPPA),
            Segment.arc(1.0 / RAMP_KAPPA, turn - RAMP_KAPPA * RAMP_CLOTHOID_M),
            Segment.clothoid(RAMP_CLOTHOID_M, RAMP_KAPPA, 0.0),
        )
    else:
        bend = (Segment.arc(1.0 / RAMP_KAPPA, turn),)
    segments = (Segment.line(RAMP_LINE_M), *bend, Segment.line(RAMP_LINE_M))
    return TrackSpec(segments=segments, start=(0.0, 0.1), heading=-RAMP_HEADING)


def valley_spec() -> TrackSpec:
    a, b, c = VALLEY_LINES_M
    segments = (
        Segment.line(a),
        Segment.kink(VALLEY_TURN),
        Segment.line(b),
        Segment.kink(VALLEY_TURN),
        Segment.line(c),
    )
    return TrackSpec(segments=segments, start=(0.0, 0.05), heading=-VALLEY_TURN)


@dataclass
class Ride:
    """A train's run at DT: per tick t, s, s', the energy and the track's force on car
    `rider`, and the state at the end (counts of kinks, bumps, losses)."""

    t: np.ndarray
    s: np.ndarray
    sd: np.ndarray
    energy: np.ndarray
    force: np.ndarray  # (n, 2)
    point: np.ndarray  # (n, 2) the lead car's track point
    state: np.void


def ride(
    spec: TrackSpec, n_cars: int, s0: float, sd0: float, seconds: float, rider: int = 0
) -> Ride:
    """Run a train of n V3.1 cars from (s0, sd0) for `seconds` at DT, free (no push)."""
    table = tabulate(spec)[0]
    train = train_record(n_cars, SPACING, LOOP.mass, LOOP.inertia, GRAVITY)[0]
    st = avar_state(s0, sd0)[0]
    n = round(seconds / DT) + 1
    out = Ride(
        np.arange(n) * DT,
        np.empty(n),
        np.empty(n),
        np.empty(n),
        np.empty((n, 2)),
        np.empty((n, 2)),
        st,
    )
    for i in range(n):
        if i > 0:
            train_step(table, train, st, 0.0, DT)
        out.s[i] = st["s"]
        out.sd[i] = st["sd"]
        out.energy[i] = train_energy(table, train, st["s"], st["sd"])
        sdd = train_accel(table, train, st["s"], st["sd"], 0.0)
        out.force[i] = track_force(table, train, st["s"], st["sd"], sdd, rider, 0.0, 0.0)
        out.point[i] = track_point(table, st["s"])[:2]
    return out


def loop_figures(seconds: float = 10.0, drift_seconds: float = 60.0) -> dict[str, Any]:
    """V3.1 and V3.3 (module docstring)."""
    t = np.arange(round(seconds / DT) + 1) * DT
    bottom = float(LOOP.potential(np.array(0.0)))
    out: dict[str, Any] = {}
    for n_cars in (1, 3):
        ours = ride(loop_spec(), n_cars, 0.0, LOOP_SPEED, seconds)
        if n_cars == 1:
            points, _ = ellipse_car(LOOP, LOOP_SPEED, t)
        else:
            points, _ = ellipse_train(LOOP, n_cars, SPACING, LOOP_SPEED, t)
        long = ride(loop_spec(), n_cars, 0.0, LOOP_SPEED, drift_seconds)
        available = long.energy[0] - n_cars * bottom  # E0 above every car at the bottom
        out[f"{n_cars}_car"] = {
            "track_error_um": float(1e6 * np.max(np.hypot(*(ours.point - points).T))),
            "energy_drift": float(np.max(np.abs(long.energy - long.energy[0])) / available),
            "laps": float(ours.s.size and _laps(ours)),
        }
    _, seed_energy = ellipse_car_seed_form(LOOP, LOOP_SPEED, t)
    seed_change = (seed_energy - seed_energy[0]) / (seed_energy[0] - bottom)
    out["seed_form"] = {
        "energy_change_max": float(np.max(np.abs(seed_change))),
        "energy_change_end": float(seed_change[-1]),
    }
    return out


def _laps(r: Ride) -> float:
    """Laps of a loop from the unwrapped s."""
    length = tabulate(loop_spec())[0]["length"]
    return float(np.sum(np.mod(np.diff(r.s) + length / 2, length) - length / 2) / length)


def ramp_figures(seconds: float = 3.0) -> dict[str, Any]:
    """V3.2 on the middle car, in units of m g: the largest per-tick |dF| over the whole ride
    with clothoid transitions; with line-arc joins, the step over each tick in which the car
    crosses a join against m v^2 kappa at that speed."""
    mg = LOOP.mass * abs(GRAVITY[1])
    out: dict[str, Any] = {}
    for name, clothoids in (("clothoid", True), ("line_arc", False)):
        spec = ramp_spec(clothoids)
        r = ride(spec, 3, 2 * SPACING + 0.005, 0.0, seconds, rider=1)
        steps = np.hypot(*np.diff(r.force, axis=0).T) / mg
        rider = r.s - SPACING
        lengths = np.cumsum([seg.length for seg in spec.segments])[:-1]
        crossed = [
            int(i) for join in lengths for i in np.flatnonzero(np.diff(np.sign(rider - join)) != 0)
        ]
        out[name] = {
            "max_force_step_mg": float(steps.max()),
            "max_step_at_joins_mg": float(max(steps[i] for i in crossed)),
            "joins_crossed": len(crossed),
            "max_speed": float(np.max(np.abs(r.sd))),
        }
        if not clothoids:
            predicted = [LOOP.mass * r.sd[i] ** 2 * RAMP_KAPPA / mg for i in crossed]
            out[name]["join_step_error"] = float(
                max(abs(steps[i] / p - 1.0) for i, p in zip(crossed, predicted, strict=True))
            )
    return out


def valley_figures(seconds: float = 2.0) -> dict[str, Any]:
    """V3.5: one car from rest at the top of the valley: each of the first two knots' loss
    against the plastic projection's closed form; the largest rise of the energy over a
    tick (one car and a train of three)."""
    out: dict[str, Any] = {}
    r = ride(valley_spec(), 1, 0.0, 0.0, seconds)
    drop = np.diff(r.energy)
    knots = np.flatnonzero(drop < -1e-9)[:2]
    v1 = math.sqrt(2.0 * abs(GRAVITY[1]) * math.sin(VALLEY_TURN) * VALLEY_LINES_M[0])
    speeds = (v1, v1 * math.cos(VALLEY_TURN))
    expected = [0.5 * LOOP.mass * v * v * math.sin(VALLEY_TURN) ** 2 for v in speeds]
    out["knot_loss_error"] = [
        float(-drop[k] / e - 1.0) for k, e in zip(knots, expected, strict=True)
    ]
    out["one_car_max_rise_j"] = float(drop.max())
    train = ride(valley_spec(), 3, 2 * SPACING, 0.0, seconds)
    out["train_max_rise_j"] = float(np.diff(train.energy).max())
    out["train_kinks"] = int(train.state["kinks"])
    out["train_plastic_loss_j"] = float(train.state["plastic_loss"])
    out["energy_start_j"] = float(train.energy[0])
    return out


def crank_figures(seconds: float = 5.0) -> dict[str, Any]:
    """V3.6 (module docstring)."""
    out: dict[str, Any] = {}
    for driver, q0, qd0 in (
        (CrankDriver.CRANK_ANGLE, 0.1, CRANK_SPEED),
        (CrankDriver.SLIDER_POSITION, CRANK["rod_length"], -0.3),
    ):
        c = crank_record(**CRANK, gravity=GRAVITY, driver=driver)
        refused = False
        try:
            check_conditioning(c, allow_singular=False, where="crank")
        except ValueError:
            refused = True
        st = avar_state(q0, qd0)[0]
        e0 = crank_energy(c[0], q0, qd0)
        q = np.empty(round(seconds / DT))
        drift = 0.0
        for i in range(q.size):
            crank_step(c[0], st, 0.0, DT)
            q[i] = st["s"]
            drift = max(drift, abs(crank_energy(c[0], st["s"], st["sd"]) - e0))
        finite = bool(np.all(np.isfinite(q)))
        out[driver.name.lower()] = {
            "conditioning": conditioning(c),
            "refused_at_load": refused,
            "finite": finite,
            "flagged_steps": int(st["singular"]),
            "dead_centres_passed": int(np.sum(np.diff(np.floor(q / math.pi)) != 0))
            if driver == 0
            else 0,
            "energy_drift": drift / abs(e0),
        }
    return out


PUSH_SCENE, PUSH_DEVICE, PUSH_USER = "coaster_loop", "twin_pantograph", "push_car"
CRANK_SCENE, CRANK_USER = "crank", "flick_crank"
WHEEL_SCENE, WHEEL_USER = "ferris_wheel", "push_gondola"
RELEASE_S = 3.0  # the free motion after the finger's last touch compared with a reference


def mechanism_run(
    scene_name: str, user: str, seconds: float, sim_hz: float | None = None
) -> tuple[SceneConfig, VirtualResult]:
    """A mechanism scene in the virtual clock with the twin pantograph and a hand that pushes
    it (optionally at another sim rate)."""
    scene = load_scene(scene_name)
    if sim_hz is not None:
        scene = dataclasses.replace(scene, sim_rate_hz=sim_hz)
    return scene, run_virtual(scene, load_device(PUSH_DEVICE), load_user(user), seconds)


def finger_work(scene: SceneConfig, result: VirtualResult) -> np.ndarray:
    """The work of the rendered finger on the mechanism up to each tick (J), from the log
    alone: sum over ticks of F_env . J_c dq, F_env the force the god-object put on each
    touched body (row god_env_force, at god_env_point), J_c that point's velocity per unit
    q' (shared/mechanism.py) and dq the tick's move of q."""
    t = result.ticks
    world = result.world
    assert world.train is not None
    body_of = {world.shape_keys[shape]: k for shape, k in world.train.owner.items()}
    mech = mechanism_record(scene)[0]
    q = t["avar_s"]
    moves = np.array([moved(mech, a, b) for a, b in itertools.pairwise(q)])
    moves = np.concatenate(([0.0], moves))
    power = np.zeros(len(t))
    for i in np.flatnonzero((t["god_env_key"] >= 0).any(axis=1)):
        for j in range(2):
            body = body_of.get(int(t["god_env_key"][i, j]), -1)
            if body < 0:
                continue
            px, py = t["god_env_point"][i, j]
            jx, jy = point_rate(mech, float(q[i - 1]), body, px, py)
            fx, fy = t["god_env_force"][i, j]
            power[i] += (fx * jx + fy * jy) * moves[i]
    return np.cumsum(power)


def _unwrapped(mech: np.void, q: np.ndarray) -> np.ndarray:
    """q without a loop's wraps (so it interpolates)."""
    steps = np.array([moved(mech, a, b) for a, b in itertools.pairwise(q)])
    return q[0] + np.concatenate(([0.0], np.cumsum(steps)))


def port_given(result: VirtualResult, window_s: float) -> np.ndarray:
    """The energy the device gave the hand up to each tick, not forgotten (J): the passivity
    observer's windowed sum (row port_energy) undone."""
    t = result.ticks
    decay = np.exp(-t["dt"] / window_s)
    given = t["port_energy"] - np.concatenate(([0.0], t["port_energy"][:-1])) * decay
    return np.cumsum(given)


def balance(scene: SceneConfig, result: VirtualResult) -> dict[str, Any]:
    """V3.4's energy figures of a pushed mechanism: its energy change against the rendered
    finger's work (of the largest work), against its own Q_eff dq (exact but for RK4), the
    most energy the device gave the hand beyond what it took, and when the finger let go."""
    t = result.ticks
    work = finger_work(scene, result)
    gained = t["avar_energy"] - t["avar_energy"][0]
    scale = float(np.max(np.abs(work)))
    touched = np.flatnonzero((t["god_env_key"] >= 0).any(axis=1))
    port = port_given(result, scene.safety.passivity_window_s)
    world = result.world
    assert world.train is not None
    # the sim's mirror after its last step, against the loop's at the instant it stands for:
    # a step covers the period after the tick it was taken at (its state leads by a period)
    mech = mechanism_record(scene)[0]
    sim_q = world.train.state[0]
    loop_q = np.interp(world.time + world.period, t["t"], _unwrapped(mech, t["avar_s"]))
    per_s = sum(result.stage_ns.values()) / 1e9 / result.sim_s
    return {
        "sim_hz": scene.sim_rate_hz,
        "cost_ms_per_sim_s": 1e3 * per_s,
        "tick_us": result.stage_ns["tick"] / 1e3 / len(t),
        "mirror_error": float(abs(moved(mech, float(loop_q), sim_q))),
        "work_j": float(work[-1]), "max_work_j": scale,
        "work_energy_error": float(np.max(np.abs(gained - work)) / max(scale, 1e-300)),
        "exact_accounting_j": float(np.max(np.abs(gained - t["avar_work"]))),
        "port_given_max_j": float(port.max()),
        "touch_ticks": int(touched.size),
        "release": int(touched[-1]) + 1 if touched.size else 0,
        "max_rate": float(np.max(np.abs(t["avar_sd"]))),
        "events": int(t["avar_events"].max()),
        "singular": int(t["avar_singular"].max()),
        "faults": int(t["fault"].max()), "pops": int(t["god_pops"][-1]),
    }  # fmt: skip


def push_figures(seconds: float = 6.0, sim_hz: float | None = None) -> dict[str, Any]:
    """V3.4 on coaster_loop (`balance`), and the free ride after the last touch against the
    independent reference (shared/reference_avar.py) started from the haptic side's state
    there: the track-point error."""
    scene, result = mechanism_run(PUSH_SCENE, PUSH_USER, seconds, sim_hz)
    t = result.ticks
    out = {"scene": PUSH_SCENE, **balance(scene, result)}
    cars = scene.cars[0]
    track = scene.tracks[0]
    loop = Ellipse(*track.semi_axes, track.center, cars.mass, cars.inertia, scene.gravity)
    release = out["release"]
    end = min(len(t) - 1, release + round(RELEASE_S / DT))
    times = t["t"][release : end + 1]
    points, _ = ellipse_train(
        loop, cars.count, cars.spacing_m, float(t["avar_sd"][release]), times,
        float(t["avar_s"][release]),
    )  # fmt: skip
    table = tabulate(scene.track_spec)[0]
    ours = np.array([track_point(table, s)[:2] for s in t["avar_s"][release : end + 1]])
    out["free_s"] = float(times[-1] - times[0])
    out["free_error_um"] = float(1e6 * np.max(np.hypot(*(ours - points).T)))
    return out


def crank_flick_figures(seconds: float = 4.0, sim_hz: float | None = None) -> dict[str, Any]:
    """V3.6 in the loop on `crank` (`balance`), the dead centres it turned through after the
    flick, and its free spin against the reference: on a table the kinetic energy holds, so
    phi' = sqrt(2 E / M(phi)) with M from finite differences of the closed-form positions
    (shared/reference_avar.py crank_mass), relative error."""
    scene, result = mechanism_run(CRANK_SCENE, CRANK_USER, seconds, sim_hz)
    t = result.ticks
    out = {"scene": CRANK_SCENE, **balance(scene, result)}
    release = out["release"]
    phi = t["avar_s"][release:]
    rate = t["avar_sd"][release:]
    c = scene.crank
    assert c is not None
    masses = (c.crank_mass, c.rod_mass, c.slider_mass)
    m0 = crank_reference_mass(c.crank_length, c.rod_length, *masses, float(phi[0]))
    kinetic = 0.5 * m0 * float(rate[0]) ** 2
    ref = np.array(
        [
            np.sqrt(2 * kinetic / crank_reference_mass(c.crank_length, c.rod_length, *masses, p))
            for p in phi
        ]
    )
    out["free_s"] = float(t["t"][-1] - t["t"][release])
    out["free_rate_error"] = float(np.max(np.abs(np.abs(rate) - ref) / ref))
    out["dead_centres"] = int(np.sum(np.diff(np.floor(phi / np.pi)) != 0))
    return out


def wheel_push_figures(seconds: float = 4.0, sim_hz: float | None = None) -> dict[str, Any]:
    """A geared tree in the loop on `ferris_wheel` (`balance`): how far the wheel turned, and
    its free spin after the last touch against the closed form: balanced, with the gondolas
    level (their gear cancels the arms'), M_q is constant and no force turns it, so q' holds
    (relative error)."""
    scene, result = mechanism_run(WHEEL_SCENE, WHEEL_USER, seconds, sim_hz)
    t = result.ticks
    out = {"scene": WHEEL_SCENE, **balance(scene, result)}
    release = out["release"]
    rate = t["avar_sd"][release:]
    mech = mechanism_record(scene)[0]
    out["turned_rad"] = float(np.ptp(_unwrapped(mech, t["avar_s"])))
    out["free_s"] = float(t["t"][-1] - t["t"][release])
    out["free_rate_error"] = float(np.max(np.abs(rate - rate[0])) / abs(rate[0]))
    return out


@njit(cache=True)
def _steps(table, train, st, n):
    for _ in range(n):
        train_step(table, train, st, 0.0, DT)


def step_cost(repeats: int = 200, batch: int = 1000) -> dict[str, float]:
    """One train_step of three cars on the loop, timed inside compiled code (batches of
    `batch` steps, as the loop calls it; the compile apart)."""
    tables = tabulate(loop_spec())
    trains = train_record(3, SPACING, LOOP.mass, LOOP.inertia, GRAVITY)
    states = avar_state(0.0, LOOP_SPEED)
    start = time.perf_counter()
    _steps(tables[0], trains[0], states[0], 1)
    compile_s = time.perf_counter() - start
    per_step = np.empty(repeats)
    for i in range(repeats):
        t0 = time.perf_counter_ns()
        _steps(tables[0], trains[0], states[0], batch)
        per_step[i] = (time.perf_counter_ns() - t0) / batch
    return {
        "compile_s": compile_s,
        "p50_us": float(np.percentile(per_step, 50) / 1e3),
        "p99_us": float(np.percentile(per_step, 99) / 1e3),
    }


def report() -> dict[str, Any]:
    return {
        "loop": loop_figures(),
        "ramp": ramp_figures(),
        "valley": valley_figures(),
        "crank": crank_figures(),
        "push": push_figures(),
        "crank_flick": crank_flick_figures(),
        "wheel_push": wheel_push_figures(),
        "step_cost": step_cost(),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", help="write the figures here too")
    args = parser.parse_args(argv)
    figures = report()
    text = json.dumps(figures, indent=2)
    print(text)
    if args.json:
        with open(args.json, "w") as f:
            f.write(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

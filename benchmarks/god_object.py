"""The god-object's validation cases V1.1-V1.6 (DESIGN-WAVE2 §3), their figures against
the closed forms, and the kernel's cost per tick against the number of shapes.

Each case drives the compiled kernel directly with an ideal device (the finger is where
the case puts it) and exact obstacle motion, so the figure is the method's own error.

    python -m haptic_local_model.benchmarks.god_object [--cost-ticks 20000]
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass

import numpy as np
from numba import njit

from haptic_local_model.haptic_server.stages.god_object import (
    Contact,
    god_data,
    god_object_tick,
    god_params,
    install_clock,
    install_shapes,
)
from haptic_local_model.shared.shapes import (
    Motion,
    ShapeKind,
    set_core,
    shape_array,
    to_body,
    to_world,
)

DT = 1e-3
RADIUS = 0.002  # r, the finger's radius in every case (the brief's)
K = (1000.0, 1000.0)
B = (2.0, 2.0)  # >= K dt / 2 (Colgate)
COST_TARGET_US = 15.0  # brief: god-object work per tick <= 15 us p99 with 16 shapes


def box(shapes: np.ndarray, k: int, size: tuple[float, float], key: int, **fields: object) -> None:
    """shapes[k] = a size[0] x size[1] box about its COM."""
    hx, hy = size[0] / 2, size[1] / 2
    set_core(shapes[k], ShapeKind.POLYGON, [[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]], 0.0)
    shapes[k]["key"] = key
    for name, value in fields.items():
        shapes[k][name] = value


# --- V1.1 a box rocking in angle, frictionless ---------------------------------------------


@dataclass(frozen=True)
class Rocking:
    max_proxy_error_m: float
    max_force_error_n: float  # against the spring-damper law on the closed-form proxy


def rocking_box(periods: int = 10) -> Rocking:
    """40 x 20 mm box, theta(t) = 0.3 sin(2 pi t / 2 s) about its centre, finger fixed 3 mm
    into the top face's Voronoi region. Reference p* = T(t) (proj_top(T^-1 x_h) + r n)."""
    amp, period = 0.3, 2.0
    shapes = shape_array(1)
    box(shapes, 0, (0.04, 0.02), 1, motion=int(Motion.SCREW))
    xh = np.array([0.005, 0.01 + RADIUS - 0.003])
    m = god_params(RADIUS, K, B, blend_s=0.0)
    d = god_data((0.005, 0.01 + RADIUS))
    ticks = round(periods * period / DT)
    worst_p = worst_f = 0.0
    prev_ref = None
    for i in range(ticks):
        t0, t1 = i * DT, (i + 1) * DT
        theta = amp * math.sin(2 * math.pi * t0 / period)
        omega = amp * 2 * math.pi / period * math.cos(2 * math.pi * t0 / period)
        shapes[0]["pose"] = (0.0, 0.0, theta)
        shapes[0]["twist"] = (0.0, 0.0, omega)
        god_object_tick(m, d, shapes, 1, xh, xh, 0.0, DT)
        th1 = amp * math.sin(2 * math.pi * t1 / period)
        pose = np.array([0.0, 0.0, th1])
        bx, _ = to_body(pose, xh[0], xh[1])
        ref = np.array(to_world(pose, bx, 0.01 + RADIUS))
        worst_p = max(worst_p, float(np.hypot(*(d[0]["proxy"] - ref))))
        if prev_ref is not None:
            f_ref = np.array(K) * (ref - xh) + np.array(B) * (ref - prev_ref) / DT
            worst_f = max(worst_f, float(np.hypot(*(d[0]["force"] - f_ref))))
        prev_ref = ref
    return Rocking(worst_p, worst_f)


# --- V1.2 static contact carried on a moving box -------------------------------------------


@dataclass(frozen=True)
class Stick:
    stick_ticks: int  # ticks in STICK before the first slip
    expected_ticks: float  # mu_s d_n / |v| / dt
    drift_m: float  # largest body-frame drift of p during the stick
    slip_ratio: float  # median |F_t| / |F_n| while slipping (mu_k expected)


def stick_on_moving_box(spin: bool, mu_s: float = 0.5, mu_k: float = 0.4) -> Stick:
    """Finger held d_n = 2 mm into the top of a 40 x 20 mm box translating at 20 mm/s
    (spin: turning at 1 rad/s about a point 10 mm left of its centre)."""
    d_n = 0.002
    shapes = shape_array(1)
    if spin:
        pivot_offset = np.array([-0.01, 0.0])
        omega = -1.0  # clockwise: the finger's side of the top face turns toward it
        v = omega * np.array([pivot_offset[1], -pivot_offset[0]])  # omega x (c - pivot)
        box(shapes, 0, (0.04, 0.02), 1, motion=int(Motion.SCREW), twist=(v[0], v[1], omega))
        speed = abs(omega) * np.hypot(0.0 - pivot_offset[0], 0.01 + RADIUS - pivot_offset[1])
    else:
        box(shapes, 0, (0.04, 0.02), 1, twist=(0.02, 0.0, 0.0))
        speed = 0.02
    xh = np.array([0.0, 0.01 + RADIUS - d_n])
    m = god_params(RADIUS, K, B, blend_s=0.0)
    d = god_data((0.0, 0.01 + RADIUS))
    shapes[0]["static_friction"] = mu_s
    shapes[0]["friction"] = mu_k
    local0 = None
    drift = 0.0
    stick = 0
    ratios = []
    slipping = False
    for i in range(400):
        god_object_tick(m, d, shapes, 1, xh, xh, i * DT, DT)
        st = d[0]
        if not slipping and st["contact"] == Contact.STICK:
            stick += 1
            local = np.array(to_body(st["poses"][0], *st["proxy"]))
            local0 = local if local0 is None else local0
            drift = max(drift, float(np.hypot(*(local - local0))))
            continue
        slipping = True
        if st["contact"] == Contact.SLIDE:
            _, nx_, ny_ = _normal(shapes, st)
            f = st["force"]
            fn = abs(f[0] * nx_ + f[1] * ny_)
            ft = abs(-f[0] * ny_ + f[1] * nx_)
            ratios.append(ft / fn)
        if not spin and i > 150:
            break
        if spin and len(ratios) > 20:
            break
    expected = mu_s * d_n / speed / DT
    return Stick(stick, expected, drift, float(np.median(ratios)) if ratios else math.nan)


def _normal(shapes: np.ndarray, st: np.void) -> tuple[float, float, float]:
    from haptic_local_model.shared.shapes import signed_distance

    return signed_distance(shapes[0], st["poses"][0], st["proxy"][0], st["proxy"][1], RADIUS)


# --- V1.3 a fast segment through a still finger --------------------------------------------


def segment_passes(speeds: np.ndarray, phases: np.ndarray, max_substeps: int) -> np.ndarray:
    """For each (speed, phase): 1 if a 0.5 mm-radius segment, 20 mm long, swept at that speed
    through a finger held at the origin, ends with the proxy behind it (a pop-through),
    2 if the kernel logged a pop, else 0 (the proxy pushed ahead, as a wall would)."""
    out = np.zeros(len(speeds), dtype=np.int64)
    m = god_params(RADIUS, K, B, max_substeps=max_substeps, max_force=1e6, blend_s=0.0)
    xh = np.zeros(2)
    for j, (v, phase) in enumerate(zip(speeds, phases, strict=True)):
        shapes = shape_array(1)
        set_core(shapes[0], ShapeKind.SEGMENT, [[0.0, -0.01], [0.0, 0.01]], 0.0005)
        shapes[0]["key"] = 1
        x_start = -0.01 - phase * v * DT
        shapes[0]["pose"] = (x_start, 0.0, 0.0)
        shapes[0]["twist"] = (v, 0.0, 0.0)
        d = god_data((0.0, 0.0))
        ticks = math.ceil(0.02 / (v * DT)) + 2
        for i in range(ticks):
            god_object_tick(m, d, shapes, 1, xh, xh, i * DT, DT)
        seg_x = x_start + v * ticks * DT
        if d[0]["pops"]:
            out[j] = 2
        elif d[0]["proxy"][0] < seg_x:
            out[j] = 1
    return out


def pop_onset(max_substeps: int, lo: float = 1.0, hi: float = 4.0, step: float = 0.02) -> float:
    """The lowest speed (m/s) at which any of 16 phases pops through."""
    phases = np.linspace(0.0, 1.0, 16, endpoint=False)
    for v in np.arange(lo, hi, step):
        got = segment_passes(np.full(16, v), phases, max_substeps)
        if np.any(got == 1):
            return float(v)
    return math.inf


# --- V1.4 slabs closing on the finger ------------------------------------------------------


@dataclass(frozen=True)
class Slabs:
    pops: int
    max_step_n: float  # largest per-tick |dF|
    ramp_step_n: float  # F_max dt / T_pop
    max_force_n: float
    finite: bool


def closing_slabs(max_force: float = 4.0, pop_ramp_s: float = 0.02) -> Slabs:
    """A floor and a ceiling 10 mm apart; the ceiling descends at 20 mm/s to a 2 mm gap
    (< 2 r) while the finger presses 3 mm into the floor."""
    shapes = shape_array(2)
    box(shapes, 0, (0.06, 0.01), 1, pose=(0.0, -0.01, 0.0))  # top at y = -0.005
    box(shapes, 1, (0.06, 0.01), 2, pose=(0.0, 0.01, 0.0), twist=(0.0, -0.02, 0.0))
    xh = np.array([0.0, -0.005 + RADIUS - 0.003])
    m = god_params(RADIUS, K, B, max_force=max_force, pop_ramp_s=pop_ramp_s, blend_s=0.0)
    d = god_data((0.0, -0.005 + RADIUS))
    forces = []
    for i in range(400):  # 8 mm at 20 mm/s
        god_object_tick(m, d, shapes, 2, xh, xh, i * DT, DT)
        forces.append(d[0]["force"].copy())
    f = np.array(forces)
    steps = np.hypot(*np.diff(f, axis=0).T)
    return Slabs(
        int(d[0]["pops"]),
        float(steps.max()),
        max_force * DT / pop_ramp_s,
        float(np.hypot(*f.T).max()),
        bool(np.all(np.isfinite(f)) and np.all(np.isfinite(d[0]["proxy"]))),
    )


# --- V1.5 a fast finger through a thin wall ------------------------------------------------


def thin_wall_trials(n: int, speed: float = 3.0, seed: int = 5) -> int:
    """How many of n straight strokes at `speed` through a 0.05 mm-radius static segment
    (random height, angle within 60 degrees of the normal, tick phase) leave the proxy on
    the far side."""
    rng = np.random.default_rng(seed)
    shapes = shape_array(1)
    set_core(shapes[0], ShapeKind.SEGMENT, [[0.0, -0.05], [0.0, 0.05]], 0.00005)  # no way round
    shapes[0]["key"] = 1
    m = god_params(RADIUS, K, B, blend_s=0.0)
    crossed = 0
    for _ in range(n):
        y = rng.uniform(-0.008, 0.008)
        angle = rng.uniform(-math.pi / 3, math.pi / 3)
        u = np.array([math.cos(angle), math.sin(angle)])
        start = np.array([-0.005, y]) - rng.uniform(0, speed * DT) * u
        d = god_data(tuple(start))
        x0 = start.copy()
        for i in range(int(0.012 / (speed * DT)) + 1):
            x1 = start + (i + 1) * speed * DT * u
            god_object_tick(m, d, shapes, 1, x0, x1, 0.0, DT)
            x0 = x1
        if d[0]["proxy"][0] > 0.0:
            crossed += 1
    return crossed


# --- V1.6 the update boundary ---------------------------------------------------------------


@dataclass(frozen=True)
class Boundary:
    install_max_n: float  # largest per-tick |dF| on install ticks and the tick after
    other_p99_n: float  # p99 of the other ticks
    ratio: float


def update_boundary(blend_s: float, rate_hz: float = 30.0, seconds: float = 5.0) -> Boundary:
    """The testbed shuttle's motion (25 mm, 2.5 s; a_max 0.158 m/s^2) along the contact
    normal: a platform moving up and down under a finger that rides it 1 mm deep. The sim
    samples the platform's pose and velocity at rate_hz; between updates the kernel carries
    it by its twist, and at each install the old extrapolation's error fades out over
    blend_s (0: it jumps)."""
    amp, period = 0.025, 2.5
    w = 2 * math.pi / period

    def state(t: float) -> tuple[float, float]:
        return amp * math.sin(w * t), amp * w * math.cos(w * t)

    old, new = shape_array(1), shape_array(1)
    box(old, 0, (0.06, 0.01), 1)
    box(new, 0, (0.06, 0.01), 1)
    m = god_params(RADIUS, K, B, blend_s=blend_s)
    y0, v0 = state(0.0)
    new[0]["pose"] = (0.0, y0, 0.0)
    new[0]["twist"] = (0.0, v0, 0.0)
    d = god_data((0.0, y0 + 0.005 + RADIUS))
    period_ticks = 1.0 / rate_hz / DT
    last_update = 0.0
    installs = []
    forces = []
    x0 = np.array([0.0, y0 + 0.005 + RADIUS - 0.001])
    next_update = 1
    for i in range(int(seconds / DT)):
        t = i * DT
        if i >= round(next_update * period_ticks):
            old[:] = new
            y, v = state(t)
            new[0]["pose"] = (0.0, y, 0.0)
            new[0]["twist"] = (0.0, v, 0.0)
            install_shapes(m, d, old, 1, new, 1, install_clock(t - last_update, 0.0, t))
            last_update = t
            installs.append(i)
            next_update += 1
        x1 = np.array([0.0, state(t + DT)[0] + 0.005 + RADIUS - 0.001])
        god_object_tick(m, d, new, 1, x0, x1, t - last_update, DT)
        forces.append(d[0]["force"].copy())
        x0 = x1
    f = np.array(forces)
    steps = np.hypot(*np.diff(f, axis=0).T)  # steps[i] = |F[i+1] - F[i]|: tick i+1's change
    is_install = np.zeros(len(f), dtype=bool)
    is_install[installs] = True
    after = np.roll(is_install, 1)  # the next tick: a jump's velocity returns through B
    at = steps[is_install[1:] | after[1:]]
    other = steps[~(is_install | after)[1:]][5:]
    p99 = float(np.percentile(other, 99))
    return Boundary(float(at.max()), p99, float(at.max() / p99))


# --- cost ----------------------------------------------------------------------------------


@njit(cache=True)
def _ticks(m, d, shapes, n_shapes, xs, out):
    x0 = xs[0]
    for i in range(1, xs.shape[0]):
        x1 = xs[i]
        god_object_tick(m, d, shapes, n_shapes, x0, x1, i * 1e-3, 1e-3)
        out[i] = d[0].force[0]
        x0 = x1


def cost_scene(
    n_shapes: int, ticks: int = 2001
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A finger stroking across a floor among n_shapes boxes, some spinning and sliding
    within reach (the hardest case: every shape near, sub-stepping on)."""
    rng = np.random.default_rng(3)
    shapes = shape_array(n_shapes)
    box(shapes, 0, (0.2, 0.02), 0, pose=(0.0, -0.01, 0.0), static_friction=0.5, friction=0.4)
    for k in range(1, n_shapes):
        x = rng.uniform(-0.05, 0.05)
        box(
            shapes, k, (0.008, 0.008), k, motion=int(Motion.SCREW),
            pose=(x, rng.uniform(0.004, 0.03), rng.uniform(0, 6)),
            twist=(rng.uniform(-0.3, 0.3), 0.0, rng.uniform(-3, 3)),
            static_friction=0.3, friction=0.2,
        )  # fmt: skip
    t = np.arange(ticks) * 1e-3
    xs = np.stack([0.04 * np.sin(2 * np.pi * t), -0.002 + 0.001 * np.sin(7 * t)], axis=1)
    m = god_params(RADIUS, K, B, blend_s=0.0)
    d = god_data((xs[0, 0], RADIUS + 1e-4))
    return m, d, shapes, xs


def cost_us(n_shapes: int, ticks: int, repeats: int = 9) -> dict[str, float]:
    """Per-tick cost (us) of the kernel in a compiled loop: median and p99 of the per-chunk
    means over repeats, and the p99 of single ticks timed one by one from Python (what the
    loop's work figure sees, call overhead included)."""
    m, d, shapes, xs = cost_scene(n_shapes, ticks)
    out = np.zeros(len(xs))
    start = time.perf_counter()
    _ticks(m, d, shapes, n_shapes, xs[:3], out)
    compile_s = time.perf_counter() - start
    chunk = []
    for _ in range(repeats):
        m, d, shapes, xs = cost_scene(n_shapes, ticks)
        t0 = time.perf_counter_ns()
        _ticks(m, d, shapes, n_shapes, xs, out)
        chunk.append((time.perf_counter_ns() - t0) / (len(xs) - 1) / 1e3)
    m, d, shapes, xs = cost_scene(n_shapes, ticks)
    single = np.empty(len(xs) - 1)
    for i in range(1, len(xs)):
        t0 = time.perf_counter_ns()
        god_object_tick(m, d, shapes, n_shapes, xs[i - 1], xs[i], i * 1e-3, 1e-3)
        single[i - 1] = (time.perf_counter_ns() - t0) / 1e3
    return {
        "compile_s": compile_s,
        "loop_median_us": float(np.median(chunk)),
        "loop_max_us": float(np.max(chunk)),
        "tick_p50_us": float(np.percentile(single, 50)),
        "tick_p99_us": float(np.percentile(single, 99)),
        "tick_max_us": float(single.max()),
    }


def report_cost(ticks: int) -> None:
    """The cost table (also printed by benchmarks/kernel_cost.py)."""
    print("god-object cost per tick (a finger stroking a floor among spinning, sliding boxes):")
    for n in (1, 16, 64):
        c = cost_us(n, ticks)
        note = f"  (target <= {COST_TARGET_US} us p99)" if n == 16 else ""
        print(
            f"  {n:2d} shapes: compiled loop median {c['loop_median_us']:.2f} us; one call per "
            f"tick p50 {c['tick_p50_us']:.2f} p99 {c['tick_p99_us']:.2f} max "
            f"{c['tick_max_us']:.1f} us{note}"
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m haptic_local_model.benchmarks.god_object")
    parser.add_argument("--cost-ticks", type=int, default=20000)
    parser.add_argument("--passes", type=int, default=1000, help="V1.3/V1.5 trials")
    args = parser.parse_args(argv)
    rock = rocking_box()
    print(f"V1.1 rocking box: max |p - p*| {rock.max_proxy_error_m * 1e6:.3f} um (<= 2), "
          f"max |F - F*| {rock.max_force_error_n * 1e3:.3f} mN (<= {K[0] * 2e-3:.1f})")  # fmt: skip
    for spin in (False, True):
        s = stick_on_moving_box(spin)
        print(f"V1.2 stick on a {'spinning' if spin else 'translating'} box: drift "
              f"{s.drift_m * 1e6:.4f} um (<= 1), stick {s.stick_ticks} ticks "
              f"(closed form {s.expected_ticks:.1f}), slip ratio {s.slip_ratio:.4f} (0.4 +- 1%)")  # fmt: skip
    for sub in (1, 16):
        print(f"V1.3 pop-through onset, max_substeps {sub}: {pop_onset(sub, hi=9.0)} m/s "
              f"((r + rho)/dt = {(RADIUS + 0.0005) / DT} m/s)")  # fmt: skip
    rng = np.random.default_rng(1)
    got = segment_passes(rng.uniform(0.1, 5.0, args.passes), rng.uniform(0, 1, args.passes), 16)
    print(f"V1.3 {args.passes} passes at 0.1..5 m/s with sub-steps: {int(np.sum(got == 1))} "
          f"pop-throughs, {int(np.sum(got == 2))} logged pops")  # fmt: skip
    got = segment_passes(np.full(200, 8.0), rng.uniform(0, 1, 200), 16)
    print(f"V1.3 200 passes at 8 m/s: {int(np.sum(got == 1))} silent pop-throughs, "
          f"{int(np.sum(got == 2))} logged")  # fmt: skip
    slabs = closing_slabs()
    print(f"V1.4 closing slabs: {slabs.pops} pop(s), max per-tick |dF| {slabs.max_step_n:.4f} N "
          f"(ramp bound {slabs.ramp_step_n:.4f}), max |F| {slabs.max_force_n:.3f} N, "
          f"finite {slabs.finite}")  # fmt: skip
    print(f"V1.5 thin wall at 3 m/s: {args.passes - thin_wall_trials(args.passes)}/{args.passes} "
          "strokes held on the near side")  # fmt: skip
    for blend in (0.025, 8e-3, 0.0):
        b = update_boundary(blend)
        print(f"V1.6 updates at 30 Hz, pose FOH {blend * 1e3:.0f} ms: install-tick max |dF| "
              f"{b.install_max_n:.4f} N, other ticks p99 {b.other_p99_n:.4f} N, ratio {b.ratio:.2f} (<= 2)")  # fmt: skip
    report_cost(args.cost_ticks)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Tracks for animation-variable linkages: arc-length tables of planar curves (seed 003 §4;
DESIGN-WAVE2 §5).

A track is a curve p(s) in the world's vertical plane, parametrised by arc length s, with
heading psi(s) (the tangent t = (cos psi, sin psi)), curvature kappa = psi' and its rate
kappa'. It is built from segments laid end to end from a start pose:

- ``line`` (L): kappa = 0;
- ``arc`` (R, dpsi): kappa = sign(dpsi) / R over L = R |dpsi|;
- ``clothoid`` (L, kappa0, kappa1): kappa linear in s, so a line joins an arc with no step in
  kappa (C2: no step in the force on a car);
- ``kink`` (dpsi): a zero-length turn, a C0 knot where the tangent jumps (a polyline's
  corner; a car crossing it loses energy by the plastic projection, DESIGN-WAVE2 §5 (i));

or it is one closed ``ellipse`` (centre, semi-axes a, b), s = 0 at its lowest point, run
counter-clockwise. A closed segment track must end where it starts, with its heading; a
kink first or last in it is the corner at its seam (s = length = 0). An open track's kinks
lie between two pieces.

The table samples (x, y, psi, kappa, kappa', kappa'') at knots no farther apart than
KNOT_SPACING_M, every segment's ends included: two knots share an s at each join, one per
side, so interpolation never straddles a join. Between knots every column is a cubic
Hermite interpolant on its derivative column (x, y on cos psi, sin psi; psi on kappa; kappa
on kappa'; kappa' on kappa''), which is exact for lines, arcs and clothoids' curvature and
within 1e-12 m of the ellipse. Building the table is Python (at load, outside the tick);
`track_point` is the numba kernel of the 1 kHz loop.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

MAX_KNOTS = 8192
MAX_KINKS = 16
KNOT_SPACING_M = 2.5e-4  # DESIGN-WAVE2 §5: the haptic side tabulates at 0.25 mm
CLOSURE_M = 1.0e-6  # a closed segment track must end this near its start
CLOSURE_RAD = 1.0e-6  # ... with its heading (modulo a turn)
_GAUSS_X, _GAUSS_W = np.polynomial.legendre.leggauss(8)  # per knot interval: exact to 1e-16
ELLIPSE_PANELS = 4096  # the ellipse's arc length S(u) on this many Gauss panels
NEWTON_ROUNDS = 8  # s -> u on the ellipse (quadratic convergence from a 1e-4 guess)


class SegmentKind(enum.IntEnum):
    LINE = 0
    ARC = 1
    CLOTHOID = 2
    KINK = 3


@dataclass(frozen=True)
class Segment:
    """One piece of a segment track: its length and its curvature at both ends (a kink:
    no length, a turn of `turn` rad)."""

    kind: SegmentKind
    length: float = 0.0
    kappa0: float = 0.0
    kappa1: float = 0.0
    turn: float = 0.0

    @staticmethod
    def line(length: float) -> Segment:
        return Segment(SegmentKind.LINE, length)

    @staticmethod
    def arc(radius: float, turn: float) -> Segment:
        if not radius > 0.0:
            raise ValueError(f"an arc's radius must be > 0, got {radius}")
        k = math.copysign(1.0 / radius, turn)
        return Segment(SegmentKind.ARC, radius * abs(turn), k, k)

    @staticmethod
    def clothoid(length: float, kappa0: float, kappa1: float) -> Segment:
        return Segment(SegmentKind.CLOTHOID, length, kappa0, kappa1)

    @staticmethod
    def kink(turn: float) -> Segment:
        return Segment(SegmentKind.KINK, turn=turn)


@dataclass(frozen=True)
class TrackSpec:
    """A track: an ellipse (`semi_axes` > 0) or segments from `start` heading `heading`."""

    segments: tuple[Segment, ...] = ()
    start: tuple[float, float] = (0.0, 0.0)
    heading: float = 0.0
    closed: bool = False
    center: tuple[float, float] = (0.0, 0.0)
    semi_axes: tuple[float, float] = (0.0, 0.0)

    @property
    def is_ellipse(self) -> bool:
        return self.semi_axes[0] > 0.0


TRACK_DTYPE = np.dtype(
    [
        ("closed", np.int64),  # 1: s wraps at length (a loop); 0: open, ends at 0 and length
        ("n_knots", np.int64),
        ("length", np.float64),  # m
        ("s", np.float64, (MAX_KNOTS,)),  # m, non-decreasing; a join's two knots share an s
        ("x", np.float64, (MAX_KNOTS,)),
        ("y", np.float64, (MAX_KNOTS,)),
        ("psi", np.float64, (MAX_KNOTS,)),  # heading, rad, continuous except at kinks
        ("kappa", np.float64, (MAX_KNOTS,)),  # 1/m
        ("dkappa", np.float64, (MAX_KNOTS,)),  # 1/m^2
        ("ddkappa", np.float64, (MAX_KNOTS,)),  # 1/m^3
        ("n_kinks", np.int64),
        ("kink_s", np.float64, (MAX_KINKS,)),  # where the tangent jumps
        ("kink_before", np.int64, (MAX_KINKS,)),  # the knot that ends the segment before
        ("kink_after", np.int64, (MAX_KINKS,)),  # the knot that starts the one after
    ]
)


def _segment_knots(seg: Segment, x0: float, y0: float, psi0: float) -> np.ndarray:
    """Columns (s, x, y, psi, kappa, kappa', kappa'') at the knots of one segment, s from 0:
    psi and kappa in closed form, the position by 8-point Gauss per knot interval."""
    n = max(1, math.ceil(seg.length / KNOT_SPACING_M - 1e-9))
    s = np.linspace(0.0, seg.length, n + 1)
    rate = (seg.kappa1 - seg.kappa0) / seg.length if seg.length > 0.0 else 0.0

    def heading(u: np.ndarray) -> np.ndarray:
        return psi0 + seg.kappa0 * u + 0.5 * rate * u * u

    h = np.diff(s)
    mid = 0.5 * (s[:-1] + s[1:])
    nodes = mid[:, None] + 0.5 * h[:, None] * _GAUSS_X[None, :]
    angle = heading(nodes)
    dx = 0.5 * h * (np.cos(angle) @ _GAUSS_W)
    dy = 0.5 * h * (np.sin(angle) @ _GAUSS_W)
    out = np.empty((n + 1, 7))
    out[:, 0] = s
    out[:, 1] = x0 + np.concatenate(([0.0], np.cumsum(dx)))
    out[:, 2] = y0 + np.concatenate(([0.0], np.cumsum(dy)))
    out[:, 3] = heading(s)
    out[:, 4] = seg.kappa0 + rate * s
    out[:, 5] = rate
    out[:, 6] = 0.0
    return out


def _ellipse_knots(center: tuple[float, float], a: float, b: float) -> np.ndarray:
    """Columns (s, x, y, psi, kappa, kappa', kappa'') of the ellipse p(u) = c + (a sin u,
    -b cos u), s = 0 at the bottom, counter-clockwise: S(u) by Gauss panels, s -> u by
    Newton, the rest in closed form in u."""
    edges = np.linspace(0.0, 2.0 * np.pi, ELLIPSE_PANELS + 1)

    def speed(u: np.ndarray) -> np.ndarray:
        return np.sqrt(a * a * np.cos(u) ** 2 + b * b * np.sin(u) ** 2)

    def arc_from(u0: np.ndarray, u1: np.ndarray) -> np.ndarray:
        mid = 0.5 * (u0 + u1)
        half = 0.5 * (u1 - u0)
        return half * (speed(mid[..., None] + half[..., None] * _GAUSS_X) @ _GAUSS_W)

    panel = np.concatenate(([0.0], np.cumsum(arc_from(edges[:-1], edges[1:]))))
    length = float(panel[-1])
    n = math.ceil(length / KNOT_SPACING_M)
    s = np.linspace(0.0, length, n + 1)
    u = np.interp(s, panel, edges)
    for _ in range(NEWTON_ROUNDS):
        j = np.clip(np.searchsorted(edges, u, side="right") - 1, 0, ELLIPSE_PANELS - 1)
        u = u - (panel[j] + arc_from(edges[j], u) - s) / speed(u)
    u[0] = 0.0
    u[-1] = 2.0 * np.pi
    rho = a * a * np.cos(u) ** 2 + b * b * np.sin(u) ** 2  # |p_u|^2
    rho_u = (b * b - a * a) * np.sin(2.0 * u)
    rho_uu = 2.0 * (b * b - a * a) * np.cos(2.0 * u)
    kappa = a * b * rho**-1.5
    kappa_u = -1.5 * a * b * rho**-2.5 * rho_u
    kappa_uu = a * b * (3.75 * rho**-3.5 * rho_u**2 - 1.5 * rho**-2.5 * rho_uu)
    out = np.empty((n + 1, 7))
    out[:, 0] = s
    out[:, 1] = center[0] + a * np.sin(u)
    out[:, 2] = center[1] - b * np.cos(u)
    out[:, 3] = np.unwrap(np.arctan2(b * np.sin(u), a * np.cos(u)))
    out[:, 4] = kappa
    out[:, 5] = kappa_u / np.sqrt(rho)
    out[:, 6] = (kappa_uu / np.sqrt(rho) - 0.5 * kappa_u * rho**-1.5 * rho_u) / np.sqrt(rho)
    return out


def _check(spec: TrackSpec) -> None:
    if spec.is_ellipse:
        if not all(math.isfinite(v) and v > 0.0 for v in spec.semi_axes):
            raise ValueError(f"an ellipse's semi_axes must be finite and > 0, got {spec.semi_axes}")
        return
    if not any(seg.kind != SegmentKind.KINK for seg in spec.segments):
        raise ValueError("a segment track needs at least one segment with a length")
    for i, seg in enumerate(spec.segments):
        values = (seg.length, seg.kappa0, seg.kappa1, seg.turn)
        if not all(math.isfinite(v) for v in values):
            raise ValueError(
                f"segment {i} ({seg.kind.name.lower()}) has a value that is not finite"
            )
        if seg.kind != SegmentKind.KINK and not seg.length > 0.0:
            raise ValueError(
                f"segment {i} ({seg.kind.name.lower()}) needs a length > 0, got {seg.length}"
            )


def tabulate(spec: TrackSpec) -> np.ndarray:
    """The track's table, TRACK_DTYPE[1] (ValueError naming what is wrong with the spec)."""
    _check(spec)
    table = np.zeros(1, dtype=TRACK_DTYPE)
    t = table[0]
    kinks: list[tuple[float, int, int]] = []
    if spec.is_ellipse:
        knots = _ellipse_knots(spec.center, *spec.semi_axes)
        closed = True
    else:
        pieces: list[np.ndarray] = []
        x, y, psi, s0, count = spec.start[0], spec.start[1], spec.heading, 0.0, 0
        pending_kink = False
        seam_kink = False  # a closed track's corner where it ends and begins again
        for i, seg in enumerate(spec.segments):
            if seg.kind == SegmentKind.KINK:
                if count == 0 or i == len(spec.segments) - 1:
                    if not spec.closed:
                        raise ValueError(
                            f"segment {i} (kink): an open track's kink must lie between two pieces"
                        )
                    seam_kink = True
                psi += seg.turn
                pending_kink = True
                continue
            piece = _segment_knots(seg, x, y, psi)
            piece[:, 0] += s0
            if pending_kink and count > 0:
                kinks.append((s0, count - 1, count))
            pending_kink = False
            pieces.append(piece)
            count += len(piece)
            s0, x, y, psi = piece[-1, 0], piece[-1, 1], piece[-1, 2], piece[-1, 3]
        knots = np.concatenate(pieces)
        closed = spec.closed
        if closed:
            gap = math.hypot(x - spec.start[0], y - spec.start[1])
            turn = (psi - spec.heading) / (2.0 * np.pi)
            if gap > CLOSURE_M or abs(turn - round(turn)) * 2.0 * np.pi > CLOSURE_RAD:
                raise ValueError(
                    "a closed track must end at its start with its heading: it ends "
                    f"{gap * 1e3:.3g} mm away, turned {turn * 360.0:.6g} deg"
                )
            if seam_kink:  # its last knot before, its first after (s = length = 0)
                kinks.append((s0, count - 1, 0))
    if len(knots) > MAX_KNOTS:
        raise ValueError(
            f"the track needs {len(knots)} knots at {KNOT_SPACING_M * 1e3} mm; at most {MAX_KNOTS} "
            f"(a track of about {MAX_KNOTS * KNOT_SPACING_M:.1f} m)"
        )
    if len(kinks) > MAX_KINKS:
        raise ValueError(f"a track has at most {MAX_KINKS} kinks, got {len(kinks)}")
    n = len(knots)
    t["closed"] = int(closed)
    t["n_knots"] = n
    t["length"] = knots[-1, 0]
    for col, name in enumerate(("s", "x", "y", "psi", "kappa", "dkappa", "ddkappa")):
        t[name][:n] = knots[:, col]
    t["n_kinks"] = len(kinks)
    for k, (s, before, after) in enumerate(kinks):
        t["kink_s"][k] = s
        t["kink_before"][k] = before
        t["kink_after"][k] = after
    return table


@njit(cache=True)
def wrap_s(tr, s):
    """s on the table's range: modulo the length on a loop, clamped at an open track's ends."""
    if tr.closed == 1:
        s = s % tr.length
        return s if s < tr.length else 0.0
    return min(max(s, 0.0), tr.length)


@njit(cache=True)
def knot_interval(tr, s):
    """The last knot i <= n - 2 with s_i <= s (at a join: the knot after it)."""
    lo = 0
    hi = tr.n_knots - 2
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if tr.s[mid] <= s:
            lo = mid
        else:
            hi = mid - 1
    return lo


@njit(cache=True, inline="always")
def _hermite(v0, d0, v1, d1, h, u):
    u2 = u * u
    u3 = u2 * u
    return (
        (2.0 * u3 - 3.0 * u2 + 1.0) * v0
        + (u3 - 2.0 * u2 + u) * h * d0
        + (3.0 * u2 - 2.0 * u3) * v1
        + (u3 - u2) * h * d1
    )


@njit(cache=True, inline="always")
def _locate(tr, s):
    """The knot interval i of s (wrapped or clamped), its length h and s's place u in it."""
    s = wrap_s(tr, s)
    i = knot_interval(tr, s)
    h = tr.s[i + 1] - tr.s[i]
    return i, h, (s - tr.s[i]) / h if h > 0.0 else 0.0


@njit(cache=True)
def track_point(tr, s):
    """(x, y, psi, kappa, kappa') of the track at arc length s (wrapped or clamped)."""
    i, h, u = _locate(tr, s)
    j = i + 1
    x = _hermite(tr.x[i], math.cos(tr.psi[i]), tr.x[j], math.cos(tr.psi[j]), h, u)
    y = _hermite(tr.y[i], math.sin(tr.psi[i]), tr.y[j], math.sin(tr.psi[j]), h, u)
    psi, kappa, dkappa = track_heading(tr, s)
    return x, y, psi, kappa, dkappa


@njit(cache=True)
def track_heading(tr, s):
    """(psi, kappa, kappa') at s: track_point without the position (the dynamics' share)."""
    i, h, u = _locate(tr, s)
    j = i + 1
    psi = _hermite(tr.psi[i], tr.kappa[i], tr.psi[j], tr.kappa[j], h, u)
    kappa = _hermite(tr.kappa[i], tr.dkappa[i], tr.kappa[j], tr.dkappa[j], h, u)
    dkappa = _hermite(tr.dkappa[i], tr.ddkappa[i], tr.dkappa[j], tr.ddkappa[j], h, u)
    return psi, kappa, dkappa


@njit(cache=True)
def knot_point(tr, i):
    """(x, y, psi, kappa, kappa') at knot i exactly (a kink's one side)."""
    return tr.x[i], tr.y[i], tr.psi[i], tr.kappa[i], tr.dkappa[i]

"""The time-domain passivity controller of a port link, written once for both its ends (a
station's, stages/station.py `_passivity`; the world's, stages/world_ports.py
`port_passivity`; docs/stations.md, "Passivity"), and the carrying of the other end's
energy across its restarts."""

from __future__ import annotations

from numba import njit

#: The controller's damping is at most this many times the coupling's own (grasp_vertical:
#: 5 x 40 N s/m; the delay's energy at 16 Hz and 2 kN/m is about 20 v^2 W)
PC_MAX_OVER_B = 5.0


@njit(cache=True)
def pc_damping(held, out, per_damping, cap):
    """Ryu and Hannaford's controller on one axis: 0 unless this tick's output `out` (J,
    > 0: given out) leaves the link holding less than none (`held` < 0, after it); then the
    damping that removes the deficit, -held / per_damping (per_damping: the energy one
    N s/m of damping takes this tick, v^2 dt and the ramp's gain), at most `cap`."""
    if out > 0.0 and held < 0.0:
        return min(cap, -held / per_damping)
    return 0.0


@njit(cache=True)
def carry_budget(base, budget, floats, at, first):
    """The other end's energy (floats[at:at + 3], its message's) as this end's `budget`,
    less `base`; on the `first` message of a new epoch (a restarted station or world) the
    base is set so that the budget carries on where it was."""
    if first:
        for a in range(3):
            base[a] = floats[at + a] - budget[a]
    for a in range(3):
        budget[a] = floats[at + a] - base[a]

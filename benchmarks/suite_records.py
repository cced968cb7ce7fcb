"""The records of hapticbench (benchmarks/hapticbench.py): a case, and what a method hands
back for it. Their own module so that a baseline (benchmarks/peers.py, a plug-in) needs only
these, not the suite."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from haptic_local_model.shared.config import SceneConfig


@dataclass(frozen=True)
class Case:
    """One scene of the suite with its reference and the metric its table leads with."""

    name: str
    scene: str
    device: str
    user: str
    seconds: float
    reference: str
    headline: str  # the error metric the table and the plot show


@dataclass(frozen=True)
class MethodRun:
    """What a baseline hands back: the records the suite's metrics are computed over."""

    ticks: np.ndarray  # TICK_DTYPE records, one per 1 ms tick
    scene: SceneConfig  # the scene as the method rendered it (the reference reads it)
    cost_ms_per_sim_s: float  # wall-clock ms per simulated second of the stages it needs
    sim_hz: float
    substeps: int

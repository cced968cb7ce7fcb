"""The records of hapticbench (benchmarks/hapticbench.py): a case, and what a method hands
back for it. Their own module so that a baseline (benchmarks/peers.py, a plug-in) needs only
these, not the suite."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from haptic_local_model.shared.config import SceneConfig
from haptic_local_model.shared.port_config import PortSceneConfig


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
    #: the devices on the scene: 1, or 2 for a port scene (configs/ports/, the two-device
    #: grasp), whose devices and hands the scene names; a coupling that drives one device
    #: raises NotApplicable for it
    ports: int = 1


@dataclass(frozen=True)
class MethodRun:
    """What a baseline hands back: the records the suite's metrics are computed over."""

    ticks: np.ndarray  # TICK_DTYPE records, one per 1 ms tick (none for a port scene)
    scene: SceneConfig | PortSceneConfig  # the scene as rendered (the reference reads it)
    cost_ms_per_sim_s: float  # wall-clock ms per simulated second of the stages it needs
    sim_hz: float
    substeps: int
    #: what a case's metrics read beyond the ticks: the grasp's port run (PortResult), whose
    #: rows hold both devices and the box; None for a one-device case
    records: Any = None


class NotApplicableError(Exception):
    """Raised by a method for a case it cannot render, with the reason: the suite records
    the reason in the case's row instead of figures (a coupling of one device, a two-device
    case)."""

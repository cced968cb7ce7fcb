"""The station-link sweeps' plot (benchmarks/station_links_plot.py): each configuration's
line holds the worse port's figures, its ratios over its own unimpaired run or the base's, a
fallen box drawn at the top; the command writes a PNG from the sweeps' JSON."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest

from haptic_local_model.benchmarks.station_links_plot import (
    FELL_AT_MM,
    _drawn,
    config_label,
    main,
    series,
)


def _port(energy: float, rms: float, felt: float | None) -> dict[str, Any]:
    port: dict[str, Any] = {"energy_out_j": energy, "rms_above_5hz_n": rms}
    if felt is not None:  # a press run: its felt stiffness and its drift
        port["felt"] = {"n_per_m": felt}
        port["drift"] = {"drift_mm": felt / 1e4}
    return port


def _point(delay: float, loss: float, left: Any, right: Any, moved: float) -> dict[str, Any]:
    return {
        "impairment": {"delay_ms": delay, "jitter_ms": 0.2 * delay, "loss": loss},
        "passivity": "tdpa",
        "local_model": "on",
        "left": left,
        "right": right,
        "box_moved_mm": moved,
        "box_sank_mm": moved,
    }


SWEEP = [  # given out of order: the lines run by delay
    _point(50.0, 0.0, _port(0.01, 0.6, 1500.0), _port(0.03, 0.2, 1800.0), 1.5),
    _point(0.0, 0.0, _port(0.0, 0.2, 1875.0), _port(0.0, 0.1, 2000.0), 1.0),
    _point(50.0, 0.05, _port(0.5, 1.0, None), _port(0.0, 0.1, None), 300.0),
]


def test_each_configuration_has_the_worse_ports_figures_over_its_reference() -> None:
    data = series({"sweep": SWEEP}, None)
    lossless = data[config_label("sweep", SWEEP[0])]
    assert lossless["delay_ms"] == [0.0, 50.0]
    assert lossless["energy_j"] == [0.0, 0.03]
    # 0.6 / 0.2 on the left, 0.2 / 0.1 on the right: the worse is 3
    assert lossless["ratio"] == pytest.approx([1.0, 3.0])
    # 1500 / 1875 on the left, 1800 / 2000 on the right: the smaller share, 0.8
    assert lossless["felt"] == pytest.approx([1.0, 0.8])
    assert lossless["moved_mm"] == [1.0, 1.5]
    assert lossless["drift_mm"] == pytest.approx([0.2, 0.18])  # the larger port's
    lossy = data[config_label("sweep", SWEEP[2])]
    assert math.isnan(lossy["ratio"][0])  # no reference of its own, no base
    assert math.isnan(lossy["felt"][0])  # no press, no 0 ms run of its own
    assert math.isnan(lossy["drift_mm"][0])  # no press


def test_a_configuration_without_its_own_unimpaired_run_is_over_the_base() -> None:
    base = SWEEP[1]
    lossy = series({"sweep": SWEEP}, base)[config_label("sweep", SWEEP[2])]
    assert lossy["ratio"] == pytest.approx([5.0])  # 1.0 / 0.2 on the left, 1 on the right
    assert lossy["energy_j"] == [0.5]


def test_the_log_axes_draw_zero_energy_and_a_fallen_box() -> None:
    assert _drawn("energy_j", 0.0) > 0.0
    assert _drawn("moved_mm", 300.0) == FELL_AT_MM
    assert _drawn("moved_mm", 1.5) == 1.5
    assert _drawn("ratio", 2.0) == 2.0
    assert _drawn("drift_mm", 0.0) > 0.0 and _drawn("drift_mm", 0.3) == 0.3


@pytest.mark.slow  # matplotlib draws the five panels
def test_the_command_writes_the_png(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep.json"
    sweep.write_text(json.dumps(SWEEP))
    out = tmp_path / "links.png"
    assert main([str(sweep), "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main([str(tmp_path / "missing.json"), "--out", str(out)]) == 2

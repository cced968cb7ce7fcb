"""Fake pyOpenHaptics.hd_callback: the decorator wraps the servo function in a frame."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from pyOpenHaptics import hd


def hd_callback(fn: Callable[[], Any]) -> Callable[[], Any]:
    def frame() -> Any:
        hd.IN_FRAME.on = True
        try:
            return fn()
        finally:
            hd.IN_FRAME.on = False

    return frame

"""Fake pyOpenHaptics.hd: get_transform (mm) and set_force (N), only inside a servo frame."""

from __future__ import annotations

import threading
from typing import Any

import _fake_handle

_fake_handle.runtime("libHD.so")

IN_FRAME = threading.local()


def _h() -> _fake_handle.FakeHandle:
    h = _fake_handle.HANDLE
    assert h is not None
    if not getattr(IN_FRAME, "on", False):
        raise RuntimeError("OpenHaptics call outside a scheduler frame")
    return h


def get_transform() -> list[list[float]]:
    h = _h()
    h.call("hd.get_transform")
    h.advance()
    x, y, z = (1e3 * v for v in h.position)
    return [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [x, y, z, 1.0]]


def set_force(feedback: Any) -> None:
    h = _h()
    h.call("hd.set_force")
    h.command(feedback)

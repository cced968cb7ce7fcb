"""Fake forcedimension_core.drd: open, isInitialized, autoInit, stop (error codes, no raise)."""

from __future__ import annotations

import _fake_handle

_fake_handle.runtime("libdrd.so.3")
DEVICE_ID = 0


def open() -> int:
    h = _fake_handle.handle("forcedimension")
    h.call("drd.open")
    return DEVICE_ID if _fake_handle.attached() else -1


def isInitialized(ID: int = -1) -> bool:
    h = _fake_handle.HANDLE
    assert h is not None
    h.call("drd.isInitialized")
    return h.calibrated


def autoInit(ID: int = -1) -> int:
    h = _fake_handle.HANDLE
    assert h is not None
    h.call("drd.autoInit")
    h.calibrated = True
    return 0


def stop(frc: bool = False, ID: int = -1) -> int:
    h = _fake_handle.HANDLE
    assert h is not None
    h.call("drd.stop")
    return 0

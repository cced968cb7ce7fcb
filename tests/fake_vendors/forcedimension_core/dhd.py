"""Fake forcedimension_core.dhd: positions and velocities filled in place (m, m/s), forces in
N, error codes (-1) instead of exceptions, errorGetLastStr for the reason."""

from __future__ import annotations

from typing import Any

import _fake_handle

_fake_handle.runtime("libdhd.so.3")
_last_error = "no error"


def getDeviceCount() -> int:
    return _fake_handle.attached()


def _h() -> _fake_handle.FakeHandle:
    h = _fake_handle.HANDLE
    assert h is not None
    return h


def errorGetLastStr() -> str:
    return _last_error


def setMaxForce(limit: float, ID: int = -1) -> int:
    _h().call("dhd.setMaxForce")
    _h().sdk_max_force = limit  # type: ignore[attr-defined]
    return 0


def enableForce(val: bool, ID: int = -1) -> int:
    _h().call("dhd.enableForce")
    if not _h().calibrated:
        return -1
    return 0


def getPosition(out: Any, ID: int = -1) -> int:
    global _last_error
    h = _h()
    h.call("dhd.getPosition")
    try:
        h.advance()
    except RuntimeError as exc:
        _last_error = str(exc)
        return -1
    out[0], out[1], out[2] = h.position
    return 0


def getLinearVelocity(out: Any, ID: int = -1) -> int:
    h = _h()
    h.call("dhd.getLinearVelocity")
    out[0], out[1], out[2] = h.velocity
    return 0


def setForce(f: Any, ID: int = -1) -> int:
    global _last_error
    h = _h()
    h.call("dhd.setForce")
    try:
        h.command(f)
    except RuntimeError as exc:
        _last_error = str(exc)
        return -1
    return 0


def stop(ID: int = -1) -> int:
    global _last_error
    _h().call("stop")
    if _h().close_fails:  # the device does not answer: its forces may still be on
        _last_error = "communication error (fake: FAKE_VENDOR_CLOSE_FAIL)"
        return -1
    _h().force = [0.0, 0.0, 0.0]
    return 0


def close(ID: int = -1) -> int:
    _h().call("close")
    _h().close()
    return 0

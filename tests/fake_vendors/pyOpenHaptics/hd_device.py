"""Fake pyOpenHaptics.hd_device.HapticDevice: init, force output on, the scheduler (a thread
calling the callback every millisecond, as OpenHaptics' servo loop does), close."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import _fake_handle

SERVO_PERIOD_S = 0.001


class HapticDevice:
    def __init__(
        self, callback: Callable[[], Any], device_name: str = "Default Device",
        scheduler_type: str = "async",
    ) -> None:  # fmt: skip
        h = self._h = _fake_handle.handle("touch")
        h.call("hdInitDevice")
        if not _fake_handle.attached():  # pyOpenHaptics raises on HD_DEVICE_ERROR
            raise RuntimeError(f"HD_DEVICE_ERROR: cannot initialise {device_name!r}")
        h.call("hdEnable(HD_FORCE_OUTPUT)")
        h.call("hdStartScheduler")
        self._callback = callback
        self._running = True
        self.errors: list[str] = []
        self._thread = threading.Thread(target=self._servo, daemon=True)
        self._thread.start()

    def _servo(self) -> None:
        next_s = time.monotonic()
        while self._running:
            try:
                self._callback()
            except Exception as exc:  # the real scheduler unschedules a failing callback
                self.errors.append(repr(exc))
                self._h.call("callback raised")
                return
            next_s += SERVO_PERIOD_S
            time.sleep(max(0.0, next_s - time.monotonic()))

    def close(self) -> None:
        self._running = False
        self._thread.join(1.0)
        self._h.call("hdStopScheduler")
        self._h.call("hdDisableDevice")
        if self._h.close_fails:  # pyOpenHaptics raises on an HD error
            raise RuntimeError("HD_COMM_ERROR: hdDisableDevice failed (FAKE_VENDOR_CLOSE_FAIL)")
        self._h.close()

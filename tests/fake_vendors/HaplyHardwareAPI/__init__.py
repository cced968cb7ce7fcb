"""A fake of Haply's HaplyHardwareAPI at the calls the adapter makes (see _fake_handle):
detect_inverse3s, SerialStream, Inverse3(stream).device_wakeup_dict / end_effector_force
(N in; position m and velocity m/s out)."""

from __future__ import annotations

from typing import Any

from _fake_handle import FakeHandle, attached, handle

PORT = "/dev/ttyFAKE0"


def detect_inverse3s() -> list[str]:
    return [PORT][: attached()]


class SerialStream:
    def __init__(self, port: str) -> None:
        if port != PORT:
            raise ValueError(f"cannot open {port}")
        self.port = port


class Inverse3:
    def __init__(self, stream: SerialStream) -> None:
        self._h: FakeHandle = handle("haply")
        self._h.call("Inverse3")
        self._awake = False

    def device_wakeup_dict(self) -> dict[str, Any]:
        self._h.call("device_wakeup_dict")
        self._awake = True
        return {"device_id": 1234, "device_model_number": 1, "firmware_version": 7}

    def end_effector_force(self, forces: Any = None) -> tuple[list[float], list[float]]:
        h = self._h
        h.call("end_effector_force")
        if not self._awake:
            raise RuntimeError("end_effector_force before device_wakeup_dict")
        if forces is None:
            h.advance()
        else:
            h.command(forces)
        return list(h.position), list(h.velocity)

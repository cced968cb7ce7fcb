"""Zenoh sessions and key expressions (peer mode, explicit endpoints, no multicast scouting).

Key expressions under the configured namespace (docs/protocol.md):
- `<ns>/local_model`: LocalModelUpdate, sim -> haptic
- `<ns>/proxy`: ProxyState, haptic -> sim
- `<ns>/input/pointer`: PointerInput, `haptic-pointer` -> haptic
"""

from __future__ import annotations

import contextlib
import ctypes
import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import zenoh

from haptic_local_model.shared.net.security import zenoh_keys

if TYPE_CHECKING:  # annotations only: the config module imports this one
    from haptic_local_model.shared.net.config import EndpointSpec


@dataclass(frozen=True)
class Keys:
    update: str
    proxy: str
    pointer: str
    static: str  # latched description of the scene's train (shared/protocol/static.py)
    alive: str  # the sim's liveliness token: <alive>/<epoch> while its session lives


def keys(namespace: str) -> Keys:
    return Keys(
        update=f"{namespace}/local_model",
        proxy=f"{namespace}/proxy",
        pointer=f"{namespace}/input/pointer",
        static=f"{namespace}/static",
        alive=f"{namespace}/alive/sim",
    )


def session_config(
    endpoints: EndpointSpec,
    extra: dict[str, Any] | None = None,
    namespace: str | None = None,
    mode: str = "peer",
) -> zenoh.Config:
    """A config in Zenoh's `mode` (peer, or a station network's router and clients) on explicit
    endpoints; gossip and multicast off (STACK-NOTES); the endpoint's credentials and access
    control (rules under `namespace`, shared/net/security.py)."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps(list(endpoints.listen)))
    conf.insert_json5("connect/endpoints", json.dumps(list(endpoints.connect)))
    for key, text in zenoh_keys(endpoints, namespace).items():
        try:
            conf.insert_json5(key, text)
        except zenoh.ZError as exc:  # e.g. an unknown path in the config's `zenoh` table
            raise ValueError(f"zenoh.{key}: {exc}") from None
    for key, value in (extra or {}).items():
        conf.insert_json5(key, json.dumps(value))
    return conf


def open_session(
    endpoints: EndpointSpec, extra: dict[str, Any] | None = None, namespace: str | None = None
) -> zenoh.Session:
    return zenoh.open(session_config(endpoints, extra, namespace))


def newest_payload(subscriber: Any) -> list[bytes]:
    """Everything waiting in a ring-channel subscriber, oldest first, without blocking."""
    out: list[bytes] = []
    while True:
        sample = subscriber.try_recv()
        if sample is None:
            return out
        out.append(sample.payload.to_bytes())


TRIM_AFTER = 1000  # messages received in a second: a flood's worth
TRIM_EVERY_S = 1.0


class FloodTrim:
    """After a flood, the memory its messages took handed back to the system: Zenoh's receive
    path allocates through glibc, whose per-thread arenas keep what was freed, and a first
    flood of 30,000 messages on a key left a receiving process 0-24 MB larger for good
    (benchmarks/flood.py). A loop calls `after` as often as it likes, with how to count its
    messages received (taken, refused or dropped): it counts them once a second, and
    `malloc_trim` runs (ctypes releases the GIL for it; tens of microseconds) in each second
    a flood's worth arrived in and in the one after."""

    def __init__(self) -> None:
        self._trim: Any = None
        with contextlib.suppress(OSError, AttributeError):  # not glibc: nothing to trim
            self._trim = ctypes.CDLL("libc.so.6").malloc_trim
        self._counted = 0
        self._flooding = False
        self._next = 0.0

    def after(self, now_s: float, count: Callable[[], int]) -> None:
        """At `now_s` (a monotonic clock, in s); `count()`: the messages received so far."""
        if self._trim is None or now_s < self._next:
            return
        counted = count()
        flooding = counted - self._counted >= TRIM_AFTER
        if flooding or self._flooding:  # in a flood's seconds, and the one after its end
            self._trim(0)
        self._counted, self._flooding, self._next = counted, flooding, now_s + TRIM_EVERY_S

"""Zenoh sessions and key expressions (peer mode, explicit endpoints, no multicast scouting).

Key expressions under the configured namespace (docs/protocol.md):
- `<ns>/local_model`: LocalModelUpdate, sim -> haptic
- `<ns>/proxy`: ProxyState, haptic -> sim
- `<ns>/input/pointer`: PointerInput, `haptic-pointer` -> haptic
- `<ns>/view/world`: the world's shapes and poses, sim -> the live view (through the haptic
  server's I/O process; shared/protocol/world_view.py)
"""

from __future__ import annotations

import json
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
    view: str  # the world for the live view (sent only while a view subscribes)


def keys(namespace: str) -> Keys:
    return Keys(
        update=f"{namespace}/local_model",
        proxy=f"{namespace}/proxy",
        pointer=f"{namespace}/input/pointer",
        static=f"{namespace}/static",
        alive=f"{namespace}/alive/sim",
        view=f"{namespace}/view/world",
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

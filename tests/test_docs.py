"""The docs stay true to the code: every logged field and topic is documented."""

from __future__ import annotations

from pathlib import Path

from haptic_server.layout import TICK_DTYPE
from haptic_server.mcap_log import (
    EVENT_TOPIC,
    TICK_TOPIC,
    UPDATE_JSON_SCHEMA,
    UPDATE_TOPIC,
    run_metadata,
)

DOCS = Path(__file__).resolve().parent.parent / "docs"


def test_log_format_documents_every_tick_field_and_topic() -> None:
    text = (DOCS / "log-format.md").read_text()
    for name in TICK_DTYPE.names or ():
        assert f"| `{name}` |" in text, f"tick field {name} missing from docs/log-format.md"
    for name in UPDATE_JSON_SCHEMA["properties"]:  # type: ignore[attr-defined]
        assert f"`{name}`" in text, f"update field {name} missing from docs/log-format.md"
    for topic in (TICK_TOPIC, UPDATE_TOPIC, EVENT_TOPIC):
        assert f"`{topic}`" in text


def test_log_format_documents_the_metadata_and_replay() -> None:
    text = (DOCS / "log-format.md").read_text()
    meta = run_metadata({"scene": "", "device": "", "user": "", "network": ""}, {"clock": ""})
    for record, keys in meta.items():
        assert f"| `{record}` |" in text, f"metadata record {record} missing"
        for key in keys:
            assert f"`{key}`" in text, f"metadata key {record}.{key} missing"
    for option in ("--summary", "--plot", "--recover", "--no-replay"):
        assert option in text, f"haptic-replay {option} missing from docs/log-format.md"

"""The docs stay true to the code: every logged field and topic is documented."""

from __future__ import annotations

from pathlib import Path

from haptic_local_model.haptic_server.log import (
    EVENT_TOPIC,
    TICK_TOPIC,
    UPDATE_JSON_SCHEMA,
    UPDATE_TOPIC,
    run_metadata,
)
from haptic_local_model.haptic_server.model import TICK_DTYPE

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


def test_devices_doc_covers_every_model_its_aux_and_the_rendering_table() -> None:
    from dataclasses import fields

    from haptic_local_model.device_models.base import DeviceRenderingSpec
    from haptic_local_model.device_models.maglev import AUX_NAMES as MAGLEV_AUX
    from haptic_local_model.device_models.registry import DEVICE_MODELS
    from haptic_local_model.device_models.twin_pantograph import AUX_NAMES as PANTOGRAPH_AUX

    text = (DOCS / "devices.md").read_text()
    for model in DEVICE_MODELS:
        assert f"`{model}`" in text, f"device model {model} missing from docs/devices.md"
    for f in fields(DeviceRenderingSpec):
        assert f"`{f.name}`" in text, f"[rendering] key {f.name} missing from docs/devices.md"
    log = (DOCS / "log-format.md").read_text()
    assert "4 encoder angles" in log and len(PANTOGRAPH_AUX) == 8
    assert "measured z (m), roll, pitch" in log and MAGLEV_AUX[:3] == (
        "z_m",
        "roll_rad",
        "pitch_rad",
    )


def test_protocol_doc_is_the_table_and_matches_the_golden_bytes() -> None:
    """docs/protocol.md embeds the generated tables; the golden update has exactly the size
    and header values the table gives, and re-encodes to the same bytes."""
    import struct

    from haptic_local_model.shared.protocol.layout import (
        HEADER,
        HEADER_AT,
        HEADER_BYTES,
        HEADER_STRUCT,
        PROTOCOL_VERSION,
        markdown_tables,
        update_size,
    )
    from haptic_local_model.shared.protocol.update import decode_update, encode_update

    text = (DOCS / "protocol.md").read_text()
    embedded = text.split("<!-- protocol-tables:begin -->\n")[1].split("<!-- protocol-tables:end")[
        0
    ]
    assert embedded == markdown_tables(), "docs/protocol.md: regenerate the protocol tables"
    golden = (Path(__file__).parent / "golden" / "update_v3_linkage.bin").read_bytes()
    names = [f.name for f in HEADER]
    header = dict(zip(names, HEADER_STRUCT.unpack_from(golden, 0), strict=True))
    assert f"Header ({HEADER_BYTES} bytes" in text
    assert header["magic"] == b"HLMU" and header["version"] == PROTOCOL_VERSION
    d, j, n, flags = header["dof"], header["n_resisted"], header["n_contacts"], header["flags"]
    assert len(golden) == update_size(d, j, n, flags)
    at = HEADER_AT["publish_time_ns"]
    assert struct.unpack_from("<q", golden, at)[0] == decode_update(golden).publish_time_ns
    assert f"| {at} | `publish_time_ns` |" in text
    assert encode_update(decode_update(golden)) == golden


def test_protocol_doc_gives_the_proxy_header() -> None:
    """docs/protocol.md states the ProxyState header's struct, size and version as coded."""
    from haptic_local_model.shared.protocol.proxy import PROXY_HEADER, PROXY_VERSION

    text = (DOCS / "protocol.md").read_text()
    assert f"struct `{PROXY_HEADER.format}`, {PROXY_HEADER.size} bytes" in text
    assert f"version (`PROXY_VERSION`, {PROXY_VERSION})" in text


def test_the_architecture_doc_names_every_module_of_the_four_packages() -> None:
    """docs/architecture.md is the map of the house: each module of shared/, sim_server/,
    device_models/ and haptic_server/ is named there by its path (its module map), and each
    path named there is a module that exists."""
    import re

    root = DOCS.parent
    text = (DOCS / "architecture.md").read_text()
    packages = ("shared", "sim_server", "device_models", "haptic_server")
    modules = {
        p.relative_to(root).as_posix()
        for package in packages
        for p in (root / package).rglob("*.py")
        if p != root / package / "__init__.py"
    }
    missing = sorted(m for m in modules if f"`{m}`" not in text)
    assert not missing, f"docs/architecture.md does not name: {missing}"
    pattern = r"`((?:" + "|".join(packages) + r")/[\w/]+\.py)`"
    named = set(re.findall(pattern, text))
    assert not named - modules, (
        f"docs/architecture.md names modules that are not there: {sorted(named - modules)}"
    )


def _embedded(doc: str, name: str) -> str:
    text = (DOCS / doc).read_text()
    return text.split(f"<!-- access-table:{name}:begin -->\n")[1].split(
        f"<!-- access-table:{name}:end"
    )[0]


def test_the_access_tables_in_the_docs_are_the_codes() -> None:
    """docs/security.md's and docs/stations.md's access tables are generated from the
    access-control code (the hand-written one left out `<ns>/static`, which sims publish)."""
    from haptic_local_model.shared.net.security import access_control, access_table
    from haptic_local_model.shared.net.stations import access_control as router_access
    from haptic_local_model.shared.net.stations import load_station_network

    haptic = access_table(access_control("<ns>", ("sim",), ("monitor",)), "<ns>")
    assert _embedded("security.md", "haptic") == haptic
    assert "`<ns>/static`" in haptic
    net = load_station_network("stations_three_hosts", "router")
    router = access_table(router_access(net, sorted(net.stations)), net.namespace)
    assert _embedded("stations.md", "router") == router

"""Mutual TLS as docs/security.md describes it: the doc's commands make the certificates, the
doc's network config (paths moved to a temporary folder) carries the sim's updates, and peers
with a certificate from another CA, or without the sim's password, are refused."""

from __future__ import annotations

import dataclasses
import re
import shutil
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest
from conftest import free_port

from haptic_local_model.shared.config import CONFIG_ROOT
from haptic_local_model.shared.net.config import EndpointSpec, load_network
from haptic_local_model.shared.net.transport import keys, open_session

DOC = CONFIG_ROOT.parent / "docs/security.md"
UPDATES = 20
PUBLISH_PERIOD_S = 0.05
SETTLE_S = 0.5  # the last samples cross the link
OPENSSL_TIMEOUT_S = 60.0


def doc_block(marker: str, lang: str) -> str:
    """The first ```lang block after the HTML comment `<!-- marker` in docs/security.md."""
    text = DOC.read_text()
    found = re.search(rf"<!-- {marker}.*?```{lang}\n(.*?)```", text, re.S)
    assert found, f"no {lang} block after '{marker}' in {DOC}"
    return found.group(1)


def publish(sender: Any, key: str, payload: bytes) -> None:
    pub = sender.declare_publisher(key)
    for _ in range(UPDATES):
        pub.put(payload)
        time.sleep(PUBLISH_PERIOD_S)
    time.sleep(SETTLE_S)
    pub.undeclare()


@pytest.mark.processes
def test_mutual_tls_from_the_docs(tmp_path: Path) -> None:
    if shutil.which("openssl") is None:
        pytest.skip("openssl not installed")
    tls = tmp_path / "tls"
    rogue = tmp_path / "rogue"  # the same commands, another CA
    for folder in (tls, rogue):
        folder.mkdir()
        subprocess.run(
            ["bash", "-euc", doc_block("tls-certificates", "sh")],
            cwd=folder, check=True, capture_output=True, timeout=OPENSSL_TIMEOUT_S,
        )  # fmt: skip
    credentials = CONFIG_ROOT / "credentials"
    shutil.copy(credentials / "example_users.txt", tmp_path / "users.txt")
    shutil.copy(credentials / "example_sim.password", tmp_path / "sim.password")
    port = free_port()
    config = doc_block("tls-config", "toml").replace("/etc/haptic/", f"{tmp_path}/")
    config = config.replace("127.0.0.1:7447", f"127.0.0.1:{port}")
    path = tmp_path / "tls.toml"
    path.write_text(config)
    network = load_network(str(path))
    key = keys(network.namespace).update

    def sim_like(**changes: Any) -> EndpointSpec:
        spec = network.sim
        tls_json = spec.zenoh["transport/link/tls"].replace(f"{tls}/sim.", f"{rogue}/sim.")
        assert tls_json.count(str(rogue)) == 2  # the sim's key and certificate, not the CA
        if changes.pop("rogue_certificate", False):
            spec = dataclasses.replace(spec, zenoh={"transport/link/tls": tls_json})
        return dataclasses.replace(spec, **changes)

    listener = open_session(network.haptic, None, network.namespace)
    got: list[bytes] = []
    listener.declare_subscriber(key, lambda sample: got.append(sample.payload.to_bytes()))
    cases = {
        "sim": network.sim,
        "certificate from another CA": sim_like(rogue_certificate=True),
        "no password": sim_like(user="", password_file=""),
    }
    try:
        for name, spec in cases.items():
            sender = open_session(spec, None, network.namespace)
            publish(sender, key, name.encode())
            sender.close()
    finally:
        listener.close()
    counts = {name: got.count(name.encode()) for name in cases}
    assert counts == {"sim": UPDATES, "certificate from another CA": 0, "no password": 0}

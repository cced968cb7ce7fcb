"""Zenoh authentication and access control from a network config's endpoint (docs/security.md).

Username/password (`usrpwd`) authenticates the connecting peer to the listener at the
handshake: the listener (the haptic server) holds the `user:password` lines of the peers it
accepts, a connecting peer (the sim) presents its own user and password. Access control on the
listener then allows, by user name and key expression, only what the protocol needs and denies
the rest: a sim user may publish local models, pointer inputs (`haptic-pointer` connects as
the sim does) and a scene's static description, and follow the proxy; an observer may only
follow the proxy.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # annotations only: the config module imports this one
    from haptic_local_model.shared.net.config import EndpointSpec


def read_password(path: str) -> str:
    """The password in a password file: its first line, without the line end."""
    lines = Path(path).read_text().splitlines()
    if not lines or not lines[0]:
        raise ValueError(f"{path}: empty password file")
    return lines[0]


def access_control(namespace: str, sim_users: tuple[str, ...], observers: tuple[str, ...]) -> Any:
    """The listener's access-control table: default deny, then the protocol's flows only.

    The listener's own `declare_subscriber` must be allowed on egress too, or the sim never
    learns that anyone subscribes and publishes nothing (STACK-NOTES).
    """
    update, proxy = f"{namespace}/local_model", f"{namespace}/proxy"
    pointer = f"{namespace}/input/pointer"
    static = f"{namespace}/static"
    alive = f"{namespace}/alive/sim/*"
    view = f"{namespace}/view/world"
    rules = [
        {"id": "put_update_in", "messages": ["put"], "flows": ["ingress"],
         "permission": "allow", "key_exprs": [update]},
        {"id": "announce_update_sub", "messages": ["declare_subscriber"], "flows": ["egress"],
         "permission": "allow", "key_exprs": [update]},
        {"id": "follow_proxy_in", "messages": ["declare_subscriber"], "flows": ["ingress"],
         "permission": "allow", "key_exprs": [proxy]},
        {"id": "put_proxy_out", "messages": ["put"], "flows": ["egress"],
         "permission": "allow", "key_exprs": [proxy]},
        {"id": "put_pointer_in", "messages": ["put"], "flows": ["ingress"],
         "permission": "allow", "key_exprs": [pointer]},
        {"id": "announce_pointer_sub", "messages": ["declare_subscriber"], "flows": ["egress"],
         "permission": "allow", "key_exprs": [pointer]},
        {"id": "put_static_in", "messages": ["put"], "flows": ["ingress"],
         "permission": "allow", "key_exprs": [static]},
        {"id": "announce_static_sub", "messages": ["declare_subscriber"], "flows": ["egress"],
         "permission": "allow", "key_exprs": [static]},
        {"id": "put_view_in", "messages": ["put"], "flows": ["ingress"],
         "permission": "allow", "key_exprs": [view]},
        {"id": "announce_view_sub", "messages": ["declare_subscriber"], "flows": ["egress"],
         "permission": "allow", "key_exprs": [view]},
        {"id": "sim_alive_in", "messages": ["liveliness_token"], "flows": ["ingress"],
         "permission": "allow", "key_exprs": [alive]},
        {"id": "follow_sims_alive", "messages": ["declare_liveliness_subscriber",
                                                 "liveliness_query"], "flows": ["egress"],
         "permission": "allow", "key_exprs": [alive]},
    ]  # fmt: skip
    subjects = [{"id": "sims", "usernames": list(sim_users)}]
    policies = [
        {"id": "sims_drive", "subjects": ["sims"],
         "rules": ["put_update_in", "announce_update_sub", "follow_proxy_in", "put_proxy_out",
                   "put_pointer_in", "announce_pointer_sub", "put_static_in",
                   "announce_static_sub", "put_view_in", "announce_view_sub", "sim_alive_in",
                   "follow_sims_alive"]},
    ]  # fmt: skip
    if observers:
        subjects.append({"id": "observers", "usernames": list(observers)})
        policies.append(
            {"id": "observers_follow", "subjects": ["observers"],
             "rules": ["follow_proxy_in", "put_proxy_out"]}
        )  # fmt: skip
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


#: how an access-control rule reads from the subject's side: (message, flow) -> the column
ACCESS_COLUMNS = {
    ("put", "ingress"): "publishes",
    ("liveliness_token", "ingress"): "declares alive",
    ("declare_subscriber", "ingress"): "subscribes to",
    ("put", "egress"): "receives",
    ("declare_subscriber", "egress"): "is told of subscribers to",
    ("declare_liveliness_subscriber", "egress"): "is told of subscribers to",
    ("liveliness_query", "egress"): "is asked for its tokens on",
}


def access_table(acl: dict[str, Any], namespace: str) -> str:
    """A Zenoh access-control table as the markdown docs/security.md and docs/stations.md
    embed: one row per subject, what it may do by key (`namespace` shown as `<ns>`); with
    default deny, nothing else. Generated, so the docs cannot drift from the code."""
    rules = {r["id"]: r for r in acl["rules"]}
    users = {sub["id"]: sub["usernames"] for sub in acl["subjects"]}
    every = list(dict.fromkeys(ACCESS_COLUMNS.values()))
    rows = []
    for policy in acl["policies"]:
        cells: dict[str, list[str]] = {h: [] for h in every}
        for rule_id in policy["rules"]:
            rule = rules[rule_id]
            for message in rule["messages"]:
                for flow in rule["flows"]:
                    keys = [k.replace(namespace, "<ns>", 1) for k in rule["key_exprs"]]
                    cells[ACCESS_COLUMNS[(message, flow)]] += [f"`{k}`" for k in keys]
        who = ", ".join(f"`{u}`" for s in policy["subjects"] for u in users[s])
        rows.append((f"{policy['id']} ({who})", cells))
    heads = [h for h in every if any(cells[h] for _, cells in rows)]  # the columns in use
    lines = ["| subject (users) | " + " | ".join(heads) + " |", "|---" * (len(heads) + 1) + "|"]
    for who, cells in rows:
        row = [", ".join(dict.fromkeys(cells[h])) or "-" for h in heads]
        lines.append(f"| {who} | " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def zenoh_keys(endpoints: EndpointSpec, namespace: str | None) -> dict[str, str]:
    """Zenoh config path -> JSON5 value for the endpoint's credentials, access control, its
    transport and extra `zenoh` keys."""
    out: dict[str, str] = {}
    if endpoints.user:
        out["transport/auth/usrpwd/user"] = json.dumps(endpoints.user)
        out["transport/auth/usrpwd/password"] = json.dumps(read_password(endpoints.password_file))
    if endpoints.users_file:
        out["transport/auth/usrpwd/dictionary_file"] = json.dumps(endpoints.users_file)
    if endpoints.sim_users:
        if namespace is None:
            raise ValueError("access control needs the key-expression namespace")
        acl = access_control(namespace, endpoints.sim_users, endpoints.observer_users)
        out["access_control"] = json.dumps(acl)
    # larger messages are dropped on ingress before delivery: Zenoh's low-pass filter (its
    # defragmentation cap, transport/link/rx/max_message_size, did not drop a 2 MB message
    # in eclipse-zenoh 1.10 here, fragmented or not; both are set)
    limit = endpoints.max_message_bytes
    out["low_pass_filter"] = json.dumps(
        [{"id": "max_message_bytes", "flows": ["ingress"], "key_exprs": ["**"],
          "messages": ["put", "delete", "query", "reply"], "size_limit": limit}]
    )  # fmt: skip
    out["transport/link/rx/max_message_size"] = str(limit)
    # no shared-memory transport (on by default: on one host a message over 3 KB goes through
    # the sender's 16 MB pool, which the receiver maps). The haptic server's I/O process kept
    # every sim's pool mapped and resident, a killed one's too: 17 MB more for each sim
    # started (god_crowd's 17 KB updates; smaller ones never used it)
    out["transport/shared_memory/enabled"] = "false"
    if endpoints.low_latency:  # Zenoh refuses lowlatency with QoS on
        out["transport/unicast/lowlatency"] = "true"
        out["transport/unicast/qos/enabled"] = "false"
    out.update(endpoints.zenoh)
    return out

"""Zenoh settings of a secured swarm, and the one-line errors of a refused session.

A secured swarm (``--secrets DIR``, written by ``swarm keys init``) has one Zenoh router, the only
listener, and every other process is its client. Every link is TLS with a certificate on both
ends (mTLS: the router checks the client's certificate against the swarm's CA, the client the
router's) and user/password authentication (``transport/auth/usrpwd``); the router applies the
swarm's access control (``access_control``: deny by default, each role's rights by its
certificate's common name and its user name, ``protocols.secrets.swarm_secrets.RIGHTS``). A message
a role has no right to send is dropped by the router: its subscribers and queryables never see it.

Zenoh says only "unable to connect" when the router refuses a credential; :func:`open_error`
tells a refused credential (the router's TCP port answers) from an unreachable router.
"""

from __future__ import annotations

import json
import socket
from typing import Any

from protocols.secrets.swarm_secrets import RoleSecrets, SecretsError, load_role

#: Default router port (Zenoh's usual one).
ROUTER_PORT = 7447
#: Where agents find each other without a router: the ground station (or the first agent) listens
#: on tcp/127.0.0.1:RENDEZVOUS_PORT and the others connect to it (peer mode).
RENDEZVOUS_PORT = 7447
#: How long the ground station and agents wait for their router (ms): hosts start in any order.
ROUTER_WAIT_MS = 120_000
#: Link lease between a router and its clients (ms): a link silent that long is closed and the
#: client's liveliness tokens vanish. Longer than a peer's on loopback (1 s): links cross hosts,
#: and a starved process must not drop half the swarm (a killed one's still vanish at once).
ROUTER_LEASE_MS = 3000


def secure(conf: Any, secrets: RoleSecrets, mode: str) -> None:
    """Add TLS (mTLS), user/password and (router) access control of ``secrets`` to ``conf`` (a
    ``zenoh.Config``)."""

    def put(key: str, value: object) -> None:
        conf.insert_json5(key, json.dumps(value))

    tls = "transport/link/tls"
    put(f"{tls}/root_ca_certificate", str(secrets.ca))
    put(f"{tls}/enable_mtls", True)
    side = "listen" if mode != "client" else "connect"
    put(f"{tls}/{side}_certificate", str(secrets.certificate))
    put(f"{tls}/{side}_private_key", str(secrets.private_key))
    if mode == "router":
        put("transport/auth/usrpwd/dictionary_file", str(secrets.users))
        put("access_control", secrets.access_control())
    else:
        put("transport/auth/usrpwd/user", secrets.role)
        put("transport/auth/usrpwd/password", secrets.password())


def secured_endpoint(endpoint: str) -> str:
    """``tcp/HOST:PORT`` as ``tls/HOST:PORT`` (a secured swarm speaks TLS only)."""
    return "tls/" + endpoint[4:] if endpoint.startswith("tcp/") else endpoint


def role_secrets(folder: object, role: str, swarm_id: str | None = None) -> RoleSecrets | None:
    """``role``'s secrets in ``folder`` (None when no folder is given); ValueError (one line)
    when the folder lacks them or they are another swarm's than ``swarm_id`` (the router's
    access control covers that swarm's keys only: everything else would be dropped)."""
    if folder is None:
        return None
    try:
        secrets = load_role(str(folder), role)
    except SecretsError as exc:
        raise ValueError(str(exc)) from None
    if swarm_id is not None and secrets.swarm_id != swarm_id:
        raise ValueError(
            f"the secrets in {folder} belong to swarm {secrets.swarm_id!r}, not {swarm_id!r}: give "
            f"--swarm-id {secrets.swarm_id} (or make secrets with swarm keys init --swarm-id)"
        )
    return secrets


def answers(endpoint: str) -> bool:
    """Whether something accepts TCP connections at ``proto/HOST:PORT``."""
    _, _, address = endpoint.partition("/")
    host, _, port = address.rpartition(":")
    if not port.isdigit():
        return False
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=1.0):
            return True
    except OSError:
        return False


def open_error(endpoint: str, secrets: RoleSecrets | None) -> str:
    """One line on why a client session to ``endpoint`` did not open."""
    if not answers(endpoint):
        return f"nothing reachable at {endpoint}"
    if secrets is None:
        return (
            f"{endpoint} answers but refused the session: a secured swarm needs --secrets DIR "
            "(TLS certificate and user/password of a role)"
        )
    why = certificate_problem(secrets) or "certificate not signed by its CA, or wrong user/password"
    return (
        f"the router at {endpoint} refused the {secrets.role!r} credential of {secrets.folder} "
        f"({why})"
    )


def certificate_problem(secrets: RoleSecrets) -> str | None:
    """What is wrong with the role's certificate file on its own (expired, not yet valid,
    unreadable), as a reason; None if nothing is."""
    import datetime

    from cryptography import x509

    try:
        cert = x509.load_pem_x509_certificate(secrets.certificate.read_bytes())
    except (OSError, ValueError) as exc:
        return f"its certificate {secrets.certificate} cannot be read: {exc}"
    now = datetime.datetime.now(datetime.UTC)
    if cert.not_valid_after_utc < now:
        return (
            f"its certificate expired on {cert.not_valid_after_utc:%Y-%m-%d %H:%M} UTC: make new "
            "secrets with swarm keys init"
        )
    if cert.not_valid_before_utc > now:
        return f"its certificate is valid only from {cert.not_valid_before_utc:%Y-%m-%d %H:%M} UTC"
    return None


def describe(secrets: RoleSecrets | None) -> str:
    """How a session is protected, for status lines."""
    if secrets is None:
        return "open (no TLS, no authentication, no access control)"
    return (
        f"secured (TLS with client certificates, user/password, access control; "
        f"role {secrets.role}, swarm {secrets.swarm_id})"
    )

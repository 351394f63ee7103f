"""A swarm's secrets: what ``swarm keys init DIR`` writes and every ``--secrets DIR`` reads.

=====================  ==========================================================================
``swarm.json``         version, swarm id, roles, the router's host names (no secret in it)
``mavlink.key``        MAVLink 2 signing key (64 hex characters)
``ca.pem``             the swarm's certificate authority (``ca.key``: its private key, kept to
                       issue more certificates; copy it to no other host)
``<role>.pem/.key``    one TLS certificate and private key per role, common name = the role
``<role>.password``    the role's Zenoh user/password credential (user = the role)
``users.txt``          the router's dictionary of every role's ``user:password``
``access.json``        the router's Zenoh ``access_control`` block (:func:`access_control`)
=====================  ==========================================================================

Roles: ``router`` (the Zenoh router: the one TLS listener), ``gcs`` (ground station),
``operator`` (operator commands and drills), ``agent`` (drone agents), ``sim`` (the simulator:
MAVLink only, no Zenoh right at all). Every file is written with permissions 0600 in a 0700
folder, and nothing here ever prints or logs a secret: errors name
files, never contents.

What each role may *send* (the router checks every message arriving from a client; denied by
default) is :data:`RIGHTS`: agents publish consensus, status, lockstep round markers and
liveliness of their swarm and read the plan and drills; only the operator queries ``command`` and
publishes ``fault``; only the ground station publishes and serves the plan and answers commands.
What the router forwards *to* an authenticated client is not restricted (egress within the
swarm's keys).

Pure apart from file I/O: no Zenoh import (``protocols.bus.zenoh_config`` turns this into a Zenoh
configuration).
"""

from __future__ import annotations

import datetime
import ipaddress
import json
import os
import secrets
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from protocols.wire.keys import ROOT, validate_swarm_id

VERSION = 1
ROLES = ("router", "gcs", "operator", "agent", "sim")
#: Roles that open Zenoh sessions as clients of the router.
CLIENT_ROLES = ("gcs", "operator", "agent")
MANIFEST = "swarm.json"
CERT_DAYS = 3650

#: Message kinds of Zenoh's access control (zenoh 1.10).
PUT, SUB, QUERY, QUERYABLE, REPLY = (
    "put",
    "declare_subscriber",
    "query",
    "declare_queryable",
    "reply",
)
TOKEN, LIVE_SUB, LIVE_QUERY = (
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
)
ALL_MESSAGES = (PUT, "delete", SUB, QUERY, QUERYABLE, REPLY, TOKEN, LIVE_SUB, LIVE_QUERY)

#: role -> (message kind, key suffixes under ``swarm/<sid>/``) the role may send to the router.
RIGHTS: dict[str, tuple[tuple[str, tuple[str, ...]], ...]] = {
    "agent": (
        (PUT, ("consensus/**", "status/*", "round/*")),
        (TOKEN, ("alive/*",)),
        (SUB, ("consensus/**", "plan", "fault", "round/*")),
        (LIVE_SUB, ("alive/*",)),
        (LIVE_QUERY, ("alive/*",)),
        (QUERY, ("plan",)),
    ),
    "gcs": (
        (PUT, ("plan",)),
        (QUERYABLE, ("plan", "command")),
        (REPLY, ("plan", "command")),
        (SUB, ("status/*", "plan", "fault")),
        (LIVE_SUB, ("alive/*",)),
        (LIVE_QUERY, ("alive/*",)),
        (QUERY, ("plan",)),
    ),
    "operator": (
        (QUERY, ("command",)),
        (PUT, ("fault",)),
    ),
    "sim": (),  # MAVLink only
    "router": (),
}

#: What a refusal says each right is, for one-line errors.
RIGHT_NAMES = {
    ("operator", "command"): "send operator commands and drills (swarm land, swarm drill ...)",
    ("gcs", "plan"): "publish the plan",
}


class SecretsError(ValueError):
    """A secrets folder is missing, incomplete or unreadable: one line naming the file."""


@dataclass(frozen=True)
class RoleSecrets:
    """The files one process needs to join a secured swarm as ``role`` (paths, never contents
    in its repr)."""

    folder: Path
    role: str
    swarm_id: str

    @property
    def ca(self) -> Path:
        return self.folder / "ca.pem"

    @property
    def certificate(self) -> Path:
        return self.folder / f"{self.role}.pem"

    @property
    def private_key(self) -> Path:
        return self.folder / f"{self.role}.key"

    @property
    def password_file(self) -> Path:
        return self.folder / f"{self.role}.password"

    @property
    def users(self) -> Path:
        return self.folder / "users.txt"

    @property
    def access(self) -> Path:
        return self.folder / "access.json"

    @property
    def mavlink_key(self) -> Path:
        return self.folder / "mavlink.key"

    def password(self) -> str:
        """The role's Zenoh password (read from its file, 0600)."""
        return _read(self.password_file).strip()

    def access_control(self) -> dict[str, object]:
        """The router's access-control block."""
        try:
            data = json.loads(_read(self.access))
        except json.JSONDecodeError as exc:
            raise SecretsError(f"{self.access}: not valid JSON (line {exc.lineno})") from None
        if not isinstance(data, dict):
            raise SecretsError(f"{self.access}: not an access_control object")
        return data


def _read(path: Path) -> str:
    try:
        return path.read_text()
    except OSError as exc:
        raise SecretsError(f"{path}: cannot read ({exc.strerror or exc})") from None


def load_role(folder: str | Path, role: str) -> RoleSecrets:
    """The secrets of ``role`` in ``folder``; SecretsError naming the first missing file."""
    if role not in ROLES:
        raise SecretsError(f"unknown role {role!r}: one of {', '.join(ROLES)}")
    path = Path(folder)
    manifest = path / MANIFEST
    if not manifest.is_file():
        raise SecretsError(f"{path} is not a swarm secrets folder (no {MANIFEST}: swarm keys init)")
    try:
        meta = json.loads(manifest.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise SecretsError(f"{manifest}: unreadable ({exc})") from None
    if meta.get("version") != VERSION:
        raise SecretsError(f"{manifest}: version {meta.get('version')!r}, expected {VERSION}")
    out = RoleSecrets(path, role, str(meta.get("swarm_id")))
    needed = [out.ca, out.certificate, out.private_key]
    needed += [out.users, out.access] if role == "router" else []
    needed += [out.password_file] if role in CLIENT_ROLES else []
    for f in needed:
        if not f.is_file():
            raise SecretsError(f"{f}: missing: the {role} credential is not in {path}")
    return out


def access_control(swarm_id: str) -> dict[str, object]:
    """Zenoh's ``access_control`` block for ``swarm_id``: deny by default; per role the rights of
    :data:`RIGHTS` on ingress (subjects by certificate common name *and* user name: both the
    certificate and the password of a role are needed); egress of the swarm's keys to every
    role's subject."""
    validate_swarm_id(swarm_id)
    prefix = f"{ROOT}/{swarm_id}"
    rules: list[dict[str, object]] = [
        {
            "id": "receive",
            "permission": "allow",
            "flows": ["egress"],
            "messages": list(ALL_MESSAGES),
            "key_exprs": [f"{prefix}/**"],
        }
    ]
    subjects, policies = [], []
    for role in CLIENT_ROLES:
        ids = ["receive"]
        for kind, suffixes in RIGHTS[role]:
            rule_id = f"{role}-{kind}"
            ids.append(rule_id)
            rules.append(
                {
                    "id": rule_id,
                    "permission": "allow",
                    "flows": ["ingress"],
                    "messages": [kind],
                    "key_exprs": [f"{prefix}/{s}" for s in suffixes],
                }
            )
        subjects.append({"id": role, "cert_common_names": [role], "usernames": [role]})
        policies.append({"id": f"{role}-policy", "rules": ids, "subjects": [role]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def may(role: str, kind: str, suffix: str) -> bool:
    """Whether ``role`` may send message ``kind`` on ``swarm/<sid>/<suffix>`` (exact suffixes
    of :data:`RIGHTS`, or a ``/*`` / ``/**`` one covering it)."""
    for k, suffixes in RIGHTS.get(role, ()):
        if k != kind:
            continue
        for s in suffixes:
            if s == suffix or (s.endswith("/**") and suffix.startswith(s[:-2])):
                return True
            if s.endswith("/*") and suffix.startswith(s[:-1]) and "/" not in suffix[len(s) - 1 :]:
                return True
    return False


# -- writing ------------------------------------------------------------------------------------
def _write_secret(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` created with 0600 (never world-readable, even for a moment)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.fchmod(fd, 0o600)
        os.write(fd, data)
    finally:
        os.close(fd)


def init_secrets(
    folder: str | Path, swarm_id: str = "swarm", hosts: Sequence[str] = (), force: bool = False
) -> list[Path]:
    """Create a swarm's secrets in ``folder`` (created 0700); returns the files written.

    ``hosts``: names or IP addresses clients use to reach the router (its certificate's subject
    alternative names; ``localhost`` and ``127.0.0.1`` are always in). SecretsError if the folder
    already holds secrets and not ``force``."""
    validate_swarm_id(swarm_id)
    path = Path(folder)
    if (path / MANIFEST).exists() and not force:
        raise SecretsError(f"{path} already holds swarm secrets (--force replaces them)")
    try:
        path.mkdir(parents=True, exist_ok=True, mode=0o700)
        os.chmod(path, 0o700)
    except OSError as exc:
        raise SecretsError(f"cannot create {path}: {exc.strerror or exc}") from None
    names = ["localhost", "127.0.0.1", *[h for h in hosts if h not in ("localhost", "127.0.0.1")]]
    written: list[Path] = []

    def put(name: str, data: bytes) -> None:
        _write_secret(path / name, data)
        written.append(path / name)

    put("mavlink.key", secrets.token_hex(32).encode() + b"\n")
    ca_key, ca_cert = _ca(swarm_id)
    put("ca.key", _key_pem(ca_key))
    put("ca.pem", _cert_pem(ca_cert))
    users = []
    for role in ROLES:
        key, cert = _issue(ca_key, ca_cert, role, names if role == "router" else [])
        put(f"{role}.key", _key_pem(key))
        put(f"{role}.pem", _cert_pem(cert))
        if role in CLIENT_ROLES:
            password = secrets.token_urlsafe(24)
            put(f"{role}.password", password.encode() + b"\n")
            users.append(f"{role}:{password}")
    put("users.txt", ("\n".join(users) + "\n").encode())
    put("access.json", (json.dumps(access_control(swarm_id), indent=2) + "\n").encode())
    manifest = {"version": VERSION, "swarm_id": swarm_id, "roles": list(ROLES), "hosts": names}
    put(MANIFEST, (json.dumps(manifest, indent=2) + "\n").encode())
    return written


def _ca(swarm_id: str) -> tuple[object, object]:
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"quadswarm {swarm_id} CA")])
    now = datetime.datetime.now(datetime.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=CERT_DAYS))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=True,
                crl_sign=True,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .sign(key, hashes.SHA256())
    )
    return key, cert


def _issue(
    ca_key: object,
    ca_cert: object,
    role: str,
    hosts: Iterable[str],
    valid: tuple[datetime.datetime, datetime.datetime] | None = None,
) -> tuple[object, object]:
    """A key and a certificate for ``role`` (common name = role) signed by the CA; ``hosts`` as
    DNS / IP subject alternative names (the router's); ``valid``: from, until (default: from 5
    minutes ago for CERT_DAYS)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    sans: list[x509.GeneralName] = [x509.DNSName(role)]
    for h in hosts:
        try:
            sans.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            sans.append(x509.DNSName(h))
    now = datetime.datetime.now(datetime.UTC)
    since, until = valid or (
        now - datetime.timedelta(minutes=5),
        now + datetime.timedelta(days=CERT_DAYS),
    )
    cert = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, role)]))
        .issuer_name(ca_cert.subject)  # type: ignore[attr-defined]
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(since)
        .not_valid_after(until)
        .add_extension(x509.SubjectAlternativeName(sans), critical=False)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(
            x509.ExtendedKeyUsage(
                [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
            ),
            critical=False,
        )
        .sign(ca_key, hashes.SHA256())  # type: ignore[arg-type]
    )
    return key, cert


def _key_pem(key: object) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return key.private_bytes(  # type: ignore[attr-defined]
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )


def _cert_pem(cert: object) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return cert.public_bytes(serialization.Encoding.PEM)  # type: ignore[attr-defined]

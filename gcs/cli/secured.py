"""``--secrets DIR`` and ``--role`` for the commands that join a swarm's Zenoh network (the
one-line refusal when a credential lacks a right is :func:`gcs.api.link.refusal`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from protocols.secrets.swarm_secrets import ROLES

if TYPE_CHECKING:
    from protocols.secrets.swarm_secrets import RoleSecrets


def add_secrets_flags(p: argparse.ArgumentParser, role: str) -> None:
    """``--secrets DIR`` (credentials of ``swarm keys init``) and ``--role`` (default ``role``)."""
    p.add_argument(
        "--secrets",
        type=Path,
        metavar="DIR",
        help="the swarm's secrets (swarm keys init): TLS with a client certificate, "
        f"user/password and access control; tcp/ endpoints become tls/ (role {role})",
    )
    p.add_argument(
        "--role",
        choices=ROLES,
        default=role,
        help="which credential of --secrets to use (default %(default)s)",
    )


def secrets_of(args: argparse.Namespace) -> RoleSecrets | None:
    """The role's secrets of ``--secrets`` (None without it); ValueError: one line."""
    from protocols.bus.zenoh_config import role_secrets

    return role_secrets(
        getattr(args, "secrets", None), getattr(args, "role", "operator"), args.swarm_id
    )

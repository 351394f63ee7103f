"""``swarm keys init DIR``: create a swarm's secrets (protocols/secrets/swarm_secrets.py)."""

from __future__ import annotations

import argparse
from pathlib import Path

from protocols.secrets.swarm_secrets import CLIENT_ROLES, SecretsError, init_secrets


class KeysError(Exception):
    """A user mistake: one line, exit code 2."""


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``swarm keys init``."""
    p = sub.add_parser(
        "keys",
        help="a swarm's secrets: MAVLink signing key, TLS certificates, Zenoh credentials",
        description="Create and manage a swarm's secrets.",
    )
    keys = p.add_subparsers(dest="keys_command", metavar="ACTION", required=True)
    init = keys.add_parser(
        "init",
        help="create a swarm's secrets in DIR (files 0600, folder 0700)",
        description=(
            "Create in DIR: a MAVLink 2 signing key, a certificate authority, a TLS certificate "
            "and key per role (router, gcs, operator, agent, sim), a Zenoh user/password per "
            "client role and the router's access control (agents: consensus, status and "
            "liveliness of the swarm, read the plan; the operator alone sends commands and "
            "drills; the ground station alone publishes the plan). Give each host only the files "
            "of its role (plus ca.pem, swarm.json and mavlink.key); keep ca.key offline."
        ),
    )
    init.add_argument("dir", type=Path, metavar="DIR")
    init.add_argument("--swarm-id", default="swarm", help="swarm name on Zenoh (default swarm)")
    init.add_argument(
        "--router-host",
        action="append",
        default=[],
        metavar="HOST",
        help="a name or IP address clients use to reach the router (repeatable; localhost and "
        "127.0.0.1 are always in its certificate)",
    )
    init.add_argument("--force", action="store_true", help="replace existing secrets")


def run(args: argparse.Namespace) -> int:
    """``swarm keys init``: prints what it wrote (file names only, never contents)."""
    try:
        files = init_secrets(args.dir, args.swarm_id, args.router_host, args.force)
    except (SecretsError, ValueError) as exc:
        raise KeysError(str(exc)) from None
    print(
        f"swarm keys: wrote {len(files)} files (mode 0600) for swarm {args.swarm_id!r} in "
        f"{args.dir}: {', '.join(f.name for f in files)}"
    )
    print(
        f"swarm keys: client roles {', '.join(CLIENT_ROLES)}; give --secrets {args.dir} to "
        "swarm router, gcs, agent, sim, up and the operator commands"
    )
    return 0

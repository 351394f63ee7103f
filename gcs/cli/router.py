"""``swarm router``: the swarm's Zenoh router, for swarms spread over several hosts.

Zenoh's own router (a session in router mode through the Python binding; no relay of ours) listens
on the given endpoints; the ground station, the agents, operator commands and drills join it as
clients (``--zenoh-mode client --zenoh-connect ENDPOINT``, or ``swarm up --router ENDPOINT``).
With ``--secrets DIR`` it listens on TLS only, requires a client certificate signed by the swarm's
CA and a user/password, and applies the swarm's access control (``access.json``).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

from protocols.bus.zenoh_config import (
    ROUTER_LEASE_MS,
    ROUTER_PORT,
    describe,
    role_secrets,
    secured_endpoint,
)


class RouterError(Exception):
    """A user mistake or a router that cannot start: one line, exit code 2."""


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``swarm router``."""
    p = sub.add_parser(
        "router",
        help="run the swarm's Zenoh router (multi-host swarms; secured with --secrets)",
        description=(
            "Run a Zenoh router that every process of the swarm joins as a client: the ground "
            "station, agents on companion computers, operator commands and drills. With "
            "--secrets DIR (swarm keys init) it speaks TLS only, checks every client's "
            "certificate and user/password, and enforces the swarm's access control."
        ),
    )
    p.add_argument(
        "--listen",
        nargs="+",
        default=[f"tcp/0.0.0.0:{ROUTER_PORT}"],
        metavar="ENDPOINT",
        help=f"endpoints to listen on (default tcp/0.0.0.0:{ROUTER_PORT}; with --secrets tcp/ "
        "becomes tls/)",
    )
    p.add_argument("--secrets", type=Path, metavar="DIR", help="the swarm's secrets folder")
    p.add_argument(
        "--lease-ms",
        type=int,
        default=ROUTER_LEASE_MS,
        help="link lease, ms: a client silent that long is dropped (default %(default)s)",
    )


def run(args: argparse.Namespace, stop: threading.Event | None = None) -> int:
    """Run the router until SIGINT/SIGTERM (or ``stop``)."""
    import zenoh

    from protocols.bus.zenoh_bus import ZenohSettings

    stop = stop or threading.Event()
    try:
        secrets = role_secrets(args.secrets, "router")
        listen = tuple(secured_endpoint(e) if secrets else e for e in args.listen)
        settings = ZenohSettings(
            mode="router", listen=listen, connect=(), lease_ms=args.lease_ms, secrets=secrets
        )
        conf = settings.config()
    except ValueError as exc:
        raise RouterError(str(exc)) from None
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as exc:
        raise RouterError(f"cannot start the router on {', '.join(listen)}: "
                          f"{str(exc).split(' at /', 1)[0]}") from None  # fmt: skip
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda _s, _f: stop.set())
    print(
        f"swarm router: listening on {', '.join(listen)}; network {describe(secrets)}",
        file=sys.stderr,
        flush=True,
    )
    try:
        stop.wait()
    finally:
        session.close()
    print("swarm router: stopped", file=sys.stderr, flush=True)
    return 0

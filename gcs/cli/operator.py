"""Operator commands to a running ground station: ``swarm takeoff|formation|move|rotate|scale|hold|
land|status|shutdown``. Each sends one request to ``swarm/<sid>/command`` over Zenoh and prints the
answer.

The first line says how long the ground station took to answer, from the request leaving to the
reply arriving (opening the Zenoh session is not counted): ``hold: accepted (0.004 s): ...``.

Exit codes: 0 accepted, 1 refused, 2 usage error or no ground station answering within 2 s.
"""

from __future__ import annotations

import argparse
import math
import time
from typing import TYPE_CHECKING, Any

from drone_agent.agent_cli import RENDEZVOUS_PORT
from gcs.cli.secured import add_secrets_flags, refusal, secrets_of

if TYPE_CHECKING:  # numpy (the planner), imported when a command is sent, not by the parser
    from gcs.station.commands import Reply, Request
    from protocols.swarm_secrets import RoleSecrets

ANSWER_TIMEOUT_S = 2.0
OPERATOR_COMMANDS = (
    "takeoff", "formation", "move", "rotate", "scale", "hold", "land", "status", "shutdown",
)  # fmt: skip


class OperatorError(Exception):
    """Usage error or no ground station: one line, exit code 2."""


def add_operator_flags(p: argparse.ArgumentParser) -> None:
    """The flags of a command an operator sends to a running swarm (the operator commands and
    ``swarm drill``): its swarm id, where to reach it, and the operator's secrets."""
    p.add_argument("--swarm-id", default="swarm", help="swarm name on Zenoh (default %(default)s)")
    p.add_argument(
        "--zenoh-connect",
        default=f"tcp/127.0.0.1:{RENDEZVOUS_PORT}",
        metavar="ENDPOINT",
        help="where the ground station listens, or the swarm's router (default %(default)s)",
    )
    add_secrets_flags(p, "operator")


def add_parsers(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register the operator commands."""
    helps = {
        "takeoff": "climb the swarm's centre to an altitude",
        "formation": "set the formation: centre, heading, length/width/height spreads",
        "move": "move the formation by north/east/up metres",
        "rotate": "turn the formation's heading by a number of degrees",
        "scale": "scale the formation's spreads by a factor",
        "hold": "stop the formation where it can",
        "land": "land every drone",
        "status": "a table per drone: mode, armed, position, estimate error, neighbours",
        "shutdown": "end the run: land the swarm if it flies, wait until it is down (or the "
        "ground station's --shutdown-timeout-s), write the report; swarm up then stops "
        "everything",
    }
    for name in OPERATOR_COMMANDS:
        p = sub.add_parser(name, help=f"operator: {helps[name]}", description=helps[name])
        add_operator_flags(p)
        if name not in ("hold", "land", "status", "shutdown"):
            p.add_argument(
                "--duration-s", type=float, metavar="S", help="take exactly this long (s)"
            )
        if name == "takeoff":
            p.add_argument("--altitude-m", type=float, required=True, metavar="M")
        elif name == "formation":
            centre = p.add_mutually_exclusive_group()
            centre.add_argument(
                "--centre-ned-m", type=float, nargs=3, metavar=("N", "E", "D"), help="NED, m"
            )
            centre.add_argument("--centre", metavar="N,E,ALT", help="north, east, altitude up (m)")
            p.add_argument("--heading-deg", type=float, metavar="DEG")
            for axis in ("length", "width", "height"):
                p.add_argument(f"--{axis}-m", type=float, metavar="M", help=f"{axis} spread, m")
        elif name == "move":
            for axis in ("north", "east", "up"):
                p.add_argument(f"--{axis}-m", type=float, default=0.0, metavar="M")
        elif name == "rotate":
            p.add_argument("--delta-deg", type=float, required=True, metavar="DEG")
        elif name == "scale":
            p.add_argument("--factor", type=float, required=True)


def request_of(args: argparse.Namespace) -> Request:
    """The request for parsed ``args``; OperatorError for a malformed value."""
    from gcs.station.commands import Request

    out: dict[str, Any] = {}
    keys = {
        "takeoff": ("altitude_m",),
        "formation": ("heading_deg", "length_m", "width_m", "height_m"),
        "move": ("north_m", "east_m", "up_m"),
        "rotate": ("delta_deg",),
        "scale": ("factor",),
    }.get(args.command, ())
    for key in keys:
        if getattr(args, key, None) is not None:
            out[key] = getattr(args, key)
    if args.command == "formation":
        if args.centre_ned_m is not None:
            out["centre_ned_m"] = list(args.centre_ned_m)
        elif args.centre is not None:
            try:
                n, e, alt = (float(x) for x in args.centre.split(","))
            except ValueError:
                raise OperatorError("--centre must look like N,E,ALT (metres)") from None
            out["centre_ned_m"] = [n, e, -alt]
    if getattr(args, "duration_s", None) is not None:
        out["duration_s"] = args.duration_s
    for key, value in out.items():
        values = value if isinstance(value, list) else [value]
        if not all(math.isfinite(v) for v in values):
            raise OperatorError(f"--{key.replace('_', '-')} must be finite")
    return Request(args.command, out)


def send(
    swarm_id: str,
    endpoint: str,
    payload: bytes,
    timeout_s: float = ANSWER_TIMEOUT_S,
    secrets: RoleSecrets | None = None,
) -> Reply:
    """Send one request payload to the ground station; OperatorError if none answers."""
    return send_timed(swarm_id, endpoint, payload, timeout_s, secrets)[0]


def send_timed(
    swarm_id: str,
    endpoint: str,
    payload: bytes,
    timeout_s: float = ANSWER_TIMEOUT_S,
    secrets: RoleSecrets | None = None,
) -> tuple[Reply, float]:
    """As :func:`send`, with the seconds from sending the request to its reply's arrival.

    With ``secrets``: TLS and the role's credential; a role without the right to send commands
    is refused here, in one line, before anything is sent."""
    from drone_agent.zenoh_transport import open_client
    from gcs.station.commands import CommandError, decode_reply
    from protocols.keys import SwarmKeys

    denied = refusal(secrets, "query", "command", "send operator commands and drills")
    if denied is not None:
        raise OperatorError(denied)
    try:
        key = SwarmKeys(swarm_id, 1.0).command
        bus = open_client(endpoint, secrets)
    except ValueError as exc:
        raise OperatorError(str(exc)) from None
    except ConnectionError as exc:
        raise OperatorError(f"no ground station: {exc}") from None
    with bus:
        sent = time.monotonic()
        replies = bus.session.get(key, payload=payload, timeout=timeout_s)
        for reply in replies:
            if reply.ok is not None:
                elapsed = time.monotonic() - sent
                try:
                    return decode_reply(reply.ok.payload.to_bytes()), elapsed
                except CommandError as exc:
                    raise OperatorError(str(exc)) from None
    hint = "" if secrets is None else f" (or the router refused the {secrets.role!r} credential)"
    raise OperatorError(
        f"no ground station of swarm {swarm_id!r} answered within {timeout_s:g} s at {endpoint}"
        + hint
    )


def format_reply(name: str, reply: Reply, elapsed_s: float | None = None) -> list[str]:
    """The lines printed for ``reply`` (answered after ``elapsed_s`` seconds, when known)."""
    verdict = "accepted" if reply.accepted else "refused"
    took = "" if elapsed_s is None else f" ({elapsed_s:.3f} s)"
    lines = [f"{name}: {verdict}{took}: {reply.reason}"]
    if reply.table:
        lines.append(
            f"{'drone':>5} {'alive':>5} {'mode':>8} {'armed':>5} {'position NED (m)':>24} "
            f"{'est.err(m)':>10} {'nbrs':>4} {'link':>5} {'fsafe':>5} {'rx':>8} {'tx':>8} "
            f"{'dropped':>7}"
        )
        for r in reply.table:
            pos = r.get("position_ned_m")
            pos_text = "-" if pos is None else " ".join(f"{x:7.2f}" for x in pos)
            err = r.get("estimate_error_m")
            link = r.get("link_quality")
            link_text = "-" if link is None else f"{100 * link:.0f}%"
            lines.append(
                f"{r.get('drone'):>5} {('yes' if r.get('alive') else 'no'):>5} "
                f"{r.get('mode') or '-'!s:>8} {('yes' if r.get('armed') else 'no'):>5} "
                f"{pos_text:>24} {('-' if err is None else f'{err:.3f}'):>10} "
                f"{len(r.get('neighbours') or []):>4} {link_text:>5} {r.get('failsafes', 0):>5} "
                f"{r.get('rx', 0):>8} {r.get('tx', 0):>8} "
                f"{r.get('rx_dropped', 0):>7}"
            )
        for r in reply.table:
            lost = r.get("lost")
            if isinstance(lost, dict):
                t = lost.get("t_s")
                when = f" at t = {t:.1f} s" if isinstance(t, int | float) and t == t else ""
                lines.append(f"drone {r.get('drone')} lost{when}: {lost.get('reason')}")
    return lines


def run(args: argparse.Namespace) -> int:
    """Send the command of ``args``, print the answer; 0 accepted, 1 refused."""
    from gcs.station.commands import encode_request

    request = request_of(args)
    try:
        secrets = secrets_of(args)
    except ValueError as exc:
        raise OperatorError(str(exc)) from None
    reply, elapsed_s = send_timed(
        args.swarm_id, args.zenoh_connect, encode_request(request), secrets=secrets
    )
    for line in format_reply(args.command, reply, elapsed_s):
        print(line)
    if args.command == "status":
        from drone_agent.zenoh_config import describe

        print(f"network: {describe(secrets)}")
    return 0 if reply.accepted else 1

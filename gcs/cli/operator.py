"""Operator commands to a running ground station: ``swarm takeoff|formation|move|rotate|scale|hold|
land|status|shutdown``. Each is the same call of :class:`gcs.api.Swarm` a script makes: one
request to ``swarm/<sid>/command`` over Zenoh; this module parses the flags and prints the answer.

The first line says how long the ground station took to answer, from the request leaving to the
reply arriving (opening the Zenoh session is not counted): ``hold: accepted (0.004 s): ...``.

Exit codes: 0 accepted, 1 refused, 2 usage error or no ground station answering within 2 s.
"""

from __future__ import annotations

import argparse
import json
import socket
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gcs.cli.secured import add_secrets_flags
from protocols.bus.zenoh_config import RENDEZVOUS_PORT

if TYPE_CHECKING:  # numpy (the planner), imported when a command is sent, not by the parser
    from gcs.api.swarm import Swarm
    from gcs.station.commands import Reply, Request
    from protocols.secrets.swarm_secrets import RoleSecrets

ANSWER_TIMEOUT_S = 2.0
#: Where the operator's commands meet a swarm when nothing says otherwise.
DEFAULT_ENDPOINT = f"tcp/127.0.0.1:{RENDEZVOUS_PORT}"
#: The run file of a ``swarm up`` started in this folder with its default report folder.
SESSION_RUN_FILE = Path("report") / "logs" / "run.json"
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
        default=None,
        metavar="ENDPOINT",
        help="where the ground station listens, or the swarm's router (default: where the "
        f"session started in this folder meets, from {SESSION_RUN_FILE}, else {DEFAULT_ENDPOINT})",
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
    """The request for parsed ``args`` (built by :func:`gcs.api.requests.command_request`, as the
    API builds it); OperatorError for a malformed value."""
    from gcs.api.errors import UsageError
    from gcs.api.requests import command_request

    keys = {
        "takeoff": ("altitude_m", "duration_s"),
        "formation": (
            "centre_ned_m", "heading_deg", "length_m", "width_m", "height_m", "duration_s"
        ),
        "move": ("north_m", "east_m", "up_m", "duration_s"),
        "rotate": ("delta_deg", "duration_s"),
        "scale": ("factor", "duration_s"),
    }.get(args.command, ())  # fmt: skip
    kwargs: dict[str, Any] = {key: getattr(args, key, None) for key in keys}
    if args.command == "formation" and args.centre is not None:
        try:
            kwargs["centre"] = [float(x) for x in args.centre.split(",")]
        except ValueError:
            raise OperatorError("--centre must look like N,E,ALT (metres)") from None
    try:
        return command_request(args.command, **kwargs)
    except UsageError as exc:
        raise OperatorError(str(exc)) from None


def session_endpoint(folder: Path = Path()) -> str:
    """Where the operator's commands meet the swarm when ``--zenoh-connect`` is not given: the
    endpoint of the ``swarm up`` started in ``folder`` (its default report folder's run file)
    while something listens there, else the default rendezvous. ``swarm up`` moves to a free
    port when another run holds the default one: a command typed in the session's folder follows
    it there instead of reaching the other run."""
    try:
        about = json.loads((folder / SESSION_RUN_FILE).read_text())
        endpoint = str(about["zenoh"])
    except (OSError, ValueError, KeyError, TypeError):
        return DEFAULT_ENDPOINT
    if endpoint != DEFAULT_ENDPOINT and _listening(endpoint):
        return endpoint
    return DEFAULT_ENDPOINT


def _listening(endpoint: str) -> bool:
    """Whether a TCP endpoint ``tcp/HOST:PORT`` accepts connections (a run that ended left its
    run file behind: its port is closed)."""
    proto, _, where = endpoint.partition("/")
    host, _, port = where.rpartition(":")
    if proto != "tcp" or not port.isdigit():
        return False
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=0.5):
            return True
    except OSError:
        return False


def connect(args: argparse.Namespace) -> Swarm:
    """The swarm of ``args`` (``--swarm-id``, ``--zenoh-connect``, ``--secrets``, ``--role``),
    through :meth:`gcs.api.Swarm.connect`; OperatorError (one line) if it cannot be reached."""
    from gcs.api.errors import SwarmError
    from gcs.api.swarm import Swarm

    if args.zenoh_connect is None:
        args.zenoh_connect = session_endpoint()
    try:
        return Swarm.connect(
            args.zenoh_connect, args.swarm_id, getattr(args, "secrets", None),
            getattr(args, "role", "operator"),
        )  # fmt: skip
    except SwarmError as exc:
        raise OperatorError(str(exc)) from None


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
    """As :func:`send`, with the seconds from sending the request to its reply's arrival (a raw
    payload: tests send malformed ones). With ``secrets``: TLS and the role's credential; a role
    without the right to send commands is refused here, in one line, before anything is sent."""
    from gcs.api.errors import SwarmError
    from gcs.api.swarm import Swarm

    try:
        with Swarm.connect(endpoint, swarm_id, secrets) as swarm:
            return swarm.link.ask_payload(payload, timeout_s)
    except SwarmError as exc:
        raise OperatorError(str(exc)) from None


def format_reply(name: str, reply: Reply, elapsed_s: float | None = None) -> list[str]:
    """The lines printed for ``reply`` (answered after ``elapsed_s`` seconds, when known)."""
    verdict = "accepted" if reply.accepted else "refused"
    took = "" if elapsed_s is None else f" ({elapsed_s:.3f} s)"
    lines = [f"{name}: {verdict}{took}: {reply.reason}"]
    if reply.table:
        lines.append(
            f"{'drone':>5} {'alive':>5} {'mode':>8} {'armed':>5} {'position NED (m)':>24} "
            f"{'est.err(m)':>10} {'nbrs':>4} {'link':>5} {'fsafe':>5} {'rx':>8} {'tx':>8} "
            f"{'dropped':>7} {'radio':>7}"
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
                f"{r.get('rx_dropped', 0):>7} {r.get('rx_lost_radio', 0):>7}"
            )
        for r in reply.table:
            lost = r.get("lost")
            if isinstance(lost, dict):
                t = lost.get("t_s")
                when = f" at t = {t:.1f} s" if isinstance(t, int | float) and t == t else ""
                lines.append(f"drone {r.get('drone')} lost{when}: {lost.get('reason')}")
    return lines


def run(args: argparse.Namespace) -> int:
    """Send the command of ``args`` through :class:`gcs.api.Swarm`, print the answer; 0
    accepted, 1 refused."""
    from gcs.api.errors import CommandRefused, SwarmError

    request = request_of(args)
    with connect(args) as swarm:
        try:
            if args.command in ("status", "shutdown"):
                reply, elapsed_s = swarm.ask(request)
            else:
                reply, elapsed_s = swarm.send(args.command, **request.args)
        except CommandRefused as exc:
            reply, elapsed_s = exc.reply, exc.elapsed_s
        except SwarmError as exc:
            raise OperatorError(str(exc)) from None
        secrets = swarm.link.secrets
    for line in format_reply(args.command, reply, elapsed_s):
        print(line)
    if args.command == "status":
        from protocols.bus.zenoh_config import describe

        print(f"network: {describe(secrets)}")
    return 0 if reply.accepted else 1

"""``swarm gcs``: run the ground station of a scenario until SIGTERM/SIGINT or its end time.

With ``--session`` (``swarm up --drones N``): the first plan keeps the swarm on the ground, there
is no end time, and SIGINT (or ``swarm shutdown``) lands the swarm before the run ends; a second
SIGINT, or SIGTERM, ends it at once."""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

from protocols.bus.zenoh_config import RENDEZVOUS_PORT
from protocols.mavlink.conventions import DEFAULT_GCS_PORT
from protocols.mavlink.swarm_clock import EPOCH_HELP, epoch_arg

if TYPE_CHECKING:  # Zenoh: imported when the ground station runs, not by the parser
    from protocols.bus.zenoh_bus import ZenohSettings

#: Exit code of a ground station that ends for the gcs-restart drill (EX_TEMPFAIL).
RESTART_EXIT_CODE = 75
#: The line the ground station prints once its telemetry port is bound (even with --quiet):
#: ``swarm up`` starts the simulator after it, so flight.tlog holds the flight from its start.
RECORDING = "swarm gcs: recording telemetry from"


class GcsCliError(Exception):
    """A user mistake in ``swarm gcs``'s flags: one line, exit code 2."""


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``swarm gcs``."""
    p = sub.add_parser(
        "gcs",
        help="run the ground station: plan, telemetry log, operator commands, report",
        description=(
            "Publish the scenario's descriptor trajectory as the swarm's plan over Zenoh, record "
            "the simulator's GCS telemetry (UDP) into DIR/flight.tlog, follow every agent's "
            "status and liveliness, answer operator commands (swarm formation, move, ...) and, on "
            "SIGTERM/SIGINT or at the end time, write events.jsonl, metrics.json, "
            "trajectory.json and the PNG plots into DIR. By default it listens on "
            f"tcp/127.0.0.1:{RENDEZVOUS_PORT}: the agents' rendezvous."
        ),
    )
    p.add_argument("--scenario", type=Path, required=True, metavar="FILE", help="scenario (TOML)")
    p.add_argument(
        "--report", type=Path, default=Path("report"), metavar="DIR", help="report folder"
    )
    p.add_argument("--swarm-id", default="swarm", help="swarm name on Zenoh (default %(default)s)")
    p.add_argument(
        "--gcs-port",
        type=int,
        default=DEFAULT_GCS_PORT,
        metavar="PORT",
        help="UDP port on 127.0.0.1 the simulator sends telemetry to (default %(default)s)",
    )
    p.add_argument(
        "--gcs-bind",
        default="127.0.0.1",
        metavar="HOST",
        help="address the telemetry port binds to (default 127.0.0.1; 0.0.0.0 or this host's "
        "address when the simulator runs on another host)",
    )
    p.add_argument(
        "--zenoh-mode",
        choices=("peer", "client"),
        default="peer",
        help="client: join a Zenoh router (swarm router) given by --zenoh-connect",
    )
    p.add_argument(
        "--secrets",
        type=Path,
        metavar="DIR",
        help="the swarm's secrets (swarm keys init): client of the router at --zenoh-connect "
        "over TLS with the gcs credential; MAVLink commands signed with its key",
    )
    p.add_argument(
        "--zenoh-listen",
        nargs="*",
        default=None,
        metavar="ENDPOINT",
        help=f"Zenoh endpoints to listen on (default tcp/127.0.0.1:{RENDEZVOUS_PORT})",
    )
    p.add_argument(
        "--zenoh-connect", nargs="*", default=None, metavar="ENDPOINT", help="endpoints to join"
    )
    p.add_argument(
        "--duration-s",
        type=float,
        metavar="S",
        help="stop at this simulated time, s (default: the scenario's duration)",
    )
    p.add_argument(
        "--telemetry-hz",
        type=float,
        default=10.0,
        metavar="HZ",
        help="sampling rate of the report's record (the simulator's --gcs-rate-hz; default 10)",
    )
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument(
        "--no-recording",
        action="store_true",
        help="skip flight.rrd (swarm replay makes it from the tlog when it opens the report)",
    )
    p.add_argument(
        "--run-file",
        type=Path,
        metavar="FILE",
        help="the agents' process ids (written by swarm up); enables the dropout and "
        f"gcs-restart drills (gcs-restart exits with code {RESTART_EXIT_CODE} for swarm up to "
        "restart it)",
    )
    p.add_argument(
        "--signing-key",
        type=Path,
        metavar="FILE",
        help="MAVLink 2 signing key (as given to swarm sim): sign the commands sent to vehicles",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue a run after a restart: append to flight.tlog and events.jsonl and adopt "
        "the swarm's current plan",
    )
    p.add_argument(
        "--session",
        action="store_true",
        help="an operator session: the first plan keeps the swarm on the ground (GROUND) until "
        "swarm takeoff; no end time: swarm shutdown or SIGINT lands the swarm, then ends the "
        "run (a second SIGINT, or SIGTERM, ends it at once)",
    )
    p.add_argument(
        "--shutdown-timeout-s",
        type=float,
        default=120.0,
        metavar="S",
        help="how long (wall s) a shutdown waits for the swarm to land (default %(default)s)",
    )
    p.add_argument(
        "--swarm-epoch",
        type=epoch_arg,
        default=None,
        metavar="UNIX_S",
        help=EPOCH_HELP,
    )
    p.add_argument(
        "--land-at-end",
        action="store_true",
        help="at the end time, land the swarm and end the run once every vehicle is down (or "
        "after --shutdown-timeout-s), as swarm shutdown does; swarm up sets it for vehicles "
        "that outlive the run (--ardupilot-bin)",
    )
    p.add_argument("--quiet", action="store_true", help="no status line")


def _zenoh(args: argparse.Namespace) -> ZenohSettings:
    from protocols.bus.zenoh_bus import ZenohSettings

    if args.secrets is not None:
        from protocols.bus.zenoh_config import (
            ROUTER_LEASE_MS,
            ROUTER_WAIT_MS,
            role_secrets,
            secured_endpoint,
        )

        if not args.zenoh_connect:
            raise GcsCliError("--secrets needs --zenoh-connect: the swarm router's endpoint")
        try:
            return ZenohSettings(
                mode="client",
                listen=(),
                connect=tuple(secured_endpoint(e) for e in args.zenoh_connect),
                secrets=role_secrets(args.secrets, "gcs", args.swarm_id),
                connect_timeout_ms=ROUTER_WAIT_MS,
                lease_ms=ROUTER_LEASE_MS,
            )
        except ValueError as exc:
            raise GcsCliError(str(exc)) from None
    listen = args.zenoh_listen
    if listen is None:
        listen = [f"tcp/127.0.0.1:{RENDEZVOUS_PORT}"] if args.zenoh_mode == "peer" else []
    try:
        from protocols.bus.zenoh_config import ROUTER_LEASE_MS, ROUTER_WAIT_MS

        client = args.zenoh_mode == "client"
        return ZenohSettings(
            mode=args.zenoh_mode,
            listen=tuple(listen) if not client else (),
            connect=tuple(args.zenoh_connect or ()),
            connect_timeout_ms=ROUTER_WAIT_MS if client else 0,
            lease_ms=ROUTER_LEASE_MS if client else ZenohSettings.lease_ms,
        )
    except ValueError as exc:
        raise GcsCliError(str(exc)) from None


def run(args: argparse.Namespace) -> int:
    """Run the ground station; prints a status line per second on stderr unless --quiet."""
    from gcs.station.ground_station import GcsOptions, GroundStation
    from gcs.station.planner import envelope_of
    from protocols.scenario.scenario_file import ScenarioError, load_scenario
    from protocols.wire.keys import validate_swarm_id

    try:
        scenario = load_scenario(args.scenario)
        validate_swarm_id(args.swarm_id)
    except (ScenarioError, ValueError) as exc:
        raise GcsCliError(str(exc)) from None
    key = None
    key_file = args.signing_key
    if key_file is None and args.secrets is not None:
        key_file = args.secrets / "mavlink.key"
    if key_file is not None:
        from protocols.mavlink.signing import SigningKeyError, load_signing_key

        try:
            key = load_signing_key(key_file)
        except SigningKeyError as exc:
            raise GcsCliError(str(exc)) from None
    if args.duration_s is not None and not args.duration_s > 0:
        raise GcsCliError("--duration-s must be positive")
    if not 0 < args.gcs_port < 65536:
        raise GcsCliError("--gcs-port must be 1..65535")
    if not args.telemetry_hz > 0:
        raise GcsCliError("--telemetry-hz must be positive")
    if not args.shutdown_timeout_s > 0:
        raise GcsCliError("--shutdown-timeout-s must be positive")
    if args.session and args.duration_s is not None:
        raise GcsCliError("--duration-s: a session has no end time (it ends with swarm shutdown)")
    zenoh_settings = _zenoh(args)
    options = GcsOptions(
        scenario=scenario,
        report_dir=args.report,
        zenoh=zenoh_settings,
        swarm_id=args.swarm_id,
        gcs_port=args.gcs_port,
        gcs_host=args.gcs_bind,
        duration_s=args.duration_s,
        telemetry_hz=args.telemetry_hz,
        plots=not args.no_plots,
        recording=not args.no_recording,
        run_file=args.run_file,
        resume=args.resume,
        signing_key=key,
        session=args.session,
        shutdown_timeout_s=args.shutdown_timeout_s,
        swarm_epoch_s=args.swarm_epoch,
        land_at_end=args.land_at_end,
        envelope=envelope_of(scenario.safety),
        on_line=None if args.quiet else lambda line: print(line, file=sys.stderr, flush=True),
        on_recording=lambda: print(
            f"{RECORDING} udp:{args.gcs_bind}:{args.gcs_port}", file=sys.stderr, flush=True
        ),
    )
    try:
        station = GroundStation(options)
    except OSError as exc:
        raise GcsCliError(
            f"cannot bind UDP {args.gcs_bind}:{args.gcs_port}: {exc.strerror}"
        ) from None
    except Exception as exc:  # zenoh raises ZError with the reason
        from protocols.bus.zenoh_config import open_error

        reason = str(exc).split(" at /", 1)[0]
        if zenoh_settings.mode == "client":
            reason = open_error(zenoh_settings.connect[0], zenoh_settings.secrets)
        raise GcsCliError(f"cannot start the ground station: {reason}") from None

    interrupts: list[int] = []

    def stop(_sig: int, _frame: FrameType | None) -> None:
        station.stop()

    def interrupt(_sig: int, _frame: FrameType | None) -> None:
        interrupts.append(_sig)
        if args.session and len(interrupts) == 1:
            station.request_shutdown()  # land first
        else:
            station.stop()

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, interrupt)
    with station:
        files = station.run()
    if station.restart_requested:
        print("swarm gcs: stopping for a restart (gcs-restart drill)", file=sys.stderr)
        return RESTART_EXIT_CODE
    if not args.quiet:
        for f in files:
            print(f"wrote {f}", file=sys.stderr)
    return 0

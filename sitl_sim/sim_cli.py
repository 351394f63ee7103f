"""``swarm sim``: the command-line face of the SITL simulator (registered by ``gcs/cli.py``).

:func:`add_sim_parser` declares the flags (cheap: no numpy or pymavlink import);
:func:`run_sim` checks them, opens the sockets, prints a start line and one status line per
second (unless ``--quiet``) and runs until Ctrl-C, SIGTERM or ``--duration-s``; it returns the
exit code (0). User mistakes raise :class:`~sitl_sim.sim_config.SimConfigError` (one line).
"""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

from protocols.mavlink.conventions import DEFAULT_GCS_PORT, LOCKSTEP_DROP_TIMEOUT_S, MAX_VEHICLES

DESCRIPTION = (
    "Simulate N quadcopters behind real MAVLink 2 UDP endpoints, as PX4 SITL does: vehicle i "
    "(system id i+1) serves its agent on UDP BASE_PORT+i, answering whoever last sent it a valid "
    "MAVLink frame (an agent starts with a HEARTBEAT), and every vehicle's telemetry goes to "
    "the ground station. Each vehicle has the autopilot inner loop (attitude controller + mixer "
    "at the physics rate), modes HOLD/OFFBOARD/LAND, arming, the offboard-loss failsafe, "
    "parameters and failure injection. With --dialect ardupilot the vehicles speak ArduCopter's "
    "MAVLink instead (ArduCopter 4.6 SITL): modes GUIDED_NOGPS/BRAKE/LAND, an EKF and GPS that "
    "are ready --ekf-ready-s after start, GUID_OPTIONS, GUID_TIMEOUT and the GCS heartbeat "
    "failsafe, each vehicle's LOCAL_POSITION_NED about its own start and GLOBAL_POSITION_INT on "
    "the map (sitl_sim/mavlink_edge/dialect.py). "
    "Units: metres, seconds, Hz."
)
DIALECTS = ("px4", "ardupilot")  # protocols.mavlink.conventions.Dialect (not imported: cheap)


def add_sim_parser(sub: Any) -> argparse.ArgumentParser:
    """Add the ``sim`` subcommand to an argparse ``add_subparsers()`` object."""
    p = sub.add_parser(
        "sim", help="run the SITL simulator (N vehicles, MAVLink over UDP)", description=DESCRIPTION
    )
    p.add_argument(
        "--drones",
        metavar="N|LO-HI",
        help=f"N vehicles (1..{MAX_VEHICLES}) on the ground on a 2 m grid; or a range LO-HI of "
        "drone indices: serve only those (with --scenario: a shard of its swarm; drone d keeps "
        "system id d+1 and its port), so several simulators on several hosts share a swarm "
        "(realtime clock)",
    )
    p.add_argument(
        "--scenario",
        type=Path,
        metavar="FILE",
        help="scenario file: initial positions, vehicle, gains, rates, seed, crashes, home",
    )
    p.add_argument(
        "--home",
        metavar="LAT,LON,ALT",
        help="where the NED origin is on the map: WGS-84 degrees, metres above sea level "
        "(default: the scenario's [home], else PX4 SITL's 47.397742,8.545594,488)",
    )
    p.add_argument(
        "--clock",
        choices=("realtime", "lockstep"),
        default="realtime",
        help="realtime: paced to the wall clock x --speedup; lockstep: time advances "
        "once every agent echoed the tick (protocols/mavlink/conventions.py)",
    )
    p.add_argument(
        "--speedup",
        type=float,
        default=1.0,
        metavar="X",
        help="simulated seconds per wall second (realtime; lockstep while no agent "
        "holds the barrier); default 1",
    )
    p.add_argument(
        "--dialect",
        choices=DIALECTS,
        default="px4",
        help="the autopilot the vehicles emulate on the wire: px4 (default; OFFBOARD, "
        "AUTO.LOITER, AUTO.LAND, normalised thrust) or ardupilot (ArduCopter: GUIDED_NOGPS, "
        "BRAKE, LAND; SET_ATTITUDE_TARGET's thrust a climb rate unless GUID_OPTIONS has bit 3; "
        "arming refused until the EKF is ready; lockstep keyed on GLOBAL_POSITION_INT)",
    )
    p.add_argument(
        "--ekf-ready-s",
        type=float,
        default=None,
        metavar="S",
        help="--dialect ardupilot: simulated seconds after start before each vehicle's EKF and "
        "GPS are ready and it may arm (default 2; 0: at once)",
    )
    p.add_argument(
        "--base-port",
        type=int,
        default=None,
        metavar="PORT",
        help="vehicle i listens on UDP PORT+i (default: vehicles 0-9 on 14540-14549 as PX4 SITL, "
        "10-249 on 14560-14799, never the GCS port 14550)",
    )
    p.add_argument(
        "--bind",
        default="127.0.0.1",
        metavar="HOST",
        help="address the vehicle ports bind to (default 127.0.0.1)",
    )
    p.add_argument(
        "--gcs",
        default=f"udp:127.0.0.1:{DEFAULT_GCS_PORT}",
        metavar="URL",
        help=f"ground station: udp:HOST:PORT, or none (default udp:127.0.0.1:{DEFAULT_GCS_PORT})",
    )
    p.add_argument(
        "--physics-hz",
        type=int,
        metavar="HZ",
        help="physics and inner-loop rate (default 500 or the scenario's)",
    )
    p.add_argument(
        "--control-hz",
        type=int,
        metavar="HZ",
        help="control tick = highest telemetry rate (default 50 or the scenario's)",
    )
    p.add_argument(
        "--agent-rate-hz",
        type=float,
        default=50.0,
        metavar="HZ",
        help="default ATTITUDE and LOCAL_POSITION_NED rate to agents (default 50)",
    )
    p.add_argument(
        "--gcs-rate-hz",
        type=float,
        default=10.0,
        metavar="HZ",
        help="default ATTITUDE, LOCAL_POSITION_NED and ACTUATOR_OUTPUT_STATUS rate to the GCS "
        "(default 10)",
    )
    p.add_argument(
        "--signing-key",
        type=Path,
        metavar="FILE",
        help="MAVLink 2 signing key (32 raw bytes or 64 hex characters): telemetry "
        "signed, unsigned or wrongly signed commands and setpoints rejected",
    )
    p.add_argument(
        "--secrets",
        type=Path,
        metavar="DIR",
        help="the swarm's secrets (swarm keys init): sign MAVLink with its key (the simulator "
        "uses no Zenoh)",
    )
    p.add_argument("--seed", type=int, help="random seed (default: the scenario's, else 0)")
    p.add_argument(
        "--position-noise-m",
        type=float,
        default=0.0,
        metavar="M",
        help="standard deviation of the reported position noise, m (default 0)",
    )
    p.add_argument(
        "--offboard-timeout",
        type=float,
        default=0.5,
        metavar="S",
        help="no valid setpoint for S seconds in OFFBOARD -> failsafe (default 0.5; PX4 "
        "dialect: ArduCopter's GUID_TIMEOUT is a parameter, 3 s)",
    )
    p.add_argument("--sysids", metavar="LIST", help="system ids, e.g. 1,2,7 (default 1..N)")
    p.add_argument(
        "--lockstep-timeout",
        type=float,
        default=LOCKSTEP_DROP_TIMEOUT_S,
        metavar="S",
        help="an agent silent for S wall seconds leaves the barrier (default %(default)g: on a "
        "machine so loaded that a process waits seconds for the CPU, lockstep slows down, it does "
        "not drop anyone; an agent whose process ends leaves at once, its port closed)",
    )
    p.add_argument(
        "--join-timeout",
        type=float,
        default=10.0,
        metavar="S",
        help="lockstep: tick 0 waits up to S wall seconds for agents (default 10)",
    )
    p.add_argument(
        "--wait-agents",
        type=int,
        default=None,
        metavar="K",
        help="tick 0 waits (up to --join-timeout) for K agents: in lockstep K agents in the "
        "barrier (default 1), in realtime K agents that have spoken (default 0: start at once)",
    )
    p.add_argument(
        "--duration-s",
        type=float,
        metavar="S",
        help="stop after S simulated seconds (default: run until stopped)",
    )
    p.add_argument(
        "--start-at",
        type=float,
        metavar="UNIX_S",
        help="realtime: run tick 0 at this Unix time (e.g. $(($(date +%%s) + 20))) instead of "
        "when agents have spoken; give every shard of a swarm (--drones LO-HI) the same one so "
        "they share one clock",
    )
    p.add_argument(
        "--shard-sync",
        metavar="HOST:PORT",
        help="lockstep across shards: this shard's UDP port for the shards' tick agreement "
        "(every shard steps once all hold the tick's setpoints); with --shard-peers",
    )
    p.add_argument(
        "--shard-peers",
        metavar="LIST",
        help="the other shards' --shard-sync addresses, comma-separated HOST:PORT",
    )
    p.add_argument("--quiet", action="store_true", help="no start and status lines")
    return p


def run_sim(args: argparse.Namespace, out: TextIO = sys.stdout) -> int:
    """Run ``swarm sim`` with parsed ``args``; exit code 0 after a clean stop."""
    from sitl_sim.launch import build_config, build_world, start_line, status_line
    from sitl_sim.network import Network
    from sitl_sim.server import SimServer, Status

    config = build_config(args)

    def show(status: Status) -> None:
        print(status_line(status), file=out, flush=True)

    shards = _shard_sync(args)
    try:
        # the ports first, said at once (`swarm up` starts the agents once they are bound: an
        # agent's own ephemeral port must not land on a vehicle's), then the world
        with Network(config.net, config.sysids) as network:
            if not args.quiet:
                print(start_line(config), file=out, flush=True)
            world, tunables = build_world(config)
            on_status = None if args.quiet else show
            server = SimServer(
                world, tunables, network, config.clock, on_status=on_status, shard_sync=shards
            )
            with _stop_on_signals(server.stop):
                server.run()
    finally:
        if shards is not None:
            shards.close()
    return 0


def _shard_sync(args: argparse.Namespace) -> Any:
    """The shards' tick agreement of ``--shard-sync`` / ``--shard-peers`` (None without)."""
    import time

    from sitl_sim.shard_sync import ShardSync, parse_address
    from sitl_sim.sim_config import SimConfigError

    if args.shard_sync is None and args.shard_peers is None:
        return None
    if args.shard_sync is None or not args.shard_peers:
        raise SimConfigError("lockstep across shards needs both --shard-sync and --shard-peers")
    if args.clock != "lockstep":
        raise SimConfigError("--shard-sync is for --clock lockstep (realtime shards: --start-at)")
    try:
        bind = parse_address(args.shard_sync, "--shard-sync")
        peers = [parse_address(p, "--shard-peers") for p in args.shard_peers.split(",")]
        return ShardSync(bind, peers, time.monotonic, timeout_s=args.lockstep_timeout * 5)
    except ValueError as exc:
        raise SimConfigError(str(exc)) from None


class _stop_on_signals:
    """While active, SIGINT and SIGTERM call ``stop`` instead of raising or killing."""

    def __init__(self, stop: Callable[[], None]) -> None:
        self.stop = stop
        self._old: dict[int, Any] = {}

    def __enter__(self) -> None:
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._old[sig] = signal.signal(sig, lambda _s, _f: self.stop())

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self._old.items():
            signal.signal(sig, handler)

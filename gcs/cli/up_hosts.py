"""``swarm up`` across hosts: a Zenoh router, partial starts and a secured swarm.

With ``--router ENDPOINT`` every process ``swarm up`` starts is a client of the swarm's Zenoh
router there (``swarm router``, or ``--only router,...`` on the host that runs it); ``--only``
starts some parts only (``router``, ``gcs``, ``sim``, ``agents``), ``--drones LO-HI`` narrows the
agents to a range of drones and ``--sim-drones LO-HI`` the simulator (a shard), so that each host
starts its share::

    ground (10.0.0.1):  swarm up paper.toml --router tcp/10.0.0.1:7447 --only router,gcs \\
                            --bind 10.0.0.1
    sim    (10.0.0.2):  swarm up paper.toml --router tcp/10.0.0.1:7447 --only sim \\
                            --bind 10.0.0.2 --gcs-host 10.0.0.1
    companion A:        swarm up paper.toml --router tcp/10.0.0.1:7447 --only agents \\
                            --drones 0-4 --sim-host 10.0.0.2

``--secrets DIR`` (``swarm keys init``) secures every part: the router speaks TLS only and
checks certificates, passwords and the swarm's access control; MAVLink is signed with the
swarm's key. Without ``--router`` it starts a router of its own on this machine, so ``swarm up
--secrets DIR`` alone runs a fully secured swarm.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

from gcs.cli.supervisor import Child, RunPlan, SupervisorError, flags, free_tcp_port, swarm_argv
from protocols.bus.zenoh_config import ROUTER_PORT, role_secrets, secured_endpoint

PARTS = ("router", "gcs", "sim", "agents")
#: Telemetry rate of every vehicle to the ground station (Hz), as up_cli.TELEMETRY_HZ.
TELEMETRY_HZ = 25


def add_multihost_flags(p: argparse.ArgumentParser) -> None:
    """The flags of a multi-host or secured ``swarm up``."""
    p.add_argument(
        "--router",
        metavar="ENDPOINT",
        help="the swarm's Zenoh router (e.g. tcp/10.0.0.1:7447): every process started here is "
        "its client; with 'router' in --only this host runs it, listening there",
    )
    p.add_argument(
        "--only",
        metavar="PARTS",
        help="start only these parts here, comma-separated: router, gcs, sim, agents (default: "
        "gcs,sim,agents, plus a router of this machine with --secrets and no --router)",
    )
    p.add_argument(
        "--drones",
        metavar="N | LO-HI",
        help="without a scenario file (swarm up only): N drones for an operator session, 2..250; "
        "with a scenario file and --router: only the agents of drones LO..HI (0-based), e.g. "
        "0-4 on one companion host and 5-8 on another",
    )
    p.add_argument(
        "--sim-drones",
        metavar="LO-HI",
        help="a simulator of drones LO..HI only (a shard: one per simulator host, realtime, "
        "with one --start-at on every shard's host; default: every drone)",
    )
    p.add_argument(
        "--bind",
        default="127.0.0.1",
        metavar="HOST",
        help="this host's address for the simulator's vehicle ports and the ground station's "
        "telemetry port (default 127.0.0.1)",
    )
    p.add_argument(
        "--sim-host",
        metavar="HOST",
        help="where the agents find the simulator's vehicle ports (default: --bind)",
    )
    p.add_argument(
        "--gcs-host",
        metavar="HOST",
        help="where the simulator sends telemetry: the ground station's host (default: --bind)",
    )
    p.add_argument(
        "--start-at",
        type=float,
        metavar="UNIX_S",
        help="the simulator's tick 0 at this Unix time (realtime): the same on every host of a "
        "simulator split by --sim-drones, so its shards share one clock",
    )
    p.add_argument(
        "--shard-sync",
        metavar="HOST:PORT",
        help="lockstep simulator shards: this shard's UDP port for the shards' tick agreement",
    )
    p.add_argument(
        "--shard-peers",
        metavar="LIST",
        help="lockstep simulator shards: the other shards' --shard-sync, comma-separated",
    )
    p.add_argument(
        "--secrets",
        type=Path,
        metavar="DIR",
        help="the swarm's secrets (swarm keys init): TLS, authentication and access control on "
        "Zenoh, signed MAVLink; without --router a router of this machine is started",
    )


@dataclass(frozen=True)
class HostLayout:
    """What this host runs: ``parts``, the agents of drones ``first``..``last``, the simulator's
    drones ``sim_first``..``sim_last``, the router endpoint (None: the single-host peer
    rendezvous), the secrets folder, and the addresses."""

    parts: tuple[str, ...]
    first: int
    last: int
    sim_first: int
    sim_last: int
    router: str | None
    secrets: Path | None
    bind: str
    sim_host: str
    gcs_host: str


def _parts(text: str | None) -> tuple[str, ...] | None:
    if text is None:
        return None
    parts = tuple(p.strip() for p in text.split(",") if p.strip())
    bad = [p for p in parts if p not in PARTS]
    if bad or not parts:
        raise SupervisorError(f"--only {text!r}: parts are {', '.join(PARTS)}")
    return parts


def _range(text: str | None, n: int, flag: str) -> tuple[int, int]:
    if text is None:
        return 0, n - 1
    lo, sep, hi = text.partition("-")
    if not sep:
        lo = hi = text
    if not (lo.strip().isdigit() and hi.strip().isdigit()) or not int(lo) <= int(hi) < n:
        raise SupervisorError(f"{flag} {text!r}: a range LO-HI of drones 0..{n - 1}")
    return int(lo), int(hi)


def host_layout(args: argparse.Namespace, n: int) -> HostLayout:
    """The layout of ``args``; SupervisorError (one line) for an inconsistent one."""
    parts = _parts(args.only)
    router = args.router
    if router is not None and args.zenoh_connect is not None:
        raise SupervisorError("give --router or --zenoh-connect, not both")
    if router is not None and "/" not in router:
        raise SupervisorError(f"--router must look like tcp/HOST:PORT, got {router!r}")
    if parts is None:
        parts = ("gcs", "sim", "agents")
        if args.secrets is not None and router is None:
            parts = ("router", *parts)
    elif router is None and args.secrets is None:
        raise SupervisorError(
            "--only needs --router ENDPOINT: the swarm's router, where the parts started on "
            "different hosts meet"
        )
    flags_ = ("drones", "sim_drones", "start_at", "sim_host", "gcs_host", "shard_sync")
    spread = [f for f in flags_ if getattr(args, f)]
    spread += ["bind"] if args.bind != "127.0.0.1" else []
    if spread and router is None and args.secrets is None:
        flag = "--" + spread[0].replace("_", "-")
        raise SupervisorError(f"{flag} is for a swarm spread over hosts: give --router ENDPOINT")
    roles = {"router": "router", "gcs": "gcs", "sim": "sim", "agents": "agent"}
    for part in parts if args.secrets is not None else ():
        try:
            role_secrets(args.secrets, roles[part], args.swarm_id)
        except ValueError as exc:
            raise SupervisorError(str(exc)) from None
    if router is None and args.secrets is not None:
        port = ROUTER_PORT if _tcp_free(ROUTER_PORT) else free_tcp_port()
        router = f"tcp/127.0.0.1:{port}"
    if router is not None and args.secrets is not None:
        router = secured_endpoint(router)
    first, last = _range(args.drones, n, "--drones")
    sim_first, sim_last = _range(args.sim_drones, n, "--sim-drones")
    shard = "sim" in parts and (sim_first, sim_last) != (0, n - 1)
    synced = args.shard_sync is not None and args.shard_peers is not None
    if shard and args.clock == "lockstep" and not synced:
        raise SupervisorError(
            "a lockstep simulator of some drones only (--sim-drones) needs --shard-sync "
            "HOST:PORT and --shard-peers (the other shards'), or --clock realtime and --start-at"
        )
    if shard and args.clock == "realtime" and args.start_at is None:
        raise SupervisorError(
            "a simulator of some drones only (--sim-drones) needs --start-at UNIX_S, the same "
            "on every simulator host, so its shards share one clock"
        )
    bind = args.bind
    return HostLayout(
        parts=parts,
        first=first,
        last=last,
        sim_first=sim_first,
        sim_last=sim_last,
        router=router,
        secrets=args.secrets,
        bind=bind,
        sim_host=args.sim_host or bind,
        gcs_host=args.gcs_host or bind,
    )


def _tcp_free(port: int) -> bool:
    from protocols.bus.zenoh_bus import tcp_listen_free

    return tcp_listen_free(port)


def _groups(first: int, last: int, per_process: int) -> list[range]:
    return [
        range(lo, min(lo + per_process, last + 1)) for lo in range(first, last + 1, per_process)
    ]


def multihost_plan(
    args: argparse.Namespace, scenario: Path, layout: HostLayout, n: int, duration_s: float
) -> RunPlan:
    """The children this host starts, all clients of ``layout.router``."""
    from gcs.station.drills import RUN_FILE  # pymavlink: when a plan is made, not by the parser

    assert layout.router is not None
    report: Path = args.report
    logs = report / "logs"
    try:
        logs.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SupervisorError(f"cannot write the report folder {report}: {exc}") from None
    secured = flags([("--secrets", layout.secrets), ("--signing-key", args.signing_key)])
    client = ["--zenoh-mode", "client", "--zenoh-connect", layout.router]
    common = ["--scenario", str(scenario)]
    router = gcs = sim = None
    if "router" in layout.parts:
        router_flags = flags([("--secrets", layout.secrets)])
        router = Child(
            "router", swarm_argv("router", "--listen", layout.router, *router_flags),
            logs / "router.log",
        )  # fmt: skip
    if "gcs" in layout.parts:
        gcs_flags = flags(
            [
                ("--report", report),
                ("--swarm-id", args.swarm_id),
                ("--gcs-port", args.gcs_port),
                ("--gcs-bind", layout.bind),
                ("--telemetry-hz", TELEMETRY_HZ),
                ("--run-file", logs / RUN_FILE),
                ("--duration-s", duration_s),
                ("--no-plots", args.no_plots),
                ("--no-recording", args.no_recording),
                ("--quiet", True),
            ]
        )
        gcs = Child(
            "gcs", swarm_argv("gcs", *common, *gcs_flags, *client, *secured), logs / "gcs.log"
        )
    if "sim" in layout.parts:
        drones = range(layout.sim_first, layout.sim_last + 1)
        shard = None if len(drones) == n else f"{layout.sim_first}-{layout.sim_last}"
        sim_flags = flags(
            [
                ("--clock", args.clock),
                ("--speedup", args.speedup),
                ("--wait-agents", len(drones)),
                ("--join-timeout", 120),
                ("--base-port", args.base_port),
                ("--bind", layout.bind),
                ("--gcs", f"udp:{layout.gcs_host}:{args.gcs_port}"),
                ("--gcs-rate-hz", TELEMETRY_HZ),
                ("--duration-s", duration_s),
                ("--drones", shard),
                ("--start-at", args.start_at),
                ("--shard-sync", args.shard_sync),
                ("--shard-peers", args.shard_peers),
            ]
        )
        sim = Child("simulator", swarm_argv("sim", *common, *sim_flags, *secured), logs / "sim.log")
    agents, agent_drones = [], []
    if "agents" in layout.parts:
        for group in _groups(layout.first, layout.last, args.agents_per_process):
            ids = f"{group.start}-{group.stop - 1}" if len(group) > 1 else str(group.start)
            agent_flags = flags(
                [
                    ("--base-port", args.base_port),
                    ("--swarm-id", args.swarm_id),
                    ("--vehicle-host", layout.sim_host),
                    ("--quiet", True),
                    ("--lockstep", args.clock == "lockstep"),
                ]
            )
            argv = swarm_argv("agent", "--drone-id", ids, *common, *agent_flags, *client, *secured)
            agents.append(Child(f"agent {ids}", argv, logs / f"agent-{ids}.log"))
            agent_drones.append(group)
    return RunPlan(gcs, sim, agents, agent_drones, logs / RUN_FILE, layout.router, router)

"""``swarm agent``: run one drone's agent, or several in one process (``--drone-id 0-24``)."""

from __future__ import annotations

import argparse
import functools
import os
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

from protocols.bus.zenoh_config import RENDEZVOUS_PORT
from protocols.mavlink.swarm_clock import EPOCH_HELP, epoch_arg

# the parser (add_parser, main.py) imports no more than this: the machinery (numpy, numba, Zenoh,
# pymavlink) is imported when an agent runs (tests/test_cli.py checks it)
if TYPE_CHECKING:
    from drone_agent.core.agent_core import AgentConfig
    from drone_agent.process.host import AgentHost
    from drone_agent.process.hosted_agent import HostedAgent
    from drone_agent.process.link_faults import LinkFaults
    from drone_agent.process.transport import AgentTransport, Position
    from protocols.bus.interface import Bus
    from protocols.bus.zenoh_bus import ZenohSettings
    from protocols.scenario.scenario_file import Scenario

#: Zenoh lease (ms) of a lockstep agent's session: how long a frozen agent looks alive. Lockstep's
#: wall-clock limits go lease (5 s) < the simulator's barrier timeout (10 s) < an agent's vehicle
#: timeout (LOCKSTEP_VEHICLE_TIMEOUT_S, 15 s): a hung process's drones leave its peers' rosters
#: first, so they echo the tick again before the barrier gives up on anyone.
LOCKSTEP_LEASE_MS = 5000
#: How long (µs) a lockstep agent's DROP publishers wait for room in a full send queue before a
#: consensus message is lost (and the round marker behind it then vouches for it: the flight no
#: longer repeats). A queue stays full that long only when the machine cannot run Zenoh's threads
#: (100 ms was exceeded at load 18-38) or a peer stopped reading; the latter's link closes at the
#: lease (5 s) anyway, so waiting up to 1 s costs a frozen peer's neighbours nothing more.
LOCKSTEP_DROP_WAIT_US = 1_000_000
#: A directory: the agent process runs under cProfile and dumps its profile there on exit
#: (``agent-<first drone>-<pid>.prof``, in the main thread's CPU time;
#: bench/agent_process_profile.txt).
PROFILE_ENV = "SWARM_AGENT_PROFILE"
#: Set: the agent process says on exit how much CPU it used, on its own thread and in all.
CPU_ENV = "SWARM_AGENT_CPU"
#: Batches in a lockstep agent's send queue per link (Zenoh's default 2; see ZenohSettings).
LOCKSTEP_TX_QUEUE_BATCHES = 16
#: How long (wall s) a lockstep agent waits for its vehicle's state before it leaves: longer
#: than the simulator's barrier timeout (sitl_sim ClockConfig.drop_timeout_s, 10 s), since a
#: barrier waiting for the slowest process of a loaded machine legitimately sends nothing (at
#: 3 s, 14 of 100 agents left a lockstep flight at load 25, and it flew another flight).
LOCKSTEP_VEHICLE_TIMEOUT_S = 15.0


class AgentCliError(Exception):
    """A user mistake in the agent's flags: one line, exit code 2."""


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``swarm agent``."""
    p = sub.add_parser(
        "agent",
        help="run drone agents: consensus estimator + cooperative controller of one or more drones",
        description=(
            "Run the agent of one drone, or of several drones in one process sharing one Zenoh "
            "session. Each agent reads its vehicle's state over MAVLink, estimates the swarm's "
            "descriptors with its neighbours over Zenoh, and streams attitude + thrust setpoints "
            "to its vehicle. Without Zenoh flags the first agent process on this machine listens "
            f"on tcp/127.0.0.1:{RENDEZVOUS_PORT} and the others connect to it (peer mode, no "
            "router, no multicast)."
        ),
    )
    p.add_argument(
        "--drone-id",
        required=True,
        metavar="I",
        help="0-based drone index (MAVLink system id I+1), a range 0-24 or a list 0,3,5",
    )
    p.add_argument(
        "--vehicle",
        metavar="udp:HOST:PORT",
        help="the vehicle's MAVLink endpoint (one drone only; default udp:127.0.0.1 at the "
        "vehicle's port, see --base-port)",
    )
    p.add_argument(
        "--base-port",
        type=int,
        default=None,
        help="vehicle I listens on BASE+I (default: as swarm sim: drones 0-9 on 14540-14549, "
        "10-249 on 14560-14799)",
    )
    p.add_argument(
        "--dialect",
        choices=("auto", "px4", "ardupilot"),
        default="auto",
        help="the vehicles' autopilot dialect: px4 (OFFBOARD; the project's simulator by "
        "default) or ardupilot (ArduCopter: GUIDED_NOGPS, GUID_OPTIONS thrust, EKF/GPS "
        "readiness, GLOBAL_POSITION_INT about the scenario's home); auto (default) takes it "
        "from each vehicle's HEARTBEAT",
    )
    p.add_argument(
        "--vehicle-listen",
        action="store_true",
        help="bind each vehicle's port and answer whoever sends to it, instead of sending to it "
        "(ArduCopter SITL started with --serial0 udpclient:HOST:PORT)",
    )
    p.add_argument(
        "--swarm-epoch",
        type=epoch_arg,
        default=None,
        metavar="UNIX_S",
        help=EPOCH_HELP,
    )
    p.add_argument("--swarm-id", default="swarm", help="swarm name on Zenoh (default %(default)s)")
    p.add_argument(
        "--vehicle-host",
        default="127.0.0.1",
        metavar="HOST",
        help="where the simulator's vehicle ports are (default 127.0.0.1; another host's "
        "address when the simulator runs elsewhere)",
    )
    p.add_argument(
        "--zenoh-mode",
        choices=("peer", "client"),
        default="peer",
        help="client: join a Zenoh router (swarm router) given by --zenoh-connect",
    )
    p.add_argument(
        "--zenoh-connect",
        nargs="*",
        default=None,
        metavar="ENDPOINT",
        help="Zenoh endpoints to connect to, e.g. tcp/127.0.0.1:7447",
    )
    p.add_argument(
        "--zenoh-listen",
        nargs="*",
        default=None,
        metavar="ENDPOINT",
        help="Zenoh endpoints to listen on (peer mode)",
    )
    p.add_argument(
        "--signing-key",
        type=Path,
        metavar="FILE",
        help="MAVLink 2 signing key (32 raw bytes or 64 hex characters)",
    )
    p.add_argument(
        "--secrets",
        type=Path,
        metavar="DIR",
        help="the swarm's secrets (swarm keys init): client of the router at --zenoh-connect "
        "over TLS with the agent credential; MAVLink signed with its key",
    )
    p.add_argument(
        "--comm-range-m",
        type=float,
        default=None,
        metavar="M",
        help="radio range in metres (default: the scenario's, else 10)",
    )
    p.add_argument(
        "--scenario",
        type=Path,
        metavar="FILE",
        help="scenario (TOML): gains, rates, and the plan flown until a ground "
        "station publishes one; its link faults are applied as drills",
    )
    p.add_argument(
        "--wait-for-plan",
        action="store_true",
        help="take only gains, rates and faults from --scenario, not its plan: stay on the "
        "ground until a ground station publishes one (an operator session, swarm up --drones)",
    )
    p.add_argument(
        "--no-arm", action="store_true", help="never arm: run the estimator on the ground only"
    )
    p.add_argument(
        "--seed",
        type=int,
        default=None,
        help="random seed of the link faults' draws (default: the scenario's seed, as swarm "
        "simulate draws them; 0 without a scenario)",
    )
    p.add_argument(
        "--lockstep",
        action="store_true",
        help="the simulator runs --clock lockstep (swarm up passes it): before each tick wait "
        "for every live drone's message of the previous round, however long it takes (a dead "
        "drone, whose liveliness token is gone, is dropped at once), so that two runs of a "
        "scenario repeat exactly; without it an agent waits at most a few ms (realtime)",
    )
    p.add_argument("--quiet", action="store_true", help="no status line")


def _endpoint(url: str) -> tuple[str, int]:
    scheme, _, rest = url.partition(":")
    host, _, port = rest.rpartition(":")
    if scheme != "udp" or not host or not port.isdigit():
        raise AgentCliError(f"--vehicle must look like udp:HOST:PORT, got {url!r}")
    return host, int(port)


def zenoh_settings(args: argparse.Namespace) -> ZenohSettings:
    """The session settings: the flags, or the embedded loopback rendezvous by default; with
    ``--secrets`` a TLS client of the router at ``--zenoh-connect``."""
    from protocols.bus.zenoh_bus import ZenohSettings, tcp_listen_free

    listen, connect = args.zenoh_listen, args.zenoh_connect
    if getattr(args, "secrets", None) is not None:
        return _secured_settings(args.secrets, "agent", connect, args.swarm_id)
    if listen is None and connect is None:
        if tcp_listen_free(RENDEZVOUS_PORT):
            listen, connect = [f"tcp/127.0.0.1:{RENDEZVOUS_PORT}"], []
        else:
            listen, connect = ["tcp/127.0.0.1:0"], [f"tcp/127.0.0.1:{RENDEZVOUS_PORT}"]
    try:
        from protocols.bus.zenoh_config import ROUTER_LEASE_MS, ROUTER_WAIT_MS

        client = args.zenoh_mode == "client"
        lease_ms = ROUTER_LEASE_MS if client else ZenohSettings.lease_ms
        lockstep = getattr(args, "lockstep", False)
        if lockstep:
            # a process starved of CPU for a second must not look dead (its token would go and
            # come back, changing its neighbours' rosters at a wall-clock moment); a killed one's
            # token still goes at once, when its sockets close
            lease_ms = max(lease_ms, LOCKSTEP_LEASE_MS)
        return ZenohSettings(
            mode=args.zenoh_mode,
            listen=tuple(listen or ()) if not client else (),
            connect=tuple(connect or ()),
            connect_timeout_ms=ROUTER_WAIT_MS if client else 0,
            lease_ms=lease_ms,
            drop_wait_us=LOCKSTEP_DROP_WAIT_US if lockstep else None,
            tx_queue_batches=LOCKSTEP_TX_QUEUE_BATCHES if lockstep else None,
        )
    except ValueError as exc:
        raise AgentCliError(str(exc)) from None


def _secured_settings(
    folder: Path, role: str, connect: list[str] | None, swarm_id: str
) -> ZenohSettings:
    from protocols.bus.zenoh_bus import ZenohSettings
    from protocols.bus.zenoh_config import (
        ROUTER_LEASE_MS,
        ROUTER_WAIT_MS,
        role_secrets,
        secured_endpoint,
    )

    if not connect:
        raise AgentCliError("--secrets needs --zenoh-connect: the swarm router's endpoint")
    try:
        return ZenohSettings(
            mode="client",
            listen=(),
            connect=tuple(secured_endpoint(e) for e in connect),
            secrets=role_secrets(folder, role, swarm_id),
            connect_timeout_ms=ROUTER_WAIT_MS,
            lease_ms=ROUTER_LEASE_MS,
        )
    except ValueError as exc:
        raise AgentCliError(str(exc)) from None


def _default_config(control_hz: int = 50) -> AgentConfig:
    from drone_agent.core.config import agent_config
    from protocols.scenario.scenario_file import parse_scenario

    stub = parse_scenario(
        {
            "version": 1,
            "duration_s": 1.0,  # unused: only the defaults of gains, limits and rates are taken
            "drones": [{"position_ned_m": [0, 0, 0]}, {"position_ned_m": [2, 0, 0]}],
            "rates": {"control_hz": control_hz, "physics_hz": 500},
            "trajectory": {
                "waypoints": [{"t_s": 0, "centre_ned_m": [0, 0, 0], "variance_m2": [1, 1, 0]}]
            },
        },
        "defaults",
    )
    return agent_config(stub)


def run(args: argparse.Namespace) -> int:
    """Run the agents until Ctrl-C / SIGTERM or until every one has left."""
    from drone_agent.core.config import agent_config
    from drone_agent.process.fault_drills import FaultDrills
    from drone_agent.process.host import AgentHost, DroneIdError, parse_drone_ids
    from drone_agent.process.hosted_agent import RunOptions
    from drone_agent.process.link_faults import (
        FaultyTransport,
        LinkFaults,
        PairRandom,
        radio_links,
    )
    from drone_agent.process.round_gate import RoundBook
    from drone_agent.process.transport_link import AgentLink, ConsensusHub, LinkSettings
    from drone_agent.process.vehicle_link import VehicleLink
    from protocols.bus.interface import Congestion
    from protocols.bus.zenoh_bus import ZenohBus
    from protocols.mavlink.conventions import Dialect, vehicle_port
    from protocols.mavlink.signing import SigningKeyError, load_signing_key
    from protocols.mavlink.swarm_clock import VehicleClock
    from protocols.model.frames import G_M_S2
    from protocols.runtime.collector import flight_collector
    from protocols.scenario.scenario_file import ScenarioError, load_scenario

    try:
        drones = parse_drone_ids(args.drone_id)
    except DroneIdError as exc:
        raise AgentCliError(str(exc)) from None
    scenario: Scenario | None = None
    if args.scenario is not None:
        try:
            scenario = load_scenario(args.scenario)
        except ScenarioError as exc:
            raise AgentCliError(str(exc)) from None
        too_big = [d for d in drones if d >= scenario.n_drones]
        if too_big:
            raise AgentCliError(
                f"drone {too_big[0]} is not in the scenario (0..{scenario.n_drones - 1})"
            )
    if args.vehicle is not None and len(drones) != 1:
        raise AgentCliError("--vehicle names one vehicle: use --base-port with several drones")
    key = None
    key_file = args.signing_key
    if key_file is None and args.secrets is not None:
        key_file = args.secrets / "mavlink.key"
    if key_file is not None:
        try:
            key = load_signing_key(key_file)
        except SigningKeyError as exc:
            raise AgentCliError(str(exc)) from None
    comm_range = args.comm_range_m or (scenario.comms.range_m if scenario else 10.0)
    if not comm_range > 0:
        raise AgentCliError("--comm-range-m must be positive")
    try:
        config = agent_config(scenario) if scenario else _default_config()
    except ScenarioError as exc:  # its [agent] controller cannot fly
        raise AgentCliError(str(exc)) from None
    plan = scenario.trajectory() if scenario and not args.wait_for_plan else None
    lockstep = bool(getattr(args, "lockstep", False))
    settings = LinkSettings(
        swarm_id=args.swarm_id,
        comm_range_m=comm_range,
        hold_early=lockstep,
        consensus_congestion=Congestion.QUEUED if lockstep else Congestion.DROP,
    )
    faults = LinkFaults()
    period_ms = round(config.consensus.dt_s * 1000)
    links = []
    dialect = None if args.dialect == "auto" else Dialect(args.dialect)
    limits = config.limits
    thrust_to_weight = limits.max_thrust_n / (limits.mass_kg * G_M_S2)
    origin = scenario.home if scenario is not None else None
    epoch = args.swarm_epoch
    try:
        for d in drones:
            if args.vehicle:
                address = _endpoint(args.vehicle)
            else:
                address = (args.vehicle_host, vehicle_port(d, args.base_port))
            links.append(
                VehicleLink(
                    d, address[0], address[1], signing_key=key, dialect=dialect,
                    thrust_to_weight=thrust_to_weight, control_hz=1.0 / config.consensus.dt_s,
                    origin=origin, clock=None if epoch is None else VehicleClock(epoch),
                    listen=args.vehicle_listen,
                )
            )  # fmt: skip
    except OSError as exc:
        raise AgentCliError(f"cannot open the vehicle link: {exc}") from None
    zsettings = zenoh_settings(args)
    try:
        bus: Bus = ZenohBus.open(zsettings)
    except Exception as exc:  # zenoh raises ZError with the reason
        from protocols.bus.zenoh_config import open_error

        reason = str(exc).split(" at /", 1)[0]
        if zsettings.mode == "client":
            reason = open_error(zsettings.connect[0], zsettings.secrets)
        raise AgentCliError(f"cannot open the Zenoh session: {reason}") from None

    seed = args.seed if args.seed is not None else (scenario.seed if scenario else 0)
    pair_random = PairRandom(seed)

    # one hub for the process's agents: shared subscriptions, and (several agents) their
    # messages of a pass sent as one sample per cell (protocols/wire/batch.py)
    rounds = RoundBook(bus, settings.keys(), drones) if lockstep else None
    news = None if rounds is None else (lambda: rounds.version)
    hub = ConsensusHub(bus, settings, batch=len(drones) > 1, news=news, sole=True)

    # the radio's limits (the scenario's [radio]; one state per agent: the links into it)
    radio_of = (
        None
        if scenario is None or scenario.radio.ideal
        else functools.partial(radio_links, scenario.radio, scenario.rates.dt_control_s, seed)
    )

    def transport(bus_: Bus, drone: int, position: Position) -> AgentTransport:
        # called once the host runs; ``host`` is bound by then
        inner = AgentLink(bus_, drone, position, settings, hub)
        radio = None if radio_of is None else radio_of()
        return FaultyTransport(inner, faults, pair_random, lambda: host.round_of(drone), radio)

    options = RunOptions(
        control_period_ms=period_ms,
        arm=not args.no_arm,
        lockstep=lockstep,
        vehicle_timeout_s=LOCKSTEP_VEHICLE_TIMEOUT_S if lockstep else RunOptions.vehicle_timeout_s,
    )
    roster = range(scenario.n_drones) if scenario is not None else ()
    host = AgentHost(drones, links, bus, transport, config, plan, options, rounds=rounds,
                     roster=roster, hub=hub)  # fmt: skip
    drills = _Drills(scenario, faults, host) if scenario else None

    def restart(drone: int, gap_s: float) -> None:  # the restart drill (swarm drill restart)
        done = host.restart(drone, gap_s)
        if done is not None:
            print(f"agents: {done}", file=sys.stderr, flush=True)

    def back(drone: int, time_boot_ms: int) -> None:
        print(
            f"agents: drone {drone}: a new agent starts at t={time_boot_ms / 1000:.2f}s "
            "(restart drill)",
            file=sys.stderr,
            flush=True,
        )

    def kill(drone: int) -> None:  # the dropout drill of a hosted agent (swarm drill dropout)
        host.kill(drone, "killed by a dropout drill")  # a drone it does not host: nothing

    live = FaultDrills(
        bus, args.swarm_id, faults, config.consensus.dt_s, host_round(host), restart=restart,
        kill=kill,
    )  # fmt: skip

    def stop(_sig: int, _frame: FrameType | None) -> None:
        host.stop()

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)

    said: list[str | None] = [None]  # the controller's last failure said

    def each_loop() -> None:
        live.poll()
        if drills is not None:  # the scenario's timeline, applied as soon as it is due
            drills.apply()
        error = host.controller_error
        if error is not None and error != said[0]:  # always said, --quiet or not
            said[0] = error
            print(f"agents: {error}; its drones get no setpoint (they hold)", file=sys.stderr,
                  flush=True)  # fmt: skip

    def report(h: AgentHost) -> None:
        print(_status_line(h, config.consensus.dt_s), file=sys.stderr, flush=True)

    def left(agent: HostedAgent) -> None:  # always said, --quiet or not
        t_s = max(agent.last_tick, 0) * config.consensus.dt_s
        print(
            f"agents: drone {agent.drone} left the swarm at t={t_s:.2f}s: {agent.leave_reason}",
            file=sys.stderr,
            flush=True,
        )

    profile_dir = os.environ.get(PROFILE_ENV)
    profiler = None
    if profile_dir:
        import cProfile

        # the main thread's CPU time (not wall time: the machine may be loaded)
        profiler = cProfile.Profile(time.thread_time)
        profiler.enable()
    try:
        with flight_collector():
            host.run(
                on_second=None if args.quiet else report,
                on_loop=each_loop,
                on_leave=left,
                on_return=back,
            )
    finally:
        if profiler is not None and profile_dir:
            profiler.disable()
            out = Path(profile_dir) / f"agent-{drones[0]}-{os.getpid()}.prof"
            profiler.dump_stats(out)
        if os.environ.get(CPU_ENV):  # where the process's CPU went: its thread or Zenoh's
            print(
                f"agents: CPU {time.process_time():.2f} s, of which the agents' thread "
                f"{time.thread_time():.2f} s (the rest: Zenoh's threads)",
                file=sys.stderr,
                flush=True,
            )
        live.close()
        host.close()
        hub.close()
        bus.close()
    return 0


def host_round(host: AgentHost) -> Callable[[], int]:
    """A clock of ``host``'s current control round."""
    return lambda: _current_round(host)


def _current_round(host: AgentHost) -> int:
    ticks = [a.last_tick for a in host.agents]
    return max(ticks) if ticks else 0


class _Drills:
    """Applies the scenario's timeline as simulated time passes, on the ticks the in-process
    flight applies it (gcs/reference_flight.py), so that both runners and every run agree: a
    link fault at ``t`` acts on the messages of the rounds from ``t`` on (applied before any
    hosted agent takes in the messages of round ``ceil(t / dt)``), and a drop-out at ``t`` ends
    the drone's agent before it computes its tick of ``t``. Crashes are the simulator's."""

    def __init__(self, scenario: Scenario, faults: LinkFaults, host: AgentHost) -> None:
        from drone_agent.process.fault_timeline import timeline

        actions = [a for a in timeline(scenario) if a.fault_kind != "crash"]
        self._links = [a for a in actions if a.fault_kind != "dropout"]
        self._dropouts = [a for a in actions if a.fault_kind == "dropout"]
        self._target = _HostFaults(faults, host)
        self._host = host
        self._period_s = scenario.rates.dt_control_s

    def apply(self) -> None:
        if not self._links and not self._dropouts:  # the timeline is over (or was empty)
            return
        pending = self._host.pending_rounds()
        if not pending:
            return
        # every hosted agent has taken in the messages of the rounds before its pending tick
        t_s = (min(pending.values()) - 1) * self._period_s + 1e-9
        while self._links and self._links[0].t_s <= t_s:
            self._links.pop(0).apply(self._target)
        due_s = max(pending.values()) * self._period_s + 1e-9
        while self._dropouts and self._dropouts[0].t_s <= due_s:
            self._dropouts.pop(0).apply(self._target)


class _HostFaults:
    """The fault target of one agent process (drone_agent.process.fault_timeline.FaultTarget)."""

    def __init__(self, faults: LinkFaults, host: AgentHost) -> None:
        self._faults = faults
        self._host = host

    @property
    def conditions(self) -> LinkFaults:
        return self._faults

    def kill_agent(self, drone: int) -> None:
        """A scenario drop-out: the agent dies at its time as the ``dropout`` drill kills it. A
        process hosting only this drone dies (SIGKILL, nothing said to anyone); a process hosting
        several drops only this agent, abruptly (its liveliness token goes, it sends nothing
        more), and the others fly on."""
        if drone not in self._host.drones:
            return
        print(f"agents: drone {drone}: scenario drop-out", file=sys.stderr, flush=True)
        if len(self._host.drones) == 1:
            os.kill(os.getpid(), signal.SIGKILL)
        self._host.kill(drone, "scenario drop-out")

    def crash_vehicle(self, drone: int) -> None:  # the simulator's job
        pass


def _status_line(host: AgentHost, period_s: float) -> str:
    agents = host.agents
    modes: dict[str, int] = {}
    for a in agents:
        modes[a.mode.name.lower()] = modes.get(a.mode.name.lower(), 0) + 1
    tick = _current_round(host)
    mode_text = ", ".join(f"{n} {m}" for m, n in sorted(modes.items())) or "waiting for vehicles"
    neighbours = [len(a.last_output.active_neighbours) for a in agents if a.last_output]
    nb = f"{min(neighbours)}-{max(neighbours)}" if neighbours else "-"
    planless = sum(1 for a in agents if a.fallback_plan is None and a.transport.plan() is None)
    waiting = f"; {planless} waiting for the ground station's plan" if planless else ""
    dialects = [(a.drone, a.link.dialect) for a in agents]
    unready = [(d, dialect.not_ready_reason) for d, dialect in dialects if not dialect.ready]
    if unready:  # e.g. an ArduCopter whose EKF has not settled: the swarm waits for it
        drone, why = unready[0]
        waiting += f"; {len(unready)} vehicle(s) not ready (drone {drone}: {why})"
    return (
        f"agents t={tick * period_s:7.2f}s  {len(agents)} joined: {mode_text}; neighbours {nb}"
        f"{waiting}; {time.strftime('%H:%M:%S')}"
    )

"""``swarm up`` and ``swarm demo``: fly a scenario with real processes end to end, or run an
operator session (``swarm up --drones N``, :mod:`gcs.cli.session`)."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from gcs.cli.ardupilot_sitl import ENV as ARDUPILOT_ENV
from gcs.cli.compiled import warm_compiled
from gcs.cli.supervisor import (
    EPOCH,
    SHUT_DOWN,
    Child,
    RunPlan,
    SupervisorError,
    agent_groups,
    agent_ranges,
    check_udp_ports,
    flags,
    interrupt_flag,
    rendezvous_port,
    supervise,
    swarm_argv,
)
from gcs.cli.up_hosts import add_multihost_flags, host_layout, multihost_plan
from gcs.cli.view import LAYOUTS as VIEW_LAYOUTS
from gcs.view.recording import INSTALL_HINT, rerun_available
from protocols.mavlink.conventions import DEFAULT_GCS_PORT, port_clash, vehicle_ports
from protocols.scenario.layout_names import LAYOUTS

if TYPE_CHECKING:  # numpy and pymavlink: imported when a swarm comes up, not by the parser
    from gcs.cli.session import SessionRequest

#: The paper's flight, shipped with the project (so `swarm demo` works from any folder).
PAPER = Path(__file__).resolve().parents[2] / "scenarios" / "paper.toml"
#: Telemetry rate of every vehicle to the ground station, and so of the report's record (Hz).
TELEMETRY_HZ = 25
#: A session's Ctrl-C waits this much longer than the ground station's shutdown timeout (s) for
#: the report before stopping everything.
REPORT_WAIT_S = 60.0

UP_DESCRIPTION = """\
Two ways to run a swarm with real processes (the ground station, the SITL simulator and the
drone agents as supervised child processes; the report in --report):

  swarm up SCENARIO         fly a scenario file to its end (its duration_s, or --duration-s);
                            Ctrl-C stops everything at once.
  swarm up --drones N       an operator session: N vehicles and their agents power up on the
                            ground and wait. Fly them with swarm takeoff --altitude-m H,
                            formation, move, rotate, scale, hold and land (in another terminal);
                            swarm shutdown, or Ctrl-C here, lands the swarm if it flies, waits
                            until it is down, writes the report and stops everything.
                            --layout, --spacing-m, --range-m and --seed place the drones as
                            swarm scenario new does; the session's scenario is written to
                            DIR/logs/session.toml.
"""


#: ``swarm up`` hosts every agent in one process up to this many drones by default.
ONE_PROCESS_UP_TO = 25
#: Beyond, one agent process per CPU core, at least this many.
MIN_HOSTED_PROCESSES = 2


def default_agents_per_process(n: int, cpus: int | None = None) -> int:
    """``--agents-per-process``'s default for ``n`` drones on a machine of ``cpus`` cores (None:
    this one's). Every agent in one process up to ONE_PROCESS_UP_TO drones: each process pays
    its own messaging (Zenoh, round markers, every other process's batches) on top of its agents'
    work, and the agents' maths is batched across a process's drones. Measured on two cores,
    lockstep, whole runs (bench/results_layouts.json): the paper's 9 drones at 6.4x real time in
    one process, 4.3x in two, 1.4x in nine (one per drone, as each drone's companion computer
    would run it); 16 drones 5.1x, 2.9x, 0.5x in one, two, sixteen; 25 drones 3.7x in one, 2.7x
    in two. Beyond, one agent process per core (at least
    MIN_HOSTED_PROCESSES): on two cores, a hundred processes took 16 GB and two minutes to fly
    0.06 simulated seconds; four of 25 fly at 0.70-0.77x real time (lockstep), two of 50 at
    0.98-1.01x (bench/up_lockstep.py's run_case, interleaved). A dropout drill of one hosted
    agent kills that agent only (gcs/station/drills.py)."""
    if n <= ONE_PROCESS_UP_TO:
        return max(1, n)
    processes = max(MIN_HOSTED_PROCESSES, cpus if cpus is not None else os.cpu_count() or 1)
    return math.ceil(n / processes)


def add_parsers(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``swarm up`` and ``swarm demo``."""
    up = sub.add_parser(
        "up",
        help="fly a scenario file, or power up N drones for an operator session (--drones N)",
        description=UP_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    up.add_argument(
        "scenario", type=Path, nargs="?", default=None, help="scenario file (TOML); or --drones"
    )
    session = up.add_argument_group(
        "operator session (instead of a scenario file)",
        "N drones on the ground, waiting for swarm takeoff; no fixed duration",
    )
    # --drones N itself is with the multi-host flags: one flag, LO-HI with a scenario file
    session.add_argument(
        "--layout", choices=LAYOUTS, default=None, help="where they stand (default grid)"
    )
    session.add_argument(
        "--spacing-m",
        type=float,
        metavar="M",
        help="between neighbours on the ground (default 2.5)",
    )
    session.add_argument("--range-m", type=float, metavar="M", help="radio range (default 6)")
    session.add_argument("--seed", type=int, help="random layout and the run's draws (default 0)")
    session.add_argument(
        "--shutdown-timeout-s",
        type=float,
        metavar="S",
        help="how long a shutdown waits for the swarm to land before stopping anyway "
        "(default 120 wall s)",
    )
    _common(up)
    demo = sub.add_parser(
        "demo",
        help="fly the paper's scenario end to end (swarm up scenarios/paper.toml --report report)",
        description="swarm up scenarios/paper.toml with the report in ./report, then a summary.",
    )
    _common(demo)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--report",
        type=Path,
        default=Path("report"),
        metavar="DIR",
        help="report folder (default ./report)",
    )
    p.add_argument(
        "--clock",
        choices=("lockstep", "realtime"),
        default=None,
        help="lockstep (default with our simulator): results do not depend on machine load; "
        "realtime (the only clock of --ardupilot-bin)",
    )
    p.add_argument("--speedup", type=float, default=1.0, help="realtime clock speed-up")
    p.add_argument(
        "--dialect",
        choices=("px4", "ardupilot"),
        default="px4",
        help="the autopilot dialect our simulator speaks: px4 (default; OFFBOARD) or ardupilot "
        "(ArduCopter's GUIDED_NOGPS, parameters, EKF/GPS readiness); the agents take it from "
        "each vehicle's heartbeat",
    )
    p.add_argument(
        "--ardupilot-bin",
        type=Path,
        default=None,
        metavar="PATH",
        help=f"fly ArduPilot's own ArduCopter SITL instead of our simulator: the arducopter "
        f"binary built for the sitl board (or set {ARDUPILOT_ENV}); one instance per drone, homes "
        "placed as the scenario's layout, real time. docs/autopilots.md says how to build it",
    )
    p.add_argument(
        "--ardupilot-defaults",
        type=Path,
        default=None,
        metavar="FILE",
        help="ArduPilot parameter defaults for every instance (default: "
        "Tools/autotest/default_params/copter.parm of the binary's source tree)",
    )
    p.add_argument(
        "--agents-per-process",
        type=int,
        default=None,
        metavar="K",
        help=f"drones hosted per agent process (default: all in one process up to "
        f"{ONE_PROCESS_UP_TO} drones, the fastest layout measured; more in one process per CPU "
        f"core, at least {MIN_HOSTED_PROCESSES}: each agent process takes ~200 MB and pays its "
        "own messaging; 1 runs each drone's agent in a process of its own, as its companion "
        "computer would)",
    )
    p.add_argument("--signing-key", type=Path, metavar="FILE", help="MAVLink 2 signing key")
    p.add_argument(
        "--zenoh-connect",
        metavar="ENDPOINT",
        help="use this Zenoh endpoint (e.g. a router) instead of the ground station's",
    )
    add_multihost_flags(p)
    p.add_argument("--swarm-id", default="swarm", help="swarm name on Zenoh")
    p.add_argument(
        "--base-port",
        type=int,
        default=None,
        help="vehicle i on UDP BASE+i (default: vehicles 0-9 on 14540-14549 as PX4 SITL, "
        "10-249 on 14560-14799, never the GCS port)",
    )
    p.add_argument("--gcs-port", type=int, default=DEFAULT_GCS_PORT, help="telemetry to the GCS")
    p.add_argument("--duration-s", type=float, metavar="S", help="fly only the first S seconds")
    p.add_argument(
        "--no-plots",
        action="store_true",
        help="the report without its PNG plots (the report is written sooner; for CI and sweeps)",
    )
    p.add_argument(
        "--no-recording",
        action="store_true",
        help="the report without flight.rrd (swarm replay makes it from the tlog when it opens "
        "the report)",
    )
    p.add_argument(
        "--land-at-end",
        action="store_true",
        help="at the scenario's end, land the swarm and end the run once every vehicle is "
        "disarmed on the ground (always so with --ardupilot-bin); without it the run ends with "
        "the swarm where the plan left it",
    )
    p.add_argument(
        "--view",
        action="store_true",
        help="also watch the flight live in Rerun: runs `swarm view` on the report folder and "
        "prints the web viewer's URL (needs pip install 'quadswarm[view]')",
    )
    p.add_argument("--view-web-port", type=int, default=9090, help="--view: web viewer port")
    p.add_argument("--view-grpc-port", type=int, default=9876, help="--view: viewer data port")
    p.add_argument(
        "--view-layout", choices=VIEW_LAYOUTS, default=VIEW_LAYOUTS[0],
        help="--view: the viewer's layout, swarm (default; as swarm view's) or auto (Rerun's own)",
    )  # fmt: skip


def build_plan(
    args: argparse.Namespace, scenario_path: Path, session: SessionRequest | None = None
) -> tuple[RunPlan, int]:
    """The children of the run and the number of drones. With ``session``, the session's
    scenario is generated and written to ``scenario_path`` (in the report's logs folder)."""
    from drone_agent.core.config import agent_config
    from gcs.cli.session import session_scenario, write_text
    from gcs.station.drills import RUN_FILE
    from protocols.scenario.scenario_file import ScenarioError, load_scenario

    if session is None:
        try:
            scenario = load_scenario(scenario_path)
            agent_config(scenario)  # its [agent] controller found and tried once
        except ScenarioError as exc:
            raise SupervisorError(str(exc)) from None
        text = None
    else:
        generated = session_scenario(session, scenario_path)
        scenario, text = generated.scenario, generated.text
    n = scenario.n_drones
    ardupilot_bin = _ardupilot_binary(args)
    args.layout_why = ""
    if args.agents_per_process is None:
        args.agents_per_process = default_agents_per_process(n)
        args.layout_why = (
            f" (the default: all in one process up to {ONE_PROCESS_UP_TO} drones, the fastest "
            "measured; --agents-per-process 1 gives each drone its own)"
            if n <= ONE_PROCESS_UP_TO
            else f" (the default beyond {ONE_PROCESS_UP_TO} drones: one process per CPU core)"
        )
    if args.agents_per_process < 1:
        raise SupervisorError("--agents-per-process must be at least 1")
    duration = scenario.duration_s if args.duration_s is None else args.duration_s
    if session is None and not 0 < duration <= scenario.duration_s:
        raise SupervisorError(f"--duration-s must be in (0, {scenario.duration_s:g}]")
    # a session's --drones N is its size, not the multi-host range of this host's agents
    layout = host_layout(
        args if session is None else argparse.Namespace(**{**vars(args), "drones": None}), n
    )
    multihost = layout.router is not None or layout.secrets is not None
    if multihost and ardupilot_bin is not None:  # the flags' conflict first, then the ports
        raise SupervisorError("--ardupilot-bin flies on one host: no router, secrets or hosts")
    ports = vehicle_ports(n, args.base_port)
    clash = port_clash(ports, args.gcs_port)
    if clash is not None:
        raise SupervisorError(clash)
    if "sim" in layout.parts:
        check_udp_ports(ports[layout.sim_first : layout.sim_last + 1], "vehicle ports", layout.bind)
    if "gcs" in layout.parts:
        check_udp_ports([args.gcs_port], "ground station", layout.bind)
    if multihost:
        return multihost_plan(args, scenario_path, layout, n, duration), n
    report: Path = args.report
    logs = report / "logs"
    try:
        logs.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SupervisorError(f"cannot write the report folder {report}: {exc}") from None
    if text is not None:
        write_text(scenario_path, text)
    endpoint = args.zenoh_connect
    if args.zenoh_connect:
        # the ground station joins that endpoint and listens on a port of its own: left to its
        # default it would take the rendezvous port, which another swarm on the machine may hold
        gcs_zenoh = ["--zenoh-listen", "tcp/127.0.0.1:0", "--zenoh-connect", args.zenoh_connect]
        agent_zenoh = ["--zenoh-listen", "tcp/127.0.0.1:0", "--zenoh-connect", args.zenoh_connect]
    else:
        endpoint = f"tcp/127.0.0.1:{rendezvous_port()}"
        gcs_zenoh = ["--zenoh-listen", endpoint]
        agent_zenoh = ["--zenoh-listen", "tcp/127.0.0.1:0", "--zenoh-connect", endpoint]
    key = flags([("--signing-key", args.signing_key)])
    common = ["--scenario", str(scenario_path)]
    # ArduCopter SITL instances count from their own boot: the swarm clock starts once they
    # are ready (supervisor.EPOCH); the ground station ends the run at the duration
    ardupilot = ardupilot_bin is not None
    clock_flags = ["--swarm-epoch", EPOCH] if ardupilot else []
    # --land-at-end (always with ArduCopter SITL, whose vehicles outlive the run): the ground
    # station lands the swarm at the end and ends the run; the simulator runs on until then
    land_at_end = session is None and (ardupilot or getattr(args, "land_at_end", False))
    gcs_end = ["--duration-s", str(duration), "--land-at-end"] if land_at_end else []
    gcs = Child(
        "gcs",
        swarm_argv(
            "gcs",
            *common,
            "--report",
            str(report),
            "--swarm-id",
            args.swarm_id,
            "--gcs-port",
            str(args.gcs_port),
            "--telemetry-hz",
            str(TELEMETRY_HZ),
            "--run-file",
            str(logs / RUN_FILE),
            *_session_flags(session),
            *key,
            *clock_flags,
            *gcs_end,
            *flags([("--no-plots", args.no_plots), ("--no-recording", args.no_recording)]),
            "--quiet",
            *gcs_zenoh,
        ),
        logs / "gcs.log",
    )
    sim_flags = flags(
        [
            ("--clock", args.clock),
            ("--speedup", args.speedup),
            ("--wait-agents", n),
            ("--join-timeout", 120),
            ("--base-port", args.base_port),  # None (the default layout) is left out
            ("--gcs", f"udp:127.0.0.1:{args.gcs_port}"),
            ("--gcs-rate-hz", TELEMETRY_HZ),
            # a session, or a landing at the end: the ground station ends the run
            ("--duration-s", None if session or land_at_end else duration),
            ("--dialect", None if args.dialect == "px4" else args.dialect),
        ]
    )
    sim: Child | None = None
    vehicles: list[Child] = []
    if ardupilot_bin is None:
        sim = Child("simulator", swarm_argv("sim", *common, *sim_flags, *key), logs / "sim.log")
    else:
        from gcs.cli.ardupilot_sitl import default_params, vehicle_children

        defaults = args.ardupilot_defaults or default_params(ardupilot_bin)
        vehicles = vehicle_children(ardupilot_bin, scenario, ports, args.gcs_port, logs, defaults)
    dialect_flags = ["--dialect", "ardupilot"] if ardupilot or args.dialect != "px4" else []
    if ardupilot:
        dialect_flags += ["--vehicle-listen", *clock_flags]
    groups = agent_groups(n, args.agents_per_process)
    agents = [
        Child(
            f"agent {ids}",
            swarm_argv(
                "agent",
                "--drone-id",
                ids,
                *common,
                *flags([("--base-port", args.base_port)]),
                "--swarm-id",
                args.swarm_id,
                "--quiet",
                *(["--lockstep"] if args.clock == "lockstep" else []),
                *(["--wait-for-plan"] if session else []),  # a session: GROUND until takeoff
                *dialect_flags,
                *agent_zenoh,
                *key,
            ),
            logs / f"agent-{ids}.log",
        )
        for ids in groups
    ]
    drones = agent_ranges(n, args.agents_per_process)
    plan = RunPlan(gcs, sim, agents, drones, logs / RUN_FILE, endpoint)
    plan.rendezvous_picked = not args.zenoh_connect
    if vehicles:
        from gcs.cli.ardupilot_sitl import wait_ready

        plan.vehicles = vehicles
        plan.wait_vehicles = lambda progress: wait_ready(scenario, ports, vehicles, progress)
    if session is not None:
        plan.session = True
        plan.shutdown_wait_s = session.shutdown_timeout_s + REPORT_WAIT_S
    return plan, n


def _ardupilot_binary(args: argparse.Namespace) -> Path | None:
    """The ArduCopter SITL binary to fly (None: our simulator); settles ``--clock`` and refuses
    what ArduCopter SITL cannot do here (gcs/cli/ardupilot_sitl.py)."""
    from gcs.cli.ardupilot_sitl import find_binary

    binary = find_binary(getattr(args, "ardupilot_bin", None))
    if binary is None:
        args.clock = args.clock or "lockstep"
        if getattr(args, "ardupilot_defaults", None) is not None:
            raise SupervisorError("--ardupilot-defaults goes with --ardupilot-bin")
        return None
    if args.clock == "lockstep":
        raise SupervisorError(
            "--ardupilot-bin flies in real time only: ArduCopter SITL steps its own physics "
            "(a lockstep would need our simulator as its physics through --model JSON); leave "
            "--clock out or say --clock realtime"
        )
    if args.speedup != 1.0:
        raise SupervisorError(
            "--ardupilot-bin flies at --speedup 1 only: each ArduCopter instance would speed its "
            "own clock up, while the swarm's clock is the wall clock"
        )
    if args.dialect != "px4":
        raise SupervisorError("--dialect is our simulator's; ArduCopter speaks its own")
    defaults = getattr(args, "ardupilot_defaults", None)
    if defaults is not None and not defaults.is_file():
        raise SupervisorError(f"--ardupilot-defaults {defaults}: no such parameter file")
    args.clock = "realtime"
    return binary


def _session_flags(session: SessionRequest | None) -> list[str]:
    """The ground station's flags of a session."""
    if session is None:
        return []
    return ["--session", "--shutdown-timeout-s", str(session.shutdown_timeout_s)]


#: How long ``--view`` waits for the viewer to print its URL (s).
VIEW_START_S = 30.0


@contextlib.contextmanager
def live_view(args: argparse.Namespace, scenario: Path) -> Iterator[str | None]:
    """With ``--view``: ``swarm view`` on the report folder as a child process (its output in
    logs/view.log) for the length of the block; yields the viewer's URL (None without --view)."""
    if not getattr(args, "view", False):
        yield None
        return
    if not rerun_available():
        raise SupervisorError(f"--view: {INSTALL_HINT}")
    log = args.report / "logs" / "view.log"
    argv = swarm_argv(
        "view", str(args.report), "--scenario", str(scenario),
        "--web-port", str(args.view_web_port), "--grpc-port", str(args.view_grpc_port),
        "--layout", getattr(args, "view_layout", VIEW_LAYOUTS[0]),
    )  # fmt: skip
    with log.open("wb") as out:
        proc = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT)
    try:
        yield _viewer_url(proc, log)
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


def _viewer_url(proc: subprocess.Popen[bytes], log: Path) -> str:
    """The URL ``swarm view`` prints once it serves the viewer."""
    end = time.monotonic() + VIEW_START_S
    while time.monotonic() < end:
        for line in log.read_text(errors="replace").splitlines():
            if "web viewer at " in line:
                return line.split("web viewer at ", 1)[1].strip()
        if proc.poll() is not None:
            break
        time.sleep(0.1)
    tail = log.read_text(errors="replace").strip().splitlines()[-1:] or ["(no output)"]
    raise SupervisorError(f"--view: the viewer did not start: {tail[0]}")


def run(args: argparse.Namespace) -> int:
    """``swarm up`` / ``swarm demo``; exit 0 when the scenario was flown to its end."""
    from gcs.cli.session import SESSION_FILE, session_request
    from gcs.report.summary import summary_lines

    session = session_request(args)
    if session is not None:
        scenario = args.report / "logs" / SESSION_FILE
    else:
        scenario = getattr(args, "scenario", None) or PAPER
    plan, n = build_plan(args, scenario, session)
    tty = sys.stderr.isatty()
    shown = [0.0]
    said = [""]

    def progress(line: str) -> None:
        if not line:
            return
        if not line.startswith("sim "):  # news (once each), not the simulator's status line
            if line != said[0]:
                said[0] = line
                print(f"\r{line:<150}" if tty else line, file=sys.stderr, flush=True)
        elif tty:
            print(f"\r{line[:150]:<150}", end="", file=sys.stderr, flush=True)
        elif time.monotonic() - shown[0] >= 10.0:
            print(line, file=sys.stderr, flush=True)
            shown[0] = time.monotonic()

    parts = [c.role.split()[0] for c in plan.children]
    hosting = ""
    if args.agents_per_process > 1 and len(plan.agents) > 1:
        hosting = f" of up to {args.agents_per_process} drones each"
    processes = f"{len(plan.agents)} agent process{'es' if len(plan.agents) != 1 else ''}"
    plan.layout = (
        f"{n} drones, {processes}{hosting}{getattr(args, 'layout_why', '')}, {args.clock} clock"
    )
    print(
        f"swarm up: {plan.layout}; "
        f"here: {', '.join(dict.fromkeys(parts))}; logs in {args.report / 'logs'}",
        file=sys.stderr,
    )
    secrets = f" --secrets {args.secrets}" if args.secrets is not None else ""
    print(
        f"swarm up: operator commands and drills: swarm status --swarm-id {args.swarm_id} "
        f"--zenoh-connect {plan.zenoh_endpoint}{secrets}",
        file=sys.stderr,
    )
    if session is not None:
        print(
            f"swarm up: an operator session: {n} drones ({session.layout}, "
            f"{session.spacing_m:g} m apart, radio {session.range_m:g} m) wait on the ground. "
            "Fly them with swarm takeoff --altitude-m 3, then swarm formation / move / rotate / "
            "scale / hold / land; swarm shutdown (or Ctrl-C here) lands them, writes the report "
            "and stops everything",
            file=sys.stderr,
        )
    warm_compiled(
        "swarm up", plan.sim is not None, bool(plan.agents), Path(scenario),
        links=plan.sim is not None,
    )  # fmt: skip
    with interrupt_flag() as stop, live_view(args, scenario) as url:
        if url is not None:
            print(f"swarm up: live view (Rerun) at {url}", file=sys.stderr, flush=True)
        reason = supervise(plan, progress, stop)
    if tty:
        print(file=sys.stderr)
    print(f"swarm up: {reason}", file=sys.stderr)
    metrics_path = args.report / "metrics.json"
    if metrics_path.exists():
        metrics = json.loads(metrics_path.read_text())
        files = sorted(p for p in args.report.iterdir() if p.is_file())
        for line in summary_lines(metrics, files):
            print(line)
    if plan.gcs is not None and plan.gcs.killed:
        print(
            f"swarm up: the ground station was stopped before it had finished the report (a "
            f"Ctrl-C while it wrote it, or {plan.report_stop_s:g} s after the run ended: a machine "
            f"too loaded): {args.report} may lack plots or metrics (log: {plan.gcs.log})",
            file=sys.stderr,
        )
        return 1
    return 0 if reason in ("finished", SHUT_DOWN) else 1

"""``swarm up``: the simulator, the agents and the ground station as supervised child processes.

Start order: the ground station (the Zenoh rendezvous; it publishes the plan and records the
flight), the simulator once the ground station says it records telemetry (lockstep waits for every
agent), then the agents, one process per drone or ``--agents-per-process`` drones per process. The
run ends when the simulator reaches the scenario's duration, on Ctrl-C / SIGTERM, when the ground
station ends the run (``swarm shutdown``: it lands the swarm, writes the report and exits 0), or
when the simulator or the ground station dies; an agent process that ends is a drone leaving the
swarm, which flies on. Then every child is stopped (SIGTERM, then SIGKILL) so that no process of
the run is left and its ports are free. The ground station writes the report when it is stopped.

In an operator session (``RunPlan.session``) the first Ctrl-C / SIGTERM is a shutdown: the ground
station gets SIGINT, lands the swarm if it flies, writes the report and exits; the others are
stopped after it. A second Ctrl-C, or no end within ``shutdown_wait_s``, stops everything at once.
The children run in their own process group, so a Ctrl-C typed in the terminal reaches only the
supervisor, which decides what each child gets.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

PR_SET_PDEATHSIG = 1
STOP_TIMEOUT_S = 15.0
#: The ground station writes the report when it is stopped (metrics, plots, the Rerun
#: recording): it gets this long (s) before SIGKILL, not STOP_TIMEOUT_S. The paper's 200 s flight
#: under a test suite's load was killed after two of its three plots at 15 s.
REPORT_STOP_S = 120.0


class SupervisorError(Exception):
    """The run could not start or a child failed: one line for the user."""


def _die_with_parent() -> None:  # pragma: no cover - runs in the child before exec
    """Linux: the child gets SIGTERM if the supervisor dies, so no orphan outlives a crash. It
    gets a process group of its own: the terminal's Ctrl-C goes to the supervisor alone."""
    with contextlib.suppress(OSError):
        os.setpgid(0, 0)
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


@dataclass
class Child:
    """A supervised process: its role, command line and log file."""

    role: str
    argv: list[str]
    log: Path
    proc: subprocess.Popen[bytes] | None = None
    expected_exit: bool = False
    #: where this start's output begins in ``log`` (a report folder used again keeps older runs)
    log_start: int = 0
    #: :meth:`stop` had to kill it (it did not end within its timeout after SIGTERM)
    killed: bool = False
    #: its working folder (None: the supervisor's)
    cwd: Path | None = None

    def start(self) -> None:
        self.killed = False
        with self.log.open("ab") as out:
            self.log_start = out.tell()
            self.proc = subprocess.Popen(
                self.argv, stdout=out, stderr=subprocess.STDOUT, preexec_fn=_die_with_parent,
                cwd=self.cwd,
            )  # fmt: skip

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def last_line(self) -> str:
        """The last line this start of the process wrote ("" before its first)."""
        return _last_line(self.log, self.log_start)

    def stop(
        self, timeout_s: float = STOP_TIMEOUT_S, give_up: Callable[[], bool] | None = None
    ) -> int | None:
        """SIGTERM, wait (at most ``timeout_s``, or until ``give_up()``: checked every 0.1 s),
        then SIGKILL; the exit code (None if never started)."""
        if self.proc is None:
            return None
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            deadline = time.monotonic() + timeout_s
            while self.proc.poll() is None:
                left = deadline - time.monotonic()
                if left <= 0 or (give_up is not None and give_up()):
                    self.killed = True
                    self.proc.kill()
                    self.proc.wait(5)
                    break
                with contextlib.suppress(subprocess.TimeoutExpired):
                    self.proc.wait(min(left, 0.1) if give_up is not None else left)
        return self.proc.returncode


@dataclass
class RunPlan:
    """Everything ``swarm up`` starts, in order."""

    gcs: Child | None
    sim: Child | None
    agents: list[Child] = field(default_factory=list)
    #: drones of each agent process (same order as ``agents``)
    agent_drones: list[range] = field(default_factory=list)
    #: where the agents' process ids go, for the ground station's dropout drill
    run_file: Path | None = None
    #: the Zenoh endpoint of the run (operator commands and drills connect to it)
    zenoh_endpoint: str | None = None
    #: the swarm's Zenoh router, when this run starts it (started first)
    router: Child | None = None
    #: an operator session: a Ctrl-C asks the ground station to land and end the run
    session: bool = False
    #: how the agents are laid out in processes, and why (the run file carries it to the report)
    layout: str = ""
    #: session: how long (wall s) to wait for the ground station to end the run after a Ctrl-C
    shutdown_wait_s: float = 180.0
    #: how long (wall s) the ground station may take to write the report once stopped
    report_stop_s: float = REPORT_STOP_S
    #: the ground station listens on ``zenoh_endpoint``, a port picked here because it was free
    #: (:func:`rendezvous_port`): if another process binds it before the ground station does,
    #: the run starts again on another free port (:meth:`move_rendezvous`)
    rendezvous_picked: bool = False
    #: autopilots of another project (ArduCopter SITL, gcs/cli/ardupilot_sitl.py), started
    #: first; ``wait_vehicles(progress)`` returns once they can fly, and the swarm's clock
    #: starts then: :data:`EPOCH` in the other children's arguments becomes that Unix time
    vehicles: list[Child] = field(default_factory=list)
    wait_vehicles: Callable[[Callable[[str], None] | None], None] | None = None

    @property
    def children(self) -> list[Child]:
        """Every child, in start order: vehicles, router, ground station, simulator, agents (a
        partial start on one host of several has only some of them)."""
        return (
            self.vehicles
            + [c for c in (self.router, self.gcs, self.sim) if c is not None]
            + self.agents
        )

    def move_rendezvous(self, endpoint: str) -> None:
        """Every child's Zenoh flags name ``endpoint`` instead of the run's endpoint now."""
        old = self.zenoh_endpoint
        for child in self.children:
            child.argv = [endpoint if arg == old else arg for arg in child.argv]
        self.zenoh_endpoint = endpoint

    def write_run_file(self) -> None:
        """``{"zenoh": endpoint, "agents": {"<drone>": pid}, "layout": text}``: the run's Zenoh
        endpoint, the agent processes started so far and how they host the agents, and why."""
        if self.run_file is None:
            return
        pids = {
            str(d): child.proc.pid
            for child, drones in zip(self.agents, self.agent_drones, strict=True)
            if child.proc is not None
            for d in drones
        }
        tmp = self.run_file.with_suffix(".tmp")
        about = {"zenoh": self.zenoh_endpoint, "agents": pids, "layout": self.layout}
        tmp.write_text(json.dumps(about) + "\n")
        tmp.replace(self.run_file)  # atomic: the ground station never reads half a file


def free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def rendezvous_port() -> int:
    """The agents' default rendezvous port (where ``swarm status`` etc. look by default) if it is
    free, else any free TCP port."""
    from protocols.bus.zenoh_bus import tcp_listen_free
    from protocols.bus.zenoh_config import RENDEZVOUS_PORT

    return RENDEZVOUS_PORT if tcp_listen_free(RENDEZVOUS_PORT) else free_tcp_port()


#: How many times a run moves to another rendezvous port taken between the check and the bind.
RENDEZVOUS_MOVES = 3
#: What the ground station says when its Zenoh listener's port is taken (Zenoh's bind error).
PORT_TAKEN = "Address already in use"


def _rendezvous_taken(plan: RunPlan) -> bool:
    """Whether the ground station ended because another process took the rendezvous port this
    run picked while it was free (check, then bind: a swarm started at the same moment)."""
    if not plan.rendezvous_picked or plan.gcs is None:
        return False
    said = plan.gcs.last_line()
    return PORT_TAKEN in said and f":{str(plan.zenoh_endpoint).rpartition(':')[2]}:" in said


def check_udp_ports(ports: list[int], what: str, host: str = "127.0.0.1") -> None:
    """SupervisorError naming the port if any of ``ports`` (UDP on ``host``) is taken."""
    for port in ports:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind((host, port))
            except OSError:
                raise SupervisorError(
                    f"UDP port {port} ({what}) is in use: is another swarm running? "
                    "Choose other ports with --base-port / --gcs-port"
                ) from None


def agent_ranges(n: int, per_process: int) -> list[range]:
    """The drones of each agent process: ``per_process`` consecutive drones per process."""
    return [range(lo, min(lo + per_process, n)) for lo in range(0, n, per_process)]


def agent_groups(n: int, per_process: int) -> list[str]:
    """``--drone-id`` values of :func:`agent_ranges`."""
    return [
        f"{r.start}-{r.stop - 1}" if per_process > 1 else str(r.start)
        for r in agent_ranges(n, per_process)
    ]


def swarm_argv(*args: str) -> list[str]:
    return [sys.executable, "-m", "gcs.cli", *args]


#: Why a run ended when the ground station ended it (``swarm shutdown``, or Ctrl-C in a session).
SHUT_DOWN = "shut down"
#: A placeholder argument: the swarm clock's epoch (Unix s), set once the vehicles are ready.
EPOCH = "{swarm-epoch}"


def supervise(
    plan: RunPlan,
    progress: Callable[[str], None] | None = None,
    should_stop: Callable[[], int] = lambda: 0,
    poll_s: float = 0.5,
) -> str:
    """Start every child, watch them, stop them all. Returns why the run ended: "finished",
    :data:`SHUT_DOWN` (the ground station ended the run), "interrupted" or what failed.
    ``should_stop``: how many times the user asked to stop (Ctrl-C).

    The run ends with the simulator when this host runs it, else with the ground station, else
    (agents only) when every agent process has ended (their vehicles went silent: the simulator
    on another host ended), or on Ctrl-C; a router alone runs until Ctrl-C."""
    reason = "stopped"
    shutdown_deadline: float | None = None
    moves = 0
    try:
        _start(plan, progress)
        while True:
            asked = should_stop()
            if asked and not (plan.session and asked < 2):
                reason = "interrupted"
                break
            if asked and shutdown_deadline is None:  # a session lands first; the gcs ends it
                shutdown_deadline = time.monotonic() + plan.shutdown_wait_s
                _signal(plan.gcs, signal.SIGINT)
                if progress is not None:
                    progress("shutting down: the swarm lands (Ctrl-C again: stop at once)")
            elif shutdown_deadline is not None and time.monotonic() > shutdown_deadline:
                reason = "interrupted (the shutdown took too long)"
                break
            if plan.router is not None and not plan.router.running:
                code = plan.router.proc.returncode if plan.router.proc else None
                reason = f"the Zenoh router exited with code {code} (log: {plan.router.log})"
                break
            if plan.sim is not None and not plan.sim.running:
                code = plan.sim.proc.returncode if plan.sim.proc else None
                reason = "finished" if code == 0 else f"the simulator exited with code {code}"
                break
            if plan.gcs is None:
                if plan.agents and not any(a.running for a in plan.agents):
                    reason = _agents_ended(plan.agents)
                    break
                _watch_agents(plan, progress)
                if progress is not None and plan.sim is not None:
                    progress(plan.sim.last_line())
                time.sleep(poll_s)
                continue
            gcs_proc = plan.gcs.proc
            if plan.sim is None and gcs_proc is not None and gcs_proc.poll() == 0:
                reason = "finished"
                break
            if not plan.gcs.running and _restart_asked(plan.gcs):
                if "--resume" not in plan.gcs.argv:
                    plan.gcs.argv.append("--resume")
                plan.gcs.start()
                if progress is not None:
                    progress("the ground station restarts (gcs-restart drill)")
            if not plan.gcs.running:
                code = plan.gcs.proc.returncode if plan.gcs.proc else None
                if code == 0:  # it ended the run: swarm shutdown, or a session's Ctrl-C
                    reason = SHUT_DOWN
                elif moves < RENDEZVOUS_MOVES and _rendezvous_taken(plan):
                    moves += 1
                    _move_rendezvous(plan, progress)
                    continue
                else:
                    reason = f"the ground station exited with code {code} (log: {plan.gcs.log})"
                break
            _watch_agents(plan, progress)
            if progress is not None:
                progress((plan.sim or plan.gcs).last_line())
            time.sleep(poll_s)
    finally:
        # the ground station first, so the report ends with the flight, not with the shutdown
        # (given the time to write it); the router last, so everyone leaves it cleanly
        if progress is not None and plan.gcs is not None and plan.gcs.running:
            progress("the ground station writes the report ... (Ctrl-C: stop it at once)")
        asked_before = should_stop()  # another Ctrl-C while it writes: no report, stop now
        if plan.gcs is not None:
            plan.gcs.stop(plan.report_stop_s, lambda: should_stop() > asked_before)
        for last in [*plan.agents, plan.sim, plan.router, *plan.vehicles]:
            if last is not None:
                last.stop()
    return reason


def _start(plan: RunPlan, progress: Callable[[str], None] | None = None) -> None:
    """Start the children in order (other projects' vehicles first, then, once they can fly,
    everything else on a swarm clock starting now; a router: once it listens; the simulator:
    once the ground station records; the agents: once the simulator's ports are bound) and write
    the run file."""
    from gcs.cli.gcs import RECORDING
    from sitl_sim.launch import START_LINE_PREFIX

    for vehicle in plan.vehicles:
        vehicle.start()
    if plan.wait_vehicles is not None:
        plan.wait_vehicles(progress)
    epoch = f"{time.time():.3f}"
    for child in plan.children:
        child.argv = [epoch if arg == EPOCH else arg for arg in child.argv]
    for child in plan.children:
        if any(child is vehicle for vehicle in plan.vehicles):
            continue
        child.start()
        if child is plan.router:
            _wait_listening(plan.zenoh_endpoint, child)
        elif child is plan.gcs:
            # a simulator started before would fly its first seconds unrecorded on a loaded
            # machine (the ground station's start takes ~0.6 s of CPU)
            _wait_said(child, RECORDING)
        elif child is plan.sim:
            # an agent binds an ephemeral UDP port for its vehicle link: before the simulator
            # has bound its block (free ports picked in the ephemeral range), one of a hundred
            # agents' ports may land on a vehicle's ("UDP port ... is in use")
            _wait_said(child, START_LINE_PREFIX)
        time.sleep(0.05)
    plan.write_run_file()


def _wait_said(child: Child, text: str, timeout_s: float = 30.0) -> None:
    """Wait until ``child`` has printed ``text`` in this run's log. Returns early when it ends
    (the caller reads why) and at the timeout."""
    deadline = time.monotonic() + timeout_s
    while child.running and time.monotonic() < deadline:
        if text.encode() in _read_from(child.log, child.log_start):
            return
        time.sleep(0.02)


def _move_rendezvous(plan: RunPlan, progress: Callable[[str], None] | None) -> None:
    """The rendezvous port was taken before the ground station bound it: stop what started (no
    vehicle has flown: the ground station ends within its first second) and start everything
    again on a free port."""
    taken = plan.zenoh_endpoint
    for child in [plan.gcs, *plan.agents, plan.sim]:
        if child is not None:
            child.stop()
    plan.move_rendezvous(f"tcp/127.0.0.1:{free_tcp_port()}")
    if progress is not None:
        folder = None if plan.run_file is None else _session_folder(plan.run_file)
        follow = "" if folder is None else f"typed in {folder} they find it; elsewhere "
        progress(
            f"{taken} was taken by another process as the run started: Zenoh moves to "
            f"{plan.zenoh_endpoint} (operator commands: {follow}--zenoh-connect "
            f"{plan.zenoh_endpoint})"
        )
    _start(plan)


def _session_folder(run_file: Path) -> str | None:
    """The folder where operator commands find a run whose run file is ``run_file`` by
    themselves ("this folder" for the current one), None if there is none (a report folder not
    named ``report``)."""
    from gcs.cli.operator import SESSION_RUN_FILE

    root = run_file
    for _ in SESSION_RUN_FILE.parts:
        root = root.parent
    if root / SESSION_RUN_FILE != run_file:
        return None
    try:
        return "this folder" if root.resolve() == Path.cwd().resolve() else str(root)
    except OSError:
        return str(root)


def _signal(child: Child | None, sig: int) -> None:
    if child is not None and child.proc is not None and child.proc.poll() is None:
        child.proc.send_signal(sig)


def _agents_ended(agents: list[Child]) -> str:
    """Why a run of agents only ended: "finished" when they all left cleanly (their vehicles
    stopped), else the first failure."""
    for a in agents:
        code = a.proc.returncode if a.proc is not None else None
        if code not in (0, None):
            return f"{a.role} exited with code {code} (log: {a.log})"
    return "finished"


def _watch_agents(plan: RunPlan, progress: Callable[[str], None] | None) -> None:
    for agent in plan.agents:
        if not agent.running and not agent.expected_exit:
            # a drone drop-out, not a failure of the run: the swarm flies on
            agent.expected_exit = True
            code = agent.proc.returncode if agent.proc else None
            if progress is not None:
                progress(f"{agent.role} exited with code {code}; the swarm flies on")


def _wait_listening(endpoint: str | None, child: Child, timeout_s: float = 15.0) -> None:
    """Wait until the router ``child`` accepts TCP connections at ``endpoint``; SupervisorError
    if it ends or does not listen in time."""
    if endpoint is None:
        return
    host, _, port = endpoint.partition("/")[2].rpartition(":")
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if not child.running:
            raise SupervisorError(
                f"the Zenoh router did not start: {child.last_line()} (log: {child.log})"
            )
        with contextlib.suppress(OSError), socket.create_connection((host, int(port)), 0.5):
            return
        time.sleep(0.1)
    raise SupervisorError(f"the Zenoh router does not listen on {endpoint} (log: {child.log})")


def _restart_asked(child: Child) -> bool:
    """The child ended with the gcs-restart drill's exit code."""
    from gcs.cli.gcs import RESTART_EXIT_CODE

    return child.proc is not None and child.proc.returncode == RESTART_EXIT_CODE


def _read_from(path: Path, since: int) -> bytes:
    """What ``path`` holds after byte ``since`` (b"" if unreadable)."""
    try:
        with path.open("rb") as f:
            f.seek(since)
            return f.read()
    except OSError:
        return b""


def _last_line(path: Path, since: int = 0) -> str:
    """The last non-empty line of ``path`` after byte ``since``."""
    try:
        with path.open("rb") as f:
            size = f.seek(0, 2)
            f.seek(max(since, size - 400))
            data = f.read()
    except OSError:
        return ""
    lines = [ln for ln in data.replace(b"\r", b"\n").split(b"\n") if ln.strip()]
    return lines[-1].decode(errors="replace").strip() if lines else ""


@contextlib.contextmanager
def interrupt_flag() -> Iterator[Callable[[], int]]:
    """SIGINT/SIGTERM are counted (the returned callable says how many arrived; 0 is false)
    instead of raising."""
    hit: list[int] = []

    def handler(sig: int, _frame: object) -> None:
        hit.append(sig)

    old = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield lambda: len(hit)
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def flags(values: Sequence[tuple[str, object | None]]) -> list[str]:
    """``--flag value`` pairs for the values that are set."""
    out: list[str] = []
    for name, value in values:
        if value is None or value is False:
            continue
        out += [name] if value is True else [name, str(value)]
    return out

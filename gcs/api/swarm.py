""":class:`Swarm`: a running swarm driven from Python, the one implementation behind the
``swarm`` operator commands and drills (gcs/cli/operator.py, gcs/cli/drill.py call it).

Each command sends one request to the ground station and returns a :class:`Command` (or raises
:class:`~gcs.api.errors.CommandRefused` with the reason ``swarm`` prints); ``Command.wait()``
follows the swarm until the change arrived (:func:`gcs.api.state.arrived`).
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

from gcs.api.errors import (
    CommandRefused,
    NoGroundStation,
    StartError,
    SwarmError,
    UsageError,
    WaitTimeout,
)
from gcs.api.link import ANSWER_TIMEOUT_S, Link, role_secrets
from gcs.api.requests import (
    AGENT_DRILLS,
    GCS_DRILLS,
    PLAN_COMMANDS,
    command_request,
    drill_request,
    fault_command,
)
from gcs.api.state import Descriptors, Sent, Status, arrived, baseline, descriptors_from, status_of

if TYPE_CHECKING:
    from gcs.api.launch import Launched
    from gcs.api.report import FlightReport
    from gcs.station.commands import Reply, Request
    from protocols.faults import FaultCommand
    from protocols.secrets.swarm_secrets import RoleSecrets

#: The ground station's endpoint ``swarm up`` uses on the default ports.
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
#: How long :meth:`Command.wait` waits by default (wall s).
WAIT_TIMEOUT_S = 120.0
#: How long :meth:`Swarm.start` waits for the swarm to come up (wall s).
START_TIMEOUT_S = 120.0
#: How long a swarm :meth:`Swarm.start` brought up gets to answer a request (wall s).
STARTED_ANSWER_S = 10.0
#: How long :meth:`Swarm.close` gives a session to land and write its report (wall s).
LAND_TIMEOUT_S = 300.0


@dataclass
class Command:
    """An accepted plan command: the ground station's ``reply`` (``reason`` as ``swarm``
    prints it, the new plan's ``seq``, when its change ``arrives_s`` on the plan's clock) and how
    long the answer took (``elapsed_s``). :meth:`wait` follows it until it arrived."""

    name: str
    reply: Reply
    elapsed_s: float
    swarm: Swarm
    sent: Sent

    @property
    def reason(self) -> str:
        return self.reply.reason

    @property
    def seq(self) -> int:
        return self.sent.seq

    @property
    def arrives_s(self) -> float:
        return self.sent.arrives_s

    def done(self) -> bool:
        """Whether the change has arrived now (one status request); raises as :meth:`wait`."""
        return arrived(self.sent, self.swarm.status())

    def wait(self, timeout_s: float = WAIT_TIMEOUT_S, poll_s: float = 0.1) -> Status:
        """Return the swarm's status once the change arrived: the swarm's time passed the plan's
        arrival (as late as the swarm flies the plan); a ``land`` once every drone is LANDED and
        disarmed. Raises WaitTimeout after ``timeout_s`` wall seconds, Failsafe when a vehicle
        failed safe or a drone was lost meanwhile, Superseded when a later plan replaced this
        one."""
        deadline = time.monotonic() + timeout_s
        while True:
            status = self.swarm.poll(deadline)
            if status is None:
                continue
            if arrived(self.sent, status):
                return status
            if time.monotonic() > deadline:
                raise WaitTimeout(
                    f"{self.name} (plan {self.seq}) had not arrived after {timeout_s:g} s: the "
                    f"swarm is at t = {status.t_s:.1f} s, arrival at t = {self.arrives_s:.1f} s "
                    + ("(still on the ground)" if status.plan_late_s is None else
                       f"+ {status.plan_late_s:.1f} s late")
                )  # fmt: skip
            time.sleep(poll_s)


@dataclass(frozen=True)
class Drill:
    """A drill done: ``what`` (``sent link_cut 0<->1 for 5 s``, or the ground station's reason),
    the ``fault`` command published to the agents or the ground station's ``reply``."""

    name: str
    what: str
    fault: FaultCommand | None
    reply: Reply | None


class Swarm:
    """A swarm to command: :meth:`start` brings one up (and ends it on leaving the ``with``),
    :meth:`connect` joins one already running. Commands take the ``swarm`` flags' names."""

    def __init__(self, link: Link, launched: Launched | None = None) -> None:
        self.link = link
        self.launched = launched
        #: how long a request waits for the ground station's answer (wall s): the CLI's 2 s for
        #: a joined swarm; :meth:`start` gives its own swarm, on this machine, 10 s (only a
        #: loaded machine keeps it silent that long)
        self.answer_timeout_s = ANSWER_TIMEOUT_S if launched is None else STARTED_ANSWER_S
        #: the report read back once a swarm this object started has ended (:meth:`close`)
        self.report: FlightReport | None = None
        #: why the run ended, as ``swarm up`` said it (a started swarm, after :meth:`close`)
        self.end_reason: str | None = None

    # -- lifecycle ---------------------------------------------------------------------------
    @classmethod
    def connect(
        cls,
        endpoint: str = DEFAULT_ENDPOINT,
        swarm_id: str = "swarm",
        secrets: RoleSecrets | str | Path | None = None,
        role: str = "operator",
    ) -> Swarm:
        """Join the swarm ``swarm_id`` whose ground station (or router) is at ``endpoint``, with
        ``secrets`` (a folder of ``swarm keys init``, its ``role``'s credential) if it is secured.
        NoGroundStation if nothing answers there."""
        return cls(Link(endpoint, swarm_id, role_secrets(secrets, swarm_id, role)))

    @classmethod
    def start(
        cls,
        scenario: str | Path | None = None,
        *,
        drones: int | None = None,
        clock: str = "lockstep",
        report: str | Path | None = None,
        swarm_id: str = "swarm",
        seed: int | None = None,
        layout: str | None = None,
        spacing_m: float | None = None,
        range_m: float | None = None,
        duration_s: float | None = None,
        agents_per_process: int | None = None,
        start_timeout_s: float = START_TIMEOUT_S,
    ) -> Swarm:
        """Bring a swarm up with ``swarm up``: a ``scenario`` file flown to its end (or
        ``duration_s``), or an operator session of ``drones`` on the ground waiting for
        :meth:`takeoff` (``layout``, ``spacing_m``, ``range_m``, ``seed`` as ``swarm up
        --drones``). ``clock``: lockstep (default) or realtime. ``report``: the report folder
        (default: a new temporary folder). On free ports. Returns once the ground station
        answers; use it as a context manager, which ends the run (a session lands first) and
        reads the report into :attr:`report`, also when the block raises."""
        from gcs.api.launch import launch, stop, up_words, wait_started
        from protocols.bus.zenoh_bus import ZenohBus, ZenohSettings, free_loopback_endpoint

        what, n = up_words(
            scenario, drones, clock, seed=seed, layout=layout, spacing_m=spacing_m,
            range_m=range_m, duration_s=duration_s, agents_per_process=agents_per_process,
        )  # fmt: skip
        folder = Path(report) if report is not None else Path(tempfile.mkdtemp(prefix="swarm-"))
        endpoint = free_loopback_endpoint()
        bus = ZenohBus.open(ZenohSettings(listen=(endpoint,)))
        launched = None
        try:
            launched = launch(what, n, folder.resolve(), endpoint, swarm_id, clock)
            swarm = cls(Link(endpoint, swarm_id, bus=bus), launched)
            wait_started(launched, start_timeout_s)
            swarm._wait_answer(start_timeout_s)
        except BaseException:
            if launched is not None:
                stop(launched, 10.0)
            bus.close()
            raise
        return swarm

    def _wait_answer(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                self.status()
                return
            except NoGroundStation:
                launched = self.launched
                if launched is not None and launched.proc.poll() is not None:
                    raise StartError(f"swarm up ended: {launched.last_line()}") from None
                if time.monotonic() > deadline:
                    raise

    def __enter__(self) -> Swarm:
        return self

    def __exit__(
        self, _t: type[BaseException] | None, _e: BaseException | None, _tb: TracebackType | None
    ) -> None:
        self.close()

    @property
    def report_dir(self) -> Path | None:
        """The report folder of a swarm this object started."""
        return None if self.launched is None else self.launched.report_dir

    @property
    def running(self) -> bool:
        """Whether the ``swarm up`` this object started still runs (True for a connected one)."""
        return self.launched is None or self.launched.proc.poll() is None

    def wait_end(self, timeout_s: float) -> str:
        """Wait until a started scenario run ends by itself (its duration); why it ended.
        WaitTimeout if it still runs after ``timeout_s`` wall seconds."""
        if self.launched is None:
            raise UsageError("wait_end: only a swarm started by Swarm.start ends by itself")
        try:
            self.launched.proc.wait(timeout_s)
        except Exception:
            raise WaitTimeout(f"the run still flies after {timeout_s:g} s") from None
        return self.launched.end_reason()

    def close(self, land_timeout_s: float = LAND_TIMEOUT_S) -> None:
        """A started swarm: end the run as Ctrl-C to ``swarm up`` does (a session lands first,
        then the ground station writes the report), read the report into :attr:`report`. A
        connected one: close the session. Idempotent."""
        from gcs.api.launch import stop
        from gcs.api.report import load_report

        launched, self.launched = self.launched, None
        try:
            if launched is not None:
                stop(launched, land_timeout_s)
                self.end_reason = launched.end_reason()
                if (launched.report_dir / "metrics.json").exists():
                    self.report = load_report(launched.report_dir)
        finally:
            self.link.close()
            self.launched = None

    # -- requests ----------------------------------------------------------------------------
    def ask(self, request: Request, timeout_s: float | None = None) -> tuple[Reply, float]:
        """Send one request; the reply (accepted or not) and how long it took (s).
        NoGroundStation after ``timeout_s`` (default :attr:`answer_timeout_s`) without one."""
        return self.link.ask(request, self.answer_timeout_s if timeout_s is None else timeout_s)

    def _accepted(self, request: Request) -> tuple[Reply, float]:
        reply, elapsed = self.ask(request)
        if not reply.accepted:
            raise CommandRefused(request.name, reply, elapsed)
        return reply, elapsed

    def _plan_request(self, name: str, kwargs: dict[str, Any]) -> Request:
        if name not in PLAN_COMMANDS:
            known = ", ".join(PLAN_COMMANDS)
            raise UsageError(f"{name!r} is not a plan command; those are {known}")
        return command_request(name, **kwargs)

    def send(self, name: str, **kwargs: Any) -> tuple[Reply, float]:
        """Send plan command ``name`` without following it (what ``swarm NAME`` does): the
        accepted reply and how long it took (s); CommandRefused with the ground station's
        reason."""
        return self._accepted(self._plan_request(name, kwargs))

    def command(self, name: str, **kwargs: Any) -> Command:
        """Send plan command ``name`` (takeoff, formation, move, rotate, scale, hold, land) with
        the ``swarm`` flags' arguments; CommandRefused with the ground station's reason. The
        :class:`Command` follows it from the swarm's state just before."""
        request = self._plan_request(name, kwargs)
        before = self.status()
        reply, elapsed = self._accepted(request)
        seq = reply.seq if reply.seq is not None else (before.plan_seq or 0) + 1
        arrives = reply.arrives_s if reply.arrives_s is not None else before.t_s
        return Command(name, reply, elapsed, self, baseline(name, seq, arrives, before))

    def takeoff(self, altitude_m: float, duration_s: float | None = None) -> Command:
        """Climb (or descend) the swarm's centre to ``altitude_m`` up; drones on the ground arm
        once their estimates settled."""
        return self.command("takeoff", altitude_m=altitude_m, duration_s=duration_s)

    def formation(
        self,
        centre: Sequence[float] | None = None,
        *,
        centre_ned_m: Sequence[float] | None = None,
        heading_deg: float | None = None,
        length_m: float | None = None,
        width_m: float | None = None,
        height_m: float | None = None,
        duration_s: float | None = None,
    ) -> Command:
        """Set the formation: ``centre`` (north, east, altitude up; m) or ``centre_ned_m``,
        heading, and the length/width/height spreads (m); what is left out stays."""
        return self.command(
            "formation", centre=centre, centre_ned_m=centre_ned_m, heading_deg=heading_deg,
            length_m=length_m, width_m=width_m, height_m=height_m, duration_s=duration_s,
        )  # fmt: skip

    def move(
        self,
        north_m: float = 0.0,
        east_m: float = 0.0,
        up_m: float = 0.0,
        duration_s: float | None = None,
    ) -> Command:
        """Move the formation by north/east/up metres."""
        return self.command(
            "move", north_m=north_m, east_m=east_m, up_m=up_m, duration_s=duration_s
        )

    def rotate(self, delta_deg: float, duration_s: float | None = None) -> Command:
        """Turn the formation's heading by ``delta_deg`` degrees (positive: clockwise seen from
        above)."""
        return self.command("rotate", delta_deg=delta_deg, duration_s=duration_s)

    def scale(self, factor: float, duration_s: float | None = None) -> Command:
        """Scale the formation's spreads by ``factor``."""
        return self.command("scale", factor=factor, duration_s=duration_s)

    def hold(self) -> Command:
        """Stop the formation where it can and hover there."""
        return self.command("hold")

    def land(self) -> Command:
        """Land every drone; ``wait()`` returns once all are LANDED and disarmed."""
        return self.command("land")

    def shutdown(self) -> Reply:
        """End the run: land the swarm if it flies, write the report; ``swarm up`` then stops
        everything. The reply says what happens."""
        return self._accepted(command_request("shutdown"))[0]

    # -- drills ------------------------------------------------------------------------------
    def drill(self, name: str, **kwargs: Any) -> Drill:
        """Drill ``name`` with the ``swarm drill`` arguments: ``link-cut`` (i, j, for_s,
        one_way), ``loss`` (probability, link, for_s), ``delay`` (delay_ms, link),
        ``partition`` (groups or heal), ``clear``, ``restart`` (drone, gap_s): sent to every
        agent; ``crash``, ``dropout`` (drone), ``gcs-restart``: carried out by the ground
        station, CommandRefused when it refuses. The :class:`Drill` says what was done."""
        if name in GCS_DRILLS:
            request = drill_request(name, kwargs.get("drone", 0))
            reply = self._accepted(request)[0]
            return Drill(name, reply.reason, None, reply)
        if name not in AGENT_DRILLS:
            known = ", ".join(AGENT_DRILLS + GCS_DRILLS)
            raise UsageError(f"unknown drill {name!r}; known: {known}")
        from drone_agent.process.fault_drills import describe

        command = fault_command(name, **kwargs)
        self.link.publish_fault(command)
        return Drill(name, f"sent {describe(command)}", command, None)

    # -- state -------------------------------------------------------------------------------
    def status(self) -> Status:
        """The ground station's per-drone table as arrays (:class:`~gcs.api.state.Status`)."""
        reply, _ = self.ask(command_request("status"))
        return status_of(reply.t_s, reply.plan, reply.seq, reply.table)

    def poll(self, deadline: float | None = None) -> Status | None:
        """:meth:`status`, or None when the ground station did not answer in time (a loaded
        machine) and the monotonic ``deadline`` (None: none) has not passed; NoGroundStation
        after it, SwarmError if the run this object started has ended."""
        try:
            return self.status()
        except NoGroundStation:
            if not self.running and self.launched is not None:
                raise SwarmError(f"the run ended: {self.launched.end_reason()}") from None
            if deadline is not None and time.monotonic() > deadline:
                raise
            return None

    def descriptors(self) -> Descriptors:
        """The swarm's true descriptors (from the vehicles' positions) and every agent's
        estimate of them, now."""
        return descriptors_from(self.status())

    def subscribe(self, period_s: float = 0.2, timeout_s: float | None = None) -> Iterator[Status]:
        """Yield the swarm's state (telemetry: positions, armed, modes; and every agent's
        estimate) each time the swarm's clock has moved on, asked every ``period_s`` wall
        seconds; ends after ``timeout_s`` (None: when the caller stops) or with the run."""
        end = None if timeout_s is None else time.monotonic() + timeout_s
        last = -1.0
        while end is None or time.monotonic() < end:
            if not self.running:
                return
            status = self.poll(end)
            if status is not None and status.t_s > last:
                last = status.t_s
                yield status
            time.sleep(period_s)

    def wait_ready(self, timeout_s: float = WAIT_TIMEOUT_S, drones: int | None = None) -> Status:
        """Wait until every drone's agent is READY (its estimate settled) and none is missing
        (``drones``: how many; default the swarm's, when this object started it)."""
        want = drones if drones is not None else (
            self.launched.n_drones if self.launched is not None else None
        )  # fmt: skip
        deadline = time.monotonic() + timeout_s
        while True:
            status = self.poll(deadline)
            if status is None:
                continue
            ready = [
                m for m, a in zip(status.mode, status.alive, strict=True) if a and m == "READY"
            ]
            if ready and len(ready) == (want if want is not None else status.n_drones):
                return status
            if time.monotonic() > deadline:
                raise WaitTimeout(f"not every drone READY after {timeout_s:g} s: {status.mode}")
            time.sleep(0.2)

"""``swarm drills run``: bring up a swarm, fly it into a steady formation and run the drill
catalogue (:mod:`gcs.report.drill_judge`) one drill after another, each from steady flight; print
a table of verdicts and figures, write ``drills.json`` and ``drills.png``, exit 1 if a drill failed.

This is the adapter: the swarm is ``swarm up`` (a child process, its report in
``DIR/swarm``; ``--drones N`` an operator session flown up with ``takeoff``, or a scenario file
whose plan ends in a long hold), the drills are what ``swarm drill`` and the operator commands
send (one Zenoh peer of the run: fault commands, the restart drill among them, ground-station
requests, consensus garbage), and every figure is judged by :mod:`gcs.report.drill_judge` from
the ground station's flight.tlog and events.jsonl (:mod:`gcs.report.drill_logs`), message
counters from the agents' statuses and process ends from /proc.

Exit codes: 0 every drill passed, 1 a drill failed, 2 usage error or the swarm did not fly.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # numpy and pymavlink, imported when the drills run, not by the parser
    from gcs.report.drill_judge import DrillResult, DrillSpec, Step, Window
    from gcs.report.tlog import TlogReader, TlogTrack

#: Altitude of a session's steady formation (m).
ALTITUDE_M = 3.0
#: How long (simulated s) to wait for a steady formation before a drill starts anyway.
STEADY_WAIT_S = 60.0
#: Wall seconds allowed per simulated second while waiting (lockstep slows on a busy machine).
WALL_PER_SIM_S = 8.0
#: Samples before a drill's start kept in its window (s).
LEAD_S = 2.0
STATUS_REASONS = {
    "rx_dropped_malformed": "malformed",
    "rx_dropped_wrong_swarm": "wrong_swarm",
    "rx_dropped_wrong_version": "wrong_version",
    "rejected_setpoints": "rejected_setpoints",
}


class DrillsError(Exception):
    """Usage error or a swarm that did not come up: one line, exit code 2."""


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``swarm drills run``."""
    p = sub.add_parser(
        "drills",
        help="run the drill catalogue against a swarm and judge each drill (PASS/FAIL)",
        description="Self-judging drills (swarm drills run --help).",
    )
    runs = p.add_subparsers(dest="drills_command", metavar="run", required=True)
    run = runs.add_parser(
        "run",
        help="bring up a swarm and run the drills one after another",
        description=(
            "Bring up a swarm (swarm up: --drones N, an operator session flown to 3 m, or a "
            "scenario file whose plan ends in a long hold), lockstep clock by default so "
            "verdicts do not depend on machine load, and run the drill catalogue one drill "
            "after another, each from steady flight. Each drill states its pass criteria "
            "(--list); the run prints a table with PASS/FAIL and the figures, writes "
            "drills.json and drills.png into --report and exits 1 if a drill failed."
        ),
    )
    run.add_argument("scenario", type=Path, nargs="?", help="scenario file (or --drones N)")
    run.add_argument("--drones", type=int, metavar="N", help="N drones on a grid (default 9)")
    run.add_argument(
        "--only", metavar="A,B", help="run only these drills, in this order (names from --list)"
    )
    run.add_argument("--list", action="store_true", help="list the drills and their criteria")
    run.add_argument("--seed", type=int, help="the run's random draws (with --drones; default 0)")
    run.add_argument(
        "--loss",
        type=float,
        default=0.5,
        metavar="P",
        help="loss probability of the big loss drill (default 0.5: loss-50; e.g. 0.97 to find "
        "where the estimator gives up)",
    )
    run.add_argument(
        "--report", type=Path, default=Path("drills"), metavar="DIR", help="default ./drills"
    )
    run.add_argument(
        "--clock",
        choices=("lockstep", "realtime"),
        default="lockstep",
        help="lockstep (default): verdicts do not depend on machine load",
    )
    run.add_argument("--swarm-id", default="drills", help="swarm name on Zenoh (default drills)")


def specs_of(args: argparse.Namespace, n_drones: int) -> tuple[DrillSpec, ...]:
    """The drills ``args`` select; DrillsError naming an unknown one."""
    from gcs.report.drill_judge import catalogue

    if not 0.0 <= args.loss <= 1.0:
        raise DrillsError(f"--loss must be within 0..1, got {args.loss:g}")
    try:
        specs = catalogue(n_drones, args.loss)
    except ValueError as exc:
        raise DrillsError(str(exc)) from None
    if not args.only:
        return specs
    names = [s.strip() for s in args.only.split(",") if s.strip()]
    known = {s.name: s for s in specs}
    unknown = [n for n in names if n not in known]
    if unknown or not names:
        raise DrillsError(
            f"--only: unknown drill {', '.join(unknown) or '(none given)'}; "
            f"the drills: {', '.join(known)}"
        )
    return tuple(known[n] for n in dict.fromkeys(names))  # in the order given


def list_lines(specs: Sequence[DrillSpec]) -> list[str]:
    """``--list``: each drill, what it does and its pass criteria."""
    lines = []
    for s in specs:
        lines.append(f"{s.name}: {s.summary} (then watched {s.observe_s:g} s)")
        lines += [f"    - {c}" for c in s.criteria.lines()]
    return lines


def run(args: argparse.Namespace) -> int:
    """``swarm drills run``."""
    from gcs.report.drill_judge import table, to_json

    n = _n_drones(args)
    specs = specs_of(args, n)
    if args.list:
        for line in list_lines(specs):
            print(line)
        return 0
    report: Path = args.report
    try:
        report.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DrillsError(f"cannot write the report folder {report}: {exc}") from None
    wall0 = time.monotonic()
    results: list[DrillResult] = []
    with _swarm(args, n, report / "swarm") as swarm:
        _say(f"{n} drones up ({args.clock} clock); logs in {report / 'swarm' / 'logs'}")
        if args.scenario is None:
            swarm.command("takeoff", {"altitude_m": ALTITUDE_M})
        gone: set[int] = set()  # the drones the drills so far took out
        for spec in specs:
            result = _run_drill(swarm, spec, gone)
            results.append(result)
            gone |= spec.criteria.lost
            _say(f"{spec.name}: {'PASS' if result.passed else 'FAIL'}")
        swarm.shutdown()
    info = {
        "drones": n,
        "clock": args.clock,
        "seed": args.seed,
        "scenario": str(args.scenario) if args.scenario else None,
        "report": str(report / "swarm"),
        "wall_time_s": round(time.monotonic() - wall0, 1),
    }
    (report / "drills.json").write_text(json.dumps(to_json(results, info), indent=2) + "\n")
    from gcs.report.drill_logs import plot_drills  # matplotlib: only when there is a report

    try:
        whole = _track(swarm)  # the log as the run left it, not read again from its start
    except OSError:
        whole = None
    plot_drills(report / "swarm", results, n, report / "drills.png", whole)
    for line in table(results):
        print(line)
    print(f"wrote {report / 'drills.json'} and {report / 'drills.png'}")
    return 0 if all(r.passed for r in results) else 1


def _say(line: str) -> None:
    print(f"drills: {line}", file=sys.stderr, flush=True)


def _n_drones(args: argparse.Namespace) -> int:
    if args.scenario is not None:
        if args.drones is not None or args.seed is not None:
            raise DrillsError("--drones and --seed go without a scenario file (it has its own)")
        from protocols.scenario.scenario_file import ScenarioError, load_scenario

        try:
            return load_scenario(args.scenario).n_drones
        except ScenarioError as exc:
            raise DrillsError(str(exc)) from None
    return 9 if args.drones is None else int(args.drones)


# -- the swarm ---------------------------------------------------------------------------------
def _tlog_reader() -> TlogReader:
    from gcs.report.tlog import TlogReader

    return TlogReader()


@dataclass
class Swarm:
    """A running ``swarm up`` and a Zenoh peer of it (statuses, liveliness, drills, commands)."""

    proc: subprocess.Popen[bytes]
    dir: Path
    n: int
    swarm_id: str
    bus: Any
    latest: dict[int, Any] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)
    tlog: TlogReader = field(default_factory=_tlog_reader)
    tlog_offset: int = 0

    # -- what the agents say -------------------------------------------------------------------
    def on_status(self, _key: str, payload: bytes) -> None:
        from protocols.wire.status import decode_statuses

        try:  # one status, or a process's batch of them
            statuses = decode_statuses(payload, self.swarm_id)
        except ValueError:
            return
        with self.lock:
            for status in statuses:
                old = self.latest.get(status.drone)
                if old is None or status.t_s >= old.t_s or status.round < old.round:
                    self.latest[status.drone] = status

    def now(self) -> float:
        """The newest simulated time an agent reported (s)."""
        with self.lock:
            return max((s.t_s for s in self.latest.values()), default=0.0)

    def counters(self) -> dict[int, dict[str, int]]:
        """Each agent's rejected-message counters, by reason."""
        with self.lock:
            return {
                d: {r: int(getattr(s.counters, f)) for f, r in STATUS_REASONS.items()}
                for d, s in self.latest.items()
            }

    def wait_until_sim(self, t_s: float) -> None:
        """Wait until simulated time ``t_s``; DrillsError if the run ends or time stands still."""
        last, since = self.now(), time.monotonic()
        while self.now() < t_s:
            if self.proc.poll() is not None:
                raise DrillsError(f"swarm up ended (code {self.proc.returncode}): {self._tail()}")
            if self.now() > last:
                last, since = self.now(), time.monotonic()
            elif time.monotonic() - since > 60.0:
                raise DrillsError(f"simulated time stood still at {last:.1f} s for 60 s")
            time.sleep(0.05)

    def _tail(self) -> str:
        from gcs.api.launch import UP_LOG

        lines = (self.dir / "logs" / UP_LOG).read_text(errors="replace").splitlines()
        return lines[-1] if lines else "(no output)"

    # -- what the drills send ------------------------------------------------------------------
    def command(self, name: str, args: dict[str, Any], timeout_s: float = 10.0) -> Any:
        """One request to the ground station; its reply (DrillsError if none)."""
        from gcs.station.commands import Request, encode_request

        replies = self.requests([encode_request(Request(name, args))], timeout_s)
        if replies[0] is None:
            raise DrillsError(f"the ground station did not answer {name}")
        return replies[0]

    def requests(self, payloads: Sequence[bytes], timeout_s: float = 10.0) -> list[Any]:
        """Send every payload to the command queryable at once; the replies (None: none)."""
        from gcs.station.commands import CommandError, decode_reply
        from protocols.wire.keys import SwarmKeys

        key = SwarmKeys(self.swarm_id, 1.0).command
        handlers = [self.bus.session.get(key, payload=p, timeout=timeout_s) for p in payloads]
        out: list[Any] = []
        for handler in handlers:
            reply = None
            for r in handler:
                if r.ok is not None:
                    with suppress(CommandError):
                        reply = decode_reply(r.ok.payload.to_bytes())
                    break
            out.append(reply)
        return out

    def fault(self, command: Any) -> None:
        """Publish a link-fault command (what ``swarm drill`` sends)."""
        from protocols.bus.interface import Congestion
        from protocols.wire.fault import encode_fault
        from protocols.wire.keys import SwarmKeys

        pub = self.bus.publisher(SwarmKeys(self.swarm_id, 1.0).fault, Congestion.BLOCK)
        pub.put(encode_fault(command, self.swarm_id))
        time.sleep(0.1)
        pub.close()

    def consensus_keys(self, listen_s: float = 0.5) -> set[str]:
        """The consensus keys the agents publish on (heard for ``listen_s`` wall s)."""
        from protocols.wire.keys import SwarmKeys

        keys: set[str] = set()
        sub = self.bus.subscribe_callback(
            SwarmKeys(self.swarm_id, 1.0).consensus_all(), lambda k, _p: keys.add(k)
        )
        time.sleep(listen_s)
        sub.close()
        return keys

    def shutdown(self) -> None:
        """``swarm shutdown``: land, write the report, end swarm up."""
        with suppress(DrillsError):
            self.command("shutdown", {})
        try:
            self.proc.wait(240)
        except subprocess.TimeoutExpired:
            self.proc.send_signal(signal.SIGINT)

    # -- processes -----------------------------------------------------------------------------
    def processes(self) -> dict[int, str]:
        """pid -> role ("gcs", "simulator", "agent 3") of the run's live processes."""
        roles: dict[int, str] = {}
        parents = {self.proc.pid, os.getpid()}
        for entry in Path("/proc").iterdir():
            if not entry.name.isdigit():
                continue
            try:
                stat = (entry / "stat").read_text().rsplit(")", 1)[1].split()
                argv = (entry / "cmdline").read_bytes().decode(errors="replace").split("\0")
            except (OSError, IndexError):
                continue
            if stat[0] == "Z" or int(stat[1]) not in parents or "gcs.cli" not in argv:
                continue
            role = _role(argv[argv.index("gcs.cli") + 1 :])
            if role is not None:
                roles[int(entry.name)] = role
        return roles


def _role(argv: Sequence[str]) -> str | None:
    if not argv:
        return None
    if argv[0] == "agent" and "--drone-id" in argv:
        return f"agent {argv[argv.index('--drone-id') + 1]}"
    return {"gcs": "gcs", "sim": "simulator"}.get(argv[0])


@contextmanager
def _swarm(args: argparse.Namespace, n: int, folder: Path) -> Iterator[Swarm]:
    """``swarm up`` on free ports with its report in ``folder``, meeting at a Zenoh peer of this
    process on a free port (never the default rendezvous port, which another swarm on the
    machine may hold or take at the same moment)."""
    from gcs.api.errors import SwarmError
    from gcs.api.launch import launch, stop, wait_started
    from gcs.station.commands import Request, encode_request
    from protocols.bus.zenoh_bus import ZenohBus, ZenohSettings, free_loopback_endpoint
    from protocols.wire.keys import SwarmKeys

    what = [str(args.scenario)] if args.scenario else ["--drones", str(n)]
    if args.scenario is None and args.seed is not None:
        what += ["--seed", str(args.seed)]
    endpoint = free_loopback_endpoint()
    bus = ZenohBus.open(ZenohSettings(listen=(endpoint,)))
    try:
        run = launch(what, n, folder, endpoint, args.swarm_id, args.clock)
    except SwarmError as exc:
        bus.close()
        raise DrillsError(str(exc)) from None
    swarm = Swarm(run.proc, folder, n, args.swarm_id, bus)
    try:
        try:
            wait_started(run, 60.0)
        except SwarmError as exc:
            raise DrillsError(f"swarm up did not start: {exc}") from None
        bus.subscribe_callback(SwarmKeys(args.swarm_id, 1.0).status_all(), swarm.on_status)
        deadline = time.monotonic() + 120.0
        while len(swarm.latest) < n:
            if run.proc.poll() is not None or time.monotonic() > deadline:
                raise DrillsError(f"the agents did not all report: {swarm._tail()}")
            time.sleep(0.2)
        while swarm.requests([encode_request(Request("status", {}))], 2.0)[0] is None:
            if run.proc.poll() is not None or time.monotonic() > deadline:
                raise DrillsError(f"the ground station does not answer: {swarm._tail()}")
        yield swarm
    finally:
        stop(run, 60.0, 10.0)
        if swarm.bus is not None:
            swarm.bus.close()


# -- one drill ---------------------------------------------------------------------------------
def _run_drill(swarm: Swarm, spec: DrillSpec, gone: set[int]) -> DrillResult:
    """Wait for steady flight, carry out the drill's steps, judge its window. ``gone``: the
    drones earlier drills took out; any other drone missing at the start is reported."""
    from gcs.report.drill_judge import DrillResult, joins, judge_window, rejoin_facts

    steady = _wait_steady(swarm)
    t0 = swarm.now()
    counters0, procs0 = swarm.counters(), swarm.processes()
    members = set(_positions(swarm))
    missing = sorted(set(range(swarm.n)) - members - gone)
    extra: dict[str, Any] = {"steady_at_start": steady, "gone_before_start": missing}
    for step in sorted(spec.steps, key=lambda s: s.at_s):
        swarm.wait_until_sim(t0 + step.at_s)
        facts = _do(swarm, step)
        extra["actions"] = [*extra.get("actions", []), facts.pop("action")]
        if extra.get("move_accepted") is False:  # the move refused, the stretch accepted: refused
            facts.pop("move_accepted", None)
        extra |= facts
    # a drill that stops the ground station is judged from its return (back_at_s)
    back = extra.get("back_at_s")
    t_recover = max(t0 + spec.fault_s, back if back is not None else t0)
    t_end = max(t0 + spec.length_s, t_recover + spec.length_s - spec.fault_s)
    swarm.wait_until_sim(t_end)
    procs1 = swarm.processes()
    ended = sorted(set(procs0.values()) - set(procs1.values()))
    if "gcs" not in procs1.values():
        ended.append("gcs (not back)")
    rejected = _rejected(counters0, swarm.counters())
    w, events = _window(swarm, t0 - LEAD_S, t_end, t0, t_recover)
    rejected |= _gcs_rejections(events, t0, t_end)
    if spec.criteria.rejoin is not None:
        back = [t for t in joins(events, spec.criteria.rejoin) if t > t0]
        extra |= rejoin_facts(w, spec.criteria.rejoin, back[0] if back else None)
    result = judge_window(spec, w, rejected, ended, extra)
    if not steady:
        result = DrillResult(
            spec, result.measurement, ("not steady at its start", *result.failures), t0
        )
    return result


def _wait_steady(swarm: Swarm) -> bool:
    """Wait until the formation and the estimates are converged for HOLD_S; False if not within
    STEADY_WAIT_S simulated seconds."""
    import numpy as np

    from gcs.report.drill_judge import HOLD_S, series

    t_end = swarm.now() + STEADY_WAIT_S
    while swarm.now() < t_end:
        swarm.wait_until_sim(swarm.now() + 0.5)
        t = swarm.now()
        try:
            w, _ = _window(swarm, t - HOLD_S - 0.5, t, t, t)
        except (OSError, ValueError):
            continue
        s = series(w)
        recent = s.t_s >= t - HOLD_S - 0.2
        if recent.sum() >= HOLD_S * _rate_hz() * 0.8 and bool(np.all(s.converged[recent])):
            return True
    return False


def _do(swarm: Swarm, step: Step) -> dict[str, Any]:
    """Carry out one step; facts for the drill's record."""
    if step.kind == "fault":
        command = step.args["fault"]
        if step.args.get("split") == "north":
            from gcs.report.drill_judge import split_north
            from protocols.faults import Partition

            command = Partition(split_north(_positions(swarm)))
        swarm.fault(command)
        from drone_agent.process.fault_drills import describe

        return {"action": f"sent {describe(command)}"}
    if step.kind == "gcs":
        args = {"drone": step.args["drone"]} if "drone" in step.args else {}
        reply = swarm.command(step.args["name"], args)
        facts = {"action": f"{step.args['name']}: {reply.reason}", "accepted": reply.accepted}
        if step.args["name"] == "gcs-restart" and reply.accepted:
            facts["back_at_s"] = _station_back(swarm)
        return facts
    if step.kind in ("move", "scale"):
        reply = swarm.command(step.kind, dict(step.args))
        return {"action": f"{step.kind}: {reply.reason}", "move_accepted": reply.accepted}
    if step.kind == "garbage":
        return _garbage(swarm, int(step.args["count"]), float(step.args["spread_s"]))
    if step.kind == "flood":
        return _flood(swarm, int(step.args["count"]))
    raise ValueError(f"unknown step {step.kind}")


#: How long (wall s) the drills wait for a restarted ground station to answer again.
STATION_BACK_WAIT_S = 60.0


def _station_back(swarm: Swarm) -> float | None:
    """Wait until the restarted ground station answers ``status`` again; the simulated time
    then (None: not within STATION_BACK_WAIT_S). Its telemetry log has a hole until then: the
    drill is judged from there (at several times real time the swarm flies on for seconds of
    simulated time while the station starts)."""
    deadline = time.monotonic() + STATION_BACK_WAIT_S
    time.sleep(0.5)  # the old station stops first
    while time.monotonic() < deadline:
        try:
            swarm.command("status", {}, timeout_s=2.0)
            return swarm.now()
        except DrillsError:
            time.sleep(0.2)
    return None


def _garbage(swarm: Swarm, count: int, spread_s: float) -> dict[str, Any]:
    """``count`` bad payloads on the consensus keys the agents use, over ``spread_s`` wall s."""
    import numpy as np

    from protocols.bus.interface import Congestion
    from protocols.wire.consensus_message import ConsensusMessage
    from protocols.wire.format import encode_consensus

    keys = sorted(swarm.consensus_keys())
    if not keys:
        return {"action": "garbage: no consensus key heard", "garbage_sent": 0}
    msg = ConsensusMessage(
        sender=swarm.n + 50, round=10**6, gamma=np.full(18, 1e3), edge_sums={},
        heard=frozenset(), degree=0,
    )  # fmt: skip
    valid = encode_consensus(msg, (0.0, 0.0, -3.0), swarm.swarm_id)
    rng = np.random.default_rng(7)
    kinds = [
        lambda: rng.bytes(int(rng.integers(1, 600))),
        lambda: valid[:1] + bytes([99]) + valid[2:],
        lambda: encode_consensus(msg, (0.0, 0.0, -3.0), swarm.swarm_id + "x"),
        lambda: valid[: len(valid) // 2],
    ]
    pubs = {}
    for k in {k.rsplit("/", 1)[0] for k in keys}:
        pubs[k] = swarm.bus.publisher(f"{k}/{swarm.n + 50}", Congestion.BLOCK)
    sent = 0
    for i in range(count):
        for pub in pubs.values():
            pub.put(kinds[i % len(kinds)]())
            sent += 1
        time.sleep(spread_s / count)
    for pub in pubs.values():
        pub.close()
    return {"action": f"garbage: {sent} payloads on {len(pubs)} cells", "garbage_sent": sent}


def _flood(swarm: Swarm, count: int) -> dict[str, Any]:
    """``count`` operator requests at once: a third status, a third malformed, a third an
    unknown command; how many were answered."""
    from gcs.station.commands import Request, encode_request

    kinds = [
        encode_request(Request("status", {})),
        b"{not json",
        json.dumps({"version": 1, "command": "fly-to-the-moon", "args": {}}).encode(),
    ]
    replies = swarm.requests([kinds[i % 3] for i in range(count)], timeout_s=10.0)
    answered = sum(r is not None for r in replies)
    share = answered / count
    return {"action": f"flood: {count} requests, {answered} answered", "answered_share": share}


def _rejected(
    before: dict[int, dict[str, int]], after: dict[int, dict[str, int]]
) -> dict[str, int]:
    """Messages the agents rejected between two counter snapshots, by reason (a restarted agent
    counts from zero)."""
    out: dict[str, int] = {}
    for d, now in after.items():
        then = before.get(d, {})
        for reason, value in now.items():
            delta = value - then.get(reason, 0)
            delta = value if delta < 0 else delta
            if delta:
                out[reason] = out.get(reason, 0) + delta
    return out


def _gcs_rejections(events: list[dict[str, Any]], t0: float, t1: float) -> dict[str, int]:
    """Requests the ground station refused between t0 and t1, by kind."""
    out: dict[str, int] = {}
    for e in events:
        if not t0 - 1e-3 <= float(e.get("t_s", -1.0)) <= t1 or e.get("accepted") is not False:
            continue
        kind = (
            "gcs: malformed request"
            if e.get("command", "x") is None
            else f"gcs: refused {e.get('kind')}"
        )
        out[kind] = out.get(kind, 0) + 1
    return out


# -- what the ground station logged ----------------------------------------------------------
def _rate_hz() -> float:
    """The drill logs' sample rate (gcs.report.drill_logs imports matplotlib: only when used)."""
    from gcs.report.drill_logs import RATE_HZ

    return RATE_HZ


def _window(
    swarm: Swarm, t_from: float, t_to: float, t_start: float, t_recover: float
) -> tuple[Window, list[dict[str, Any]]]:
    """The judged samples between ``t_from`` and ``t_to`` from the ground station's logs (the
    flight log read on from where the last call stopped)."""
    from gcs.report.drill_logs import window_from_logs

    track = _track(swarm)
    return window_from_logs(swarm.dir, swarm.n, t_from, t_to, t_start, t_recover, track)


def _track(swarm: Swarm) -> TlogTrack:
    """The ground station's flight log so far, read on from where the last call stopped."""
    with (swarm.dir / "flight.tlog").open("rb") as f:
        f.seek(swarm.tlog_offset)
        swarm.tlog_offset += swarm.tlog.feed(f.read())
    return swarm.tlog.track()


def _positions(swarm: Swarm) -> dict[int, list[float]]:
    """Each member drone's latest position (NED m) from the flight log."""
    t = swarm.now()
    w, _ = _window(swarm, t - 1.0, t, t, t)
    last = w.position_ned_m[-1]
    return {i: list(last[i]) for i in range(swarm.n) if w.member[-1, i]}

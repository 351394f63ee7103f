"""``swarm drill``: faults against a running swarm.

Link faults (``link-cut``, ``loss``, ``delay``, ``partition``, ``clear``) are published once on
``swarm/<sid>/fault`` (:mod:`protocols.wire.fault`, BLOCK congestion) from a short-lived Zenoh
client session; every agent applies them on its receive side and the ground station records them
in events.jsonl. ``restart --drone I --gap-s S`` goes the same way: the agent process hosting
drone I kills that agent at once and starts a new one (a new incarnation) S simulated seconds
later, in one-process-per-drone and hosted runs alike
(:meth:`drone_agent.process.host.AgentHost.restart`). ``crash --drone I`` asks the ground station
(its command queryable) to stop every motor of vehicle I, ``dropout --drone I`` to SIGKILL drone I's
agent process and ``gcs-restart`` to stop itself so that ``swarm up`` starts it again (both need a
swarm started by ``swarm up``). Exit codes: 0 done, 1 refused by the ground station, 2 usage error
or nobody reachable.

The reply, for scripts (``--json``: one JSON object on stdout instead of the line): a drill sent
to the agents prints ``drill NAME: sent WHAT`` (``{"drill": NAME, "sent": true, "what": WHAT}``
plus the drill's fields, e.g. ``"drone"`` and ``"gap_s"`` for restart); a ground-station drill
prints ``drill NAME: accepted|refused: REASON`` (``{"drill": NAME, "accepted": bool, "reason":
REASON}``). Sent means published once, reliably, to every agent process connected; the outcome is
in the ground station's events.jsonl: a ``drill`` event, and for restart the drone's
``dropout_detected`` (its agent's token went) and ``agent_joined`` (the new agent) events.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from typing import Any

from gcs.cli.operator import add_operator_flags


class DrillError(Exception):
    """Usage error or nobody reachable: one line, exit code 2."""


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``swarm drill`` and its drills."""
    p = sub.add_parser(
        "drill",
        help="drills against a running swarm: link cuts, loss, delay, partitions, crashes",
        description=(
            "Faults against a running swarm. Link faults (link-cut, loss, delay, partition, "
            "clear) go to every agent over Zenoh and are applied on their receive side; restart "
            "kills one drone's agent and starts a new one after a gap (the agent process does it); "
            "crash "
            "asks the ground station to stop every motor of one vehicle; dropout and gcs-restart "
            "(a swarm started by swarm up) kill one agent's process and restart the ground "
            "station. The ground station records each drill in events.jsonl."
        ),
    )
    drills = p.add_subparsers(dest="drill", metavar="DRILL", required=True)

    def drill(name: str, help_: str) -> argparse.ArgumentParser:
        d = drills.add_parser(name, help=help_, description=help_)
        add_operator_flags(d)
        d.add_argument(
            "--json", action="store_true", help="print the reply as one JSON object (for scripts)"
        )
        return d

    cut = drill("link-cut", "cut the radio link between drones I and J")
    cut.add_argument("i", type=int, metavar="I")
    cut.add_argument("j", type=int, metavar="J")
    cut.add_argument("--for-s", type=float, metavar="S", help="restore it after S simulated s")
    cut.add_argument("--one-way", action="store_true", help="cut only I -> J")
    loss = drill("loss", "drop each message with probability P")
    loss.add_argument("probability", type=float, metavar="P", help="0..1")
    loss.add_argument("--link", metavar="I,J", help="only on the link I-J (both ways)")
    loss.add_argument("--for-s", type=float, metavar="S", help="end it after S simulated s")
    delay = drill("delay", "delay every message by MS milliseconds")
    delay.add_argument("delay_ms", type=float, metavar="MS")
    delay.add_argument("--link", metavar="I,J", help="only on the link I-J (both ways)")
    part = drill("partition", "split the swarm into groups that do not hear each other")
    which = part.add_mutually_exclusive_group(required=True)
    which.add_argument("--groups", metavar="0,1,2/3,4", help="drone ids per group, / between")
    which.add_argument("--heal", action="store_true", help="end the partition")
    drill("clear", "end every link fault")
    crash = drill("crash", "stop every motor of one vehicle (through the ground station)")
    crash.add_argument("--drone", type=int, required=True, metavar="I", help="drone index")
    dropout = drill(
        "dropout",
        "SIGKILL one drone's agent process (through the ground station; a swarm started by "
        "swarm up)",
    )
    dropout.add_argument("--drone", type=int, required=True, metavar="I", help="drone index")
    restart = drill(
        "restart",
        "kill one drone's agent and start a new one after a gap (simulated s): it rejoins the "
        "swarm as a new member and takes its vehicle back (from the air, or from the ground "
        "after its failsafe landed it); one process per drone or hosted alike",
    )
    restart.add_argument("--drone", type=int, required=True, metavar="I", help="drone index")
    restart.add_argument(
        "--gap-s",
        type=float,
        default=3.0,
        metavar="S",
        help="simulated seconds without an agent (default %(default)s; the vehicle's failsafe "
        "holds after 0.5 s and lands after 1.5 s)",
    )
    drill(
        "gcs-restart",
        "stop the ground station and have swarm up start it again: it adopts the swarm's "
        "current plan and continues its logs",
    )


def _ids(text: str, what: str) -> tuple[int, ...]:
    try:
        return tuple(int(x) for x in text.split(","))
    except ValueError:
        raise DrillError(
            f"{what} must be drone indices separated by commas, got {text!r}"
        ) from None


def _link(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    ids = _ids(text, "--link")
    if len(ids) != 2:
        raise DrillError(f"--link must be two drone indices I,J, got {text!r}")
    return ids[0], ids[1]


def drill_args(args: argparse.Namespace) -> dict[str, Any]:
    """The keyword arguments of :meth:`gcs.api.Swarm.drill` for parsed ``args``."""
    name = args.drill
    if name == "link-cut":
        return {"i": args.i, "j": args.j, "for_s": args.for_s, "one_way": args.one_way}
    if name == "loss":
        return {"probability": args.probability, "link": _link(args.link), "for_s": args.for_s}
    if name == "delay":
        return {"delay_ms": args.delay_ms, "link": _link(args.link)}
    if name == "partition":
        if args.heal:
            return {"heal": True}
        return {"groups": [_ids(g, "--groups") for g in args.groups.split("/")]}
    if name == "restart":
        return {"drone": args.drone, "gap_s": args.gap_s}
    if name in ("crash", "dropout"):
        return {"drone": args.drone}
    return {}


def run(args: argparse.Namespace) -> int:
    """Carry out the drill of ``args`` through :meth:`gcs.api.Swarm.drill`; 0 done, 1 refused
    by the ground station."""
    from gcs.api.errors import CommandRefused, SwarmError
    from gcs.cli.operator import OperatorError, connect

    kwargs = drill_args(args)
    try:
        with connect(args) as swarm:
            done = swarm.drill(args.drill, **kwargs)
    except CommandRefused as exc:
        return _said(args, False, exc.reason)
    except (SwarmError, OperatorError) as exc:
        raise DrillError(str(exc)) from None
    if done.fault is None:
        return _said(args, True, done.what)
    if getattr(args, "json", False):
        fields = dataclasses.asdict(done.fault)
        del fields["t_s"]  # a scenario's start time; a drill acts when it arrives
        what = done.what.removeprefix("sent ")
        print(json.dumps({"drill": args.drill, "sent": True, "what": what, **fields}))
    else:
        print(f"drill {args.drill}: {done.what}")
    return 0


def _said(args: argparse.Namespace, accepted: bool, reason: str) -> int:
    """Print a ground station's drill answer; 0 accepted, 1 refused."""
    if getattr(args, "json", False):
        print(json.dumps({"drill": args.drill, "accepted": accepted, "reason": reason}))
    else:
        print(f"drill {args.drill}: {'accepted' if accepted else 'refused'}: {reason}")
    return 0 if accepted else 1

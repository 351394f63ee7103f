"""Operator commands: their JSON wire format (request and reply) and their effect on the plan. Pure.

A request is a UTF-8 JSON object ``{"version": 1, "command": NAME, "args": {...}}``; a reply is
``{"version": 1, "accepted": bool, "reason": str, "seq": int | null, "table": [...], "t_s":
number | null, "arrives_s": number | null, "plan": {...} | null}`` (the last three: the station's
simulated time, when an accepted plan command's change arrives on the new plan's clock, and for
``status`` the plan in force, :meth:`GroundStation.plan_summary`; older stations leave them out).
Units: metres, degrees, seconds; positions NED (north, east, down), or altitude up where named
``altitude_m`` / ``up_m``. :func:`parse_request` validates a request and raises
:class:`CommandError` with the reason for anything malformed; :func:`apply_command` turns a
valid plan-changing command into the next plan with :mod:`gcs.station.planner`
(``PlanRefused`` when the envelope or the geofence forbids it).
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from gcs.station.planner import (
    Envelope,
    PlanRefused,
    formation_target,
    goal_of,
    hold,
    land,
    plan_move,
)
from protocols.model.descriptor_vector import I_YAW, SHAPE
from protocols.model.formation_fit import fit_problem
from protocols.model.frames import FloatArray
from protocols.wire.plan import LAND_HANDOVER_ALTITUDE_M, FlightCommand, PlanMessage

VERSION = 1
MAX_REQUEST_BYTES = 4096
#: A hold stops a landing only while the commanded altitude is this much (m) above the altitude
#: where the agents hand their vehicles to the autopilot's LAND mode.
HOLD_ABORT_MARGIN_M = 0.5

#: Each command and its arguments: name -> (required, optional) argument names. Values are numbers
#: except ``centre_ned_m`` (a list of 3 numbers).
COMMANDS: dict[str, tuple[frozenset[str], frozenset[str]]] = {
    "takeoff": (frozenset({"altitude_m"}), frozenset()),
    "formation": (
        frozenset(),
        frozenset({"centre_ned_m", "heading_deg", "length_m", "width_m", "height_m", "duration_s"}),
    ),
    "move": (frozenset(), frozenset({"north_m", "east_m", "up_m", "duration_s"})),
    "rotate": (frozenset({"delta_deg"}), frozenset({"duration_s"})),
    "scale": (frozenset({"factor"}), frozenset({"duration_s"})),
    "hold": (frozenset(), frozenset()),
    "land": (frozenset(), frozenset()),
    "status": (frozenset(), frozenset()),
    # land if flying, then end the run and write the report (the ground station carries it out)
    "shutdown": (frozenset(), frozenset()),
    # drills: stop every motor of vehicle drone; SIGKILL its agent; restart the ground station
    "crash": (frozenset({"drone"}), frozenset()),
    "dropout": (frozenset({"drone"}), frozenset()),
    "gcs-restart": (frozenset(), frozenset()),
}


class CommandError(ValueError):
    """A malformed request; ``str(exc)`` says what is wrong."""


@dataclass(frozen=True)
class Request:
    """A validated operator command: ``name`` and its ``args`` (numbers, or a 3-list of them)."""

    name: str
    args: dict[str, Any]


@dataclass(frozen=True)
class Reply:
    """The ground station's answer: accepted or not, why, the plan seq now, a per-drone table."""

    accepted: bool
    reason: str
    seq: int | None = None
    table: tuple[dict[str, Any], ...] = ()
    #: the ground station's simulated time when it answered (s)
    t_s: float | None = None
    #: an accepted plan command: when its change arrives, on the new plan's clock (s)
    arrives_s: float | None = None
    #: ``status``: the plan in force (``seq``, ``command``, ``late_s``: how late it is flown, None
    #: while it waits on the ground for the swarm's take-off)
    plan: dict[str, Any] | None = None


def encode_request(request: Request) -> bytes:
    """The JSON payload of ``request``."""
    return json.dumps({"version": VERSION, "command": request.name, "args": request.args}).encode()


def _number(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise CommandError(f"argument {name} must be a finite number, got {value!r}")
    return float(value)


def parse_request(payload: bytes | None) -> Request:
    """Validate a request payload; CommandError with the reason if it is malformed."""
    if not payload:
        raise CommandError("empty request: expected a JSON object with version, command, args")
    if len(payload) > MAX_REQUEST_BYTES:
        raise CommandError(f"request of {len(payload)} bytes exceeds {MAX_REQUEST_BYTES}")
    try:
        data = json.loads(payload.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CommandError(f"request is not UTF-8 JSON: {exc}") from None
    if not isinstance(data, dict):
        raise CommandError("request must be a JSON object")
    if data.get("version") != VERSION:
        raise CommandError(f"unsupported request version {data.get('version')!r}, need {VERSION}")
    name = data.get("command")
    if not isinstance(name, str) or name not in COMMANDS:
        raise CommandError(f"unknown command {name!r}; known: {', '.join(COMMANDS)}")
    raw = data.get("args", {})
    if not isinstance(raw, dict):
        raise CommandError("args must be a JSON object")
    required, optional = COMMANDS[name]
    unknown = set(raw) - required - optional
    if unknown:
        raise CommandError(f"{name}: unknown argument {sorted(unknown)[0]!r}")
    missing = required - set(raw)
    if missing:
        raise CommandError(f"{name}: missing argument {sorted(missing)[0]!r}")
    args: dict[str, Any] = {}
    for key, value in raw.items():
        if key == "centre_ned_m":
            if not isinstance(value, list) or len(value) != 3:
                raise CommandError("centre_ned_m must be a list of 3 numbers (north, east, down)")
            args[key] = [_number(key, v) for v in value]
        else:
            args[key] = _number(key, value)
    return Request(name, args)


def encode_reply(reply: Reply) -> bytes:
    """The JSON payload of ``reply`` (non-finite numbers become null)."""
    from gcs.report.events import jsonable

    body = {"version": VERSION, **dataclasses.asdict(reply)}
    return json.dumps(jsonable(body)).encode()


def decode_reply(payload: bytes) -> Reply:
    """Parse a reply payload; CommandError if it is not one."""
    try:
        data = json.loads(payload.decode("utf-8"))
        if not isinstance(data, dict) or data.get("version") != VERSION:
            raise CommandError("reply has no supported version")
        return Reply(
            bool(data["accepted"]),
            str(data["reason"]),
            data.get("seq"),
            tuple(data.get("table") or ()),
            _optional_number(data.get("t_s")),
            _optional_number(data.get("arrives_s")),
            data.get("plan") if isinstance(data.get("plan"), dict) else None,
        )
    except (UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError) as exc:
        raise CommandError(f"malformed reply from the ground station: {exc}") from None


def _optional_number(value: object) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def apply_command(
    request: Request,
    current: PlanMessage,
    now_s: float,
    env: Envelope,
    positions_ned_m: FloatArray | None = None,
) -> PlanMessage:
    """The next plan (seq + 1) for a plan-changing ``request``, leaving ``current`` at ``now_s``
    (simulated s); PlanRefused with the reason if the envelope or the geofence forbid it, or if
    the new shape cannot hold the drones now at ``positions_ned_m`` (N, 3) the envelope's
    minimum separation apart (not checked without positions)."""
    return plan_command(request, current, now_s, env, positions_ned_m)[0]


def plan_command(
    request: Request,
    current: PlanMessage,
    now_s: float,
    env: Envelope,
    positions_ned_m: FloatArray | None = None,
) -> tuple[PlanMessage, str]:
    """As :func:`apply_command`, with a sentence saying when each part of the change arrives
    (each of centre, orientation and shape moves at its own pace; a part the command leaves
    alone keeps its course)."""
    plan, when, _ = plan_arrival(request, current, now_s, env, positions_ned_m)
    return plan, when


def plan_arrival(
    request: Request,
    current: PlanMessage,
    now_s: float,
    env: Envelope,
    positions_ned_m: FloatArray | None = None,
) -> tuple[PlanMessage, str, float]:
    """As :func:`plan_command`, with when the change arrives on the new plan's clock (s): the
    last commanded part's arrival (``now_s`` when nothing changes), the end of a landing's
    descent, the end of a hold's braking."""
    plan, args = current.trajectory, request.args
    duration = args.get("duration_s")
    goal = goal_of(plan, now_s)
    if current.command == FlightCommand.GROUND and request.name not in ("takeoff", "hold"):
        raise PlanRefused("the swarm is on the ground: take off first (swarm takeoff)")
    if request.name == "land":
        if current.command == FlightCommand.LAND:
            raise PlanRefused("the swarm is already landing")
        landing = land(plan, now_s, env)
        when = f"on the ground at t = {landing.end_s:.1f} s"
        return PlanMessage(landing, FlightCommand.LAND), when, landing.end_s
    if request.name == "hold":
        if current.command == FlightCommand.LAND:
            altitude = -float(plan.evaluate(now_s)[0][2])
            if altitude <= LAND_HANDOVER_ALTITUDE_M + HOLD_ABORT_MARGIN_M:
                raise PlanRefused(
                    f"the swarm is touching down (commanded altitude {altitude:.1f} m): "
                    "take off to fly again"
                )
            # a hold during the descent stops it: the swarm flies on where it stopped
            held = hold(plan, now_s, env)
            return (
                PlanMessage(held, FlightCommand.FLY),
                f"at rest at t = {held.end_s:.1f} s",
                held.end_s,
            )
        held = hold(plan, now_s, env)
        return PlanMessage(held, current.command), f"at rest at t = {held.end_s:.1f} s", held.end_s
    if current.command == FlightCommand.LAND and request.name != "takeoff":
        raise PlanRefused("the swarm is landing: take off first")
    if request.name == "takeoff":
        altitude = args["altitude_m"]
        if altitude <= 0:
            raise PlanRefused("take-off altitude must be above the ground (> 0 m)")
        goal[2] = -altitude
    elif request.name == "formation":
        spreads = [args.get(k) for k in ("length_m", "width_m", "height_m")]
        now_spread = np.sqrt(np.maximum(goal[SHAPE], 0.0))
        spread = np.array([now_spread[i] if s is None else s for i, s in enumerate(spreads)])
        centre = args.get("centre_ned_m")
        goal = formation_target(
            plan,
            now_s,
            centre_ned_m=None if centre is None else np.array(centre),
            heading_deg=args.get("heading_deg"),
            spread_m=spread,
        )
    elif request.name == "move":
        goal[0] += args.get("north_m", 0.0)
        goal[1] += args.get("east_m", 0.0)
        goal[2] -= args.get("up_m", 0.0)
    elif request.name == "rotate":
        goal[I_YAW] += math.radians(args["delta_deg"])
    elif request.name == "scale":
        factor = args["factor"]
        if factor <= 0:
            raise PlanRefused("the scale factor must be positive")
        goal[SHAPE] *= factor**2
    else:
        raise PlanRefused(f"{request.name} does not change the plan")
    if request.name in ("formation", "scale") and positions_ned_m is not None:
        problem = fit_problem(positions_ned_m, goal, env.min_separation_m)
        if problem is not None:
            raise PlanRefused(problem)
    move = plan_move(plan, now_s, goal, env, duration)
    arrives = max(move.arrivals.values(), default=now_s)
    return PlanMessage(move.trajectory, FlightCommand.FLY), move.describe(), arrives

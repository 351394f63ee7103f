"""Operator commands and drills as data, from keyword arguments. Pure.

One place builds every request that the API's methods and the ``swarm`` command send, with the
same checks and the same words: an argument is named as the API spells it and as the flag
(``altitude_m (--altitude-m)``). The ground station checks again what reaches it
(:func:`gcs.station.commands.parse_request`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from gcs.api.errors import UsageError
from gcs.station.commands import COMMANDS, Request
from protocols.faults import (
    Clear,
    Delay,
    FaultCommand,
    LinkCut,
    Loss,
    Partition,
    Restart,
)

#: Commands that change the plan (each returns a handle whose ``wait()`` follows its arrival).
PLAN_COMMANDS = ("takeoff", "formation", "move", "rotate", "scale", "hold", "land")
#: Drills the agents carry out (published on ``swarm/<sid>/fault``).
AGENT_DRILLS = ("link-cut", "loss", "delay", "partition", "clear", "restart")
#: Drills the ground station carries out (its command queryable).
GCS_DRILLS = ("crash", "dropout", "gcs-restart")


def named(key: str) -> str:
    """``altitude_m (--altitude-m)``: an argument as the API and the command line name it."""
    return f"{key} (--{key.replace('_', '-')})"


def _finite(key: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise UsageError(f"{named(key)} must be a finite number, got {value!r}")
    return float(value)


def command_request(name: str, **kwargs: object) -> Request:
    """The request of operator command ``name`` with arguments ``kwargs`` (None: left out).

    ``formation`` takes its centre as ``centre_ned_m`` (north, east, down) or ``centre``
    (north, east, altitude up), not both. UsageError names a bad or unknown argument."""
    if name not in COMMANDS or name in GCS_DRILLS:
        known = ", ".join(c for c in COMMANDS if c not in GCS_DRILLS)
        raise UsageError(f"unknown command {name!r}; known: {known}")
    given = {k: v for k, v in kwargs.items() if v is not None}
    if name == "formation" and "centre" in given:
        if "centre_ned_m" in given:
            raise UsageError("give the formation's centre once: centre (N, E, ALT) or centre_ned_m")
        n, e, alt = _triple("centre", given.pop("centre"))
        given["centre_ned_m"] = [n, e, -alt]
    required, optional = COMMANDS[name]
    for key in given:
        if key not in required | optional:
            raise UsageError(f"{name}: unknown argument {key!r}")
    for key in sorted(required - set(given)):
        raise UsageError(f"{name}: {named(key)} is required")
    args: dict[str, object] = {}
    for key, value in given.items():
        if key == "centre_ned_m":
            args[key] = list(_triple(key, value))
        else:
            args[key] = _finite(key, value)
    return Request(name, args)


def _triple(key: str, value: object) -> tuple[float, float, float]:
    if isinstance(value, str) or not isinstance(value, Sequence) or len(value) != 3:
        what = "N,E,ALT" if key == "centre" else "N,E,D"
        raise UsageError(f"{named(key)} must be 3 numbers ({what}, metres), got {value!r}")
    a, b, c = (_finite(key, v) for v in value)
    return a, b, c


def drill_request(drill: str, drone: int) -> Request:
    """The ground station's drill ``crash`` / ``dropout`` of ``drone``, or ``gcs-restart``."""
    if drill == "gcs-restart":
        return Request(drill, {})
    return Request(drill, {"drone": _drone("drone", drone)})


def _drone(key: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise UsageError(f"{named(key)} must be a drone index (0, 1, ...), got {value!r}")
    return value


def _pair(key: str, value: object) -> tuple[int, int] | None:
    if value is None:
        return None
    if isinstance(value, str) or not isinstance(value, Sequence) or len(value) != 2:
        raise UsageError(f"{named(key)} must be two drone indices I,J, got {value!r}")
    return _drone(key, value[0]), _drone(key, value[1])


def fault_command(drill: str, **kwargs: object) -> FaultCommand:
    """The fault command of an agents' drill (``link-cut``: i, j, for_s, one_way; ``loss``:
    probability, link, for_s; ``delay``: delay_ms, link; ``partition``: groups or heal;
    ``clear``; ``restart``: drone, gap_s). UsageError for a bad or missing value."""
    get = kwargs.get
    try:
        if drill == "link-cut":
            for_s = get("for_s")
            return LinkCut(
                _drone("i", get("i")),
                _drone("j", get("j")),
                bool(get("one_way", False)),
                None if for_s is None else _finite("for_s", for_s),
            )
        if drill == "loss":
            for_s = get("for_s")
            return Loss(
                _finite("probability", get("probability")),
                _pair("link", get("link")),
                None if for_s is None else _finite("for_s", for_s),
            )
        if drill == "delay":
            return Delay(_finite("delay_ms", get("delay_ms")), _pair("link", get("link")))
        if drill == "partition":
            groups = get("groups")
            if bool(get("heal", False)) == (groups is not None):
                raise UsageError("partition: give groups (lists of drone indices) or heal=True")
            if groups is None:
                return Partition(None)
            if not isinstance(groups, Sequence):
                raise UsageError(f"{named('groups')} must be lists of drone indices")
            return Partition(tuple(tuple(_drone("groups", d) for d in g) for g in groups))
        if drill == "clear":
            return Clear()
        if drill == "restart":
            gap = _finite("gap_s", get("gap_s", 3.0))
            if not gap > 0:
                raise UsageError(
                    f"{named('gap_s')} must be a positive number of seconds, got {gap:g}"
                )
            return Restart(_drone("drone", get("drone")), gap)
    except TypeError as exc:
        raise UsageError(f"drill {drill}: {exc}") from None
    known = ", ".join(AGENT_DRILLS + GCS_DRILLS)
    raise UsageError(f"unknown drill {drill!r}; known: {known}")

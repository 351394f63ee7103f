"""The swarm's state as data, from the ground station's answers, and when a command has
arrived. Pure: no I/O.

Frames and units: positions NED (north, east, down), metres; descriptors in the order of
:mod:`protocols.model.descriptor_vector` (centre NED m, roll/pitch/yaw rad, variances m²). Times are
the swarm's simulated seconds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from gcs.api.errors import Failsafe, Superseded
from protocols.model.descriptors import descriptors as descriptors_of
from protocols.model.frames import FloatArray

#: The agent mode of a drone back on the ground, disarmed, after a landing.
LANDED = "LANDED"


@dataclass(frozen=True)
class Status:
    """The ``swarm status`` table as arrays, one row per drone heard (``drone`` gives its index).

    - ``t_s``: the ground station's simulated time (s); ``plan_seq``: the plan in force;
      ``plan_command``: FLY, GROUND or LAND; ``plan_late_s``: how late the swarm flies it (s),
      None while it waits on the ground for the take-off.
    - ``drone`` (N,) int; ``alive`` (N,) bool (its agent is in the swarm); ``mode`` (N,) agent
      mode names (``LOST`` for a lost drone, "" before its first status); ``armed`` (N,) bool.
    - ``position_ned_m`` (N, 3) m; ``estimate`` (N, 9) each agent's estimate of the descriptors;
      ``estimate_error_m`` (N,) m, its centre's distance from the true centre; NaN if unknown.
    - ``link_quality`` (N,) 0..1 (NaN unknown); ``failsafes`` (N,) int, reported by its vehicle;
      ``neighbours``: each agent's neighbours this round; ``lost``: drone -> (t_s, why).
    """

    t_s: float
    plan_seq: int | None
    plan_command: str | None
    plan_late_s: float | None
    drone: npt.NDArray[np.int64]
    alive: npt.NDArray[np.bool_]
    mode: tuple[str, ...]
    armed: npt.NDArray[np.bool_]
    position_ned_m: FloatArray
    estimate: FloatArray
    estimate_error_m: FloatArray
    link_quality: FloatArray
    failsafes: npt.NDArray[np.int64]
    neighbours: tuple[tuple[int, ...], ...]
    lost: dict[int, tuple[float, str]] = field(default_factory=dict)

    @property
    def n_drones(self) -> int:
        return int(self.drone.size)

    def true_descriptors(self) -> FloatArray:
        """The descriptors (9,) of the alive drones' positions; NaN with fewer than two."""
        ok = self.alive & np.isfinite(self.position_ned_m).all(axis=1)
        if ok.sum() < 2:
            return np.full(9, np.nan)
        out: FloatArray = descriptors_of(self.position_ned_m[ok])
        return out


def _num(value: object) -> float:
    return (
        float(value) if isinstance(value, int | float) and not isinstance(value, bool) else math.nan
    )


def status_of(reply_t_s: float | None, plan: Mapping[str, Any] | None, seq: int | None,
              table: Sequence[Mapping[str, Any]]) -> Status:  # fmt: skip
    """A :class:`Status` from a ``status`` reply's time, plan summary, seq and table rows."""
    rows = sorted(table, key=lambda r: int(r.get("drone", 0)))
    n = len(rows)
    pos = np.full((n, 3), np.nan)
    est = np.full((n, 9), np.nan)
    for k, r in enumerate(rows):
        if r.get("position_ned_m") is not None:
            pos[k] = [_num(x) for x in r["position_ned_m"]]
        if r.get("estimate") is not None:
            est[k] = [_num(x) for x in r["estimate"]]
    lost = {
        int(r["drone"]): (_num(r["lost"].get("t_s")), str(r["lost"].get("reason")))
        for r in rows
        if isinstance(r.get("lost"), dict)
    }
    plan = plan or {}
    late = plan.get("late_s")
    return Status(
        t_s=_num(reply_t_s),
        plan_seq=plan.get("seq", seq),
        plan_command=plan.get("command"),
        plan_late_s=None if late is None else float(late),
        drone=np.array([int(r.get("drone", 0)) for r in rows], dtype=np.int64),
        alive=np.array([bool(r.get("alive")) for r in rows], dtype=bool),
        mode=tuple(str(r.get("mode") or "") for r in rows),
        armed=np.array([bool(r.get("armed")) for r in rows], dtype=bool),
        position_ned_m=pos,
        estimate=est,
        estimate_error_m=np.array([_num(r.get("estimate_error_m")) for r in rows]),
        link_quality=np.array([_num(r.get("link_quality")) for r in rows]),
        failsafes=np.array([int(r.get("failsafes") or 0) for r in rows], dtype=np.int64),
        neighbours=tuple(tuple(int(x) for x in r.get("neighbours") or ()) for r in rows),
        lost=lost,
    )


@dataclass(frozen=True)
class Descriptors:
    """The swarm's descriptors at ``t_s``: ``true`` (9,) from the alive drones' positions, and
    ``estimated`` (N, 9), each agent's (rows in ``drone`` order; NaN for a silent agent)."""

    t_s: float
    true: FloatArray
    estimated: FloatArray
    drone: npt.NDArray[np.int64]


def descriptors_from(status: Status) -> Descriptors:
    """The true and estimated descriptors of ``status``."""
    return Descriptors(status.t_s, status.true_descriptors(), status.estimate, status.drone)


@dataclass(frozen=True)
class Sent:
    """An accepted plan command, as :func:`arrived` follows it: its ``name``, the plan ``seq`` it
    made, when its change arrives on that plan's clock (``arrives_s``), and the failsafes and
    lost drones known when it was sent."""

    name: str
    seq: int
    arrives_s: float
    failsafes: Mapping[int, int]
    lost: frozenset[int]


def baseline(name: str, seq: int, arrives_s: float, status: Status) -> Sent:
    """The :class:`Sent` of command ``name`` (plan ``seq``) against ``status`` just before."""
    failsafes = dict(zip(status.drone.tolist(), status.failsafes.tolist(), strict=True))
    return Sent(name, seq, arrives_s, failsafes, frozenset(status.lost))


def arrived(sent: Sent, status: Status) -> bool:
    """Whether the change of ``sent`` has arrived as of ``status``: the swarm's time has passed
    its arrival, as late as the swarm flies the plan (a take-off typed on the ground waits for
    the swarm to leave it); a landing, once every drone still in the swarm is LANDED and
    disarmed. Raises :class:`Failsafe` when a vehicle failed safe or a drone was lost since it
    was sent, :class:`Superseded` when a later plan replaced its plan."""
    for d, count in zip(status.drone.tolist(), status.failsafes.tolist(), strict=True):
        if count > sent.failsafes.get(d, 0):
            raise Failsafe(f"{sent.name}: drone {d}'s vehicle failed safe (t = {status.t_s:.1f} s)")
    for d, (t_s, why) in sorted(status.lost.items()):
        if d not in sent.lost:
            raise Failsafe(f"{sent.name}: drone {d} lost at t = {t_s:.1f} s: {why}")
    if status.plan_seq is not None and status.plan_seq > sent.seq:
        raise Superseded(
            f"{sent.name}: plan {sent.seq} was replaced by plan {status.plan_seq} before it arrived"
        )
    if sent.name == "land":
        members = [m for m, a in zip(status.mode, status.alive, strict=True) if a]
        down = all(m == LANDED for m in members) and not status.armed[status.alive].any()
        return bool(members) and down
    late = status.plan_late_s
    return late is not None and status.t_s >= sent.arrives_s + late

"""What the 3-D view shows, computed from a report's files alone. Pure (numpy; no Rerun).

A :class:`Scene` is built from ``flight.tlog`` (positions, the agents' estimates), ``events.jsonl``
(who joined, was lost, failed safe; every event as a log line) and ``trajectory.json`` (the plan:
the commanded descriptors), so a recording made from it (:mod:`gcs.view.rerun_log`) shows exactly
what those files say. Samples are the tlog's own: the time grid is the tlog's LOCAL_POSITION_NED
rate, starting at its first sample, sample-and-hold (:func:`gcs.report.log_record.build_record`),
so each sample time carries the logged position of that time.

Mode of a drone at a sample (its colour in the view): ``GROUND`` (not airborne), ``FLYING``,
``FAILSAFE`` (after a ``failsafe`` event about it) and ``LOST`` (after its drop-out or crash).

Radio links (:class:`LinkLog`, :func:`link_pairs`): at a sample, drones i and j are linked when
the latest status of i (at most ``MAX_AGE_S`` old, as the report's estimates) says it integrated
j's message that tick, or j's says so of i; ``both`` when both did. Statuses of tlog layout 0
(older logs) carry no ids: their agents draw no links.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from enum import IntEnum
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from gcs.report.events import read_events
from gcs.report.flight_record import FlightRecord
from gcs.report.log_record import MAX_AGE_S, build_record, hold
from gcs.report.metrics import heading_mask, true_descriptors
from gcs.report.tlog import TlogTrack, read_tlog
from protocols.model.frames import FloatArray
from protocols.model.trajectory import DescriptorTrajectory

_LOST_KINDS = ("agent_left", "dropout_detected", "crash")
TLOG, EVENTS, TRAJECTORY = "flight.tlog", "events.jsonl", "trajectory.json"
#: Descriptor names in protocols/model/descriptor_vector.py order, and their units in the view.
DESCRIPTORS = ("centre_n", "centre_e", "centre_d", "roll", "pitch", "yaw", "s_length", "s_width",
               "s_height")  # fmt: skip
UNITS = ("m", "m", "m", "deg", "deg", "deg", "m2", "m2", "m2")


class Mode(IntEnum):
    """What a drone is doing, as the view colours it."""

    GROUND = 0
    FLYING = 1
    FAILSAFE = 2
    LOST = 3


@dataclass(frozen=True)
class EventLine:
    """One event as a log line: time (s), level (INFO, WARN, ERROR), text."""

    t_s: float
    level: str
    text: str


@dataclass(frozen=True)
class Scene:
    """A flight as the view shows it; T samples, N drones (index i = system id - 1).

    ``t_s`` (T,) s; ``position_ned_m`` (T, N, 3), NaN where a drone was not heard yet;
    ``mode`` (T, N) :class:`Mode`; ``estimate_centre_ned_m`` (T, N, 3) each agent's estimate of the
    swarm centre (NaN where none); ``estimate`` (T, N, 9) each member agent's estimate of the
    descriptors (NaN where none, or not a member); ``desired`` and ``actual`` (T, 9) the commanded
    and the true descriptors (NaN where fewer than 2 members); ``heading_ok`` (T,) where the true
    orientation is defined (length and width spreads apart); ``min_separation_m`` (T,) between
    airborne drones (NaN with fewer than 2); ``consensus_error_m`` (T,) the worst distance of an
    agent's centre estimate from the true centre; ``neighbours_mean`` (T,) the agents' mean number
    of neighbours; ``events`` in time order; ``links`` the neighbours each agent integrated (None:
    unknown, nothing drawn): :func:`link_pairs`."""

    t_s: FloatArray
    position_ned_m: FloatArray
    mode: npt.NDArray[np.int8]
    estimate_centre_ned_m: FloatArray
    estimate: FloatArray
    desired: FloatArray
    actual: FloatArray
    heading_ok: npt.NDArray[np.bool_]
    min_separation_m: FloatArray
    consensus_error_m: FloatArray
    neighbours_mean: FloatArray
    events: tuple[EventLine, ...]
    links: LinkLog | None = None

    @property
    def n_drones(self) -> int:
        return int(self.position_ned_m.shape[1])


@dataclass(frozen=True)
class LinkLog:
    """The neighbour ids the agents' statuses carried: per drone index i (a tuple of N),
    ``t_s[i]`` (S_i,) the status times, s, and ``ids[i]`` (S_i, K) the ids of the neighbours
    integrated, NaN-padded (all NaN for a status of layout 0, which carries none)."""

    t_s: tuple[FloatArray, ...]
    ids: tuple[FloatArray, ...]

    @staticmethod
    def from_track(track: TlogTrack, n_drones: int) -> LinkLog | None:
        """The links of the statuses in ``track`` (drones 0..n_drones-1); None if no status of
        it carries neighbour ids (a log older than layout 1)."""
        tracks = [track.vehicles.get(i + 1) for i in range(n_drones)]
        if not any(v is not None and (v.status_layout == 1).any() for v in tracks):
            return None
        return LinkLog(
            tuple(np.zeros(0) if v is None else v.status_t_s for v in tracks),
            tuple(np.zeros((0, 0)) if v is None else v.status_neighbours for v in tracks),
        )

    def integrated(self, t_s: FloatArray, max_age_s: float = MAX_AGE_S) -> FloatArray:
        """(T, N, K) at each time of ``t_s`` (T,), each agent's neighbour ids in its latest
        status at most ``max_age_s`` old (the report's sample-and-hold of the statuses, as its
        estimates); NaN where there is none, or it carries no ids."""
        t_grid = np.asarray(t_s, dtype=float)
        width = max((a.shape[1] for a in self.ids), default=0)
        out = np.full((t_grid.size, len(self.ids), width), np.nan)
        for i, (t, ids) in enumerate(zip(self.t_s, self.ids, strict=True)):
            if t.size:
                out[:, i, : ids.shape[1]] = hold(t_grid, t, ids, max_age_s)
        return out


def link_pairs(
    ids: FloatArray, position_ned_m: FloatArray
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_]]:
    """The radio links of one sample between drones whose positions (N, 3) are known, from each
    agent's integrated neighbours ``ids`` (N, K) (:meth:`LinkLog.integrated`): (L, 2) pairs i < j
    in ascending order, and (L,) whether both directions integrated (else only one did)."""
    n = position_ned_m.shape[0]
    rows, cols = np.nonzero(np.isfinite(ids))
    i, j = rows, ids[rows, cols].astype(np.int64)
    seen = np.isfinite(position_ned_m[:, 0])
    ok = (j >= 0) & (j < n) & (j != i)
    ok[ok] &= seen[i[ok]] & seen[j[ok]]
    key = np.minimum(i[ok], j[ok]) * n + np.maximum(i[ok], j[ok])
    pairs, count = np.unique(key, return_counts=True)
    return np.stack([pairs // n, pairs % n], axis=1), count > 1


def read_plan(path: Path) -> DescriptorTrajectory | None:
    """The plan in ``trajectory.json`` (as gcs/reference/simulate.py writes it), None if absent."""
    if not path.exists():
        return None
    data = json.loads(path.read_text())
    return DescriptorTrajectory(
        int(data["seq"]), np.asarray(data["t_knots_s"]), np.asarray(data["coeffs_ascending_powers"])
    )


def tlog_rate_hz(track: TlogTrack) -> float | None:
    """The LOCAL_POSITION_NED rate (Hz) of the busiest vehicle, None without two samples."""
    steps = [np.diff(v.t_s) for v in track.vehicles.values() if v.t_s.size >= 2]
    if not steps:
        return None
    step = float(np.median(np.concatenate(steps)))
    return 1.0 / step if step > 0 else None


def scene_from_report(
    report_dir: Path, n_drones: int | None = None, track: TlogTrack | None = None
) -> Scene | None:
    """The scene of the report in ``report_dir`` (None if its tlog holds no flight). ``n_drones``
    defaults to the largest system id in the tlog; ``track``: its flight.tlog already read."""
    if track is None:
        track = read_tlog(report_dir / TLOG)
    events = read_events(report_dir / EVENTS) if (report_dir / EVENTS).exists() else []
    plan = read_plan(report_dir / TRAJECTORY)
    n = n_drones if n_drones is not None else max(track.vehicles, default=0)
    rate = tlog_rate_hz(track)
    if plan is None or rate is None or n < 1:
        return None
    record = build_record(
        report_dir / TLOG, report_dir / EVENTS, plan, n, rate, np.inf, None, track
    )
    if record is None:
        return None
    return scene_from_record(record, events, LinkLog.from_track(track, n))


def _simulated_membership(
    record: FlightRecord, events: Sequence[Mapping[str, Any]]
) -> FlightRecord:
    """``swarm simulate``'s events have no ``agent_joined``: there every drone is a member from
    the start until its agent leaves (``agent_left``, ``dropout_detected`` or ``crash``)."""
    if any(e.get("kind") == "agent_joined" for e in events):
        return record
    lost: dict[int, float] = {}
    for e in events:
        i = e.get("drone")
        if e.get("kind") in _LOST_KINDS and isinstance(i, int) and 0 <= i < record.n_drones:
            lost.setdefault(i, float(e["t_s"]))
    member = np.ones_like(record.member)
    for i, t_lost in lost.items():
        member[record.t_s >= t_lost - 5e-4, i] = False
    return replace(record, member=member, lost_at_s=lost)


def scene_from_record(
    record: FlightRecord, events: Sequence[Mapping[str, Any]], links: LinkLog | None = None
) -> Scene:
    """The scene of a flight record, its events and its agents' links."""
    record = _simulated_membership(record, events)
    heard = np.isfinite(record.position_ned_m[..., 0]) & (
        record.member | np.any(record.position_ned_m != 0.0, axis=-1)
    )
    pos = np.where(heard[..., None], record.position_ned_m, np.nan)
    actual = true_descriptors(record)
    est = record.estimate[..., :3]
    err = np.linalg.norm(est - actual[:, None, :3], axis=-1)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN row is a NaN answer
        consensus = np.nanmax(np.where(np.isfinite(err), err, np.nan), axis=1)
        known = np.isfinite(record.estimate[..., 0])
        neighbours = np.where(
            known.any(axis=1),
            (record.neighbours * known).sum(axis=1) / np.maximum(known.sum(axis=1), 1),
            np.nan,
        )
    return Scene(
        t_s=record.t_s,
        position_ned_m=pos,
        mode=modes(record, events),
        estimate_centre_ned_m=est,
        estimate=np.where(record.member[..., None], record.estimate, np.nan),
        desired=record.desired,
        actual=actual,
        heading_ok=heading_mask(actual),
        min_separation_m=min_separation(pos, record.airborne),
        consensus_error_m=consensus,
        neighbours_mean=neighbours,
        events=tuple(event_lines(events)),
        links=links,
    )


def modes(record: FlightRecord, events: Sequence[Mapping[str, Any]]) -> npt.NDArray[np.int8]:
    """(T, N) :class:`Mode` of every drone at every sample."""
    t = record.t_s
    mode = np.where(record.airborne, Mode.FLYING, Mode.GROUND).astype(np.int8)
    for event in events:
        i = event.get("drone")
        if event.get("kind") == "failsafe" and isinstance(i, int) and 0 <= i < record.n_drones:
            late = (t >= float(event["t_s"]) - 5e-4) & record.airborne[:, i]
            mode[late, i] = Mode.FAILSAFE
    for i, t_lost in record.lost_at_s.items():
        mode[t >= t_lost - 5e-4, i] = Mode.LOST
    return mode


def min_separation(position_ned_m: FloatArray, airborne: npt.NDArray[np.bool_]) -> FloatArray:
    """(T,) the smallest distance (m) between two airborne drones, NaN with fewer than two."""
    n = position_ned_m.shape[1]
    out = np.full(position_ned_m.shape[0], np.nan)
    if n < 2:
        return out
    i, j = np.triu_indices(n, k=1)
    chunk = max(1, 2_000_000 // max(1, i.size))
    for k0 in range(0, out.size, chunk):
        x = position_ned_m[k0 : k0 + chunk]
        d = np.linalg.norm(x[:, i] - x[:, j], axis=-1)
        air = airborne[k0 : k0 + chunk]
        d = np.where(air[:, i] & air[:, j] & np.isfinite(d), d, np.inf)
        best = d.min(axis=1)
        out[k0 : k0 + chunk] = np.where(np.isfinite(best), best, np.nan)
    return out


_LEVELS = {0: "CRITICAL", 1: "CRITICAL", 2: "CRITICAL", 3: "ERROR", 4: "WARN", 5: "INFO"}
_WARN_KINDS = ("fault", "failsafe", "agent_left", "dropout_detected", "link_cut", "drill")
_ERROR_KINDS = ("crash", "hard_landing")


def event_lines(events: Sequence[Mapping[str, Any]]) -> list[EventLine]:
    """Each event as one log line, in time order: ``[drone i] kind: key=value ...``."""
    out = []
    for event in sorted(events, key=lambda e: float(e.get("t_s", 0.0))):
        kind = str(event.get("kind", "?"))
        fields = {k: v for k, v in event.items() if k not in ("t_s", "kind", "drone")}
        drone = event.get("drone")
        who = f"drone {drone} " if isinstance(drone, int) else ""
        detail = " ".join(f"{k}={v}" for k, v in fields.items())
        severity = fields.get("severity")
        if isinstance(severity, int) and severity in _LEVELS:
            level = _LEVELS[severity]
        elif kind in _ERROR_KINDS:
            level = "ERROR"
        elif kind in _WARN_KINDS or fields.get("accepted") is False:
            level = "WARN"
        else:
            level = "INFO"
        text = f"{who}{kind}: {detail}" if detail else f"{who}{kind}"
        out.append(EventLine(float(event.get("t_s", 0.0)), level, text))
    return out

"""A :class:`~gcs.report.flight_record.FlightRecord` rebuilt from the ground station's own logs
(``flight.tlog``: vehicle telemetry and the agents' statuses; ``events.jsonl``: joins, drop-outs,
crashes, drills): what the ground station's report (gcs/report/from_logs.py), the viewer's scene
and :func:`gcs.api.load_report` read a flight as.

Sampling: a uniform grid of simulated time at ``rate_hz`` (the telemetry rate), sample-and-hold.
Estimates are NaN where no status of that agent is younger than ``max_age_s``.

Controls: the simulator streams each vehicle's rotor forces (N) to the GCS in
ACTUATOR_OUTPUT_STATUS (protocols/mavlink/conventions.py); collective thrust (N) and body moments
(N m) follow from them with the mixer's geometry
(:func:`sitl_sim.physics.mixer.wrench_from_rotor_forces`) and the scenario's vehicle parameters. A
vehicle that sent none has zero thrust and moments.

Link cuts (shaded in the plots): the scenario's own
(:func:`gcs.report.flight_record.scenario_link_cuts`; the agents apply them) and the ``link_cut``
drills the ground station logged in ``events.jsonl`` (:mod:`gcs.station.drills`), each ending at
its duration, a ``link_restore`` of the pair, a ``clear`` or the end of the run.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from gcs.report.events import read_events
from gcs.report.flight_record import FlightRecord, LinkFault, scenario_link_cuts
from gcs.report.tlog import TlogTrack, VehicleTrack, read_tlog
from protocols.model.frames import FloatArray
from protocols.model.trajectory import DescriptorTrajectory
from protocols.scenario.scenario_file import Scenario
from sitl_sim.physics.mixer import wrench_from_rotor_forces
from sitl_sim.physics.vehicle_params import VehicleParams
from sitl_sim.vehicle.config import vehicle_params

AIRBORNE_M = 0.1  # above this altitude (m) a vehicle counts as airborne
MAX_AGE_S = 1.0


def hold(t_grid: FloatArray, t_src: FloatArray, values: FloatArray, max_age_s: float) -> FloatArray:
    """Sample-and-hold of ``values`` (K, ...) taken at ``t_src`` (K,) onto ``t_grid``; NaN where
    there is no sample at most ``max_age_s`` old."""
    out = np.full((t_grid.shape[0], *values.shape[1:]), np.nan)
    if t_src.size == 0:
        return out
    order = np.argsort(t_src, kind="stable")
    t_src, values = t_src[order], values[order]
    k = np.searchsorted(t_src, t_grid + 5e-4, side="right") - 1
    ok = k >= 0
    kk = np.where(ok, k, 0)
    ok &= t_grid - t_src[kk] <= max_age_s + 5e-4
    out[ok] = values[kk[ok]]
    return out


def controls(
    t_grid: FloatArray, track: VehicleTrack, params: VehicleParams
) -> tuple[FloatArray, FloatArray]:
    """Collective thrust (T,) N and body moments (T, 3) N m of one vehicle on ``t_grid`` (T,) s,
    sample-and-hold of its rotor forces; zero before its first ACTUATOR_OUTPUT_STATUS."""
    forces = np.nan_to_num(hold(t_grid, track.actuator_t_s, track.rotor_forces_n, np.inf))
    thrust, moments = wrench_from_rotor_forces(forces.T, params)
    return thrust, moments.T


def drill_link_faults(events: Iterable[Mapping[str, Any]], end_s: float) -> list[LinkFault]:
    """The link cuts of the accepted ``drill`` events (times in s; their ``link``, ``one_way`` and
    ``duration_s`` fields, gcs.station.drills), in order: each lasts its duration, or until a
    ``link_restore`` of the pair, a ``clear`` or ``end_s``."""
    cuts: list[LinkFault] = []
    for event in events:
        if event.get("kind") != "drill" or not event.get("accepted"):
            continue
        t, drill, link = float(event["t_s"]), event.get("drill"), event.get("link")
        if drill == "link_cut" and link:
            duration = event.get("duration_s")
            t1 = min(end_s, t + float(duration)) if duration else end_s
            cuts.append(LinkFault(t, t1, int(link[0]), int(link[1]), bool(event.get("one_way"))))
        elif drill == "clear" or (drill == "link_restore" and link):
            ends = {int(link[0]), int(link[1])} if drill == "link_restore" and link else None
            for k, c in enumerate(cuts):
                if c.t0_s <= t < c.t1_s and (ends is None or {c.i, c.j} == ends):
                    cuts[k] = replace(c, t1_s=t)
    return cuts


def build_record(
    tlog_path: Path,
    events_path: Path,
    plan: DescriptorTrajectory,
    n_drones: int,
    rate_hz: float,
    end_s: float,
    scenario: Scenario | None = None,
    track: TlogTrack | None = None,
    events: list[dict[str, Any]] | None = None,
) -> FlightRecord | None:
    """The flight as the ground station logged it, or None if no vehicle was heard.

    Everything comes from the files, so a ground station restarted mid-flight reports the whole
    flight: positions, attitudes, rotor forces and agent statuses from ``tlog_path``; who was in
    the swarm (``agent_joined``, ``dropout_detected``, ``crash``) and the link-cut drills from
    ``events_path``; the commanded descriptors from ``plan``, the final plan (a plan keeps the
    segments already flown). ``scenario`` gives the vehicle parameters that turn rotor forces
    into thrust and moments (default: :class:`VehicleParams`) and its own link cuts. ``track``:
    the tlog already read (else it is read from ``tlog_path``); ``events``: the events to read
    membership and drills from (else those of ``events_path``).
    """
    if track is None:
        track = read_tlog(tlog_path)
    heard = [v for s, v in track.vehicles.items() if 1 <= s <= n_drones and v.t_s.size]
    if not heard:
        return None
    t0 = min(float(v.t_s[0]) for v in heard)
    t1 = min(end_s, max(float(v.t_s[-1]) for v in heard))
    t = np.arange(t0, t1 + 1e-9, 1.0 / rate_hz)
    if t.size < 2:
        return None
    n = n_drones
    pos = np.full((t.size, n, 3), np.nan)
    vel, euler = np.zeros((t.size, n, 3)), np.zeros((t.size, n, 3))
    thrust, moments = np.zeros((t.size, n)), np.zeros((t.size, n, 3))
    params = VehicleParams() if scenario is None else vehicle_params(scenario)
    est = np.full((t.size, n, 9), np.nan)
    nbrs = np.zeros((t.size, n), dtype=int)
    for sysid, v in track.vehicles.items():
        i = sysid - 1
        if not 0 <= i < n:
            continue
        pos[:, i] = hold(t, v.t_s, v.position_ned_m, np.inf)
        vel[:, i] = np.nan_to_num(hold(t, v.t_s, v.velocity_ned_m_s, np.inf))
        euler[:, i] = np.nan_to_num(hold(t, v.attitude_t_s, v.euler_rad, np.inf))
        thrust[:, i], moments[:, i] = controls(t, v, params)
        status = hold(t, v.status_t_s, v.status, MAX_AGE_S)
        est[:, i] = status[:, :9]
        nbrs[:, i] = np.nan_to_num(status[:, 9]).astype(int)
    if events is None:
        events = read_events(events_path) if events_path.exists() else []
    alive, lost_at_s = membership(events, t, n)
    returns = [g for g in absences(events, n) if g["back_s"] is not None]
    known = ~np.isnan(pos[..., 0])
    pos = np.where(known[..., None], pos, 0.0)
    return FlightRecord(
        t_s=t,
        position_ned_m=pos,
        velocity_ned_m_s=vel,
        euler_rad=euler,
        thrust_n=thrust,
        moments_nm=moments,
        desired=plan.evaluate_many(t)[0],
        estimate=est,
        member=known & alive,
        airborne=known & (-pos[..., 2] > AIRBORNE_M),
        neighbours=nbrs,
        link_faults=_link_faults(scenario, events, float(t[-1])),
        lost_at_s=lost_at_s,
        returns=[(g["drone"], g["left_s"], g["back_s"]) for g in returns],
    )


def membership(
    events: Iterable[Mapping[str, Any]], t_grid: FloatArray, n_drones: int
) -> tuple[npt.NDArray[np.bool_], dict[int, float]]:
    """Who is in the swarm on ``t_grid`` (T,) s: (T, N) True from an ``agent_joined`` event until
    the drone is lost; and when each drone lost at the end was lost (the ``dropout_detected`` or
    ``crash`` that began its last absence, s). A drone whose agent left comes back with a later
    ``agent_joined`` (a restarted agent: :func:`absences`); a crashed one never does."""
    alive = np.zeros((t_grid.size, n_drones), dtype=bool)
    lost_at_s: dict[int, float] = {}
    for gap in absences(events, n_drones):
        i, left, back = gap["drone"], gap["left_s"], gap["back_s"]
        if back is None:
            lost_at_s[i] = left
    for i, spans in _present(events, n_drones).items():
        for t0, t1 in spans:
            alive[(t_grid >= t0 - 5e-4) & (t_grid < t1), i] = True
    return alive, lost_at_s


def _present(
    events: Iterable[Mapping[str, Any]], n_drones: int
) -> dict[int, list[tuple[float, float]]]:
    """Per drone, the spans [joined, lost) it was a member (the last one open: inf)."""
    spans: dict[int, list[tuple[float, float]]] = {}
    since: dict[int, float] = {}
    crashed: set[int] = set()
    for event in events:
        i, kind = event.get("drone"), event.get("kind")
        if not isinstance(i, int) or not 0 <= i < n_drones:
            continue
        t = float(event["t_s"])
        if kind == "agent_joined" and i not in crashed and i not in since:
            since[i] = t
        elif kind in ("dropout_detected", "crash"):
            if kind == "crash":
                crashed.add(i)
            if i in since:
                spans.setdefault(i, []).append((since.pop(i), t))
            else:  # lost before it was seen to join (a report from the files of a later start)
                spans.setdefault(i, [])
    for i, t0 in since.items():
        spans.setdefault(i, []).append((t0, np.inf))
    return spans


def absences(events: Iterable[Mapping[str, Any]], n_drones: int) -> list[dict[str, Any]]:
    """Each time a drone left the swarm, in time order: ``{"drone", "left_s", "back_s",
    "gap_s", "reason"}`` with ``back_s``/``gap_s`` None when it did not come back (a crash never
    does; an agent that left comes back when a new agent of that drone joins: the restart drill,
    or ``swarm agent`` started again). ``reason``: the event that began it (``dropout_detected``
    or ``crash``)."""
    out: list[dict[str, Any]] = []
    open_gap: dict[int, dict[str, Any]] = {}
    crashed: set[int] = set()
    for event in events:
        i, kind = event.get("drone"), event.get("kind")
        if not isinstance(i, int) or not 0 <= i < n_drones:
            continue
        t = float(event["t_s"])
        if kind in ("dropout_detected", "crash"):
            if kind == "crash":
                crashed.add(i)
            if i not in open_gap:
                gap = {"drone": i, "left_s": t, "back_s": None, "gap_s": None, "reason": kind}
                open_gap[i] = gap
                out.append(gap)
        elif kind == "agent_joined" and i in open_gap and i not in crashed:
            gap = open_gap.pop(i)
            gap["back_s"], gap["gap_s"] = t, t - gap["left_s"]
    return out


def _link_faults(
    scenario: Scenario | None, events: Iterable[Mapping[str, Any]], end_s: float
) -> list[LinkFault]:
    """The scenario's link cuts and the drills among ``events``."""
    faults = [] if scenario is None else scenario_link_cuts(scenario)
    return faults + drill_link_faults(events, end_s)

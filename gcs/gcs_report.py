"""The ground station's report: a :class:`~gcs.flight_record.FlightRecord` rebuilt from what the
ground station saw (its own ``flight.tlog``, the plans it published, the agents' statuses and
liveliness), then ``metrics.json``, ``trajectory.json`` and the paper-style PNG plots, the same
files as ``swarm simulate`` writes.

Sampling: a uniform grid of simulated time at ``rate_hz`` (the telemetry rate), sample-and-hold.
Estimates are NaN where no status of that agent is younger than ``max_age_s``.

Controls: the simulator streams each vehicle's rotor forces (N) to the GCS in
ACTUATOR_OUTPUT_STATUS (protocols/mavlink_conventions.py); collective thrust (N) and body moments
(N m) follow from them with the mixer's geometry (:func:`sitl_sim.mixer.wrench_from_rotor_forces`)
and the scenario's vehicle parameters. A vehicle that sent none has zero thrust and moments.

Link cuts (shaded in the plots): the scenario's own (:func:`gcs.fault_timeline.link_faults`, the
agents apply them) and the ``link_cut`` drills the ground station logged in ``events.jsonl``
(:mod:`gcs.gcs_drills`), each ending at its duration, a ``link_restore`` of the pair, a ``clear``
or the end of the run.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from gcs.events import read_events
from gcs.fault_timeline import link_faults
from gcs.flight_record import FlightRecord, LinkFault
from gcs.metrics import compute_metrics
from gcs.plots import write_plots
from gcs.simulate import _write_trajectory
from gcs.tlog import VehicleTrack, read_tlog
from protocols.frames import FloatArray
from protocols.scenario import Scenario
from protocols.trajectory import DescriptorTrajectory
from sitl_sim.config import vehicle_params
from sitl_sim.mixer import wrench_from_rotor_forces
from sitl_sim.vehicle_params import VehicleParams

AIRBORNE_M = 0.1  # above this altitude (m) a vehicle counts as airborne
MAX_AGE_S = 1.0
#: ``what`` of a link-cut / link-restore drill event (drone_agent.fault_drills.describe).
_CUT = re.compile(r"link_cut (\d+)(->|<->)(\d+)(?: for (\S+) s)?")
_RESTORE = re.compile(r"link_restore (\d+)<->(\d+)")


@dataclass
class Observations:
    """What the ground station saw over Zenoh, in simulated time (s).

    ``plans``: (t_from_s, trajectory) in publication order; ``statuses``: drone -> list of
    (t_s, estimate (9,), neighbour count); ``alive``: drone -> list of (t_s, alive);
    ``lost_at_s``: drone -> time its drop-out or crash was detected.
    """

    plans: list[tuple[float, DescriptorTrajectory]] = field(default_factory=list)
    statuses: dict[int, list[tuple[float, FloatArray, int]]] = field(default_factory=dict)
    alive: dict[int, list[tuple[float, bool]]] = field(default_factory=dict)
    lost_at_s: dict[int, float] = field(default_factory=dict)


def _hold(
    t_grid: FloatArray, t_src: FloatArray, values: FloatArray, max_age_s: float
) -> FloatArray:
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
    forces = np.nan_to_num(_hold(t_grid, track.actuator_t_s, track.rotor_forces_n, np.inf))
    thrust, moments = wrench_from_rotor_forces(forces.T, params)
    return thrust, moments.T


def drill_link_faults(events: Iterable[Mapping[str, Any]], end_s: float) -> list[LinkFault]:
    """The link cuts of the accepted ``drill`` events (times in s), in order: each lasts its
    duration, or until a ``link_restore`` of the pair, a ``clear`` or ``end_s``."""
    cuts: list[LinkFault] = []
    for event in events:
        if event.get("kind") != "drill" or not event.get("accepted"):
            continue
        t, drill, what = float(event["t_s"]), event.get("drill"), str(event.get("what", ""))
        if drill == "link_cut" and (cut := _CUT.fullmatch(what)):
            i, j, duration = int(cut[1]), int(cut[3]), cut[4]
            t1 = min(end_s, t + float(duration)) if duration else end_s
            cuts.append(LinkFault(t, t1, i, j, one_way=cut[2] == "->"))
        elif drill in ("link_restore", "clear"):
            pair = _RESTORE.fullmatch(what)
            ends = None if pair is None else {int(pair[1]), int(pair[2])}
            if drill == "link_restore" and ends is None:
                continue
            for k, c in enumerate(cuts):
                if c.t0_s <= t < c.t1_s and (ends is None or {c.i, c.j} == ends):
                    cuts[k] = replace(c, t1_s=t)
    return cuts


def build_record(
    tlog_path: Path,
    n_drones: int,
    obs: Observations,
    rate_hz: float,
    end_s: float,
    scenario: Scenario | None = None,
    events_path: Path | None = None,
) -> FlightRecord | None:
    """The flight as seen by the ground station, or None if no vehicle was heard.

    ``scenario`` gives the vehicle parameters that turn rotor forces into thrust and moments
    (default: :class:`VehicleParams`) and its link cuts; ``events_path`` (an ``events.jsonl``)
    the link-cut drills. Without them the record has no link faults.
    """
    track = read_tlog(tlog_path)
    heard = [v for s, v in track.vehicles.items() if 1 <= s <= n_drones and v.t_s.size]
    if not heard or not obs.plans:
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
    alive = np.zeros((t.size, n), dtype=bool)
    for sysid, v in track.vehicles.items():
        i = sysid - 1
        if not 0 <= i < n:
            continue
        pos[:, i] = _hold(t, v.t_s, v.position_ned_m, np.inf)
        vel[:, i] = np.nan_to_num(_hold(t, v.t_s, v.velocity_ned_m_s, np.inf))
        euler[:, i] = np.nan_to_num(_hold(t, v.attitude_t_s, v.euler_rad, np.inf))
        thrust[:, i], moments[:, i] = controls(t, v, params)
    for i, rows in obs.statuses.items():
        if 0 <= i < n and rows:
            ts = np.array([r[0] for r in rows])
            est[:, i] = _hold(t, ts, np.array([r[1] for r in rows]), MAX_AGE_S)
            nb = _hold(t, ts, np.array([float(r[2]) for r in rows]), MAX_AGE_S)
            nbrs[:, i] = np.nan_to_num(nb).astype(int)
    for i, changes in obs.alive.items():
        if 0 <= i < n and changes:
            ts = np.array([c[0] for c in changes])
            held = _hold(t, ts, np.array([1.0 if c[1] else 0.0 for c in changes]), np.inf)
            alive[:, i] = held == 1.0
    known = ~np.isnan(pos[..., 0])
    pos = np.where(known[..., None], pos, 0.0)
    desired = np.empty((t.size, 9))
    for k, tk in enumerate(t):
        plan = next((p for t_from, p in reversed(obs.plans) if t_from <= tk), obs.plans[0][1])
        desired[k] = plan.evaluate(float(tk))[0]
    member = known & alive
    for i, t_lost in obs.lost_at_s.items():
        if 0 <= i < n:
            member[t >= t_lost, i] = False
    return FlightRecord(
        t_s=t,
        position_ned_m=pos,
        velocity_ned_m_s=vel,
        euler_rad=euler,
        thrust_n=thrust,
        moments_nm=moments,
        desired=desired,
        estimate=est,
        member=member,
        airborne=known & (-pos[..., 2] > AIRBORNE_M),
        neighbours=nbrs,
        link_faults=_link_faults(scenario, events_path, float(t[-1])),
        lost_at_s=dict(obs.lost_at_s),
    )


def _link_faults(
    scenario: Scenario | None, events_path: Path | None, end_s: float
) -> list[LinkFault]:
    """The scenario's link cuts and the drills logged in ``events_path`` (if it exists)."""
    faults = [] if scenario is None else link_faults(scenario)
    if events_path is not None and events_path.exists():
        faults += drill_link_faults(read_events(events_path), end_s)
    return faults


def write_report(
    report_dir: Path,
    record: FlightRecord | None,
    plan: DescriptorTrajectory,
    settle_s: float,
    extra: dict[str, Any],
    plots: bool = True,
) -> list[Path]:
    """Write ``trajectory.json``, ``metrics.json`` (when there is a record) and the plots."""
    files = [_write_trajectory(plan, report_dir / "trajectory.json")]
    metrics_path = report_dir / "metrics.json"
    if record is None:
        metrics: dict[str, Any] = {"n_samples": 0, "note": "no telemetry received", **extra}
    else:
        faults = [(t, f"drone {i} lost") for i, t in sorted(record.lost_at_s.items())]
        metrics = compute_metrics(record, settle_s=settle_s, faults=faults, extra=extra)
    metrics_path.write_text(json.dumps(metrics, indent=2) + "\n")
    files.append(metrics_path)
    if plots and record is not None:
        files += write_plots(record, report_dir)
    return files

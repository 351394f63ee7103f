"""The ground station's report: a :class:`~gcs.flight_record.FlightRecord` rebuilt from what the
ground station saw (its own ``flight.tlog``, the plans it published, the agents' statuses and
liveliness), then ``metrics.json``, ``trajectory.json`` and the paper-style PNG plots, the same
files as ``swarm simulate`` writes.

Sampling: a uniform grid of simulated time at ``rate_hz`` (the telemetry rate), sample-and-hold.
Thrust and moments are not in the GCS telemetry stream: they are recorded as zeros. Estimates are
NaN where no status of that agent is younger than ``max_age_s``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gcs.flight_record import FlightRecord
from gcs.metrics import compute_metrics
from gcs.plots import write_plots
from gcs.simulate import _write_trajectory
from gcs.tlog import read_tlog
from protocols.frames import FloatArray
from protocols.trajectory import DescriptorTrajectory

AIRBORNE_M = 0.1  # above this altitude (m) a vehicle counts as airborne
MAX_AGE_S = 1.0


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


def build_record(
    tlog_path: Path, n_drones: int, obs: Observations, rate_hz: float, end_s: float
) -> FlightRecord | None:
    """The flight as seen by the ground station, or None if no vehicle was heard."""
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
        thrust_n=np.zeros((t.size, n)),
        moments_nm=np.zeros((t.size, n, 3)),
        desired=desired,
        estimate=est,
        member=member,
        airborne=known & (-pos[..., 2] > AIRBORNE_M),
        neighbours=nbrs,
        lost_at_s=dict(obs.lost_at_s),
    )


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

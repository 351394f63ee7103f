"""The large-swarm bars of issue 10, judged from a flight's flight.tlog and its scenario alone.

- every drone not lost by a fault of the scenario is airborne at the end;
- no two airborne drones closer than ``min_separation_m`` (1.5 m) at any sample;
- during each hold of the plan (two consecutive waypoints with the same value), from
  ``settle_s`` after it starts: the swarm's centroid within 0.05 m of the plan and every spread
  (RMS distance from the centre along the plan's axes) within 2 % of the plan's; the drones
  counted are those still in the swarm (a drone leaves at its drop-out or crash), and the
  ``after_loss_s`` after a drone is lost are left out (the survivors re-form then).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gcs.report.tlog import read_tlog
from gcs.report.trajectory_file import read_trajectory
from protocols.model.descriptors import desired_axes
from protocols.scenario.scenario_file import Crash, Dropout, load_scenario


@dataclass(frozen=True)
class Verdict:
    """What the bars measured: ``lost`` (drone ids the scenario loses), ``airborne_at_end``,
    ``min_separation_m`` between airborne drones, worst centroid error (m) and worst spread
    error (relative) during holds, and the hold samples judged."""

    lost: frozenset[int]
    not_airborne_at_end: tuple[int, ...]
    min_separation_m: float
    centroid_error_m: float
    spread_error: float
    hold_samples: int


def judge(
    report: Path, scenario_path: Path, settle_s: float = 3.0, after_loss_s: float = 5.0
) -> Verdict:
    """The bars of the module doc for the flight in ``report`` of the scenario file."""
    scenario = load_scenario(scenario_path)
    n = scenario.n_drones
    lost_at = {f.drone: f.t_s for f in scenario.faults if isinstance(f, Dropout | Crash)}
    track = read_tlog(report / "flight.tlog")
    dt = 0.1
    t = np.arange(0.0, scenario.duration_s - dt / 2, dt)
    pos = track.resample(t, n, max_age_s=1.0)  # (T, N, 3)
    end = pos[-1]
    survivors = [i for i in range(n) if i not in lost_at]
    not_up = tuple(i for i in survivors if not (np.isfinite(end[i, 2]) and -end[i, 2] > 0.5))
    airborne = np.isfinite(pos[..., 2]) & (-pos[..., 2] > 0.3)
    min_sep = np.inf
    for k in range(t.shape[0]):
        p = pos[k, airborne[k]]
        if p.shape[0] < 2:
            continue
        d = np.linalg.norm(p[:, None] - p[None], axis=-1)
        np.fill_diagonal(d, np.inf)
        min_sep = min(min_sep, float(d.min()))
    # the plan as flown (re-timed to the take-off: protocols/model/plan_timing.py)
    plan = read_trajectory(report / "trajectory.json")
    late = plan.start_s - scenario.trajectory().start_s
    wps = scenario.waypoints
    holds = [
        (a.t_s + late + settle_s, b.t_s + late)
        for a, b in itertools.pairwise(wps)
        if np.allclose(plan.evaluate(a.t_s + late)[0], plan.evaluate(b.t_s + late)[0])
        and -plan.evaluate(a.t_s + late)[0][2] > 1.0  # in the air
    ]
    worst_c, worst_s, samples = 0.0, 0.0, 0
    for k, tk in enumerate(t):
        if not any(lo <= tk <= hi for lo, hi in holds):
            continue
        if any(0.0 <= tk - tl < after_loss_s for tl in lost_at.values()):
            continue
        members = [i for i in range(n) if lost_at.get(i, np.inf) > tk]
        p = pos[k, members]
        if not np.all(np.isfinite(p)):
            continue
        a = plan.evaluate(float(tk))[0]
        centre = p.mean(axis=0)
        axes = desired_axes(a)
        spread = np.sqrt((((p - centre) @ axes) ** 2).mean(axis=0))
        want = np.sqrt(np.maximum(a[6:9], 0.0))
        worst_c = max(worst_c, float(np.linalg.norm(centre - a[:3])))
        flat = want < 0.2  # a flat axis has no spread to be 2 % of
        rel = np.abs(spread[~flat] - want[~flat]) / want[~flat]
        worst_s = max(worst_s, float(rel.max(initial=0.0)))
        samples += 1
    return Verdict(frozenset(lost_at), not_up, min_sep, worst_c, worst_s, samples)

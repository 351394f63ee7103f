"""The orientation bars of issue 15, recomputed from a flight's flight.tlog and its scenario alone.

The true formation of each sample is the principal axes of the positions of the drones still in
the swarm (eigenvectors assigned to the plan's axes, protocols/descriptors.align_axes); against the
plan's axes at the same time it gives

- ``normal_deg``: the angle between the formation's plane normal (third axis) and the plan's;
- ``length_deg``: the angle between the formation's length axis (first axis) and the plan's;
- ``heading_deg``: the true heading (ZYX yaw of the axes) minus the plan's, signed (a lag behind
  a turn to positive yaw is negative), wrapped to (-180, 180].

Samples where a drone is not yet airborne (below 0.3 m) or not reporting are NaN.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gcs.report.tlog import read_tlog
from protocols.model.descriptors import align_axes, desired_axes
from protocols.model.frames import FloatArray, zyx_from_rot
from protocols.scenario.scenario_file import Crash, Dropout, load_scenario


@dataclass(frozen=True)
class OrientationTrack:
    """Per sample time ``t_s`` (T,): the angles of the module doc, degrees (T,) each."""

    t_s: FloatArray
    normal_deg: FloatArray
    length_deg: FloatArray
    heading_deg: FloatArray

    def worst(self, lo_s: float, hi_s: float = np.inf) -> tuple[float, float, float]:
        """The largest |normal|, |length| and |heading| errors for ``lo_s <= t <= hi_s``."""
        k = (self.t_s >= lo_s) & (self.t_s <= hi_s)
        if not k.any() or not np.isfinite(self.normal_deg[k]).all():
            raise AssertionError(f"no complete samples between {lo_s} and {hi_s} s")
        return (
            float(np.abs(self.normal_deg[k]).max()),
            float(np.abs(self.length_deg[k]).max()),
            float(np.abs(self.heading_deg[k]).max()),
        )


def _angle_deg(u: FloatArray, w: FloatArray) -> float:
    """Angle between two unit axes, sign-free (an axis and its opposite are the same axis)."""
    return float(np.degrees(np.arccos(np.clip(abs(float(u @ w)), 0.0, 1.0))))


def orientation_track(
    report: Path, scenario_path: Path, dt_s: float = 0.1, end_s: float | None = None
) -> OrientationTrack:
    """The angles of the module doc for the flight in ``report`` of the scenario file (flown to
    ``end_s``, default its duration)."""
    scenario = load_scenario(scenario_path)
    n = scenario.n_drones
    lost_at = {f.drone: f.t_s for f in scenario.faults if isinstance(f, Dropout | Crash)}
    plan = scenario.trajectory()
    t = np.arange(0.0, (end_s or scenario.duration_s) - dt_s / 2, dt_s)
    pos = read_tlog(report / "flight.tlog").resample(t, n, max_age_s=1.0)
    out = np.full((3, t.shape[0]), np.nan)
    for k, tk in enumerate(t):
        members = [i for i in range(n) if lost_at.get(i, np.inf) > tk]
        p = pos[k, members]
        if not np.isfinite(p).all() or (-p[:, 2] < 0.3).any():
            continue
        d = p - p.mean(axis=0)
        want = desired_axes(plan.evaluate(float(tk))[0])
        axes, _ = align_axes(d.T @ d / d.shape[0], want)
        out[0, k] = _angle_deg(axes[:, 2], want[:, 2])
        out[1, k] = _angle_deg(axes[:, 0], want[:, 0])
        lag = zyx_from_rot(axes)[0] - zyx_from_rot(want)[0]
        out[2, k] = np.degrees((lag + np.pi) % (2 * np.pi) - np.pi)
    return OrientationTrack(t, out[0], out[1], out[2])

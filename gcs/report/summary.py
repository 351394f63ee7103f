"""The short summary table printed at the end of a run."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from gcs.report.agent_timing import summary_lines as timing_summary


def _fmt(value: Any, unit: str = "", digits: int = 3) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, float):
        return f"{value:.{digits}f}{unit}"
    return f"{value}{unit}"


def _rms_max(block: dict[str, Any], key: str, unit: str) -> str:
    stat = block.get(key) or {}
    return f"RMS {_fmt(stat.get('rms'), unit, 4):>11}   max {_fmt(stat.get('max'), unit, 3):>9}"


def summary_lines(metrics: dict[str, Any], files: Sequence[Path]) -> list[str]:
    """Human-readable lines: tracking, consensus, safety, faults, speed, and the files."""
    steady = metrics.get("tracking_steady", {})
    tr = metrics.get("tracking", {})
    cons = metrics.get("consensus_steady", {})
    sep = metrics.get("separation") or {}
    if metrics.get("n_drones") is None:  # nothing flew: the ground station heard no vehicle
        return [
            f"scenario {metrics.get('scenario')}: no vehicle telemetry was recorded, nothing "
            "to report (did the simulator start? see the logs)",
            "report: " + ", ".join(str(f) for f in files),
        ]
    lines = [
        f"scenario {metrics.get('scenario')}: {metrics.get('n_drones')} drones, "
        f"{_fmt(metrics.get('duration_s'), ' s', 1)} simulated in "
        f"{_fmt(metrics.get('wall_time_s'), ' s', 1)} "
        f"(real-time factor {_fmt(metrics.get('real_time_factor'), 'x', 1)})",
        f"after the first {_fmt(metrics.get('settle_s'), ' s', 0)}:",
        f"  centroid tracking, steady    {_rms_max(steady, 'centroid_m', ' m')}",
        f"  shape tracking, steady       {_rms_max(steady, 'shape_m2', ' m2')}",
        f"  centroid tracking, all       {_rms_max(tr, 'centroid_m', ' m')}",
        f"  shape tracking, all          {_rms_max(tr, 'shape_m2', ' m2')}",
        *(
            f"  {f'{name} tracking, {label}':<29}{_rms_max(block, name + '_deg', ' deg')}"
            for label, block in (("steady", steady), ("all", tr))
            for name in ("heading", "pitch", "roll")
        ),
        f"  consensus error, steady      {_rms_max(cons, 'centroid_m', ' m')}",
        f"  min separation airborne      {_fmt(sep.get('min_m'), ' m', 2)}"
        f" (drones {sep.get('pair')} at t = {_fmt(sep.get('t_s'), ' s', 1)})",
        f"  collisions                   {metrics.get('collisions', {}).get('count', 'n/a')}",
    ]
    if metrics.get("layout"):
        lines.insert(1, f"layout: {metrics['layout']}")
    takeoff = metrics.get("takeoff")
    if takeoff:
        late = takeoff.get("retimed_by_s") or 0.0
        lines.insert(
            1,
            f"take-off at t = {_fmt(takeoff.get('t_s'), ' s', 2)}, plan re-timed by "
            f"{_fmt(late, ' s', 2)}"
            + (" (the plan waited on the ground for the swarm)" if late > 0 else ""),
        )
    for lost in metrics.get("drones_lost", []):
        lines.append(
            f"  drone {lost['index']} (sysid {lost['sysid']}) lost at {_fmt(lost['t_s'], ' s', 1)}"
        )
    for rc in metrics.get("reconvergence", []):
        lines.append(
            f"  {rc.get('description')} at {_fmt(rc.get('t_s'), ' s', 1)}: "
            f"re-converged in {_fmt(rc.get('time_to_reconverge_s'), ' s', 1)}, "
            f"peak error {_fmt(rc.get('peak_centroid_error_m'), ' m', 2)} / "
            f"{_fmt(rc.get('peak_shape_error_m2'), ' m2', 2)}"
        )
    lines += timing_summary(metrics.get("agent_timing"))
    lines.append("('steady' leaves out the 10 s after each drone loss; 'all' keeps them)")
    lines.append("report: " + ", ".join(str(f) for f in files))
    return lines

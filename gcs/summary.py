"""The short summary table printed at the end of a run."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any


def _fmt(value: Any, unit: str = "", digits: int = 3) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, float):
        return f"{value:.{digits}f}{unit}"
    return f"{value}{unit}"


def summary_lines(metrics: dict[str, Any], files: Sequence[Path]) -> list[str]:
    """Human-readable lines: tracking, consensus, safety, faults, speed, and the files."""
    tr = metrics.get("tracking", {})
    cons = metrics.get("consensus", {})
    sep = metrics.get("separation") or {}
    lines = [
        f"scenario {metrics.get('scenario')} ({metrics.get('n_drones')} drones, "
        f"{_fmt(metrics.get('duration_s'), ' s', 1)} simulated, "
        f"real-time factor {_fmt(metrics.get('real_time_factor'), 'x', 1)})",
        f"  after {_fmt(metrics.get('settle_s'), ' s', 0)}:",
        f"  centroid tracking    RMS {_fmt(tr.get('centroid_m', {}).get('rms'), ' m', 4)}"
        f"   max {_fmt(tr.get('centroid_m', {}).get('max'), ' m', 3)}",
        f"  shape tracking       RMS {_fmt(tr.get('shape_m2', {}).get('rms'), ' m2', 4)}"
        f"  max {_fmt(tr.get('shape_m2', {}).get('max'), ' m2', 3)}",
        f"  consensus (centroid) RMS {_fmt(cons.get('centroid_m', {}).get('rms'), ' m', 4)}"
        f"   max {_fmt(cons.get('centroid_m', {}).get('max'), ' m', 3)}",
        f"  min separation       {_fmt(sep.get('min_m'), ' m', 2)}"
        f" (drones {sep.get('pair')}, t = {_fmt(sep.get('t_s'), ' s', 1)})",
        f"  collisions           {metrics.get('collisions', {}).get('count', 'n/a')}",
    ]
    for lost in metrics.get("drones_lost", []):
        lines.append(f"  drone {lost['index']} (sysid {lost['sysid']}) lost at "
                     f"{_fmt(lost['t_s'], ' s', 1)}")
    for rc in metrics.get("reconvergence", []):
        lines.append(f"  after {rc.get('description')} at {_fmt(rc.get('t_s'), ' s', 1)}: "
                     f"re-converged in {_fmt(rc.get('reconverge_s'), ' s', 1)}")
    lines.append("report: " + ", ".join(str(f) for f in files))
    return lines

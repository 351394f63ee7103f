"""The ground station's report: the :class:`~gcs.report.flight_record.FlightRecord` rebuilt from
its own logs (:func:`gcs.report.log_record.build_record`) and the final plan, then
``metrics.json``, ``trajectory.json``, the paper-style PNG plots and ``flight.rrd`` (with Rerun
installed), the same files as ``swarm simulate`` writes. The record's reading (sampling, controls,
link cuts, membership) is gcs/report/log_record.py.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from gcs.report.flight_record import FlightRecord
from gcs.report.metrics import compute_metrics
from gcs.report.plots import write_plots
from gcs.report.tlog import TlogTrack
from gcs.report.trajectory_file import write_trajectory
from gcs.view.recording import report_recording
from protocols.model.trajectory import DescriptorTrajectory


def record_metrics(
    record: FlightRecord | None,
    settle_s: float,
    extra: dict[str, Any],
    max_thrust_n: float | None = None,
) -> dict[str, Any]:
    """``metrics.json`` of a record rebuilt from the logs: :func:`compute_metrics` with the
    record's losses and returns as its faults (the ground station's report and
    :func:`gcs.api.load_report` alike)."""
    if record is None:
        return {"n_samples": 0, "note": "no telemetry received", **extra}
    faults = [(t, f"drone {i} lost") for i, t in sorted(record.lost_at_s.items())]
    for i, left_s, back_s in record.returns:
        faults += [(left_s, f"drone {i} left"), (back_s, f"drone {i} back")]
    return compute_metrics(
        record, settle_s=settle_s, faults=faults, max_thrust_n=max_thrust_n, extra=extra
    )


def write_report(
    report_dir: Path,
    record: FlightRecord | None,
    plan: DescriptorTrajectory,
    settle_s: float,
    extra: dict[str, Any],
    plots: bool = True,
    max_thrust_n: float | None = None,
    recording: bool = True,
    track: TlogTrack | None = None,
) -> list[Path]:
    """Write ``trajectory.json``, ``metrics.json`` (when there is a record), the plots and, where
    Rerun is installed and ``recording``, ``flight.rrd`` (from the report's files; without it,
    an earlier flight's is removed: swarm replay makes it when it opens the report);
    ``max_thrust_n`` (N) gives the metrics' max_thrust_ratio; ``track``: flight.tlog already
    read."""
    files = [write_trajectory(plan, report_dir / "trajectory.json")]
    metrics_path = report_dir / "metrics.json"
    metrics = record_metrics(record, settle_s, extra, max_thrust_n)
    metrics_path.write_text(json.dumps(metrics, indent=2) + "\n")
    files.append(metrics_path)
    if plots and record is not None:
        files += write_plots(record, report_dir)
    if record is not None or not recording:  # no flight: nothing to record
        n = None if record is None else record.n_drones
        rrd = report_recording(report_dir, n, recording, track)
        files += [] if rrd is None else [rrd]
    return files

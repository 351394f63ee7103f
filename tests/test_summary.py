"""The printed summary of a report (gcs/report/summary.py)."""

from __future__ import annotations

from pathlib import Path

from gcs.report.summary import summary_lines


def test_a_report_with_no_vehicle_says_so_instead_of_a_table_of_n_a() -> None:
    # what the ground station writes when the simulator never started (its ports in use)
    lines = summary_lines({"scenario": "grid", "n_drones": None}, [Path("r/flight.tlog")])
    assert lines[0].startswith("scenario grid: no vehicle telemetry was recorded"), lines
    assert "None drones" not in "\n".join(lines) and "n/a" not in "\n".join(lines)
    assert lines[-1] == "report: r/flight.tlog"


def test_a_flown_report_has_its_tracking_table() -> None:
    metrics = {"scenario": "grid", "n_drones": 4, "duration_s": 10.0, "settle_s": 5.0}
    lines = summary_lines(metrics, [])
    assert lines[0].startswith("scenario grid: 4 drones, 10.0 s simulated")
    assert any(line.strip().startswith("centroid tracking, steady") for line in lines)

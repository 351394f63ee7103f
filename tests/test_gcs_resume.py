"""A restarted ground station (``swarm drill gcs-restart``) reports the whole run: its wall time
counts from the run's start, which the first station wrote into events.jsonl."""

from __future__ import annotations

from pathlib import Path

from gcs.report.events import EventLog
from gcs.station.ground_station import _run_started


def test_the_run_start_wall_clock_is_read_back(tmp_path: Path) -> None:
    path = tmp_path / "events.jsonl"
    assert _run_started(path) is None  # no log yet
    log = EventLog(path)
    log.open()
    log.record(0.0, "run_start", scenario="s", end_s=10.0, wall_clock_s=1_700_000_000.5)
    log.record(4.0, "gcs_stopped", reason="restart", plan_seq=0)
    log.record(4.0, "gcs_restarted", scenario="s", end_s=10.0, wall_clock_s=1_700_000_009.0)
    log.close()
    assert _run_started(path) == 1_700_000_000.5
    path.write_text('{"t_s": 0.0, "kind": "run_start"}\n')  # a log from before the field
    assert _run_started(path) is None

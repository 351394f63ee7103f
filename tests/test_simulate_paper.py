"""``swarm simulate scenarios/paper.toml`` end to end, judged from the run's own flight.tlog.

The full 200 s paper flight runs once (about a minute) for the session. The run is seeded, so
its figures do not vary from run to run; the bars sit at 2-3x the figures docs/measured.md quotes
(measured, in brackets), never looser than the flight-core issue's (centroid RMS < 0.05 m,
shape-variance RMS < 0.1 m^2 after 20 s, 1.0 m separation, re-converged within 10 s):

- steady flight (after 20 s, leaving out the 10 s after the crash): centroid RMS < 0.1 mm
  (0.03 mm), shape RMS < 0.008 m^2 (0.0028 m^2); with the crash: < 0.05 m / 0.1 m^2 (0.048 m /
  0.095 m^2, the crash transient itself);
- no two airborne drones closer than 1.9 m (2.02 m);
- drone 1 crashes at 30 s: peak error 0.4-0.6 m / 0.8-1.2 m^2 (0.50 m / 0.98 m^2), survivors back
  within 5 cm / 0.1 m^2 in under 6 s (5.2 s) and within 1.5 mm / 0.01 m^2 from 40 s (0.5 mm /
  0.0033 m^2); agents' centroid consensus error in steady flight < 1.5 mm RMS (0.57 mm).
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from paper_flight import ENV, min_airborne_separation, paper_flight

from gcs.report.events import read_events
from gcs.report.metrics import descriptors_of, tracking_from_positions


@pytest.fixture(scope="module")
def report(simulated_paper_report: Path) -> Path:
    return simulated_paper_report


@pytest.fixture(scope="module")
def flight(report: Path) -> dict[str, np.ndarray]:
    return paper_flight(report)


@pytest.mark.slow
def test_tracking_from_the_tlog(flight: dict[str, np.ndarray]) -> None:
    steady = tracking_from_positions(
        flight["t"],
        flight["positions"],
        flight["member"],
        flight["desired"],
        20.0,
        exclude=[(30.0, 40.0)],
    )
    assert steady["centroid_m"]["rms"] < 1e-4, steady["centroid_m"]  # docs/measured.md: 0.03 mm
    assert steady["shape_m2"]["rms"] < 0.008, steady["shape_m2"]  # docs/measured.md: 0.003 m^2
    everything = tracking_from_positions(
        flight["t"], flight["positions"], flight["member"], flight["desired"], 20.0
    )
    # the drop-out transient included, the flight-core bars still hold (0.048 m / 0.095 m^2:
    # the in-process run is seeded, so this does not vary from run to run)
    assert everything["centroid_m"]["rms"] < 0.05, everything["centroid_m"]
    assert everything["shape_m2"]["rms"] < 0.1, everything["shape_m2"]


@pytest.mark.slow
def test_no_two_airborne_drones_closer_than_1_9_metres(flight: dict[str, np.ndarray]) -> None:
    separation = min_airborne_separation(flight["positions"])
    assert separation > 1.9, separation  # docs/measured.md: 2.0 m


@pytest.mark.slow
def test_drop_out_survived_and_reconverged_within_6_s(flight: dict[str, np.ndarray]) -> None:
    t, pos, member, desired = flight["t"], flight["positions"], flight["member"], flight["desired"]
    a = descriptors_of(pos, member, desired)
    centroid = np.linalg.norm(a[:, :3] - desired[:, :3], axis=1)
    shape = np.abs(a[:, 6:9] - desired[:, 6:9]).max(axis=1)
    # the loss is felt (docs/measured.md: peak 0.50 m) ...
    just_after = (t >= 30.0) & (t < 31.0)
    assert 0.4 < centroid[just_after].max() < 0.6, centroid[just_after].max()
    # ... the survivors are back within 5 cm / 0.1 m^2 within 6 s (docs/measured.md: 5.2 s) and stay
    # there until the next fault (67 s) ...
    recovered = (t >= 36.0) & (t < 67.0)
    assert centroid[recovered].max() < 0.05 and shape[recovered].max() < 0.1
    # ... and from 40 s on they are back to steady flight (0.5 mm / 0.0033 m^2)
    back = (t >= 40.0) & (t < 67.0)
    assert centroid[back].max() < 0.0015, centroid[back].max()
    assert shape[back].max() < 0.01, shape[back].max()
    # every survivor flies to the end; the crashed drone went silent after it hit the ground
    end = pos[-1]
    survivors = [i for i in range(pos.shape[1]) if i != 1]
    assert np.all(-end[survivors, 2] > 4.5)
    assert np.all(np.isnan(end[1]))


@pytest.mark.slow
def test_report_contents(report: Path) -> None:
    metrics = json.loads((report / "metrics.json").read_text())
    for key in (
        "tracking",
        "tracking_steady",
        "consensus",
        "consensus_steady",
        "reconvergence",
        "separation",
        "collisions",
        "drones_lost",
        "real_time_factor",
    ):
        assert key in metrics
    assert metrics["collisions"]["count"] == 0
    assert [d["sysid"] for d in metrics["drones_lost"]] == [2]
    crash = next(r for r in metrics["reconvergence"] if "crash" in r["description"])
    # docs/measured.md: re-converged in 5.2 s, peak error 0.50 m / 0.98 m^2
    assert crash["time_to_reconverge_s"] is not None and crash["time_to_reconverge_s"] < 6.0
    assert 0.4 < crash["peak_centroid_error_m"] < 0.6, crash
    assert 0.8 < crash["peak_shape_error_m2"] < 1.2, crash
    # docs/measured.md: consensus error 0.6 mm
    assert metrics["consensus_steady"]["centroid_m"]["rms"] < 0.0015, metrics["consensus_steady"]
    assert metrics["separation"]["min_m"] > 1.9, metrics["separation"]
    kinds = [e["kind"] for e in read_events(report / "events.jsonl")]
    assert kinds[0] == "run_start" and kinds[-1] == "run_end"
    assert "agent_left" in kinds and kinds.count("armed") == 9
    # the separation layer never had to act: the formation keeps the drones 2 m apart
    assert "separation" not in kinds
    for png in ("paths.png", "descriptors.png", "controls.png"):
        data = (report / png).read_bytes()
        assert data.startswith(b"\x89PNG") and len(data) > 20_000
    # with its defaults it also writes the Rerun recording (tests/test_view.py reads one back)
    assert (report / "flight.rrd").read_bytes()[:4] == b"RRF2"


@pytest.mark.slow
def test_tlog_reads_back_with_mavlogdump(report: Path) -> None:
    mavlogdump = Path(sys.executable).parent / "mavlogdump.py"
    proc = subprocess.run(
        [
            sys.executable,
            str(mavlogdump),
            "--types",
            "LOCAL_POSITION_NED",
            "--show-source",
            str(report / "flight.tlog"),
        ],
        capture_output=True,
        text=True,
        env=ENV,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    rows = re.findall(r"time_boot_ms : (\d+),.* srcSystem=(\d+) ", proc.stdout)
    assert {int(sysid) for _, sysid in rows} == set(range(1, 10))
    times = sorted(int(ms) for ms, sysid in rows if sysid == "5")
    assert times[-1] == 200_000
    assert np.median(np.diff(times)) <= 100  # at least 10 Hz
    as_json = subprocess.run(
        [
            sys.executable,
            str(mavlogdump),
            "--types",
            "ATTITUDE",
            "--format",
            "json",
            str(report / "flight.tlog"),
        ],
        capture_output=True,
        text=True,
        env=ENV,
        timeout=300,
    )
    assert as_json.returncode == 0, as_json.stderr
    first = json.loads(as_json.stdout.splitlines()[0])
    assert first["meta"]["type"] == "ATTITUDE"

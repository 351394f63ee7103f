"""``swarm demo`` (what ``make demo`` runs) end to end: the paper's 200 s flight with the real
simulator, the 9 agents (hosted in one process, the default) over Zenoh and the ground station,
judged from the ground station's own ``report/flight.tlog`` (recomputed here, not read from
metrics.json), and compared with the in-process reference ``swarm simulate`` on the same
scenario.

The bars sit at 2-3x the figures docs/measured.md quotes (measured on two runs, in brackets), never
looser than the ground-station issue's (centroid RMS < 0.10 m, shape < 0.2 m^2 after 20 s, 1.0 m
separation, estimates back within the agent issue's bound within 10 s, within 0.05 m / 0.1 m^2
RMS of ``swarm simulate``); where the figure is a crash transient the flight repeats exactly, the
bar is closer:

- after 20 s: centroid RMS < 0.06 m, shape < 0.12 m^2 with the crash (0.048 m / 0.095 m^2);
  < 2 mm / 0.008 m^2 in steady flight (0.6 mm / 0.0032-0.0034 m^2);
- no two airborne drones closer than 1.9 m (2.02 m);
- drone 1 (system id 2) crashes at 30 s: the survivors' formation is back within 5 cm / 0.1 m^2
  within 7 s (5.2 s), every surviving agent's estimate within the agent issue's bound 0.4 s after
  the crash (0.12-0.16 s; docs/measured.md: within 0.2 s); agents' centroid estimate error in
  steady flight < 2.5 mm RMS (0.8-0.9 mm);
- against ``swarm simulate``: tracking RMS within 1 mm / 0.003 m^2 of each other (0.1-0.2 mm /
  0.0006-0.0009 m^2), flights < 2 mm / 0.008 m^2 RMS apart in steady flight (0.6 mm /
  0.0017-0.0033 m^2) and < 2 mm / 0.01 m^2 with the crash (0.6 mm / 0.002-0.004 m^2).

Lockstep: the simulated flight does not depend on the machine's load (a consensus message that
misses its tick on a loaded machine shifts the distributed transient a little). It takes about 3
minutes.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from paper_flight import ENV, ROOT, flight_of, min_airborne_separation, paper_flight

from gcs.report.events import read_events
from gcs.report.metrics import descriptors_of, tracking_from_positions
from gcs.report.tlog import TlogTrack, read_tlog

pytestmark = pytest.mark.slow
CRASHED, CRASH_T_S = 1, 30.0
SURVIVORS = [i for i in range(9) if i != CRASHED]
SETTLE_S = 20.0
HEADING = 3  # index of yaw in the checked rows below
#: Simulated time after the crash by which every surviving agent's estimate is within the bound.
ESTIMATES_BACK_S = 0.4


@pytest.fixture(scope="module")
def demo(demo_run: tuple[Path, str]) -> tuple[Path, str]:
    """``swarm demo``, run once for the session (tests/conftest.py)."""
    return demo_run


@pytest.fixture(scope="module")
def track(demo: tuple[Path, str]) -> TlogTrack:
    return read_tlog(demo[0] / "flight.tlog")


@pytest.fixture(scope="module")
def flight(demo: tuple[Path, str], track: TlogTrack) -> dict[str, np.ndarray]:
    return flight_of(track, demo[0])


def test_tracking_from_the_ground_stations_tlog(flight: dict[str, np.ndarray]) -> None:
    t, pos, member, desired = flight["t"], flight["positions"], flight["member"], flight["desired"]
    errors = tracking_from_positions(t, pos, member, desired, SETTLE_S)
    assert errors["centroid_m"]["rms"] < 0.06, errors["centroid_m"]  # docs/measured.md: 0.048 m
    assert errors["shape_m2"]["rms"] < 0.12, errors["shape_m2"]  # docs/measured.md: 0.095 m^2
    window = [(CRASH_T_S, CRASH_T_S + 10.0)]
    steady = tracking_from_positions(t, pos, member, desired, SETTLE_S, exclude=window)
    assert steady["centroid_m"]["rms"] < 0.002, steady["centroid_m"]  # docs/measured.md: 0.6 mm
    assert steady["shape_m2"]["rms"] < 0.008, steady["shape_m2"]  # docs/measured.md: 0.003 m^2


def test_no_two_airborne_drones_closer_than_1_9_metres(flight: dict[str, np.ndarray]) -> None:
    separation = min_airborne_separation(flight["positions"])
    assert separation > 1.9, separation  # docs/measured.md: 2.0 m


def test_drop_out_survived_and_every_estimate_back_within_0_4_s(
    flight: dict[str, np.ndarray], track: TlogTrack
) -> None:
    t, pos, member, desired = flight["t"], flight["positions"], flight["member"], flight["desired"]
    truth = descriptors_of(pos, member, desired)
    # the survivors fly to the end; the crashed vehicle went silent after it hit the ground
    assert np.all(-pos[-1, SURVIVORS, 2] > 4.5)
    assert np.all(np.isnan(pos[-1, CRASHED]))
    # their formation is back within 5 cm / 0.1 m^2 of the plan within 7 s (docs/measured.md:
    # 5.2 s) and stays there until the next fault (67 s)
    centroid = np.linalg.norm(truth[:, :3] - desired[:, :3], axis=1)
    shape = np.abs(truth[:, 6:9] - desired[:, 6:9]).max(axis=1)
    recovered = (t >= CRASH_T_S + 7.0) & (t < 67.0)
    assert centroid[recovered].max() < 0.05 and shape[recovered].max() < 0.1
    # each survivor's own estimate (its AGENT records in the tlog) against the survivors' truth
    rows = [0, 1, 2, 5, 6, 7, 8]  # centre, heading, variances (roll/pitch of a flat swarm ~0)
    bound = np.maximum(0.02 * np.abs(truth[:, rows]), 0.05)
    back = (t >= CRASH_T_S + ESTIMATES_BACK_S) & (t <= t[-1] - 1.0)
    # heading is undefined where length and width variances tie (ALGORITHM.md §1: masked)
    tie = np.abs(truth[:, 6] - truth[:, 7]) / (truth[:, 6] + truth[:, 7]) < 0.05
    assert tie[back].any() and not tie[back].all()  # the width crosses the length once
    for i in SURVIVORS:
        v = track.vehicles[i + 1]
        assert v.status_t_s.size > 1000, i  # statuses were logged all flight
        k = np.clip(np.searchsorted(v.status_t_s, t + 5e-4, side="right") - 1, 0, None)
        estimate = v.status[k, :9]
        fresh = t - v.status_t_s[k] < 0.5
        assert fresh[back].all(), i
        err = np.abs(estimate[:, rows] - truth[:, rows])
        err[tie, HEADING] = 0.0
        assert (err[back] <= bound[back]).all(), (i, err[back].max(axis=0))
    # the crash is felt (docs/measured.md: peak error 0.50 m), so the bound above is not vacuous
    during = (t >= CRASH_T_S) & (t < CRASH_T_S + 1.0)
    assert np.nanmax(np.abs(truth[during, 0] - desired[during, 0])) > 0.4


def test_distributed_flight_matches_swarm_simulate(
    flight: dict[str, np.ndarray], simulated_paper_report: Path
) -> None:
    """Tracking RMS of the two runs within 1 mm / 0.003 m^2 of each other (the issue's bar: 0.05 m
    / 0.1 m^2), and the flights themselves close: measured 0.6 mm / 0.002-0.004 m^2 RMS apart
    after 20 s, crash included (bars 2 mm / 0.008 m^2 away from it, 2 mm / 0.01 m^2 with it: a
    consensus message that misses its tick on a loaded machine shifts the distributed transient
    a little)."""
    reference = paper_flight(simulated_paper_report)
    t = flight["t"]
    ours = descriptors_of(flight["positions"], flight["member"], flight["desired"])
    theirs = descriptors_of(reference["positions"], reference["member"], reference["desired"])
    for a_true in (ours, theirs):
        assert np.isfinite(a_true[t >= SETTLE_S]).all()

    def rms(x: np.ndarray, mask: np.ndarray) -> float:
        return float(np.sqrt(np.mean(x[mask] ** 2)))

    after = t >= SETTLE_S
    steady = after & ~((t >= CRASH_T_S) & (t < CRASH_T_S + 10.0))
    desired = flight["desired"]
    for part, bar in ((slice(0, 3), 0.001), (slice(6, 9), 0.003)):
        tracking = [np.linalg.norm(a[:, part] - desired[:, part], axis=1) for a in (ours, theirs)]
        gap = abs(rms(tracking[0], after) - rms(tracking[1], after))
        assert gap < bar, (part, gap)
    centre_diff = np.linalg.norm(ours[:, :3] - theirs[:, :3], axis=1)
    shape_diff = np.linalg.norm(ours[:, 6:9] - theirs[:, 6:9], axis=1)
    apart = {
        "steady": (rms(centre_diff, steady), rms(shape_diff, steady)),
        "after": (rms(centre_diff, after), rms(shape_diff, after)),
    }
    assert apart["steady"][0] < 0.002 and apart["steady"][1] < 0.008, apart
    assert apart["after"][0] < 0.002 and apart["after"][1] < 0.01, apart


def test_report_and_summary(demo: tuple[Path, str]) -> None:
    report, stdout = demo
    assert "centroid tracking" in stdout and "re-converged" in stdout
    metrics = json.loads((report / "metrics.json").read_text())
    assert metrics["mode"] == "distributed (swarm gcs)"
    assert [d["sysid"] for d in metrics["drones_lost"]] == [CRASHED + 1]
    crash = next(r for r in metrics["reconvergence"] if "lost" in r["description"])
    # the ground station's measure also waits for every agent's estimate: 5.2 s and 8.5 s measured
    assert crash["time_to_reconverge_s"] is not None and crash["time_to_reconverge_s"] < 10.0
    # docs/measured.md: agents' centroid estimate error 0.8-0.9 mm RMS in steady flight
    assert metrics["consensus_steady"]["centroid_m"]["rms"] < 0.0025, metrics["consensus_steady"]
    events = read_events(report / "events.jsonl")
    assert {e["drone"] for e in events if e["kind"] == "agent_joined"} == set(range(9))
    assert any(e["kind"] == "crash" and e["drone"] == CRASHED for e in events)
    for png in ("paths.png", "descriptors.png", "controls.png"):
        data = (report / png).read_bytes()
        assert data.startswith(b"\x89PNG") and len(data) > 20_000


def test_ground_station_tlog_reads_back_with_mavlogdump(demo: tuple[Path, str]) -> None:
    mavlogdump = Path(sys.executable).parent / "mavlogdump.py"
    proc = subprocess.run(
        [
            sys.executable,
            str(mavlogdump),
            "--types",
            "LOCAL_POSITION_NED,ACTUATOR_OUTPUT_STATUS,DEBUG_FLOAT_ARRAY",
            "--format",
            "json",
            str(demo[0] / "flight.tlog"),
        ],
        capture_output=True,
        text=True,
        env=ENV,
        cwd=ROOT,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    kinds = {json.loads(line)["meta"]["type"] for line in proc.stdout.splitlines()}
    assert kinds == {"LOCAL_POSITION_NED", "ACTUATOR_OUTPUT_STATUS", "DEBUG_FLOAT_ARRAY"}

"""Every scenario fault happens in every runner (issue 14 item 5).

One 6-drone scenario with every fault kind (loss, delay, a link cut, a partition, an agent
drop-out, a vehicle crash) flown as a newcomer types it, ``swarm up FILE`` with its defaults
(lockstep, default ports) and three agents hosted per process, and with ``swarm simulate FILE``.
Found in both reports: each fault's event at its time; its effect in flight.tlog (the drop-out's
vehicle fails safe and lands, the crashed one falls, everyone else flies on); and the survivors
of the two runners within 5 cm of each other.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest
from sitl_client import ENV, ROOT, swarm_command
from test_drill_flight import _default_ports_lock

from gcs.report.events import read_events
from gcs.report.tlog import read_tlog

pytestmark = pytest.mark.slow

DURATION_S = 30.0
DROPOUT, CRASH = 4, 5
SURVIVORS = [0, 1, 2, 3]
SCENARIO = f"""version = 1
name = "every-fault"
duration_s = {DURATION_S}
settle_s = 8.0

[comms]
range_m = 10.0

{
    "".join(
        f"[[drones]]{chr(10)}position_ned_m = [{x}, {y}, 0.0]{chr(10)}{chr(10)}"
        for x in (0.0, 3.0)
        for y in (0.0, 2.5, 5.0)
    )
}
[[trajectory.waypoints]]
t_s = 0.0
centre_ned_m = [1.5, 2.5, -0.1]
spread_m = [1.5, 2.04, 0.0]

[[trajectory.waypoints]]
t_s = 8.0
centre_ned_m = [1.5, 2.5, -3.0]
spread_m = [1.5, 2.04, 0.0]

[[faults]]
t_s = 10.0
kind = "loss"
probability = 0.2
duration_s = 3.0

[[faults]]
t_s = 12.0
kind = "delay"
delay_ms = 40.0
duration_s = 2.0

[[faults]]
t_s = 14.0
kind = "link_cut"
drones = [0, 1]
duration_s = 2.0

[[faults]]
t_s = 16.0
kind = "partition"
groups = [[0, 1, 2], [3, 4, 5]]
duration_s = 2.0

[[faults]]
t_s = 20.0
kind = "dropout"
drone = {DROPOUT}

[[faults]]
t_s = 23.0
kind = "crash"
drone = {CRASH}
"""
KINDS = {
    "loss": 10.0,
    "delay": 12.0,
    "link_cut": 14.0,
    "partition": 16.0,
    "dropout": 20.0,
    "crash": 23.0,
}


def _faults(report: Path) -> dict[str, float]:
    """Fault kind -> time (s) of its "fault" event in the report."""
    return {
        str(e["fault"]): float(e["t_s"])
        for e in read_events(report / "events.jsonl")
        if e["kind"] == "fault"
    }


def _between(samples: np.ndarray, t0: float, t1: float) -> np.ndarray:
    """The altitudes of ``samples`` (t, altitude, ...) with t0 <= t <= t1."""
    t = samples[:, 0]
    return samples[(t >= t0) & (t <= t1), 1]


def _effects(report: Path) -> dict[int, np.ndarray]:
    """Each vehicle's (t, altitude) samples from flight.tlog, checked for the faults' effects."""
    track = read_tlog(report / "flight.tlog")
    assert sorted(track.vehicles) == [1, 2, 3, 4, 5, 6]
    out = {}
    for sysid, v in track.vehicles.items():
        out[sysid - 1] = np.column_stack([v.t_s, -v.position_ned_m[:, 2], v.position_ned_m])
    # everyone flew; the survivors fly at the end
    for i, samples in out.items():
        assert samples[:, 1].max() > 2.5, i
    end = {i: s[-1] for i, s in out.items()}
    for i in SURVIVORS:
        assert end[i][1] > 2.5, (i, end[i])
    # the crashed vehicle flew until its crash, then fell (its last report near the ground,
    # within a few seconds: a destroyed vehicle stops reporting)
    crash = out[CRASH]
    assert _between(crash, KINDS["crash"] - 5.0, KINDS["crash"] - 0.5).min() > 2.5
    assert crash[-1, 1] < 0.5 and crash[-1, 0] < KINDS["crash"] + 5.0, crash[-1]
    drop = out[DROPOUT]
    assert _between(drop, KINDS["dropout"] - 5.0, KINDS["dropout"] - 0.5).min() > 2.5
    assert drop[-1, 1] < 2.0  # descending (failsafe: level, sink, disarm) since its agent died
    return out


def test_every_scenario_fault_happens_in_both_runners(tmp_path: Path) -> None:
    (tmp_path / "every-fault.toml").write_text(SCENARIO)
    sim = subprocess.run(
        swarm_command("simulate", "every-fault.toml", "--report", "simulated"),
        capture_output=True,
        text=True,
        env=ENV,
        cwd=tmp_path,
        timeout=300,
    )
    assert sim.returncode == 0, sim.stdout + sim.stderr
    with _default_ports_lock():
        up = subprocess.run(
            [*swarm_command("up", "every-fault.toml"), "--agents-per-process", "3"],
            capture_output=True,
            text=True,
            env={**ENV, "PYTHONPATH": str(ROOT)},
            cwd=tmp_path,
            timeout=600,
        )
    assert up.returncode == 0, up.stdout[-3000:] + up.stderr[-3000:]
    reports = {"simulate": tmp_path / "simulated", "up": tmp_path / "report"}
    flights = {}
    for runner, report in reports.items():
        faults = _faults(report)
        for kind, t in KINDS.items():
            assert kind in faults, (runner, kind, faults)
            assert abs(faults[kind] - t) < 0.1, (runner, kind, faults[kind])
        flights[runner] = _effects(report)
    # the distributed agents carried out the drop-out: its agent left, the others did not
    events = read_events(reports["up"] / "events.jsonl")
    gone = {int(e["drone"]) for e in events if e["kind"] == "dropout_detected"}
    assert DROPOUT in gone and not gone & set(SURVIVORS), gone
    left = [e for e in events if e["kind"] == "dropout_detected" and e["drone"] == DROPOUT]
    assert abs(float(left[0]["t_s"]) - KINDS["dropout"]) < 1.0, left
    # its process let go of its vehicle link: the lockstep barrier stopped waiting for it at
    # once (the port closed), not after the 2 s silence timeout
    texts = [m.text for m in read_tlog(reports["up"] / "flight.tlog").statustexts
             if m.sysid == DROPOUT + 1 and "barrier" in m.text]  # fmt: skip
    assert texts and texts[0] == "Lockstep: agent gone, left the barrier", texts
    # the two runners fly the same flight: survivors within 5 cm at common times
    for i in SURVIVORS:
        a, b = flights["simulate"][i], flights["up"][i]
        t = np.arange(9.0, DURATION_S - 0.5, 0.5)
        for k in (2, 3, 4):
            gap = np.abs(np.interp(t, a[:, 0], a[:, k]) - np.interp(t, b[:, 0], b[:, k])).max()
            assert gap < 0.05, (i, k, gap)

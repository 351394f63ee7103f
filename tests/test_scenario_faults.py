"""Every scenario fault happens in every runner, and each link fault acts on the agents.

One 6-drone scenario with every fault kind flown as a newcomer types it, ``swarm up FILE`` with
its defaults (lockstep, default ports) and three agents hosted per process, and with ``swarm
simulate FILE``. The link faults (loss, delay, a link cut, a one-way cut, a partition) each fall
on a formation change (a move, a turn, a move back, a turn back, a stretch), where estimates need
the messages; then an agent drop-out and a vehicle crash. Found in both reports: each fault's
event at its time; from the agents' statuses in flight.tlog, that each link fault acted
(tests/link_fault_judge.py: loss near its rate, the wait for late rounds as long as the delay, the
cut pairs absent from each other's neighbours, no neighbour across the partition and its halves'
estimates parting); the drop-out's vehicle fails safe and lands, the crashed one falls, everyone
else flies on; the two runners' figures and survivors' paths agree. The same scenario flown
without its link faults (the agents' view if they ignored them) fails every one of those judges.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest
from link_fault_judge import (
    Statuses,
    judge_cut,
    judge_delay,
    judge_loss,
    judge_partition,
)
from sitl_client import ENV, ROOT, swarm_command
from test_drill_flight import _default_ports_lock

from gcs.report.events import read_events
from gcs.report.tlog import TlogTrack, read_tlog

pytestmark = pytest.mark.slow

DURATION_S = 34.0
DROPOUT, CRASH = 4, 5
SURVIVORS = [0, 1, 2, 3]
DRONES = list(range(6))
#: (t_s, centre_ned_m, yaw_deg, spread_m): take off, then a formation change under each link fault
WAYPOINTS = [
    (0.0, (1.5, 2.5, -0.1), 0.0, (1.5, 2.04, 0.0)),
    (8.0, (1.5, 2.5, -3.0), 0.0, (1.5, 2.04, 0.0)),
    (10.0, (1.5, 2.5, -3.0), 0.0, (1.5, 2.04, 0.0)),
    (13.0, (3.5, 2.5, -3.0), 0.0, (1.5, 2.04, 0.0)),  # a move under loss
    (14.0, (3.5, 2.5, -3.0), 0.0, (1.5, 2.04, 0.0)),
    (17.0, (3.5, 2.5, -3.0), 30.0, (1.5, 2.04, 0.0)),  # a turn under delay
    (18.0, (3.5, 2.5, -3.0), 30.0, (1.5, 2.04, 0.0)),
    (20.5, (1.5, 2.5, -3.0), 30.0, (1.5, 2.04, 0.0)),  # back under a link cut
    (21.0, (1.5, 2.5, -3.0), 30.0, (1.5, 2.04, 0.0)),
    (23.5, (1.5, 2.5, -3.0), 0.0, (1.5, 2.04, 0.0)),  # turn back under a one-way cut
    (24.0, (1.5, 2.5, -3.0), 0.0, (1.5, 2.04, 0.0)),
    (27.0, (1.5, 2.5, -3.0), 0.0, (2.0, 2.04, 0.0)),  # stretched along north, partitioned
]
LOSS = (10.0, 3.0, 0.3)  # t_s, duration_s, probability
DELAY = (14.0, 3.0, 0.2)  # t_s, duration_s, delay_s
CUT = (18.0, 2.5, (0, 4))
ONE_WAY = (21.0, 2.5, (2, 3))  # 2 -> 3 only
PARTITION = (24.0, 3.0, ([0, 1, 2], [3, 4, 5]))
LINK_FAULTS = f"""
[[faults]]
t_s = {LOSS[0]}
kind = "loss"
probability = {LOSS[2]}
duration_s = {LOSS[1]}

[[faults]]
t_s = {DELAY[0]}
kind = "delay"
delay_ms = {DELAY[2] * 1e3}
duration_s = {DELAY[1]}

[[faults]]
t_s = {CUT[0]}
kind = "link_cut"
drones = {list(CUT[2])}
duration_s = {CUT[1]}

[[faults]]
t_s = {ONE_WAY[0]}
kind = "link_cut"
drones = {list(ONE_WAY[2])}
one_way = true
duration_s = {ONE_WAY[1]}

[[faults]]
t_s = {PARTITION[0]}
kind = "partition"
groups = {[list(g) for g in PARTITION[2]]}
duration_s = {PARTITION[1]}
"""
VEHICLE_FAULTS = f"""
[[faults]]
t_s = 29.0
kind = "dropout"
drone = {DROPOUT}

[[faults]]
t_s = 31.0
kind = "crash"
drone = {CRASH}
"""


def scenario(link_faults: bool = True) -> str:
    """The scenario; without ``link_faults``: the same flight on a perfect radio."""
    drones = "".join(
        f"[[drones]]\nposition_ned_m = [{x}, {y}, 0.0]\n\n"
        for x in (0.0, 3.0)
        for y in (0.0, 2.5, 5.0)
    )
    waypoints = "".join(
        f"[[trajectory.waypoints]]\nt_s = {t}\ncentre_ned_m = {list(c)}\nyaw_deg = {yaw}\n"
        f"spread_m = {list(sp)}\n\n"
        for t, c, yaw, sp in WAYPOINTS
    )
    head = (
        f'version = 1\nname = "every-fault"\nduration_s = {DURATION_S}\nsettle_s = 8.0\n\n'
        "[comms]\nrange_m = 10.0\n\n"
    )
    return head + drones + waypoints + (LINK_FAULTS if link_faults else "") + VEHICLE_FAULTS


#: each fault kind's times in the scenario
KINDS = {
    "loss": [LOSS[0]],
    "delay": [DELAY[0]],
    "link_cut": [CUT[0], ONE_WAY[0]],
    "partition": [PARTITION[0]],
    "dropout": [29.0],
    "crash": [31.0],
}


def judge_link_faults(track: TlogTrack) -> dict[str, float]:
    """Each link fault's figure (tests/link_fault_judge.py); AssertionError if one did not act."""
    s = Statuses.of(track, DRONES)
    gap, inside = judge_partition(s, PARTITION[0], PARTITION[0] + PARTITION[1], PARTITION[2])
    return {
        "loss": judge_loss(s, LOSS[0], LOSS[0] + LOSS[1], LOSS[2]),
        "delay_s": judge_delay(s, DELAY[0], DELAY[0] + DELAY[1], DELAY[2]),
        "cut": judge_cut(s, CUT[0], CUT[0] + CUT[1], *CUT[2]),
        "one_way": judge_cut(s, ONE_WAY[0], ONE_WAY[0] + ONE_WAY[1], *ONE_WAY[2]),
        "partition_gap": gap,
        "partition_inside": inside,
    }


def _faults(report: Path) -> dict[str, list[float]]:
    """Fault kind -> times (s) of its "fault" events in the report."""
    out: dict[str, list[float]] = {}
    for e in read_events(report / "events.jsonl"):
        if e["kind"] == "fault":
            out.setdefault(str(e["fault"]), []).append(float(e["t_s"]))
    return out


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
    assert _between(crash, KINDS["crash"][0] - 5.0, KINDS["crash"][0] - 0.5).min() > 2.5
    assert crash[-1, 1] < 0.5 and crash[-1, 0] < KINDS["crash"][0] + 5.0, crash[-1]
    drop = out[DROPOUT]
    assert _between(drop, KINDS["dropout"][0] - 5.0, KINDS["dropout"][0] - 0.5).min() > 2.5
    assert drop[-1, 1] < 2.0  # descending (failsafe: level, sink, disarm) since its agent died
    return out


def test_every_scenario_fault_happens_in_both_runners(tmp_path: Path) -> None:
    (tmp_path / "every-fault.toml").write_text(scenario())
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
        for kind, times in KINDS.items():
            assert kind in faults, (runner, kind, faults)
            assert np.allclose(sorted(faults[kind]), times, atol=0.1), (runner, kind, faults[kind])
        flights[runner] = _effects(report)
    # the distributed agents carried out the drop-out: its agent left, the others did not
    events = read_events(reports["up"] / "events.jsonl")
    gone = {int(e["drone"]) for e in events if e["kind"] == "dropout_detected"}
    assert DROPOUT in gone and not gone & set(SURVIVORS), gone
    left = [e for e in events if e["kind"] == "dropout_detected" and e["drone"] == DROPOUT]
    assert abs(float(left[0]["t_s"]) - KINDS["dropout"][0]) < 1.0, left
    # its process let go of its vehicle link: the lockstep barrier stopped waiting for it at
    # once (the port closed), not after the 2 s silence timeout
    texts = [m.text for m in read_tlog(reports["up"] / "flight.tlog").statustexts
             if m.sysid == DROPOUT + 1 and "barrier" in m.text]  # fmt: skip
    assert texts and texts[0] == "Lockstep: agent gone, left the barrier", texts
    # each link fault acted on the agents, alike in both runners
    acted = {
        runner: judge_link_faults(read_tlog(r / "flight.tlog")) for runner, r in reports.items()
    }
    sim_seen, up_seen = acted["simulate"], acted["up"]
    assert abs(sim_seen["loss"] - up_seen["loss"]) < 0.05, acted
    assert abs(sim_seen["partition_gap"] - up_seen["partition_gap"]) < 0.05, acted
    # the two runners fly the same flight: survivors within 5 cm at common times
    for i in SURVIVORS:
        a, b = flights["simulate"][i], flights["up"][i]
        t = np.arange(9.0, DURATION_S - 0.5, 0.5)
        for k in (2, 3, 4):
            gap = np.abs(np.interp(t, a[:, 0], a[:, k]) - np.interp(t, b[:, 0], b[:, k])).max()
            assert gap < 0.05, (i, k, gap)


def test_agents_that_ignored_the_link_faults_would_fail_every_judge(tmp_path: Path) -> None:
    """The judges can fail: the same flight on a perfect radio (what the agents would see if
    they ignored the faults) fails each of them, the way the faulted flight passes them."""
    (tmp_path / "perfect-radio.toml").write_text(scenario(link_faults=False))
    sim = subprocess.run(
        swarm_command(
            "simulate", "perfect-radio.toml", "--report", "report", "--no-plots", "--no-recording"
        ),
        capture_output=True,
        text=True,
        env=ENV,
        cwd=tmp_path,
        timeout=300,
    )
    assert sim.returncode == 0, sim.stdout + sim.stderr
    s = Statuses.of(read_tlog(tmp_path / "report" / "flight.tlog"), DRONES)
    judges = {
        "loss": lambda: judge_loss(s, LOSS[0], LOSS[0] + LOSS[1], LOSS[2]),
        "delay": lambda: judge_delay(s, DELAY[0], DELAY[0] + DELAY[1], DELAY[2]),
        "link cut": lambda: judge_cut(s, CUT[0], CUT[0] + CUT[1], *CUT[2]),
        "one-way": lambda: judge_cut(s, ONE_WAY[0], ONE_WAY[0] + ONE_WAY[1], *ONE_WAY[2]),
        "partition": lambda: judge_partition(
            s, PARTITION[0], PARTITION[0] + PARTITION[1], PARTITION[2]
        ),
    }
    for name, judge in judges.items():
        with pytest.raises(AssertionError):
            judge()
            pytest.fail(f"the {name} judge passed a flight without its fault")

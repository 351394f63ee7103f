"""``swarm drills run`` end to end, as a user types it (issue 14 item 1).

One run of three drills against the default swarm (nine drones, lockstep clock, swarm up on
UDP ports of its own, Zenoh on the default rendezvous when free: under the default-ports lock):
two cheap drills that pass (garbage on the consensus keys, a flood of operator commands) and,
last (``--only`` keeps the order given), the big loss drill made to fail with ``--loss 1.0``
(every message lost while the formation moves 1 m: the estimates cannot follow and, without
their neighbours' positions, drones come close), so the verdicts are seen to fail: FAIL in the
table and in drills.json, exit code 1. Plus ``--list`` and a bad ``--only``, which need no
swarm.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from sitl_client import ENV
from test_drill_flight import _default_ports_lock

pytestmark = pytest.mark.slow


def _swarm(*args: str, cwd: Path, timeout_s: float = 60.0) -> subprocess.CompletedProcess[str]:
    exe = Path(sys.executable).with_name("swarm")
    argv = [str(exe)] if exe.exists() else [sys.executable, "-m", "gcs.cli"]
    return subprocess.run(
        [*argv, *args], capture_output=True, text=True, env=ENV, cwd=cwd, timeout=timeout_s
    )


def test_list_shows_every_drill_with_its_criteria(tmp_path: Path) -> None:
    done = _swarm("drills", "run", "--list", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    out = done.stdout
    for name in (
        "link-cut", "one-way-link", "loss-20", "loss-50", "delay-100ms", "partition", "garbage",
        "command-flood", "gcs-restart", "dropout", "crash", "restart",
    ):  # fmt: skip
        assert f"\n{name}: " in f"\n{out}", name
    assert "re-converged (estimates 2 %, formation 5 cm / 2 %)" in out
    assert "drones lost: 8" in out  # the crash drill of nine drones
    assert "drone 4 rejoins" in out
    assert not (tmp_path / "drills").exists()  # --list flies nothing


def test_an_unknown_drill_is_a_one_line_error(tmp_path: Path) -> None:
    done = _swarm("drills", "run", "--only", "garbage,meteor", cwd=tmp_path)
    assert done.returncode == 2
    assert (
        done.stderr.strip().splitlines() == [done.stderr.strip().splitlines()[0]]
        and "unknown drill meteor" in done.stderr
    )


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[subprocess.CompletedProcess[str], Path]:
    cwd = tmp_path_factory.mktemp("drills_run")
    with _default_ports_lock():  # swarm up takes the default Zenoh port 7447 when it is free
        done = _swarm(
            "drills", "run", "--only", "garbage,command-flood,loss-100", "--loss", "1.0",
            cwd=cwd, timeout_s=900.0,
        )  # fmt: skip
    print(done.stdout, done.stderr[-3000:])
    return done, cwd / "drills"


def test_a_failed_drill_is_reported_fail_with_exit_code_1(
    run: tuple[subprocess.CompletedProcess[str], Path],
) -> None:
    done, report = run
    assert done.returncode == 1, done.stderr[-2000:]
    rows = {line.split()[0]: line.split()[1] for line in done.stdout.splitlines()[2:5]}
    assert rows == {"garbage": "PASS", "command-flood": "PASS", "loss-100": "FAIL"}
    assert "FAIL loss-100: peak estimate error" in done.stdout
    data = json.loads((report / "drills.json").read_text())
    assert data["passed"] is False and data["drones"] == 9 and data["clock"] == "lockstep"
    assert [d["name"] for d in data["drills"]] == ["garbage", "command-flood", "loss-100"]
    loss = data["drills"][2]
    assert loss["name"] == "loss-100" and not loss["passed"]
    assert loss["peak_estimate_error"] > 0.05  # the bar it failed


def test_cheap_drills_pass_with_their_figures(
    run: tuple[subprocess.CompletedProcess[str], Path],
) -> None:
    _, report = run
    data = json.loads((report / "drills.json").read_text())
    garbage, flood = data["drills"][:2]
    assert garbage["passed"] and flood["passed"], (garbage["failures"], flood["failures"])
    # every kind of garbage rejected and counted by the agents, none of it believed
    assert min(garbage["rejected"][k] for k in ("malformed", "wrong_version", "wrong_swarm")) > 0
    assert garbage["peak_estimate_error"] < 0.02 and garbage["drones_lost"] == []
    # every request answered; the malformed third refused by the ground station
    assert flood["answered_share"] == 1.0
    assert flood["rejected"]["gcs: malformed request"] == 200
    for drill in (garbage, flood):
        assert drill["processes_ended"] == [] and drill["steady_at_start"]
        assert drill["min_separation_m"] > 1.0 and drill["time_to_reconverge_s"] is not None
    assert (report / "drills.png").stat().st_size > 10_000
    assert (report / "swarm" / "flight.tlog").exists()  # the swarm's own report

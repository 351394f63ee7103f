"""``swarm drills run`` end to end, as a user types it.

The whole catalogue once, as a user accepting a swarm types it (``swarm drills run``: nine
drones, lockstep clock, every drill with its default criteria, swarm up on UDP ports of its own,
Zenoh on the default rendezvous when free: under the default-ports lock): every verdict PASS,
exit code 0, each figure docs/processes.md quotes for a drill within a factor of 2, and the
cheap drills' own figures (garbage on the consensus keys counted and not believed, a flood of
operator commands answered). Then a run of one drill, the big loss drill made to fail with
``--loss 1.0`` (every message lost while the formation moves 1 m: the estimates cannot follow
and, without their neighbours' positions, drones come close), so the verdicts are seen to fail:
FAIL in the table and in drills.json, exit code 1. Plus ``--list`` and a bad ``--only``, which
need no swarm.
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


CATALOGUE = (
    "link-cut", "one-way-link", "loss-20", "loss-50", "delay-100ms", "partition", "garbage",
    "command-flood", "gcs-restart", "dropout", "crash", "restart",
)  # fmt: skip


@pytest.fixture(scope="module")
def catalogue(
    tmp_path_factory: pytest.TempPathFactory,
) -> tuple[subprocess.CompletedProcess[str], Path]:
    """``swarm drills run`` as a user accepting a swarm types it: every drill, its defaults."""
    cwd = tmp_path_factory.mktemp("drills_catalogue")
    with _default_ports_lock():  # swarm up takes the default Zenoh port 7447 when it is free
        done = _swarm("drills", "run", cwd=cwd, timeout_s=900.0)
    print(done.stdout, done.stderr[-3000:])
    return done, cwd / "drills"


def _failed_drills(report: Path) -> str:
    """What a failed drill's record says (its figures, when its peaks were, the events of its
    window): a failure on a CI machine leaves no folder to look into."""
    try:
        data = json.loads((report / "drills.json").read_text())
        events = [json.loads(line) for line in (report / "swarm" / "events.jsonl").open()]
    except (OSError, ValueError) as exc:
        return f"\n(no record: {exc})"
    out = []
    for drill in data["drills"]:
        if drill["passed"]:
            continue
        t0 = drill["t_start_s"]
        out.append(f"\n{json.dumps(drill)}")
        out += [f"\n  {e}" for e in events if t0 - 1.0 <= e.get("t_s", -1e9) <= t0 + 30.0]
    return "".join(out)


def test_every_drill_of_the_catalogue_passes(
    catalogue: tuple[subprocess.CompletedProcess[str], Path],
) -> None:
    done, report = catalogue
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:] + _failed_drills(report)
    data = json.loads((report / "drills.json").read_text())
    assert data["passed"] and data["drones"] == 9 and data["clock"] == "lockstep"
    assert [d["name"] for d in data["drills"]] == list(CATALOGUE)
    failed = {d["name"]: d["failures"] for d in data["drills"] if not d["passed"]}
    assert failed == {}, failed
    for drill in data["drills"]:
        assert drill["steady_at_start"] and drill["min_separation_m"] > 1.0, drill["name"]
        assert drill["time_to_reconverge_s"] is not None, drill["name"]
    rows = {line.split()[0]: line.split()[1] for line in done.stdout.splitlines()[2:14]}
    assert rows == dict.fromkeys(CATALOGUE, "PASS"), rows


def test_the_drills_figures_are_the_documented_ones(
    catalogue: tuple[subprocess.CompletedProcess[str], Path],
) -> None:
    """Each figure docs/processes.md quotes for a drill, within a factor of 2: the centroid's
    jump when the drop-out and the crash take a drone out (0.35 m, 0.56 m: its offset over
    N - 1), the partition's estimates and spreads while split (9.7 %, 8.9 %) and its
    re-convergence after the heal (4 s); the link drills leave the formation within 5 cm; the
    ground station's restart costs nothing (it is judged from its return); the restarted agent
    rejoins."""
    _, report = catalogue
    d = {x["name"]: x for x in json.loads((report / "drills.json").read_text())["drills"]}

    def near(value: float, quoted: float) -> bool:
        return quoted / 2 <= value <= quoted * 2

    assert near(d["dropout"]["start_centroid_error_m"], 0.35), d["dropout"]
    assert near(d["crash"]["start_centroid_error_m"], 0.56), d["crash"]
    assert d["dropout"]["drones_lost"] == [7] and d["crash"]["drones_lost"] == [8]
    split = d["partition"]
    assert near(split["peak_estimate_error"], 0.097), split
    assert near(split["peak_spread_error"], 0.089), split
    assert near(split["time_to_reconverge_s"], 4.0), split
    for name in ("link-cut", "one-way-link", "loss-20", "loss-50", "delay-100ms"):
        assert d[name]["peak_centroid_error_m"] < 0.05, d[name]
    restart = d["gcs-restart"]
    assert restart["back_at_s"] is not None and restart["peak_centroid_error_m"] < 0.05, restart
    assert d["restart"]["returned_s"] is not None, d["restart"]
    assert (report / "drills.png").stat().st_size > 10_000
    assert (report / "swarm" / "flight.tlog").exists()  # the swarm's own report


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[subprocess.CompletedProcess[str], Path]:
    cwd = tmp_path_factory.mktemp("drills_run")
    with _default_ports_lock():  # swarm up takes the default Zenoh port 7447 when it is free
        done = _swarm(
            "drills", "run", "--only", "loss-100", "--loss", "1.0",
            cwd=cwd, timeout_s=900.0,
        )  # fmt: skip
    print(done.stdout, done.stderr[-3000:])
    return done, cwd / "drills"


def test_a_failed_drill_is_reported_fail_with_exit_code_1(
    run: tuple[subprocess.CompletedProcess[str], Path],
) -> None:
    done, report = run
    assert done.returncode == 1, done.stderr[-2000:]
    rows = {line.split()[0]: line.split()[1] for line in done.stdout.splitlines()[2:3]}
    assert rows == {"loss-100": "FAIL"}, done.stdout
    assert "FAIL loss-100: peak estimate error" in done.stdout
    data = json.loads((report / "drills.json").read_text())
    assert data["passed"] is False and data["drones"] == 9 and data["clock"] == "lockstep"
    assert [d["name"] for d in data["drills"]] == ["loss-100"]
    loss = data["drills"][0]
    assert loss["name"] == "loss-100" and not loss["passed"]
    assert loss["peak_estimate_error"] > 0.05  # the bar it failed


def test_cheap_drills_pass_with_their_figures(
    catalogue: tuple[subprocess.CompletedProcess[str], Path],
) -> None:
    _, report = catalogue
    data = json.loads((report / "drills.json").read_text())
    drills = {d["name"]: d for d in data["drills"]}
    garbage, flood = drills["garbage"], drills["command-flood"]
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

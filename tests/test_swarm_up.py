"""``swarm up`` end to end: it flies a scenario with real child processes, the ground station
writes the report, and whether it ends normally or by Ctrl-C nothing of it is left running and
its ports are free."""

from __future__ import annotations

import itertools
import json
import os
import signal
import socket
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from agent_harness import write_scenario
from sitl_client import ENV, ROOT, free_port_block, free_udp_port, swarm_command

from gcs.report.events import read_events
from gcs.report.tlog import read_tlog
from protocols.descriptors import descriptors

pytestmark = pytest.mark.slow
SQUARE = [(0.0, 0.0, 0.0), (0.0, 3.0, 0.0), (4.0, 0.0, 0.0), (4.0, 3.0, 0.0)]


def _processes_mentioning(text: str) -> list[int]:
    pids = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if text in cmdline and int(entry.name) != os.getpid():
            pids.append(int(entry.name))
    return pids


def _udp_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _up(
    tmp_path: Path, *extra: str, duration_s: float = 30.0
) -> tuple[subprocess.Popen[bytes], Path, int, int]:
    scenario = write_scenario(
        tmp_path / "hover.toml",
        SQUARE,
        centre=(2.0, 1.5, -2.0),
        spread=(2.0, 1.5, 0.0),
        duration_s=duration_s,
        settle_s=8.0,
    )
    base, gcs_port = free_port_block(4), free_udp_port()
    report = tmp_path / "report"
    proc = subprocess.Popen(
        swarm_command(
            "up",
            str(scenario),
            "--report",
            str(report),
            "--base-port",
            str(base),
            "--gcs-port",
            str(gcs_port),
            *extra,
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        env=ENV,
        cwd=ROOT,
    )
    return proc, report, base, gcs_port


def _assert_nothing_left(report: Path, base: int, gcs_port: int) -> None:
    deadline = time.monotonic() + 5.0
    while _processes_mentioning(str(report.parent)) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert _processes_mentioning(str(report.parent)) == []
    assert all(_udp_free(p) for p in range(base, base + 4))
    assert _udp_free(gcs_port)


def test_swarm_up_flies_and_reports(tmp_path: Path) -> None:
    proc, report, base, gcs_port = _up(tmp_path, "--duration-s", "14", "--agents-per-process", "2")
    out, _ = proc.communicate(timeout=180)
    text = out.decode(errors="replace")
    assert proc.returncode == 0, text
    assert "swarm up: finished" in text
    metrics = json.loads((report / "metrics.json").read_text())
    assert metrics["n_drones"] == 4
    assert metrics["tracking_steady"]["centroid_m"]["rms"] < 0.05
    assert metrics["collisions"]["count"] == 0
    track = read_tlog(report / "flight.tlog")
    assert set(track.vehicles) == {1, 2, 3, 4}
    assert all(-v.position_ned_m[-1, 2] > 1.5 for v in track.vehicles.values())
    for png in ("paths.png", "descriptors.png"):
        assert (report / png).stat().st_size > 10_000
    _assert_nothing_left(report, base, gcs_port)


def test_ctrl_c_stops_everything(tmp_path: Path) -> None:
    proc, report, base, gcs_port = _up(tmp_path)
    deadline = time.monotonic() + 60
    while not (report / "logs" / "sim.log").exists() and time.monotonic() < deadline:
        time.sleep(0.2)
    time.sleep(4.0)
    assert len(_processes_mentioning(str(tmp_path))) >= 4  # up, gcs, sim, agents
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=60)
    assert "interrupted" in out.decode(errors="replace")
    assert proc.returncode == 1
    _assert_nothing_left(report, base, gcs_port)


def _swarm(run: dict[str, object], *args: str) -> subprocess.CompletedProcess[str]:
    """An operator command or drill against the run (its endpoint from the run file)."""
    cmd = swarm_command(*args, "--swarm-id", "drills", "--zenoh-connect", str(run["zenoh"]))
    return subprocess.run(cmd, capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=30)


def _status_rows(run: dict[str, object]) -> tuple[float, list[list[str]]]:
    """Simulated time and the table rows of ``swarm status`` (-1 and [] if no answer)."""
    out = _swarm(run, "status")
    if out.returncode != 0:
        return -1.0, []
    t = float(out.stdout.split("t = ", 1)[1].split(" s", 1)[0])
    rows = [ln.split() for ln in out.stdout.splitlines() if ln.split() and ln.split()[0].isdigit()]
    return t, rows


def _wait(condition: object, timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if callable(condition) and condition():
            return True
        time.sleep(0.5)
    return False


def test_drills_dropout_link_cut_and_gcs_restart_during_a_run(tmp_path: Path) -> None:
    """In a swarm started by swarm up: a formation change is flown and a move beyond the geofence
    refused (the plan is unchanged); swarm drill dropout kills an agent process, link-cut cuts a
    link, gcs-restart restarts the ground station, which adopts the current plan and continues
    its logs; the swarm flies on."""
    proc, report, base, gcs_port = _up(tmp_path, "--swarm-id", "drills", duration_s=70.0)
    try:
        run_file = report / "logs" / "run.json"
        assert _wait(run_file.exists, 60.0)
        run = json.loads(run_file.read_text())
        assert sorted(run["agents"]) == ["0", "1", "2", "3"]

        def flying() -> bool:
            t, rows = _status_rows(run)
            return t > 12.0 and len(rows) == 4 and all("FLYING" in r for r in rows)

        assert _wait(flying, 90.0), _swarm(run, "status").stdout
        moved = _swarm(run, "formation", "--heading-deg", "20", "--length-m", "3")
        assert moved.returncode == 0 and "plan 1" in moved.stdout, moved.stdout + moved.stderr
        fenced = _swarm(run, "move", "--north-m", "5000")
        assert fenced.returncode == 1 and "geofence" in fenced.stdout, fenced.stdout
        killed = _swarm(run, "drill", "dropout", "--drone", "3")
        assert killed.returncode == 0 and "killed" in killed.stdout, killed.stdout + killed.stderr
        again = _swarm(run, "drill", "dropout", "--drone", "3")
        assert again.returncode == 1 and "not running" in again.stdout, again.stdout
        cut = _swarm(run, "drill", "link-cut", "0", "1", "--for-s", "5")
        assert cut.returncode == 0, cut.stdout + cut.stderr
        restart = _swarm(run, "drill", "gcs-restart")
        assert restart.returncode == 0 and "accepted" in restart.stdout, restart.stdout
        t_restart, _ = _status_rows(run)

        def back() -> bool:
            t, rows = _status_rows(run)
            return t > t_restart + 2.0 and sum("FLYING" in r for r in rows) == 3

        assert _wait(back, 60.0), _swarm(run, "status").stdout
        assert "plan 2" in _swarm(run, "hold").stdout  # the restarted station went on from 1
        out, _ = proc.communicate(timeout=240)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            proc.communicate(timeout=60)
    text = out.decode(errors="replace")
    assert proc.returncode == 0, text
    events = read_events(report / "events.jsonl")
    kinds = [e["kind"] for e in events]
    assert "run_start" in kinds[:2] and kinds[-1] == "run_end"
    assert kinds.count("gcs_restarted") == 1 and kinds.count("gcs_stopped") == 1
    times = [e["t_s"] for e in events]
    # the restarted station's clock carries on (vehicle and agent clocks may differ by a tick)
    assert all(b >= a - 0.5 for a, b in itertools.pairwise(times)), times
    drills = [(e["drill"], e["accepted"]) for e in events if e["kind"] == "drill"]
    assert ("dropout", True) in drills and ("dropout", False) in drills
    assert ("link_cut", True) in drills and ("gcs_restart", True) in drills
    assert any(e["kind"] == "dropout_detected" and e["drone"] == 3 for e in events)
    # one log across the restart: every survivor's telemetry from take-off to the end, and the
    # gap while the station restarted is short
    track = read_tlog(report / "flight.tlog")
    for sysid in (1, 2, 3):
        t = track.vehicles[sysid].t_s
        assert t[0] < 1.0 and t[-1] > 68.0 and np.diff(t).max() < 10.0, sysid
        assert -track.vehicles[sysid].position_ned_m[-1, 2] > 1.5  # still flying
    assert track.vehicles[4].t_s[-1] < 68.0 or -track.vehicles[4].position_ned_m[-1, 2] < 0.2
    # the three survivors took the commanded heading and length (true, from telemetry)
    end = min(float(track.vehicles[s].t_s[-1]) for s in (1, 2, 3))
    truth = descriptors(track.resample(np.array([end]), 3)[0])
    assert abs(np.degrees(truth[5]) - 20.0) < 3.0 and abs(np.sqrt(truth[6]) - 3.0) < 0.15, truth
    metrics = json.loads((report / "metrics.json").read_text())
    assert metrics["plan_seq"] == 2  # formation (1), then hold (2) after the restart
    assert [d["sysid"] for d in metrics["drones_lost"]] == [4]
    _assert_nothing_left(report, base, gcs_port)


def test_a_dead_simulator_ends_the_run_and_everything_is_stopped(tmp_path: Path) -> None:
    """A child that dies (here the simulator, SIGKILLed) ends swarm up with exit code 1 and the
    reason; no process of the run is left and its ports are free."""
    proc, report, base, gcs_port = _up(tmp_path)
    run_file = report / "logs" / "run.json"
    assert _wait(run_file.exists, 60.0)
    time.sleep(3.0)
    sims = [p for p in _processes_mentioning(str(tmp_path)) if _cmdline(p).find(" sim ") > 0]
    assert len(sims) == 1, [_cmdline(p) for p in _processes_mentioning(str(tmp_path))]
    os.kill(sims[0], signal.SIGKILL)
    out, _ = proc.communicate(timeout=90)
    text = out.decode(errors="replace")
    assert proc.returncode == 1, text
    assert "the simulator exited with code -9" in text
    _assert_nothing_left(report, base, gcs_port)


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""

"""``swarm up`` end to end: it flies a scenario with real child processes, the ground station
writes the report, and whether it ends normally or by Ctrl-C nothing of it is left running and
its ports are free. Drills typed during a ``swarm up`` run (dropout, typed twice; link cut;
gcs-restart, which goes on from the current plan) fly in tests/test_drill_flight.py, against
the swarm ``swarm up`` starts with the README's defaults."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import threading
import time
from pathlib import Path

import pytest
from agent_harness import write_scenario
from sitl_client import ENV, ROOT, free_port_block, free_udp_port, swarm_command

from gcs.report.tlog import read_tlog

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
    deadline = time.monotonic() + 30.0  # a cap for a loaded machine, not a bound
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
    # the report says how the agents were laid out in processes (the start line's words)
    layout = "4 drones, 2 agent processes of up to 2 drones each, lockstep clock"
    assert metrics["layout"] == layout, metrics["layout"]
    assert f"layout: {layout}" in text
    track = read_tlog(report / "flight.tlog")
    assert set(track.vehicles) == {1, 2, 3, 4}
    assert all(-v.position_ned_m[-1, 2] > 1.5 for v in track.vehicles.values())
    for png in ("paths.png", "descriptors.png"):
        assert (report / png).stat().st_size > 10_000
    _assert_nothing_left(report, base, gcs_port)


def test_ctrl_c_stops_everything(tmp_path: Path) -> None:
    # long enough not to end on its own first (hosted agents fly 4 drones at several x)
    proc, report, base, gcs_port = _up(tmp_path, duration_s=600.0)
    # every process started and the agents joined (however slowly a loaded machine starts them)
    assert _wait(lambda: _run_started(report, "agent_joined"), 120.0), "no agent ever joined"
    assert len(_processes_mentioning(str(tmp_path))) >= 4  # up, gcs, sim, agents
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=60)
    assert "interrupted" in out.decode(errors="replace")
    assert proc.returncode == 1
    _assert_nothing_left(report, base, gcs_port)


def _run_started(report: Path, kind: str = "run_start") -> bool:
    """The ground station logged the run's start (it and the simulator are up), or another event
    ``kind`` ("agent_joined": an agent process is up too)."""
    events = report / "events.jsonl"
    return events.exists() and f'"kind":"{kind}"' in events.read_text(errors="replace")


def _wait(condition: object, timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if callable(condition) and condition():
            return True
        time.sleep(0.5)
    return False


def test_a_dead_simulator_ends_the_run_and_everything_is_stopped(tmp_path: Path) -> None:
    """A child that dies (here the simulator, SIGKILLed) ends swarm up with exit code 1 and the
    reason; no process of the run is left and its ports are free."""
    proc, report, base, gcs_port = _up(tmp_path, duration_s=600.0)
    assert _wait(lambda: _run_started(report), 120.0), "the run never started"

    def sims() -> list[int]:
        return [p for p in _processes_mentioning(str(tmp_path)) if _cmdline(p).find(" sim ") > 0]

    # the ground station may log the start before the simulator's process shows (a loaded machine)
    assert _wait(lambda: len(sims()) == 1, 60.0), [
        _cmdline(p) for p in _processes_mentioning(str(tmp_path))
    ]
    os.kill(sims()[0], signal.SIGKILL)
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


def _status_typed_in(cwd: Path, taken: str, typed: list[subprocess.CompletedProcess[str]]) -> None:
    """``swarm status`` typed in ``cwd`` (no flags) until it lists the 4 drones, once the run has
    moved from the ``taken`` endpoint (its run file says where to), while it flies."""
    run_file = cwd / "report" / "logs" / "run.json"
    deadline = time.monotonic() + 50.0
    while time.monotonic() < deadline:
        with contextlib.suppress(OSError, ValueError):
            if json.loads(run_file.read_text())["zenoh"] != taken:
                break
        time.sleep(0.05)
    while time.monotonic() < deadline:
        argv = swarm_command("status")
        said = subprocess.run(argv, capture_output=True, text=True, env=ENV, cwd=cwd, timeout=30)
        typed.append(said)
        if len(_status_rows(typed[-1].stdout)) == 4:
            return
        time.sleep(0.2)


def _status_rows(text: str) -> list[list[str]]:
    """The drone rows of ``swarm status``'s table."""
    return [w for w in (ln.split() for ln in text.splitlines()[2:]) if w and w[0].isdigit()]


def test_a_rendezvous_port_taken_as_the_run_starts_moves_the_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``swarm up`` picks the rendezvous port (7447) when it is free, and the ground station binds
    it a moment later: a swarm started at the same moment can take it in between (it did, to the
    demo in a loaded test run: "Address already in use", the run died). The run now starts
    again on a free port and flies. Here the port the plan picked is held by a listener of the
    test's own before the ground station starts: the same moment, made certain."""
    from gcs.cli.main import _parser
    from gcs.cli.supervisor import supervise
    from gcs.cli.up import build_plan

    for key in ("MAVLINK20", "MPLBACKEND", "PYTHONUNBUFFERED"):
        monkeypatch.setenv(key, ENV[key])
    scenario = write_scenario(
        tmp_path / "hover.toml", SQUARE, centre=(2.0, 1.5, -2.0), spread=(2.0, 1.5, 0.0),
        duration_s=30.0, settle_s=8.0,
    )  # fmt: skip
    base, gcs_port = free_port_block(4), free_udp_port()
    report = tmp_path / "report"
    args = _parser().parse_args(
        ["up", str(scenario), "--report", str(report), "--base-port", str(base),
         "--gcs-port", str(gcs_port), "--clock", "lockstep", "--agents-per-process", "4",
         "--duration-s", "8"]
    )  # fmt: skip
    plan = build_plan(args, scenario)[0]
    assert plan.rendezvous_picked
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as taken:
        taken.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        plan.move_rendezvous(f"tcp/127.0.0.1:{port}")  # picked while free, then taken
        said: list[str] = []
        typed: list[subprocess.CompletedProcess[str]] = []
        operator = threading.Thread(
            target=_status_typed_in, args=(tmp_path, plan.zenoh_endpoint, typed)
        )
        operator.start()
        try:
            reason = supervise(plan, said.append)
        finally:
            operator.join(60.0)
    assert reason == "finished", (reason, said)
    assert any("was taken by another process" in line for line in said), said
    assert any(f"typed in {tmp_path} they find it" in line for line in said), said
    # ``swarm status`` typed in the run's folder, without --zenoh-connect, reached the moved run
    assert typed and typed[-1].returncode == 0, "\n".join(f"{t.stdout} {t.stderr}" for t in typed)
    assert len(_status_rows(typed[-1].stdout)) == 4, typed[-1].stdout
    run = json.loads((report / "logs" / "run.json").read_text())
    assert run["zenoh"] == plan.zenoh_endpoint != f"tcp/127.0.0.1:{port}"
    assert "Address already in use" in (report / "logs" / "gcs.log").read_text()
    track = read_tlog(report / "flight.tlog")
    assert set(track.vehicles) == {1, 2, 3, 4}
    assert all(-v.position_ned_m[-1, 2] > 1.5 for v in track.vehicles.values())
    _assert_nothing_left(report, base, gcs_port)

"""An operator session without a scenario file (issue 13 item 4), typed as a newcomer types it.

``swarm up --drones 4`` in a fresh folder (default ports, swarm id, endpoint, report folder and
lockstep clock), then in another "terminal" ``swarm takeoff --altitude-m 3``, ``swarm formation``,
``swarm rotate``, ``swarm land`` and ``swarm shutdown``; ``swarm up`` must end by itself with the
report written. What happened to the vehicles is read back from the report's flight.tlog and
events.jsonl: on the ground and disarmed until the take-off command (nobody takes off by
themselves), airborne at 3 m after it, in the commanded formation, landed and disarmed after
``land``, no crash.

The run holds the machine's default ports under the lock other runs use
(``flock /tmp/quadswarm-default-ports.lock``).
"""

from __future__ import annotations

import json
import math
import re
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from agent_harness import SwarmObserver
from sitl_client import ENV
from test_drill_flight import _default_ports_lock, _swarm_exe
from test_operator_flight import (
    DEFAULT_ENDPOINT,
    _armed_at,
    _command_time,
    _positions,
    assert_landed_safely,
    assert_no_crash,
)

from gcs.report.events import read_events
from gcs.report.tlog import TlogTrack, read_tlog
from protocols.model.descriptors import descriptors

pytestmark = pytest.mark.slow
N = 4
ALTITUDE_M = 3.0
#: How long (simulated s) the swarm waits on the ground, settled, before the take-off.
GROUND_WAIT_S = 8.0
#: How long (simulated s) after a formation's plan arrives the four drones have turned into it.
FORMATION_SETTLE_S = 12.0
#: drone -> (mode, armed), as ``swarm status`` shows it
Rows = dict[int, tuple[str, bool]]


class Session:
    """``swarm up --drones 4`` running in ``cwd``, and the operator's commands typed beside it.
    Waits watch the agents' statuses as a Zenoh peer of the run's default rendezvous (polling
    ``swarm status``, a new process of about a second of CPU each time, took a core from the
    lockstep flight it waited for); ``swarm status`` itself is typed and checked at the
    session's milestones."""

    def __init__(self, cwd: Path, proc: subprocess.Popen[bytes], out: Path) -> None:
        self.cwd, self.proc, self.out = cwd, proc, out
        self.obs: SwarmObserver | None = None

    def __enter__(self) -> Session:
        run_file = self.cwd / "report" / "logs" / "run.json"
        deadline = time.monotonic() + 60.0
        while not run_file.exists() and time.monotonic() < deadline:
            assert self.proc.poll() is None, self.log()
            time.sleep(0.1)
        assert run_file.exists(), self.log()
        # where the run meets: the default rendezvous, or the free port it moved to when another
        # run on the machine held that (the operator's commands, typed in cwd, follow it too)
        endpoint = json.loads(run_file.read_text()).get("zenoh") or DEFAULT_ENDPOINT
        self.obs = SwarmObserver(swarm_id="swarm", connect=(endpoint,))
        return self

    def __exit__(self, *_exc: object) -> None:
        if self.obs is not None:
            self.obs.close()

    def swarm(self, *words: str) -> subprocess.CompletedProcess[str]:
        """``swarm WORDS``, nothing else: the defaults find the session."""
        return subprocess.run(
            [*_swarm_exe(), *words], capture_output=True, text=True, env=ENV, cwd=self.cwd,
            timeout=60,
        )  # fmt: skip

    def command(self, *words: str) -> str:
        out = self.swarm(*words)
        assert out.returncode == 0 and "accepted" in out.stdout, (words, out.stdout, out.stderr)
        return out.stdout

    def status(self) -> tuple[float, Rows]:
        """Simulated time and each drone's (mode, armed), from ``swarm status``."""
        out = self.swarm("status")
        if out.returncode != 0:
            return -1.0, {}
        t_s = float(re.search(r"t = ([-\d.]+) s", out.stdout).group(1))  # type: ignore[union-attr]
        rows: Rows = {}
        for line in out.stdout.splitlines()[2:]:
            words = line.split()
            if len(words) > 3 and words[0].isdigit():
                rows[int(words[0])] = (words[2], words[3] == "yes")
        return t_s, rows

    def seen(self) -> tuple[float, Rows]:
        """Simulated time and each drone's (mode, armed), from the agents' own statuses."""
        assert self.obs is not None
        st = self.obs.statuses()
        t_s = max((s.t_s for s in st.values()), default=-1.0)
        return t_s, {d: (s.mode.name, s.armed) for d, s in st.items()}

    def wait(self, what: str, ok: Callable[[float, Rows], bool], timeout_s: float = 180.0) -> float:
        """Wait until ``ok(t_s, rows)`` holds for the agents' statuses; the simulated time then."""
        deadline = time.monotonic() + timeout_s
        t_s, rows = -1.0, {}  # type: tuple[float, Rows]
        while time.monotonic() < deadline:
            assert self.proc.poll() is None, self.log()
            t_s, rows = self.seen()
            if ok(t_s, rows):
                return t_s
            time.sleep(0.05)
        pytest.fail(f"waiting for {what}: t = {t_s}, {rows}\n{self.log()}")

    def wait_t(self, t_s: float) -> float:
        return self.wait(f"t >= {t_s}", lambda t, _rows: t >= t_s)

    def wait_modes(self, mode: str) -> float:
        return self.wait(
            f"every drone {mode}",
            lambda _t, rows: len(rows) == N and all(m == mode for m, _ in rows.values()),
        )

    def log(self) -> str:
        return self.out.read_text(errors="replace")[-3000:]

    def status_says(self, mode: str, armed: bool) -> None:
        """``swarm status`` typed: every drone in ``mode``, armed or not (what the agents say)."""
        t_s, rows = self.status()
        assert t_s >= 0.0 and rows == {d: (mode, armed) for d in range(N)}, (t_s, rows)


def _arrival(reply: str) -> float:
    """The latest "t = X s" a command's reply names (when the last part of it arrives)."""
    return max(float(x) for x in re.findall(r"t = ([\d.]+) s", reply))


def _descriptors_at(track: TlogTrack, t_s: float, heading_deg: float) -> np.ndarray:
    desired = np.zeros(9)
    desired[5] = math.radians(heading_deg)
    return descriptors(_positions(track, N, t_s), desired)


def test_an_operator_session_from_power_up_to_the_report(tmp_path: Path) -> None:
    out = tmp_path / "swarm-up.out"
    with _default_ports_lock(), out.open("wb") as sink:
        proc = subprocess.Popen(
            [*_swarm_exe(), "up", "--drones", str(N)],
            stdout=sink, stderr=subprocess.STDOUT, env=ENV, cwd=tmp_path,
        )  # fmt: skip
        started = time.monotonic()
        try:
            with Session(tmp_path, proc, out) as session:
                # powered up, settled, and waiting on the ground: nobody arms by itself
                t_ready = session.wait_modes("READY")
                session.wait(
                    "the swarm still on the ground",
                    lambda t, rows: (
                        t >= t_ready + GROUND_WAIT_S
                        and all(m == "READY" and not armed for m, armed in rows.values())
                    ),
                )
                session.status_says("READY", armed=False)
                # refused on the ground: a shape command before the take-off
                early = session.swarm("formation", "--heading-deg", "30")
                assert early.returncode == 1 and "take off first" in early.stdout, early.stdout
                reply = session.command("takeoff", "--altitude-m", str(ALTITUDE_M))
                session.wait_modes("FLYING")
                session.wait_t(_arrival(reply) + 2.0)
                session.status_says("FLYING", armed=True)
                reply = session.command(
                    "formation", "--heading-deg", "30", "--length-m", "2", "--width-m", "1.5"
                )
                # four drones turn slowly: 14 deg of 30 when the plan arrives, 23 deg 5 s later
                session.wait_t(_arrival(reply) + FORMATION_SETTLE_S)
                reply = session.command("rotate", "--delta-deg", "-30")
                session.wait_t(_arrival(reply) + 2.0)
                session.command("land")
                t_landed = session.wait_modes("LANDED")
                session.status_says("LANDED", armed=False)
                reply = session.command("shutdown")
                assert "on the ground" in reply, reply
                code = proc.wait(120)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)
    took = time.monotonic() - started
    text = out.read_text(errors="replace")
    assert code == 0, text[-3000:]
    assert "swarm up: shut down" in text, text[-3000:]
    report = tmp_path / "report"
    for name in ("flight.tlog", "events.jsonl", "metrics.json", "trajectory.json"):
        assert (report / name).exists(), name
    assert "swarm up --drones 4" in (report / "logs" / "session.toml").read_text()
    track = read_tlog(report / "flight.tlog")
    events = read_events(report / "events.jsonl")
    assert_no_crash(events)
    plans = [e for e in events if e["kind"] == "plan_published"]
    assert plans[0]["command"] == "GROUND", plans[0]
    t_takeoff = _command_time(events, "takeoff")
    t_formation = _command_time(events, "formation", 1)  # the first was refused on the ground
    t_rotate, t_land = _command_time(events, "rotate"), _command_time(events, "land")
    t_shutdown = _command_time(events, "shutdown")
    assert t_takeoff > GROUND_WAIT_S
    assert sorted(track.vehicles) == list(range(1, N + 1))
    for sysid, v in track.vehicles.items():
        # on the ground, disarmed, until the take-off command
        before = v.t_s < t_takeoff
        assert np.abs(v.position_ned_m[before, 2]).max() < 0.05, sysid
        beats = v.heartbeat_t_s < t_takeoff - 0.1  # a heartbeat has its vehicle's last time
        assert beats.sum() >= GROUND_WAIT_S - 1 and not v.armed[beats].any(), sysid
        # airborne at 3 m before the formation command, armed
        k = int(np.searchsorted(v.t_s, t_formation)) - 1
        assert -v.position_ned_m[k, 2] == pytest.approx(ALTITUDE_M, abs=0.2), sysid
        assert _armed_at(v, t_formation), sysid
        # down and disarmed before the shutdown
        assert not _armed_at(v, t_shutdown), sysid
    # the formation flown as typed, then turned back
    a = _descriptors_at(track, t_rotate - 0.1, 30.0)
    assert -a[2] == pytest.approx(ALTITUDE_M, abs=0.1)
    assert math.degrees(a[5]) == pytest.approx(30.0, abs=3.0)
    np.testing.assert_allclose(np.sqrt(a[6:8]), (2.0, 1.5), rtol=0.05)
    a = _descriptors_at(track, t_land - 0.1, 0.0)
    assert math.degrees(a[5]) == pytest.approx(0.0, abs=3.0)
    assert_landed_safely(track, N, t_land, t_landed)
    kinds = [e["kind"] for e in events]
    assert "shutdown_landed" in kinds and kinds[-1] == "run_end", kinds[-5:]
    print(f"operator session: {took:.0f} s wall, {track.vehicles[1].t_s[-1]:.0f} s simulated")


def test_ctrl_c_lands_a_flying_session_before_it_stops(tmp_path: Path) -> None:
    """Ctrl-C to ``swarm up`` while the swarm flies: it lands, then the run ends, report written."""
    out = tmp_path / "swarm-up.out"
    with _default_ports_lock(), out.open("wb") as sink:
        proc = subprocess.Popen(
            [*_swarm_exe(), "up", "--drones", str(N), "--layout", "line"],
            stdout=sink, stderr=subprocess.STDOUT, env=ENV, cwd=tmp_path,
        )  # fmt: skip
        try:
            with Session(tmp_path, proc, out) as session:
                session.wait_modes("READY")
                reply = session.command("takeoff", "--altitude-m", str(ALTITUDE_M))
                session.wait_modes("FLYING")
                session.wait_t(_arrival(reply) + 1.0)
                proc.send_signal(signal.SIGINT)  # Ctrl-C
                code = proc.wait(120)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)
    text = out.read_text(errors="replace")
    assert code == 0 and "swarm up: shut down" in text, text[-3000:]
    assert "the swarm lands" in text, text[-3000:]
    report = tmp_path / "report"
    assert (report / "metrics.json").exists()
    track = read_tlog(report / "flight.tlog")
    events = read_events(report / "events.jsonl")
    assert_no_crash(events)
    (shutdown,) = [e for e in events if e["kind"] == "shutdown"]
    assert shutdown["reason"] == "interrupt" and shutdown["airborne"] == list(range(N))
    landing = [e for e in events if e["kind"] == "plan_published"][-1]
    assert landing["command"] == "LAND", landing
    t_down = next(float(e["t_s"]) for e in events if e["kind"] == "shutdown_landed")
    assert_landed_safely(track, N, float(shutdown["t_s"]), t_down)
    for sysid, v in track.vehicles.items():
        k = int(np.searchsorted(v.t_s, float(shutdown["t_s"]))) - 1
        assert -v.position_ned_m[k, 2] == pytest.approx(ALTITUDE_M, abs=0.2), sysid

"""The paper's flight across four hosts (Linux network namespaces on a bridge), secured.

- ground (10.231.S.1): the Zenoh router and the ground station
  (``swarm up --only router,gcs``);
- sim (.2): the simulator, its vehicle ports on its own address (``--only sim``);
- companion A (.3) and B (.4): the agents of drones 0-4 and 5-8 (``--only agents --drones``).

MAVLink UDP (agents to vehicles, vehicles to the ground station) and Zenoh (every process a
client of the router) cross the namespaces on their own addresses: no process shares a loopback
with another host's. The swarm is secured with ``swarm keys init`` (TLS with client certificates,
user/password, access control, signed MAVLink). The first 60 s of the paper flight, including
drone 1's crash at 30 s, are judged from the ground station's flight.tlog by the bars of
``test_demo_paper.py`` (the one-host flight). About 2 minutes.

Without root or ``ip netns`` the test is skipped, saying why.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import netns
import numpy as np
import pytest
from paper_flight import PAPER, ROOT, SWARM, flight_of, min_airborne_separation

from gcs.metrics import descriptors_of, tracking_from_positions
from gcs.tlog import read_tlog

pytestmark = pytest.mark.slow
WHY_NOT = netns.unavailable()
DURATION_S = 60.0
CRASHED, CRASH_T_S = 1, 30.0
SETTLE_S = 20.0
ENV = {
    **os.environ,
    "MAVLINK20": "1",
    "MPLBACKEND": "Agg",
    "PYTHONUNBUFFERED": "1",
    "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
}


def _start(host: netns.Host, out: Path, *args: str) -> subprocess.Popen[bytes]:
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("wb") as sink:
        return subprocess.Popen(
            host.argv(*SWARM, *args), stdout=sink, stderr=subprocess.STDOUT, env=ENV, cwd=ROOT
        )


def _logs(folder: Path) -> str:
    texts = [f"== {p}:\n{p.read_text(errors='replace')[-1500:]}" for p in folder.rglob("*.log")]
    texts += [f"== {p}:\n{p.read_text(errors='replace')[-1500:]}" for p in folder.glob("*.out")]
    return "\n".join(texts)


def _stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


def _wait_for(path: Path, text: str, timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if path.exists() and text in path.read_text(errors="replace"):
            return True
        time.sleep(0.2)
    return False


@pytest.mark.skipif(WHY_NOT is not None, reason=f"network namespaces: {WHY_NOT}")
def test_secured_paper_flight_across_four_hosts(tmp_path: Path) -> None:
    with netns.hosts(["ground", "sim", "compa", "compb"]) as h:
        ground, sim = h["ground"], h["sim"]
        router = f"tcp/{ground.ip}:7447"
        secrets = tmp_path / "secrets"
        keys = subprocess.run(
            [*SWARM, "keys", "init", str(secrets), "--router-host", ground.ip,
             "--swarm-id", "paper"],
            capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=60,
        )  # fmt: skip
        assert keys.returncode == 0, keys.stderr
        common = [
            "up", str(PAPER), "--router", router, "--secrets", str(secrets),
            "--duration-s", str(DURATION_S), "--swarm-id", "paper",
        ]  # fmt: skip
        procs: list[subprocess.Popen[bytes]] = []
        try:
            out = tmp_path / "ground.out"
            procs.append(
                _start(ground, out, *common, "--report", str(tmp_path / "ground"),
                       "--only", "router,gcs", "--bind", ground.ip)
            )  # fmt: skip
            assert _wait_for(out, "here: router, gcs", 30.0), _logs(tmp_path)
            time.sleep(2.0)
            for name, drones in (("compa", "0-4"), ("compb", "5-8")):
                procs.append(
                    _start(h[name], tmp_path / f"{name}.out", *common,
                           "--report", str(tmp_path / name), "--only", "agents",
                           "--drones", drones, "--agents-per-process", "5", "--sim-host", sim.ip)
                )  # fmt: skip
            # the simulator host waits until every agent is on the swarm network, then starts
            procs.append(
                _start(sim, tmp_path / "sim.out", *common, "--report", str(tmp_path / "sim"),
                       "--only", "sim", "--bind", sim.ip, "--gcs-host", ground.ip)
            )  # fmt: skip
            # the ground station ends at 60 s of simulated time and writes the report
            procs[0].wait(timeout=300)
            for p in procs[1:]:
                p.wait(timeout=60)
        finally:
            for p in procs:
                _stop(p)
        logs = _logs(tmp_path)
        assert [p.returncode for p in procs] == [0, 0, 0, 0], logs
        report = tmp_path / "ground"
        assert "finished" in (tmp_path / "ground.out").read_text(), logs
    # the agents reached their vehicles on the simulator's address and the router on the
    # ground's; nothing of theirs listens on or talks to a loopback of another host
    sim_log = (tmp_path / "sim" / "logs" / "sim.log").read_text()
    assert f"on UDP {sim.ip}:" in sim_log and f"GCS udp:{ground.ip}:" in sim_log, sim_log
    assert "signed" in sim_log
    router_log = (report / "logs" / "router.log").read_text()
    assert f"tls/{ground.ip}:7447" in router_log and "secured" in router_log, router_log
    _assert_paper_bars(report)


def _assert_paper_bars(report: Path) -> None:
    """The bars of test_demo_paper.py (one host), over the first 60 s."""
    flight = flight_of(read_tlog(report / "flight.tlog"))
    keep = flight["t"] <= DURATION_S - 0.5
    t, pos = flight["t"][keep], flight["positions"][keep]
    member, desired = flight["member"][keep], flight["desired"][keep]
    errors = tracking_from_positions(t, pos, member, desired, SETTLE_S)
    assert errors["centroid_m"]["rms"] < 0.06, errors["centroid_m"]
    assert errors["shape_m2"]["rms"] < 0.12, errors["shape_m2"]
    window = [(CRASH_T_S, CRASH_T_S + 10.0)]
    steady = tracking_from_positions(t, pos, member, desired, SETTLE_S, exclude=window)
    assert steady["centroid_m"]["rms"] < 0.002, steady["centroid_m"]
    assert steady["shape_m2"]["rms"] < 0.008, steady["shape_m2"]
    assert min_airborne_separation(pos) > 1.9
    truth = descriptors_of(pos, member, desired)
    centroid = np.linalg.norm(truth[:, :3] - desired[:, :3], axis=1)
    shape = np.abs(truth[:, 6:9] - desired[:, 6:9]).max(axis=1)
    recovered = t >= CRASH_T_S + 7.0
    assert centroid[recovered].max() < 0.05 and shape[recovered].max() < 0.1
    during = (t >= CRASH_T_S) & (t < CRASH_T_S + 1.0)
    assert np.nanmax(np.abs(truth[during, 0] - desired[during, 0])) > 0.4  # the crash is felt
    survivors = [i for i in range(9) if i != CRASHED]
    assert np.all(-pos[-1, survivors, 2] > 4.5)

"""MAVProxy, a real ground station (headless, commands on stdin), on the simulator's GCS port:
it detects both vehicles, fetches parameters, ``arm throttle`` arms vehicle 1, and its ``status``
shows each vehicle's GLOBAL_POSITION_INT on the map (around PX4 SITL's default home).

MAVProxy is part of the test environment (``make venv`` installs it): without it this test fails
and says how to install it, instead of skipping and leaving the real-peer check silently undone.
"""

from __future__ import annotations

import contextlib
import importlib.util
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from protocols.model.geodesy import GeoPoint, ned_to_geodetic
from tests.sitl_client import ENV, HOST, MavPeer, free_udp_port, sim_process

pytestmark = pytest.mark.timeout(120)
MAVPROXY = Path(sys.executable).parent / "mavproxy.py"
INSTALL_HINT = (
    "run `make venv`, or install it into this interpreter's environment: "
    f"{sys.executable} -m pip install --no-deps 'MAVProxy>=1.8,<2' 'pyserial>=3.5'"
)


def require_mavproxy() -> None:
    """Fail (never skip) when MAVProxy is not installed next to this interpreter."""
    missing = [
        what
        for what, present in (
            (f"the script {MAVPROXY}", MAVPROXY.exists()),
            ("the MAVProxy package", importlib.util.find_spec("MAVProxy") is not None),
            ("pyserial", importlib.util.find_spec("serial") is not None),
        )
        if not present
    ]
    if missing:
        pytest.fail(f"MAVProxy is missing ({', '.join(missing)}): {INSTALL_HINT}", pytrace=False)


@contextlib.contextmanager
def mavproxy(tmp_path: Path, port: int) -> Iterator[tuple[subprocess.Popen[bytes], Path]]:
    """MAVProxy listening on ``port``; its output goes to a file. Always ended (it exits 1)."""
    log = tmp_path / "mavproxy.out"
    with log.open("wb") as out:
        proc = subprocess.Popen(
            [sys.executable, str(MAVPROXY), f"--master=udpin:{HOST}:{port}",
             "--cmd=set param_ftp 0", "--state-basedir", str(tmp_path)],
            stdin=subprocess.PIPE, stdout=out, stderr=subprocess.STDOUT, cwd=tmp_path, env=ENV,
        )  # fmt: skip
    try:
        yield proc, log
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)
        assert proc.stdin is not None
        proc.stdin.close()


def _wait_output(log: Path, *needles: str, timeout_s: float = 30.0) -> str:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        text = log.read_text(errors="replace")
        if all(n in text for n in needles):
            return text
        time.sleep(0.1)
    raise AssertionError(f"MAVProxy did not print {needles}; it printed:\n{text[-3000:]}")


def test_mavproxy_sees_the_vehicles_and_arms_one(tmp_path: Path) -> None:
    require_mavproxy()
    port = free_udp_port()
    with (
        mavproxy(tmp_path, port) as (proc, log),
        sim_process(tmp_path, "--drones", "2", "--gcs", f"udp:{HOST}:{port}") as sim,
    ):
        _wait_output(log, "online system 1", "Detected vehicle 2:1", "Received 11 parameters")
        assert proc.stdin is not None
        proc.stdin.write(b"arm throttle\n")
        proc.stdin.flush()
        text = _wait_output(log, "COMPONENT_ARM_DISARM: ACCEPTED", "ARMED")
        assert "DENIED" not in text and "UNSUPPORTED" not in text
        # vehicle 1 sits on home, vehicle 2 2 m east of it (the --drones grid)
        home_lat, home_lon = ned_to_geodetic(GeoPoint(), np.zeros((1, 3)))[:2]
        east_lon = ned_to_geodetic(GeoPoint(), np.array([[0.0, 2.0, 0.0]]))[1]
        for sysid, lon in ((1, home_lon[0]), (2, east_lon[0])):
            proc.stdin.write(f"vehicle {sysid}\nstatus GLOBAL_POSITION_INT\n".encode())
            proc.stdin.flush()
            _wait_output(log, f"lat : {round(home_lat[0] * 1e7)}, lon : {round(lon * 1e7)}")
        with MavPeer(1, 191, (HOST, sim.base_port)) as agent:  # the vehicle's own view
            agent.connect()
            assert agent.wait_for("HEARTBEAT").base_mode & 128
        with MavPeer(2, 191, (HOST, sim.base_port + 1)) as agent:
            agent.connect()
            assert not agent.wait_for("HEARTBEAT").base_mode & 128
        assert sim.alive()

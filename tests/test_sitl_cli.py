"""``swarm sim`` start-up checks (one line, exit 2), status lines, and clean stops on signals."""

from __future__ import annotations

import signal
import socket
import subprocess
import time
from pathlib import Path

import pytest

from gcs.cli.main import main
from tests.sitl_client import ENV, HOST, ROOT, MavPeer, free_port_block, sim_process, swarm_command

pytestmark = pytest.mark.timeout(60)


def _error(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    assert main(["sim", "--quiet", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("swarm: error: "), err
    return err[0]


@pytest.mark.parametrize(
    "argv,needle",
    [
        (("--drones", "251"), "251 vehicles: between 1 and 250"),
        (("--drones", "0"), "between 1 and 250"),
        (
            ("--drones", "3", "--sysids", "1,2,2"),
            "two vehicles with system id 2 (vehicles 1 and 2)",
        ),
        (("--drones", "2", "--sysids", "1,251"), "system id 251 outside 1..250"),
        (("--drones", "2", "--gcs", "tcp:127.0.0.1:14550"), "--gcs 'tcp:127.0.0.1:14550'"),
        (("--drones", "2", "--gcs", "udp:127.0.0.1"), "expected udp:HOST:PORT"),
        (("--drones", "2", "--gcs", "udp:no.such.host.invalid:14550"), "cannot resolve"),
        (("--scenario", "no/such/file.toml"), "no such file"),
        (("--drones", "2", "--control-hz", "30"), "--physics-hz 500 must be a positive multiple"),
        (("--drones", "2", "--speedup", "0"), "--speedup must be a number > 0"),
        (("--drones", "2", "--base-port", "65535"), "--base-port 65535"),
    ],
)
def test_bad_options_are_one_line_errors(
    capsys: pytest.CaptureFixture[str], argv: tuple[str, ...], needle: str
) -> None:
    assert needle in _error(capsys, *argv)


def test_bad_signing_key_file(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    key = tmp_path / "short.key"
    key.write_bytes(b"12345")
    line = _error(capsys, "--drones", "1", "--signing-key", str(key))
    assert "--signing-key" in line and "32 raw bytes or 64 hex" in line


def test_a_port_in_use_names_the_port_and_the_vehicle(capsys: pytest.CaptureFixture[str]) -> None:
    base = free_port_block(3)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as squatter:
        squatter.bind((HOST, base + 1))
        line = _error(capsys, "--drones", "3", "--base-port", str(base), "--gcs", "none")
    assert f"UDP port {base + 1} (vehicle 1, system id 2) is in use" in line
    # everything bound before the clash was released: the ports are free again
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as again:
        again.bind((HOST, base))


def test_duration_runs_and_exits_zero(tmp_path: Path) -> None:
    base = free_port_block(2)
    proc = subprocess.run(
        swarm_command("sim", "--drones", "2", "--base-port", str(base), "--gcs", "none",
                      "--speedup", "4", "--duration-s", "6"),
        capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=60,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0].startswith("swarm sim: 2 vehicles (system ids 1..2) on UDP 127.0.0.1:")
    status = [line for line in lines if line.startswith("sim ")]
    assert status and "armed 0 flying 0 failsafe 0 crashed 0" in status[-1]
    assert float(status[-1].split("rtf")[1].split("|")[0]) > 0  # (its value depends on load)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signals_stop_it_cleanly(tmp_path: Path, sig: signal.Signals) -> None:
    with sim_process(tmp_path, "--drones", "2", "--gcs", "none") as sim:
        with MavPeer(1, 191, (HOST, sim.base_port)) as agent:
            agent.connect()
        time.sleep(0.3)
        assert sim.stop(sig) == 0
        assert "Traceback" not in sim.stderr()
    for port in (sim.base_port, sim.base_port + 1):  # sockets closed
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind((HOST, port))


def test_quiet_prints_nothing(tmp_path: Path) -> None:
    base = free_port_block(1)
    proc = subprocess.run(
        swarm_command("sim", "--drones", "1", "--base-port", str(base), "--gcs", "none",
                      "--quiet", "--speedup", "10", "--duration-s", "2"),
        capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=60,
    )  # fmt: skip
    assert proc.returncode == 0 and proc.stdout == "" and proc.stderr == ""

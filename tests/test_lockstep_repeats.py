"""Lockstep repeats exactly (issue 14, item 4): two ``swarm up`` runs of the paper scenario log
identical LOCAL_POSITION_NED and ATTITUDE samples for every vehicle over the first 20 s, with
the link cuts at 17 s, field by field at each ``time_boot_ms``, however the machine's load
schedules the processes: one run gives each drone's agent a process of its own
(``--agents-per-process 1 --duration-s 20``), the other hosts the nine in one process, as by
default: ``swarm demo`` (``swarm up scenarios/paper.toml``), the session's demo flight that
tests/test_demo_paper.py judges, whose first 20 s are compared. Each agent waits for every live
drone's round-done marker of the previous round before its tick (drone_agent/process/round_gate.py),
link faults act by message round and draw from per-link seeded generators, and an agent's
commands go before its tick's echo. About a minute beside the demo's flight."""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
from sitl_client import ENV, ROOT, free_port_block, free_udp_port, swarm_command

from gcs.report.tlog import vehicle_samples
from protocols.bus.zenoh_bus import ZenohBus, ZenohSettings, free_loopback_endpoint

pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]
DURATION_S = 20.0  # the paper's link cuts start at 17 s


@pytest.fixture(scope="module")
def rendezvous() -> Iterator[str]:
    """A Zenoh peer both runs meet at (not the default rendezvous port: no lock needed)."""
    endpoint = free_loopback_endpoint()
    with ZenohBus.open(ZenohSettings(listen=(endpoint,))):
        yield endpoint


def _fly(tmp_path: Path, endpoint: str, name: str, *extra: str) -> Path:
    base, gcs_port = free_port_block(9), free_udp_port()
    report = tmp_path / name
    proc = subprocess.run(
        [
            *swarm_command("up", str(ROOT / "scenarios" / "paper.toml")),
            *("--duration-s", str(DURATION_S), "--report", str(report)),
            *("--base-port", str(base), "--gcs-port", str(gcs_port), "--swarm-id", name),
            *("--zenoh-connect", endpoint, *extra),
        ],
        capture_output=True,
        text=True,
        env=ENV,
        cwd=ROOT,
        timeout=600,
    )
    logs = "\n".join(f"{p.name}: {p.read_text()[-1500:]}" for p in (report / "logs").glob("*.log"))
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:] + logs
    return report / "flight.tlog"


def test_two_lockstep_runs_log_identical_vehicle_telemetry(
    tmp_path: Path, rendezvous: str, demo_run: tuple[Path, str]
) -> None:
    hosted = vehicle_samples(_fly(tmp_path, rendezvous, "apart", "--agents-per-process", "1"))
    # hosted (the default): the demo's flight (200 s) up to where the other run's log ends
    end_ms = max(t for _, _, t in hosted)
    assert end_ms >= (DURATION_S - 1.0) * 1e3, end_ms
    apart = {
        k: v for k, v in vehicle_samples(demo_run[0] / "flight.tlog").items() if k[2] <= end_ms
    }
    # every vehicle, both messages, the whole flight (the ground station logs at 25 Hz; a ground
    # station that starts late on a loaded machine misses the first samples of its run)
    expected = 2 * 9 * round(DURATION_S * 25)
    both = hosted.keys() & apart.keys()
    assert len(both) >= 0.95 * expected, len(both)
    assert all(t < 2000 for _, _, t in hosted.keys() ^ apart.keys())
    differ = sorted(k for k in both if hosted[k] != apart[k])
    assert not differ, (len(differ), differ[:3], [(hosted[k], apart[k]) for k in differ[:1]])
    # the flight flew: every drone airborne after 15 s (the plan climbs to 5 m)
    heights = [
        -v[2] for (msg, _, t), v in hosted.items() if msg == "LOCAL_POSITION_NED" and t > 15e3
    ]
    assert min(heights) > 1.0

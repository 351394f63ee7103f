"""Lockstep: with one seed and a scripted client, two runs give identical LOCAL_POSITION_NED
sequences (noisy positions included); another seed gives other ones. Also: simulated time
waits for a slow agent instead of running away from it."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest

from tests.sitl_client import (
    HOST,
    AltitudePD,
    MavPeer,
    Pilot,
    fly,
    free_udp_port,
    of_system,
    sim_process,
)

pytestmark = pytest.mark.timeout(120)
Track = list[tuple[float, ...]]


def _run(tmp_path: Path, seed: int) -> dict[int, Track]:
    gcs = f"udp:{HOST}:{free_udp_port()}"
    args = ("--drones", "3", "--clock", "lockstep", "--wait-agents", "2", "--seed", str(seed),
            "--position-noise-m", "0.02", "--gcs", gcs, "--quiet")  # fmt: skip
    with sim_process(tmp_path, *args) as sim:
        pilots = [
            Pilot(MavPeer(1, 191, (HOST, sim.base_port)), 1, AltitudePD(target_m=1.0)),
            Pilot(MavPeer(2, 191, (HOST, sim.base_port + 1)), 2, AltitudePD(target_m=2.0)),
        ]

        def tilt() -> None:
            pilots[1].roll_rad = 0.1 if pilots[1].flown_s() > 1.0 else 0.0

        fly(pilots, lambda: min(p.flown_s() for p in pilots) >= 3.0, 60, meanwhile=tilt)
        for pilot in pilots:
            pilot.peer.close()
    return {p.sysid: _track(p.messages, p.sysid, 3000) for p in pilots}


def _track(messages: list[Any], sysid: int, until_ms: int) -> Track:
    track: dict[int, tuple[float, ...]] = {}
    for m in of_system(messages, sysid, "LOCAL_POSITION_NED"):
        if m.time_boot_ms <= until_ms:
            track.setdefault(m.time_boot_ms, (m.time_boot_ms, m.x, m.y, m.z, m.vx, m.vy, m.vz))
    return [track[ms] for ms in sorted(track)]


def test_two_runs_with_one_seed_are_identical(tmp_path: Path) -> None:
    first, second = _run(tmp_path, seed=7), _run(tmp_path, seed=7)
    for sysid in (1, 2):
        assert len(first[sysid]) == 151  # every tick from 0 to 3 s
        assert first[sysid] == second[sysid]
    assert -first[2][-1][3] > 1.0  # it really flew
    other = _run(tmp_path, seed=8)
    assert other[1] != first[1]


def test_time_waits_for_a_slow_agent(tmp_path: Path) -> None:
    args = ("--drones", "1", "--clock", "lockstep", "--lockstep-timeout", "5", "--quiet",
            "--gcs", "none")  # fmt: skip
    with sim_process(tmp_path, *args) as sim, MavPeer(1, 191, (HOST, sim.base_port)) as agent:
        agent.connect()
        tick0 = agent.wait_for("LOCAL_POSITION_NED", 5.0)
        assert tick0.time_boot_ms == 0
        agent.setpoint(1, 0, 0.0)  # join with the echo of tick 0
        tick1 = agent.wait_for("LOCAL_POSITION_NED", 5.0, lambda m: m.time_boot_ms > 0)
        assert tick1.time_boot_ms == 20
        time.sleep(1.0)  # a slow agent: one second to answer
        assert not [m for m in agent.poll(0.0) if m.get_type() == "LOCAL_POSITION_NED"
                    and m.time_boot_ms > 20]  # fmt: skip
        agent.setpoint(1, 20, 0.0)
        tick2 = agent.wait_for("LOCAL_POSITION_NED", 5.0, lambda m: m.time_boot_ms > 20)
        assert tick2.time_boot_ms == 40

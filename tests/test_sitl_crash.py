"""Crashes: MAV_CMD_INJECT_FAILURE (all motors off) on vehicle 2 while four vehicles hover; it
falls, hits the ground, goes silent, and 1, 3, 4 fly on. A scenario's crash fault does the same
from the timeline."""

from __future__ import annotations

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


def test_injected_crash_falls_and_goes_silent_while_the_others_fly_on(tmp_path: Path) -> None:
    gcs = MavPeer(255, 190, bind_port=free_udp_port())
    args = ("--drones", "4", "--clock", "lockstep", "--wait-agents", "4", "--quiet",
            "--gcs", f"udp:{HOST}:{gcs.port}")  # fmt: skip
    with gcs, sim_process(tmp_path, *args) as sim:
        pilots = [
            Pilot(MavPeer(i + 1, 191, (HOST, sim.base_port + i)), i + 1, AltitudePD(target_m=2.0))
            for i in range(4)
        ]
        survivors = [pilots[0], pilots[2], pilots[3]]
        fly(pilots, lambda: min(p.flown_s() for p in pilots) >= 5.0, timeout_s=60)
        assert all(abs(p.samples[-1].altitude_m - 2.0) < 0.05 for p in pilots)

        gcs.poll(0.0)
        gcs.command(2, 420, 101, 1, 0)  # FAILURE_UNIT_SYSTEM_MOTOR, FAILURE_TYPE_OFF, all
        crash_ms = pilots[1].samples[-1].time_boot_ms
        to_gcs: list[Any] = []
        fly(pilots, lambda: min(p.flown_s() for p in survivors) >= 10.0, 60,
            lambda: to_gcs.extend(gcs.poll(0.0)))  # fmt: skip
        acks = of_system(to_gcs, 2, "COMMAND_ACK")
        assert [(a.command, a.result) for a in acks] == [(420, 0)]

        victim = pilots[1]
        texts = victim.texts
        assert "Failure injected: all motors off" in texts
        assert any(t.startswith("Crashed: hit the ground at 6.") for t in texts)  # from 2 m
        falling = [s for s in victim.samples if s.time_boot_ms > crash_ms]
        assert falling[-1].altitude_m == 0.0 and len(falling) < 60  # fell in < 1.2 s
        last_word_ms = victim.samples[-1].time_boot_ms
        assert last_word_ms < survivors[0].samples[-1].time_boot_ms - 3000
        assert not victim.peer.poll(0.3)  # silent on its own link and to the ground station
        gcs_last = {
            sysid: max(m.time_boot_ms for m in of_system(to_gcs, sysid, "LOCAL_POSITION_NED"))
            for sysid in (1, 2, 3, 4)
        }
        assert gcs_last[2] <= last_word_ms and gcs_last[1] == gcs_last[3] == gcs_last[4]
        assert gcs_last[2] < gcs_last[3] - 3000
        victim.peer.command(2, 400, 1)
        assert not victim.peer.poll(0.5)  # a wreck answers nothing

        for pilot in survivors:
            after = [s for s in pilot.samples if s.time_boot_ms > crash_ms]
            assert len(after) > 200 and all(abs(s.altitude_m - 2.0) < 0.1 for s in after)
            assert not any(t.startswith(("Failsafe", "Lockstep")) for t in pilot.texts)
        for pilot in pilots:
            pilot.peer.close()


SCENARIO = """
version = 1
name = "two"
duration_s = 30.0
[[drones]]
position_ned_m = [0.0, 0.0, 0.0]
[[drones]]
position_ned_m = [0.0, 3.0, 0.0]
yaw_deg = 90.0
[[trajectory.waypoints]]
t_s = 0.0
centre_ned_m = [0.0, 1.5, 0.0]
spread_m = [1.0, 1.0, 0.0]
[[faults]]
t_s = 1.0
kind = "crash"
drone = 1
"""


def test_scenario_crash_fault_fires_on_time(tmp_path: Path) -> None:
    scenario = tmp_path / "two.toml"
    scenario.write_text(SCENARIO)
    gcs = MavPeer(255, 190, bind_port=free_udp_port())
    args = ("--scenario", str(scenario), "--speedup", "4", "--gcs", f"udp:{HOST}:{gcs.port}")
    with gcs, sim_process(tmp_path, *args, base_port=None) as sim:
        gcs.wait_for("HEARTBEAT", 20.0)
        msgs = gcs.collect(1.5)
        texts = [m for m in of_system(msgs, 2, "STATUSTEXT")]
        assert [t.text for t in texts] == ["Failure injected: all motors off"]
        yaw = of_system(msgs, 2, "ATTITUDE")[0].yaw
        assert yaw == pytest.approx(1.5708, abs=1e-3)  # the scenario's heading
        last = max(m.time_boot_ms for m in of_system(msgs, 2, "ATTITUDE"))
        assert 1000 <= last <= 1100
        later = gcs.collect(1.0)
        assert not of_system(later, 2) and of_system(later, 1, "LOCAL_POSITION_NED")
        assert sim.alive()

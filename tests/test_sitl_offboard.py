"""An agent flies vehicle 1 in OFFBOARD with an altitude PD on SET_ATTITUDE_TARGET and holds 1 m;
then it goes silent: the failsafe levels the vehicle, lands it, disarms it and says so.

Lockstep keeps the flight independent of machine load: the agent echoes every tick, and once it
stops, the simulator drops it from the barrier after 0.5 s of wall time and runs on at 5x.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from tests.sitl_client import HOST, MavPeer, Pilot, fly, free_udp_port, sim_process

pytestmark = pytest.mark.timeout(120)


def test_altitude_hold_then_offboard_loss_failsafe(tmp_path: Path) -> None:
    args = ("--drones", "2", "--clock", "lockstep", "--lockstep-timeout", "0.5", "--speedup", "5",
            "--gcs", f"udp:{HOST}:{free_udp_port()}")  # fmt: skip
    with sim_process(tmp_path, *args) as sim, MavPeer(1, 191, (HOST, sim.base_port)) as peer:
        pilot = Pilot(peer, 1)
        fly([pilot], lambda: pilot.flown_s() >= 14.0, timeout_s=60)
        assert pilot.texts[:2] == ["Armed", "Mode OFFBOARD"]
        assert pilot.offboard_ms is not None
        start = pilot.offboard_ms + 4000
        hold = [s for s in pilot.samples if start <= s.time_boot_ms <= start + 10_000]
        assert len(hold) == 501  # 10 s at 50 Hz
        assert all(abs(s.altitude_m - 1.0) <= 0.1 for s in hold)

        pilot.roll_rad = math.radians(10)  # tilted when the link dies
        fly([pilot], lambda: pilot.flown_s() >= 14.5, timeout_s=10)
        assert pilot.samples[-1].roll_rad > math.radians(8)
        pilot.silent = True
        silent_ms = pilot.samples[-1].time_boot_ms
        fly([pilot], lambda: any("disarmed" in t for t in pilot.texts), timeout_s=30)

        texts = [t for t in pilot.texts if t.startswith(("Failsafe", "Lockstep"))]
        assert texts == [
            "Lockstep: agent silent 0.5 s, left the barrier",
            "Failsafe: offboard lost (0.5 s), level hold",
            "Failsafe: descending to land",
            "Failsafe: landed, disarmed",
        ]
        after = [s for s in pilot.samples if s.time_boot_ms > silent_ms]
        levelled = [s for s in after if silent_ms + 1000 <= s.time_boot_ms <= silent_ms + 1400]
        assert levelled and all(abs(s.roll_rad) < math.radians(1) for s in levelled)
        assert all(s.altitude_m > 0.85 for s in levelled)  # held while level
        assert pilot.samples[-1].altitude_m < 0.01
        # the last word: disarmed in HOLD, on the ground
        heartbeat = peer.wait_for("HEARTBEAT", 10.0)
        assert not heartbeat.base_mode & 128 and heartbeat.custom_mode == (4 << 16) | (3 << 24)
        assert sim.alive()

"""Hostile input: random bytes, truncated and oversized frames, wrong target ids, NaN setpoints.
The simulator keeps running, counts each kind (SYS_STATUS errors_count*), and the vehicle being
flown next door does not notice."""

from __future__ import annotations

import math
import socket
from pathlib import Path

import numpy as np
import pytest

from tests.sitl_client import HOST, MavPeer, Pilot, fly, free_udp_port, of_system, sim_process

pytestmark = pytest.mark.timeout(120)
NAN = float("nan")


class Vandal:
    """Throws a bit of everything at vehicle 2's port (and at the GCS socket) on each call."""

    def __init__(self, peer: MavPeer, gcs_address: tuple[str, int]) -> None:
        self.peer, self.gcs_address = peer, gcs_address
        self.rng = np.random.default_rng(11)
        self.raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.calls = 0

    def __call__(self) -> None:
        self.calls += 1
        peer, rng = self.peer, self.rng
        for size in rng.integers(1, 4000, 3):
            junk = rng.integers(0, 256, int(size), dtype=np.uint8).tobytes()
            peer.send_raw(junk)
            self.raw.sendto(junk, self.gcs_address)
        frame = peer.mav.set_attitude_target_encode(0, 2, 1, 7, [1, 0, 0, 0], 0, 0, 0, 0.9)
        data = frame.pack(peer.mav)
        peer.send_raw(data[: int(rng.integers(1, len(data) - 1))])  # truncated
        peer.send_raw(bytes(600) + data)  # oversized: junk then a frame
        peer.setpoint(2, 0, NAN)  # NaN thrust
        peer.setpoint(2, 0, 0.5, (NAN, 0.0, 0.0, 0.0))  # NaN attitude
        peer.setpoint(2, 0, 1.5)  # thrust out of range
        peer.setpoint(2, 0, 0.5, (3.0, 0.0, 0.0, 0.0))  # not a unit quaternion
        peer.setpoint(3, 0, 0.9)  # vehicle 3's setpoint sent to vehicle 2
        peer.command(7, 400, 1)  # arm vehicle 7 (there is none) on vehicle 2's link
        raw = MavPeer(255, 190, remote=self.gcs_address)
        raw.setpoint(99, 0, 0.5)  # through the GCS link to a system that does not exist
        raw.close()


def test_garbage_is_counted_and_harmless(tmp_path: Path) -> None:
    gcs = MavPeer(255, 190, bind_port=free_udp_port())
    args = ("--drones", "4", "--speedup", "2", "--offboard-timeout", "2",
            "--gcs", f"udp:{HOST}:{gcs.port}")  # fmt: skip
    with gcs, sim_process(tmp_path, *args) as sim:
        gcs.wait_for("HEARTBEAT", 20.0)
        assert gcs.remote is not None
        pilot = Pilot(MavPeer(1, 191, (HOST, sim.base_port)), 1)
        victim = MavPeer(2, 191, (HOST, sim.base_port + 1))
        victim.connect()
        fly([pilot], lambda: pilot.flown_s() >= 4.0, timeout_s=30)

        vandal = Vandal(victim, gcs.remote)
        gcs.collect(0.1)
        fly([pilot], lambda: pilot.flown_s() >= 10.0, timeout_s=30, meanwhile=vandal)
        seen_by_gcs = gcs.collect(0.1)
        assert vandal.calls > 100 and sim.alive()

        # vehicle 1 held its altitude throughout
        assert pilot.offboard_ms is not None
        during = [s for s in pilot.samples if s.time_boot_ms >= pilot.offboard_ms + 4000]
        assert len(during) > 200 and all(abs(s.altitude_m - 1.0) < 0.1 for s in during)
        assert not any(t.startswith("Failsafe") for t in pilot.texts)

        # vehicle 2 counted every kind of rejection, flew nothing, still answers
        latest = victim.collect(1.5)
        status = of_system(latest, 2, "SYS_STATUS")[-1]
        calls = vandal.calls  # (UDP on loopback may drop a little on a loaded machine)
        assert status.errors_count1 >= 0.9 * 3 * calls  # malformed: junk, truncated, oversized
        assert 0.9 * 4 * calls <= status.errors_count2 <= 4 * calls  # NaN, range, norm
        assert 0.9 * 2 * calls <= status.errors_count4 <= 2 * calls  # wrong target system
        assert status.errors_comm >= status.errors_count1 + status.errors_count2
        target = of_system(latest, 2, "ATTITUDE_TARGET")[-1]
        assert target.thrust == 0.0 and all(math.isfinite(v) for v in target.q)
        assert not of_system(latest, 2, "HEARTBEAT")[-1].base_mode & 128

        # vehicles 3 and 4 kept streaming to the ground station
        msgs = gcs.collect(2.0) + seen_by_gcs
        for sysid in (3, 4):
            assert len(of_system(msgs, sysid, "LOCAL_POSITION_NED")) >= 15
        victim.close()
        pilot.peer.close()
    assert "rejected" in sim.stdout()
    rejected = [int(line.split("rejected ")[1].split()[0]) for line in sim.stdout().splitlines()
                if line.startswith("sim ")]  # fmt: skip
    assert max(rejected) > 1000

"""Lockstep notices a dead agent at once: when an agent's socket closes (its process died), the
simulator's next datagram to it comes back as ICMP port unreachable, the vehicle leaves the
barrier and simulated time moves on within a fraction of a second, instead of stalling for the
barrier's wall-clock timeout (2 s); the ground station is told why."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from tests.sitl_client import HOST, AltitudePD, MavPeer, Pilot, fly, free_udp_port, sim_process

pytestmark = pytest.mark.timeout(90)


def test_a_closed_agent_leaves_the_barrier_within_half_a_second(tmp_path: Path) -> None:
    gcs = MavPeer(255, 190, bind_port=free_udp_port())
    args = ("--drones", "2", "--clock", "lockstep", "--wait-agents", "2",
            "--gcs", f"udp:{HOST}:{gcs.port}", "--quiet")  # fmt: skip
    with gcs, sim_process(tmp_path, *args) as sim:
        stays = Pilot(MavPeer(1, 191, (HOST, sim.base_port)), 1, AltitudePD(target_m=1.0))
        dies = Pilot(MavPeer(2, 191, (HOST, sim.base_port + 1)), 2, AltitudePD(target_m=1.0))
        fly([stays, dies], lambda: min(p.flown_s() for p in (stays, dies)) >= 1.0, 60)
        last_ms = stays.samples[-1].time_boot_ms
        dies.peer.close()  # as a killed process's socket closes
        closed = time.monotonic()
        # the survivor keeps answering; simulated time must move on quickly
        fly([stays], lambda: stays.samples[-1].time_boot_ms >= last_ms + 200, 10)
        resumed = time.monotonic() - closed
        texts = [(m.get_srcSystem(), str(m.text)) for m in gcs.collect(0.5)
                 if m.get_type() == "STATUSTEXT"]  # fmt: skip
        stays.peer.close()
    # 10 more ticks (200 ms simulated) within half a second of wall time: no 2 s stall
    assert resumed < 0.5, resumed
    assert (2, "Lockstep: agent gone, left the barrier") in texts, texts

"""MAVLink 2 signing (``--signing-key``): telemetry is signed; unsigned and wrongly signed
setpoints and commands are rejected and counted; signed ones are flown."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tests.sitl_client import (
    HOST,
    FixedThrust,
    MavPeer,
    Pilot,
    fly,
    free_udp_port,
    of_system,
    sim_process,
)

pytestmark = pytest.mark.timeout(120)


def test_only_signed_setpoints_are_flown(tmp_path: Path) -> None:
    key = os.urandom(32)
    key_file = tmp_path / "swarm.key"
    key_file.write_text(key.hex() + "\n")
    gcs = MavPeer(255, 190, bind_port=free_udp_port(), signing_key=key)
    args = ("--drones", "2", "--signing-key", str(key_file), "--offboard-timeout", "2",
            "--gcs", f"udp:{HOST}:{gcs.port}")  # fmt: skip
    with gcs, sim_process(tmp_path, *args) as sim:
        heartbeat = gcs.wait_for("HEARTBEAT", 20.0)
        assert heartbeat.get_signed() and gcs.bad == 0  # telemetry signed with our key
        port = (HOST, sim.base_port)
        law = FixedThrust(0.3)  # below hover: stays on the ground
        pilot = Pilot(MavPeer(1, 191, port, signing_key=key), 1, law)
        unsigned = MavPeer(1, 191, port)
        wrong_key = MavPeer(1, 191, port, signing_key=bytes(32))
        fly([pilot], lambda: pilot.flown_s() >= 0.5, timeout_s=20)

        sent = 0

        def attack() -> None:
            nonlocal sent
            unsigned.setpoint(1, 0, 0.9)
            wrong_key.setpoint(1, 0, 0.8)
            unsigned.command(2, 400, 1)  # arm vehicle 2, unsigned, through vehicle 1's port
            sent += 3

        fly([pilot], lambda: pilot.flown_s() >= 2.5, timeout_s=20, meanwhile=attack)
        seen = len(pilot.messages)
        fly([pilot], lambda: pilot.flown_s() >= 3.7, timeout_s=20)
        latest = pilot.messages[seen:]
        targets = of_system(latest, 1, "ATTITUDE_TARGET")
        assert targets and all(t.thrust == pytest.approx(0.3) for t in targets), (
            [round(t.thrust, 3) for t in targets],
            pilot.texts,
        )
        status = of_system(latest, 1, "SYS_STATUS")[-1]
        assert sent > 50 and 0.9 * sent <= status.errors_count3 <= sent
        assert all(m.get_signed() for m in latest)
        assert not unsigned.poll(0.2) and not wrong_key.poll(0.0)  # nobody answers them
        assert max(s.altitude_m for s in pilot.samples) < 0.01

        law.value = 0.6  # a signed climb
        fly([pilot], lambda: pilot.flown_s() >= 5.0, timeout_s=20)
        assert pilot.samples[-1].altitude_m > 0.3
        gcs.collect(0.1)
        vehicle2 = of_system(gcs.collect(1.2), 2, "HEARTBEAT")
        assert vehicle2 and not vehicle2[-1].base_mode & 128  # never armed by the unsigned one
        for peer in (pilot.peer, unsigned, wrong_key):
            peer.close()

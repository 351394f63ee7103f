"""``swarm sim --drones 2`` over real UDP: every vehicle streams its rotor forces
(ACTUATOR_OUTPUT_STATUS, N) to the GCS at the GCS state rate, stamped with simulated time: zeros
on the ground disarmed, the weight shared by four rotors in a hover; none to an agent unless it
asks. Plus the stream table and the message builder without a process."""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from protocols.model.frames import G_M_S2
from sitl_sim.mavlink_edge.messages import actuator_output_status, rotor_forces_n
from sitl_sim.mavlink_edge.streams import (
    ACTUATOR_OUTPUT_STATUS,
    AGENT_RATES_HZ,
    GCS_RATES_HZ,
    LOCAL_POSITION_NED,
    StreamSchedule,
)
from sitl_sim.physics.attitude_control import AttitudeGains
from sitl_sim.physics.vehicle_params import VehicleParams
from sitl_sim.vehicle.tunables import FleetAttitudeGains
from sitl_sim.vehicle.world import World, WorldConfig
from tests.sitl_client import (
    HOST,
    AltitudePD,
    MavPeer,
    Pilot,
    SimProcess,
    fly,
    free_udp_port,
    of_system,
    sim_process,
)

pytestmark = pytest.mark.timeout(120)
GCS_HZ = 25.0
MASS_KG = VehicleParams().mass_kg


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[SimProcess, MavPeer]]:
    tmp = tmp_path_factory.mktemp("sim2")
    gcs = MavPeer(255, 190, bind_port=free_udp_port())
    args = ("--drones", "2", "--gcs", f"udp:{HOST}:{gcs.port}", "--gcs-rate-hz", f"{GCS_HZ:g}")
    with gcs, sim_process(tmp, *args) as proc:
        gcs.wait_for("HEARTBEAT", 20.0)
        yield proc, gcs


def _forces(msg: Any) -> list[float]:
    return [float(f) for f in msg.actuator[:4]]


def test_gcs_gets_rotor_forces_of_every_vehicle_at_the_state_rate(
    sim: tuple[SimProcess, MavPeer],
) -> None:
    _, gcs = sim
    msgs = gcs.collect(3.0)
    for sysid in (1, 2):
        outputs = of_system(msgs, sysid, "ACTUATOR_OUTPUT_STATUS")
        assert len(outputs) == pytest.approx(3.0 * GCS_HZ, rel=0.25), sysid
        span_s = (outputs[-1].time_usec - outputs[0].time_usec) / 1e6
        assert (len(outputs) - 1) / span_s == pytest.approx(GCS_HZ, rel=0.05)
        for m in outputs:  # disarmed on the ground: every rotor stopped
            assert m.active == 0b1111 and m.get_srcComponent() == 1
            assert _forces(m) == [0.0] * 4 and not any(m.actuator[4:])
        # simulated time, on the clock of time_boot_ms (same ticks at the same rate)
        boot_ms = {m.time_boot_ms for m in of_system(msgs, sysid, "LOCAL_POSITION_NED")}
        stamped = [m.time_usec for m in outputs]
        assert all(t % 1000 == 0 for t in stamped)
        assert len({t // 1000 for t in stamped} & boot_ms) >= len(stamped) - 2


def test_hover_forces_carry_the_weight_and_agents_get_none_by_default(
    sim: tuple[SimProcess, MavPeer],
) -> None:
    proc, gcs = sim
    got: list[Any] = []
    with MavPeer(1, 191, remote=(HOST, proc.base_port)) as peer:
        pilot = Pilot(peer, 1, AltitudePD(target_m=1.0))
        gcs.poll(0.0)
        gcs.collect(0.0)  # drop the backlog
        fly([pilot], lambda: pilot.flown_s() >= 7.0, 60, lambda: got.extend(gcs.poll(0.0)))
        assert pilot.offboard_ms is not None
        assert not [m for m in pilot.messages if m.get_type() == "ACTUATOR_OUTPUT_STATUS"]
        hover_from_us = (pilot.offboard_ms + 4000) * 1000
        flying = of_system(got, 1, "ACTUATOR_OUTPUT_STATUS")
        hovering = [m for m in flying if m.time_usec >= hover_from_us]
        assert len(hovering) >= 2 * GCS_HZ
        for m in hovering:
            forces = _forces(m)
            assert all(math.isfinite(f) and f > 0.0 for f in forces)
            assert sum(forces) == pytest.approx(MASS_KG * G_M_S2, rel=0.05)
            assert max(forces) - min(forces) < 0.05 * sum(forces)  # level: shared evenly
        grounded = of_system(got, 2, "ACTUATOR_OUTPUT_STATUS")
        assert grounded and all(_forces(m) == [0.0] * 4 for m in grounded)

        peer.command(1, 511, ACTUATOR_OUTPUT_STATUS, 100_000)  # an agent may ask: 10 Hz
        assert peer.ack(511) == 0
        peer.wait_for("ACTUATOR_OUTPUT_STATUS", 5.0)


def test_stream_defaults() -> None:
    assert GCS_RATES_HZ[ACTUATOR_OUTPUT_STATUS] == GCS_RATES_HZ[LOCAL_POSITION_NED]
    agent = StreamSchedule(AGENT_RATES_HZ, 50)
    assert agent.interval_us(ACTUATOR_OUTPUT_STATUS) == -1  # off, but streamable on request
    assert all(ACTUATOR_OUTPUT_STATUS not in agent.due(k) for k in range(100))
    assert agent.set_interval_us(ACTUATOR_OUTPUT_STATUS, 20_000)
    assert ACTUATOR_OUTPUT_STATUS in agent.due(100)


def test_world_rotor_forces_and_message() -> None:
    """The forces are those the last physics step applied: none before the first step and while
    disarmed; c w^2 of the applied rotor speeds after (the hover check flies a real process)."""
    params = VehicleParams()
    positions = np.array([[0.0, 0.0, -5.0], [2.0, 0.0, 0.0]])
    gains = FleetAttitudeGains(AttitudeGains(), 2)
    world = World(params, gains, positions, np.zeros(2), WorldConfig(), np.random.default_rng(0))
    assert rotor_forces_n(world).shape == (4, 2) and not rotor_forces_n(world).any()
    world.step()
    assert not rotor_forces_n(world).any()  # disarmed: motors stopped
    hover_speed = np.sqrt(params.weight_n / 4 / params.thrust_coeff)
    world.rotor_speed_rad_s = np.full((4, 2), hover_speed)
    forces = rotor_forces_n(world)
    np.testing.assert_allclose(forces.sum(axis=0), params.weight_n, rtol=1e-9)
    msg = actuator_output_status(1_020_000, forces[:, 1]).message()
    assert msg.time_usec == 1_020_000 and msg.active == 0b1111
    np.testing.assert_allclose(msg.actuator[:4], forces[:, 1], rtol=1e-6)
    assert msg.actuator[4:] == [0.0] * 28

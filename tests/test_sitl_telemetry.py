"""``swarm sim --drones 4`` over real UDP: heartbeats of every vehicle on the GCS port, telemetry
at the requested rates on each vehicle's port, and the autopilot services (commands, parameters,
AUTOPILOT_VERSION, TIMESYNC)."""

from __future__ import annotations

import select
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.sitl_client import HOST, MavPeer, SimProcess, free_udp_port, of_system, sim_process

pytestmark = pytest.mark.timeout(120)
N = 4
ATTITUDE, LOCAL_POSITION_NED = 30, 32


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[SimProcess, MavPeer]]:
    tmp = tmp_path_factory.mktemp("sim4")
    gcs = MavPeer(255, 190, bind_port=free_udp_port())
    with gcs, sim_process(tmp, "--drones", str(N), "--gcs", f"udp:{HOST}:{gcs.port}") as proc:
        gcs.wait_for("HEARTBEAT", 20.0)
        yield proc, gcs


def _agents(proc: SimProcess) -> list[MavPeer]:
    agents = [MavPeer(i + 1, 191, remote=(HOST, proc.base_port + i)) for i in range(N)]
    for agent in agents:
        agent.connect()
    return agents


def _collect(peers: list[MavPeer], seconds: float) -> list[list[Any]]:
    """Messages each peer receives during ``seconds`` of wall time."""
    for peer in peers:
        peer.poll(0.0)  # drop the backlog
    got: list[list[Any]] = [[] for _ in peers]
    end = time.monotonic() + seconds
    while (left := end - time.monotonic()) > 0:
        ready, _, _ = select.select([p.sock for p in peers], [], [], left)
        for k, peer in enumerate(peers):
            if peer.sock in ready:
                got[k] += peer.poll(0.0)
    return got


def test_gcs_sees_heartbeats_of_every_vehicle(sim: tuple[SimProcess, MavPeer]) -> None:
    _, gcs = sim
    msgs = gcs.collect(2.5)
    heartbeats = [m for m in msgs if m.get_type() == "HEARTBEAT"]
    assert {m.get_srcSystem() for m in heartbeats} == {1, 2, 3, 4}
    for m in heartbeats:
        assert m.type == 2 and m.autopilot == 12 and m.get_srcComponent() == 1  # quad, PX4
        assert m.custom_mode == (4 << 16) | (3 << 24)  # AUTO.LOITER = HOLD
    kinds = {m.get_type() for m in of_system(msgs, 3)}
    assert {"SYS_STATUS", "ATTITUDE", "LOCAL_POSITION_NED", "ATTITUDE_TARGET"} <= kinds


def test_telemetry_arrives_at_the_requested_rates(sim: tuple[SimProcess, MavPeer]) -> None:
    proc, gcs = sim
    agents = _agents(proc)
    try:
        agents[1].command(2, 511, ATTITUDE, 50_000)  # 20 Hz on vehicle 2's link
        assert agents[1].ack(511) == 0
        agents[2].command(3, 511, LOCAL_POSITION_NED, 100_000)  # 10 Hz on vehicle 3's link
        assert agents[2].ack(511) == 0
        seconds = 4.0
        got = _collect([*agents, gcs], seconds)
        expected = {  # (vehicle, message) -> Hz
            (0, "ATTITUDE"): 50, (0, "LOCAL_POSITION_NED"): 50,
            (1, "ATTITUDE"): 20, (1, "LOCAL_POSITION_NED"): 50,
            (2, "ATTITUDE"): 50, (2, "LOCAL_POSITION_NED"): 10,
            (3, "HEARTBEAT"): 1,
        }  # fmt: skip
        for (i, kind), rate in expected.items():
            msgs = of_system(got[i], i + 1, kind)
            assert len(msgs) == pytest.approx(rate * seconds, rel=0.1, abs=1), (i, kind)
            if kind != "HEARTBEAT":  # the same in simulated time
                span_s = (msgs[-1].time_boot_ms - msgs[0].time_boot_ms) / 1000
                assert (len(msgs) - 1) / span_s == pytest.approx(rate, rel=0.1)
        for sysid in range(1, N + 1):  # the GCS default, unchanged by the agents' requests
            msgs = of_system(got[N], sysid, "LOCAL_POSITION_NED")
            assert len(msgs) == pytest.approx(10 * seconds, rel=0.1, abs=1)
    finally:
        for agent in agents:
            agent.close()


def test_commands_parameters_and_version(sim: tuple[SimProcess, MavPeer]) -> None:
    proc, _ = sim
    with MavPeer(4, 191, remote=(HOST, proc.base_port + 3)) as agent:
        agent.command(4, 512, 148)  # REQUEST_MESSAGE AUTOPILOT_VERSION
        assert agent.ack(512) == 0
        version = agent.wait_for("AUTOPILOT_VERSION")
        assert version.uid == 4 and version.capabilities & 64  # SET_ATTITUDE_TARGET
        agent.command(4, 31000)  # a command this autopilot does not have
        assert agent.ack(31000) == 3  # UNSUPPORTED, not silence
        agent.command(4, 176, 1, 3)  # POSCTL: not available
        assert agent.ack(176) == 2
        agent.wait_for("STATUSTEXT", where=lambda m: "Mode change denied" in m.text)

        agent.send(agent.mav.param_request_list_encode(4, 1))
        values = [agent.wait_for("PARAM_VALUE") for _ in range(3)]
        count = values[0].param_count
        values += [agent.wait_for("PARAM_VALUE") for _ in range(count - 3)]
        names = {v.param_id for v in values}
        assert len(names) == count and {"COM_OF_LOSS_T", "ATT_ROLL_KP", "MAV_SYS_ID"} <= names
        agent.send(agent.mav.param_set_encode(4, 1, b"COM_OF_LOSS_T", 1.25, 9))
        value = agent.wait_for("PARAM_VALUE", where=lambda m: m.param_id == "COM_OF_LOSS_T")
        assert value.param_value == pytest.approx(1.25)
        agent.send(agent.mav.param_set_encode(4, 1, b"COM_OF_LOSS_T", -3.0, 9))
        value = agent.wait_for("PARAM_VALUE", where=lambda m: m.param_id == "COM_OF_LOSS_T")
        assert value.param_value == pytest.approx(1.25)  # refused: unchanged
        agent.send(agent.mav.param_request_read_encode(4, 1, b"MAV_SYS_ID", -1))
        value = agent.wait_for("PARAM_VALUE", where=lambda m: m.param_id == "MAV_SYS_ID")
        assert value.param_value == 4.0

        agent.send(agent.mav.command_int_encode(4, 1, 0, 512, 0, 0, 148, 0, 0, 0, 0, 0, 0))
        assert agent.ack(512) == 0  # COMMAND_INT is answered the same way
        assert agent.wait_for("AUTOPILOT_VERSION").uid == 4
        land = (4 << 16) | (6 << 24)  # PX4 AUTO.LAND through the SET_MODE message
        agent.send(agent.mav.set_mode_encode(4, 1, land))
        agent.wait_for("HEARTBEAT", where=lambda m: m.custom_mode == land)
        agent.send(agent.mav.set_mode_encode(4, 1, (4 << 16) | (3 << 24)))

        agent.send(agent.mav.timesync_encode(0, 777))
        sync = agent.wait_for("TIMESYNC", where=lambda m: m.ts1 == 777)
        assert sync.tc1 > 0


def test_status_line_every_second(sim: tuple[SimProcess, MavPeer], tmp_path: Path) -> None:
    proc, _ = sim
    lines = [line for line in proc.stdout().splitlines() if line.startswith("sim ")]
    assert len(lines) >= 2
    assert "rtf" in lines[-1] and "armed" in lines[-1] and "rejected" in lines[-1]
    assert proc.stdout().startswith("swarm sim: 4 vehicles (system ids 1..4)")

"""Map-ready telemetry: a ground station on ``swarm sim``'s GCS port gets each vehicle's home (on
request, MAV_CMD_GET_HOME_POSITION and REQUEST_MESSAGE), global position consistent with its
LOCAL_POSITION_NED, a 3-D GPS fix, its landed state and its battery; an agent link asks for the
global position through the message-interval protocol. Then the same builders without sockets:
the landed states of a flight's phases, the battery, the default rates and phases."""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from protocols.model.geodesy import GeoPoint, ned_to_geodetic
from sitl_sim.mavlink_edge.map_telemetry import landed_state
from sitl_sim.mavlink_edge.messages import RxCounters, sys_status
from sitl_sim.mavlink_edge.streams import (
    EXTENDED_SYS_STATE,
    GCS_RATES_HZ,
    GLOBAL_POSITION_INT,
    GPS_RAW_INT,
    HOME_POSITION,
    StreamSchedule,
)
from sitl_sim.vehicle.autopilot import Autopilot, AutopilotConfig, Mode
from sitl_sim.vehicle.battery import Battery
from sitl_sim.vehicle.world import Snapshot
from tests.sitl_client import HOST, MavPeer, SimProcess, free_udp_port, of_system, sim_process

HOME = GeoPoint(-33.8568, 151.2153, 42.5)
START_NED = ((10.0, -20.0, 0.0), (12.0, -20.0, 0.0), (-300.0, 400.0, 0.0))
SCENARIO = f"""
version = 1
duration_s = 60.0
[home]
lat_deg = {HOME.lat_deg}
lon_deg = {HOME.lon_deg}
alt_m = {HOME.alt_m}
{"".join(f"[[drones]]{chr(10)}position_ned_m = {list(p)}{chr(10)}" for p in START_NED)}
[[trajectory.waypoints]]
t_s = 0.0
centre_ned_m = [0.0, 0.0, -2.0]
variance_m2 = [0.0, 0.0, 0.0]
[safety]
min_separation_m = 0.0
"""


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[SimProcess, MavPeer]]:
    tmp = tmp_path_factory.mktemp("simmap")
    scenario = tmp / "home.toml"
    scenario.write_text(SCENARIO)
    gcs = MavPeer(255, 190, bind_port=free_udp_port())
    with (
        gcs,
        sim_process(tmp, "--scenario", str(scenario), "--gcs", f"udp:{HOST}:{gcs.port}") as proc,
    ):
        gcs.wait_for("HEARTBEAT", 20.0)
        yield proc, gcs


def _home_matches(msg: Any) -> None:
    assert msg.latitude == round(HOME.lat_deg * 1e7)
    assert msg.longitude == round(HOME.lon_deg * 1e7)
    assert msg.altitude == round(HOME.alt_m * 1000)
    assert (msg.x, msg.y, msg.z) == (0.0, 0.0, 0.0)


@pytest.mark.timeout(60)
def test_home_position_on_request(sim: tuple[SimProcess, MavPeer]) -> None:
    _, gcs = sim
    gcs.command(2, mavlink.MAV_CMD_GET_HOME_POSITION)
    assert gcs.ack(mavlink.MAV_CMD_GET_HOME_POSITION) == mavlink.MAV_RESULT_ACCEPTED
    _home_matches(gcs.wait_for("HOME_POSITION", where=lambda m: m.get_srcSystem() == 2))
    gcs.command(3, mavlink.MAV_CMD_REQUEST_MESSAGE, HOME_POSITION)
    assert gcs.ack(mavlink.MAV_CMD_REQUEST_MESSAGE) == mavlink.MAV_RESULT_ACCEPTED
    _home_matches(gcs.wait_for("HOME_POSITION", where=lambda m: m.get_srcSystem() == 3))


@pytest.mark.timeout(60)
def test_gcs_gets_each_vehicle_on_the_map(sim: tuple[SimProcess, MavPeer]) -> None:
    _, gcs = sim
    msgs = gcs.collect(2.2)
    for k, start in enumerate(START_NED):
        sysid = k + 1
        globals_ = of_system(msgs, sysid, "GLOBAL_POSITION_INT")
        assert 8 <= len(globals_) <= 13, len(globals_)  # 5 Hz
        local = {m.time_boot_ms: m for m in of_system(msgs, sysid, "LOCAL_POSITION_NED")}
        paired = [(g, local[g.time_boot_ms]) for g in globals_ if g.time_boot_ms in local]
        assert len(paired) >= 5, "GLOBAL_POSITION_INT and LOCAL_POSITION_NED share ticks"
        for g, lpn in paired:
            lat, lon, alt = ned_to_geodetic(HOME, np.array([[lpn.x, lpn.y, lpn.z]]))
            assert abs(g.lat - lat[0] * 1e7) <= 1 and abs(g.lon - lon[0] * 1e7) <= 1
            assert abs(g.alt - alt[0] * 1000) <= 1 and abs(g.relative_alt + lpn.z * 1000) <= 1
            assert (g.vx, g.vy, g.vz) == (0, 0, 0) and g.hdg == 0
        assert lpn.x == pytest.approx(start[0], abs=1e-3)  # where the scenario put it
        gps = of_system(msgs, sysid, "GPS_RAW_INT")
        assert 1 <= len(gps) <= 3
        assert gps[0].fix_type == mavlink.GPS_FIX_TYPE_3D_FIX and gps[0].satellites_visible > 6
        assert abs(gps[0].lat - g.lat) <= 1 and gps[0].alt == g.alt
        (state, *_) = of_system(msgs, sysid, "EXTENDED_SYS_STATE")
        assert state.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND
        status = of_system(msgs, sysid, "SYS_STATUS")[0]
        assert status.voltage_battery == 12600 and status.battery_remaining == 100
        assert status.current_battery == 0  # disarmed
        assert len(of_system(msgs, sysid, "HOME_POSITION")) in (1, 2, 3)  # 1 Hz


@pytest.mark.timeout(60)
def test_agent_link_asks_for_the_global_position(sim: tuple[SimProcess, MavPeer]) -> None:
    proc, _ = sim
    with MavPeer(1, 191, remote=(HOST, proc.base_port)) as agent:
        agent.connect()
        assert not of_system(agent.collect(0.5), 1, "GLOBAL_POSITION_INT")  # off by default
        agent.command(1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, GLOBAL_POSITION_INT, 50_000)
        assert agent.ack(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL) == mavlink.MAV_RESULT_ACCEPTED
        assert 15 <= len(of_system(agent.collect(1.0), 1, "GLOBAL_POSITION_INT")) <= 25
        agent.command(1, mavlink.MAV_CMD_GET_MESSAGE_INTERVAL, GLOBAL_POSITION_INT)
        assert agent.wait_for("MESSAGE_INTERVAL").interval_us == 50_000  # 2.5 ticks, met on average
        agent.command(1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, GLOBAL_POSITION_INT, -1)
        assert agent.ack(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL) == mavlink.MAV_RESULT_ACCEPTED


# -- without sockets --------------------------------------------------------------------------
def _snapshot(z_m: float, vz_m_s: float) -> Snapshot:
    return Snapshot(0, 0, [[0.0, 0.0, z_m]], [[0.0, 0.0, vz_m_s]], [[0.0] * 3], [[0.0] * 3])


def test_landed_state_through_a_flight() -> None:
    ap = Autopilot(1, AutopilotConfig(), np.zeros(1))
    assert landed_state(ap, _snapshot(0.0, 0.0), 0) == mavlink.MAV_LANDED_STATE_ON_GROUND
    ap.armed[0], ap.landed[0] = True, False
    ap.mode[0] = Mode.OFFBOARD
    assert landed_state(ap, _snapshot(-0.5, -1.0), 0) == mavlink.MAV_LANDED_STATE_TAKEOFF
    assert landed_state(ap, _snapshot(-0.5, 0.0), 0) == mavlink.MAV_LANDED_STATE_IN_AIR
    assert landed_state(ap, _snapshot(-3.0, -1.0), 0) == mavlink.MAV_LANDED_STATE_IN_AIR
    ap.mode[0] = Mode.LAND
    assert landed_state(ap, _snapshot(-3.0, 0.5), 0) == mavlink.MAV_LANDED_STATE_LANDING


def test_battery_drains_with_thrust_and_reports_in_sys_status() -> None:
    battery = Battery(2)
    armed = np.array([True, False])
    for _ in range(50 * 60):  # a minute at 50 Hz, vehicle 0 hovering on 3.3 N
        battery.drain(armed, np.array([3.3, 0.0]), 0.02)
    hover_a = 0.5 + 1.2 * 3.3
    assert battery.current_a[0] == pytest.approx(hover_a)
    used = hover_a * 60 / (1500 * 3.6)
    assert battery.remaining() == pytest.approx([1 - used, 1.0])
    ap = Autopilot(2, AutopilotConfig(), np.zeros(2))
    msg = sys_status(ap, 0, RxCounters(), 0.0, battery)
    assert msg.current_battery == round(100 * hover_a)
    assert msg.battery_remaining == round(100 * (1 - used))
    expected_v = 3 * (3.5 + 0.7 * (1 - used)) - 0.05 * hover_a
    assert msg.voltage_battery == round(1000 * expected_v)
    assert sys_status(ap, 1, RxCounters(), 0.0, battery).voltage_battery == 12600
    unknown = sys_status(ap, 1, RxCounters(), 0.0)
    assert (unknown.voltage_battery, unknown.battery_remaining) == (0xFFFF, -1)


def test_map_messages_default_rates_and_phases() -> None:
    schedule = StreamSchedule(GCS_RATES_HZ, 50)
    first: dict[int, int] = {}
    counts: dict[int, int] = {}
    for tick in range(500):
        for msg_id in schedule.due(tick):
            first.setdefault(msg_id, tick)
            counts[msg_id] = counts.get(msg_id, 0) + 1
    assert counts[GLOBAL_POSITION_INT] == 50
    assert counts[GPS_RAW_INT] == counts[HOME_POSITION] == counts[EXTENDED_SYS_STATE] == 10
    one_hz = [first[m] for m in (0, 1, GPS_RAW_INT, HOME_POSITION, EXTENDED_SYS_STATE)]
    assert sorted(one_hz) == [0, 0, 12, 25, 37], "the fleet's 1 Hz messages spread over a second"
    assert math.isclose(first[GLOBAL_POSITION_INT], 5)

"""The agents' autopilot dialects (drone_agent/process/dialects.py), the ArduCopter side of the
vehicle link (drone_agent/process/vehicle_link.py: GLOBAL_POSITION_INT about the swarm's origin,
pairing by time, listening for an ArduCopter SITL's udpclient) and the swarm clock
(protocols/mavlink/swarm_clock.py), with a real UDP peer speaking as an ArduCopter would."""

from __future__ import annotations

import math
import os
import socket
import time
from typing import Any

import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as apm

from drone_agent.process.dialects import FS_GCS_LAND, ArduCopterDialect, Px4Dialect, make_dialect
from drone_agent.process.vehicle_link import VehicleLink
from protocols.mavlink.conventions import (
    EKF_READY_FLAGS,
    GUID_OPTIONS_THRUST,
    MODE_OFFBOARD,
    SYS_STATUS_PREARM_CHECK,
    CopterMode,
    Dialect,
)
from protocols.mavlink.swarm_clock import VehicleClock
from protocols.model.geodesy import GeoPoint, geodetic_to_ned, ned_to_geodetic


class _Io:
    """Records what a dialect asks of its link."""

    def __init__(self) -> None:
        self.sent: list[tuple[str, Any]] = []

    def command(self, *args: float) -> None:
        self.sent.append(("command", args))

    def request_interval(self, message_id: int, rate_hz: float) -> None:
        self.sent.append(("interval", (message_id, rate_hz)))

    def param_set(self, name: str, value: float) -> None:
        self.sent.append(("set", (name, value)))

    def param_read(self, name: str) -> None:
        self.sent.append(("read", name))


def _codec(sysid: int = 1) -> Any:
    return apm.MAVLink(None, srcSystem=sysid, srcComponent=1)


def _param(name: str, value: float) -> Any:
    return _codec().param_value_encode(name.encode(), value, 9, 1, 0)


def _ekf(flags: int) -> Any:
    return _codec().ekf_status_report_encode(flags, 0, 0, 0, 0, 0)


def _ready(d: ArduCopterDialect, sysid: int = 1) -> None:
    mav = _codec()
    d.on_message("EKF_STATUS_REPORT", _ekf(EKF_READY_FLAGS | 0x300))
    d.on_message("GPS_RAW_INT", mav.gps_raw_int_encode(0, 3, 0, 0, 0, 0, 0, 0, 0, 10))
    bit = SYS_STATUS_PREARM_CHECK
    d.on_message("SYS_STATUS", mav.sys_status_encode(bit, bit, bit, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0))
    d.on_message("PARAM_VALUE", _param("GUID_OPTIONS", GUID_OPTIONS_THRUST))
    d.on_message("PARAM_VALUE", _param("MOT_THST_HOVER", 0.39))
    d.on_message("PARAM_VALUE", _param("MAV_GCS_SYSID", sysid))
    d.on_message("PARAM_VALUE", _param("FS_GCS_ENABLE", FS_GCS_LAND))


def test_px4_dialect_is_the_projects_own() -> None:
    d = make_dialect(Dialect.PX4, 2.0, 50.0)
    assert isinstance(d, Px4Dialect) and d.ready and not d.global_frame
    assert d.modes(MODE_OFFBOARD).in_offboard
    assert d.wire_thrust(0.4, 0.3, 0.2) == 0.4


def test_ardupilot_readiness_names_what_is_missing_until_all_is_confirmed() -> None:
    d = ArduCopterDialect(thrust_to_weight=2.0, sysid=3)
    assert not d.ready and "EKF" in d.not_ready_reason
    d.on_message("EKF_STATUS_REPORT", _ekf(0xA7))
    assert "EKF not ready (flags 0xa7)" in d.not_ready_reason  # ArduCopter before GPS is used
    _ready(d, sysid=3)
    assert d.ready, d.not_ready_reason
    d.on_message("PARAM_VALUE", _param("FS_GCS_ENABLE", 0))  # someone turned it off
    assert "failsafe" in d.not_ready_reason
    d.on_message("PARAM_VALUE", _param("FS_GCS_ENABLE", FS_GCS_LAND))
    d.on_message("EKF_STATUS_REPORT", _ekf(EKF_READY_FLAGS | 0x8000))
    assert "EKF" in d.not_ready_reason  # a GPS glitch


def test_ardupilot_setup_keeps_the_users_guid_options_bits_and_retries_until_confirmed() -> None:
    d = ArduCopterDialect(thrust_to_weight=2.0, sysid=4)
    io = _Io()
    d.service(io, 0.0)
    assert ("read", "GUID_OPTIONS") in io.sent and ("read", "MOT_THST_HOVER") in io.sent
    assert ("set", ("MAV_GCS_SYSID", 4.0)) in io.sent and ("set", ("FS_GCS_ENABLE", 5.0)) in io.sent
    assert ("interval", (33, 50.0)) in io.sent and ("interval", (30, 50.0)) in io.sent
    d.on_message("PARAM_VALUE", _param("GUID_OPTIONS", 1))  # the user's bit 0
    io.sent.clear()
    d.service(io, 0.5)  # not due yet
    assert not any(kind == "set" and args[0] == "GUID_OPTIONS" for kind, args in io.sent)
    d.service(io, 1.5)
    assert ("set", ("GUID_OPTIONS", float(1 | GUID_OPTIONS_THRUST))) in io.sent
    d.on_message("PARAM_VALUE", _param("GUID_OPTIONS", 1 | GUID_OPTIONS_THRUST))
    io.sent.clear()
    d.service(io, 3.0)
    assert not any(args[0] == "GUID_OPTIONS" for _, args in io.sent if isinstance(args, tuple))


def test_ardupilot_thrust_is_hover_scaled_and_leaves_the_angle_boost_to_the_autopilot() -> None:
    d = ArduCopterDialect(thrust_to_weight=2.0)
    _ready(d)
    # hover: half the scenario vehicle's maximum = its weight -> MOT_THST_HOVER, level
    assert d.wire_thrust(0.5, 0.0, 0.0) == pytest.approx(0.39)
    # tilted 30 deg in roll with 1/cos(30) of the weight: ArduCopter boosts by 1/cos again
    tilt = math.radians(30.0)
    assert d.wire_thrust(0.5 / math.cos(tilt), tilt, 0.0) == pytest.approx(0.39)
    assert d.wire_thrust(5.0, 0.0, 0.0) == 1.0 and d.wire_thrust(-1.0, 0.0, 0.0) == 0.0
    m = d.modes(int(CopterMode.GUIDED_NOGPS))
    assert m.in_offboard and not m.in_land
    assert d.modes(int(CopterMode.LAND)).in_land and d.modes(int(CopterMode.BRAKE)).in_hold
    assert d.offboard_command() == (176, (1.0, 20.0))


def test_geodetic_to_ned_inverts_ned_to_geodetic_within_a_tenth_of_a_millimetre() -> None:
    home = GeoPoint()
    rng = np.random.default_rng(1)
    ned = rng.uniform(-1000.0, 1000.0, size=(200, 3))
    ned[:, 2] = rng.uniform(-120.0, 0.0, size=200)
    lat, lon, alt = ned_to_geodetic(home, ned)
    assert np.abs(geodetic_to_ned(home, lat, lon, alt) - ned).max() < 1e-4


def test_vehicle_clock_follows_the_least_delayed_message_and_a_reboot() -> None:
    wall = [1000.0]
    clock = VehicleClock(epoch_s=990.0, wall=lambda: wall[0])
    # vehicle booted at swarm time 4 s: stamps 0, 20, ... ms arrive 5-30 ms late
    for k, late_ms in enumerate([30, 5, 12, 30, 8]):
        boot_ms = 6000 + 20 * k
        wall[0] = 990.0 + (4000 + boot_ms + late_ms) / 1000.0
        got = clock.swarm_ms(boot_ms)
    assert got == 4000 + boot_ms + 5  # the least delayed so far sets the offset
    wall[0] += 10.0
    assert clock.swarm_ms(100) == round((wall[0] - 990.0) * 1000.0) - 0  # rebooted: starts anew


class _FakeArduCopter:
    """A UDP peer that speaks to a listening vehicle link as ArduCopter SITL's udpclient does."""

    def __init__(self, port: int, sysid: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.settimeout(1.0)
        self.address = ("127.0.0.1", port)
        self.mav = _codec(sysid)

    def send(self, msg: Any) -> None:
        self.sock.sendto(msg.pack(self.mav), self.address)

    def received(self) -> list[Any]:
        out = []
        self.sock.settimeout(0.2)
        try:
            while True:
                data = self.sock.recv(65535)
                out += self.mav.parse_buffer(data) or []
        except (TimeoutError, OSError):
            pass
        return out


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _poll(link: VehicleLink, until: float = 1.0) -> list[Any]:
    end = time.monotonic() + until
    samples: list[Any] = []
    while time.monotonic() < end:
        samples += link.poll()
        time.sleep(0.01)
    return samples


def test_a_listening_link_learns_ardupilot_from_the_heartbeat_and_flies_the_swarm_frame() -> None:
    port = _free_udp_port()
    home = GeoPoint(47.397742, 8.545594, 488.0)
    link = VehicleLink(2, "127.0.0.1", port, dialect=None, origin=home, listen=True)
    peer = _FakeArduCopter(port, sysid=3)
    try:
        # this vehicle started 6 m north, 3 m east of the swarm's origin, 2 m up
        lat, lon, alt = ned_to_geodetic(home, np.array([[6.0, 3.0, -2.0]]))
        gpi = peer.mav.global_position_int_encode(
            5020, round(lat[0] * 1e7), round(lon[0] * 1e7), round(alt[0] * 1000), 2000,
            150, -50, 10, 9000,
        )  # fmt: skip
        # its own EKF origin is where it started: LOCAL_POSITION_NED says (0, 0, -2)
        peer.send(peer.mav.local_position_ned_encode(5020, 0.0, 0.0, -2.0, 1.5, -0.5, 0.1))
        peer.send(gpi)  # before the heartbeat: which frame is not known, no sample
        assert _poll(link, 0.2) == []
        peer.send(peer.mav.heartbeat_encode(2, 3, 1, int(CopterMode.BRAKE), 3))
        assert _poll(link, 0.2) == [] and link.dialect.name == Dialect.ARDUPILOT
        peer.send(peer.mav.local_position_ned_encode(5040, 0.0, 0.0, -2.0, 1.5, -0.5, 0.1))
        peer.send(peer.mav.attitude_encode(5031, 0.1, -0.2, 0.3, 0, 0, 0))  # 9 ms off: paired
        peer.send(gpi)
        samples = _poll(link, 0.3)
        assert len(samples) == 1
        s = samples[0]
        assert s.time_boot_ms == 5020
        assert np.allclose(s.position_ned_m, [6.0, 3.0, -2.0], atol=0.01)  # degE7: 1 cm
        assert np.allclose(s.velocity_ned_m_s, [1.5, -0.5, 0.1])
        assert np.allclose(s.euler_rad, [0.1, -0.2, 0.3])
        assert link.modes().in_hold
        # far apart in time: no pair
        peer.send(peer.mav.attitude_encode(5200, 0.0, 0.0, 0.0, 0, 0, 0))
        peer.send(peer.mav.global_position_int_encode(5300, 0, 0, 0, 0, 0, 0, 0, 0))
        assert _poll(link, 0.3) == []
        # the link answers whoever spoke: the mode command reaches the peer
        link.set_offboard()
        got = [m for m in peer.received() if m.get_type() == "COMMAND_LONG"]
        assert got and got[0].command == 176 and got[0].param2 == float(CopterMode.GUIDED_NOGPS)
    finally:
        link.close()
        peer.sock.close()


def test_auto_dialect_with_a_px4_heartbeat_keeps_local_position() -> None:
    port = _free_udp_port()
    peer_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer_sock.bind(("127.0.0.1", port))
    link = VehicleLink(0, "127.0.0.1", port, dialect=None)
    try:
        link.send_heartbeat()
        _, agent_addr = peer_sock.recvfrom(65535)
        mav = _codec(1)
        for msg in (
            mav.heartbeat_encode(2, 12, 1, MODE_OFFBOARD, 3),
            mav.local_position_ned_encode(40, 1.0, 2.0, -3.0, 0.0, 0.0, 0.0),
            mav.attitude_encode(40, 0.0, 0.0, 0.5, 0, 0, 0),
        ):
            peer_sock.sendto(msg.pack(mav), agent_addr)
        samples = _poll(link, 0.3)
        assert link.dialect.name == Dialect.PX4 and len(samples) == 1
        assert np.allclose(samples[0].position_ned_m, [1.0, 2.0, -3.0])
        assert link.in_offboard
    finally:
        link.close()
        peer_sock.close()


def _hover_flight(d: ArduCopterDialect, true_hover: float, z0: float, seconds: float) -> float:
    """A vehicle whose real hover throttle is ``true_hover`` held at 5 m by a PD altitude loop
    (as the paper's controller, kp 1, kd 1.5) through the dialect, velocities in whole cm/s as
    GLOBAL_POSITION_INT has them, a 50 ms motor lag; its altitude error (m) at the end."""
    g, dt = 9.80665, 0.02
    up, vz, thrust = z0, 0.0, true_hover
    for k in range(int(seconds / dt)):
        accel = g + 1.0 * (5.0 - up) - 1.5 * vz
        sent = d.wire_thrust(accel / g / d.thrust_to_weight, 0.0, 0.0)
        thrust += (sent - thrust) * dt / 0.05
        vz += g * (thrust / true_hover - 1.0) * dt
        up += vz * dt
        d.on_sample(20 * k, -round(vz * 100) / 100, 0.0, 0.0, armed=True)
    return up - 5.0


def test_ardupilot_learns_the_hover_throttle_from_what_the_throttle_did() -> None:
    d = ArduCopterDialect(thrust_to_weight=2.0, control_hz=50.0)
    _ready(d)  # MOT_THST_HOVER 0.39
    error = _hover_flight(d, true_hover=0.42, z0=5.0, seconds=20.0)
    assert d.hover == pytest.approx(0.42, rel=0.02)
    assert abs(error) < 0.05
    # a metre too high (a late take-off's overshoot): back within 5 cm in 6 s, no long tail
    assert abs(_hover_flight(d, true_hover=0.42, z0=6.0, seconds=6.0)) < 0.05
    before = d.hover
    for k in range(500):  # disarmed, idling or tilted: nothing is learnt
        d.wire_thrust(0.1, 0.0, 0.0)
        d.on_sample(100_000 + 20 * k, -1.0, 0.0, 0.0, armed=True)
        d.on_sample(200_000 + 20 * k, -1.0, 0.0, 0.0, armed=False)
        d.wire_thrust(0.5, 0.5, 0.0)
        d.on_sample(300_000 + 20 * k, -1.0, 0.5, 0.0, armed=True)
    assert d.hover == before

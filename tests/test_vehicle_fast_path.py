"""The vehicle link's fast path (drone_agent/process/vehicle_link.py on protocols/mavlink/fast.py):
its datagrams read and its messages packed without pymavlink's per-frame machinery give the same
samples, counters, status and bytes as pymavlink's codec; what the fast parser does not take (bad
CRCs, signed links) still goes through pymavlink."""

from __future__ import annotations

import os
import socket
import time

import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common

from drone_agent.process.vehicle_link import VehicleLink, VehicleSample
from protocols.mavlink import fast as mavlink_fast
from protocols.mavlink.conventions import AGENT_COMPID, AUTOPILOT_COMPID, sysid_of

pytestmark = pytest.mark.timeout(60)


class _Vehicle:
    """A UDP socket speaking for vehicle ``index`` to a VehicleLink."""

    def __init__(self, index: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.mav = common.MAVLink(None, srcSystem=sysid_of(index), srcComponent=AUTOPILOT_COMPID)

    def send_to(self, link: VehicleLink, *frames: bytes) -> None:
        self.sock.sendto(b"".join(frames), link._sock.getsockname())

    def close(self) -> None:
        self.sock.close()


def _poll_all(link: VehicleLink, datagrams: int) -> list[VehicleSample]:
    out: list[VehicleSample] = []
    deadline = time.monotonic() + 5.0
    while link.counters.rx_datagrams < datagrams and time.monotonic() < deadline:
        out += link.poll()
        time.sleep(0.001)
    return out


def _frames(mav: common.MAVLink, rng: np.random.Generator, ms: int) -> tuple[bytes, bytes]:
    att = rng.normal(size=6).astype(np.float32)
    pos = rng.normal(size=6).astype(np.float32) * 10
    if rng.random() < 0.3:  # trailing zero fields: MAVLink 2 truncates the payload
        att[3:] = 0.0
        pos[2:] = 0.0
    a = mav.attitude_encode(ms, *map(float, att)).pack(mav)
    p = mav.local_position_ned_encode(ms, *map(float, pos)).pack(mav)
    return a, p


def _same(a: list[VehicleSample], b: list[VehicleSample]) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        assert x.time_boot_ms == y.time_boot_ms
        for f in ("position_ned_m", "velocity_ned_m_s", "euler_rad"):
            u, v = getattr(x, f), getattr(y, f)
            assert u.dtype == v.dtype and u.shape == v.shape and u.tobytes() == v.tobytes()


def test_telemetry_fast_path_gives_what_pymavlink_gives() -> None:
    rng = np.random.default_rng(3)
    vehicle = _Vehicle(2)
    fast = VehicleLink(2, "127.0.0.1", vehicle.port)
    slow = VehicleLink(2, "127.0.0.1", vehicle.port)
    slow._fast = False
    parsed = {"fast": 0}
    parse = fast._mav.parse_buffer

    def counting(data: bytes) -> object:
        parsed["fast"] += 1
        return parse(data)

    fast._mav.parse_buffer = counting
    other = common.MAVLink(None, srcSystem=sysid_of(5), srcComponent=AUTOPILOT_COMPID)
    try:
        sent = 0
        for k in range(60):
            a, p = _frames(vehicle.mav, rng, 20 * k)
            kind = k % 6
            if kind == 0:
                datagrams = [a + p]  # both in one datagram
            elif kind == 1:
                datagrams = [p, a]  # position first
            elif kind == 2:  # a bad CRC in the attitude: counted bad, no sample
                datagrams = [a[:-1] + bytes([a[-1] ^ 0xFF]), p]
            elif kind == 3:  # another vehicle's telemetry: foreign
                datagrams = [_frames(other, rng, 20 * k)[0], a, p]
            elif kind == 4:  # a heartbeat with the telemetry: pymavlink's path, same result
                hb = vehicle.mav.heartbeat_encode(2, 12, 129, 393216, 4).pack(vehicle.mav)
                datagrams = [a + hb, p]
            else:
                datagrams = [a, p]
            for d in datagrams:
                vehicle.send_to(fast, d)
                vehicle.send_to(slow, d)
            sent += len(datagrams)
            got_fast, got_slow = _poll_all(fast, sent), _poll_all(slow, sent)
            _same(got_fast, got_slow)
            assert fast.counters == slow.counters
            assert fast.status == slow.status
        assert fast.counters.rx_bad > 0 and fast.counters.rx_foreign > 0
        assert fast.counters.rx_messages > 100
        assert parsed["fast"] < fast.counters.rx_datagrams / 3  # most took the fast path
    finally:
        for thing in (fast, slow, vehicle):
            thing.close()


def test_setpoints_and_commands_go_out_as_pymavlink_packs_them() -> None:
    rng = np.random.default_rng(5)
    vehicle = _Vehicle(3)
    vehicle.sock.settimeout(5.0)
    link = VehicleLink(3, "127.0.0.1", vehicle.port)
    reference = common.MAVLink(None, srcSystem=link.sysid, srcComponent=AGENT_COMPID)
    try:
        for k in range(200):
            q = rng.normal(size=4)
            if k % 7 == 0:
                q[1:] = 0.0
            thrust = 0.0 if k % 11 == 0 else float(rng.random())
            ms = int(rng.integers(0, 2**32))
            link.send_setpoint(ms, q, thrust)
            want = reference.set_attitude_target_encode(
                ms, link.sysid, AUTOPILOT_COMPID, 0b0000_0111, [float(v) for v in q],
                0.0, 0.0, 0.0, thrust,
            ).pack(reference)  # fmt: skip
            assert vehicle.sock.recv(1024) == want
        link.arm(True)
        want = reference.command_long_encode(link.sysid, AUTOPILOT_COMPID, 400, 0, 1.0, *[0.0] * 6)
        assert vehicle.sock.recv(1024) == want.pack(reference)
    finally:
        link.close()
        vehicle.close()


def test_signed_link_never_takes_the_fast_path() -> None:
    link = VehicleLink(1, "127.0.0.1", 9, signing_key=b"k" * 32)
    try:
        assert not mavlink_fast.fast_receive_ok(link._mav)
    finally:
        link.close()

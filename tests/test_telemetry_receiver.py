"""The ground station's telemetry receiver (gcs/station/telemetry.py): the frequent state
messages, read from their fields without pymavlink's message objects, leave the same vehicle
states, status texts and flight.tlog as pymavlink's parser does."""

from __future__ import annotations

import socket
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common

import gcs.station.telemetry as telemetry
from gcs.station.telemetry import TelemetryReceiver


def _frames() -> list[bytes]:
    """Datagrams as the simulator sends them (one or several frames each), and some that are
    not a vehicle's or not whole."""
    out = []
    for sysid in (1, 2, 3):
        mav = common.MAVLink(None, srcSystem=sysid, srcComponent=1)
        hb = mav.heartbeat_encode(2, 12, 128 + 1, 0, 4).pack(mav)
        lpn = mav.local_position_ned_encode(1000 * sysid, 1.5, -2.25, -3.0, 0.1, 0.2, -0.3)
        att = mav.attitude_encode(1000 * sysid + 20, 0.01, -0.02, 1.25, 0.1, 0.2, 0.3)
        act = mav.actuator_output_status_encode(10**6 * sysid, 4, [0.5] * 4 + [0.0] * 28)
        sys_status = mav.sys_status_encode(0, 0, 0, 500, 12000, -1, 90, 0, 0, 0, 0, 0, 0)
        text = mav.statustext_encode(6, b"Armed by the agent")
        out.append(hb)
        out.append(lpn.pack(mav) + att.pack(mav))  # two frames in one datagram
        out += [act.pack(mav), sys_status.pack(mav), text.pack(mav)]
        late = mav.local_position_ned_encode(1000 * sysid + 40, 1.6, -2.2, -3.1, 0.0, 0.0, 0.0)
        out.append(late.pack(mav))
    nobody = common.MAVLink(None, srcSystem=0, srcComponent=1)
    out.append(nobody.attitude_encode(5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0).pack(nobody))
    broken = bytearray(out[2])
    broken[-1] ^= 0xFF  # a bad checksum
    out += [bytes(broken), b"\xfd\x01garbage"]
    return out


def _received(tmp_path: Path, name: str) -> tuple[TelemetryReceiver, list[object]]:
    rx = TelemetryReceiver("127.0.0.1", 0, tmp_path / f"{name}.tlog")
    port = rx._sock.getsockname()[1]
    texts: list[object] = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        for datagram in _frames():
            tx.sendto(datagram, ("127.0.0.1", port))
            time.sleep(0.002)
            texts += rx.poll()
    time.sleep(0.05)
    texts += rx.poll()
    rx.close()
    return rx, texts


def test_state_messages_read_from_their_fields_leave_what_pymavlink_leaves(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    fast, fast_texts = _received(tmp_path, "fast")
    monkeypatch.setattr(telemetry, "fast_receive_ok", lambda _codec: False)
    slow, slow_texts = _received(tmp_path, "slow")
    assert set(fast.vehicles) == {0, 1, 2}
    assert fast.vehicles == slow.vehicles
    assert fast.vehicles[1].position_ned_m == (
        1.600000023841858,
        -2.200000047683716,
        -3.0999999046325684,
    )
    assert fast.vehicles[1].euler_rad[2] == 1.25 and fast.vehicles[1].armed
    assert fast_texts == slow_texts and len(fast_texts) == 3
    assert fast.sim_time_s == slow.sim_time_s == 3.04
    assert fast.malformed == slow.malformed == 1  # the bad checksum (the garbage is not MAVLink)
    assert fast.sim_address is not None and fast.sim_address[0] == "127.0.0.1"
    assert (tmp_path / "fast.tlog").read_bytes() == (tmp_path / "slow.tlog").read_bytes()

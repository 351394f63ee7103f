"""The agent's MAVLink link to its own vehicle over UDP; pymavlink is used only as a codec.

The agent speaks as its vehicle's system id with component 191 (onboard computer), sends to the
vehicle's UDP port (``14540 + index`` by default) and receives from it. It builds a
:class:`VehicleSample` whenever ATTITUDE and LOCAL_POSITION_NED of one ``time_boot_ms`` have both
arrived: that stamp is the agent's clock and names the control tick (lockstep handshake in
protocols/mavlink_conventions.py). Malformed datagrams and messages from other systems are counted
and dropped.
"""

from __future__ import annotations

import os
import socket
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common
from pymavlink.dialects.v20.common import mcrf4xx

from protocols.frames import FloatArray
from protocols.mavlink_conventions import (
    AGENT_COMPID,
    AUTOPILOT_COMPID,
    MODE_OFFBOARD,
    Px4AutoSubMode,
    Px4MainMode,
    sysid_of,
    vehicle_port,
)
from protocols.mavlink_signing import setup_signing

_MAX_DATAGRAM = 65535
#: SET_ATTITUDE_TARGET type_mask: ignore body rates, use attitude and thrust.
IGNORE_BODY_RATES = 0b0000_0111

# The fast path (unsigned links): the two telemetry messages of every tick are read, and the
# setpoint of every tick is packed, with struct and the CRC pymavlink uses, to the same values
# and bytes as pymavlink's generic codec (which handles everything else); checked against it in
# tests/test_vehicle_fast_path.py.
_MAVLINK2 = 0xFD
_HEADER2 = struct.Struct("<BBBBBBBHB")
_ATTITUDE = common.MAVLink_attitude_message
_POSITION = common.MAVLink_local_position_ned_message
_SETPOINT = common.MAVLink_set_attitude_target_message
#: time_boot_ms and six float32s: both telemetry messages' layout (asserted below)
_TELEMETRY = struct.Struct("<Iffffff")
#: msgid -> (crc extra byte, whether it is the attitude)
_FAST_IN = {
    _ATTITUDE.id: (bytes((_ATTITUDE.crc_extra,)), True),
    _POSITION.id: (bytes((_POSITION.crc_extra,)), False),
}
_SETPOINT_CRC_EXTRA = bytes((_SETPOINT.crc_extra,))
assert _ATTITUDE.unpacker.format == _POSITION.unpacker.format == _TELEMETRY.format
assert _ATTITUDE.fieldnames[:4] == ["time_boot_ms", "roll", "pitch", "yaw"]
assert _POSITION.fieldnames == ["time_boot_ms", "x", "y", "z", "vx", "vy", "vz"]


@dataclass(frozen=True)
class VehicleSample:
    """The vehicle's state at ``time_boot_ms`` (simulated ms): NED position (m), velocity (m/s),
    attitude (roll, pitch, yaw; rad)."""

    time_boot_ms: int
    position_ned_m: FloatArray
    velocity_ned_m_s: FloatArray
    euler_rad: FloatArray


@dataclass
class VehicleStatus:
    """What the vehicle's heartbeats, acks and texts said last."""

    armed: bool = False
    custom_mode: int = 0
    system_status: int = 0
    heartbeats: int = 0
    last_ack: dict[int, int] = field(default_factory=dict)
    texts: list[str] = field(default_factory=list)
    emergency: bool = False


@dataclass
class LinkCounters:
    """Per-link counters: datagrams and messages in/out, what was dropped and why."""

    rx_datagrams: int = 0
    rx_messages: int = 0
    rx_bad: int = 0
    rx_foreign: int = 0
    tx_messages: int = 0
    tx_errors: int = 0


class VehicleLink:
    """UDP MAVLink client of vehicle ``index``. Non-blocking: call :meth:`poll` when readable."""

    def __init__(
        self,
        index: int,
        host: str = "127.0.0.1",
        port: int | None = None,
        signing_key: bytes | None = None,
        wall_clock: Callable[[], float] | None = None,
    ) -> None:
        self.index = index
        self.sysid = sysid_of(index)
        self.address = (host, vehicle_port(index) if port is None else port)
        self._mav = common.MAVLink(None, srcSystem=self.sysid, srcComponent=AGENT_COMPID)
        self._mav.robust_parsing = True
        if signing_key is not None:
            setup_signing(self._mav, signing_key, link_id=1, wall_clock=wall_clock)
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.setblocking(False)
        self._sock.connect(self.address)
        self.status = VehicleStatus()
        self.counters = LinkCounters()
        #: half pairs by time_boot_ms: (x, y, z, vx, vy, vz) and (roll, pitch, yaw)
        self._pos: dict[int, tuple[float, ...]] = {}
        self._att: dict[int, tuple[float, ...]] = {}
        #: the fast path's codec: unsigned links only (pymavlink checks and makes signatures)
        self._fast = signing_key is None and mcrf4xx is not None

    def fileno(self) -> int:
        return self._sock.fileno()

    def close(self) -> None:
        self._sock.close()

    def reopen(self) -> None:
        """Close this link's port and speak from a new one to the same vehicle: the simulator
        sees the old port closed at its next send (an agent gone: lockstep stops waiting for it
        at once), and whoever speaks next from the new port is a new agent to it. Samples half
        assembled on the old port are dropped. Re-register :meth:`fileno` with any selector."""
        old = self._sock
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.setblocking(False)
        self._sock.connect(self.address)
        old.close()
        self._pos.clear()
        self._att.clear()

    def __enter__(self) -> VehicleLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- receive -------------------------------------------------------------------------------
    def poll(self) -> list[VehicleSample]:
        """Read every pending datagram; return the complete samples, oldest first."""
        samples: list[VehicleSample] = []
        while True:
            try:
                data = self._sock.recv(_MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                break
            except ConnectionRefusedError:  # the vehicle is not (yet) listening
                break
            self.counters.rx_datagrams += 1
            if self._fast and self._fast_telemetry(data, samples):
                continue
            try:
                messages = self._mav.parse_buffer(data) or []
            except Exception:  # pymavlink raises MAVError and struct errors alike
                self.counters.rx_bad += 1
                continue
            for msg in messages:
                samples += self._handle(msg)
        return samples

    def _fast_telemetry(self, data: bytes, samples: list[VehicleSample]) -> bool:
        """Take in a datagram made only of unsigned, well-formed MAVLink 2 ATTITUDE and
        LOCAL_POSITION_NED frames of this vehicle's autopilot, as :meth:`_handle` would after
        pymavlink; False (nothing taken in) for any other datagram, which pymavlink then
        parses (and counts, if it is bad)."""
        if self._mav.buf_len():  # pymavlink holds part of a frame: it goes on parsing
            return False
        frames = []
        off, n = 0, len(data)
        while off < n:
            if n - off < 12 or data[off] != _MAVLINK2 or data[off + 2] or data[off + 3]:
                return False  # not MAVLink 2, or flagged (signed, ...)
            plen = data[off + 1]
            end = off + 12 + plen
            fast = _FAST_IN.get(data[off + 7] | data[off + 8] << 8 | data[off + 9] << 16)
            if fast is None or plen > _TELEMETRY.size or end > n:
                return False
            if data[off + 5] != self.sysid or data[off + 6] != AUTOPILOT_COMPID:
                return False
            crc = mcrf4xx(data[off + 1 : end - 2] + fast[0], 0xFFFF)
            if crc != data[end - 2] | data[end - 1] << 8:
                return False
            body = data[off + 10 : end - 2]
            if plen < _TELEMETRY.size:  # MAVLink 2 drops trailing zero bytes
                body += bytes(_TELEMETRY.size - plen)
            frames.append((fast[1], _TELEMETRY.unpack(body)))
            off = end
        for attitude, fields in frames:
            self.counters.rx_messages += 1
            ms = fields[0]
            if attitude:
                self._att[ms] = fields[1:4]
            else:
                self._pos[ms] = fields[1:7]
            samples += self._pair(ms)
        return True

    def _handle(self, msg: Any) -> list[VehicleSample]:
        if msg.get_type() == "BAD_DATA":
            self.counters.rx_bad += 1
            return []
        if msg.get_srcSystem() != self.sysid or msg.get_srcComponent() != AUTOPILOT_COMPID:
            self.counters.rx_foreign += 1
            return []
        self.counters.rx_messages += 1
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            self.status.heartbeats += 1
            self.status.armed = bool(msg.base_mode & common.MAV_MODE_FLAG_SAFETY_ARMED)
            self.status.custom_mode = int(msg.custom_mode)
            self.status.system_status = int(msg.system_status)
        elif kind == "COMMAND_ACK":
            self.status.last_ack[int(msg.command)] = int(msg.result)
        elif kind == "STATUSTEXT":
            self.status.texts.append(str(msg.text))
            del self.status.texts[:-50]
            if int(msg.severity) == common.MAV_SEVERITY_EMERGENCY:
                self.status.emergency = True  # e.g. motors failed: the vehicle is going down
        elif kind == "LOCAL_POSITION_NED":
            self._pos[int(msg.time_boot_ms)] = (msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz)
            return self._pair(int(msg.time_boot_ms))
        elif kind == "ATTITUDE":
            self._att[int(msg.time_boot_ms)] = (msg.roll, msg.pitch, msg.yaw)
            return self._pair(int(msg.time_boot_ms))
        return []

    def _pair(self, ms: int) -> list[VehicleSample]:
        pos, att = self._pos.get(ms), self._att.get(ms)
        if pos is None or att is None:
            self._prune(ms)
            return []
        del self._pos[ms], self._att[ms]
        self._prune(ms)
        return [
            VehicleSample(
                ms,
                np.array(pos[:3], dtype=float),
                np.array(pos[3:], dtype=float),
                np.array(att, dtype=float),
            )
        ]

    def _prune(self, ms: int) -> None:
        """Forget half-pairs more than a second older than ``ms``."""
        for store in (self._pos, self._att):
            for old in [k for k in store if k < ms - 1000]:
                del store[old]

    # -- send ----------------------------------------------------------------------------------
    def _send(self, msg: Any) -> None:
        self._send_packed(msg.pack(self._mav))

    def _send_packed(self, frame: bytes) -> None:
        try:
            self._sock.send(frame)
            self.counters.tx_messages += 1
        except OSError:
            self.counters.tx_errors += 1

    def send_setpoint(self, time_boot_ms: int, quat_wxyz: FloatArray, thrust: float) -> None:
        """SET_ATTITUDE_TARGET: attitude quaternion (w, x, y, z) body -> NED and normalised
        thrust 0..1; ``time_boot_ms`` echoes the tick it answers (lockstep handshake)."""
        q = [float(v) for v in quat_wxyz]
        ms = int(time_boot_ms) & 0xFFFFFFFF
        if self._fast and len(q) == 4:
            self._send_packed(self._pack_setpoint(ms, q, float(thrust)))
            return
        self._send(
            self._mav.set_attitude_target_encode(
                ms, self.sysid, AUTOPILOT_COMPID, IGNORE_BODY_RATES, q, 0.0, 0.0, 0.0, float(thrust)
            )
        )

    def _pack_setpoint(self, ms: int, q: list[float], thrust: float) -> bytes:
        """The frame pymavlink packs for this SET_ATTITUDE_TARGET (unsigned: the fast path)."""
        payload = _SETPOINT.unpacker.pack(
            ms, *q, 0.0, 0.0, 0.0, thrust, self.sysid, AUTOPILOT_COMPID, IGNORE_BODY_RATES
        )
        plen = len(payload)
        while plen > 1 and payload[plen - 1] == 0:  # MAVLink 2 drops trailing zero bytes
            plen -= 1
        mav = self._mav
        frame = (
            _HEADER2.pack(
                _MAVLINK2, plen, 0, 0, mav.seq, mav.srcSystem, mav.srcComponent,
                _SETPOINT.id & 0xFFFF, _SETPOINT.id >> 16,
            )
            + payload[:plen]
        )  # fmt: skip
        crc = mcrf4xx(frame[1:] + _SETPOINT_CRC_EXTRA, 0xFFFF)
        return frame + struct.pack("<H", crc)

    def send_heartbeat(self) -> None:
        self._send(
            self._mav.heartbeat_encode(
                common.MAV_TYPE_ONBOARD_CONTROLLER,
                common.MAV_AUTOPILOT_INVALID,
                0,
                0,
                common.MAV_STATE_ACTIVE,
            )
        )

    def command(self, command: int, *params: float) -> None:
        """COMMAND_LONG to the vehicle's autopilot (up to 7 params, the rest 0)."""
        p = [float(v) for v in params] + [0.0] * (7 - len(params))
        self._send(self._mav.command_long_encode(self.sysid, AUTOPILOT_COMPID, command, 0, *p))

    def arm(self, arm: bool = True) -> None:
        self.command(common.MAV_CMD_COMPONENT_ARM_DISARM, 1.0 if arm else 0.0)

    def set_offboard(self) -> None:
        self.command(
            common.MAV_CMD_DO_SET_MODE,
            common.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
            float(Px4MainMode.OFFBOARD),
        )

    def set_land(self) -> None:
        """The autopilot's LAND mode (PX4 AUTO.LAND): level, sink, disarm on touchdown."""
        self._set_px4_mode(Px4MainMode.AUTO, Px4AutoSubMode.LAND)

    def set_hold(self) -> None:
        """The autopilot's HOLD mode (PX4 AUTO.LOITER): level, hold the altitude."""
        self._set_px4_mode(Px4MainMode.AUTO, Px4AutoSubMode.LOITER)

    def _set_px4_mode(self, main: int, sub: int) -> None:
        self.command(
            common.MAV_CMD_DO_SET_MODE,
            common.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
            float(main),
            float(sub),
        )

    @property
    def in_offboard(self) -> bool:
        return self.status.custom_mode == MODE_OFFBOARD

    def request_interval(self, message_id: int, rate_hz: float) -> None:
        """MAV_CMD_SET_MESSAGE_INTERVAL for one message id at ``rate_hz``."""
        self.command(common.MAV_CMD_SET_MESSAGE_INTERVAL, float(message_id), 1e6 / rate_hz)

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
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common

from protocols import mavlink_fast
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
_POSITION = common.MAVLink_local_position_ned_message
_ATTITUDE = common.MAVLink_attitude_message
#: SET_ATTITUDE_TARGET type_mask: ignore body rates, use attitude and thrust.
IGNORE_BODY_RATES = 0b0000_0111


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
        #: half samples by time_boot_ms: (time_boot_ms, x, y, z, vx, vy, vz) and
        #: (time_boot_ms, roll, pitch, yaw, ...)
        self._pos: dict[int, tuple[Any, ...]] = {}
        self._att: dict[int, tuple[Any, ...]] = {}

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
            # unsigned links: protocols/mavlink_fast.py; pymavlink's codec for anything it does
            # not take, and for signed links (their signature policy)
            fast = mavlink_fast.fast_receive_ok(self._mav)
            messages = self._fast_parse(data) if fast else None
            if messages is None:
                try:
                    messages = self._mav.parse_buffer(data) or []
                except Exception:  # pymavlink raises MAVError and struct errors alike
                    self.counters.rx_bad += 1
                    continue
            for msg in messages:
                if type(msg) is tuple:  # a state half of our vehicle (see _fast_parse)
                    self.counters.rx_messages += 1
                    store = self._pos if msg[0] else self._att
                    store[msg[1]] = msg[1:]
                    samples += self._pair(msg[1])
                else:
                    samples += self._handle(msg)
        return samples

    def _fast_parse(self, data: bytes) -> list[Any] | None:
        """:func:`protocols.mavlink_fast.parse` of ``data``, except that our vehicle's
        LOCAL_POSITION_NED and ATTITUDE (every tick's traffic) come as the tuples
        ``(is_position, time_boot_ms, 6 floats)`` of their fields in wire order, without
        pymavlink's message objects; None where parse gives None."""
        found = mavlink_fast.frames(data)
        if found is None:
            return None
        out: list[Any] = []
        sysid = self.sysid
        for frame in found:
            cls = frame.cls
            if (
                (cls is _POSITION or cls is _ATTITUDE)
                and frame.sysid == sysid
                and frame.compid == AUTOPILOT_COMPID
            ):
                out.append((cls is _POSITION, *cls.unpacker.unpack(frame.body)))
                continue
            msg = mavlink_fast.message_of(frame, data)
            if msg is None:
                return None
            out.append(msg)
        return out

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
            ms = int(msg.time_boot_ms)
            self._pos[ms] = (ms, msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz)
            return self._pair(ms)
        elif kind == "ATTITUDE":
            ms = int(msg.time_boot_ms)
            self._att[ms] = (ms, msg.roll, msg.pitch, msg.yaw)
            return self._pair(ms)
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
                np.array(pos[1:4], dtype=float),
                np.array(pos[4:7], dtype=float),
                np.array(att[1:4], dtype=float),
            )
        ]

    def _prune(self, ms: int) -> None:
        """Forget half-pairs more than a second older than ``ms``."""
        for store in (self._pos, self._att):
            for old in [k for k in store if k < ms - 1000]:
                del store[old]

    # -- send ----------------------------------------------------------------------------------
    def _send(self, msg: Any) -> None:
        try:
            self._sock.send(mavlink_fast.pack(msg, self._mav))  # msg.pack's bytes
            self.counters.tx_messages += 1
        except OSError:
            self.counters.tx_errors += 1

    def send_setpoint(self, time_boot_ms: int, quat_wxyz: FloatArray, thrust: float) -> None:
        """SET_ATTITUDE_TARGET: attitude quaternion (w, x, y, z) body -> NED and normalised
        thrust 0..1; ``time_boot_ms`` echoes the tick it answers (lockstep handshake)."""
        q = [float(v) for v in quat_wxyz]
        self._send(
            self._mav.set_attitude_target_encode(
                int(time_boot_ms) & 0xFFFFFFFF,
                self.sysid,
                AUTOPILOT_COMPID,
                IGNORE_BODY_RATES,
                q,
                0.0,
                0.0,
                0.0,
                float(thrust),
            )
        )

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

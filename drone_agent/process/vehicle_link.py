"""The agent's MAVLink link to its own vehicle over UDP; pymavlink is used only as a codec.

The agent speaks as its vehicle's system id with component 191 (onboard computer), sends to the
vehicle's UDP port (``14540 + index`` by default) and receives from it; or, with ``listen``, binds
that port and answers whoever sends to it (an ArduCopter SITL's ``--serial0 udpclient:...``, as
PX4 SITL's onboard port does). Malformed datagrams and messages from other systems are counted
and dropped.

What the vehicle's autopilot speaks is its :class:`~drone_agent.process.dialects.AutopilotDialect`:
forced (``dialect``) or taken from its first HEARTBEAT's ``autopilot`` field (until then no
sample is made). In the PX4 dialect a :class:`VehicleSample` is made whenever ATTITUDE and
LOCAL_POSITION_NED of one ``time_boot_ms`` have both arrived: that stamp is the agent's clock and
names the control tick (lockstep handshake in protocols/mavlink/conventions.py). In the ArduCopter
dialect the position in the swarm's frame is GLOBAL_POSITION_INT about the swarm's common origin
(``origin``; each vehicle's LOCAL_POSITION_NED is about its own EKF origin and is not used), paired
with the ATTITUDE nearest in time (within :data:`PAIR_MS`): the sample's time is the position's.
With a ``clock`` (vehicles that each count from their own boot: protocols/mavlink/swarm_clock.py)
the sample's ``time_boot_ms`` is the vehicle's stamp on the swarm's clock.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega, common

from drone_agent.process.dialects import AutopilotDialect, Command, ModeView, make_dialect
from protocols.mavlink import fast as mavlink_fast
from protocols.mavlink.conventions import (
    AGENT_COMPID,
    AUTOPILOT_COMPID,
    Dialect,
    MavSeverity,
    dialect_of_autopilot,
    sysid_of,
    vehicle_port,
)
from protocols.mavlink.signing import setup_signing
from protocols.mavlink.swarm_clock import VehicleClock
from protocols.model.frames import FloatArray
from protocols.model.geodesy import GeoPoint, ned_of_global_int

_MAX_DATAGRAM = 65535
_POSITION = common.MAVLink_local_position_ned_message
_ATTITUDE = common.MAVLink_attitude_message
#: SET_ATTITUDE_TARGET type_mask: ignore body rates, use attitude and thrust.
IGNORE_BODY_RATES = 0b0000_0111
_SAT = common.MAVLink_set_attitude_target_message
#: SET_ATTITUDE_TARGET's payload in wire order: time_boot_ms, q (w, x, y, z), the three body
#: rates, thrust, target system and component, type_mask
_SET_ATTITUDE_TARGET = _SAT.unpacker
#: whether this pymavlink's message has those fields (else every setpoint takes the message path)
_SETPOINT_FRAME = _SAT.ordered_fieldnames == [
    "time_boot_ms", "q", "body_roll_rate", "body_pitch_rate", "body_yaw_rate", "thrust",
    "target_system", "target_component", "type_mask",
]  # fmt: skip
#: ArduCopter dialect: a position and an attitude at most this far apart (ms) make one sample.
PAIR_MS = 30
#: Messages a dialect reads (parameters, EKF and GPS state, pre-arm checks).
_DIALECT_KINDS = frozenset(
    {"PARAM_VALUE", "EKF_STATUS_REPORT", "GPS_RAW_INT", "SYS_STATUS", "ATTITUDE"}
)


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
    #: the HEARTBEAT's ``autopilot`` field (MAV_AUTOPILOT), None before the first
    autopilot: int | None = None
    #: EXTENDED_SYS_STATE's MAV_LANDED_STATE, None while the vehicle sent none
    landed_state: int | None = None

    @property
    def on_ground(self) -> bool | None:
        """What the vehicle's land detector says (None: it said nothing, or UNDEFINED)."""
        if self.landed_state in (None, common.MAV_LANDED_STATE_UNDEFINED):
            return None
        return self.landed_state == common.MAV_LANDED_STATE_ON_GROUND


@dataclass
class MavlinkCounters:
    """Counts of the MAVLink traffic of one vehicle link: datagrams and messages in/out, what
    was dropped and why."""

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
        dialect: Dialect | None = Dialect.PX4,
        thrust_to_weight: float = 2.0,
        control_hz: float = 50.0,
        origin: GeoPoint | None = None,
        clock: VehicleClock | None = None,
        listen: bool = False,
    ) -> None:
        """``dialect``: the vehicle's autopilot dialect, None to take it from its HEARTBEAT;
        ``thrust_to_weight`` and ``control_hz``: the scale of the agent's normalised thrust and
        its control rate (the ArduCopter dialect's thrust and stream rates); ``origin``: the
        swarm frame's origin on the map (ArduCopter dialect); ``clock``: maps the vehicle's own
        ``time_boot_ms`` onto the swarm's; ``listen``: bind the port instead of sending to it."""
        self.index = index
        self.sysid = sysid_of(index)
        self.address = (host, vehicle_port(index) if port is None else port)
        self._mav = common.MAVLink(None, srcSystem=self.sysid, srcComponent=AGENT_COMPID)
        self._mav.robust_parsing = True
        # ArduPilot's own messages (EKF_STATUS_REPORT) need its dialect's codec to be read
        self._apm = ardupilotmega.MAVLink(None, srcSystem=self.sysid, srcComponent=AGENT_COMPID)
        self._apm.robust_parsing = True
        if signing_key is not None:
            setup_signing(self._mav, signing_key, link_id=1, wall_clock=wall_clock)
            setup_signing(self._apm, signing_key, link_id=1, wall_clock=wall_clock)
        self._listen = listen
        self._peer: tuple[str, int] | None = None
        self._sock = self._open()
        self._thrust_to_weight, self._control_hz = thrust_to_weight, control_hz
        self.dialect_forced = dialect is not None
        self.dialect: AutopilotDialect = make_dialect(
            dialect or Dialect.PX4, thrust_to_weight, control_hz, self.sysid
        )
        self.origin = origin if origin is not None else GeoPoint()
        self.clock = clock
        self.status = VehicleStatus()
        self.counters = MavlinkCounters()
        #: half samples by time_boot_ms: (time_boot_ms, x, y, z, vx, vy, vz) and
        #: (time_boot_ms, roll, pitch, yaw, ...)
        self._pos: dict[int, tuple[Any, ...]] = {}
        self._att: dict[int, tuple[Any, ...]] = {}

    def _open(self) -> socket.socket:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setblocking(False)
        if self._listen:
            sock.bind(self.address)
        else:
            sock.connect(self.address)
        return sock

    @property
    def dialect_known(self) -> bool:
        """The dialect was forced, or the vehicle's HEARTBEAT named it."""
        return self.dialect_forced or self.status.autopilot is not None

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
        if self._listen:
            old.close()
            self._peer = None
            self._sock = self._open()
        else:
            self._sock = self._open()
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
                if self._listen:  # answer whoever spoke last
                    data, self._peer = self._sock.recvfrom(_MAX_DATAGRAM)
                else:
                    data = self._sock.recv(_MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                break
            except ConnectionRefusedError:  # the vehicle is not (yet) listening
                break
            self.counters.rx_datagrams += 1
            # unsigned links: protocols/mavlink/fast.py; pymavlink's codec for anything it does
            # not take, and for signed links (their signature policy)
            fast = (
                mavlink_fast.fast_receive_ok(self._mav)
                and self.dialect_known
                and not self.dialect.global_frame
            )
            messages = self._fast_parse(data) if fast else None
            if messages is None:
                codec = self._mav if fast else self._rx_codec()
                try:
                    messages = codec.parse_buffer(data) or []
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

    def _rx_codec(self) -> Any:
        """The codec of the slow path: ArduPilot's until a PX4 dialect is known."""
        if self.dialect_known and not self.dialect.global_frame:
            return self._mav
        return self._apm

    def _fast_parse(self, data: bytes) -> list[Any] | None:
        """:func:`protocols.mavlink.fast.parse` of ``data``, except that our vehicle's
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
        if kind in _DIALECT_KINDS:
            self.dialect.on_message(kind, msg)
        if kind == "HEARTBEAT":
            self.status.heartbeats += 1
            self.status.armed = bool(msg.base_mode & common.MAV_MODE_FLAG_SAFETY_ARMED)
            self.status.custom_mode = int(msg.custom_mode)
            self.status.system_status = int(msg.system_status)
            if self.status.autopilot is None:
                self._learn_dialect(int(msg.autopilot))
        elif kind == "COMMAND_ACK":
            self.status.last_ack[int(msg.command)] = int(msg.result)
        elif kind == "EXTENDED_SYS_STATE":
            self.status.landed_state = int(msg.landed_state)
        elif kind == "STATUSTEXT":
            self.status.texts.append(str(msg.text))
            del self.status.texts[:-50]
            if int(msg.severity) == MavSeverity.EMERGENCY:
                self.status.emergency = True  # e.g. motors failed: the vehicle is going down
        elif not self.dialect_known:
            return []  # which frame a position is in is not known yet
        elif kind == "LOCAL_POSITION_NED" and not self.dialect.global_frame:
            ms = int(msg.time_boot_ms)
            self._pos[ms] = (ms, msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz)
            return self._pair(ms)
        elif kind == "GLOBAL_POSITION_INT" and self.dialect.global_frame:
            ms = int(msg.time_boot_ms)
            ned = ned_of_global_int(self.origin, msg.lat, msg.lon, msg.alt)[0]
            self._pos[ms] = (ms, *ned, msg.vx * 0.01, msg.vy * 0.01, msg.vz * 0.01)
            return self._pair_nearest(ms, self._pos, self._att)
        elif kind == "ATTITUDE":
            ms = int(msg.time_boot_ms)
            self._att[ms] = (ms, msg.roll, msg.pitch, msg.yaw)
            if self.dialect.global_frame:
                return self._pair_nearest(ms, self._att, self._pos)
            return self._pair(ms)
        return []

    def _learn_dialect(self, autopilot: int) -> None:
        """The first HEARTBEAT: its autopilot names the dialect unless one was forced."""
        self.status.autopilot = autopilot
        if self.dialect_forced:
            return
        found = dialect_of_autopilot(autopilot)
        if found is not None and found != self.dialect.name:
            self.dialect = make_dialect(found, self._thrust_to_weight, self._control_hz, self.sysid)
            self._pos.clear()
            self._att.clear()

    def _pair_nearest(
        self, ms: int, mine: dict[int, tuple[Any, ...]], other: dict[int, tuple[Any, ...]]
    ) -> list[VehicleSample]:
        """ArduCopter dialect: the half just stored at ``ms`` with the other half nearest in time
        (within PAIR_MS); both used up, older halves forgotten."""
        near = [k for k in other if abs(k - ms) <= PAIR_MS]
        if not near:
            self._prune(ms)
            return []
        k = min(near, key=lambda k: abs(k - ms))
        mine_half, other_half = mine.pop(ms), other.pop(k)
        pos, att = (mine_half, other_half) if mine is self._pos else (other_half, mine_half)
        for store in (self._pos, self._att):  # what is older than the pair is stale now
            for old in [t for t in store if t < min(ms, k)]:
                del store[old]
        stamp = int(pos[0])
        if self.clock is not None:
            stamp = self.clock.swarm_ms(stamp)
        self.dialect.on_sample(
            int(pos[0]), float(pos[6]), float(att[1]), float(att[2]), self.status.armed
        )
        return [_sample(stamp, pos, att)]

    def _pair(self, ms: int) -> list[VehicleSample]:
        pos, att = self._pos.get(ms), self._att.get(ms)
        if pos is None or att is None:
            self._prune(ms)
            return []
        del self._pos[ms], self._att[ms]
        self._prune(ms)
        return [_sample(ms, pos, att)]

    def _prune(self, ms: int) -> None:
        """Forget half-pairs more than a second older than ``ms``."""
        for store in (self._pos, self._att):
            for old in [k for k in store if k < ms - 1000]:
                del store[old]

    # -- send ----------------------------------------------------------------------------------
    def _send(self, msg: Any) -> None:
        self._send_frame(mavlink_fast.pack(msg, self._mav))  # msg.pack's bytes

    def _send_frame(self, data: bytes) -> None:
        try:
            if self._listen:
                if self._peer is None:  # nobody has spoken to us yet
                    self.counters.tx_errors += 1
                    return
                self._sock.sendto(data, self._peer)
            else:
                self._sock.send(data)
            self.counters.tx_messages += 1
        except OSError:
            self.counters.tx_errors += 1

    def send_setpoint(self, time_boot_ms: int, quat_wxyz: FloatArray, thrust: float) -> None:
        """SET_ATTITUDE_TARGET: attitude quaternion (w, x, y, z) body -> NED and normalised
        thrust 0..1; ``time_boot_ms`` echoes the tick it answers (lockstep handshake)."""
        q = [float(v) for v in quat_wxyz]
        if _SETPOINT_FRAME and not self._mav.signing.sign_outgoing:
            # the frame packed from the fields in wire order: the bytes of pymavlink's message
            # object packed (tests/test_vehicle_fast_path.py), without building the object
            # (~7 us -> ~1 us, every agent every tick)
            payload = _SET_ATTITUDE_TARGET.pack(
                int(time_boot_ms) & 0xFFFFFFFF, *q, 0.0, 0.0, 0.0, float(thrust),
                self.sysid, AUTOPILOT_COMPID, IGNORE_BODY_RATES,
            )  # fmt: skip
            self._send_frame(mavlink_fast.pack_payload(_SAT, payload, self._mav))
            return
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

    def _send_command(self, command: Command) -> None:
        self.command(command[0], *command[1])

    def set_offboard(self) -> None:
        """The mode that flies the agent's attitude setpoints (PX4 OFFBOARD, ArduCopter
        GUIDED_NOGPS)."""
        self._send_command(self.dialect.offboard_command())

    def set_land(self) -> None:
        """The autopilot's LAND mode: level, sink, disarm on touchdown."""
        self._send_command(self.dialect.land_command())

    def set_hold(self) -> None:
        """The autopilot's hold (PX4 AUTO.LOITER, ArduCopter BRAKE)."""
        self._send_command(self.dialect.hold_command())

    def modes(self) -> ModeView:
        """Which of the agent's modes the vehicle reports."""
        return self.dialect.modes(self.status.custom_mode)

    @property
    def in_offboard(self) -> bool:
        return self.modes().in_offboard

    def service_dialect(self, now_s: float) -> None:
        """The dialect's set-up due now (streams, parameters; nothing for PX4)."""
        if self.dialect_known:
            self.dialect.service(self, now_s)

    def param_set(self, name: str, value: float) -> None:
        """PARAM_SET of a numeric parameter (sent as MAV_PARAM_TYPE_REAL32's value)."""
        self._send(
            self._mav.param_set_encode(
                self.sysid, AUTOPILOT_COMPID, name.encode(), float(value),
                common.MAV_PARAM_TYPE_REAL32,
            )
        )  # fmt: skip

    def param_read(self, name: str) -> None:
        """PARAM_REQUEST_READ of a parameter by name."""
        request = self._mav.param_request_read_encode
        self._send(request(self.sysid, AUTOPILOT_COMPID, name.encode(), -1))

    def request_interval(self, message_id: int, rate_hz: float) -> None:
        """MAV_CMD_SET_MESSAGE_INTERVAL for one message id at ``rate_hz``."""
        self.command(common.MAV_CMD_SET_MESSAGE_INTERVAL, float(message_id), 1e6 / rate_hz)


def _sample(time_boot_ms: int, pos: tuple[Any, ...], att: tuple[Any, ...]) -> VehicleSample:
    """A sample of the halves ``(ms, x, y, z, vx, vy, vz)`` and ``(ms, roll, pitch, yaw)``."""
    return VehicleSample(
        time_boot_ms,
        np.array(pos[1:4], dtype=float),
        np.array(pos[4:7], dtype=float),
        np.array(att[1:4], dtype=float),
    )

"""The ground station's MAVLink side: receives the simulator's GCS telemetry stream over UDP,
records every packet into ``flight.tlog`` stamped with simulated time, and keeps the newest state
of each vehicle (system id = drone index + 1).

The simulator sends to the ground station's address; the ground station sends back only drills
(:meth:`TelemetryReceiver.send_command`, e.g. MAV_CMD_INJECT_FAILURE), to the address the vehicles'
telemetry comes from. The record time of a packet is its own ``time_boot_ms`` (s) when it has one,
else its vehicle's last known time, else the newest simulated time heard from any vehicle.

Vehicles of either autopilot dialect (protocols/mavlink/conventions.py), known by their HEARTBEAT:
a PX4-dialect vehicle's position is its LOCAL_POSITION_NED (one simulator, one frame); an
ArduCopter's is its GLOBAL_POSITION_INT about the swarm's origin (``origin``, written into the log
as a GPS_GLOBAL_ORIGIN of the ground station's system id, 255, so that the report reads it back),
since each ArduCopter keeps its own EKF origin. With ``epoch_s`` (autopilots that each count from
their own boot: protocols/mavlink/swarm_clock.py) a ``time_boot_ms`` is put on the swarm's clock
first. Commands go back to the address each vehicle's telemetry comes from (one simulator, or one
ArduCopter instance each).
"""

from __future__ import annotations

import contextlib
import socket
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega, common

from gcs.report.tlog import TlogWriter
from protocols.mavlink.conventions import (
    AGENT_STATUS_VALUES,
    GCS_COMPID,
    GCS_SYSID,
    MAV_AUTOPILOT_ARDUPILOTMEGA,
)
from protocols.mavlink.fast import Frame, fast_receive_ok, field_places, frames, message_of, pack
from protocols.mavlink.signing import setup_signing
from protocols.mavlink.swarm_clock import VehicleClock
from protocols.model.geodesy import GeoPoint, ned_of_global_int
from protocols.wire.status import N_ESTIMATE, AgentStatus

_MAX_DATAGRAM = 65535
_ARMED_FLAG = 128  # MAV_MODE_FLAG_SAFETY_ARMED
#: the messages :meth:`TelemetryReceiver._handle` reads from pymavlink's message object (the
#: others are read from their fields: :meth:`TelemetryReceiver._fast`)
_AS_OBJECTS = frozenset({"HEARTBEAT", "GLOBAL_POSITION_INT", "STATUSTEXT"})


@dataclass
class VehicleState:
    """The newest telemetry of one vehicle: time (s), NED position (m) and velocity (m/s),
    roll/pitch/yaw (rad), armed flag and MAV_STATE from its heartbeat."""

    t_s: float = 0.0
    position_ned_m: tuple[float, float, float] | None = None
    velocity_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    euler_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    armed: bool = False
    system_status: int = 0
    packets: int = 0
    #: its HEARTBEAT says ArduPilot: its position is GLOBAL_POSITION_INT about the origin
    ardupilot: bool = False


@dataclass(frozen=True)
class VehicleText:
    """A STATUSTEXT from vehicle ``drone`` (index) at simulated time ``t_s`` (s)."""

    t_s: float
    drone: int
    severity: int
    text: str


@dataclass
class TelemetryReceiver:
    """Binds UDP ``host:port``; :meth:`poll` drains what arrived into the tlog at ``tlog_path``
    (appended to with ``append``, else started afresh). With ``signing_key`` its commands are
    signed (MAVLink 2 signing, link id 2). Use as a context manager (closes the socket and the
    tlog)."""

    host: str
    port: int
    tlog_path: Path
    vehicles: dict[int, VehicleState] = field(default_factory=dict)
    sim_time_s: float = 0.0
    malformed: int = 0
    sim_address: tuple[str, int] | None = None
    append: bool = False
    signing_key: bytes | None = None
    #: the swarm frame's origin on the map (ArduCopter-dialect positions)
    origin: GeoPoint | None = None
    #: the swarm clock's epoch (Unix s) for vehicles that each count from their own boot
    epoch_s: float | None = None

    def __post_init__(self) -> None:
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._clocks: dict[int, VehicleClock] = {}
        self._address_of: dict[int, tuple[str, int]] = {}
        try:
            self._sock.bind((self.host, self.port))
            self._sock.setblocking(False)
            _large_receive_buffer(self._sock)
            # ArduPilot's own messages (EKF_STATUS_REPORT, ...) are logged too
            self._codec = ardupilotmega.MAVLink(None)
            self._out = common.MAVLink(None, srcSystem=255, srcComponent=190)  # a GCS
            if self.signing_key is not None:  # the simulator rejects unsigned commands then
                setup_signing(self._out, self.signing_key, link_id=2)
            self._codec.robust_parsing = True
            self._tlog = TlogWriter(self.tlog_path, append=self.append)
            self._tlog.open()
            if self.origin is not None:
                self._log_origin(self.origin)
        except BaseException:
            self._sock.close()
            raise

    def __enter__(self) -> TelemetryReceiver:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the socket and the tlog (idempotent)."""
        self._sock.close()
        self._tlog.close()

    def fileno(self) -> int:
        """The socket, for ``select``."""
        return self._sock.fileno()

    def _log_origin(self, origin: GeoPoint) -> None:
        """GPS_GLOBAL_ORIGIN of the swarm frame, as the ground station (report/tlog.py)."""
        codec = self._tlog.codec(GCS_SYSID, GCS_COMPID)
        msg = codec.gps_global_origin_encode(
            round(origin.lat_deg * 1e7), round(origin.lon_deg * 1e7), round(origin.alt_m * 1e3)
        )
        self._tlog.write_packet(self.sim_time_s, pack(msg, codec))  # from 255/190, not a vehicle

    def poll(self) -> list[VehicleText]:
        """Drain every waiting datagram; returns the status texts that came."""
        texts: list[VehicleText] = []
        while True:
            try:
                data, address = self._sock.recvfrom(_MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                return texts
            except OSError:
                return texts
            found = frames(data) if fast_receive_ok(self._codec) else None
            if found is not None:
                # a message object only where one is read (_handle); the frequent state
                # messages are read from their fields (_fast: nine in ten of a swarm's)
                messages: list[Any] = []
                for f in found:
                    msg = f if f.cls.msgname not in _AS_OBJECTS else message_of(f, data)
                    if msg is None:  # one pymavlink cannot build: the datagram goes to it
                        found = None
                        break
                    messages.append(msg)
            if found is None:  # not only whole, valid, unsigned MAVLink 2 frames: pymavlink
                try:
                    messages = self._codec.parse_buffer(data) or []
                except common.MAVError:
                    self.malformed += 1
                    continue
            for msg in messages:
                frame = isinstance(msg, Frame)
                sysid = msg.sysid if frame else msg.get_srcSystem()
                if (frame or msg.get_type() != "BAD_DATA") and 1 <= sysid <= 254:
                    self.sim_address = (str(address[0]), int(address[1]))
                    self._address_of[sysid] = self.sim_address
                    if frame:
                        self._fast(msg, data)
                if not frame and (text := self._handle(msg)) is not None:
                    texts.append(text)

    def log_agent_statuses(self, statuses: Sequence[AgentStatus]) -> None:
        """Record agents' statuses in the tlog, in order (protocols/mavlink/conventions.py
        "AGENT": the estimate, the neighbour count, the mode and armed; the neighbours' ids)."""
        values = np.empty((len(statuses), AGENT_STATUS_VALUES))
        for row, status in zip(values, statuses, strict=True):
            row[:N_ESTIMATE] = status.estimate
            row[N_ESTIMATE:] = (len(status.neighbours), int(status.mode), int(status.armed))
        self._tlog.write_agent_statuses(
            [s.t_s for s in statuses], [s.drone + 1 for s in statuses], values,
            [s.neighbours for s in statuses],
        )  # fmt: skip

    def send_command(self, drone: int, command: int, *params: float) -> None:
        """COMMAND_LONG ``command`` with up to 7 ``params`` to vehicle ``drone`` (index; system id
        drone + 1) through the simulator's GCS endpoint; OSError if nothing has been heard yet."""
        if self.sim_address is None:
            raise OSError("no telemetry heard yet: the simulator's address is unknown")
        padded = [float(p) for p in params] + [0.0] * (7 - len(params))
        msg = self._out.command_long_encode(drone + 1, 1, command, 0, *padded)
        address = self._address_of.get(drone + 1, self.sim_address)
        self._sock.sendto(msg.pack(self._out), address)

    def _handle(self, msg: Any) -> VehicleText | None:
        if msg.get_type() == "BAD_DATA":
            self.malformed += 1
            return None
        sysid = msg.get_srcSystem()
        if not 1 <= sysid <= 254:
            return None
        state = self._logged(sysid, getattr(msg, "time_boot_ms", None), bytes(msg.get_msgbuf()))
        kind = msg.get_type()
        if kind == "LOCAL_POSITION_NED":
            if not state.ardupilot:  # an ArduCopter's is about its own EKF origin
                state.position_ned_m = (msg.x, msg.y, msg.z)
                state.velocity_ned_m_s = (msg.vx, msg.vy, msg.vz)
        elif kind == "GLOBAL_POSITION_INT":
            if state.ardupilot:
                origin = self.origin if self.origin is not None else GeoPoint()
                ned = ned_of_global_int(origin, msg.lat, msg.lon, msg.alt)[0]
                state.position_ned_m = (float(ned[0]), float(ned[1]), float(ned[2]))
                state.velocity_ned_m_s = (msg.vx * 0.01, msg.vy * 0.01, msg.vz * 0.01)
        elif kind == "ATTITUDE":
            state.euler_rad = (msg.roll, msg.pitch, msg.yaw)
        elif kind == "HEARTBEAT":
            if msg.get_srcComponent() != 1:  # a companion's or a camera's: not the vehicle's
                return None
            state.armed = bool(msg.base_mode & _ARMED_FLAG)
            state.system_status = int(msg.system_status)
            state.ardupilot = int(msg.autopilot) == MAV_AUTOPILOT_ARDUPILOTMEGA
        elif kind == "STATUSTEXT":
            raw = getattr(msg, "_text_raw", b"")
            text = raw.split(b"\x00", 1)[0].decode("utf-8", "replace") if raw else str(msg.text)
            return VehicleText(state.t_s, sysid - 1, int(msg.severity), text)
        return None

    def _logged(self, sysid: int, boot_ms: Any, raw: bytes) -> VehicleState:
        """Vehicle ``sysid``'s state, its time moved to the packet's ``time_boot_ms`` where it
        has one (an int), and the packet ``raw`` recorded in the tlog at that time."""
        state = self.vehicles.setdefault(sysid - 1, VehicleState(t_s=self.sim_time_s))
        if isinstance(boot_ms, int):
            if self.epoch_s is not None:
                clock = self._clocks.get(sysid)
                if clock is None:
                    clock = self._clocks[sysid] = VehicleClock(self.epoch_s)
                boot_ms = clock.swarm_ms(boot_ms)
            state.t_s = boot_ms / 1000.0
            self.sim_time_s = max(self.sim_time_s, state.t_s)
        state.packets += 1
        self._tlog.write_packet(state.t_s, raw)
        return state

    def _fast(self, f: Frame, data: bytes) -> None:
        """:meth:`_handle` of a checked frame (of a vehicle, not one of :data:`_AS_OBJECTS`)
        from its unpacked fields, the values its message object would hold."""
        places = field_places(f.cls)
        at = places.at
        t = f.cls.unpacker.unpack(f.body)
        i = at.get("time_boot_ms")
        state = self._logged(f.sysid, None if i is None else t[i], data[f.start : f.end])
        kind = f.cls.msgname
        if kind == "LOCAL_POSITION_NED":
            if not state.ardupilot:
                state.position_ned_m = (t[at["x"]], t[at["y"]], t[at["z"]])
                state.velocity_ned_m_s = (t[at["vx"]], t[at["vy"]], t[at["vz"]])
        elif kind == "ATTITUDE":
            state.euler_rad = (t[at["roll"]], t[at["pitch"]], t[at["yaw"]])


#: The telemetry socket's receive buffer (bytes): seconds of a large swarm's telemetry at
#: several times real time, so that a station busy for a moment (starting again after the
#: gcs-restart drill, answering a command) loses none of it.
RECEIVE_BUFFER_BYTES = 16 * 1024 * 1024


def _large_receive_buffer(sock: socket.socket) -> None:
    """Ask for :data:`RECEIVE_BUFFER_BYTES` (beyond the kernel's rmem_max where allowed: as
    root; else as much as it grants)."""
    force = getattr(socket, "SO_RCVBUFFORCE", None)
    if force is not None:
        try:
            sock.setsockopt(socket.SOL_SOCKET, force, RECEIVE_BUFFER_BYTES)
            return
        except OSError:
            pass
    with contextlib.suppress(OSError):
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER_BYTES)

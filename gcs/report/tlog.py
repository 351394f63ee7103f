"""MAVLink 2 telemetry log (``.tlog``), the format MAVProxy and QGroundControl write.

A tlog is a sequence of records, each an 8-byte big-endian uint64 timestamp in microseconds
followed by one MAVLink packet. pymavlink's ``mavlogdump.py`` and MAVExplorer read it.

Timestamps: a record's timestamp is the *simulated* time in µs plus a fixed ``epoch_offset_s``
(default 0: the log starts on 1970-01-01, which mavlogdump reads fine, and two lockstep runs give
byte-identical logs). As MAVProxy does, the two low bits of the timestamp carry the link number
(here always 0), so a record time is rounded down to a multiple of 4 µs. Messages that carry
``time_boot_ms`` (LOCAL_POSITION_NED, ATTITUDE) hold the simulated time in ms; the reader takes
vehicle time from that field, not from the record timestamp, and from ``time_usec`` (µs) for
ACTUATOR_OUTPUT_STATUS (the rotor forces, N, of rotors 1..4: protocols/mavlink/conventions.py).
The ground station also logs each agent's status as DEBUG_FLOAT_ARRAY "AGENT" from the agent's
component (191), ``time_usec`` = simulated time (same file), so the log alone holds the flight;
layout 1 (``array_id``) carries the ids of the neighbours the agent integrated, layout 0 (older
logs) does not and reads back with those ids unknown (protocols/mavlink/conventions.py).

pymavlink is used only as a codec, one per (system id, component): the autopilot (1) for vehicle
telemetry, the onboard computer (191) for agent statuses; each carries its own sequence numbers.

ArduCopter-dialect vehicles (their HEARTBEAT's autopilot is ArduPilot; protocols/
mavlink/conventions.py) each keep their own EKF origin and their own boot clock: the reader takes
their position from GLOBAL_POSITION_INT about the swarm frame's origin (the GPS_GLOBAL_ORIGIN the
ground station, system 255, wrote at the start; the default home without one), and the time of
their positions and attitudes from the record timestamps (the swarm's clock, on which the ground
station stamped them: gcs/station/telemetry.py).

Where the vehicles' state estimates are not the truth (a scenario's [sensors]), their
LOCAL_POSITION_NED and ATTITUDE carry what each believes, and the simulator also sends its true
state as ODOMETRY (estimator type MOCAP; ``time_usec``): the reader then gives the truth as the
track (``position_ned_m``, ``euler_rad``...) and what the vehicle reported beside it
(``reported_t_s``, ``reported_position_ned_m``).
"""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"  # before any pymavlink import (DEPENDENCIES.md)

import dataclasses
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO

import numpy as np
import numpy.typing as npt
from pymavlink.dialects.v20 import ardupilotmega, common

from protocols.mavlink.conventions import (
    ACTUATOR_ROTORS,
    AGENT_COMPID,
    AGENT_NEIGHBOUR_SLOTS,
    AGENT_STATUS_LAYOUT,
    AGENT_STATUS_NAME,
    AGENT_STATUS_VALUES,
    GCS_SYSID,
    MAV_AUTOPILOT_ARDUPILOTMEGA,
    MAV_ESTIMATOR_TYPE_MOCAP,
    truth_odometry_fields,
)
from protocols.mavlink.fast import (
    FieldPlaces,
    Frame,
    field_places,
    frames,
    message_of,
    pack,
    pack_payload,
)
from protocols.model.frames import FloatArray, zyx_from_quat_batch
from protocols.model.geodesy import GeoPoint, ned_of_global_int

_TS = struct.Struct(">Q")
#: LOCAL_POSITION_NED's and ATTITUDE's payload: time_boot_ms and six floats
_SAMPLE = struct.Struct("<Iffffff")
_LPN, _ATT = common.MAVLink_local_position_ned_message, common.MAVLink_attitude_message
assert _LPN.unpacker.format == _ATT.unpacker.format == _SAMPLE.format
#: an agent status's DEBUG_FLOAT_ARRAY payload: time_usec, array_id, name, data[58]
_STATUS = struct.Struct("<QH10s58f")
_DEBUG_FLOAT_ARRAY = common.MAVLink_debug_float_array_message
assert _DEBUG_FLOAT_ARRAY.unpacker.format == _STATUS.format
_STATUS_NAME = AGENT_STATUS_NAME.encode()
_STATUS_ROW = np.dtype([("t", "<u8"), ("layout", "<u2"), ("name", "S10"), ("data", "<f4", (58,))])
assert _STATUS_ROW.itemsize == _STATUS.size


def _as_float32(values: Sequence[float]) -> list[float]:
    """``values`` rounded to float32 as ``struct``'s ``f`` rounds them, except that a finite value
    beyond float32's range becomes +-inf (``struct`` refuses it: a diverged agent estimate must
    not stop the ground station's log)."""
    with np.errstate(over="ignore"):
        return np.array(values, dtype=np.float64).astype(np.float32).tolist()


def _floats(values: Sequence[float] | FloatArray) -> Sequence[float]:
    """``values`` as numbers ``struct`` packs: an array's as Python floats (one C call)."""
    return values.tolist() if isinstance(values, np.ndarray) else values


_Rows = list[tuple[float, ...]]
_AUTOPILOT_COMPONENT = 1
#: A vehicle whose last sample is older than this is reported NaN by ``TlogTrack.resample``.
MAX_SAMPLE_AGE_S = 0.5


class TlogWriter:
    """Writes vehicle telemetry to a ``.tlog`` file; use as a context manager.

    ``epoch_offset_s`` is added to the simulated time to make each record's timestamp;
    ``append`` continues an existing log (a restarted ground station) instead of starting afresh.
    """

    def __init__(self, path: str | Path, epoch_offset_s: float = 0.0, append: bool = False) -> None:
        self.path = Path(path)
        self.append = append
        self.epoch_offset_us = round(epoch_offset_s * 1e6)
        self._codecs: dict[tuple[int, int], Any] = {}
        self._file: BinaryIO | None = None
        self.n_records = 0

    def __enter__(self) -> TlogWriter:
        self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def open(self) -> None:
        """Create (truncate) the file, or append to it with ``append``; done by ``__enter__``."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = self.path.open("ab" if self.append else "wb")

    def close(self) -> None:
        """Flush and close the file (idempotent)."""
        if self._file is not None:
            self._file.close()
            self._file = None

    def codec(self, sysid: int, compid: int = _AUTOPILOT_COMPONENT) -> Any:
        """The pymavlink MAVLink 2 codec speaking as ``sysid``, ``compid`` (default 1)."""
        if not 1 <= sysid <= 255:
            raise ValueError(f"system id {sysid} outside 1..255")
        key = (sysid, compid)
        if key not in self._codecs:
            self._codecs[key] = common.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        return self._codecs[key]

    def write_packet(self, t_s: float, packet: bytes) -> None:
        """Append one already-encoded MAVLink packet stamped with simulated time ``t_s`` (s)."""
        if self._file is None:
            raise RuntimeError("TlogWriter is not open (use it as a context manager)")
        usec = (round(t_s * 1e6) + self.epoch_offset_us) & ~0x3  # low bits: link 0
        if usec < 0:
            raise ValueError(f"record time {t_s} s before the epoch")
        self._file.write(_TS.pack(usec) + packet)
        self.n_records += 1

    def write_message(self, t_s: float, sysid: int, msg: Any) -> None:
        """Encode a pymavlink message object as ``sysid`` and append it."""
        self.write_packet(t_s, pack(msg, self.codec(sysid)))

    def write_vehicle_sample(
        self,
        t_s: float,
        sysid: int,
        position_ned_m: Sequence[float] | FloatArray,
        velocity_ned_m_s: Sequence[float] | FloatArray,
        euler_rad: Sequence[float] | FloatArray,
        body_rates_rad_s: Sequence[float] | FloatArray,
    ) -> None:
        """LOCAL_POSITION_NED and ATTITUDE of one vehicle at simulated time ``t_s`` (s).

        ``position_ned_m`` (3,), ``velocity_ned_m_s`` (3,), ``euler_rad`` (3,) roll, pitch, yaw,
        ``body_rates_rad_s`` (3,) p, q, r (arrays or lists of floats). ``time_boot_ms`` is the
        simulated time in ms. The frames are pymavlink's for the same fields (both messages are
        a uint32 and six floats: their payloads packed here, no message objects; a tlog's
        codecs never sign).
        """
        ms = _time_boot_ms(t_s)
        mav = self.codec(sysid)
        lpn = _SAMPLE.pack(ms, *_floats(position_ned_m), *_floats(velocity_ned_m_s))
        att = _SAMPLE.pack(ms, *_floats(euler_rad), *_floats(body_rates_rad_s))
        self.write_packet(t_s, pack_payload(_LPN, lpn, mav))
        self.write_packet(t_s, pack_payload(_ATT, att, mav))

    def write_truth(
        self,
        t_s: float,
        sysid: int,
        position_ned_m: FloatArray,
        velocity_ned_m_s: FloatArray,
        quat_wxyz: FloatArray,
        body_rates_rad_s: FloatArray,
    ) -> None:
        """The vehicle's true state at simulated ``t_s`` as the simulator sends it where the
        state estimates are not the truth (protocols/mavlink/conventions.py
        ``truth_odometry_fields``)."""
        mav = self.codec(sysid)
        msg = mav.odometry_encode(
            *truth_odometry_fields(
                round(t_s * 1e6), position_ned_m, velocity_ned_m_s, quat_wxyz, body_rates_rad_s
            )
        )
        self.write_packet(t_s, pack(msg, mav))

    def write_agent_status(
        self,
        t_s: float,
        sysid: int,
        values: FloatArray,
        neighbour_ids: Sequence[int] | None = None,
    ) -> None:
        """An agent's status (``values``: protocols/mavlink/conventions.py AGENT_STATUS_VALUES,
        NaN allowed) as DEBUG_FLOAT_ARRAY "AGENT" from (``sysid``, 191) at simulated ``t_s``.

        ``neighbour_ids``: the indices of the neighbours whose messages the agent integrated
        (layout 1; the lowest AGENT_NEIGHBOUR_SLOTS of them); None writes layout 0 (unknown)."""
        data = [float(v) for v in values][:AGENT_STATUS_VALUES]
        data += [float("nan")] * (AGENT_STATUS_VALUES - len(data))
        layout = 0
        if neighbour_ids is not None:
            layout = AGENT_STATUS_LAYOUT
            data += [float(j) for j in sorted(neighbour_ids)[:AGENT_NEIGHBOUR_SLOTS]]
        data += [float("nan")] * (58 - len(data))
        mav = self.codec(sysid, AGENT_COMPID)
        usec = max(0, round(t_s * 1e6))
        try:  # pymavlink's field order; struct rounds to float32 as numpy does
            payload = _STATUS.pack(usec, layout, _STATUS_NAME, *data)
        except OverflowError:  # a value beyond float32's range
            payload = _STATUS.pack(usec, layout, _STATUS_NAME, *_as_float32(data))
        self.write_packet(t_s, pack_payload(_DEBUG_FLOAT_ARRAY, payload, mav))

    def write_agent_statuses(
        self,
        t_s: Sequence[float],
        sysids: Sequence[int],
        values: FloatArray,
        neighbour_ids: Sequence[Sequence[int]],
    ) -> None:
        """:meth:`write_agent_status` of each row (``values`` (n, AGENT_STATUS_VALUES)) in order
        (layout 1): the same records, their payloads laid out together (one array) and written
        at once (no numba in the ground station: its first call would stall it)."""
        n = len(sysids)
        if n == 0:
            return
        rows = np.full((n, 58), np.nan)
        head = AGENT_STATUS_VALUES
        rows[:, :head] = np.asarray(values, dtype=np.float64)[:, :head]
        for r, ids in enumerate(neighbour_ids):
            if ids:
                kept = sorted(ids)[:AGENT_NEIGHBOUR_SLOTS]
                rows[r, head : head + len(kept)] = kept
        with np.errstate(over="ignore"):
            data = rows.astype(np.float32)  # (beyond float32: inf, as _as_float32)
        times = [round(t * 1e6) for t in t_s]
        if min(times) + self.epoch_offset_us < 0 or max(times) >= 2**62:
            for r in range(n):  # as one by one (which raises where it must)
                self.write_agent_status(t_s[r], sysids[r], values[r], neighbour_ids[r])
            return
        payload = np.zeros(n, dtype=_STATUS_ROW)
        payload["t"] = [max(0, t) for t in times]
        payload["layout"] = AGENT_STATUS_LAYOUT
        payload["name"] = _STATUS_NAME
        payload["data"] = data
        if self._file is None:
            raise RuntimeError("TlogWriter is not open (use it as a context manager)")
        payloads, size, offset = payload.tobytes(), _STATUS.size, self.epoch_offset_us
        self._file.write(b"".join(
            _TS.pack((t + offset) & ~0x3) + pack_payload(
                _DEBUG_FLOAT_ARRAY, payloads[r * size : (r + 1) * size],
                self.codec(sysid, AGENT_COMPID))
            for r, (t, sysid) in enumerate(zip(times, sysids, strict=True))
        ))  # fmt: skip
        self.n_records += n

    def write_heartbeat(
        self, t_s: float, sysid: int, armed: bool, system_status: int, custom_mode: int = 0
    ) -> None:
        """HEARTBEAT of a quadrotor (generic autopilot); ``system_status`` is a MAV_STATE."""
        base_mode = common.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if armed:
            base_mode |= common.MAV_MODE_FLAG_SAFETY_ARMED
        mav = self.codec(sysid)
        msg = mav.heartbeat_encode(
            common.MAV_TYPE_QUADROTOR,
            common.MAV_AUTOPILOT_GENERIC,
            base_mode,
            custom_mode,
            system_status,
            3,
        )
        self.write_packet(t_s, pack(msg, mav))

    def write_statustext(self, t_s: float, sysid: int, severity: int, text: str) -> None:
        """STATUSTEXT (``severity`` a MAV_SEVERITY); text longer than 50 bytes is chunked."""
        data = text.encode("utf-8")
        mav = self.codec(sysid)
        if len(data) <= 50:
            self.write_packet(t_s, pack(mav.statustext_encode(severity, data), mav))
            return
        # MAVLink 2 long text: a non-zero id, chunks of 50; a short (NUL-padded) chunk ends it.
        text_id = (self.n_records % 65535) + 1
        chunks = [data[k : k + 50] for k in range(0, len(data), 50)]
        if len(chunks[-1]) == 50:
            chunks.append(b"")
        for seq, chunk in enumerate(chunks):
            msg = mav.statustext_encode(severity, chunk, text_id, seq)
            self.write_packet(t_s, pack(msg, mav))


def _time_boot_ms(t_s: float) -> int:
    ms = round(t_s * 1000.0)
    if not 0 <= ms < 2**32:
        raise ValueError(f"simulated time {t_s} s outside the uint32 time_boot_ms range")
    return ms


@dataclass
class VehicleTrack:
    """Telemetry of one system id read back from a tlog.

    - ``t_s`` (K,): LOCAL_POSITION_NED time_boot_ms / 1000, s; ``position_ned_m`` (K, 3),
      ``velocity_ned_m_s`` (K, 3).
    - ``attitude_t_s`` (L,): ATTITUDE time_boot_ms / 1000, s; ``euler_rad`` (L, 3) roll, pitch, yaw;
      ``body_rates_rad_s`` (L, 3).
    - ``actuator_t_s`` (M,): ACTUATOR_OUTPUT_STATUS time_usec / 1e6, s; ``rotor_forces_n`` (M, 4)
      the forces of rotors 1..4, N (empty when the log has none).
    - ``status_t_s`` (S,): the agent's status times (DEBUG_FLOAT_ARRAY "AGENT"), s;
      ``status`` (S, AGENT_STATUS_VALUES): estimate (9), neighbours, mode, armed (empty if none);
      ``status_layout`` (S,) each status's layout (1: neighbour ids carried; 0: unknown);
      ``status_neighbours`` (S, AGENT_NEIGHBOUR_SLOTS) the ids of the neighbours integrated
      (ascending, NaN-padded; all NaN in layout 0): :meth:`neighbour_ids`.
    - ``heartbeat_t_s`` (H,): record times of the autopilot's HEARTBEATs, s; ``armed`` (H,) its
      armed flag; ``custom_mode`` (H,) its PX4 custom mode (protocols/mavlink/conventions.py).
    - ``named`` : NAMED_VALUE_FLOAT name -> (K, 2) rows of (time_boot_ms / 1000 s, value), e.g.
      the simulator's ``agt_intime`` and ``agt_lag_ms`` (sitl_sim/mavlink_edge/messages.py).
    - Where the log holds the vehicle's true state (ODOMETRY, module doc), the position,
      velocity, attitude and body rates above are the truth, and ``reported_t_s`` (R,),
      ``reported_position_ned_m`` (R, 3) what the vehicle reported (its state estimate).
    Samples are sorted by time.
    """

    t_s: FloatArray
    position_ned_m: FloatArray
    velocity_ned_m_s: FloatArray
    attitude_t_s: FloatArray
    euler_rad: FloatArray
    body_rates_rad_s: FloatArray
    actuator_t_s: FloatArray = field(default_factory=lambda: np.zeros(0))
    rotor_forces_n: FloatArray = field(default_factory=lambda: np.zeros((0, ACTUATOR_ROTORS)))
    status_t_s: FloatArray = field(default_factory=lambda: np.zeros(0))
    status: FloatArray = field(default_factory=lambda: np.zeros((0, AGENT_STATUS_VALUES)))
    status_layout: npt.NDArray[np.int64] = field(
        default_factory=lambda: np.zeros(0, dtype=np.int64)
    )
    status_neighbours: FloatArray = field(
        default_factory=lambda: np.zeros((0, AGENT_NEIGHBOUR_SLOTS))
    )
    heartbeat_t_s: FloatArray = field(default_factory=lambda: np.zeros(0))
    armed: npt.NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))
    custom_mode: npt.NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    named: dict[str, FloatArray] = field(default_factory=dict)
    #: where the log holds the true state (ODOMETRY): the positions the vehicle reported
    #: (LOCAL_POSITION_NED, its state estimate) at their times; empty otherwise
    reported_t_s: FloatArray = field(default_factory=lambda: np.zeros(0))
    reported_position_ned_m: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))

    def neighbour_ids(self, k: int) -> tuple[int, ...] | None:
        """The neighbours status ``k`` says its agent integrated; None where the layout carries
        none (layout 0: unknown)."""
        if self.status_layout[k] != AGENT_STATUS_LAYOUT:
            return None
        ids = self.status_neighbours[k]
        return tuple(int(j) for j in ids[np.isfinite(ids)])


@dataclass(frozen=True)
class StatusText:
    """A STATUSTEXT (long texts reassembled); ``t_s`` is the record time minus the epoch offset."""

    t_s: float
    sysid: int
    severity: int
    text: str


@dataclass
class TlogTrack:
    """What ``read_tlog`` found: per-system-id tracks, status texts, undecodable record count."""

    vehicles: dict[int, VehicleTrack]
    statustexts: list[StatusText] = field(default_factory=list)
    bad_records: int = 0

    def resample(
        self, t_grid_s: FloatArray, n_drones: int | None = None, max_age_s: float = MAX_SAMPLE_AGE_S
    ) -> FloatArray:
        """Positions (T, N, 3), NED m, of vehicles i = sysid - 1 on the time grid (T,), s.

        Sample-and-hold: each grid time takes the vehicle's latest sample at or before it (0.5 ms
        tolerance for the ms resolution of time_boot_ms). NaN before a vehicle's first sample,
        where that sample is older than ``max_age_s`` (the vehicle stopped sending), and for
        system ids without data. N defaults to the largest system id seen.
        """
        t_grid = np.asarray(t_grid_s, dtype=float)
        n = n_drones if n_drones is not None else max(self.vehicles, default=0)
        out = np.full((t_grid.shape[0], n, 3), np.nan)
        for sysid, track in self.vehicles.items():
            if not 1 <= sysid <= n or track.t_s.size == 0:
                continue
            k = np.searchsorted(track.t_s, t_grid + 5e-4, side="right") - 1
            ok = k >= 0
            kk = np.where(ok, k, 0)
            ok &= t_grid - track.t_s[kk] <= max_age_s + 5e-4
            out[ok, sysid - 1] = track.position_ned_m[kk[ok]]
        return out


def read_tlog(path: str | Path, epoch_offset_s: float = 0.0) -> TlogTrack:
    """Parse a tlog with the pymavlink codec (MAVLink 1 and 2 packets, signed or not).

    Undecodable records (bad CRC, unknown framing) are skipped and counted; a truncated last
    record is ignored. ``epoch_offset_s`` is subtracted from record times (status texts only).
    """
    reader = TlogReader(epoch_offset_s)
    reader.feed(Path(path).read_bytes())
    return reader.track()


def vehicle_samples(path: str | Path) -> dict[tuple[str, int, int], tuple[float, ...]]:
    """Every vehicle's LOCAL_POSITION_NED and ATTITUDE samples of a tlog, and its true state
    (ODOMETRY, where the log has it: module doc), field by field: ``(message type, system id,
    time ms)`` -> the message's other fields, as logged (the first sample of a key if it was
    logged twice). Two lockstep runs of one scenario and seed give equal dictionaries (the
    records' wall stamps are left out)."""
    reader = TlogReader()
    reader.feed(Path(path).read_bytes())
    out: dict[tuple[str, int, int], tuple[float, ...]] = {}
    tables = (("LOCAL_POSITION_NED", reader._pos), ("ATTITUDE", reader._att),
              ("ODOMETRY", reader._truth))  # fmt: skip
    for name, table in tables:
        for sysid, rows in table.items():
            for row in rows:
                out.setdefault((name, sysid, int(row[0])), tuple(row[1:]))
    return out


class TlogReader:
    """Reads a tlog piece by piece (a log still being written): :meth:`feed` the bytes that
    follow the last ones it consumed, :meth:`track` what has been read so far."""

    def __init__(self, epoch_offset_s: float = 0.0) -> None:
        self.epoch_offset_s = epoch_offset_s
        self._codec = ardupilotmega.MAVLink(None)  # an ArduPilot vehicle's messages too
        self._pos: dict[int, list[tuple[float, ...]]] = {}
        #: ArduCopter dialect: GLOBAL_POSITION_INT rows (record ms, lat, lon (degE7), alt (mm),
        #: vx, vy, vz (m/s)) and each ATTITUDE's record time (ms); which vehicles; the origin
        self._global: dict[int, list[tuple[float, ...]]] = {}
        self._att_rec: dict[int, list[float]] = {}
        self._ardupilot: set[int] = set()
        self.origin: GeoPoint | None = None
        self._att: dict[int, list[tuple[float, ...]]] = {}
        #: the true state (ODOMETRY): (ms, x, y, z, vx, vy, vz, w, qx, qy, qz, p, q, r)
        self._truth: dict[int, list[tuple[float, ...]]] = {}
        self._act: dict[int, list[tuple[float, ...]]] = {}
        self._agent: dict[int, list[tuple[float, ...]]] = {}
        self._beats: dict[int, list[tuple[float, ...]]] = {}
        self._named: dict[int, dict[str, list[tuple[float, float]]]] = {}
        self._texts: list[StatusText] = []
        self._chunks: dict[tuple[int, int], list[bytes]] = {}
        self._bad = 0
        #: (table, sysid) -> rows already made arrays, and those arrays: track() converts only
        #: the rows read since its last call (a drills run asks for it every half second)
        self._tables: dict[tuple[str, int], tuple[int, list[FloatArray]]] = {}

    def feed(self, data: bytes) -> int:
        """Parse the records of ``data``; the number of bytes consumed (a truncated last record
        is left for the next call, which starts with it)."""
        resyncing = False
        ofs, size = 0, len(data)
        while ofs + 8 + 8 <= size:
            length = _packet_length(data, ofs + 8)
            end = ofs + 8 + (length or 0)
            if length is not None and end > size:
                break  # truncated last record
            try:
                if length is None:
                    raise common.MAVError("no MAVLink marker")
                record = data[ofs + 8 : end]
                checked = frames(record)  # an unsigned MAVLink 2 record, usually
                if checked is not None and len(checked) == 1:
                    frame = checked[0]
                    if frame.cls.msgname not in _READ:  # checked, and nothing to read in it
                        resyncing, ofs = False, end
                        continue
                    if (rows := _FAST_ROWS.get(frame.cls.msgname)) is not None:
                        t_rec = _TS.unpack_from(data, ofs)[0] * 1e-6 - self.epoch_offset_s
                        resyncing, ofs = False, end
                        self._fast(rows, frame, t_rec)
                        continue
                msg = message_of(checked[0], record) if checked and len(checked) == 1 else None
                if msg is None:  # signed, MAVLink 1, another dialect's or a bad one
                    msg = self._codec.decode(bytearray(record))
            except (common.MAVError, ardupilotmega.MAVError):  # each dialect has its own class
                self._bad += 0 if resyncing else 1
                resyncing = True
                ofs += 1  # resynchronise byte by byte, as mavlogdump does
                continue
            resyncing = False
            t_rec = _TS.unpack_from(data, ofs)[0] * 1e-6 - self.epoch_offset_s
            ofs = end
            self._message(msg, t_rec)
        return ofs

    def _fast(self, rows: FieldPlaces, frame: Frame, t_rec: float) -> None:
        """The rows :meth:`_message` makes of the most frequent messages, from the unpacked
        payload's fields (the values of pymavlink's message object) without building it."""
        t = frame.cls.unpacker.unpack(frame.body)
        name, sysid = frame.cls.msgname, frame.sysid
        if name == "LOCAL_POSITION_NED":
            self._pos.setdefault(sysid, []).append(tuple(t[i] for i in rows.scalars))
        elif name == "ATTITUDE":
            self._att.setdefault(sysid, []).append(tuple(t[i] for i in rows.scalars))
            self._att_rec.setdefault(sysid, []).append(t_rec * 1000.0)
        elif name == "ACTUATOR_OUTPUT_STATUS":
            at = rows.arrays["actuator"]
            row = _actuator_row(t[rows.at["time_usec"]], t[at : at + ACTUATOR_ROTORS])
            self._act.setdefault(sysid, []).append(row)
        elif (
            name == "DEBUG_FLOAT_ARRAY"
            and frame.compid == AGENT_COMPID
            and _name(t[rows.at["name"]].rstrip(b"\x00")) == AGENT_STATUS_NAME
        ):
            at = rows.arrays["data"]
            row = _status_row(t[rows.at["time_usec"]], t[rows.at["array_id"]], t[at : at + 58])
            self._agent.setdefault(sysid, []).append(row)

    def _message(self, msg: Any, t_rec: float) -> None:
        sysid = msg.get_srcSystem()
        mtype = msg.get_type()
        if mtype == "LOCAL_POSITION_NED":
            row = (msg.time_boot_ms, msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz)
            self._pos.setdefault(sysid, []).append(row)
        elif mtype == "ATTITUDE":
            rates = (msg.rollspeed, msg.pitchspeed, msg.yawspeed)
            self._att.setdefault(sysid, []).append(
                (msg.time_boot_ms, msg.roll, msg.pitch, msg.yaw, *rates)
            )
            self._att_rec.setdefault(sysid, []).append(t_rec * 1000.0)
        elif mtype == "ODOMETRY" and msg.estimator_type == MAV_ESTIMATOR_TYPE_MOCAP:
            row = (msg.time_usec / 1000.0, msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz, *msg.q,
                   msg.rollspeed, msg.pitchspeed, msg.yawspeed)  # fmt: skip
            self._truth.setdefault(sysid, []).append(row)
        elif mtype == "GLOBAL_POSITION_INT":
            row = (t_rec * 1000.0, msg.lat, msg.lon, msg.alt,
                   msg.vx * 0.01, msg.vy * 0.01, msg.vz * 0.01)  # fmt: skip
            self._global.setdefault(sysid, []).append(row)
        elif mtype == "GPS_GLOBAL_ORIGIN" and sysid == GCS_SYSID:
            self.origin = GeoPoint(msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3)
        elif mtype == "ACTUATOR_OUTPUT_STATUS":
            self._act.setdefault(sysid, []).append(_actuator_row(msg.time_usec, msg.actuator))
        elif mtype == "DEBUG_FLOAT_ARRAY" and msg.get_srcComponent() == AGENT_COMPID:
            if _name(msg.name) == AGENT_STATUS_NAME:
                status = _status_row(msg.time_usec, msg.array_id, msg.data)
                self._agent.setdefault(sysid, []).append(status)
        elif mtype == "HEARTBEAT" and msg.get_srcComponent() == _AUTOPILOT_COMPONENT:
            if msg.autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
                self._ardupilot.add(sysid)
            armed = float(bool(msg.base_mode & common.MAV_MODE_FLAG_SAFETY_ARMED))
            beat = (t_rec * 1000.0, armed, float(msg.custom_mode))
            self._beats.setdefault(sysid, []).append(beat)
        elif mtype == "NAMED_VALUE_FLOAT":
            rows = self._named.setdefault(sysid, {}).setdefault(_name(msg.name), [])
            rows.append((msg.time_boot_ms / 1000.0, float(msg.value)))
        elif mtype == "STATUSTEXT":
            text = _statustext(msg, sysid, self._chunks)
            if text is not None:
                self._texts.append(StatusText(t_rec, sysid, int(msg.severity), text))

    def track(self) -> TlogTrack:
        """Everything read so far."""
        pos, att, act, agent, beats = self._pos, self._att, self._act, self._agent, self._beats
        if self._ardupilot:
            pos, att = dict(pos), dict(att)
            for s in self._ardupilot:
                pos[s], att[s] = self._ardupilot_rows(s)
        vehicles = {
            s: _track(
                *(
                    _by_time(rows.get(s, []), width)
                    if s in self._ardupilot and kind in ("pos", "att")  # made anew each call
                    else self._table(kind, s, rows.get(s, []), width)
                    for kind, rows, width in (
                        ("pos", pos, 7),
                        ("att", att, 7),
                        ("act", act, 1 + ACTUATOR_ROTORS),
                        ("agent", agent, 2 + AGENT_STATUS_VALUES + AGENT_NEIGHBOUR_SLOTS),
                        ("beats", beats, 3),
                    )
                )
            )
            for s in sorted(set(pos) | set(att) | set(act) | set(agent))
        }
        for s, rows in self._truth.items():
            if s in vehicles:
                vehicles[s] = _with_truth(vehicles[s], self._table("truth", s, rows, 14))
        for s, values in self._named.items():
            if s in vehicles:
                vehicles[s].named = {
                    name: _by_time([tuple(r) for r in rows], 2) for name, rows in values.items()
                }
        return TlogTrack(vehicles, list(self._texts), self._bad)

    def _table(
        self, kind: str, sysid: int, rows: list[tuple[float, ...]], width: int
    ) -> FloatArray:
        """``_by_time(rows, width)``, converting only the rows added since the last call."""
        done, arrays = self._tables.get((kind, sysid), (0, []))
        if len(rows) > done:
            arrays.append(np.asarray(rows[done:], dtype=float).reshape(-1, width))
        if len(arrays) > 1:
            arrays[:] = [np.concatenate(arrays)]
        self._tables[(kind, sysid)] = (len(rows), arrays)
        table = arrays[0] if arrays else np.empty((0, width))
        return table[np.argsort(table[:, 0], kind="stable")]

    def _ardupilot_rows(self, sysid: int) -> tuple[_Rows, _Rows]:
        """An ArduCopter vehicle's position rows (record ms, NED about the origin, velocity) and
        attitude rows on record times (module doc)."""
        rows = self._global.get(sysid, [])
        pos: list[tuple[float, ...]] = []
        if rows:
            table = np.asarray(rows, dtype=float)
            origin = self.origin if self.origin is not None else GeoPoint()
            ned = ned_of_global_int(origin, table[:, 1], table[:, 2], table[:, 3])
            out = np.column_stack([table[:, 0], ned, table[:, 4:7]])
            pos = [tuple(r) for r in out.tolist()]
        att = [
            (t, *row[1:])
            for t, row in zip(self._att_rec.get(sysid, []), self._att.get(sysid, []), strict=True)
        ]
        return pos, att


def _actuator_row(time_usec: int, actuator: Sequence[float]) -> tuple[float, ...]:
    """An ACTUATOR_OUTPUT_STATUS row: (ms, the rotors' forces)."""
    return (time_usec / 1000.0, *actuator[:ACTUATOR_ROTORS])


def _status_row(time_usec: int, layout: int, data: Sequence[float]) -> tuple[float, ...]:
    """An agent status row (DEBUG_FLOAT_ARRAY "AGENT"): (ms, values, layout, neighbour ids;
    NaN ids in layout 0, the older logs' that had none)."""
    ids: Sequence[float] = data[AGENT_STATUS_VALUES:58]
    if int(layout) != AGENT_STATUS_LAYOUT:
        ids = [float("nan")] * AGENT_NEIGHBOUR_SLOTS
    return (time_usec / 1000.0, *data[:AGENT_STATUS_VALUES], float(int(layout)), *ids)


#: The messages :class:`TlogReader` reads rows from its own way (nine in ten records of a flight).
_FAST_ROWS = {
    cls.msgname: field_places(cls)
    for cls in (
        common.MAVLink_local_position_ned_message,
        common.MAVLink_attitude_message,
        common.MAVLink_actuator_output_status_message,
        common.MAVLink_debug_float_array_message,
    )
}
#: The messages TlogReader._message reads (keep the two together); a checked frame of another
#: is skipped unbuilt.
_READ = frozenset(
    {
        "LOCAL_POSITION_NED", "ATTITUDE", "ODOMETRY", "GLOBAL_POSITION_INT", "GPS_GLOBAL_ORIGIN",
        "ACTUATOR_OUTPUT_STATUS", "DEBUG_FLOAT_ARRAY", "HEARTBEAT", "NAMED_VALUE_FLOAT",
        "STATUSTEXT",
    }
)  # fmt: skip


def _packet_length(data: bytes, ofs: int) -> int | None:
    """Length of the MAVLink packet starting at ``ofs``, None if no valid marker there."""
    marker = data[ofs]
    if marker == common.PROTOCOL_MARKER_V2:
        signed = data[ofs + 2] & common.MAVLINK_IFLAG_SIGNED
        return 10 + data[ofs + 1] + 2 + (common.MAVLINK_SIGNATURE_BLOCK_LEN if signed else 0)
    if marker == common.PROTOCOL_MARKER_V1:
        return 6 + data[ofs + 1] + 2
    return None


def _statustext(msg: Any, sysid: int, chunks: dict[tuple[int, int], list[bytes]]) -> str | None:
    raw = getattr(msg, "_text_raw", None)
    raw = raw.split(b"\x00", 1)[0] if isinstance(raw, bytes) else str(msg.text).encode("utf-8")
    text_id = int(getattr(msg, "id", 0))
    if text_id == 0:
        return raw.decode("utf-8", errors="replace")
    parts = chunks.setdefault((sysid, text_id), [])
    parts.append(raw)
    if len(raw) == 50:
        return None
    del chunks[(sysid, text_id)]
    return b"".join(parts).decode("utf-8", errors="replace")


def _name(raw: Any) -> str:
    """A fixed-length MAVLink char[] field as text (pymavlink gives str or bytes)."""
    text = raw.decode("ascii", "replace") if isinstance(raw, bytes) else str(raw)
    return text.split("\x00", 1)[0]


def _track(
    p: FloatArray, a: FloatArray, f: FloatArray, st: FloatArray, hb: FloatArray
) -> VehicleTrack:
    """Rows ``(time ms, values...)`` of each message (position, attitude, actuators, agent
    status, heartbeat), sorted by time, as a track."""
    end = 1 + AGENT_STATUS_VALUES
    return VehicleTrack(
        t_s=p[:, 0] / 1000.0,
        position_ned_m=p[:, 1:4],
        velocity_ned_m_s=p[:, 4:7],
        attitude_t_s=a[:, 0] / 1000.0,
        euler_rad=a[:, 1:4],
        body_rates_rad_s=a[:, 4:7],
        actuator_t_s=f[:, 0] / 1000.0,
        rotor_forces_n=f[:, 1:],
        status_t_s=st[:, 0] / 1000.0,
        status=st[:, 1:end],
        status_layout=st[:, end].astype(np.int64),
        status_neighbours=st[:, end + 1 :],
        heartbeat_t_s=hb[:, 0] / 1000.0,
        armed=hb[:, 1] > 0.5,
        custom_mode=hb[:, 2].astype(np.int64),
    )


def _with_truth(track: VehicleTrack, truth: FloatArray) -> VehicleTrack:
    """``track`` with its position, velocity and attitude taken from the true-state rows
    ``truth`` (ms, x, y, z, vx, vy, vz, w, qx, qy, qz, p, q, r), what it reported kept beside."""
    yaw, pitch, roll = zyx_from_quat_batch(np.ascontiguousarray(truth[:, 7:11].T))
    t = truth[:, 0] / 1000.0
    return dataclasses.replace(
        track,
        t_s=t,
        position_ned_m=truth[:, 1:4],
        velocity_ned_m_s=truth[:, 4:7],
        attitude_t_s=t,
        euler_rad=np.column_stack([roll, pitch, yaw]),
        body_rates_rad_s=truth[:, 11:14],
        reported_t_s=track.t_s,
        reported_position_ned_m=track.position_ned_m,
    )


def _by_time(rows: list[tuple[float, ...]], width: int) -> FloatArray:
    table = np.asarray(rows, dtype=float).reshape(-1, width)
    return table[np.argsort(table[:, 0], kind="stable")]

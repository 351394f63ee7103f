"""The messages that put a vehicle on a ground station's map: GLOBAL_POSITION_INT, GPS_RAW_INT,
HOME_POSITION and EXTENDED_SYS_STATE, built from the world's NED state and its home point.

The NED origin is the scenario's ``[home]`` (protocols/model/geodesy.py: the tangent plane at home,
altitude flat). Every vehicle reports that one point as its HOME_POSITION (x = y = z = 0: the
swarm's shared launch point), so the map shows one home and each vehicle at its own place. (In
the ArduCopter dialect each vehicle's home is where it started, and ``relative_alt`` is above it:
sitl_sim/mavlink_edge/dialect.py.)

- GLOBAL_POSITION_INT: the telemetry position (with its noise, the one LOCAL_POSITION_NED carries
  at the same tick) as latitude/longitude (degE7), altitude MSL and above home (mm), NED velocity
  (cm/s) and heading (cdeg, 0..35999).
- GPS_RAW_INT: the same fix as a 3-D fix from 12 satellites, HDOP 0.8, VDOP 1.2, accuracies the
  position noise (at least 1 cm); ``alt_ellipsoid`` = ``alt`` (no geoid).
- EXTENDED_SYS_STATE: landed state ON_GROUND (in contact), LANDING (LAND mode in the air), TAKEOFF
  (armed, climbing, below :data:`TAKEOFF_HEIGHT_M` above the ground), else IN_AIR.

The geodetic conversion is done once per tick for every vehicle when first asked
(:class:`MapFix`), so a tick with many vehicles due costs one vectorised conversion.
"""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"  # before any pymavlink import (DEPENDENCIES.md)

import math
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from protocols.model.geodesy import GeoPoint, ned_to_geodetic
from sitl_sim.vehicle.autopilot import Autopilot, Mode
from sitl_sim.vehicle.world import Snapshot

#: Below this height (m) above the ground, an armed vehicle climbing is taking off.
TAKEOFF_HEIGHT_M = 1.0
#: Climb rate (m/s, up) above which a low vehicle counts as taking off rather than hovering.
TAKEOFF_CLIMB_M_S = 0.1
SATELLITES = 12
HDOP_CENTI, VDOP_CENTI = 80, 120
_DEG_E7 = 1e7
_I16 = 32767
_U16_UNKNOWN = 0xFFFF


class MapFix:
    """Latitude, longitude (degE7) and altitude MSL (mm) of every vehicle at one snapshot."""

    def __init__(self, home: GeoPoint, snap: Snapshot) -> None:
        lat, lon, alt = ned_to_geodetic(home, np.asarray(snap.position_ned_m, dtype=float))
        self.tick = snap.tick
        self.lat_e7: list[int] = np.rint(lat * _DEG_E7).astype(np.int64).tolist()
        self.lon_e7: list[int] = np.rint(lon * _DEG_E7).astype(np.int64).tolist()
        self.alt_mm: list[int] = np.rint(alt * 1000.0).astype(np.int64).tolist()


def _cm_s(v: float) -> int:
    return max(-_I16, min(_I16, round(v * 100.0)))


def _cdeg(angle_rad: float) -> int:
    return round(math.degrees(angle_rad) * 100.0) % 36000


def global_position_int(
    snap: Snapshot, fix: MapFix, home: GeoPoint, i: int, home_alt_mm: int | None = None
) -> Any:
    """GLOBAL_POSITION_INT of vehicle ``i`` at the snapshot's time; ``relative_alt`` is above
    ``home_alt_mm`` (mm MSL; None: ``home``'s altitude)."""
    vn, ve, vd = snap.velocity_ned_m_s[i]
    if home_alt_mm is None:
        home_alt_mm = round(home.alt_m * 1000.0)
    relative_mm = fix.alt_mm[i] - home_alt_mm
    return mavlink.MAVLink_global_position_int_message(
        snap.time_boot_ms, fix.lat_e7[i], fix.lon_e7[i], fix.alt_mm[i], relative_mm,
        _cm_s(vn), _cm_s(ve), _cm_s(vd), _cdeg(snap.euler_rad[i][2]),
    )  # fmt: skip


_GLOBAL_POSITION = np.dtype(
    [("t", "<u4"), ("where", "<i4", (4,)), ("v", "<i2", (3,)), ("hdg", "<u2")]
)


def global_position_int_rows(snap: Snapshot, fix: MapFix, home: GeoPoint) -> Any:
    """:func:`global_position_int` of every vehicle (sitl_sim/mavlink_edge/messages.py
    ``Rows``: the same bytes; None where a value would not pack as struct packs it)."""
    _, velocity, euler, _ = snap.columns()
    yaw = euler[:, 2]
    if not (np.isfinite(velocity).all() and np.isfinite(yaw).all()):
        return None  # (round() refuses them: the one-by-one builder raises as before)
    alt = np.array(fix.alt_mm, dtype=np.int64)
    where = np.stack([np.array(fix.lat_e7, dtype=np.int64), np.array(fix.lon_e7, dtype=np.int64),
                      alt, alt - round(home.alt_m * 1000.0)], axis=1)  # fmt: skip
    if not (0 <= snap.time_boot_ms < 2**32 and (np.abs(where) < 2**31).all()):
        return None
    rows = np.empty(where.shape[0], dtype=_GLOBAL_POSITION)
    rows["t"] = snap.time_boot_ms
    rows["where"] = where
    rows["v"] = np.clip(np.rint(velocity * 100.0), -_I16, _I16)
    rows["hdg"] = np.mod(np.rint(np.degrees(yaw) * 100.0).astype(np.int64), 36000)
    return rows.view(np.uint8).reshape(where.shape[0], _GLOBAL_POSITION.itemsize)


def gps_raw_int(snap: Snapshot, fix: MapFix, accuracy_m: float, i: int) -> Any:
    """GPS_RAW_INT of vehicle ``i``: a 3-D fix at the telemetry position; ``accuracy_m`` the
    horizontal and vertical accuracy claimed (m)."""
    vn, ve, _ = snap.velocity_ned_m_s[i]
    speed = math.hypot(vn, ve)
    cog = _cdeg(math.atan2(ve, vn)) if speed > 0.05 else _U16_UNKNOWN
    acc_mm = max(10, round(accuracy_m * 1000.0))
    return mavlink.MAVLink_gps_raw_int_message(
        snap.time_boot_ms * 1000, mavlink.GPS_FIX_TYPE_3D_FIX, fix.lat_e7[i], fix.lon_e7[i],
        fix.alt_mm[i], HDOP_CENTI, VDOP_CENTI, min(round(speed * 100.0), _U16_UNKNOWN - 1), cog,
        SATELLITES, fix.alt_mm[i], acc_mm, acc_mm, 50, 0, 0,
    )  # fmt: skip


def gps_no_fix(time_usec: int) -> Any:
    """GPS_RAW_INT of a receiver without a fix (ArduPilot before its first fix): fix type 1,
    position and altitude 0, accuracies and course unknown, no satellites."""
    return mavlink.MAVLink_gps_raw_int_message(
        time_usec, mavlink.GPS_FIX_TYPE_NO_FIX, 0, 0, 0, _U16_UNKNOWN, _U16_UNKNOWN, 0,
        _U16_UNKNOWN, 0, 0, 0, 0, 0, 0, 0,
    )  # fmt: skip


def home_position(home: GeoPoint, time_usec: int) -> Any:
    """HOME_POSITION: the scenario's home, the NED origin (x = y = z = 0), approach unset."""
    return mavlink.MAVLink_home_position_message(
        round(home.lat_deg * _DEG_E7), round(home.lon_deg * _DEG_E7), round(home.alt_m * 1000.0),
        0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, time_usec,
    )  # fmt: skip


def landed_state(ap: Autopilot, snap: Snapshot, i: int) -> int:
    """MAV_LANDED_STATE of vehicle ``i``."""
    if ap.landed[i]:
        return int(mavlink.MAV_LANDED_STATE_ON_GROUND)
    if ap.armed[i] and ap.mode[i] == Mode.LAND:
        return int(mavlink.MAV_LANDED_STATE_LANDING)
    height_m = -snap.position_ned_m[i][2]
    climbing = -snap.velocity_ned_m_s[i][2] > TAKEOFF_CLIMB_M_S
    if ap.armed[i] and climbing and height_m < TAKEOFF_HEIGHT_M:
        return int(mavlink.MAV_LANDED_STATE_TAKEOFF)
    return int(mavlink.MAV_LANDED_STATE_IN_AIR)


def extended_sys_state(ap: Autopilot, snap: Snapshot, i: int) -> Any:
    """EXTENDED_SYS_STATE of vehicle ``i`` (a multicopter: VTOL state undefined)."""
    return mavlink.MAVLink_extended_sys_state_message(
        mavlink.MAV_VTOL_STATE_UNDEFINED, landed_state(ap, snap, i)
    )

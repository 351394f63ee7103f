"""The map's telemetry of a flight, read back from its flight.tlog and held against the swarm's
own: every GLOBAL_POSITION_INT a vehicle sent agrees with the LOCAL_POSITION_NED and ATTITUDE it
sent around the same ``time_boot_ms`` (position about the scenario's home, velocity, heading;
the local samples carried to the global one's time: position by its velocity, velocity and
heading linearly; a velocity across a touch-down against the nearer local sample). A map
ground station (QGroundControl, Mission Planner, MAVSDK) draws a drone from those fields alone."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")

import numpy as np
from pymavlink import mavutil

from protocols.model.geodesy import GeoPoint, ned_of_global_int


@dataclass(frozen=True)
class MapAgreement:
    """The worst disagreements over the pairs compared: horizontal and vertical position (m),
    velocity (m/s), heading (deg); how many pairs; the largest speed and heading change seen
    (that the flight moved and turned)."""

    pairs: int
    position_m: float
    altitude_m: float
    velocity_m_s: float
    heading_deg: float
    top_speed_m_s: float
    heading_span_deg: float
    #: where the worst velocity disagreement was: (system id, time_boot_ms in s)
    velocity_worst_at: tuple[int, float] = (0, 0.0)


def map_agreement(tlog: Path, home: GeoPoint, t_from_s: float = 0.0) -> MapAgreement:
    """Compare each vehicle's GLOBAL_POSITION_INT with its LOCAL_POSITION_NED and ATTITUDE of
    the same ``time_boot_ms`` (from ``t_from_s`` on)."""
    glob: dict[int, list[tuple[float, ...]]] = {}
    local: dict[int, list[tuple[float, ...]]] = {}
    att: dict[int, list[tuple[float, float]]] = {}
    log = mavutil.mavlink_connection(str(tlog), dialect="common")
    while msg := log.recv_match(type=["GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ATTITUDE"]):
        sysid, t = msg.get_srcSystem(), msg.time_boot_ms / 1000.0
        if t < t_from_s:
            continue
        kind = msg.get_type()
        if kind == "GLOBAL_POSITION_INT":
            row = (t, msg.lat, msg.lon, msg.alt, msg.vx, msg.vy, msg.vz, msg.hdg)
            glob.setdefault(sysid, []).append(row)
        elif kind == "LOCAL_POSITION_NED":
            local.setdefault(sysid, []).append((t, msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz))
        else:
            att.setdefault(sysid, []).append((t, msg.yaw))
    worst = np.zeros(4)
    pairs, top_speed, span = 0, 0.0, 0.0
    worst_at = (0, 0.0)
    for sysid, rows in glob.items():
        g = np.array(rows, dtype=float)
        n = np.unique(np.array(local[sysid], dtype=float), axis=0)
        a = np.unique(np.array(att[sysid], dtype=float), axis=0)
        inside = (g[:, 0] >= n[0, 0]) & (g[:, 0] <= n[-1, 0]) & (g[:, 0] >= a[0, 0])
        g = g[inside & (g[:, 0] <= a[-1, 0])]
        if g.shape[0] == 0:
            continue
        k = np.clip(np.searchsorted(n[:, 0], g[:, 0], side="right") - 1, 0, n.shape[0] - 2)
        dt = (g[:, 0] - n[k, 0])[:, None]
        pos = n[k, 1:4] + n[k, 4:7] * dt
        vel = np.stack([np.interp(g[:, 0], n[:, 0], n[:, c]) for c in (4, 5, 6)], axis=1)
        yaw = np.interp(g[:, 0], a[:, 0], np.unwrap(a[:, 1]))
        ned = ned_of_global_int(home, g[:, 1], g[:, 2], g[:, 3])
        heading_err = (g[:, 7] / 100.0 - np.degrees(yaw) + 180.0) % 360.0 - 180.0
        # the velocity the map shows against the local one carried to its time, or, across a
        # touch-down (the ground stops a 0.7 m/s descent between two local samples), against the
        # local sample on either side of it: whichever is nearer
        v_map = g[:, 4:7] / 100.0
        vel_err = np.min(
            [np.abs(v_map - v).max(axis=1) for v in (vel, n[k, 4:7], n[k + 1, 4:7])], axis=0
        )
        # and not at all where one of the two local samples rests on the ground and the other
        # does not: the lift-off's kick (0.14 m/s up 20 ms after the ground let go, 0.06 m/s
        # 20 ms later) lives between two local samples, which cannot tell it
        resting = (np.abs(n[:, 3]) < 1e-3) & (np.abs(n[:, 4:7]).max(axis=1) < 1e-3)
        vel_err = np.where(resting[k] != resting[k + 1], 0.0, vel_err)
        if vel_err.max() > worst[2]:
            worst_at = (sysid, float(g[vel_err.argmax(), 0]))
        worst = np.maximum(
            worst,
            [
                np.linalg.norm(ned[:, :2] - pos[:, :2], axis=1).max(),
                np.abs(ned[:, 2] - pos[:, 2]).max(),
                vel_err.max(),
                np.abs(heading_err).max(),
            ],
        )
        pairs += g.shape[0]
        top_speed = max(top_speed, float(np.linalg.norm(n[:, 4:6], axis=1).max()))
        turned = np.degrees(np.unwrap(a[:, 1]))
        span = max(span, float(turned.max() - turned.min()))
    assert pairs, "no GLOBAL_POSITION_INT within the vehicles' local samples"
    return MapAgreement(pairs, *(float(x) for x in worst), top_speed, span, worst_at)

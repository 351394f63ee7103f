"""The messages an ArduCopter vehicle sends differently from PX4, built from the world's state.

pymavlink is used only as a codec, as in :mod:`sitl_sim.mavlink_edge.messages`.

- HEARTBEAT: MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_ARDUPILOTMEGA, ``base_mode`` CUSTOM_MODE_ENABLED
  (+ SAFETY_ARMED when armed), ``custom_mode`` the copter mode number
  (:data:`sitl_sim.vehicle.copter.COPTER_MODE`), ``system_status`` as PX4's.
- EKF_STATUS_REPORT (id 193, ardupilotmega.xml: not in common.xml, so a peer decoding with the
  common dialect alone sees it as an unknown message): before the EKF is ready only
  EKF_UNINITIALIZED (:data:`EKF_NOT_READY_FLAGS`), then :data:`EKF_READY_REPORTED` (attitude,
  velocities, relative and absolute positions, and the predicted ones).
- LOCAL_POSITION_NED about the vehicle's own start (its EKF origin): each ArduCopter instance
  keeps its own origin, so two vehicles side by side both start at zero.
"""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"  # before any pymavlink import (DEPENDENCIES.md)

from collections.abc import Sequence
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega
from pymavlink.dialects.v20 import common as mavlink

from protocols.mavlink.conventions import (
    EKF_READY_FLAGS,
    MAV_AUTOPILOT_ARDUPILOTMEGA,
    MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
    MAV_MODE_FLAG_SAFETY_ARMED,
    MAV_TYPE_QUADROTOR,
)
from sitl_sim.mavlink_edge.messages import system_status
from sitl_sim.vehicle.autopilot import Autopilot, Mode
from sitl_sim.vehicle.copter import COPTER_MODE
from sitl_sim.vehicle.world import Snapshot

#: EKF_STATUS_REPORT flags: EKF_PRED_POS_HORIZ_REL | EKF_PRED_POS_HORIZ_ABS, and uninitialised.
EKF_PREDICTED_POSITIONS = 0x100 | 0x200
EKF_UNINITIALIZED = 0x400
EKF_READY_REPORTED = EKF_READY_FLAGS | EKF_PREDICTED_POSITIONS
EKF_NOT_READY_FLAGS = EKF_UNINITIALIZED
#: EKF_STATUS_REPORT variances (test ratios: below 0.5 is good, 1 is at the limit).
_SETTLED_VARIANCE = 0.02
_UNSETTLED_VARIANCE = 1.0
_COPTER_MODE_NUMBER = {mode: int(number) for mode, number in COPTER_MODE.items()}


def heartbeat(ap: Autopilot, i: int) -> Any:
    """ArduCopter's HEARTBEAT of vehicle ``i``."""
    base_mode = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if ap.armed[i]:
        base_mode |= MAV_MODE_FLAG_SAFETY_ARMED
    return mavlink.MAVLink_heartbeat_message(
        MAV_TYPE_QUADROTOR,
        MAV_AUTOPILOT_ARDUPILOTMEGA,
        base_mode,
        _COPTER_MODE_NUMBER[Mode(int(ap.mode[i]))],
        system_status(ap, i),
        3,
    )


def ekf_status_report(ready: bool) -> Any:
    """EKF_STATUS_REPORT of a vehicle whose EKF is (not yet) ready."""
    flags = EKF_READY_REPORTED if ready else EKF_NOT_READY_FLAGS
    variance = _SETTLED_VARIANCE if ready else _UNSETTLED_VARIANCE
    return ardupilotmega.MAVLink_ekf_status_report_message(
        flags, variance, variance, variance, variance, 0.0, 0.0
    )


def local_position_ned(snap: Snapshot, start_ned_m: Sequence[Sequence[float]], i: int) -> Any:
    """LOCAL_POSITION_NED of vehicle ``i``: position (m) about its start (``start_ned_m``, one
    (north, east, down) per vehicle) in the world's NED axes, velocity (m/s) NED."""
    x, y, z = snap.position_ned_m[i]
    x0, y0, z0 = start_ned_m[i]
    vx, vy, vz = snap.velocity_ned_m_s[i]
    return mavlink.MAVLink_local_position_ned_message(
        snap.time_boot_ms, x - x0, y - y0, z - z0, vx, vy, vz
    )

"""The autopilot dialect the simulator speaks on the wire: PX4 (the default) or ArduCopter.

``swarm sim --dialect`` (:class:`~protocols.mavlink.conventions.Dialect`, carried by
:attr:`sitl_sim.vehicle.world.WorldConfig.dialect`) chooses it once at start; the flight core
follows it (sitl_sim/vehicle/world.py: :mod:`sitl_sim.vehicle.copter` for ArduCopter), and here one
class per firmware behind one base tells the server, the dispatcher and the command handler, which
never branch on the firmware themselves:

- which message of a control tick, sent to an agent, makes the lockstep barrier await that agent
  (:attr:`SimDialect.tick_message`), and the tick's state sent again to an agent that is new or
  late (:attr:`SimDialect.tick_state`);
- the streamed messages it builds its own way (:meth:`SimDialect.builders`) and its default
  stream rates and phases (:meth:`SimDialect.agent_rates`, :meth:`SimDialect.gcs_rates`,
  :attr:`SimDialect.agent_phases`);
- how DO_SET_MODE and SET_MODE name the modes (:attr:`SimDialect.modes`), and how a
  SET_ATTITUDE_TARGET is checked (:attr:`SimDialect.validate`);
- the parameter table (:func:`tunables_for`).

PX4 (:class:`SimDialect` itself) is the simulator's behaviour before dialects existed, byte for
byte. ArduCopter (:class:`ArduCopterSim`, modelled on ArduCopter 4.6 SITL):

- HEARTBEAT ARDUPILOTMEGA with copter mode numbers (sitl_sim/mavlink_edge/copter_messages.py);
DO_SET_MODE's
  param2 and SET_MODE's ``custom_mode`` are copter modes: GUIDED_NOGPS (20), LAND (9), BRAKE (17)
  and LOITER (5), flown as the simulator's HOLD and reported as BRAKE; others are DENIED.
- Until its EKF is ready (``ekf_ready_s``, sitl_sim/vehicle/copter.py): EKF_STATUS_REPORT flags
  EKF_UNINITIALIZED, GPS_RAW_INT without a fix, SYS_STATUS's pre-arm bit
  (MAV_SYS_STATUS_PREARM_CHECK) present and enabled but not healthy; then the ready EKF flags, a
  3-D fix, the bit healthy.
  EKF_STATUS_REPORT goes to the GCS at 1 Hz, SYS_STATUS and GPS_RAW_INT as for PX4; an agent asks
  for them (MAV_CMD_SET_MESSAGE_INTERVAL).
- Positions: each vehicle's LOCAL_POSITION_NED is about its own start (its own EKF origin, as
  every ArduCopter instance has); GLOBAL_POSITION_INT is its true place on the map
  (sitl_sim/mavlink_edge/map_telemetry.py, about the scenario's home), its ``relative_alt`` above
  its own start; HOME_POSITION is its own start.
- On an agent link ATTITUDE, LOCAL_POSITION_NED and GLOBAL_POSITION_INT go out at the link's state
  rate (``--agent-rate-hz``, every control tick by default), in phase, all stamped with the tick's
  ``time_boot_ms``; the lockstep barrier keys on GLOBAL_POSITION_INT (the position an ArduCopter
  agent flies by). The echo in SET_ATTITUDE_TARGET's ``time_boot_ms`` is as for PX4 (a real
  ArduCopter ignores that field; the lockstep is our extension).
- SET_ATTITUDE_TARGET's thrust is clamped to 0..1 (ArduCopter constrains rather than rejects; a
  non-finite value or a bad quaternion is still rejected and counted), then read per GUID_OPTIONS
  (sitl_sim/vehicle/copter.py).
- Parameters: the common table without the PX4 failsafe's, plus GUID_OPTIONS, MOT_THST_HOVER,
  WPNAV_SPEED_UP, WPNAV_SPEED_DN, GUID_TIMEOUT, SYSID_THISMAV and the GCS failsafe's SYSID_MYGCS,
  FS_GCS_ENABLE and FS_GCS_TIMEOUT (ArduCopter 4.6's names), each with its ArduPilot
  MAV_PARAM_TYPE (:func:`sitl_sim.vehicle.copter.copter_params`). A PARAM_SET of a name it does not
  have is ignored, as ArduPilot does (no PARAM_VALUE, no STATUSTEXT).
- HEARTBEATs from the vehicle's SYSID_MYGCS (on its agent link, or the GCS link) feed the GCS
  heartbeat failsafe, on simulated time (sitl_sim/vehicle/copter.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any, Protocol

import numpy as np

from protocols.mavlink.conventions import CopterMode, Dialect
from protocols.model.geodesy import GeoPoint, ned_to_geodetic
from sitl_sim.mavlink_edge import copter_messages, map_telemetry, messages
from sitl_sim.mavlink_edge.commands import ModeDecoder, Px4Modes
from sitl_sim.mavlink_edge.dispatch import HeartbeatWatch, SetpointCheck
from sitl_sim.mavlink_edge.map_telemetry import MapFix
from sitl_sim.mavlink_edge.streams import (
    ATTITUDE,
    COPTER_AGENT_PHASE,
    COPTER_AGENT_RATES_HZ,
    COPTER_GCS_RATES_HZ,
    EKF_STATUS_REPORT,
    GLOBAL_POSITION_INT,
    GPS_RAW_INT,
    HEARTBEAT,
    HOME_POSITION,
    LOCAL_POSITION_NED,
    PHASE,
    SYS_STATUS,
)
from sitl_sim.vehicle.autopilot import Mode
from sitl_sim.vehicle.copter import PX4_FAILSAFE_PARAMS, CopterAutopilot, copter_params
from sitl_sim.vehicle.setpoint import AttitudeSetpoint, Rejection, validate_attitude_target
from sitl_sim.vehicle.tunables import FleetAttitudeGains, Tunables
from sitl_sim.vehicle.world import Snapshot, World

#: A streamed message of vehicle ``i`` now.
Builder = Callable[[int], Any]


class TelemetrySource(Protocol):
    """What a dialect's message builders read from the server at the current tick."""

    def snapshot(self) -> Snapshot:
        """Every vehicle's telemetry at the current tick."""
        ...

    def map_fix(self) -> MapFix:
        """Every vehicle's geodetic position at the current tick."""
        ...

    def sys_status(self, i: int, prearm_ok: bool | None = None) -> Any:
        """Vehicle ``i``'s SYS_STATUS (``prearm_ok``:
        :func:`sitl_sim.mavlink_edge.messages.sys_status`)."""
        ...


class SimDialect:
    """The PX4 dialect, and the interface (module doc)."""

    name = Dialect.PX4
    #: the message whose tick, sent to an agent, has the lockstep barrier await that agent
    tick_message: int = LOCAL_POSITION_NED
    #: the current tick's state sent again to a new or awaited agent, in this order
    tick_state: tuple[int, ...] = (ATTITUDE, LOCAL_POSITION_NED)
    #: where each streamed message starts in its interval on an agent link, and to the GCS
    agent_phases: Mapping[int, float] = PHASE
    gcs_phases: Mapping[int, float] = PHASE

    def __init__(self, world: World) -> None:
        self.world = world
        self.modes: ModeDecoder = Px4Modes()
        self.validate: SetpointCheck = validate_attitude_target
        #: what received HEARTBEATs do (None: nothing); a PARAM_SET of an unknown name unanswered
        self.on_heartbeat: HeartbeatWatch | None = None
        self.quiet_unknown_params = False

    def builders(self, source: TelemetrySource) -> dict[int, Builder]:
        """The streamed messages this dialect builds its own way (none for PX4), by id."""
        return {}

    def agent_rates(self, rates: Mapping[int, float]) -> Mapping[int, float]:
        """The agent links' default rates (Hz) given the configured ones."""
        return rates

    def gcs_rates(self, rates: Mapping[int, float]) -> Mapping[int, float]:
        """The GCS link's default rates (Hz) given the configured ones."""
        return rates


class CopterModes:
    """ArduCopter's modes: DO_SET_MODE param2 and SET_MODE ``custom_mode`` are the copter mode
    number (module doc)."""

    FLOWN: Mapping[int, Mode] = {
        CopterMode.GUIDED_NOGPS: Mode.OFFBOARD,
        CopterMode.LAND: Mode.LAND,
        CopterMode.BRAKE: Mode.HOLD,
        CopterMode.LOITER: Mode.HOLD,
    }

    def params_of_custom(self, custom_mode: int) -> tuple[int, int]:
        return custom_mode, 0

    def mode_of_params(self, param2: int, param3: int) -> Mode | str:
        mode = self.FLOWN.get(param2)
        if mode is not None:
            return mode
        known = {int(m): m.name for m in CopterMode}
        name = known.get(param2, str(param2))
        return f"Mode change denied: {name} not available (GUIDED_NOGPS, BRAKE, LAND)"


def copter_setpoint(quat_wxyz: Any, thrust: float, type_mask: int) -> AttitudeSetpoint | Rejection:
    """ArduCopter's check of a SET_ATTITUDE_TARGET: the thrust clamped to 0..1 (a climb rate is
    read from 0..1, a thrust from -1..1 with the negative part as 0), the rest as PX4's."""
    value = float(thrust)
    if math.isfinite(value):
        value = min(max(value, 0.0), 1.0)
    return validate_attitude_target(quat_wxyz, value, type_mask)


class ArduCopterSim(SimDialect):
    """The ArduCopter dialect (module doc)."""

    name = Dialect.ARDUPILOT
    tick_message = GLOBAL_POSITION_INT
    tick_state = (ATTITUDE, LOCAL_POSITION_NED, GLOBAL_POSITION_INT)
    agent_phases = COPTER_AGENT_PHASE
    #: the GCS's record takes an ArduCopter's position from GLOBAL_POSITION_INT: on the ticks of
    #: its attitude and its agent's status (half an interval later, a moving centre read 2 cm
    #: stale: the distributed report's consensus error 1.9 cm instead of 0.07)
    gcs_phases = COPTER_AGENT_PHASE

    def __init__(self, world: World) -> None:
        super().__init__(world)
        assert isinstance(world.autopilot, CopterAutopilot), "world not built for ArduCopter"
        self.autopilot: CopterAutopilot = world.autopilot
        self.modes = CopterModes()
        self.validate = copter_setpoint
        ap = self.autopilot
        self.on_heartbeat = lambda sysid, i: ap.heartbeat_from(sysid, world.t_s, i)
        self.quiet_unknown_params = True  # ArduPilot ignores them (the agents set 4.7's names too)
        home = world.config.home
        self.start_ned_m: list[list[float]] = world.start_ned_m.tolist()
        lat, lon, alt = ned_to_geodetic(home, world.start_ned_m)
        #: each vehicle's home: where it started
        self.homes = [
            GeoPoint(float(a), float(o), float(h)) for a, o, h in zip(lat, lon, alt, strict=True)
        ]
        self.home_alt_mm = [int(v) for v in np.rint(alt * 1000.0)]

    def builders(self, source: TelemetrySource) -> dict[int, Builder]:
        world, ap = self.world, self.autopilot
        home, start, homes, home_alt = (
            world.config.home, self.start_ned_m, self.homes, self.home_alt_mm
        )  # fmt: skip
        noise = world.config.position_noise_m

        def gps(i: int) -> Any:
            if not ap.ready[i]:
                return map_telemetry.gps_no_fix(messages.time_usec(world))
            return map_telemetry.gps_raw_int(source.snapshot(), source.map_fix(), noise, i)

        return {
            HEARTBEAT: lambda i: copter_messages.heartbeat(ap, i),
            SYS_STATUS: lambda i: source.sys_status(i, bool(ap.ready[i])),
            LOCAL_POSITION_NED: lambda i: copter_messages.local_position_ned(
                source.snapshot(), start, i
            ),
            GLOBAL_POSITION_INT: lambda i: map_telemetry.global_position_int(
                source.snapshot(), source.map_fix(), home, i, home_alt[i]
            ),
            GPS_RAW_INT: gps,
            HOME_POSITION: lambda i: map_telemetry.home_position(
                homes[i], messages.time_usec(world)
            ),
            EKF_STATUS_REPORT: lambda i: copter_messages.ekf_status_report(bool(ap.ready[i])),
        }

    def agent_rates(self, rates: Mapping[int, float]) -> Mapping[int, float]:
        """The configured rates, plus the ArduCopter messages they do not name (at their
        defaults: :data:`sitl_sim.mavlink_edge.streams.COPTER_AGENT_RATES_HZ`)."""
        return _with_defaults(rates, COPTER_AGENT_RATES_HZ)

    def gcs_rates(self, rates: Mapping[int, float]) -> Mapping[int, float]:
        return _with_defaults(rates, COPTER_GCS_RATES_HZ)


def _with_defaults(rates: Mapping[int, float], defaults: Mapping[int, float]) -> dict[int, float]:
    """``rates``, and the messages of ``defaults`` they do not name at their default rates."""
    out = dict(rates)
    for msg_id, rate in defaults.items():
        out.setdefault(msg_id, rate)
    return out


def sim_dialect(world: World) -> SimDialect:
    """The dialect object of ``world``'s vehicles (``world.config.dialect``)."""
    if world.config.dialect == Dialect.ARDUPILOT:
        return ArduCopterSim(world)
    return SimDialect(world)


def tunables_for(world: World, gains: FleetAttitudeGains, sysids: list[int]) -> Tunables:
    """The parameter table of ``world``'s vehicles in their dialect."""
    ap = world.autopilot
    if isinstance(ap, CopterAutopilot):
        return Tunables(ap, gains, sysids, copter_params(ap, sysids), PX4_FAILSAFE_PARAMS)
    return Tunables(ap, gains, sysids)

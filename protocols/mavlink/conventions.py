"""MAVLink conventions shared by the simulator, the agents and the ground station.

Identities (SPEC.md "Conventions"): vehicle index i = 0..N-1 is MAVLink system id ``i + 1``,
component 1 (autopilot). Its agent speaks as the same system id with component 191 (onboard
computer). The ground station is system 255, component 190.

Ports (:func:`vehicle_port`): by default vehicles 0..9 serve their agents on UDP 14540..14549 (the
PX4 SITL habit) and vehicles 10..249 on 14560..14799, so that no vehicle ever lands on the GCS
port 14550 (where the simulator sends the telemetry of every vehicle; QGroundControl listens there)
whatever the number of drones. With an explicit ``--base-port B`` vehicle i is on ``B + i``, and a
clash with the GCS port is an error (:func:`port_clash`). The simulator *listens* on
the agent ports and answers the address a packet last came from; it *sends* to the GCS address and
answers GCS commands arriving on that same socket.

Modes use PX4's custom-mode encoding so GCS tools (MAVProxy, QGroundControl) name them:
``custom_mode = main_mode << 16 | sub_mode << 24``, HEARTBEAT autopilot MAV_AUTOPILOT_PX4.

Units on the wire: SET_ATTITUDE_TARGET carries a quaternion (w, x, y, z) body FRD -> world NED and a
*normalised* collective thrust 0..1 of the vehicle's maximum (PX4 offboard convention).

Rotor outputs: ACTUATOR_OUTPUT_STATUS (id 375; streamed to the GCS at the state rate, off on an
agent link unless asked for) carries the *force in newtons* of rotors 1..4 in ``actuator[0..3]``
(``active`` = 0b1111, the other entries 0) and ``time_usec`` = simulated time in µs, on the same
clock as ``time_boot_ms``. Rotor order (sitl_sim/physics/mixer.py, body FRD, plus frame): 1 left
(-y), 2 front (+x), 3 right (+y), 4 back (-x), so with arm length D and yaw moment per newton k (m):
thrust ``T = F1+F2+F3+F4``, moments ``l = D(F1-F3)``, ``m = D(F2-F4)``, ``n = k(F1-F2+F3-F4)``
(``sitl_sim.physics.mixer.wrench_from_rotor_forces``).

Agent status in the ground station's log: DEBUG_FLOAT_ARRAY (id 350) named "AGENT" from system
``i + 1``, component 191, ``time_usec`` = the status's simulated time (µs), ``array_id`` the
layout version (:data:`AGENT_STATUS_LAYOUT`); ``data[0..8]`` the agent's estimate of the
descriptors (m, rad, m²; NaN if it has none), ``data[9]`` its neighbour count, ``data[10]`` its
mode (protocols/wire_status.AgentMode), ``data[11]`` armed (0/1). Layout 1 adds, in
``data[12..57]``, the indices (system id - 1) of the neighbours whose messages the agent integrated
that tick (the status's ``neighbours``), ascending, NaN after the last; an agent integrating more
than :data:`AGENT_NEIGHBOUR_SLOTS` carries its lowest 46 (``data[9]`` still counts them all).
Layout 0 (``array_id`` 0, logs written before layout 1) has NaN there: its neighbours are unknown.
Only the ground station (and ``swarm simulate``'s recorder) writes it (into flight.tlog); agents
publish their status on Zenoh.

Lockstep handshake (needs nothing beyond standard MAVLink; SPEC.md "Time"):
1. The simulator sends the state of control tick k to each agent: ATTITUDE and
   LOCAL_POSITION_NED with ``time_boot_ms = k * control_period_ms``.
2. The agent answers with SET_ATTITUDE_TARGET whose own ``time_boot_ms`` echoes that value (also
   while disarmed on the ground: thrust 0, it still acknowledges the tick).
3. The simulator advances one control period once it holds tick k's setpoint from every vehicle
   in the barrier. A vehicle joins the barrier with its agent's first echoed setpoint; an agent
   silent for the wall-clock timeout leaves it (its vehicle failsafes).
The agent takes its clock from these time stamps, never from the host.

Details of the simulator's side (``swarm sim``, sitl_sim/mavlink_edge/lockstep.py and
sitl_sim/server.py):
- ``time_boot_ms`` of tick k is ``round(k * 1000 / control_hz)``; an echo names tick k only if
  it equals that value exactly. A join counts with an echo of a tick at most 50 ticks old.
- A vehicle is awaited at tick k only if tick k's LOCAL_POSITION_NED went to its agent (an agent
  that asked for a lower rate is awaited at the ticks it sees). The echo counts for the barrier
  even when the setpoint itself is rejected (NaN, out of range): it is the agent's liveness.
- While it waits, the simulator re-sends the current tick's ATTITUDE and LOCAL_POSITION_NED
  every 0.25 s wall time, and at once to a new agent address: an agent may see one tick twice and
  should answer it again without advancing its own state twice.
- Tick 0 waits up to ``--join-timeout`` for ``--wait-agents`` agents (so several agents start on
  the same tick); while nobody holds the barrier, time runs paced at ``--speedup``. A crashed
  vehicle that went silent leaves the barrier at once.
- Each vehicle reports its receive counters in SYS_STATUS: errors_comm = every rejected frame,
  errors_count1 malformed, errors_count2 rejected setpoints, errors_count3 signature failures,
  errors_count4 wrong target system.
"""

from __future__ import annotations

from collections.abc import Iterable
from enum import IntEnum, StrEnum
from typing import Any

GCS_SYSID = 255
GCS_COMPID = 190
AUTOPILOT_COMPID = 1
AGENT_COMPID = 191
AGENT_STATUS_NAME = "AGENT"
#: Values of the agent status in the log: estimate (9), neighbours, mode, armed.
AGENT_STATUS_VALUES = 12
#: The agent status's layout version (DEBUG_FLOAT_ARRAY ``array_id``): 1 carries neighbour ids.
AGENT_STATUS_LAYOUT = 1
#: Neighbour ids an agent status carries (layout 1): the 58 floats less the 12 values.
AGENT_NEIGHBOUR_SLOTS = 58 - AGENT_STATUS_VALUES

DEFAULT_BASE_PORT = 14540
DEFAULT_GCS_PORT = 14550
#: The default layout's second block: vehicles 10.. on 14560 + (i - 10), clear of 14550..14559.
DEFAULT_SECOND_BASE_PORT = 14560
PX4_PORT_BLOCK = 10
MAX_VEHICLES = 250  # system ids 1..250; 251..255 stay free for ground stations

#: Lockstep: the simulator's default wall-clock timeout (s) after which a silent agent leaves the
#: barrier (``swarm sim --lockstep-timeout``, sitl_sim.sim_config.ClockConfig.drop_timeout_s).
LOCKSTEP_DROP_TIMEOUT_S = 10.0

#: MAVLink 2 signing: link id used by the simulator's outgoing telemetry.
SIGNING_LINK_ID = 0

#: Above this altitude (m) a vehicle counts as airborne: the agents' flight phase (never sent less
#: than the minimum thrust), the ground station and ``swarm simulate``'s record.
AIRBORNE_ALTITUDE_M = 0.1
#: MAV_CMD_COMPONENT_ARM_DISARM ``param2`` that forces a disarm in flight.
FORCE_DISARM_MAGIC = 21196.0


class MavState(IntEnum):
    """HEARTBEAT ``system_status`` (MAV_STATE)."""

    UNINIT = 0
    BOOT = 1
    CALIBRATING = 2
    STANDBY = 3
    ACTIVE = 4
    CRITICAL = 5
    EMERGENCY = 6
    POWEROFF = 7
    FLIGHT_TERMINATION = 8


#: The states in which a vehicle is lost to its agent (crashed, or terminated).
LOST_STATES = frozenset({MavState.EMERGENCY, MavState.FLIGHT_TERMINATION})


class MavSeverity(IntEnum):
    """STATUSTEXT ``severity`` (MAV_SEVERITY). EMERGENCY: the vehicle is lost (motors off,
    crashed); the agents leave the swarm on it and the ground station logs a crash."""

    EMERGENCY = 0
    ALERT = 1
    CRITICAL = 2
    ERROR = 3
    WARNING = 4
    NOTICE = 5
    INFO = 6
    DEBUG = 7


class MavResult(IntEnum):
    """COMMAND_ACK ``result`` (MAV_RESULT)."""

    ACCEPTED = 0
    TEMPORARILY_REJECTED = 1
    DENIED = 2
    UNSUPPORTED = 3
    FAILED = 4
    IN_PROGRESS = 5


#: ACTUATOR_OUTPUT_STATUS: rotors in ``actuator[0..ACTUATOR_ROTORS-1]`` (forces, N), their bits.
ACTUATOR_ROTORS = 4
ACTUATOR_ROTORS_ACTIVE = (1 << ACTUATOR_ROTORS) - 1


def vehicle_port(index: int, base_port: int | None = None) -> int:
    """UDP port of vehicle ``index``'s agent link: ``base_port + index`` when a base is given,
    else the default layout (module doc): never the default GCS port, for any number of drones."""
    if base_port is not None:
        return base_port + index
    if index < PX4_PORT_BLOCK:
        return DEFAULT_BASE_PORT + index
    return DEFAULT_SECOND_BASE_PORT + index - PX4_PORT_BLOCK


def vehicle_ports(n: int, base_port: int | None = None) -> list[int]:
    """The agent-link ports of vehicles 0..n-1."""
    return [vehicle_port(i, base_port) for i in range(n)]


def port_clash(
    ports: list[int], gcs_port: int | None, base_flag: str = "--base-port"
) -> str | None:
    """Why this port layout cannot work (one line naming the clash), or None: every port in
    1..65535, no two vehicles on one port, no vehicle on the GCS port."""
    for i, port in enumerate(ports):
        if not 1 <= port <= 65535:
            return (
                f"{base_flag} {ports[0]}: vehicle {i} (system id {sysid_of(i)}) would listen on "
                f"UDP {port}, outside 1..65535"
            )
    seen: dict[int, int] = {}
    for i, port in enumerate(ports):
        if port in seen:
            return f"vehicles {seen[port]} and {i} would both listen on UDP {port}"
        seen[port] = i
    if gcs_port is not None and gcs_port in seen:
        i = seen[gcs_port]
        return (
            f"vehicle {i} (system id {sysid_of(i)}) would listen on UDP {gcs_port}, the ground "
            f"station's port: choose {base_flag} so that the {len(ports)} vehicle ports "
            f"{ports[0]}..{ports[-1]} leave {gcs_port} out, or another --gcs-port (or leave "
            f"both to their defaults, which never collide)"
        )
    return None


def describe_ports(ports: list[int]) -> str:
    """Ports as ranges, e.g. ``14540-14549, 14560-14561``."""
    ranges: list[list[int]] = []
    for port in ports:
        if ranges and port == ranges[-1][1] + 1:
            ranges[-1][1] = port
        else:
            ranges.append([port, port])
    return ", ".join(f"{a}-{b}" if a != b else f"{a}" for a, b in ranges)


def sysid_of(index: int) -> int:
    """MAVLink system id of vehicle ``index`` (0-based)."""
    return index + 1


def index_of(sysid: int) -> int:
    """Vehicle index (0-based) of a MAVLink system id."""
    return sysid - 1


class Px4MainMode(IntEnum):
    """PX4 main modes (custom_mode bits 16..23)."""

    MANUAL = 1
    ALTCTL = 2
    POSCTL = 3
    AUTO = 4
    ACRO = 5
    OFFBOARD = 6
    STABILIZED = 7


class Px4AutoSubMode(IntEnum):
    """PX4 sub modes of AUTO (custom_mode bits 24..31)."""

    READY = 1
    TAKEOFF = 2
    LOITER = 3
    MISSION = 4
    RTL = 5
    LAND = 6


def px4_custom_mode(main: int, sub: int = 0) -> int:
    """The 32-bit HEARTBEAT custom_mode of a PX4 main/sub mode."""
    return (int(main) << 16) | (int(sub) << 24)


def px4_mode_of(custom_mode: int) -> tuple[int, int]:
    """(main, sub) of a PX4 custom_mode."""
    return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF


#: The modes the simulated autopilot flies.
MODE_HOLD = px4_custom_mode(Px4MainMode.AUTO, Px4AutoSubMode.LOITER)
MODE_OFFBOARD = px4_custom_mode(Px4MainMode.OFFBOARD)
MODE_LAND = px4_custom_mode(Px4MainMode.AUTO, Px4AutoSubMode.LAND)
MODE_NAMES = {MODE_HOLD: "HOLD", MODE_OFFBOARD: "OFFBOARD", MODE_LAND: "LAND"}


# -- autopilot dialects ------------------------------------------------------------------------
#
# The agents fly two firmware dialects (drone_agent/process/dialects.py; the simulator speaks
# either, ``swarm sim --dialect``). PX4 (above) is the project's own simulator's default.
# ArduCopter: HEARTBEAT autopilot MAV_AUTOPILOT_ARDUPILOTMEGA, ``custom_mode`` = the copter mode
# number (:class:`CopterMode`, base_mode has CUSTOM_MODE_ENABLED); attitude + thrust setpoints are
# flown in GUIDED_NOGPS; the agent holds in BRAKE and lands in LAND. SET_ATTITUDE_TARGET's thrust is
# a climb rate unless GUID_OPTIONS has bit 3 (:data:`GUID_OPTIONS_THRUST`): 0.5 holds, above climbs
# at up to WPNAV_SPEED_UP (cm/s) at 1, below descends at up to WPNAV_SPEED_DN at 0. As a thrust it
# is the motors' linearised throttle, hover at MOT_THST_HOVER, divided by the cosine of the tilt
# by the attitude controller (angle boost). Each ArduCopter vehicle keeps its own EKF origin, so
# its LOCAL_POSITION_NED is relative to where it started: the swarm's one frame comes from
# GLOBAL_POSITION_INT and a common origin (protocols/model/geodesy.py).


class Dialect(StrEnum):
    """The autopilot firmware a vehicle speaks (``--dialect``)."""

    PX4 = "px4"
    ARDUPILOT = "ardupilot"


#: HEARTBEAT autopilot values of the two dialects.
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12
#: HEARTBEAT ``type`` of a quadrotor, base_mode flags.
MAV_TYPE_QUADROTOR = 2
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_SAFETY_ARMED = 128


def dialect_of_autopilot(autopilot: int) -> Dialect | None:
    """The dialect of a HEARTBEAT's ``autopilot`` field, None if neither."""
    if autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
        return Dialect.ARDUPILOT
    if autopilot == MAV_AUTOPILOT_PX4:
        return Dialect.PX4
    return None


class CopterMode(IntEnum):
    """ArduCopter's flight modes (HEARTBEAT custom_mode) the project uses or names."""

    STABILIZE = 0
    ALT_HOLD = 2
    GUIDED = 4
    LOITER = 5
    RTL = 6
    LAND = 9
    BRAKE = 17
    GUIDED_NOGPS = 20


#: GUID_OPTIONS bit 3: SET_ATTITUDE_TARGET's thrust is a thrust, not a climb rate.
GUID_OPTIONS_THRUST = 8
#: ArduCopter's defaults of the parameters the climb-rate reading uses (cm/s).
WPNAV_SPEED_UP_CM_S = 250.0
WPNAV_SPEED_DN_CM_S = 150.0
#: GUID_TIMEOUT (s): GUIDED_NOGPS without a new attitude target levels and holds its altitude.
GUID_TIMEOUT_S = 3.0

#: EKF_STATUS_REPORT flags (EKF_STATUS_FLAGS) an ArduCopter vehicle must show before it flies:
#: attitude, velocities, relative and absolute horizontal position, absolute vertical position.
EKF_READY_FLAGS = 0x001 | 0x002 | 0x004 | 0x008 | 0x010 | 0x020
#: ... and must not show: constant position mode, uninitialised, GPS glitch.
EKF_BAD_FLAGS = 0x080 | 0x400 | 0x8000
#: SYS_STATUS sensor bit MAV_SYS_STATUS_PREARM_CHECK: healthy = its pre-arm checks pass.
SYS_STATUS_PREARM_CHECK = 0x10000000
#: GPS_RAW_INT fix_type of a 3-D fix.
GPS_FIX_3D = 3
#: Message ids the ArduCopter dialect streams or asks for.
MSG_GLOBAL_POSITION_INT = 33
MSG_ATTITUDE = 30
MSG_LOCAL_POSITION_NED = 32
MSG_SYS_STATUS = 1
MSG_GPS_RAW_INT = 24
MSG_EKF_STATUS_REPORT = 193

#: MAV_FRAME_LOCAL_NED and MAV_ESTIMATOR_TYPE_MOCAP (common.xml): the frame and the estimator
#: type of the ODOMETRY that carries a vehicle's true state (:func:`truth_odometry_fields`)
MAV_FRAME_LOCAL_NED = 1
MAV_ESTIMATOR_TYPE_MOCAP = 6
_NO_COVARIANCE = (float("nan"),) * 21


def truth_odometry_fields(
    time_usec: int,
    position_ned_m: Iterable[float],
    velocity_ned_m_s: Iterable[float],
    quat_wxyz: Iterable[float],
    body_rates_rad_s: Iterable[float],
) -> tuple[Any, ...]:
    """ODOMETRY's fields, in order, for a vehicle's true state (the simulator's, not its
    autopilot's estimate), sent where the state estimates are not the truth: position and
    velocity in the world NED frame, attitude (w, x, y, z), body rates, no covariance, estimator
    type MOCAP (what a motion-capture system, a lab's ground truth, would measure). The simulator
    sends it (sitl_sim/mavlink_edge/messages.py), ``swarm simulate``'s tlog writes it and the tlog
    reader takes ODOMETRY of this estimator type as the truth (gcs/report/tlog.py)."""
    x, y, z = (float(v) for v in position_ned_m)
    vx, vy, vz = (float(v) for v in velocity_ned_m_s)
    p, q, r = (float(v) for v in body_rates_rad_s)
    return (
        time_usec, MAV_FRAME_LOCAL_NED, MAV_FRAME_LOCAL_NED, x, y, z,
        [float(v) for v in quat_wxyz], vx, vy, vz, p, q, r,
        list(_NO_COVARIANCE), list(_NO_COVARIANCE), 0, MAV_ESTIMATOR_TYPE_MOCAP,
    )  # fmt: skip

"""The autopilot dialects an agent speaks: one class per firmware behind one interface.

An agent never branches on the firmware elsewhere: its vehicle link
(drone_agent/process/vehicle_link.py) holds one :class:`AutopilotDialect`, taken from the vehicle's
HEARTBEAT (its ``autopilot`` field) unless ``--dialect`` forces one, and asks it

- which of the agent's modes the vehicle is in (:meth:`AutopilotDialect.modes`: flying the
  agent's setpoints, its own LAND, its own hold) and how to ask for each
  (:meth:`~AutopilotDialect.offboard_command`, :meth:`~AutopilotDialect.land_command`,
  :meth:`~AutopilotDialect.hold_command`);
- what to set up on the vehicle, and whether the vehicle is ready to fly
  (:meth:`~AutopilotDialect.service`, :attr:`~AutopilotDialect.ready` and
  :attr:`~AutopilotDialect.not_ready_reason`);
- how its thrust goes on the wire (:meth:`~AutopilotDialect.wire_thrust`);
- which message carries the position in the swarm's frame (:attr:`~AutopilotDialect.global_frame`).

PX4 (the project's own simulator's default): OFFBOARD, AUTO.LAND, AUTO.LOITER; the thrust is the
normalised thrust of the vehicle's maximum; LOCAL_POSITION_NED is already in the swarm's frame
(one simulator, one origin); always ready.

ArduCopter (protocols/mavlink/conventions.py, "autopilot dialects"): GUIDED_NOGPS flies
SET_ATTITUDE_TARGET, LAND lands and disarms, BRAKE holds. The agent reads GUID_OPTIONS and sets its
bit 3 (thrust as thrust, not a climb rate), and counts it done only once a PARAM_VALUE says so;
it makes itself the vehicle's GCS for the heartbeat failsafe (MAV_GCS_SYSID, SYSID_MYGCS before
ArduPilot 4.7, = the vehicle's own system id: its companion's heartbeats count) with
FS_GCS_ENABLE = 5 (land), so that a vehicle whose agent dies lands after FS_GCS_TIMEOUT (5 s)
instead of hovering on in GUIDED_NOGPS (which only levels and holds its altitude), also confirmed
by PARAM_VALUE;
it reads MOT_THST_HOVER once to put its thrust in the autopilot's units:
``throttle = thrust / weight * hover * cos(roll) cos(pitch)`` (the attitude controller divides by
the cosine again: angle boost, so the throttle sent is the vertical thrust in hover units).
``hover`` starts at MOT_THST_HOVER and is then estimated in flight from what the throttle did: a
vertical thrust ``u`` (hover units) accelerates the vehicle up by ``g (u / H - 1)``, so each
sample's measured vertical acceleration gives ``H = u g / (g + a_up)``, low-passed with the time
constant :data:`HOVER_LEARN_TC_S` while the vehicle is armed, above idle and nearly level. Without
it the paper's controller, a PD without an integral, holds a steady altitude error wherever the
parameter is off (measured on ArduCopter SITL: 0.3 m high at 5 m with MOT_THST_HOVER 0.39). (A
learning from the throttle that holds the vehicle, as ArduCopter's own, is an integral of the
altitude error: after an overshoot it held the swarm up for 30 s.)
It asks for the messages it needs (ATTITUDE and GLOBAL_POSITION_INT at the control rate,
EKF_STATUS_REPORT, GPS_RAW_INT and SYS_STATUS at 2 Hz) and calls the vehicle ready once its EKF
reports attitude, velocities and positions (no constant-position mode, no GPS glitch), its GPS a
3-D fix, its SYS_STATUS pre-arm checks passing, and the parameters are known and confirmed.
Until then the agent says it is not ready, so the swarm waits for it (flight_phase.Readiness).
Each ArduCopter vehicle keeps its own EKF origin: its position in the swarm's one frame comes from
GLOBAL_POSITION_INT about the swarm's common origin.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, Protocol

from protocols.mavlink.conventions import (
    EKF_BAD_FLAGS,
    EKF_READY_FLAGS,
    GPS_FIX_3D,
    GUID_OPTIONS_THRUST,
    MODE_HOLD,
    MODE_LAND,
    MODE_OFFBOARD,
    MSG_ATTITUDE,
    MSG_EKF_STATUS_REPORT,
    MSG_GLOBAL_POSITION_INT,
    MSG_GPS_RAW_INT,
    MSG_SYS_STATUS,
    SYS_STATUS_PREARM_CHECK,
    CopterMode,
    Dialect,
    Px4AutoSubMode,
    Px4MainMode,
)
from protocols.model.frames import G_M_S2

#: MAV_CMD_DO_SET_MODE and its base-mode flag.
CMD_DO_SET_MODE = 176
CUSTOM_MODE_ENABLED = 1.0
#: How often (s, the agent's clock) an ArduCopter set-up step not yet confirmed is asked again.
SETUP_RETRY_S = 1.0
#: The hover estimate's time constant (s): a sample's estimate is noisy (GLOBAL_POSITION_INT's
#: velocity is in cm/s: 0.5 m/s² over a 20 ms step), a few seconds average it to under 1 %.
HOVER_LEARN_TC_S = 3.0
#: ... used while the vehicle is tilted less than this (rad), samples at most this far apart (s).
HOVER_LEARN_MAX_TILT_RAD, HOVER_LEARN_MAX_GAP_S = 0.3, 0.1
#: ... and kept within this factor of MOT_THST_HOVER.
HOVER_LEARN_RANGE = 1.5
#: The status-message rate (Hz) an ArduCopter agent asks for.
STATUS_RATE_HZ = 2.0
#: The cosine of the tilt the throttle is scaled by is never taken below this (as ArduCopter).
MIN_BOOST_COS = 0.1
#: FS_GCS_ENABLE's value "always land".
FS_GCS_LAND = 5
#: The GCS system id parameter's names: ArduPilot 4.7 and earlier releases.
GCS_SYSID_PARAMS = ("MAV_GCS_SYSID", "SYSID_MYGCS")

#: (command id, params) of a COMMAND_LONG; the link sends it to its vehicle's autopilot.
Command = tuple[int, tuple[float, ...]]


@dataclass(frozen=True)
class ModeView:
    """Which of the agent's modes the vehicle is in."""

    in_offboard: bool
    in_land: bool
    in_hold: bool


class VehicleIo(Protocol):
    """What a dialect may do on its link: the link's own sends
    (drone_agent/process/vehicle_link.py)."""

    def request_interval(self, message_id: int, rate_hz: float) -> None: ...

    def param_set(self, name: str, value: float) -> None: ...

    def param_read(self, name: str) -> None: ...


class AutopilotDialect:
    """The PX4 dialect, and the interface (module doc)."""

    name = Dialect.PX4
    #: whether the swarm-frame position is GLOBAL_POSITION_INT about the common origin (else
    #: LOCAL_POSITION_NED), paired with ATTITUDE by time rather than by equal ``time_boot_ms``
    global_frame = False

    def modes(self, custom_mode: int) -> ModeView:
        return _px4_modes(custom_mode)

    def offboard_command(self) -> Command:
        return CMD_DO_SET_MODE, (CUSTOM_MODE_ENABLED, float(Px4MainMode.OFFBOARD))

    def land_command(self) -> Command:
        """PX4 AUTO.LAND: level, sink, disarm on touchdown."""
        return CMD_DO_SET_MODE, (
            CUSTOM_MODE_ENABLED, float(Px4MainMode.AUTO), float(Px4AutoSubMode.LAND)
        )  # fmt: skip

    def hold_command(self) -> Command:
        """PX4 AUTO.LOITER: level, hold the altitude."""
        return CMD_DO_SET_MODE, (
            CUSTOM_MODE_ENABLED, float(Px4MainMode.AUTO), float(Px4AutoSubMode.LOITER)
        )  # fmt: skip

    def service(self, io: VehicleIo, now_s: float) -> None:
        """Set-up due now (nothing for PX4)."""

    def on_message(self, kind: str, msg: Any) -> None:
        """A message of the vehicle's autopilot the dialect reads (parameters, EKF, ...)."""

    def on_sample(
        self, t_ms: int, velocity_down_m_s: float, roll_rad: float, pitch_rad: float, armed: bool
    ) -> None:
        """A state sample of the vehicle (one a control period), at its own ``t_ms``."""

    @property
    def ready(self) -> bool:
        """Whether the vehicle can be armed and flown with this dialect's setpoints."""
        return True

    @property
    def not_ready_reason(self) -> str:
        """Why it is not :attr:`ready` ("" when it is)."""
        return ""

    def wire_thrust(self, thrust_normalised: float, roll_rad: float, pitch_rad: float) -> float:
        """SET_ATTITUDE_TARGET's thrust for the agent's thrust (normalised, of the scenario
        vehicle's maximum) at the setpoint's attitude."""
        return thrust_normalised


class Px4Dialect(AutopilotDialect):
    """PX4's OFFBOARD dialect (the base class's behaviour)."""


class ArduCopterDialect(AutopilotDialect):
    """ArduCopter's GUIDED_NOGPS dialect (module doc). ``thrust_to_weight``: the scenario
    vehicle's maximum thrust over its weight, the scale of the agent's normalised thrust;
    ``control_hz``: the rate at which ATTITUDE and GLOBAL_POSITION_INT are asked for."""

    name = Dialect.ARDUPILOT
    global_frame = True

    def __init__(self, thrust_to_weight: float, control_hz: float = 50.0, sysid: int = 1) -> None:
        self.thrust_to_weight = thrust_to_weight
        self.control_hz = control_hz
        self.sysid = sysid
        #: parameters as the vehicle last said them (PARAM_VALUE)
        self.params: dict[str, float] = {}
        self.guid_options: int | None = None  # as the vehicle last said
        self.hover: float | None = None  # MOT_THST_HOVER as the vehicle last said
        self.ekf_flags: int | None = None
        self.gps_fix: int | None = None
        self.prearm_ok: bool | None = None
        self._streams_asked_s = -math.inf
        self._options_asked_s = -math.inf
        self._hover_asked_s = -math.inf
        self._last_throttle: float | None = None
        self._parameter_hover: float | None = None
        self._last_sample: tuple[int, float] | None = None  # (t_ms, velocity down)
        self._failsafe_asked_s = -math.inf
        self._heard_stream = False

    def modes(self, custom_mode: int) -> ModeView:
        return _copter_modes(custom_mode)

    def offboard_command(self) -> Command:
        return CMD_DO_SET_MODE, (CUSTOM_MODE_ENABLED, float(CopterMode.GUIDED_NOGPS))

    def land_command(self) -> Command:
        """LAND: descend, disarm on touchdown."""
        return CMD_DO_SET_MODE, (CUSTOM_MODE_ENABLED, float(CopterMode.LAND))

    def hold_command(self) -> Command:
        """BRAKE: stop and hold the position, no pilot input."""
        return CMD_DO_SET_MODE, (CUSTOM_MODE_ENABLED, float(CopterMode.BRAKE))

    @property
    def failsafe_confirmed(self) -> bool:
        """The vehicle said its GCS is this agent and its GCS failsafe lands."""
        mine = any(self.params.get(name) == float(self.sysid) for name in GCS_SYSID_PARAMS)
        return mine and self.params.get("FS_GCS_ENABLE") == float(FS_GCS_LAND)

    @property
    def thrust_confirmed(self) -> bool:
        """The vehicle said GUID_OPTIONS has the thrust bit."""
        return self.guid_options is not None and bool(self.guid_options & GUID_OPTIONS_THRUST)

    def service(self, io: VehicleIo, now_s: float) -> None:
        if not self._heard_stream and _due(now_s, self._streams_asked_s, SETUP_RETRY_S):
            self._streams_asked_s = now_s
            io.request_interval(MSG_ATTITUDE, self.control_hz)
            io.request_interval(MSG_GLOBAL_POSITION_INT, self.control_hz)
            for msg_id in (MSG_EKF_STATUS_REPORT, MSG_GPS_RAW_INT, MSG_SYS_STATUS):
                io.request_interval(msg_id, STATUS_RATE_HZ)
        if not self.thrust_confirmed and _due(now_s, self._options_asked_s, SETUP_RETRY_S):
            self._options_asked_s = now_s
            if self.guid_options is None:
                io.param_read("GUID_OPTIONS")
            else:  # keep the user's other bits
                io.param_set("GUID_OPTIONS", float(self.guid_options | GUID_OPTIONS_THRUST))
        if not self.failsafe_confirmed and _due(now_s, self._failsafe_asked_s, SETUP_RETRY_S):
            self._failsafe_asked_s = now_s
            for name in GCS_SYSID_PARAMS:  # a release that lacks one ignores it
                io.param_set(name, float(self.sysid))
            io.param_set("FS_GCS_ENABLE", float(FS_GCS_LAND))
        if self.hover is None and _due(now_s, self._hover_asked_s, SETUP_RETRY_S):
            self._hover_asked_s = now_s
            io.param_read("MOT_THST_HOVER")

    def on_message(self, kind: str, msg: Any) -> None:
        if kind == "PARAM_VALUE":
            name = _param_name(msg.param_id)
            value = float(msg.param_value)
            self.params[name] = value
            if name == "GUID_OPTIONS" and math.isfinite(value):
                self.guid_options = int(value)
            elif name == "MOT_THST_HOVER" and self.hover is None and 0.05 <= value <= 0.95:
                self.hover = self._parameter_hover = value  # then learnt in flight (on_sample)
        elif kind == "EKF_STATUS_REPORT":
            self.ekf_flags = int(msg.flags)
        elif kind == "GPS_RAW_INT":
            self.gps_fix = int(msg.fix_type)
        elif kind == "SYS_STATUS":
            present = int(msg.onboard_control_sensors_present) & SYS_STATUS_PREARM_CHECK
            healthy = int(msg.onboard_control_sensors_health) & SYS_STATUS_PREARM_CHECK
            self.prearm_ok = bool(present and healthy)
        elif kind in ("GLOBAL_POSITION_INT", "ATTITUDE"):
            self._heard_stream = True

    def on_sample(
        self, t_ms: int, velocity_down_m_s: float, roll_rad: float, pitch_rad: float, armed: bool
    ) -> None:
        """Estimate the hover throttle (module doc) from the throttle sent since the last
        sample and the vertical acceleration it gave."""
        previous, self._last_sample = self._last_sample, (t_ms, velocity_down_m_s)
        sent, hover, base = self._last_throttle, self.hover, self._parameter_hover
        if previous is None or sent is None or hover is None or base is None or not armed:
            return
        if sent < 0.5 * hover:  # idling on the ground, or cutting its thrust
            return
        if abs(roll_rad) > HOVER_LEARN_MAX_TILT_RAD or abs(pitch_rad) > HOVER_LEARN_MAX_TILT_RAD:
            return
        dt = (t_ms - previous[0]) / 1000.0
        if not 0.0 < dt <= HOVER_LEARN_MAX_GAP_S:
            return
        up = -(velocity_down_m_s - previous[1]) / dt
        estimate = sent * G_M_S2 / max(G_M_S2 + up, 0.5 * G_M_S2)
        learnt = hover + dt / (dt + HOVER_LEARN_TC_S) * (estimate - hover)
        self.hover = min(max(learnt, base / HOVER_LEARN_RANGE), base * HOVER_LEARN_RANGE)

    @property
    def ready(self) -> bool:
        return self.not_ready_reason == ""

    @property
    def not_ready_reason(self) -> str:
        flags = self.ekf_flags
        if flags is None:
            return "no EKF status yet"
        if flags & EKF_READY_FLAGS != EKF_READY_FLAGS or flags & EKF_BAD_FLAGS:
            return f"EKF not ready (flags 0x{flags:x})"
        if self.gps_fix is None or self.gps_fix < GPS_FIX_3D:
            return f"GPS has no 3-D fix (fix type {self.gps_fix})"
        if not self.prearm_ok:
            return "pre-arm checks failing"
        if not self.thrust_confirmed:
            return "GUID_OPTIONS thrust bit not confirmed"
        if not self.failsafe_confirmed:
            return "heartbeat failsafe (MAV_GCS_SYSID, FS_GCS_ENABLE) not confirmed"
        if self.hover is None:
            return "MOT_THST_HOVER unknown"
        return ""

    def wire_thrust(self, thrust_normalised: float, roll_rad: float, pitch_rad: float) -> float:
        hover = self.hover if self.hover is not None else 0.0
        cos_tilt = max(math.cos(roll_rad) * math.cos(pitch_rad), MIN_BOOST_COS)
        throttle = min(max(thrust_normalised * self.thrust_to_weight * hover * cos_tilt, 0.0), 1.0)
        self._last_throttle = throttle  # the vertical thrust, hover units (angle boost)
        return throttle


def make_dialect(
    dialect: Dialect, thrust_to_weight: float, control_hz: float, sysid: int = 1
) -> AutopilotDialect:
    """A fresh dialect object of ``dialect`` for vehicle ``sysid``."""
    if dialect == Dialect.ARDUPILOT:
        return ArduCopterDialect(thrust_to_weight, control_hz, sysid)
    return Px4Dialect()


@functools.cache
def _px4_modes(custom_mode: int) -> ModeView:
    """The PX4 dialect's view of a custom mode (one object per mode: asked every tick)."""
    return ModeView(
        custom_mode == MODE_OFFBOARD, custom_mode == MODE_LAND, custom_mode == MODE_HOLD
    )


@functools.cache
def _copter_modes(custom_mode: int) -> ModeView:
    """The ArduCopter dialect's view of a custom mode."""
    return ModeView(
        custom_mode == CopterMode.GUIDED_NOGPS,
        custom_mode == CopterMode.LAND,
        custom_mode == CopterMode.BRAKE,
    )


def _due(now_s: float, last_s: float, period_s: float) -> bool:
    """``period_s`` has passed since ``last_s``, or the clock changed (a greeting on the wall
    clock, then a lockstep agent on simulated time)."""
    return not 0.0 <= now_s - last_s < period_s


def _param_name(raw: Any) -> str:
    """A PARAM_* param_id (str or bytes, NUL-padded) as text."""
    if isinstance(raw, bytes | bytearray):
        raw = raw.decode("ascii", errors="replace")
    return str(raw).rstrip("\x00")

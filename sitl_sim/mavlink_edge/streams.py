"""Message-interval bookkeeping: which streamed messages a link is due at each control tick. Pure.

Each link of each vehicle (its agent link and its share of the GCS link) streams HEARTBEAT,
SYS_STATUS, ATTITUDE, LOCAL_POSITION_NED, ATTITUDE_TARGET and ACTUATOR_OUTPUT_STATUS (the four
rotor forces, N; protocols/mavlink/conventions.py), and the map's messages (GLOBAL_POSITION_INT,
GPS_RAW_INT, HOME_POSITION, EXTENDED_SYS_STATE; sitl_sim/mavlink_edge/map_telemetry.py) at its own
rates, changed by MAV_CMD_SET_MESSAGE_INTERVAL (interval in µs; 0 = the default rate, -1 = off).
Telemetry is sent at control ticks, so the highest rate is the control rate: a shorter interval
is accepted and capped. A rate that does not divide the control rate is met on average (the due
time accumulates in fractional ticks). ACTUATOR_OUTPUT_STATUS is off by default on an agent link
(an agent may ask for it) and goes to the GCS at the state rate, so that a ground station can
rebuild thrust and moments. The map's messages go to the GCS only by default, slowly (5 Hz
global position, 1 Hz the rest: at 100 vehicles 800 messages a second), and are off on agent
links (an agent may ask). Each map message starts at its own phase of its interval
(:data:`PHASE`), so that the whole fleet's 1 Hz messages do not all fall on one tick.

The ArduCopter dialect (sitl_sim/mavlink_edge/dialect.py) streams more by default:
GLOBAL_POSITION_INT at the agent link's state rate (its swarm-frame position; in phase with
ATTITUDE, every control tick at the default rates) and EKF_STATUS_REPORT (off on an agent link, 1 Hz
to the GCS) (:data:`COPTER_AGENT_RATES_HZ`, :data:`COPTER_GCS_RATES_HZ`).

Links that keep the default rates share one :class:`StreamSchedule`; :class:`StreamTable` gives a
link its own copy on its first change (copy on write), so the common case costs one schedule
evaluation per tick for all vehicles.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

HEARTBEAT = 0
SYS_STATUS = 1
GPS_RAW_INT = 24
ATTITUDE = 30
LOCAL_POSITION_NED = 32
GLOBAL_POSITION_INT = 33
ATTITUDE_TARGET = 83
EKF_STATUS_REPORT = 193
HOME_POSITION = 242
EXTENDED_SYS_STATE = 245
ACTUATOR_OUTPUT_STATUS = 375
#: the vehicle's true state (ODOMETRY, estimator type MOCAP: what a motion-capture system would
#: measure), to the GCS only and only when the state estimates are not the truth ([sensors])
ODOMETRY = 331

#: Default rates (Hz) on an agent link (onboard computer) and to the ground station.
AGENT_RATES_HZ: Mapping[int, float] = {
    HEARTBEAT: 1.0,
    SYS_STATUS: 1.0,
    ATTITUDE: 50.0,
    LOCAL_POSITION_NED: 50.0,
    ATTITUDE_TARGET: 10.0,
    ACTUATOR_OUTPUT_STATUS: 0.0,
    GLOBAL_POSITION_INT: 0.0,
    GPS_RAW_INT: 0.0,
    HOME_POSITION: 0.0,
    EXTENDED_SYS_STATE: 0.0,
    ODOMETRY: 0.0,
}
GCS_RATES_HZ: Mapping[int, float] = {
    HEARTBEAT: 1.0,
    SYS_STATUS: 1.0,
    ATTITUDE: 10.0,
    LOCAL_POSITION_NED: 10.0,
    ATTITUDE_TARGET: 2.0,
    ACTUATOR_OUTPUT_STATUS: 10.0,
    GLOBAL_POSITION_INT: 5.0,
    GPS_RAW_INT: 1.0,
    HOME_POSITION: 1.0,
    EXTENDED_SYS_STATE: 1.0,
    ODOMETRY: 0.0,
}
#: Where in its interval (a fraction) a message is first due; the others start at tick 0.
PHASE: Mapping[int, float] = {
    GLOBAL_POSITION_INT: 0.5,
    GPS_RAW_INT: 0.25,
    HOME_POSITION: 0.5,
    EXTENDED_SYS_STATE: 0.75,
    EKF_STATUS_REPORT: 0.875,
}
#: The messages whose default rate is the link's state rate (``--agent-rate-hz``,
#: ``--gcs-rate-hz``): the vehicle state on both links, and the rotor outputs to the GCS.
AGENT_STATE_STREAMS: tuple[int, ...] = (ATTITUDE, LOCAL_POSITION_NED)
GCS_STATE_STREAMS: tuple[int, ...] = (ATTITUDE, LOCAL_POSITION_NED, ACTUATOR_OUTPUT_STATUS)

#: The ArduCopter dialect's defaults (module doc): the swarm-frame position joins the agent's
#: state streams, the EKF's status goes to the GCS.
COPTER_AGENT_RATES_HZ: Mapping[int, float] = {
    **AGENT_RATES_HZ,
    GLOBAL_POSITION_INT: 50.0,
    EKF_STATUS_REPORT: 0.0,
}
COPTER_GCS_RATES_HZ: Mapping[int, float] = {**GCS_RATES_HZ, EKF_STATUS_REPORT: 1.0}
COPTER_AGENT_STATE_STREAMS: tuple[int, ...] = (ATTITUDE, LOCAL_POSITION_NED, GLOBAL_POSITION_INT)
#: ... and the GCS's: an ArduCopter's position in the swarm's frame is its GLOBAL_POSITION_INT, so
#: the ground station's record takes it at the state rate (5 Hz held a moving centre 9 cm off)
COPTER_GCS_STATE_STREAMS: tuple[int, ...] = (*GCS_STATE_STREAMS, GLOBAL_POSITION_INT)
#: An ArduCopter agent link's phases: its state streams (GLOBAL_POSITION_INT among them) all
#: start at tick 0, so that each tick's position and attitude go out together.
COPTER_AGENT_PHASE: Mapping[int, float] = {
    msg_id: phase for msg_id, phase in PHASE.items() if msg_id != GLOBAL_POSITION_INT
}


class StreamSchedule:
    """Rates and due times of the streamed messages of one link, counted in control ticks."""

    def __init__(
        self,
        defaults_hz: Mapping[int, float],
        control_hz: float,
        phases: Mapping[int, float] = PHASE,
    ) -> None:
        self.defaults_hz = dict(defaults_hz)
        self.control_hz = control_hz
        self.phases = phases
        self._interval_ticks: dict[int, float] = {}
        self._next_tick: dict[int, float] = {}
        for msg_id, rate in self.defaults_hz.items():
            self._set_rate(msg_id, rate)
        self._due_tick = -1
        self._due: list[int] = []

    def copy(self) -> StreamSchedule:
        """An independent schedule with the same rates and phase."""
        twin = StreamSchedule(self.defaults_hz, self.control_hz, self.phases)
        twin._interval_ticks = dict(self._interval_ticks)
        twin._next_tick = dict(self._next_tick)
        return twin

    def streams(self, msg_id: int) -> bool:
        """Whether ``msg_id`` is a streamable message."""
        return msg_id in self.defaults_hz

    def set_interval_us(self, msg_id: int, interval_us: float) -> bool:
        """MAV_CMD_SET_MESSAGE_INTERVAL: > 0 µs sets, 0 restores the default, < 0 stops.
        False if ``msg_id`` is not streamed or the interval is not a number."""
        if msg_id not in self.defaults_hz or math.isnan(interval_us):
            return False
        if interval_us == 0:
            rate = self.defaults_hz[msg_id]
        elif interval_us < 0:
            rate = 0.0
        else:
            rate = 1e6 / interval_us
        self._set_rate(msg_id, rate)
        return True

    def interval_us(self, msg_id: int) -> int:
        """The interval (µs) of ``msg_id`` as MESSAGE_INTERVAL reports it: -1 off, 0 unknown."""
        if msg_id not in self._interval_ticks:
            return 0
        ticks = self._interval_ticks[msg_id]
        return -1 if math.isinf(ticks) else round(ticks / self.control_hz * 1e6)

    def due(self, tick: int) -> list[int]:
        """The message ids due at control tick ``tick`` (call once per tick, ticks increasing;
        a repeated call for the same tick returns the same answer)."""
        if tick == self._due_tick:
            return self._due
        due = []
        for msg_id, next_tick in self._next_tick.items():
            if tick >= next_tick - 1e-9:
                interval = self._interval_ticks[msg_id]
                following = next_tick + interval
                self._next_tick[msg_id] = following if following > tick else tick + interval
                due.append(msg_id)
        self._due_tick, self._due = tick, due
        return due

    def _set_rate(self, msg_id: int, rate_hz: float) -> None:
        if rate_hz <= 0.0:
            self._interval_ticks[msg_id] = math.inf
            self._next_tick[msg_id] = math.inf
            return
        interval = max(1.0, self.control_hz / rate_hz)
        self._interval_ticks[msg_id] = interval
        current = self._next_tick.get(msg_id, math.floor(self.phases.get(msg_id, 0.0) * interval))
        self._next_tick[msg_id] = 0.0 if math.isinf(current) else current


class StreamTable:
    """The schedules of one kind of link for every vehicle, sharing the default one
    (``phases``: where each message starts in its interval, :data:`PHASE` by default)."""

    def __init__(
        self,
        n: int,
        defaults_hz: Mapping[int, float],
        control_hz: float,
        phases: Mapping[int, float] = PHASE,
    ) -> None:
        self.shared = StreamSchedule(defaults_hz, control_hz, phases)
        self._own: dict[int, StreamSchedule] = {}
        self.n = n

    @property
    def split(self) -> dict[int, StreamSchedule]:
        """The vehicles with schedules of their own (read only); the others follow
        :attr:`shared`."""
        return self._own

    def of(self, vehicle: int) -> StreamSchedule:
        """The schedule vehicle ``vehicle`` follows (possibly the shared one: read only)."""
        return self._own.get(vehicle, self.shared)

    def own(self, vehicle: int) -> StreamSchedule:
        """Vehicle ``vehicle``'s own schedule, split from the shared one if needed (to change)."""
        if vehicle not in self._own:
            self._own[vehicle] = self.shared.copy()
        return self._own[vehicle]

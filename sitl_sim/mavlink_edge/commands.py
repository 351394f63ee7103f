"""COMMAND_LONG / COMMAND_INT and SET_MODE: what each command does to a vehicle, and its answer.

Every command gets a COMMAND_ACK (never silence): ACCEPTED, DENIED (valid but not now; the
reply's reason goes out as a STATUSTEXT), UNSUPPORTED (a command this autopilot does not have)
or FAILED (the vehicle cannot: crashed, motor failure). Handled:

- MAV_CMD_COMPONENT_ARM_DISARM (400): param1 1 arm / 0 disarm, param2 21196 forces a disarm.
- MAV_CMD_DO_SET_MODE (176): param1 base mode with CUSTOM_MODE_ENABLED; the mode in the
  dialect's encoding (a :class:`ModeDecoder`, from sitl_sim/mavlink_edge/dialect.py): PX4's param2
  main mode, param3 sub mode, HOLD (AUTO.LOITER), OFFBOARD, LAND (AUTO.LAND) (:class:`Px4Modes`, the
  default); ArduCopter's param2 copter mode. Modes the simulator does not fly are DENIED. The
  SET_MODE message's ``custom_mode`` is read the same way (:meth:`CommandHandler.set_custom_mode`).
- MAV_CMD_NAV_LAND (21): LAND mode.
- MAV_CMD_SET_MESSAGE_INTERVAL (511) / MAV_CMD_GET_MESSAGE_INTERVAL (510): the rates of the link
  the command came on (param1 message id, param2 interval µs: 0 default, -1 off).
- MAV_CMD_REQUEST_MESSAGE (512): AUTOPILOT_VERSION and every streamed message (HOME_POSITION
  among them), once.
- MAV_CMD_GET_HOME_POSITION (410, deprecated for REQUEST_MESSAGE but still sent by ground
  stations): HOME_POSITION.
- MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES (520): AUTOPILOT_VERSION.
- MAV_CMD_INJECT_FAILURE (420), PX4 vocabulary: param1 FAILURE_UNIT_SYSTEM_MOTOR (101), param2
  FAILURE_TYPE_OFF (1) or FAILURE_TYPE_OK (0), param3 motor instance 1..4, 0 = all motors (all
  off = crash). Denied while SYS_FAILURE_EN is 0.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

from protocols.mavlink.conventions import Px4AutoSubMode, Px4MainMode
from sitl_sim.mavlink_edge import messages
from sitl_sim.mavlink_edge.streams import StreamTable
from sitl_sim.vehicle.autopilot import (
    ACCEPTED,
    FORCE_DISARM_MAGIC,
    Mode,
    Outcome,
    Result,
    VehicleEvent,
)
from sitl_sim.vehicle.world import World

CMD_NAV_LAND = 21
CMD_DO_SET_MODE = 176
CMD_COMPONENT_ARM_DISARM = 400
CMD_GET_HOME_POSITION = 410
CMD_INJECT_FAILURE = 420
CMD_GET_MESSAGE_INTERVAL = 510
CMD_SET_MESSAGE_INTERVAL = 511
CMD_REQUEST_MESSAGE = 512
CMD_REQUEST_AUTOPILOT_CAPABILITIES = 520
MSG_AUTOPILOT_VERSION = 148
MSG_HOME_POSITION = 242
FAILURE_UNIT_SYSTEM_MOTOR = 101
FAILURE_TYPE_OK = 0
FAILURE_TYPE_OFF = 1
_CUSTOM_MODE_ENABLED = 1

#: A message of vehicle ``i`` built on request (``msg_id``), None if it is not available.
MessageBuilder = Callable[[int, int], Any | None]


@dataclass
class CommandReply:
    """The ACK's outcome, messages to send after the ACK on the same link, and events."""

    outcome: Outcome
    messages: list[Any] = field(default_factory=list)
    events: list[VehicleEvent] = field(default_factory=list)


def mode_of(main: int, sub: int) -> Mode | None:
    """The simulator's mode for a PX4 (main, sub) mode, None if it does not fly it."""
    if main == Px4MainMode.OFFBOARD:
        return Mode.OFFBOARD
    if main == Px4MainMode.AUTO and sub == Px4AutoSubMode.LOITER:
        return Mode.HOLD
    if main == Px4MainMode.AUTO and sub == Px4AutoSubMode.LAND:
        return Mode.LAND
    return None


class ModeDecoder(Protocol):
    """How a dialect names the modes in MAV_CMD_DO_SET_MODE and in SET_MODE."""

    def params_of_custom(self, custom_mode: int) -> tuple[int, int]:
        """DO_SET_MODE's (param2, param3) for a SET_MODE / HEARTBEAT ``custom_mode``."""
        ...

    def mode_of_params(self, param2: int, param3: int) -> Mode | str:
        """The simulator's mode DO_SET_MODE's param2 and param3 ask for, or why it is denied."""
        ...


class Px4Modes:
    """PX4's custom modes: param2 main mode, param3 sub mode (``custom_mode`` bits 16..31)."""

    def params_of_custom(self, custom_mode: int) -> tuple[int, int]:
        return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF

    def mode_of_params(self, param2: int, param3: int) -> Mode | str:
        mode = mode_of(param2, param3)
        if mode is None:
            return f"Mode change denied: mode {param2}.{param3} not available"
        return mode


class CommandHandler:
    """Executes commands on ``world``'s vehicles; ``build`` makes requested messages; ``modes``
    reads the dialect's mode encoding (PX4's by default)."""

    def __init__(
        self,
        world: World,
        sysids: Sequence[int],
        build: MessageBuilder,
        modes: ModeDecoder | None = None,
    ) -> None:
        self.world = world
        self.sysids = list(sysids)
        self.build = build
        self.modes: ModeDecoder = Px4Modes() if modes is None else modes

    def command(
        self, i: int, command: int, params: Sequence[float], streams: StreamTable
    ) -> CommandReply:
        """Run ``command`` with ``params`` (param1..param7) on vehicle ``i``; ``streams`` are the
        schedules of the link it came on."""
        p = [float(v) for v in params] + [0.0] * (7 - len(params))
        if command == CMD_COMPONENT_ARM_DISARM:
            return self._arm_disarm(i, p)
        if command == CMD_DO_SET_MODE:
            if not int(_finite(p[0])) & _CUSTOM_MODE_ENABLED:
                return _denied("Mode change denied: custom mode flag not set")
            return self.set_mode(i, int(_finite(p[1])), int(_finite(p[2])))
        if command == CMD_NAV_LAND:
            return self._mode(i, Mode.LAND)
        if command == CMD_SET_MESSAGE_INTERVAL:
            if not streams.own(i).set_interval_us(int(_finite(p[0])), p[1]):
                return _denied(f"Message {p[0]:g} cannot be streamed")
            return CommandReply(ACCEPTED)
        if command == CMD_GET_MESSAGE_INTERVAL:
            msg_id = int(_finite(p[0]))
            interval = streams.of(i).interval_us(msg_id)
            return CommandReply(ACCEPTED, [messages.message_interval(msg_id, interval)])
        if command == CMD_REQUEST_MESSAGE:
            return self._request(i, int(_finite(p[0])))
        if command == CMD_GET_HOME_POSITION:
            return self._request(i, MSG_HOME_POSITION)
        if command == CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            return CommandReply(ACCEPTED, [messages.autopilot_version(self.sysids[i])])
        if command == CMD_INJECT_FAILURE:
            return self._inject(i, int(_finite(p[0])), int(_finite(p[1])), int(_finite(p[2])))
        return CommandReply(Outcome(Result.UNSUPPORTED))

    def set_mode(self, i: int, param2: int, param3: int = 0) -> CommandReply:
        """The mode of DO_SET_MODE's param2 and param3 in the dialect's encoding (PX4: main and
        sub mode)."""
        mode = self.modes.mode_of_params(param2, param3)
        if isinstance(mode, str):
            return _denied(mode)
        return self._mode(i, mode)

    def set_custom_mode(self, i: int, custom_mode: int) -> CommandReply:
        """The SET_MODE message's ``custom_mode`` in the dialect's encoding."""
        return self.set_mode(i, *self.modes.params_of_custom(custom_mode))

    def _mode(self, i: int, mode: Mode) -> CommandReply:
        outcome, events = self.world.autopilot.set_mode(i, mode, self.world.t_s)
        return CommandReply(outcome, events=events)

    def _arm_disarm(self, i: int, p: list[float]) -> CommandReply:
        ap = self.world.autopilot
        if p[0] == 1.0:
            outcome, events = ap.arm(i, self.world.t_s)
        elif p[0] == 0.0:
            outcome, events = ap.disarm(i, force=p[1] == FORCE_DISARM_MAGIC)
        else:
            return _denied(f"Arm/disarm denied: param1 {p[0]:g} is not 0 or 1")
        return CommandReply(outcome, events=events)

    def _request(self, i: int, msg_id: int) -> CommandReply:
        if msg_id == MSG_AUTOPILOT_VERSION:
            return CommandReply(ACCEPTED, [messages.autopilot_version(self.sysids[i])])
        msg = self.build(i, msg_id)
        if msg is None:
            return _denied(f"Message {msg_id} not available")
        return CommandReply(ACCEPTED, [msg])

    def _inject(self, i: int, unit: int, kind: int, instance: int) -> CommandReply:
        if unit != FAILURE_UNIT_SYSTEM_MOTOR or kind not in (FAILURE_TYPE_OK, FAILURE_TYPE_OFF):
            return CommandReply(Outcome(Result.UNSUPPORTED))
        if not self.world.autopilot.failure_injection[i]:
            return _denied("Failure injection disabled (SYS_FAILURE_EN)")
        if not 0 <= instance <= 4:
            return _denied(f"Failure injection: no motor {instance}")
        motor = None if instance == 0 else instance - 1
        events = self.world.autopilot.motor_failure(i, motor, off=kind == FAILURE_TYPE_OFF)
        return CommandReply(ACCEPTED, events=events)


def _finite(value: float) -> float:
    """``value`` if finite, else -1 (never a valid id, mode or instance)."""
    return value if math.isfinite(value) else -1.0


def _denied(reason: str) -> CommandReply:
    return CommandReply(Outcome(Result.DENIED, reason))

"""COMMAND_LONG semantics and the parameter table, without sockets: every command is answered."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from protocols.mavlink.conventions import Px4AutoSubMode, Px4MainMode
from sitl_sim.mavlink_edge.commands import CommandHandler, mode_of
from sitl_sim.mavlink_edge.streams import AGENT_RATES_HZ, ATTITUDE, StreamTable
from sitl_sim.physics.attitude_control import AttitudeGains
from sitl_sim.physics.vehicle_params import VehicleParams
from sitl_sim.vehicle.autopilot import Mode, Result
from sitl_sim.vehicle.setpoint import AttitudeSetpoint, validate_attitude_target
from sitl_sim.vehicle.tunables import FleetAttitudeGains, SetStatus, Tunables
from sitl_sim.vehicle.world import World, WorldConfig

ARM, SET_MODE, LAND, INJECT = 400, 176, 21, 420
GET_INTERVAL, SET_INTERVAL, REQUEST, CAPABILITIES = 510, 511, 512, 520
OFFBOARD = (1, Px4MainMode.OFFBOARD)
HOLD = (1, Px4MainMode.AUTO, Px4AutoSubMode.LOITER)


def _handler(n: int = 2) -> tuple[CommandHandler, World, StreamTable]:
    world = World(
        VehicleParams(),
        FleetAttitudeGains(AttitudeGains(), n),
        np.zeros((n, 3)) + np.arange(n)[:, None] * [2.0, 0.0, 0.0],
        np.zeros(n),
        WorldConfig(),
        np.random.default_rng(0),
    )

    def build(i: int, msg_id: int) -> Any:
        return ("built", i, msg_id) if msg_id == ATTITUDE else None

    streams = StreamTable(n, AGENT_RATES_HZ, 50)
    return CommandHandler(world, [1, 2], build), world, streams


def _stream_setpoints(world: World, i: int) -> None:
    sp = validate_attitude_target((1.0, 0.0, 0.0, 0.0), 0.0, 7)
    assert isinstance(sp, AttitudeSetpoint)
    world.autopilot.setpoint(i, sp, world.t_s)


def test_arm_then_offboard_then_land() -> None:
    h, world, streams = _handler()
    assert h.command(0, ARM, [1], streams).outcome.result == Result.ACCEPTED
    reply = h.command(0, SET_MODE, OFFBOARD, streams)
    assert reply.outcome.result == Result.DENIED and "setpoint" in reply.outcome.reason
    _stream_setpoints(world, 0)
    reply = h.command(0, SET_MODE, OFFBOARD, streams)
    assert reply.outcome.result == Result.ACCEPTED and world.autopilot.mode[0] == Mode.OFFBOARD
    assert [e.text for e in reply.events] == ["Mode OFFBOARD"]
    assert h.command(0, LAND, [], streams).outcome.result == Result.ACCEPTED
    assert world.autopilot.mode[0] == Mode.LAND
    assert h.command(0, SET_MODE, HOLD, streams).outcome.result == Result.ACCEPTED


@pytest.mark.parametrize(
    "params,result",
    [
        ((1, Px4MainMode.POSCTL), Result.DENIED),
        ((0, Px4MainMode.OFFBOARD), Result.DENIED),
        ((1, Px4MainMode.AUTO, Px4AutoSubMode.MISSION), Result.DENIED),
        ((1, float("nan")), Result.DENIED),
        ((*HOLD,), Result.ACCEPTED),
    ],
)
def test_set_mode_outcomes(params: tuple[float, ...], result: Result) -> None:
    h, _, streams = _handler()
    assert h.command(0, SET_MODE, params, streams).outcome.result == result


def test_mode_mapping() -> None:
    assert mode_of(Px4MainMode.OFFBOARD, 0) == Mode.OFFBOARD
    assert mode_of(Px4MainMode.AUTO, Px4AutoSubMode.LAND) == Mode.LAND
    assert mode_of(Px4MainMode.AUTO, Px4AutoSubMode.RTL) is None


def test_arm_disarm_param_checks() -> None:
    h, world, streams = _handler()
    assert h.command(0, ARM, [0.5], streams).outcome.result == Result.DENIED
    assert h.command(0, ARM, [0], streams).outcome.result == Result.ACCEPTED  # already disarmed
    h.command(0, ARM, [1], streams)
    assert world.autopilot.armed[0]
    assert h.command(0, ARM, [0], streams).outcome.result == Result.ACCEPTED
    assert not world.autopilot.armed[0]


def test_unknown_commands_are_unsupported_never_silent() -> None:
    h, _, streams = _handler()
    for command in (16, 22, 246, 519, 31000):
        assert h.command(0, command, [], streams).outcome.result == Result.UNSUPPORTED


def test_message_interval_per_vehicle_link() -> None:
    h, _, streams = _handler()
    assert h.command(1, SET_INTERVAL, [ATTITUDE, 100_000], streams).outcome.result == 0
    reply = h.command(1, GET_INTERVAL, [ATTITUDE], streams)
    assert reply.messages[0].interval_us == 100_000
    assert h.command(0, GET_INTERVAL, [ATTITUDE], streams).messages[0].interval_us == 20_000
    assert h.command(0, SET_INTERVAL, [148, 1e5], streams).outcome.result == Result.DENIED


def test_request_message_and_capabilities() -> None:
    h, _, streams = _handler()
    for reply in (h.command(1, REQUEST, [148], streams), h.command(1, CAPABILITIES, [1], streams)):
        assert reply.outcome.result == Result.ACCEPTED
        version = reply.messages[0]
        assert version.get_type() == "AUTOPILOT_VERSION" and version.uid == 2
        assert version.capabilities & 8192  # MAVLink 2
    assert h.command(0, REQUEST, [ATTITUDE], streams).messages == [("built", 0, ATTITUDE)]
    assert h.command(0, REQUEST, [24], streams).outcome.result == Result.DENIED


def test_failure_injection_vocabulary() -> None:
    h, world, streams = _handler()
    assert h.command(0, INJECT, [101, 2, 1], streams).outcome.result == Result.UNSUPPORTED
    assert h.command(0, INJECT, [0, 1, 0], streams).outcome.result == Result.UNSUPPORTED
    assert h.command(0, INJECT, [101, 1, 7], streams).outcome.result == Result.DENIED
    reply = h.command(0, INJECT, [101, 1, 2], streams)
    assert reply.outcome.result == Result.ACCEPTED and not world.autopilot.motor_ok[1, 0]
    assert h.command(0, INJECT, [101, 0, 2], streams).outcome.result == Result.ACCEPTED
    assert world.autopilot.motor_ok.all()
    reply = h.command(1, INJECT, [101, 1, 0], streams)
    assert world.autopilot.crashed.tolist() == [False, True]
    assert "all motors off" in reply.events[0].text


def test_failure_injection_can_be_disabled_by_parameter() -> None:
    h, world, streams = _handler()
    tunables = Tunables(world.autopilot, world.gains, [1, 2])  # type: ignore[arg-type]
    assert tunables.set(0, "SYS_FAILURE_EN", 0.0) == SetStatus.OK
    reply = h.command(0, INJECT, [101, 1, 0], streams)
    assert reply.outcome.result == Result.DENIED and "SYS_FAILURE_EN" in reply.outcome.reason
    assert not world.autopilot.crashed[0]


def test_parameter_table() -> None:
    _, world, _ = _handler()
    gains = world.gains
    assert isinstance(gains, FleetAttitudeGains)
    t = Tunables(world.autopilot, gains, [1, 2])
    names = [t.value(0, k)[0] for k in range(t.count)]
    assert "COM_OF_LOSS_T" in names and "ATT_ROLL_KP" in names and len(set(names)) == t.count
    assert all(len(name) <= 16 for name in names)
    assert t.set(1, "COM_OF_LOSS_T", 1.5) == SetStatus.OK
    assert world.autopilot.offboard_timeout_s.tolist() == [0.5, 1.5]
    assert t.set(0, "ATT_PITCH_KD", 20.0) == SetStatus.OK and gains.kd_matrix[1, 0] == 20.0
    assert t.set(0, "ATT_PITCH_KD", -1.0) == SetStatus.OUT_OF_RANGE
    assert t.set(0, "ATT_PITCH_KD", float("nan")) == SetStatus.OUT_OF_RANGE
    assert t.set(0, "NO_SUCH", 1.0) == SetStatus.UNKNOWN
    assert t.set(0, "MAV_SYS_ID", 9.0) == SetStatus.READ_ONLY
    mav_sys_id = t.index_of("MAV_SYS_ID")
    assert mav_sys_id is not None and t.value(1, mav_sys_id) == ("MAV_SYS_ID", 2.0)

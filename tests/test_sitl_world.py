"""The world stepping N vehicles through autopilot, inner loop and dynamics (no sockets)."""

from __future__ import annotations

import numpy as np
import pytest

from protocols.model.frames import wxyz_from_zyx
from sitl_sim.physics.attitude_control import AttitudeGains
from sitl_sim.physics.vehicle_params import VehicleParams
from sitl_sim.vehicle.autopilot import Mode, Result
from sitl_sim.vehicle.setpoint import AttitudeSetpoint, validate_attitude_target
from sitl_sim.vehicle.tunables import FleetAttitudeGains
from sitl_sim.vehicle.world import World, WorldConfig

HOVER = 0.5  # default vehicle: thrust-to-weight 2


def _world(n: int = 3, z: float = 0.0, **config: object) -> World:
    positions = np.stack([2.0 * np.arange(n), np.zeros(n), np.full(n, z)], axis=1)
    return World(
        VehicleParams(),
        FleetAttitudeGains(AttitudeGains(), n),
        positions,
        np.zeros(n),
        WorldConfig(**config),  # type: ignore[arg-type]
        np.random.default_rng(1),
    )


def _sp(thrust: float, roll: float = 0.0) -> AttitudeSetpoint:
    sp = validate_attitude_target(wxyz_from_zyx(0.0, 0.0, roll), thrust, 7)
    assert isinstance(sp, AttitudeSetpoint)
    return sp


def _offboard(w: World, i: int) -> None:
    """Arm vehicle ``i`` in OFFBOARD (in the air too, as if it had taken off)."""
    w.autopilot.landed[i] = True
    w.autopilot.setpoint(i, _sp(0.0), w.t_s)
    assert w.autopilot.arm(i, w.t_s)[0].result == Result.ACCEPTED
    assert w.autopilot.set_mode(i, Mode.OFFBOARD, w.t_s)[0].result == Result.ACCEPTED


def _fly(w: World, seconds: float, thrust: dict[int, float], roll: float = 0.0) -> list[str]:
    texts = []
    for _ in range(round(seconds * w.config.control_hz)):
        for i, value in thrust.items():
            w.autopilot.setpoint(i, _sp(value, roll), w.t_s)
        texts += [f"{e.vehicle}:{e.text}" for e in w.step()]
    return texts


def test_time_is_the_control_tick() -> None:
    w = _world(control_hz=50, physics_hz=500)
    for _ in range(7):
        w.step()
    assert w.tick == 7 and w.t_s == pytest.approx(0.14) and w.time_boot_ms() == 140
    assert w.tick_of_ms(140) == 7 and w.tick_of_ms(141) is None
    w30 = _world(control_hz=30, physics_hz=300)
    assert [w30.time_boot_ms(k) for k in range(4)] == [0, 33, 67, 100]
    assert [w30.tick_of_ms(ms) for ms in (33, 34, 67)] == [1, None, 2]


def test_disarmed_vehicles_stay_on_the_ground() -> None:
    w = _world()
    _fly(w, 1.0, {})
    assert np.all(w.state[2] == 0.0) and not w.autopilot.armed.any()


def test_thrust_above_hover_climbs_and_others_are_unaffected() -> None:
    w = _world()
    _offboard(w, 0)
    _fly(w, 1.0, {0: 0.6})
    # a = g (0.6 / 0.5 - 1) = 1.96 m/s^2 up: 0.98 m after 1 s
    assert -w.state[2, 0] == pytest.approx(0.98, abs=0.03)
    assert np.all(w.state[2, 1:] == 0.0)


def test_offboard_roll_setpoint_is_tracked_by_the_inner_loop() -> None:
    w = _world(n=1, z=-5.0)
    _offboard(w, 0)
    _fly(w, 1.0, {0: HOVER}, roll=0.2)
    assert w.snapshot().euler_rad[0][0] == pytest.approx(0.2, abs=0.005)
    euler, thrust = w.commanded()
    assert euler[0, 0] == pytest.approx(0.2) and thrust[0] == pytest.approx(HOVER)


def test_offboard_loss_failsafe_levels_holds_then_lands_and_disarms() -> None:
    w = _world(n=2)
    _offboard(w, 0)
    _fly(w, 1.0, {0: 0.6})
    _fly(w, 1.0, {0: 0.4})  # climbed ~2 m and stopped
    _fly(w, 0.3, {0: HOVER}, roll=0.15)  # tilted when the setpoints stop
    altitude = -w.state[2, 0]
    texts = _fly(w, 1.0, {})
    assert texts and "Failsafe: offboard lost" in texts[0]
    snap = w.snapshot()
    assert abs(snap.euler_rad[0][0]) < 0.01 and abs(snap.euler_rad[0][1]) < 0.01  # level
    assert w.autopilot.mode[0] == Mode.HOLD
    texts = _fly(w, 10.0, {})
    assert (
        texts[0] == "0:Failsafe: descending to land" and texts[-1] == "0:Failsafe: landed, disarmed"
    )
    assert w.state[2, 0] == 0.0 and not w.autopilot.armed[0]
    assert altitude > 1.5 and not w.autopilot.crashed[0]  # a gentle landing from > 1.5 m


def test_hold_mode_keeps_the_altitude_it_was_entered_at() -> None:
    w = _world(n=1)
    _offboard(w, 0)
    _fly(w, 1.5, {0: 0.6})
    w.autopilot.set_mode(0, Mode.HOLD, w.t_s)
    entered = -w.state[2, 0]
    _fly(w, 8.0, {})  # it was climbing at 2.9 m/s: overshoot, then back
    assert -w.state[2, 0] == pytest.approx(entered, abs=0.05)
    assert abs(w.state[5, 0]) < 0.05 and w.autopilot.armed[0]


def test_crash_falls_lands_hard_and_goes_silent() -> None:
    w = _world(n=2, z=-3.0)
    for i in (0, 1):
        w.autopilot.setpoint(i, _sp(HOVER), 0.0)
        w.autopilot.set_mode(i, Mode.OFFBOARD, 0.0)
    w.autopilot.landed[:] = True  # armed mid-air, as if it had taken off
    for i in (0, 1):
        w.autopilot.arm(i, 0.0)
    w.autopilot.motor_failure(1, None, off=True)
    texts = _fly(w, 1.5, {0: HOVER})
    assert any(t.startswith("1:Crashed: hit the ground at 7.") for t in texts)
    assert w.autopilot.silent[1] and w.state[2, 1] == 0.0
    assert -w.state[2, 0] == pytest.approx(3.0, abs=0.05) and not w.autopilot.silent[0]


def test_one_motor_off_makes_the_vehicle_fall() -> None:
    w = _world(n=1, z=-10.0)
    w.autopilot.landed[:] = True
    w.autopilot.arm(0, 0.0)
    w.autopilot.motor_failure(0, 0, off=True)
    _fly(w, 1.0, {})
    assert w.state[5, 0] > 2.0  # falling (NED down), HOLD cannot hold it


def test_scheduled_crash_fires_at_its_time() -> None:
    w = _world(n=2, crashes=((0.5, 1),))
    texts = _fly(w, 0.48, {})
    assert not w.autopilot.crashed.any()
    texts = _fly(w, 0.04, {})
    assert texts == ["1:Failure injected: all motors off"] and w.autopilot.crashed[1]


def test_position_noise_is_seeded() -> None:
    a, b = _world(position_noise_m=0.1), _world(position_noise_m=0.1)
    pa, pb = a.snapshot().position_ned_m, b.snapshot().position_ned_m
    assert pa == pb and pa != _world().snapshot().position_ned_m
    assert np.std(np.array(pa) - _world().state[0:3].T) < 0.3


def test_per_vehicle_gains_change_only_that_vehicle() -> None:
    w = _world(n=2, z=-5.0)
    gains = w.gains
    assert isinstance(gains, FleetAttitudeGains)
    gains.kp_matrix[0, 1] = 36.0  # a slow roll loop on vehicle 1 only
    gains.kd_matrix[0, 1] = 11.4
    w.autopilot.landed[:] = True
    for i in (0, 1):
        _offboard(w, i)
    _fly(w, 0.1, {0: HOVER, 1: HOVER}, roll=0.2)
    roll = [row[0] for row in w.snapshot().euler_rad]
    assert roll[0] > 0.1 and roll[1] < 0.05

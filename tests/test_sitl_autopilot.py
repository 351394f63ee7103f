"""The autopilot state machine on its own: arming checks, modes, failsafe steps, crash, wreck.

Altitudes and touchdown speeds are fed in directly, so every transition is checked without
physics.
"""

from __future__ import annotations

import numpy as np
import pytest

from sitl_sim.vehicle.autopilot import Autopilot, AutopilotConfig, Mode, Result, VehicleEvent
from sitl_sim.vehicle.setpoint import AttitudeSetpoint, validate_attitude_target

GROUND, AIR = 0.0, -2.0


def _sp(thrust: float = 0.5) -> AttitudeSetpoint:
    sp = validate_attitude_target((1.0, 0.0, 0.0, 0.0), thrust, 7)
    assert isinstance(sp, AttitudeSetpoint)
    return sp


def _ap(n: int = 2) -> Autopilot:
    return Autopilot(n, AutopilotConfig(), np.zeros(n))


def _update(ap: Autopilot, t: float, z: float, impact: float = 0.0) -> list[VehicleEvent]:
    """Every vehicle at NED z ``z``; vehicle 0 touched down at ``impact`` m/s."""
    impacts = np.zeros(ap.n)
    impacts[0] = impact
    return ap.update(t, np.full(ap.n, z), impacts)


def _texts(events: list[VehicleEvent]) -> list[str]:
    return [e.text for e in events]


def _flying_offboard(ap: Autopilot, t: float = 0.0) -> None:
    ap.setpoint(0, _sp(), t)
    assert ap.arm(0, t)[0].result == Result.ACCEPTED
    assert ap.set_mode(0, Mode.OFFBOARD, t)[0].result == Result.ACCEPTED
    _update(ap, t, AIR)


def test_arms_in_hold_on_the_ground_and_reports_it() -> None:
    ap = _ap()
    outcome, events = ap.arm(0, 0.0)
    assert outcome.result == Result.ACCEPTED and ap.armed[0] and not ap.armed[1]
    assert _texts(events) == ["Armed"]
    assert ap.arm(0, 0.0)[0].result == Result.ACCEPTED  # already armed: idempotent


def test_arming_is_denied_in_the_air_in_land_and_in_offboard_without_setpoints() -> None:
    ap = _ap()
    _update(ap, 0.0, AIR)
    assert ap.arm(0, 0.0)[0].result == Result.DENIED
    _update(ap, 0.1, GROUND)
    ap.set_mode(0, Mode.LAND, 0.1)
    assert ap.arm(0, 0.1)[0].result == Result.DENIED
    ap.setpoint(0, _sp(), 0.1)
    ap.set_mode(0, Mode.OFFBOARD, 0.1)
    assert ap.arm(0, 5.0)[0].result == Result.DENIED  # setpoint 4.9 s old
    assert ap.arm(0, 0.2)[0].result == Result.ACCEPTED


def test_offboard_needs_a_fresh_setpoint_stream() -> None:
    ap = _ap()
    outcome, _ = ap.set_mode(0, Mode.OFFBOARD, 1.0)
    assert outcome.result == Result.DENIED and "setpoint" in outcome.reason
    ap.setpoint(0, _sp(), 1.0)
    assert ap.set_mode(0, Mode.OFFBOARD, 1.4)[0].result == Result.ACCEPTED
    assert ap.mode[0] == Mode.OFFBOARD


def test_disarm_in_flight_is_denied_unless_forced() -> None:
    ap = _ap()
    _flying_offboard(ap)
    assert ap.disarm(0)[0].result == Result.DENIED and ap.armed[0]
    outcome, events = ap.disarm(0, force=True)
    assert outcome.result == Result.ACCEPTED and not ap.armed[0]
    assert ap.mode[0] == Mode.HOLD and "forced" in events[0].text


def test_offboard_loss_levels_holds_descends_and_disarms_on_touchdown() -> None:
    ap = _ap()
    _flying_offboard(ap)
    ap.setpoint(0, _sp(), 1.0)
    assert _update(ap, 1.5, AIR) == []  # exactly the timeout: still fine
    events = _update(ap, 1.52, AIR)
    assert "Failsafe: offboard lost" in _texts(events)[0]
    assert ap.failsafe[0] and ap.mode[0] == Mode.HOLD and ap.armed[0]
    assert _update(ap, 2.5, AIR) == []  # level hold for 1 s
    assert _texts(_update(ap, 2.52, AIR)) == ["Failsafe: descending to land"]
    assert ap.mode[0] == Mode.LAND
    assert _update(ap, 3.0, AIR) == []
    assert _texts(_update(ap, 4.0, GROUND)) == ["Failsafe: landed, disarmed"]
    assert not ap.armed[0] and not ap.failsafe[0] and ap.mode[0] == Mode.HOLD
    assert not ap.armed[1]  # the other vehicle never moved


def test_setpoints_resuming_do_not_cancel_the_failsafe_but_a_mode_change_does() -> None:
    ap = _ap()
    _flying_offboard(ap)
    _update(ap, 0.6, AIR)
    assert ap.failsafe[0]
    ap.setpoint(0, _sp(), 0.7)
    _update(ap, 0.7, AIR)
    assert ap.failsafe[0] and ap.mode[0] == Mode.HOLD
    assert ap.set_mode(0, Mode.OFFBOARD, 0.7)[0].result == Result.ACCEPTED
    assert not ap.failsafe[0] and ap.mode[0] == Mode.OFFBOARD


def test_land_mode_disarms_on_touchdown() -> None:
    ap = _ap()
    _flying_offboard(ap)
    ap.set_mode(0, Mode.LAND, 0.1)
    assert _update(ap, 0.2, AIR) == []
    assert _texts(_update(ap, 0.3, GROUND)) == ["Landed, disarmed"]
    assert not ap.armed[0]


def test_crash_falls_then_the_wreck_goes_silent_one_tick_after_resting() -> None:
    ap = _ap()
    _flying_offboard(ap)
    events = ap.motor_failure(0, None, off=True)
    assert ap.crashed[0] and not ap.armed[0] and "all motors off" in events[0].text
    assert _update(ap, 0.1, AIR) == [] and not ap.silent[0]
    events = _update(ap, 0.2, GROUND, impact=6.0)
    assert _texts(events) == ["Crashed: hit the ground at 6.0 m/s"]
    assert not ap.silent[0]  # the impact report still goes out
    _update(ap, 0.3, GROUND)
    assert ap.silent[0] and not ap.silent[1]
    assert ap.arm(0, 0.3)[0].result == Result.FAILED
    assert ap.set_mode(0, Mode.HOLD, 0.3)[0].result == Result.FAILED


def test_hard_landing_destroys_an_intact_vehicle() -> None:
    ap = _ap()
    _flying_offboard(ap)
    events = _update(ap, 0.1, GROUND, impact=3.5)
    assert "Hard landing at 3.5 m/s" in events[0].text
    assert ap.crashed[0] and not ap.armed[0]
    assert _update(ap, 0.2, GROUND, impact=1.9) == []  # below the limit: nothing new


def test_single_motor_failure_and_recovery() -> None:
    ap = _ap()
    events = ap.motor_failure(0, 2, off=True)
    assert "motor 3 off" in events[0].text and not ap.crashed[0]
    assert ap.motor_ok[:, 0].tolist() == [True, True, False, True]
    assert ap.arm(0, 0.0)[0].result == Result.FAILED
    ap.motor_failure(0, 2, off=False)
    assert ap.motor_ok.all() and ap.arm(0, 0.0)[0].result == Result.ACCEPTED


@pytest.mark.parametrize("mode", list(Mode))
def test_event_texts_fit_one_statustext(mode: Mode) -> None:
    ap = _ap()
    _flying_offboard(ap)
    texts = _texts(ap.set_mode(0, mode, 0.0)[1])
    texts += _texts(_update(ap, 5.0, AIR)) + _texts(_update(ap, 9.0, AIR))
    texts += _texts(_update(ap, 9.5, GROUND, impact=9.9))
    texts += _texts(ap.motor_failure(1, 3, off=True))
    assert all(len(t.encode()) <= 50 for t in texts), texts

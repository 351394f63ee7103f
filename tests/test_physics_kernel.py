"""The fused physics sub-step (sitl_sim.physics.kernel) against the reference functions.

The reference is the numpy oracle (tests/physics_oracle.py): ``inner_loop`` (attitude controller
+ mixer) followed by the rotor mask and ``step_with_contact`` (RK4 + ground contact), the array
code the simulator ran before the per-vehicle rules were written once and compiled. The
kernel must give the same states, rotor forces and touchdown speeds to 1e-9 over hundreds of steps
that go through take-off from the ground, touchdowns and hard landings, vehicles resting tilted,
saturated mixers (full roll commands, thrust 0 and 1, a NaN thrust), disarming, dead motors,
per-vehicle gains and the yaw wrap; and a World stepped with it must fly as it did with the
reference step, and ``swarm simulate`` (a World whose steady periods take their sub-steps in one
kernel call) as one sub-step at a time.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from gcs.reference.flight import ReferenceFlight
from protocols.model.frames import FloatArray, wxyz_from_zyx
from protocols.scenario.scenario_file import parse_scenario
from sitl_sim.physics.attitude_control import AttitudeGains
from sitl_sim.physics.dynamics import initial_state
from sitl_sim.physics.kernel import PhysicsKernel
from sitl_sim.physics.vehicle_params import VehicleParams
from sitl_sim.vehicle.autopilot import AutopilotConfig, Mode, VehicleEvent
from sitl_sim.vehicle.setpoint import AttitudeSetpoint, validate_attitude_target
from sitl_sim.vehicle.tunables import FleetAttitudeGains
from sitl_sim.vehicle.world import World, WorldConfig
from tests.physics_oracle import inner_loop, step_with_contact

TOL = 1e-9
DT = 0.002


def _reference_substep(
    state: FloatArray,
    euler: FloatArray,
    thrust: FloatArray,
    params: VehicleParams,
    gains: AttitudeGains,
    armed: npt.NDArray[np.bool_],
    motor_ok: npt.NDArray[np.bool_],
) -> tuple[FloatArray, FloatArray, FloatArray]:
    rotor = inner_loop(state, euler, thrust, params, gains, armed)
    rotor[~motor_ok] = 0.0
    result = step_with_contact(state, rotor, params, DT)
    return result.state, rotor, result.impact_speed_m_s


def _forces(rotor: FloatArray, params: VehicleParams) -> FloatArray:
    """Rotor forces (4, N) N of rotor speeds (4, N) rad/s."""
    return params.thrust_coeff * (rotor * rotor)


def _fleet(n: int, rng: np.random.Generator) -> FloatArray:
    """Vehicles spread out: a third on the ground (some yawed past +-pi), the rest at 0.2-6 m,
    moving and spinning, some tilted by up to 60 degrees."""
    pos = np.stack([3.0 * np.arange(n), rng.uniform(-2, 2, n), -rng.uniform(0.2, 6.0, n)], 1)
    pos[::3, 2] = 0.0
    state = initial_state(pos, rng.uniform(-3.5, 3.5, n))
    airborne = pos[:, 2] < 0.0
    state[3:6, airborne] = rng.normal(0.0, 1.5, (3, int(airborne.sum())))
    state[10:13, airborne] = rng.normal(0.0, 2.0, (3, int(airborne.sum())))
    tilt = rng.normal(0.0, 0.5, (3, n))
    state[7:10] += tilt * state[6]
    state[6:10] /= np.linalg.norm(state[6:10], axis=0)
    return state


@pytest.mark.parametrize(("n", "seed"), [(1, 0), (3, 1), (9, 2), (40, 3)])
def test_kernel_matches_inner_loop_and_step_with_contact(n: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    params = VehicleParams(rotor_speed_min_rad_s=50.0 if seed % 2 else 0.0)
    gains = FleetAttitudeGains(AttitudeGains(), n)
    gains.kp_matrix[:, 0] *= 1.7  # per-vehicle gains
    kernel = PhysicsKernel(params, n, DT, gains)
    ref = fast = _fleet(n, rng)
    armed = np.ones(n, dtype=bool)
    motor_ok = np.ones((4, n), dtype=bool)
    touchdowns = hard = saturated = resting = 0
    for k in range(600):
        phase = k // 100
        euler = np.stack(
            [
                0.4 * np.sin(0.03 * k + np.arange(n)),
                0.3 * np.cos(0.02 * k + 2.0 * np.arange(n)),
                np.full(n, 3.1 if phase % 2 else -3.1),  # across the yaw wrap
            ]
        )
        thrust = np.clip(0.5 + 0.3 * np.sin(0.05 * k + np.arange(n)), 0.0, 1.0)
        if phase == 1:  # saturate: full roll one way, thrust at the limits
            euler[0, ::2] = 1.4
            thrust[::2] = 1.0
            thrust[1::2] = 0.0
        if phase == 2 and n > 1:
            thrust[1] = np.nan  # demands that are not finite
            euler[1, -1] = np.nan if k % 20 < 10 else euler[1, -1]
        if phase == 3:  # some vehicles disarmed (they fall), a motor dead on another
            armed[::4] = False
            motor_ok[2, 1::5] = False
        if phase == 4:
            armed[:] = True
        if phase == 5:  # all idle: everything comes down and lands
            thrust[:] = 0.0
        if k % 100 == 50:
            gains.kd_matrix[:, -1] = 20.0 + k / 50.0  # a parameter set between steps
        ref, rotor_ref, impact_ref = _reference_substep(
            ref, euler, thrust, params, gains, armed, motor_ok
        )
        fast, rotor_fast, impact = kernel.substep(fast, euler, thrust, armed & motor_ok)
        impact_fast = np.zeros(n) if impact is None else impact
        np.testing.assert_allclose(fast, ref, rtol=0.0, atol=TOL, err_msg=f"step {k}")
        # rotor forces, not speeds: a rotor at zero force (minimum speed 0, the mixer saturated)
        # has a speed of sqrt(round-off), ~1e-6 rad/s for ~1e-17 N (the C library's and numpy's
        # sin/atan2 may differ in the last bit)
        np.testing.assert_allclose(
            _forces(rotor_fast, params), _forces(rotor_ref, params), rtol=0.0, atol=TOL
        )
        np.testing.assert_allclose(impact_fast, impact_ref, rtol=0.0, atol=TOL)
        touchdowns += int(np.count_nonzero(impact_ref))
        hard += int(np.count_nonzero(impact_ref > AutopilotConfig().hard_landing_m_s))
        saturated += int(np.count_nonzero(rotor_ref >= params.rotor_speed_max_rad_s))
        resting += int(np.count_nonzero(ref[2] == 0.0))
    # the run went through what it is meant to test
    assert resting > 0 and saturated > 0
    if n >= 3:
        assert touchdowns > 0 and hard > 0


def test_kernel_uses_new_gains_and_shared_gains() -> None:
    params, n = VehicleParams(), 4
    state = _fleet(n, np.random.default_rng(7))
    euler, thrust = np.full((3, n), 0.2), np.full(n, 0.5)
    kernel = PhysicsKernel(params, n, DT)  # default gains, shared by all vehicles
    new, rotor, _ = kernel.substep(state, euler, thrust)
    ref = step_with_contact(state, inner_loop(state, euler, thrust, params), params, DT)
    np.testing.assert_allclose(new, ref.state, rtol=0.0, atol=TOL)
    other = AttitudeGains(kp=(100.0, 200.0, 50.0), kd=(10.0, 20.0, 5.0))
    kernel.use_gains(other.kp_col(), other.kd_col())
    new, rotor, _ = kernel.substep(state, euler, thrust)
    np.testing.assert_allclose(rotor, inner_loop(state, euler, thrust, params, other), atol=TOL)


def test_kernel_returns_new_arrays_and_leaves_its_inputs_alone() -> None:
    params, n = VehicleParams(), 3
    state = _fleet(n, np.random.default_rng(8))
    before = state.copy()
    kernel = PhysicsKernel(params, n, DT)
    first, rotor1, _ = kernel.substep(state, np.zeros((3, n)), np.full(n, 0.5))
    kept = first.copy(), rotor1.copy()
    second, rotor2, _ = kernel.substep(first, np.zeros((3, n)), np.full(n, 0.5))
    np.testing.assert_array_equal(state, before)
    np.testing.assert_array_equal(first, kept[0])
    np.testing.assert_array_equal(rotor1, kept[1])
    assert second is not first and rotor2 is not rotor1


# --- the World (swarm sim) steps as it did with the reference functions -----------------------


def _reference_world_step(w: World) -> list[VehicleEvent]:
    """World.step as it was before the kernel: inner_loop, dead motors, step_with_contact."""
    ap = w.autopilot
    w.guidance.prepare(w.state)
    impact = np.zeros(w.n)
    state = w.state
    for _ in range(w.substeps):
        euler, thrust = w.guidance.command(state)
        rotor = inner_loop(state, euler, thrust, w.params, w.gains, ap.armed)
        if not ap.motor_ok.all():
            rotor[~ap.motor_ok] = 0.0
        result = step_with_contact(state, rotor, w.params, w.dt_physics_s)
        w.rotor_speed_rad_s = rotor
        state = result.state
        np.maximum(impact, result.impact_speed_m_s, out=impact)
    w.state = state
    w.tick += 1
    events, w.pending_events = w.pending_events, []
    events += ap.update(w.t_s, state[2], impact)
    while w._crashes and w._crashes[0][0] <= w.t_s + 1e-9:
        _, vehicle = w._crashes.pop(0)
        events += ap.motor_failure(vehicle, None, off=True)
    return events


def _world(n: int) -> World:
    positions = np.stack([2.0 * np.arange(n), np.zeros(n), np.zeros(n)], axis=1)
    config = WorldConfig(crashes=((2.0, 1),))
    gains = FleetAttitudeGains(AttitudeGains(), n)
    return World(VehicleParams(), gains, positions, np.zeros(n), config, np.random.default_rng(1))


def _drive(w: World, tick: int) -> None:
    """Setpoints and commands as agents would send them: all climb in OFFBOARD; vehicle 2 is
    switched to HOLD, vehicle 3 to LAND, vehicle 4 loses its setpoints (failsafe), vehicle 0
    loses a motor; the gains of vehicle 5 change."""
    ap, t = w.autopilot, w.t_s
    for i in range(w.n):
        if i == 4 and tick > 120:
            continue
        sp = validate_attitude_target(wxyz_from_zyx(0.3, 0.0, 0.1 * np.sin(0.05 * tick + i)), 0.6)
        assert isinstance(sp, AttitudeSetpoint)
        ap.setpoint(i, sp, t)
    if tick == 5:
        for i in range(w.n):
            ap.landed[i] = True
            ap.arm(i, t)
            ap.set_mode(i, Mode.OFFBOARD, t)
    if tick == 80:
        ap.set_mode(2, Mode.HOLD, t)
        ap.set_mode(3, Mode.LAND, t)
    if tick == 150:
        ap.motor_failure(0, 3, off=True)
    if tick == 160:
        w.gains.kp_matrix[:, 5] = 150.0


def test_world_steps_as_with_the_reference_functions() -> None:
    fast, ref = _world(6), _world(6)
    for tick in range(300):
        _drive(fast, tick)
        _drive(ref, tick)
        events_fast = fast.step()
        events_ref = _reference_world_step(ref)
        assert [e.text for e in events_fast] == [e.text for e in events_ref], tick
        np.testing.assert_allclose(fast.state, ref.state, rtol=0.0, atol=TOL, err_msg=str(tick))
        np.testing.assert_allclose(
            _forces(fast.rotor_speed_rad_s, fast.params),
            _forces(ref.rotor_speed_rad_s, ref.params),
            rtol=0.0,
            atol=TOL,
        )
    ap = fast.autopilot
    assert ap.crashed[1] and not ap.motor_ok[3, 0] and ap.failsafe[4]
    assert ap.mode[2] == Mode.HOLD and ap.mode[3] == Mode.LAND


# --- swarm simulate flies as the world one sub-step at a time ------------------------------------


SCENARIO = """
version = 1
name = "kernel"
duration_s = 16.0
settle_s = 3.0
[comms]
range_m = 6.0
[[drones]]
position_ned_m = [0.0, 0.0, 0.0]
[[drones]]
position_ned_m = [0.0, 2.5, 0.0]
[[drones]]
position_ned_m = [2.5, 0.0, 0.0]
[[drones]]
position_ned_m = [2.5, 2.5, 0.0]
[[trajectory.waypoints]]
t_s = 0.0
centre_ned_m = [1.25, 1.25, -2.0]
spread_m = [1.25, 1.25, 0.0]
[[trajectory.waypoints]]
t_s = 6.0
centre_ned_m = [3.25, 1.25, -3.0]
spread_m = [1.25, 1.25, 0.0]
yaw_deg = 40.0
[[faults]]
kind = "crash"
t_s = 8.0
drone = 1
[[faults]]
kind = "dropout"
t_s = 9.0
drone = 2
"""


def test_swarm_simulate_flies_as_with_one_substep_at_a_time(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """``swarm simulate``'s World takes a period's sub-steps in one kernel call while no
    vehicle's command depends on the state (World.step); the flight is the one of one call per
    sub-step to the last bit, through take-off, a crash (a wreck falling, a hard landing), a
    drop-out's failsafe (altitude hold, then LAND: sub-step by sub-step) and its disarm."""
    import tomllib

    scenario = parse_scenario(tomllib.loads(SCENARIO), "kernel.toml")
    fast = ReferenceFlight(scenario)
    record_fast = fast.run()
    substeps = PhysicsKernel.substeps
    calls = {"fused": 0}

    def counted(self: PhysicsKernel, *args: object, **kwargs: object) -> object:
        calls["fused"] += 1
        return substeps(self, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(PhysicsKernel, "substeps", counted)
    fused = ReferenceFlight(scenario)
    fused.run()
    # most periods in one call; those of the failsafe's hold and landing sub-step by sub-step
    periods = round(scenario.duration_s * scenario.rates.control_hz)
    assert 0.5 * periods < calls["fused"] < periods - 100, calls
    calls["fused"] = 0
    one_by_one = ReferenceFlight(scenario)
    one_by_one.world._fused = False
    record_ref = one_by_one.run()
    assert calls["fused"] == 0
    for name in ("position_ned_m", "velocity_ned_m_s", "euler_rad", "thrust_n", "moments_nm"):
        np.testing.assert_array_equal(
            getattr(record_fast, name), getattr(record_ref, name), err_msg=name
        )
    kinds = [(e.t_s, e.kind, e.fields.get("drone")) for e in fast.events]
    assert kinds == [(e.t_s, e.kind, e.fields.get("drone")) for e in one_by_one.events]
    # the flight went through a crash (hard landing), a failsafe landing and a disarm
    assert {"hard_landing", "failsafe", "disarmed"} <= {k for _, k, _ in kinds}


@pytest.mark.parametrize(("n", "seed"), [(1, 0), (9, 2), (40, 3)])
def test_substeps_is_substep_after_substep(n: int, seed: int) -> None:
    """PhysicsKernel.substeps (swarm simulate's tick) gives the numbers of as many substep calls,
    bit for bit, through take-off, flight, saturation, a falling disarmed vehicle and touchdowns
    (ground contact within a run and on its last sub-step), and the same touchdown speeds."""
    rng = np.random.default_rng(seed)
    params = VehicleParams()
    kernel = PhysicsKernel(params, n, DT)
    state = _fleet(n, rng)
    state[2, ::2] = 0.0  # some on the ground
    armed = np.ones(n, dtype=bool)
    touched = 0
    for tick in range(120):
        euler = np.stack(
            [0.3 * np.sin(0.1 * tick + np.arange(n)), 0.2 * np.cos(0.07 * tick + np.arange(n)),
             np.full(n, 3.1)]
        )  # fmt: skip
        thrust = np.clip(0.55 + 0.3 * np.sin(0.2 * tick + np.arange(n)), 0.0, 1.0)
        if tick >= 60:
            thrust[:] = 0.05 if tick < 100 else 1.0
            armed[::3] = False
        count = 1 + tick % 10
        one = state
        impacts = []
        for _ in range(count):
            one, rotor_one, impact = kernel.substep(one, euler, thrust, armed)
            if impact is not None:
                impacts.append(impact)
        many, rotor_many, impacts_many = kernel.substeps(state, euler, thrust, armed, count)
        np.testing.assert_array_equal(many, one, err_msg=f"tick {tick}")
        np.testing.assert_array_equal(rotor_many, rotor_one)
        assert len(impacts_many) == len(impacts)
        for a, b in zip(impacts_many, impacts, strict=True):
            np.testing.assert_array_equal(a, b)
        touched += len(impacts)
        state = many
    assert touched > 0
    with pytest.raises(ValueError, match="at least 1"):
        kernel.substeps(state, euler, thrust, armed, 0)

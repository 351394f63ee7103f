"""Motors that lag (``[vehicle] motor_tau_s``, ``[vehicles] motor_tau_spread``): each rotor's speed
follows its command as a first-order lag, ``d w / dt = (w_cmd - w) / tau`` (thrust ``c w^2``),
exact over a physics step (the command is held) with the rigid body's RK4 taking the rotors'
wrench at its stage times; the rotor speeds are state the World keeps per vehicle. Checked against
the closed-form step response, the numpy oracle (tests/physics_oracle.py), the spread's
statistics, a simulator shard against the whole world, the scenario's checks, and a flight."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from sitl_client import ROOT, simulate_metrics

from gcs.cli.main import _parser
from gcs.report.scenario_summary import summary_lines
from protocols.model.frames import G_M_S2, FloatArray
from protocols.scenario.scenario_file import ScenarioError, load_scenario
from sitl_sim.launch import build_config, build_world
from sitl_sim.physics.attitude_control import AttitudeGains
from sitl_sim.physics.dynamics import initial_state
from sitl_sim.physics.kernel import PhysicsKernel
from sitl_sim.physics.vehicle_params import VehicleParams, vehicle_scales
from sitl_sim.vehicle.autopilot import Mode, Result
from sitl_sim.vehicle.config import vehicle_scales as scenario_scales
from sitl_sim.vehicle.setpoint import AttitudeSetpoint, validate_attitude_target
from sitl_sim.vehicle.world import World
from tests.physics_oracle import inner_loop, step_with_contact, step_with_lag

DT = 0.002
LEVEL = np.zeros((3, 1))


def _step_response(params: VehicleParams, steps: int) -> tuple[FloatArray, FloatArray]:
    """One level vehicle in the air, its rotors at rest, commanded half thrust: its rotor 1's
    speed (rad/s) and its downward speed (m/s) after each of ``steps`` physics steps."""
    kernel = PhysicsKernel(params, 1, DT)
    state, rotor = initial_state(np.array([[0.0, 0.0, -5.0]])), None
    speed, vz = np.empty(steps), np.empty(steps)
    for k in range(steps):
        state, rotor, _ = kernel.substep(state, LEVEL, np.array([0.5]), None, rotor)
        speed[k], vz[k] = rotor[0, 0], state[5, 0]
    return speed, vz


@pytest.mark.parametrize("tau_s", [0.03, 0.025, 0.005])
def test_a_rotor_follows_a_step_as_a_first_order_lag(tau_s: float) -> None:
    """The rotor speed is ``w_c (1 - exp(-t / tau))`` (to round-off: the lag is solved exactly),
    so it reaches 1 - 1/e of the command at tau (within one step; its thrust ``c w^2`` then
    (1 - 1/e)^2 of the final); the body's vertical speed is the
    closed-form integral of ``g - 4 c w(t)^2 / m``:
    ``g t - (4 c w_c^2 / m) (t - 2 tau (1 - e^(-t/tau)) + tau / 2 (1 - e^(-2t/tau)))``, which
    RK4 with the rotors' wrench at its stage times follows within Simpson's rule's error bound
    (~2e-9 m/s a step at tau = 30 ms)."""
    params = VehicleParams(motor_tau_s=tau_s)
    steps = round(4 * tau_s / DT)
    speed, vz = _step_response(params, steps)
    command, _ = _step_response(VehicleParams(), 1)  # no lag: the command, at once
    w_c = command[0]
    t = DT * np.arange(1, steps + 1)
    np.testing.assert_allclose(speed, w_c * (1.0 - np.exp(-t / tau_s)), rtol=1e-12, atol=0.0)
    first = t[np.argmax(speed >= (1.0 - 1.0 / math.e) * w_c)]
    assert abs(first - tau_s) <= DT + 1e-12  # (at tau itself it may be short by round-off)
    thrust = 4.0 * params.thrust_coeff * speed**2
    k_tau = round(tau_s / DT) - 1  # (the step ending at tau when tau is a multiple of DT)
    if abs(t[k_tau] - tau_s) < 1e-12:
        final = 4.0 * params.thrust_coeff * w_c**2
        assert thrust[k_tau] == pytest.approx((1.0 - 1.0 / math.e) ** 2 * final, rel=1e-12)
    decay = np.exp(-t / tau_s)
    integral = t - 2.0 * tau_s * (1.0 - decay) + 0.5 * tau_s * (1.0 - decay * decay)
    lift = 4.0 * params.thrust_coeff * w_c**2 / params.mass_kg
    # RK4 on an input that depends on time alone is Simpson's rule: each step within
    # h^5 / 2880 max|f| of the integral, f at most 14 lift / tau^4 (at t = 0)
    simpson = DT**5 / 2880.0 * 14.0 * lift / tau_s**4
    error = np.abs(vz - (G_M_S2 * t - lift * integral))
    assert np.all(error <= np.arange(1, steps + 1) * simpson + 1e-12), error.max()


def test_without_a_time_constant_the_rotors_turn_as_commanded_at_once() -> None:
    """tau = 0: the first step's rotor speed is the command, and the flight is today's to the
    bit, whatever rotor speeds the kernel is handed."""
    speed, vz = _step_response(VehicleParams(motor_tau_s=0.0), 20)
    assert np.all(speed == speed[0]) and speed[0] > 0.0
    kernel = PhysicsKernel(VehicleParams(), 1, DT)
    state = initial_state(np.array([[0.0, 0.0, -5.0]]))
    plain, plain_rotor, _ = kernel.substeps(state, LEVEL, np.array([0.5]), None, 20)
    handed, handed_rotor, _ = kernel.substeps(
        state, LEVEL, np.array([0.5]), None, 20, np.full((4, 1), 123.0)
    )
    assert plain.tobytes() == handed.tobytes() and plain_rotor.tobytes() == handed_rotor.tobytes()
    assert plain[5, 0] == vz[-1]


def _fleet_state(n: int, rng: np.random.Generator) -> FloatArray:
    """Vehicles spread out, a third on the ground, the rest at 0.2-6 m, moving, spinning, tilted."""
    pos = np.stack([3.0 * np.arange(n), rng.uniform(-2, 2, n), -rng.uniform(0.2, 6.0, n)], 1)
    pos[::3, 2] = 0.0
    state = initial_state(pos, rng.uniform(-3.5, 3.5, n))
    up = pos[:, 2] < 0.0
    state[3:6, up] = rng.normal(0.0, 1.5, (3, int(up.sum())))
    state[10:13, up] = rng.normal(0.0, 2.0, (3, int(up.sum())))
    state[7:10] += rng.normal(0.0, 0.4, (3, n)) * state[6]
    state[6:10] /= np.linalg.norm(state[6:10], axis=0)
    return state


def test_the_kernel_with_lag_is_the_oracles_and_vehicles_without_it_are_todays() -> None:
    """A fleet where every other vehicle's motors lag (each its own time constant, its rotors
    started anywhere), through take-off, saturation, disarming, a dead motor and idling: each
    physics step of the kernel from the oracle's state is the oracle's step to 1e-9 (the lagging
    ones its ``step_with_lag``, the contact judged on the thrust at the step's end; the others
    its ``step_with_contact``), states and rotor forces, and flown on its own over the 400 steps
    the kernel stays within 1e-8 of it. Not to the bit: a rotor the mixer sets to zero force
    turns at sqrt(round-off), ~1e-6 rad/s, whose last bits the C library's sin and numpy's set
    differently (tests/test_physics_kernel.py); lagging, that speed weighs in the rotor's thrust
    while it spins down (~1e-10 N). ``substeps`` equals one step at a time handed the last rotor
    speeds, to the bit."""
    n, rng = 8, np.random.default_rng(4)
    base = VehicleParams()
    fleet = [VehicleParams(motor_tau_s=0.01 + 0.01 * i) if i % 2 == 0 else base for i in range(n)]
    gains = AttitudeGains()
    kernel = PhysicsKernel(base, n, DT, gains, fleet)
    ref = fast = _fleet_state(n, rng)
    ref_rotor = fast_rotor = rng.uniform(0.0, 900.0, (4, n))
    on = np.ones((4, n), dtype=bool)
    for k in range(400):
        phase = k // 100
        euler = np.stack([0.3 * np.sin(0.03 * k + np.arange(n)), 0.2 * np.cos(0.02 * k)
                          + np.zeros(n), np.full(n, 3.1 if phase % 2 else -3.1)])  # fmt: skip
        thrust = np.clip(0.5 + 0.3 * np.sin(0.05 * k + np.arange(n)), 0.0, 1.0)
        if phase == 1:
            euler[0, ::2], thrust[::2], thrust[1::2] = 1.4, 1.0, 0.0
        if phase == 2:
            on[:, ::4] = False  # disarmed: their rotors spin down
            on[2, 1::3] = False  # a dead motor
        if phase == 3:
            on[:] = True
            thrust[:] = 0.0
        command = np.stack([inner_loop(ref[:, [i]], euler[:, [i]], thrust[[i]], fleet[i], gains)
                            for i in range(n)], 1)[:, :, 0] * on  # fmt: skip
        new_ref, new_rotor = np.empty_like(ref), np.empty_like(ref_rotor)
        for i, params in enumerate(fleet):
            col = [i]
            if params.motor_tau_s > 0.0:
                result, new_rotor[:, col] = step_with_lag(
                    ref[:, col], ref_rotor[:, col], command[:, col], params, DT
                )
            else:
                result = step_with_contact(ref[:, col], command[:, col], params, DT)
                new_rotor[:, col] = command[:, col]
            new_ref[:, col] = result.state
        one, one_rotor, _ = kernel.substep(ref, euler, thrust, on, ref_rotor)
        np.testing.assert_allclose(one, new_ref, rtol=0.0, atol=1e-9, err_msg=f"step {k}")
        np.testing.assert_allclose(
            base.thrust_coeff * one_rotor**2, base.thrust_coeff * new_rotor**2, atol=1e-9
        )
        ref, ref_rotor = new_ref, new_rotor
        fast, fast_rotor, _ = kernel.substep(fast, euler, thrust, on, fast_rotor)
    np.testing.assert_allclose(fast, ref, rtol=0.0, atol=1e-8)
    state, rotor = _fleet_state(n, rng), rng.uniform(0.0, 900.0, (4, n))
    euler, thrust = np.full((3, n), 0.1), np.full(n, 0.6)
    together = kernel.substeps(state, euler, thrust, None, 10, rotor)
    for _ in range(10):
        state, rotor, _ = kernel.substep(state, euler, thrust, None, rotor)
    assert together[0].tobytes() == state.tobytes() and together[1].tobytes() == rotor.tobytes()


def test_the_time_constants_spread_as_drawn_from_the_seed() -> None:
    """Each vehicle's time constant factor: normal about 1 with the spread as its relative
    standard deviation, cut at 3 sigma, apart from the masses and thrusts (which stay what they
    were without it), one vehicle's the same however many are drawn after it (shards)."""
    plain = vehicle_scales(20_000, 0.05, 0.02, 3)
    scales = vehicle_scales(20_000, 0.05, 0.02, 3, 0.1)
    assert [s[:2] for s in scales] == list(plain) and all(len(s) == 3 for s in scales)
    tau = np.array([s[2] for s in scales])
    assert abs(tau.mean() - 1.0) < 0.003 and tau.std() == pytest.approx(0.1, rel=0.03)
    assert np.all(np.abs(tau - 1.0) <= 0.3 + 1e-12)
    assert abs(np.corrcoef(tau, [s[0] for s in scales])[0, 1]) < 0.03
    assert vehicle_scales(10, 0.0, 0.0, 3, 0.1) == vehicle_scales(20, 0.0, 0.0, 3, 0.1)[:10]
    assert vehicle_scales(10, 0.0, 0.0, 3, 0.1) != vehicle_scales(10, 0.0, 0.0, 4, 0.1)
    assert all(s[:2] == (1.0, 1.0) for s in vehicle_scales(10, 0.0, 0.0, 3, 0.1))


def _scenario(tmp_path: Path, extra: str, n: int = 3) -> Path:
    path = tmp_path / "lag.toml"
    drones = "".join(f"[[drones]]\nposition_ned_m = [{2 * i}, 0, 0]\n" for i in range(n))
    path.write_text(
        "version = 1\nduration_s = 10\nseed = 5\n" + drones
        + "[[trajectory.waypoints]]\nt_s = 0\ncentre_ned_m = [0.7, 0.7, -2]\n"
        f"spread_m = [{n}, 1, 0.1]\n" + extra
    )  # fmt: skip
    return path


def _offboard(world: World, thrust: float, roll: float) -> None:
    """Every vehicle armed in OFFBOARD at ``thrust`` and ``roll`` rad."""
    sp = validate_attitude_target(np.array([math.cos(roll / 2), math.sin(roll / 2), 0, 0]),
                                  thrust, 7)  # fmt: skip
    assert isinstance(sp, AttitudeSetpoint)
    for i in range(world.n):
        world.autopilot.setpoint(i, sp, world.t_s)
        assert world.autopilot.arm(i, world.t_s)[0].result == Result.ACCEPTED
        assert world.autopilot.set_mode(i, Mode.OFFBOARD, world.t_s)[0].result == Result.ACCEPTED


def test_a_shard_of_the_swarm_steps_as_in_the_whole_world(tmp_path: Path) -> None:
    """``swarm sim --scenario`` of six drones whose motors lag 30 ms with a 20 % spread (and
    masses 2 % apart): each vehicle's time constant is the nominal one times its own drawn
    factor, and the shards 0-2 and 3-5 step their vehicles, rotor speeds included, to the bit
    as the whole world does through take-off, a roll and its release."""
    path = _scenario(
        tmp_path, "[vehicle]\nmotor_tau_s = 0.03\n[vehicles]\nmotor_tau_spread = 0.2\n"
        "mass_spread = 0.02\n", n=6,
    )  # fmt: skip
    scenario = load_scenario(path)
    factors = [s[2] for s in scenario_scales(scenario)]

    def worlds(*drones: str) -> World:
        argv = ["sim", "--scenario", str(path), *(["--drones", *drones] if drones else [])]
        return build_world(build_config(_parser().parse_args(argv)))[0]

    whole, shards = worlds(), [worlds("0-2"), worlds("3-5")]
    taus = [v.motor_tau_s for v in whole.fleet]
    assert taus == pytest.approx([0.03 * f for f in factors], rel=1e-15)
    assert len(set(taus)) == 6 and all(0.01 < t < 0.05 for t in taus)
    for w in (whole, *shards):
        _offboard(w, 0.6, 0.0)
    for tick in range(150):
        for w in (whole, *shards):
            if tick in (50, 100):
                _offboard(w, 0.55, 0.2 if tick == 50 else 0.0)
            w.step()
    rows: list[npt.NDArray[np.intp]] = [np.arange(3), np.arange(3, 6)]
    for shard, idx in zip(shards, rows, strict=True):
        assert shard.state.tobytes() == whole.state[:, idx].tobytes()
        assert shard.rotor_speed_rad_s.tobytes() == whole.rotor_speed_rad_s[:, idx].tobytes()
    assert np.all(whole.state[2] < -0.5)  # they flew


def test_the_scenario_gives_the_time_constant_and_checks_it(tmp_path: Path) -> None:
    """Read into the vehicles' parameters and said by ``swarm scenario check``; a spread without
    a time constant changes nothing; a value out of range or not a number is one line naming
    the field."""
    lag = load_scenario(_scenario(tmp_path, "[vehicle]\nmotor_tau_s = 0.03\n"))
    assert lag.vehicle.motor_tau_s == 0.03 and lag.vehicles.motor_tau_spread == 0.0
    assert scenario_scales(lag) == ()
    (line,) = [x for x in summary_lines(lag) if x.startswith("vehicles ")]
    assert "all alike" in line and "motors' time constant 30 ms" in line, line
    spread = load_scenario(_scenario(
        tmp_path, "[vehicle]\nmotor_tau_s = 0.03\n[vehicles]\nmotor_tau_spread = 0.1\n"
    ))  # fmt: skip
    assert scenario_scales(spread) == vehicle_scales(3, 0.0, 0.0, 5, 0.1)
    (line,) = [x for x in summary_lines(spread) if x.startswith("vehicles ")]
    assert "motors' time constant 30 ms within 10 %" in line, line
    no_lag = load_scenario(_scenario(tmp_path, "[vehicles]\nmotor_tau_spread = 0.1\n"))
    assert scenario_scales(no_lag) == ()
    assert any(x.startswith("vehicles   all alike (0.34 kg)") for x in summary_lines(no_lag))
    for extra, field in (
        ("[vehicle]\nmotor_tau_s = -0.01\n", "vehicle.motor_tau_s"),
        ("[vehicle]\nmotor_tau_s = 0.6\n", "vehicle.motor_tau_s"),
        ('[vehicle]\nmotor_tau_s = "fast"\n', "vehicle.motor_tau_s"),
        ("[vehicles]\nmotor_tau_spread = -0.1\n", "vehicles.motor_tau_spread"),
        ("[vehicles]\nmotor_tau_spread = 0.5\n", "vehicles.motor_tau_spread"),
        ('[vehicles]\nmotor_tau_spread = "wide"\n', "vehicles.motor_tau_spread"),
    ):
        with pytest.raises(ScenarioError) as err:
            load_scenario(_scenario(tmp_path, extra))
        assert "\n" not in str(err.value) and field in str(err.value), str(err.value)


def test_a_swarm_with_lagging_motors_still_flies(tmp_path: Path) -> None:
    """``swarm simulate`` of scenarios/tilt9.toml with 30 ms motors, the first 20 s (judged
    from 10 s on: the climb to 6 m and the start of the tilt): no collision, the drones at least
    the scenario's 1 m apart (measured 2.46 m), the centre within 2 cm RMS of the plan (measured
    2.5 mm; the same flight without the lag 0.6 mm, a bar of at least 1.5 mm says the lag is
    felt)."""
    text = (ROOT / "scenarios" / "tilt9.toml").read_text().replace(
        "settle_s = 30.0", "settle_s = 10.0"
    )  # fmt: skip
    assert "settle_s = 10.0" in text
    scenario = tmp_path / "tilt9_lag.toml"
    scenario.write_text(text + "\n[vehicle]\nmotor_tau_s = 0.03\n")
    metrics = simulate_metrics(tmp_path, scenario, "--duration-s", "20", "--progress", "off")
    assert metrics["collisions"]["count"] == 0
    assert metrics["separation"]["min_m"] > 1.0
    centre_rms = metrics["tracking_steady"]["centroid_m"]["rms"]
    assert 0.0015 < centre_rms < 0.02, centre_rms

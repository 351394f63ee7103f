"""Vehicles that differ (issue 37 item 2, the fleet's part): each vehicle's mass and thrust
coefficient drawn once from the scenario's seed (``[vehicles] mass_spread, thrust_spread``),
flown by the compiled physics with each vehicle's own constants, the autopilots knowing only the
nominal vehicle."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gcs.report.scenario_summary import summary_lines
from protocols.scenario.scenario_file import ScenarioError, load_scenario
from sitl_sim.physics.dynamics import initial_state
from sitl_sim.physics.kernel import PhysicsKernel
from sitl_sim.physics.vehicle_params import VehicleParams, vehicle_scales
from sitl_sim.vehicle.config import vehicle_scales as scenario_scales


def test_the_spread_has_its_statistics_and_is_the_seeds_alone() -> None:
    assert vehicle_scales(100, 0.0, 0.0, 3) == ()
    scales = np.array(vehicle_scales(20_000, 0.05, 0.02, 3))
    assert np.allclose(scales.mean(axis=0), 1.0, atol=0.002)
    assert np.allclose(scales.std(axis=0), (0.05, 0.02), rtol=0.03)
    assert abs(np.corrcoef(scales.T)[0, 1]) < 0.03  # mass and thrust drawn apart
    assert np.all(np.abs(scales - 1.0) <= 3 * np.array([0.05, 0.02]) + 1e-12)  # cut at 3 sigma
    # one vehicle's factors do not depend on how many more are drawn after it (shards)
    assert vehicle_scales(10, 0.05, 0.02, 3) == vehicle_scales(20, 0.05, 0.02, 3)[:10]
    assert vehicle_scales(10, 0.05, 0.02, 3) != vehicle_scales(10, 0.05, 0.02, 4)


def test_each_vehicle_flies_its_own_parameters_in_one_kernel() -> None:
    """Three different vehicles stepped together are, to the last bit, each one stepped alone
    with its own parameters; a fleet of nominal vehicles is the fleet without a spread."""
    base = VehicleParams()
    fleet = [base.scaled(1.1, 0.95), base.scaled(0.9, 1.05), base]
    state = initial_state(np.array([[0.0, 0, -5], [3, 0, -5], [6, 0, -5]]), np.zeros(3))
    euler = np.array([[0.05, -0.02, 0.0], [0.0, 0.03, 0.01], [0.1, 0.2, 0.3]])
    thrust = np.array([0.55, 0.5, 0.45])
    together = PhysicsKernel(base, 3, 0.002, fleet=fleet)
    new, rotor, _ = together.substeps(state, euler, thrust, None, 10)
    for i, params in enumerate(fleet):
        alone = PhysicsKernel(params, 1, 0.002)
        one, one_rotor, _ = alone.substeps(state[:, [i]], euler[:, [i]], thrust[[i]], None, 10)
        assert (
            new[:, [i]].tobytes() == one.tobytes()
            and rotor[:, [i]].tobytes() == one_rotor.tobytes()
        )
    nominal, _, _ = PhysicsKernel(base, 3, 0.002, fleet=[base] * 3).substeps(
        state, euler, thrust, None, 10
    )
    plain, _, _ = PhysicsKernel(base, 3, 0.002).substeps(state, euler, thrust, None, 10)
    assert nominal.tobytes() == plain.tobytes()
    # level, the same demand: the heavier vehicle with weaker rotors climbs least (NED: +z down)
    level, _, _ = together.substeps(state, np.zeros((3, 3)), np.full(3, 0.6), None, 50)
    assert level[2, 0] > level[2, 2] > level[2, 1]


def _scenario(tmp_path: Path, extra: str) -> Path:
    path = tmp_path / "fleet.toml"
    path.write_text(
        "version = 1\nduration_s = 10\nseed = 5\n"
        "[[drones]]\nposition_ned_m = [0, 0, 0]\n"
        "[[drones]]\nposition_ned_m = [2, 0, 0]\n"
        "[[drones]]\nposition_ned_m = [0, 2, 0]\n"
        "[[trajectory.waypoints]]\nt_s = 0\ncentre_ned_m = [0.7, 0.7, -2]\n"
        "spread_m = [1, 1, 0.1]\n" + extra
    )
    return path


def test_the_scenario_says_how_the_vehicles_differ(tmp_path: Path) -> None:
    scenario = load_scenario(_scenario(tmp_path, "[vehicles]\nmass_spread = 0.05\n"))
    assert scenario.vehicles.mass_spread == 0.05 and scenario.vehicles.thrust_spread == 0.0
    assert scenario_scales(scenario) == vehicle_scales(3, 0.05, 0.0, 5)
    (line,) = [x for x in summary_lines(scenario) if x.startswith("vehicles ")]
    assert "mass within 5 % and thrust within 0 %" in line
    alike = load_scenario(_scenario(tmp_path, ""))
    assert scenario_scales(alike) == ()
    assert any(x.startswith("vehicles   all alike") for x in summary_lines(alike))
    for extra, words in (
        ("[vehicles]\nmass_spread = 0.5\n", "vehicles.mass_spread"),
        ("[vehicles]\nthrust_spread = -0.1\n", "vehicles.thrust_spread"),
        ("[vehicles]\nmotor_tau = 0.02\n", "motor_tau"),
    ):
        with pytest.raises(ScenarioError) as err:
            load_scenario(_scenario(tmp_path, extra))
        assert "\n" not in str(err.value) and words in str(err.value), str(err.value)

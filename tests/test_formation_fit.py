"""Whether a formation can hold its drones at the minimum separation
(protocols/model/formation_fit.py), and where that is checked: operator commands and scenario
waypoints."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gcs.station.commands import Request, apply_command
from gcs.station.planner import Envelope, PlanRefused
from protocols.model.descriptors import descriptors
from protocols.model.formation_fit import closest_pair, fit_problem, formation_positions
from protocols.model.trajectory import DescriptorTrajectory, Waypoint
from protocols.scenario.scenario_file import parse_scenario
from protocols.scenario.schema import ScenarioError
from protocols.wire.plan import PlanMessage

GRID = np.array([[x, y, 0.0] for x in (0.0, 2.0, 4.0) for y in (0.0, 2.0, 4.0)])


@pytest.mark.parametrize(
    "target",
    [
        [10.0, 0.0, -5.0, 0.0, 0.0, 0.3, 10.0, 8.0, 0.0],
        [-3.0, 7.0, -2.0, 0.1, -0.2, -1.0, 2.0, 6.0, 0.0],
    ],
)
def test_the_predicted_formation_has_the_commanded_descriptors(target: list[float]) -> None:
    a = np.array(target)
    placed = formation_positions(GRID, a)
    np.testing.assert_allclose(descriptors(placed, a), a, atol=1e-9)


def test_closest_pair_and_the_reason_for_a_tight_formation() -> None:
    assert closest_pair(GRID) == (pytest.approx(2.0), (0, 1))
    tight = np.array([0, 0, -5.0, 0, 0, 0, 0.3, 0.3, 0])  # spreads 0.55 m: 0.67 m apart
    reason = fit_problem(GRID, tight, 1.0)
    assert reason is not None and "cannot hold 9 drones 1 m apart" in reason
    assert "0.67 m apart" in reason
    assert fit_problem(GRID, tight, 0.5) is None
    # a flat swarm stays flat: a commanded height cannot make room
    thick = np.array([0, 0, -5.0, 0, 0, 0, 0.3, 0.3, 50.0])
    assert fit_problem(GRID, thick, 1.0) is not None


def test_operator_formation_and_scale_that_cannot_hold_the_drones_are_refused() -> None:
    hover = np.array([2.0, 2.0, -5.0, 0, 0, 0, 8 / 3, 8 / 3, 0])
    current = PlanMessage(DescriptorTrajectory.from_waypoints([Waypoint(0, hover)]))
    flying = GRID + np.array([0, 0, -5.0])
    env = Envelope()
    tight = Request("formation", {"length_m": 0.6, "width_m": 0.6})
    with pytest.raises(PlanRefused, match="cannot hold 9 drones 1 m apart"):
        apply_command(tight, current, 1.0, env, flying)
    with pytest.raises(PlanRefused, match="make it larger"):
        apply_command(Request("scale", {"factor": 0.3}), current, 1.0, env, flying)
    ok = apply_command(Request("scale", {"factor": 0.7}), current, 1.0, env, flying)  # 1.4 m
    assert ok.seq == 1
    # the scenario's minimum separation is the envelope's
    with pytest.raises(PlanRefused, match=r"1\.5 m apart"):
        apply_command(
            Request("scale", {"factor": 0.7}), current, 1.0, Envelope(min_separation_m=1.5), flying
        )
    # without positions (no telemetry yet) nothing is predicted
    assert apply_command(tight, current, 1.0, env).seq == 1


def _scenario(spread: float, safety: dict[str, float] | None = None) -> dict[str, object]:
    data: dict[str, object] = {
        "version": 1,
        "duration_s": 20.0,
        "drones": [{"position_ned_m": list(p)} for p in GRID],
        "trajectory": {
            "waypoints": [
                {"t_s": 0.0, "centre_ned_m": [2, 2, 0], "spread_m": [1.63, 1.63, 0]},
                {"t_s": 10.0, "centre_ned_m": [2, 2, -5], "spread_m": [spread, spread, 0]},
            ]
        },
    }
    if safety is not None:
        data["safety"] = safety
    return data


def test_a_scenario_waypoint_that_cannot_hold_the_drones_is_a_one_line_error() -> None:
    assert parse_scenario(_scenario(1.5), "ok").safety.min_separation_m == 1.0
    with pytest.raises(ScenarioError) as err:
        parse_scenario(_scenario(0.5), "tight.toml")
    text = str(err.value)
    assert text.startswith("tight.toml: trajectory.waypoints[1]: at t = 10 s a formation")
    assert "cannot hold 9 drones 1 m apart" in text and "\n" not in text
    assert parse_scenario(_scenario(0.5, {"min_separation_m": 0.5}), "ok") is not None
    with pytest.raises(ScenarioError, match=r"safety\.min_separation_m"):
        parse_scenario(_scenario(1.5, {"min_separation_m": -1.0}), "bad")
    assert math.isclose(parse_scenario(_scenario(1.5, {}), "ok").safety.min_separation_m, 1.0)

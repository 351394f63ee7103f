"""Scenario files: the paper's flight, defaults, conversions, and one clear error per mistake."""

from __future__ import annotations

import copy
import importlib.util
import math
import tomllib
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

from protocols.scenario.scenario_file import (
    Crash,
    Delay,
    Dropout,
    GainsConfig,
    GeoPoint,
    LinkCut,
    Loss,
    Partition,
    RatesConfig,
    ScenarioError,
    load_scenario,
    parse_scenario,
)

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "scenarios" / "paper.toml"


def _generator() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "make_paper", ROOT / "scripts/make_paper_scenario.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# --- the paper's flight -----------------------------------------------------------------------


def test_paper_scenario_content() -> None:
    sc = load_scenario(PAPER)
    assert sc.version == 1 and sc.name == "paper"
    assert sc.duration_s == 200.0 and sc.comms.range_m == 10.0 and sc.n_drones == 9
    grid = [(x, y, 0.0) for x in (0.0, 2.0, 4.0) for y in (0.0, 2.0, 4.0)]
    np.testing.assert_array_equal(sc.positions_ned_m(), grid)
    assert sc.faults == (
        LinkCut(3, 4, duration_s=30.0, t_s=17.0),
        LinkCut(0, 1, duration_s=13.0, t_s=17.0),
        Crash(1, t_s=30.0),
        LinkCut(5, 8, duration_s=8.0, t_s=67.0),
        LinkCut(6, 7, one_way=True, duration_s=12.0, t_s=100.0),
    )
    times = [w.t_s for w in sc.waypoints]
    assert times[:3] == [0.0, 0.5, 1.0] and 20.0 in times and times[-1] == 200.0
    assert all(w.rate is not None and w.accel is not None for w in sc.waypoints)
    # ALGORITHM.md §6 defaults.
    assert sc.rates == RatesConfig(500, 50) and sc.gains == GainsConfig()
    assert sc.consensus.rho == 2.0 and sc.consensus.c == 1.0 and sc.consensus.f == 2.0
    assert sc.settle_s == 20.0


def _paper_reference(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ALGORITHM.md §7 written out independently of the generator: value and rate (T, 9)."""
    h = 2.5 * (np.tanh((t - 5) / 2) - np.tanh((t - 300) / 2))
    h_dot = 1.25 * (np.cosh((t - 5) / 2) ** -2 - np.cosh((t - 300) / 2) ** -2)
    w = 2 * np.pi / 200
    zero, one = np.zeros_like(t), np.ones_like(t)
    value = [t + 4, zero, -h, zero, zero, zero, 10 * one, 8 + 4 * np.sin(w * t), zero]
    rate = [one, zero, -h_dot, zero, zero, zero, zero, 4 * w * np.cos(w * t), zero]
    return np.stack(value, axis=1), np.stack(rate, axis=1)


def test_paper_trajectory_matches_the_analytic_reference() -> None:
    traj = load_scenario(PAPER).trajectory()
    assert traj.seq == 0 and traj.start_s == 0.0 and traj.end_s == 200.0
    t = np.linspace(0.0, 200.0, 40_001)
    a, a_dot, _ = traj.evaluate_many(t)
    value, rate = _paper_reference(t)
    assert np.abs(a - value).max() < 1e-3
    assert np.abs(a_dot - rate).max() < 1e-2


def test_paper_file_is_what_the_generator_writes() -> None:
    assert _generator().render() == PAPER.read_text(encoding="utf-8")


# --- a minimal scenario, defaults and conversions ---------------------------------------------


def _base() -> dict[str, Any]:
    return {
        "version": 1,
        "drones": [
            {"position_ned_m": [0.0, 0.0, 0.0]},
            {"position_ned_m": [2.0, 0.0, -1.0], "yaw_deg": 30.0},
            {"position_ned_m": [0.0, 2.0, 0.0]},
        ],
        "trajectory": {
            "waypoints": [
                {"t_s": 0.0, "centre_ned_m": [1.0, 1.0, -2.0], "spread_m": [2.0, 1.0, 0.0]},
                {
                    "t_s": 10.0,
                    "centre_ned_m": [5.0, 1.0, -2.0],
                    "spread_m": [3.0, 1.0, 0.5],
                    "yaw_deg": 90.0,
                    "rate": {"centre_ned_m": [0.5, 0.0, 0.0], "yaw_deg": 9.0},
                },
            ]
        },
    }


def test_minimal_scenario_defaults_and_conversions() -> None:
    sc = parse_scenario(_base(), "scenarios/mini.toml")
    assert sc.name == "mini" and sc.duration_s == 10.0 and sc.seed == 0 and sc.faults == ()
    assert sc.drones[1].yaw_deg == 30.0 and sc.drones[0].yaw_deg == 0.0
    assert sc.gains.kd == tuple(1.8 * math.sqrt(k) for k in sc.gains.kp)
    assert sc.rates.physics_steps_per_control == 10 and sc.rates.dt_control_s == 0.02
    assert sc.vehicle.mass_kg == 0.34 and sc.vehicle.thrust_to_weight == 2.0
    assert sc.consensus.warmup_s == 3.0 and sc.consensus.delay_ticks == 1
    assert sc.waypoints[1].variance_m2 == (9.0, 1.0, 0.25)
    traj = sc.trajectory()
    # the plan is written 2 m up from its start: it climbs there from the ground first, in 4 s
    # (protocols/model/plan_timing.py, from_the_ground), and flies the waypoints 4 s later
    a0, a0_dot, _ = traj.evaluate(0.0)
    np.testing.assert_allclose(a0, [1, 1, 0, 0, 0, 0, 4, 1, 0], atol=1e-12)
    np.testing.assert_allclose(a0_dot, np.zeros(9), atol=1e-12)
    np.testing.assert_allclose(traj.evaluate(4.0)[0], [1, 1, -2, 0, 0, 0, 4, 1, 0], atol=1e-12)
    np.testing.assert_allclose(traj.evaluate(4.0)[1], np.zeros(9), atol=1e-12)
    a, a_dot, _ = traj.evaluate(14.0)
    np.testing.assert_allclose(a, [5, 1, -2, 0, 0, math.pi / 2, 9, 1, 0.25], atol=1e-12)
    np.testing.assert_allclose(a_dot, [0.5, 0, 0, 0, 0, math.radians(9), 0, 0, 0], atol=1e-12)
    # written on the ground from its start, it is flown as written
    data = _base()
    for w in data["trajectory"]["waypoints"]:
        w["centre_ned_m"][2] = 0.0
    ground = parse_scenario(data, "scenarios/mini.toml").trajectory()
    np.testing.assert_allclose(ground.evaluate(10.0)[0][:2], [5, 1], atol=1e-12)


def test_home_default_and_given() -> None:
    assert parse_scenario(_base(), "x.toml").home == GeoPoint(47.397742, 8.545594, 488.0)
    data = _base()
    data["home"] = {"lat_deg": -33.86, "lon_deg": 151.21, "alt_m": 3}
    assert parse_scenario(data, "x.toml").home == GeoPoint(-33.86, 151.21, 3.0)


def test_kd_defaults_follow_a_given_kp() -> None:
    data = _base()
    data["gains"] = {"kp": [4.0] * 9}
    assert parse_scenario(data, "x.toml").gains.kd == (3.6,) * 9


def test_every_fault_kind_parses() -> None:
    data = _base()
    data["duration_s"] = 60.0
    data["faults"] = [
        {"t_s": 1.0, "kind": "dropout", "drone": 2},
        {"t_s": 2.0, "kind": "loss", "probability": 0.1},
        {"t_s": 3.0, "kind": "loss", "probability": 0.5, "drones": [0, 1], "duration_s": 2.0},
        {"t_s": 4.0, "kind": "delay", "delay_ms": 40.0, "duration_s": 5.0},
        {"t_s": 5.0, "kind": "partition", "groups": [[0], [2]], "duration_s": 10.0},
        {"t_s": 60.0, "kind": "link_cut", "drones": [2, 0]},
    ]
    sc = parse_scenario(data, "x.toml")
    assert sc.faults == (
        Dropout(2, t_s=1.0),
        Loss(0.1, t_s=2.0),
        Loss(0.5, (0, 1), 2.0, t_s=3.0),
        Delay(40.0, None, 5.0, t_s=4.0),
        Partition(((0,), (2,)), 10.0, t_s=5.0),
        LinkCut(2, 0, t_s=60.0),
    )
    partition = sc.faults[4]
    assert isinstance(partition, Partition) and partition.group_ids(3) == (0, 2, 1)
    cut, loss = sc.faults[5], sc.faults[2]
    assert isinstance(cut, LinkCut) and cut.link == (2, 0)
    assert isinstance(loss, Loss) and loss.link == (0, 1)
    assert [f.kind for f in sc.faults] == [
        "dropout",
        "loss",
        "loss",
        "delay",
        "partition",
        "link_cut",
    ]


# --- one clear error per mistake --------------------------------------------------------------


def _set(path: str, value: Any) -> Callable[[dict[str, Any]], None]:
    """A mutation setting ``a.b[0].c`` (created as needed) to ``value``; None deletes the key."""

    def mutate(data: dict[str, Any]) -> None:
        node: Any = data
        parts = path.replace("]", "").replace("[", ".").split(".")
        for part in parts[:-1]:
            node = node[int(part)] if part.isdigit() else node.setdefault(part, {})
        last = parts[-1]
        if value is None:
            del node[last]
        elif last.isdigit():
            node[int(last)] = value
        else:
            node[last] = value

    return mutate


def _faults(*faults: dict[str, Any]) -> Callable[[dict[str, Any]], None]:
    return _set("faults", list(faults))


BAD = [
    pytest.param(_set("version", 2), "version: 2 is not supported (supported: 1)", id="version 2"),
    pytest.param(_set("version", None), "version: missing", id="no version"),
    pytest.param(
        _set("version", "1"), "version: must be an integer, got a string '1'", id="version string"
    ),
    pytest.param(
        _set("duraton_s", 5.0), "duraton_s: unknown key (did you mean 'duration_s'?", id="top typo"
    ),
    pytest.param(
        _set("consensus.rhoo", 1.0), "consensus.rhoo: unknown key (did you mean", id="section typo"
    ),
    pytest.param(
        _set("gains.kp", [0.5, 0.5, math.nan, 0, 0, 0, 0, 0, 0]),
        "gains.kp[2]: must be a finite number, got nan",
        id="nan gain",
    ),
    pytest.param(_set("gains.kp", [1.0] * 8), "gains.kp: must have 9 items, got 8", id="short kp"),
    pytest.param(_set("gains.kd", "fast"), "gains.kd: must be an array", id="kd string"),
    pytest.param(_set("gains.max_tilt_deg", 90.0), "gains.max_tilt_deg: must be < 90", id="tilt"),
    pytest.param(
        _set("vehicle.mass_kg", -1.0), "vehicle.mass_kg: must be > 0, got -1.0", id="neg mass"
    ),
    pytest.param(
        _set("vehicle.ixx", math.inf), "vehicle.ixx: must be a finite number", id="inf inertia"
    ),
    pytest.param(
        _set("vehicle.mass_kg", True),
        "vehicle.mass_kg: must be a number, got a boolean",
        id="bool mass",
    ),
    pytest.param(
        _set("vehicle.thrust_to_weight", 0.9),
        "vehicle.thrust_to_weight: must be > 1",
        id="weak vehicle",
    ),
    pytest.param(
        _set("vehicle", 3), "vehicle: must be a table, got an integer", id="vehicle scalar"
    ),
    pytest.param(
        _set("rates", {"physics_hz": 500, "control_hz": 60}),
        "rates.physics_hz: 500 is not an integer multiple of control_hz = 60",
        id="rates",
    ),
    pytest.param(
        _set("rates.control_hz", 50.0), "rates.control_hz: must be an integer", id="float rate"
    ),
    pytest.param(
        _set("consensus.degree_normalised", "yes"),
        "consensus.degree_normalised: must be true or false",
        id="bool flag",
    ),
    pytest.param(
        _set("consensus.delay_ticks", -1),
        "consensus.delay_ticks: must be >= 0",
        id="neg delay ticks",
    ),
    pytest.param(_set("consensus.warmup_s", -0.5), "consensus.warmup_s: must be >= 0", id="warmup"),
    pytest.param(_set("consensus.rho", 0), "consensus.rho: must be > 0, got 0", id="rho"),
    pytest.param(_set("comms.range_m", 0.0), "comms.range_m: must be > 0", id="range"),
    pytest.param(_set("settle_s", -1.0), "settle_s: must be >= 0", id="settle"),
    pytest.param(_set("seed", 1.5), "seed: must be an integer", id="seed"),
    pytest.param(_set("duration_s", 0.0), "duration_s: must be > 0", id="duration"),
    pytest.param(_set("drones", None), "drones: missing", id="no drones"),
    pytest.param(
        _set("drones", [{"position_ned_m": [0.0, 0.0, 0.0]}]),
        "drones: need 2..250 drones (MAVLink system ids 1..250), got 1",
        id="one drone",
    ),
    pytest.param(_set("drones", 3), "drones: must be an array of tables", id="drones scalar"),
    pytest.param(
        _set("drones[1].position_ned_m", [2.0, 0.0, 1.0]),
        "drones[1].position_ned_m: z must be <= 0",
        id="underground",
    ),
    pytest.param(
        _set("drones[0].position_ned_m", [2.0, 0.0]),
        "drones[0].position_ned_m: must have 3 items",
        id="2-d position",
    ),
    pytest.param(
        _set("drones[2].position_ned_m", [0.3, 0.0, 0.0]),
        "drones[2].position_ned_m: 0.3 m from drones[0] (minimum 0.5 m)",
        id="too close",
    ),
    pytest.param(
        _set("drones[0].yaw", 1.0),
        "drones[0].yaw: unknown key (did you mean 'yaw_deg'?",
        id="drone typo",
    ),
    pytest.param(_set("trajectory", None), "trajectory.waypoints: missing", id="no trajectory"),
    pytest.param(
        _set("trajectory.waypoints", []),
        "trajectory.waypoints: needs at least one waypoint",
        id="no waypoints",
    ),
    pytest.param(
        _set("trajectory.waypoints[1].t_s", 0.0),
        "trajectory.waypoints[1].t_s: 0 is not after waypoints[0].t_s = 0",
        id="time order",
    ),
    pytest.param(
        _set("trajectory.waypoints[0].t_s", -1.0),
        "trajectory.waypoints[0].t_s: must be >= 0",
        id="negative time",
    ),
    pytest.param(
        _set("trajectory.waypoints[0].variance_m2", [1.0, 1.0, 0.0]),
        "trajectory.waypoints[0]: give the shape as exactly one of spread_m or variance_m2",
        id="both shapes",
    ),
    pytest.param(
        _set("trajectory.waypoints[0].spread_m", None),
        "trajectory.waypoints[0]: give the shape as exactly one",
        id="no shape",
    ),
    pytest.param(
        _set("trajectory.waypoints[0].spread_m", [1.0, -1.0, 0.0]),
        "trajectory.waypoints[0].spread_m[1]: must be >= 0",
        id="neg spread",
    ),
    pytest.param(
        _set("trajectory.waypoints[0].pitch_deg", 90.0),
        "trajectory.waypoints[0].pitch_deg: must be < 90",
        id="pitch",
    ),
    pytest.param(
        _set("trajectory.waypoints[0].centre_ned", [0, 0, 0]),
        "trajectory.waypoints[0].centre_ned: unknown key (did you mean 'centre_ned_m'?",
        id="centre typo",
    ),
    pytest.param(
        _set("trajectory.waypoints[1].rate.spread_m", [1.0, 0.0, 0.0]),
        "trajectory.waypoints[1].rate.spread_m: not allowed: the descriptor is the variance",
        id="spread rate",
    ),
    pytest.param(
        _set("trajectory.waypoints[1].accel.yaw", 1.0),
        "trajectory.waypoints[1].accel.yaw: unknown key",
        id="accel typo",
    ),
    pytest.param(
        _set("trajectory.waypoints[0].centre_ned_m", [0.0, math.nan, 0.0]),
        "trajectory.waypoints[0].centre_ned_m[1]: must be a finite number",
        id="waypoint nan",
    ),
    pytest.param(
        _faults({"t_s": 1.0, "kind": "crash", "drone": 12}),
        "faults[0].drone: 12 is not a drone index (0..2)",
        id="drone index",
    ),
    pytest.param(
        _faults({"t_s": 1.0, "kind": "dropout", "drone": True}),
        "faults[0].drone: must be an integer, got a boolean",
        id="bool index",
    ),
    pytest.param(
        _faults({"t_s": 1.0, "kind": "explode", "drone": 0}),
        "faults[0].kind: 'explode' is not a fault kind (one of: dropout, crash",
        id="kind",
    ),
    pytest.param(_faults({"t_s": 1.0, "drone": 0}), "faults[0].kind: missing", id="no kind"),
    pytest.param(
        _faults({"t_s": 1.0, "kind": "link_cut", "drones": [1, 1]}),
        "faults[0].drones: a link needs two different drones, got [1, 1]",
        id="self link",
    ),
    pytest.param(
        _faults({"t_s": 1.0, "kind": "link_cut"}), "faults[0].drones: missing", id="link no drones"
    ),
    pytest.param(
        _faults({"t_s": 1.0, "kind": "link_cut", "drones": [0, 3]}),
        "faults[0].drones[1]: 3 is not a drone index (0..2)",
        id="link index",
    ),
    pytest.param(
        _faults({"t_s": 1.0, "kind": "link_cut", "drones": [0, 1], "duration_s": 0.0}),
        "faults[0].duration_s: must be > 0",
        id="link duration",
    ),
    pytest.param(
        _faults({"t_s": 1.0, "kind": "crash", "drone": 0, "duration_s": 2.0}),
        "faults[0].duration_s: unknown key (allowed: drone, kind, t_s)",
        id="crash extra",
    ),
    pytest.param(
        _faults(
            {"t_s": 1.0, "kind": "crash", "drone": 0}, {"t_s": 11.0, "kind": "crash", "drone": 1}
        ),
        "faults[1].t_s: 11 is after the end of the scenario (duration_s = 10)",
        id="late fault",
    ),
    pytest.param(
        _faults({"t_s": 1.0, "kind": "loss", "probability": 1.0}),
        "faults[0].probability: must be < 1",
        id="loss 1",
    ),
    pytest.param(
        _faults({"t_s": 1.0, "kind": "delay", "delay_ms": -5.0}),
        "faults[0].delay_ms: must be >= 0",
        id="delay",
    ),
    pytest.param(
        _faults({"t_s": 1.0, "kind": "partition", "groups": [[0, 1], [0]]}),
        "faults[0].groups[1][0]: drone 0 is already in groups[0]",
        id="partition overlap",
    ),
    pytest.param(
        _faults({"t_s": 1.0, "kind": "partition", "groups": [[0, 5]]}),
        "faults[0].groups[0][1]: 5 is not a drone index (0..2)",
        id="partition index",
    ),
    pytest.param(
        _faults({"t_s": 1.0, "kind": "partition", "groups": [[]]}),
        "faults[0].groups[0]: must be a non-empty array",
        id="partition empty",
    ),
    pytest.param(_set("faults", [3]), "faults[0]: must be a table", id="fault scalar"),
    pytest.param(_set("home.lat_deg", 95.0), "home.lat_deg: must be < 90, got 95.0", id="home lat"),
    pytest.param(
        _set("home.lon_deg", -181), "home.lon_deg: must be >= -180, got -181", id="home lon"
    ),
    pytest.param(_set("home.alt_m", "high"), "home.alt_m: must be a number", id="home alt"),
    pytest.param(_set("home.lat", 1.0), "home.lat: unknown key (did you mean", id="home typo"),
]


@pytest.mark.parametrize(("mutate", "expected"), BAD)
def test_broken_input_names_file_field_and_problem(
    mutate: Callable[[dict[str, Any]], None], expected: str
) -> None:
    data = copy.deepcopy(_base())
    mutate(data)
    with pytest.raises(ScenarioError) as info:
        parse_scenario(data, "scenarios/bad.toml")
    message = str(info.value)
    assert message.startswith("scenarios/bad.toml: "), message
    assert expected in message, message
    assert "\n" not in message


def test_duration_needed_when_the_plan_ends_at_zero() -> None:
    data = _base()
    del data["trajectory"]["waypoints"][1]
    with pytest.raises(ScenarioError, match=r"x.toml: duration_s: missing"):
        parse_scenario(data, "x.toml")
    data["duration_s"] = 5.0
    assert parse_scenario(data, "x.toml").duration_s == 5.0


def test_the_example_message_from_the_spec() -> None:
    text = PAPER.read_text(encoding="utf-8").replace("drone = 1  #", "drone = 12  #")
    with pytest.raises(ScenarioError) as info:
        parse_scenario(tomllib.loads(text), "scenarios/x.toml")
    assert str(info.value) == "scenarios/x.toml: faults[2].drone: 12 is not a drone index (0..8)"


# --- reading files ----------------------------------------------------------------------------


def test_load_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.toml"
    with pytest.raises(ScenarioError, match=r"nope.toml: no such file"):
        load_scenario(path)


def test_load_directory(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match="cannot read"):
        load_scenario(tmp_path)


def test_load_bad_toml_gives_line_and_column(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text("version = 1\nname = \n", encoding="utf-8")
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    message = str(info.value)
    assert message.startswith(f"{path}: invalid TOML: ") and "line 2, column" in message


def test_load_not_utf8(tmp_path: Path) -> None:
    path = tmp_path / "latin.toml"
    path.write_bytes(b'version = 1\nname = "caf\xe9"\n')
    with pytest.raises(ScenarioError, match="not UTF-8"):
        load_scenario(path)


def test_load_nan_from_toml(tmp_path: Path) -> None:
    path = tmp_path / "nan.toml"
    text = PAPER.read_text(encoding="utf-8").replace("range_m = 10.0", "range_m = nan")
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ScenarioError, match=r"nan.toml: comms.range_m: must be a finite number"):
        load_scenario(path)


def test_load_round_trip_from_a_written_file(tmp_path: Path) -> None:
    path = tmp_path / "paper_copy.toml"
    _generator().main([str(path)])
    sc = load_scenario(path)
    assert sc.source == str(path) and sc.n_drones == 9 and len(sc.faults) == 5


def test_a_scenario_holds_as_many_drones_as_mavlink_numbers_vehicles(tmp_path: Path) -> None:
    """A scenario's drones are MAVLink vehicles (system ids 1..250) and rows of the agents'
    neighbour tables: 251 are refused in one line saying why, before anything flies."""
    from protocols.mavlink.conventions import MAX_VEHICLES
    from protocols.scenario.generator import MAX_DRONES as GENERATED
    from protocols.scenario.scenario_file import MAX_DRONES
    from protocols.wire.keys import MAX_SWARM

    assert MAX_DRONES == GENERATED == MAX_VEHICLES == MAX_SWARM == 250
    drones = "".join(
        f"[[drones]]\nposition_ned_m = [{2.0 * (k // 16)}, {2.0 * (k % 16)}, 0.0]\n"
        for k in range(251)
    )
    path = tmp_path / "big.toml"
    path.write_text(
        'version = 1\nname = "big"\nduration_s = 5.0\n\n' + drones
        + "[[trajectory.waypoints]]\nt_s = 0.0\ncentre_ned_m = [15.0, 15.0, -3.0]\n"
        "spread_m = [9.0, 9.0, 0.0]\n"
    )  # fmt: skip
    with pytest.raises(ScenarioError, match=r"need 2\.\.250 drones \(MAVLink system ids"):
        load_scenario(path)

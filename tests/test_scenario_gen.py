"""The scenario generator (protocols/scenario/generator.py, protocols/scenario/layout.py) and the
library it writes: layouts keep their spacing and are connected, every template x layout
validates and round-trips through the loader, formations keep the minimum separation, the plan
stays in the envelope, faults land inside the flight on drones whose loss leaves the graph whole,
and scenarios/ is what the generator makes now."""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import tomllib
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gcs.report.scenario_summary import closest_in_formation, envelope_problem
from protocols.faults import Crash, Dropout, Loss
from protocols.scenario.generator import (
    TEMPLATES,
    FaultRequest,
    GeneratorError,
    GeneratorOptions,
    generate,
    parse_faults,
)
from protocols.scenario.layout import (
    LAYOUTS,
    is_cut_free,
    layout_positions,
    min_spacing,
    radio_graph,
)
from protocols.scenario.scenario_file import load_scenario, parse_scenario

ROOT = Path(__file__).resolve().parents[1]
ALL_FAULTS = FaultRequest(dropouts=1, crashes=1, loss=0.2)


# --- layouts -----------------------------------------------------------------------------------


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("n", [2, 3, 7, 16, 25, 60])
@pytest.mark.parametrize("spacing", [1.0, 2.5])
def test_layouts_keep_the_spacing_on_the_ground(layout: str, n: int, spacing: float) -> None:
    x = layout_positions(layout, n, spacing, np.random.default_rng(3))
    assert x.shape == (n, 3)
    assert np.all(x[:, 2] == 0.0)
    assert np.allclose(x[:, :2].min(axis=0), 0.0)  # the bounding box starts at the origin
    assert min_spacing(x) >= spacing - 1e-6
    var = x[:, :2].var(axis=0)
    assert var[0] >= var[1] * (1 - 1e-6)  # the larger spread along north: yaw 0 is the layout


@pytest.mark.parametrize("n", [2, 4, 9, 10, 16, 25, 99, 100, 250])
def test_a_grid_is_connected_when_the_range_reaches_the_diagonal(n: int) -> None:
    x = layout_positions("grid", n, 2.5, np.random.default_rng(0))
    graph = radio_graph(x, 2.5 * math.sqrt(2.0))
    assert graph.connected
    # links are strictly shorter than the range: at exactly the spacing nobody hears anybody
    assert radio_graph(x, 2.5).components == n


def test_a_grid_of_25_at_6_m_range_has_the_expected_degrees() -> None:
    # 5 x 5, 2.5 m apart, 6 m range: corners hear 7, the middle 20 (all but the far corners)
    graph = radio_graph(layout_positions("grid", 25, 2.5, np.random.default_rng(0)), 6.0)
    assert (graph.degree_min, graph.degree_max) == (7, 20)


def test_a_ring_has_neighbours_one_spacing_apart() -> None:
    x = layout_positions("circle", 12, 2.5, np.random.default_rng(0))
    centre = x.mean(axis=0)
    radius = np.linalg.norm(x - centre, axis=1)
    assert np.allclose(radius, radius[0])
    assert np.isclose(np.linalg.norm(x[1] - x[0]), 2.5)


@settings(max_examples=30, deadline=None)
@given(
    n=st.integers(2, 60),
    spacing=st.floats(0.5, 4.0),
    reach=st.floats(1.05, 2.0),
    seed=st.integers(0, 2**31),
)
def test_random_layouts_are_spaced_connected_and_seeded(
    n: int, spacing: float, reach: float, seed: int
) -> None:
    range_m = reach * spacing
    x = layout_positions("random", n, spacing, np.random.default_rng(seed), reach_m=range_m)
    assert min_spacing(x) >= spacing * (1 - 1e-6)
    # built within reach of a placed drone: connected at any range above that reach
    assert radio_graph(x, range_m * (1 + 1e-6) + 1e-6).connected
    again = layout_positions("random", n, spacing, np.random.default_rng(seed), reach_m=range_m)
    np.testing.assert_array_equal(x, again)


def test_cut_vertices_are_recognised() -> None:
    x = layout_positions("grid", 9, 1.0, np.random.default_rng(0))
    x[:, 1] = 0.0
    x[:, 0] = np.arange(9.0)  # a path 0-1-...-8
    adjacency = radio_graph(x, 1.5).adjacency
    assert is_cut_free(adjacency, {0}) and is_cut_free(adjacency, {8})
    assert not is_cut_free(adjacency, {4})


# --- generated scenarios -----------------------------------------------------------------------


@pytest.mark.parametrize("template", TEMPLATES)
@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("n", [5, 16])
def test_every_template_and_layout_validates_and_round_trips(
    template: str, layout: str, n: int, tmp_path: Path
) -> None:
    options = GeneratorOptions(n, layout, template=template, faults=ALL_FAULTS, seed=7)
    g = generate(options, "x.toml")
    path = tmp_path / "x.toml"
    path.write_text(g.text)
    loaded = load_scenario(path)
    assert dataclasses.replace(loaded, source="x.toml") == g.scenario
    assert g.scenario.n_drones == n
    np.testing.assert_allclose(loaded.positions_ned_m(), g.positions_ned_m, atol=1e-6)
    # the formations of the plan keep the minimum separation, the plan stays in the envelope
    closest, _ = closest_in_formation(loaded)
    assert closest >= loaded.safety.min_separation_m
    assert envelope_problem(loaded) is None
    # it takes off: on the ground at t = 0, at altitude after the climb, never below the ground
    a = loaded.trajectory().evaluate_many(np.linspace(0.0, loaded.duration_s, 200))[0]
    assert a[0, 2] == 0.0 and np.all(a[:, 2] <= 1e-9)
    assert -a[:, 2].min() >= 2.9


def test_the_text_is_commented_and_carries_the_command_line() -> None:
    options = GeneratorOptions(16, "grid", faults=ALL_FAULTS, seed=4, name="g16")
    text = generate(options, "scenarios/g16.toml").text
    assert text.splitlines()[2] == (
        "#   swarm scenario new --drones 16 --layout grid --spacing-m 2.5 --range-m 6 "
        "--template turn-and-stretch --faults dropout=1,crash=1,loss=0.2 --name g16 --seed 4 "
        "-o scenarios/g16.toml"
    )
    for section in ("[comms]", "[safety]", "[consensus]", "[[drones]]", "[[trajectory.waypoints]]"):
        before = text[: text.index(section)].rstrip().splitlines()[-1]
        assert before.startswith("#") or section.startswith("[["), section
    assert text.count("# t = ") >= 4  # each waypoint of the plan says what it is for


def test_turn_and_stretch_is_issue_10s_flight() -> None:
    g = generate(GeneratorOptions(25, "grid", faults=ALL_FAULTS), None)
    w = g.scenario.waypoints
    first, last = w[2], w[-1]  # after the climb, and the end
    assert first.centre_ned_m[2] == -3.0
    assert math.isclose(last.centre_ned_m[0] - first.centre_ned_m[0], 20.0)
    assert last.yaw_deg == 30.0
    assert math.isclose(math.sqrt(last.variance_m2[0] / first.variance_m2[0]), 1.15, rel_tol=1e-6)
    assert last.variance_m2[1:] == first.variance_m2[1:]


def test_faults_fall_inside_the_flight_on_drones_that_do_not_cut_the_graph() -> None:
    request = FaultRequest(dropouts=3, crashes=2, loss=0.3)
    g = generate(GeneratorOptions(25, "random", faults=request, seed=11), None)
    sc = g.scenario
    lost = [f.drone for f in sc.faults if isinstance(f, Dropout | Crash)]
    assert len(lost) == 5 and len(set(lost)) == 5
    assert is_cut_free(radio_graph(g.positions_ned_m, sc.comms.range_m).adjacency, set(lost))
    airborne_s = sc.waypoints[2].t_s
    assert all(airborne_s < f.t_s < sc.duration_s for f in sc.faults if not isinstance(
        f, Loss))  # fmt: skip
    (loss,) = [f for f in sc.faults if isinstance(f, Loss)]
    assert loss.probability == 0.3 and loss.link is None and loss.duration_s is None
    assert [f.t_s for f in sc.faults] == sorted(f.t_s for f in sc.faults)


def test_one_seed_one_scenario() -> None:
    a = generate(GeneratorOptions(30, "random", faults=ALL_FAULTS, seed=5), None).text
    b = generate(GeneratorOptions(30, "random", faults=ALL_FAULTS, seed=5), None).text
    c = generate(GeneratorOptions(30, "random", faults=ALL_FAULTS, seed=6), None).text
    assert a == b and a != c


def test_every_swarm_keeps_the_default_consensus_and_large_ones_rest_longer() -> None:
    small = generate(GeneratorOptions(9, "grid", spacing_m=2.0, range_m=10.0), None).scenario
    assert not small.consensus.degree_normalised and small.consensus.rho == 2.0
    assert small.consensus.warmup_s == 3.0
    large = generate(GeneratorOptions(100, "grid", range_m=6.0), None).scenario
    assert not large.consensus.degree_normalised and large.consensus.rho == 2.0
    assert large.consensus.warmup_s == 6.0


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("", FaultRequest()),
        ("none", FaultRequest()),
        ("dropout,crash,loss", FaultRequest(1, 1, 0.2)),
        ("dropouts=2, crashes=3, loss=0.35", FaultRequest(2, 3, 0.35)),
        ("dropout,dropout", FaultRequest(2, 0, 0.0)),
    ],
)
def test_fault_lists(text: str, expected: FaultRequest) -> None:
    assert parse_faults(text) == expected


@pytest.mark.parametrize("text", ["meteor", "loss=1.5", "crash=1.5", "dropout=x", "loss=0"])
def test_bad_fault_lists_name_the_option(text: str) -> None:
    with pytest.raises(GeneratorError, match=r"^faults: "):
        parse_faults(text)


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"drones": 1}, "drones"),
        ({"drones": 251}, "drones"),
        ({"range_m": 2.0}, "range_m"),  # grid 2.5 m apart: nobody hears anybody
        ({"spacing_m": 0.8}, "spacing_m"),  # below the 1 m minimum separation
        ({"spacing_m": -1.0}, "spacing_m"),
        ({"duration_s": 20.0}, "duration_s"),  # turn-and-stretch needs 41 s
        ({"altitude_m": 0.2}, "altitude_m"),
        ({"faults": FaultRequest(dropouts=9)}, "faults"),
        ({"layout": "spiral"}, "layout"),
        ({"template": "loop"}, "template"),
    ],
)
def test_options_that_cannot_be_met_name_the_option(changes: dict[str, object], field: str) -> None:
    options = dataclasses.replace(GeneratorOptions(9, "grid"), **changes)  # type: ignore[arg-type]
    with pytest.raises(GeneratorError, match=rf"^{field}: "):
        generate(options, None)


def test_a_formation_too_tight_for_the_separation_is_refused() -> None:
    # a ring 1.2 m apart, 1 m minimum: the 10 % length stretch is fine, but the paper template's
    # breathing width (variance -30 %) brings neighbours closer than 1 m
    options = GeneratorOptions(12, "circle", spacing_m=1.05, template="paper", range_m=3.0)
    with pytest.raises(GeneratorError, match="cannot hold 12 drones 1 m apart"):
        generate(options, None)


# --- the library -------------------------------------------------------------------------------


def _library() -> ModuleType:
    path = ROOT / "scripts" / "make_scenarios.py"
    spec = importlib.util.spec_from_file_location("make_scenarios", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_library_is_what_the_generator_makes() -> None:
    assert _library().main(["--check"]) == 0, "run make scenarios"


@pytest.mark.parametrize("name", sorted(p.name for p in (ROOT / "scenarios").glob("*.toml")))
def test_every_library_scenario_validates_inside_the_envelope(name: str) -> None:
    sc = load_scenario(ROOT / "scenarios" / name)
    assert envelope_problem(sc) is None
    assert radio_graph(sc.positions_ned_m(), sc.comms.range_m).connected
    assert closest_in_formation(sc)[0] >= sc.safety.min_separation_m


@pytest.mark.parametrize("n", [25, 100, 250])
def test_the_large_grids_are_issue_10s(n: int) -> None:
    sc = load_scenario(ROOT / "scenarios" / f"large_grid{n}.toml")
    assert sc.n_drones == n and sc.comms.range_m == 6.0
    assert math.isclose(min_spacing(sc.positions_ned_m()), 2.5)
    kinds = sorted(f.kind for f in sc.faults)
    assert kinds == ["crash", "dropout", "loss"]
    assert [f.probability for f in sc.faults if isinstance(f, Loss)] == [0.2]
    assert sc.waypoints[-1].yaw_deg == 30.0
    header = (ROOT / "scenarios" / f"large_grid{n}.toml").read_text().splitlines()[2]
    assert f"swarm scenario new --drones {n} --layout grid" in header


def test_a_toml_round_trip_of_the_parsed_data_is_exact() -> None:
    g = generate(GeneratorOptions(16, "circle", template="survey", faults=ALL_FAULTS), "s")
    again = parse_scenario(tomllib.loads(g.text), "s")
    assert again == g.scenario


# --- outdoors ----------------------------------------------------------------------------------


@pytest.mark.parametrize("receiver", ["rtk", "gnss"])
def test_outdoors_writes_the_documented_air_vehicles_sensors_and_radio(receiver: str) -> None:
    """``--outdoor`` writes protocols/scenario/outdoor.py's values (docs/scenarios.md cites them);
    without a wind of its own the scenario gets the light breeze; the header's command makes it
    again."""
    from protocols.scenario import outdoor

    options = GeneratorOptions(
        9, "grid", outdoor=receiver, wind_m_s=outdoor.BREEZE_M_S, turbulence_m_s=0.5
    )
    generated = generate(options, None)
    s = generated.scenario
    assert f"--outdoor {receiver}" in generated.text.splitlines()[2]
    assert dataclasses.asdict(s.vehicles) == outdoor.VEHICLES
    assert s.vehicle.motor_tau_s == outdoor.VEHICLE["motor_tau_s"] > 0
    sensors = dataclasses.asdict(s.sensors)
    assert {k: sensors[k] for k in outdoor.SENSORS[receiver]} == outdoor.SENSORS[receiver]
    radio = dataclasses.asdict(s.radio)
    assert {k: radio[k] for k in outdoor.RADIO} == outdoor.RADIO
    assert s.environment.wind_ned_m_s == (0.0, 3.0, 0.0) and s.vehicle.drag_xy_per_s > 0
    assert s.sensors.lie and not s.radio.ideal
    # scenario check sums them up, and warns where the GNSS bias is large against the spacing
    from gcs.report.scenario_summary import summary_lines

    lines = "\n".join(summary_lines(s))
    assert "sensors    GNSS bias" in lines and "radio link 100 kB/s a link" in lines
    assert ("WARNING: a GNSS bias of 2 m" in lines) is (receiver == "gnss"), lines
    wide = generate(dataclasses.replace(options, spacing_m=9.0, range_m=20.0), None).scenario
    assert "WARNING: a GNSS bias" not in "\n".join(summary_lines(wide))
    with pytest.raises(GeneratorError, match=r"^outdoor: "):
        generate(dataclasses.replace(options, outdoor="mocap"), None)


def test_a_newcomers_outdoor_swarm_flies_on_rtk(tmp_path: Path) -> None:
    """The plain commands: ``swarm scenario new --drones 9 --outdoor rtk -o o.toml`` then
    ``swarm simulate o.toml``: the swarm leaves the ground at the end of its warm-up (the
    plateau rule: its estimates never agree to 2 %), holds together in the breeze (no
    collision, the drones at least the scenario's 1 m apart in truth, ODOMETRY in flight.tlog),
    the estimates within 10 cm of the true descriptors, while the radio dropped and delayed
    messages (fewer delivered than sent in range)."""
    import json

    from sitl_client import run_swarm, simulate_metrics

    from gcs.report.tlog import vehicle_samples

    run_swarm(tmp_path, "scenario", "new", "--drones", "9", "--outdoor", "rtk", "-o", "o.toml")
    metrics = simulate_metrics(tmp_path, "o.toml")
    assert metrics["collisions"]["count"] == 0
    assert metrics["separation"]["min_m"] > 1.0
    assert metrics["consensus_steady"]["centroid_m"]["rms"] < 0.1
    messages = metrics["messages"]
    radio = messages["radio_lost"]
    assert radio["burst"] > 0.005 * messages["sent"] and messages["lost"] >= sum(radio.values())
    events = [json.loads(line) for line in (tmp_path / "r" / "events.jsonl").open()]
    (takeoff,) = [e for e in events if e["kind"] == "takeoff"]
    warmup_s = load_scenario(tmp_path / "o.toml").consensus.warmup_s
    assert takeoff["t_s"] <= warmup_s + 1.0, takeoff
    heights = {}
    for (msg, sysid, t_ms), v in vehicle_samples(tmp_path / "r" / "flight.tlog").items():
        if msg == "ODOMETRY" and t_ms > 15_000:
            heights.setdefault(sysid, []).append(-v[2])
    assert len(heights) == 9 and all(min(h) > 1.5 for h in heights.values()), {
        k: min(h) for k, h in heights.items()
    }

"""The formation controller's plug-in point (drone_agent/core/controller.py, controller_load.py):
``[agent] controller`` in a scenario, each mistake in naming one a one-line error naming the
file and the field (at load, before anything flies), and a controller that fails in flight
(raises, gives NaN or the wrong shape) leaves its drones without a setpoint, counted and said,
while the others of the batch fly on."""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import textwrap
from pathlib import Path

import numpy as np
import pytest

from drone_agent.core.agent_core import AgentOutput, BatchAgentCore
from drone_agent.core.config import agent_config
from drone_agent.core.controller import CooperativeController
from drone_agent.core.flight_phase import FlightPhase, Request, VehicleView
from gcs.cli.main import main
from protocols.scenario.scenario_file import ScenarioError, load_scenario
from protocols.wire.plan import FlightCommand
from protocols.wire.status import AgentMode

SCENARIO = """\
version = 1
duration_s = 10.0
[[drones]]
position_ned_m = [0.0, 0.0, 0.0]
[[drones]]
position_ned_m = [0.0, 2.5, 0.0]
[[drones]]
position_ned_m = [2.5, 0.0, 0.0]
[[trajectory.waypoints]]
t_s = 0.0
centre_ned_m = [0.8, 0.8, -2.0]
spread_m = [1.5, 1.2, 0.0]
"""

MODULE = """\
import numpy as np
from drone_agent.core.controller import Controller


class Hover(Controller):
    '''Holds each drone where it is: a controller that works and ignores the formation.'''

    def acceleration(self, inputs):
        return -1.0 * inputs.velocity_ned_m_s


class Raising(Controller):
    def acceleration(self, inputs):
        raise ZeroDivisionError("gain over zero")


class NotFinite(Controller):
    def acceleration(self, inputs):
        out = np.zeros((len(inputs.agent_ids), 3))
        out[0] = np.nan
        return out


class WrongShape(Controller):
    def acceleration(self, inputs):
        return np.zeros(3)


class BadThrust(Controller):
    def thrust_attitude(self, accel, inputs):
        k = len(inputs.agent_ids)
        return np.zeros(k), np.zeros(k), np.zeros(k), np.full(k, 1e3), np.zeros(k, dtype=bool)

    def acceleration(self, inputs):
        return np.zeros((len(inputs.agent_ids), 3))


class NoAcceleration(Controller):
    pass


class NotOne:
    def acceleration(self, inputs):
        return np.zeros((len(inputs.agent_ids), 3))


class BuildFails(Controller):
    def __init__(self, setup):
        raise KeyError("kp")

    def acceleration(self, inputs):
        return np.zeros((len(inputs.agent_ids), 3))


class Switchable(Controller):
    '''Fails while ``fail`` is set: a controller that breaks in flight.'''

    fail = None

    def acceleration(self, inputs):
        out = np.zeros((len(inputs.agent_ids), 3))
        if Switchable.fail == "raise":
            raise RuntimeError("lost the plot")
        if Switchable.fail == "nan":
            out[:] = np.nan
        if Switchable.fail == "shape":
            return out[:, :2]
        return out


class NanForOne(Controller):
    '''Holds each drone, but drone 1's command is NaN once in flight.'''

    def acceleration(self, inputs):
        out = -1.0 * inputs.velocity_ned_m_s
        if inputs.t_s > 0:
            out[np.array(inputs.agent_ids) == 1] = np.nan
        return out


NOT_A_CLASS = 3
"""


def _scenario(tmp_path: Path, agent: str, module: str = MODULE, name: str = "ctl.toml") -> Path:
    (tmp_path / "my_controllers.py").write_text(module)
    path = tmp_path / name
    path.write_text(SCENARIO + textwrap.dedent(agent))
    return path


def _error(path: Path) -> str:
    with pytest.raises(ScenarioError) as info:
        agent_config(load_scenario(path))
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"{path}: agent.controller: "), message
    return message


def test_no_agent_section_flies_the_papers_controller(tmp_path: Path) -> None:
    config = agent_config(load_scenario(_scenario(tmp_path, "")))
    assert config.controller is CooperativeController
    assert config.controller_options == ()


def test_a_controller_beside_the_scenario_is_found_with_its_options(tmp_path: Path) -> None:
    path = _scenario(
        tmp_path,
        """
        [agent]
        controller = "my_controllers:Hover"
        options = { kp = 2.0, name = "x" }
        """,
    )
    config = agent_config(load_scenario(path))
    assert config.controller.__name__ == "Hover"
    core = BatchAgentCore(range(3), config)
    assert dict(core.controller.setup.options) == {"kp": 2.0, "name": "x"}  # type: ignore[attr-defined]


def test_path_is_relative_to_the_scenario_file(tmp_path: Path) -> None:
    (tmp_path / "lib").mkdir()
    (tmp_path / "lib" / "ctl_in_lib.py").write_text(MODULE)
    path = tmp_path / "s.toml"
    path.write_text(SCENARIO + '[agent]\ncontroller = "ctl_in_lib:Hover"\npath = ["lib"]\n')
    assert agent_config(load_scenario(path)).controller.__name__ == "Hover"


@pytest.mark.parametrize(
    ("agent", "says"),
    [
        (
            'controller = "no_such_module_here:X"',
            "no module named 'no_such_module_here' (looked in",
        ),
        ('controller = "my_controllers:Missing"', "my_controllers.py has no 'Missing'"),
        ('controller = "my_controllers:NOT_A_CLASS"', "is a int, not a class"),
        ('controller = "my_controllers:NotOne"', "no method thrust_attitude"),
        ('controller = "my_controllers:NoAcceleration"', "no method acceleration"),
        ('controller = "my_controllers:BuildFails"', "building it raised KeyError: 'kp'"),
        (
            'controller = "my_controllers:Raising"',
            "on the scenario's start, acceleration raised ZeroDivisionError: gain over zero",
        ),
        ('controller = "my_controllers:NotFinite"', "acceleration not finite for drones [0]"),
        ('controller = "my_controllers:WrongShape"', "acceleration gave shape (3,), not (3, 3)"),
        ('controller = "my_controllers:BadThrust"', "gave a thrust of 1e+03 N, outside 0..6.67 N"),
    ],
)
def test_each_mistake_is_one_line_naming_the_field(tmp_path: Path, agent: str, says: str) -> None:
    name = f"ctl_{abs(hash(agent))}"  # a module name of its own: imports are cached
    path = _scenario(tmp_path, "[agent]\n" + agent.replace("my_controllers", name))
    (tmp_path / f"{name}.py").write_text(MODULE)
    assert says.replace("my_controllers", name) in _error(path)


def test_a_module_that_fails_to_import_says_why(tmp_path: Path) -> None:
    path = _scenario(tmp_path, '[agent]\ncontroller = "broken_ctl:X"\n')
    (tmp_path / "broken_ctl.py").write_text("import numpy\nimport not_installed_pkg_xyz\n")
    assert "importing broken_ctl raised ModuleNotFoundError: No module named" in _error(path)
    path.write_text(SCENARIO + '[agent]\ncontroller = "broken_syntax_ctl:X"\n')
    (tmp_path / "broken_syntax_ctl.py").write_text("def (:\n")
    assert "importing broken_syntax_ctl raised SyntaxError" in _error(path)


@pytest.mark.parametrize(
    ("agent", "says"),
    [
        ('controller = "pd controller"', "agent.controller: 'pd controller' is not a controller"),
        ('controller = "x:Y"\npath = [1]', "agent.path[0]: must be a non-empty string"),
        ('controler = "x:Y"', "agent.controler: unknown key (did you mean 'controller'?"),
    ],
)
def test_the_section_is_checked_at_load(tmp_path: Path, agent: str, says: str) -> None:
    path = _scenario(tmp_path, "[agent]\n" + agent)
    with pytest.raises(ScenarioError, match=None) as info:
        load_scenario(path)
    assert says in str(info.value)


def test_check_simulate_up_and_agent_say_it_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _scenario(tmp_path, '[agent]\ncontroller = "my_controllers:Missing"\n')
    for argv in (
        ["scenario", "check", str(path)],
        ["simulate", str(path), "--no-plots", "--no-recording", "--report", str(tmp_path / "sim")],
        ["up", str(path), "--report", str(tmp_path / "up")],  # before any process starts
        ["agent", "--scenario", str(path), "--drone-id", "0"],
    ):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "agent.controller:" in err and "has no 'Missing'" in err


class _Flying:
    """Three agents of a scenario in the air, ticked by hand."""

    def __init__(self, path: Path) -> None:
        self.scenario = load_scenario(path)
        self.core = BatchAgentCore(range(3), agent_config(self.scenario))
        self.x = np.add(self.scenario.positions_ned_m(), [0.0, 0.0, -2.0])

    def tick(self, round_: int, v: np.ndarray | None = None) -> list[AgentOutput]:
        plans = [self.scenario.trajectory()] * 3
        v = np.zeros((3, 3)) if v is None else v
        t_s = 4.0 + round_ * 0.02  # after the warm-up
        return self.core.tick([0, 1, 2], round_, t_s, self.x, v, plans, [[]] * 3, [None] * 3)


@pytest.mark.parametrize(
    ("fail", "says"),
    [
        ("raise", "acceleration raised RuntimeError: lost the plot"),
        ("nan", "acceleration not finite for drones [0, 1, 2]"),
        ("shape", "acceleration gave shape (3, 2), not (3, 3)"),
    ],
)
def test_a_controller_failing_in_flight_gives_no_setpoint(
    tmp_path: Path, fail: str, says: str
) -> None:
    import my_controllers  # type: ignore[import-not-found]

    flying = _Flying(_scenario(tmp_path, '[agent]\ncontroller = "my_controllers:Switchable"\n'))
    core = flying.core
    try:
        assert all(out.setpoint is not None for out in flying.tick(0))
        my_controllers.Switchable.fail = fail
        outs = flying.tick(1)
        assert [out.setpoint for out in outs] == [None, None, None]
        assert core.rejected_setpoints == [1, 1, 1]
        assert core.controller_failures == 1
        assert core.controller_error == f"controller my_controllers:Switchable: {says}"
        my_controllers.Switchable.fail = None
        assert all(out.setpoint is not None for out in flying.tick(2))
    finally:
        my_controllers.Switchable.fail = None


def test_one_bad_row_leaves_the_others_flying(tmp_path: Path) -> None:
    flying = _Flying(_scenario(tmp_path, '[agent]\ncontroller = "my_controllers:NanForOne"\n'))
    core = flying.core
    outs = flying.tick(0)
    assert [out.setpoint is None for out in outs] == [False, True, False]
    assert core.rejected_setpoints == [0, 1, 0]
    said = "controller my_controllers:NanForOne: acceleration not finite for drones [1]"
    assert core.controller_error == said
    hover = outs[0].setpoint
    assert hover is not None and math.isclose(hover.roll_rad, 0.0, abs_tol=1e-12)


def test_a_drone_without_a_setpoint_in_the_air_holds() -> None:
    """What the flight-phase rules do with a refused command: the autopilot's HOLD mode, at the
    hover thrust (never less than the minimum), and back to the formation when it answers."""
    path_limits = agent_config(load_scenario(Path("scenarios/paper.toml"))).limits
    phase = FlightPhase(path_limits)
    flying = VehicleView(armed=True, in_offboard=True, in_land=False, in_hold=False, altitude_m=3.0)
    order = phase.decide(FlightCommand.FLY, True, True, None, 3.0, flying, 0.0)
    assert (order.mode, order.request) == (AgentMode.HOLDING, Request.HOLD_MODE)
    assert order.setpoint.thrust_normalised >= phase.min_thrust_normalised


def test_the_example_scenario_is_the_papers_flight_flown_by_the_pd_example() -> None:
    root = Path(__file__).resolve().parents[1]
    spec = importlib.util.spec_from_file_location(
        "make_paper", root / "scripts/make_paper_scenario.py"
    )
    assert spec is not None and spec.loader is not None
    make_paper = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(make_paper)
    example = root / "examples" / "pd_paper.toml"
    assert example.read_text() == make_paper.render("pd_controller:PDFormation")
    assert (root / "scenarios" / "paper.toml").read_text() == make_paper.render()
    pd, paper = load_scenario(example), load_scenario(root / "scenarios" / "paper.toml")
    assert dataclasses.replace(pd, source=paper.source, name=paper.name, agent=paper.agent) == paper
    assert agent_config(pd).controller.__name__ == "PDFormation"

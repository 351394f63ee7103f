"""Finding the controller a scenario names (``[agent] controller = "package.module:Name"``) and
trying it once before anything flies: the edge between a scenario file and user code.

The module is looked for in the scenario's ``[agent] path`` folders (relative to the scenario
file; default its own folder), then on ``sys.path``. Every process that loads the scenario (``swarm
simulate``, ``swarm scenario check``, each ``swarm up`` agent process) finds the same module
whatever its working folder. Each mistake is a :class:`ControllerError` (a ScenarioError) of one
line naming the file and the field: no such module, no such name, not a class, not implementing
the interface (drone_agent/core/controller.py), raising while built, or failing a first call on the
scenario's start (every drone where it starts, the true descriptors, the plan at t = 0).
"""

from __future__ import annotations

import difflib
import importlib
import sys
from pathlib import Path

import numpy as np

from drone_agent.core.controller import (
    Controller,
    ControllerInputs,
    ControllerSetup,
    CooperativeController,
    FormationController,
    call_acceleration,
    call_thrust_attitude,
    raised,
)
from drone_agent.core.moments import SwarmMoments
from protocols.model.descriptors import align_axes_batch, desired_axes_batch
from protocols.scenario.scenario_file import Scenario, ScenarioError

ControllerClass = type[FormationController]
METHODS = ("acceleration", "thrust_attitude")


class ControllerError(ScenarioError):
    """A scenario's ``[agent] controller`` cannot fly; the message is one line."""


def controller_class(scenario: Scenario) -> ControllerClass:
    """The class ``[agent] controller`` names (the paper's :class:`CooperativeController`
    when it names none), imported and checked against the interface."""
    ref = scenario.agent.controller
    if ref is None:
        return CooperativeController
    where = f"{scenario.source}: agent.controller"
    module_name, _, name = ref.partition(":")
    folders = _search_path(scenario)
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name is not None and (module_name + ".").startswith(exc.name + "."):
            looked = ", ".join(str(f) for f in folders)
            raise ControllerError(
                f"{where}: no module named {exc.name!r} (looked in {looked}, then sys.path)"
            ) from None
        raise ControllerError(f"{where}: importing {module_name} {raised(exc)}") from None
    except Exception as exc:  # a user's module: say what it raised, on one line
        raise ControllerError(f"{where}: importing {module_name} {raised(exc)}") from None
    cls = getattr(module, name, None)
    origin = getattr(module, "__file__", None) or module_name
    if cls is None:
        close = difflib.get_close_matches(name, [n for n in dir(module) if not n.startswith("_")])
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ControllerError(f"{where}: {origin} has no {name!r}{hint}")
    if not isinstance(cls, type):
        raise ControllerError(f"{where}: {ref} is a {type(cls).__name__}, not a class")
    missing = [m for m in METHODS if not callable(getattr(cls, m, None))]
    if getattr(cls, "acceleration", None) is Controller.acceleration:
        missing.insert(0, "acceleration")
    if missing:
        raise ControllerError(
            f"{where}: {ref} does not implement the controller interface: no method "
            f"{' or '.join(missing)} (see docs/controllers.md)"
        )
    return cls


def check_controller(
    scenario: Scenario, cls: ControllerClass, setup: ControllerSetup
) -> FormationController:
    """A controller of ``cls`` built with ``setup`` and called once on the scenario's start
    (module doc); raises :class:`ControllerError` saying what failed."""
    where = f"{scenario.source}: agent.controller: {scenario.agent.controller}"
    try:
        controller = cls(setup)  # type: ignore[call-arg]
    except Exception as exc:  # a user's class: say what it raised, on one line
        raise ControllerError(f"{where}: building it {raised(exc)}") from None
    inputs = start_inputs(scenario)
    accel, _, error = call_acceleration(controller, inputs)
    if error is None:
        *_, error = call_thrust_attitude(controller, accel, inputs, setup.limits.max_thrust_n)
    if error is not None:
        raise ControllerError(f"{where}: on the scenario's start, {error}")
    return controller


def start_inputs(scenario: Scenario) -> ControllerInputs:
    """Every drone's inputs at the scenario's start: at rest where it starts, with the true
    descriptors of the swarm as its estimate and the plan at t = 0."""
    x = scenario.positions_ned_m()
    n = x.shape[0]
    plan = [np.repeat(f[None], n, axis=0) for f in scenario.trajectory().evaluate(0.0)]
    p = x - x.mean(axis=0)
    sigma = p.T @ p / n
    moments = SwarmMoments(
        np.repeat(x.mean(axis=0)[None], n, axis=0),
        np.zeros((n, 3)),
        np.repeat(sigma[None], n, axis=0),
        np.zeros((n, 3, 3)),
    )
    r_d = desired_axes_batch(plan[0])
    axes, s = align_axes_batch(moments.sigma_m2, r_d)
    return ControllerInputs(
        tuple(range(n)), 0.0, x, np.zeros((n, 3)), moments, axes, s, plan[0], plan[1], plan[2], r_d
    )


def _search_path(scenario: Scenario) -> list[Path]:
    """The scenario's ``[agent] path`` folders, put first on ``sys.path`` (once each)."""
    base = Path(scenario.source).resolve().parent
    folders = [(base / p).resolve() for p in scenario.agent.path]
    for folder in reversed(folders):
        if str(folder) not in sys.path:
            sys.path.insert(0, str(folder))
    return folders

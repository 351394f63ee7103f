"""The formation controller's interface: batched arrays in (each drone's own state, its estimate
of the swarm, the plan), an acceleration and then thrust and attitude out. Pure and I/O-free.

A controller is a class built once per batch of agents with a :class:`ControllerSetup`, then
called each control tick with the :class:`ControllerInputs` of the drones ready to fly (row k:
one drone). Two methods:

- :meth:`Controller.acceleration` -> (K, 3) NED m/s^2, gravity not included (``x_ddot = a``):
  what the drone should do. The agent's safety layers act on it: a returning drone's climb
  replaces it, and the separation layer (drone_agent/core/separation/layer.py) changes it where a
  neighbour, the altitude floor or the geofence is near.
- :meth:`Controller.thrust_attitude` -> :class:`AttitudeCommands` (K,) each: the collective
  thrust (N) and the attitude setpoint (ZYX, rad) that realise the (filtered) acceleration.
  :class:`Controller` gives the paper's mapping (ALGORITHM.md eq. 35 as corrected) with the
  scenario's tilt and thrust limits; override it to fly your own.

Around whatever is plugged in (drone_agent/core/agent_core.py): a call that raises, or returns the
wrong shape, gives no setpoint to any drone of that call; a row not finite, or a thrust outside
0..the vehicle's maximum, gives none to that drone. Each is counted in the drone's
``rejected_setpoints``; a drone without a setpoint does not arm, and in the air the flight-phase
rules (drone_agent/core/flight_phase.py) hand it to its autopilot's HOLD mode until the controller
answers again. :class:`CooperativeController` (the paper's) is the default and the first
implementation.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

import numpy as np
import numpy.typing as npt

from drone_agent.core.cooperative import CooperativeGains, virtual_acceleration_batch
from drone_agent.core.moments import SwarmMoments
from drone_agent.core.thrust_attitude import ThrustLimits, attitude_thrust_batch
from protocols.model.descriptor_vector import I_YAW
from protocols.model.frames import FloatArray

BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class ControllerSetup:
    """What a controller is built with: the scenario's ``[gains]`` (``gains``: the outer loop's,
    ``limits``: tilt and thrust, and the vehicle's mass and maximum thrust), the control period
    ``dt_s`` (s) and the scenario's ``[agent.options]`` table as it is (``options``)."""

    gains: CooperativeGains
    limits: ThrustLimits
    dt_s: float
    options: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class ControllerInputs:
    """One tick's inputs of K drones, row k each (NED, m, s, rad; descriptor order: centre,
    roll, pitch, yaw, three variances).

    ``agent_ids`` (K,): the drones (index in the scenario); ``t_s``: the simulated time.
    Own state: ``position_ned_m``, ``velocity_ned_m_s`` (K, 3). The drone's consensus estimate
    of the swarm: ``estimate`` (centre (K, 3), its rate (K, 3), covariance Sigma (K, 3, 3) m^2
    and its rate), its principal axes ``axes`` (K, 3, 3; columns, each assigned to the plan's
    axis it is closest to) and the variances along them ``variances_m2`` (K, 3). The plan now:
    ``plan``, ``plan_rate``, ``plan_accel`` (K, 9) descriptors and their first and second time
    derivatives, and the plan's axes ``plan_axes`` (K, 3, 3; columns: length, width, height)."""

    agent_ids: tuple[int, ...]
    t_s: float
    position_ned_m: FloatArray
    velocity_ned_m_s: FloatArray
    estimate: SwarmMoments
    axes: FloatArray
    variances_m2: FloatArray
    plan: FloatArray
    plan_rate: FloatArray
    plan_accel: FloatArray
    plan_axes: FloatArray


class AttitudeCommands(NamedTuple):
    """K drones' commands, (K,) each: attitude setpoint (ZYX, rad), collective thrust (N) and
    whether a limit cut the command (``limited``, bool)."""

    roll_rad: FloatArray
    pitch_rad: FloatArray
    yaw_rad: FloatArray
    thrust_n: FloatArray
    limited: npt.NDArray[np.bool_]


class FormationController(Protocol):
    """The interface (module doc): what ``[agent] controller`` names is a class
    ``Name(setup: ControllerSetup)`` whose instances have these two methods."""

    def acceleration(self, inputs: ControllerInputs) -> FloatArray:
        """Commanded accelerations (K, 3) NED m/s^2, gravity not included."""
        ...

    def thrust_attitude(
        self, accel_ned_m_s2: FloatArray, inputs: ControllerInputs
    ) -> AttitudeCommands:
        """Thrust and attitude (K,) each that realise the accelerations (K, 3)."""
        ...


class Controller:
    """A base for controllers: keeps the setup and maps an acceleration to thrust and attitude
    the paper's way; a subclass gives :meth:`acceleration`."""

    def __init__(self, setup: ControllerSetup) -> None:
        self.setup = setup

    def acceleration(self, inputs: ControllerInputs) -> FloatArray:
        """Commanded accelerations (K, 3) NED m/s^2, gravity not included."""
        raise NotImplementedError

    def thrust_attitude(
        self, accel_ned_m_s2: FloatArray, inputs: ControllerInputs
    ) -> AttitudeCommands:
        """ALGORITHM.md eq. 35 as corrected, at the plan's heading, with the scenario's limits
        (drone_agent/core/thrust_attitude.py: vertical first, then tilt and the thrust left)."""
        yaw = inputs.plan[:, I_YAW]
        roll, pitch, thrust_n, limited = attitude_thrust_batch(
            accel_ned_m_s2, yaw, self.setup.limits
        )
        return AttitudeCommands(roll, pitch, yaw, thrust_n, limited)


class CooperativeController(Controller):
    """The paper's cooperative controller (ALGORITHM.md §4, drone_agent/core/cooperative.py): each
    drone's own block of the descriptor Jacobian's pseudo-inverse, with the scenario's
    ``[gains]``."""

    def acceleration(self, inputs: ControllerInputs) -> FloatArray:
        return virtual_acceleration_batch(
            inputs.position_ned_m,
            inputs.velocity_ned_m_s,
            inputs.estimate,
            (inputs.plan, inputs.plan_rate, inputs.plan_accel),
            self.setup.gains,
            (inputs.plan_axes, inputs.axes, inputs.variances_m2),
        )


def controller_name(controller: object) -> str:
    """``module:Class`` of a controller instance (what a scenario names)."""
    cls = type(controller)
    return f"{cls.__module__}:{cls.__qualname__}"


def call_acceleration(
    controller: FormationController, inputs: ControllerInputs
) -> tuple[FloatArray, BoolArray, str | None]:
    """``controller.acceleration(inputs)`` checked: the accelerations (K, 3), which rows are
    usable and what went wrong (None: nothing). A call that raises or gives another shape
    leaves no row usable; a row not finite is unusable; unusable rows are zeros."""
    n = len(inputs.agent_ids)
    try:
        accel = np.asarray(controller.acceleration(inputs), dtype=float)
    except Exception as exc:  # a user's controller: any failure must keep the drones safe
        return np.zeros((n, 3)), np.zeros(n, dtype=bool), "acceleration " + raised(exc)
    if accel.shape != (n, 3):
        error = f"acceleration gave shape {accel.shape}, not ({n}, 3)"
        return np.zeros((n, 3)), np.zeros(n, dtype=bool), error
    if np.isfinite(accel).all():  # (the usual case: one reduction)
        return accel, np.ones(n, dtype=bool), None
    good = np.isfinite(accel).all(axis=1)
    bad = [inputs.agent_ids[k] for k in np.flatnonzero(~good).tolist()]
    return np.where(good[:, None], accel, 0.0), good, f"acceleration not finite for drones {bad}"


def call_thrust_attitude(
    controller: FormationController,
    accel_ned_m_s2: FloatArray,
    inputs: ControllerInputs,
    max_thrust_n: float,
) -> tuple[FloatArray, BoolArray, BoolArray, str | None]:
    """``controller.thrust_attitude(...)`` checked: the commands as rows (roll, pitch, yaw,
    thrust normalised to ``max_thrust_n``) (4, K), ``limited`` (K,), which are usable (K,: finite,
    thrust within 0..``max_thrust_n``) and what went wrong (None: nothing). A call that raises
    or gives other shapes gives NaN commands, none usable."""
    n = len(inputs.agent_ids)
    failed = np.full((4, n), np.nan), np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    try:
        roll, pitch, yaw, thrust_n, limited = controller.thrust_attitude(accel_ned_m_s2, inputs)
        command = np.array([roll, pitch, yaw, thrust_n / max_thrust_n], dtype=float)
        flags = np.asarray(limited, dtype=bool)
    except Exception as exc:  # a user's controller: any failure must keep the drones safe
        return *failed, "thrust_attitude " + raised(exc)
    if command.shape != (4, n) or flags.shape != (n,):
        shapes = [np.shape(c) for c in (roll, pitch, yaw, thrust_n, limited)]
        return *failed, f"thrust_attitude gave shapes {shapes}, not ({n},) each"
    fine = np.isfinite(command).all(axis=0)
    usable = fine & (command[3] >= 0.0) & (command[3] <= 1.0)
    if usable.all():
        return command, flags, usable, None
    if not fine.all():
        bad = [inputs.agent_ids[k] for k in np.flatnonzero(~fine).tolist()]
        return command, flags, usable, f"thrust_attitude not finite for drones {bad}"
    worst = float(command[3][np.argmax(np.abs(command[3] - 0.5))]) * max_thrust_n
    error = f"thrust_attitude gave a thrust of {worst:.3g} N, outside 0..{max_thrust_n:.3g} N"
    return command, flags, usable, error


def raised(exc: BaseException) -> str:
    """``raised KeyError: 'x'``: the exception, on one line."""
    text = str(exc).strip().splitlines()
    return f"raised {type(exc).__name__}" + (f": {text[0]}" if text else "")

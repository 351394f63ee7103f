"""Scenario files: typed, validated, versioned (SPEC.md "Scenarios"). Pure apart from reading.

A scenario is a TOML file with ``version = 1``: the drones' initial positions, vehicle parameters,
rates, gains, consensus settings, communication range, the descriptor trajectory as waypoints, a
timeline of faults, and where the NED origin is on the map (``[home] lat_deg, lon_deg, alt_m``:
WGS-84 degrees, metres above sea level; default PX4 SITL's home, Zürich). Defaults are
ALGORITHM.md §6. :func:`load_scenario` raises ScenarioError
(a ValueError) with a one-line message ``<file>: <field path>: <what>`` for every mistake. Angles
are degrees in the file and radians in the trajectory; shape is a spread (RMS distance from the
centre, m) or a variance (m²) per swarm axis in the file, always a variance in the trajectory.
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from protocols.faults import (
    Crash,
    Delay,
    Dropout,
    Fault,
    LinkCut,
    Loss,
    Partition,
)
from protocols.model.formation_fit import fit_problem
from protocols.model.frames import FloatArray
from protocols.model.geodesy import GeoPoint
from protocols.model.plan_timing import from_the_ground
from protocols.model.trajectory import DescriptorTrajectory, Waypoint
from protocols.scenario.schema import ScenarioError, Table

__all__ = [
    "AgentSection",
    "Crash",
    "Delay",
    "Dropout",
    "Fault",
    "GeoPoint",
    "LinkCut",
    "Loss",
    "Partition",
    "Scenario",
    "ScenarioError",
    "load_scenario",
    "parse_scenario",
]

SUPPORTED_VERSIONS = (1,)
#: a scenario's drones: every one a MAVLink vehicle (system ids 1..250; 251..255 are the ground
#: stations': protocols/mavlink/conventions.py MAX_VEHICLES, held equal by tests/test_scenario.py)
#: and a row of the agents' neighbour tables, which hold that many
MIN_DRONES, MAX_DRONES = 2, 250
MIN_SEPARATION_M = 0.5
PAPER_KP = (0.5, 0.5, 1.75, 0.15, 0.15, 0.15, 0.5, 0.5, 0.5)
#: Orientation's own PD gains (roll, pitch, yaw), drone_agent/core/cooperative.py.
ORIENTATION_KP = (0.5, 0.5, 0.5)
Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class VehicleConfig:
    """[vehicle]: mass (kg), principal inertia (kg m²), arm (m), thrust-to-weight, top rotor speed
    (rad/s), reaction yaw moment per newton of thrust (m); body drag per mass along the body's
    x and y axes and along z (1/s: m/s² of deceleration per m/s of airspeed; a small
    quadcopter's rotor drag is ~0.4 in xy, ~0.15 in z); the motors' time constant (s: each
    rotor's speed follows its command as a first-order lag; 0: at once). Defaults: paper Table II,
    no drag, no motor lag."""

    mass_kg: float = 0.34
    ixx: float = 3.22e-4
    iyy: float = 3.06e-4
    izz: float = 5.78e-4
    arm_m: float = 0.089
    thrust_to_weight: float = 2.0
    rotor_speed_max_rad_s: float = 1000.0
    yaw_moment_per_thrust_m: float = 0.016
    drag_xy_per_s: float = 0.0
    drag_z_per_s: float = 0.0
    motor_tau_s: float = 0.0


@dataclass(frozen=True)
class FleetConfig:
    """[vehicles]: how the vehicles differ from [vehicle], each drawn once from the scenario's
    seed: ``mass_spread`` and ``thrust_spread`` are the relative standard deviations of each
    vehicle's mass and rotor thrust coefficient (0.05: 5 %), ``motor_tau_spread`` of its motors'
    time constant (where [vehicle] gives one). Default: all alike. The autopilots know only
    [vehicle]'s values, as real ones know only their configuration."""

    mass_spread: float = 0.0
    thrust_spread: float = 0.0
    motor_tau_spread: float = 0.0


@dataclass(frozen=True)
class SensorsConfig:
    """[sensors]: what each vehicle's autopilot believes about itself, as a GNSS + EKF reports it
    (sitl_sim/vehicle/estimate.py): ``gnss_bias_m`` the standard deviation (m) of a horizontal
    position bias and ``altitude_bias_m`` of a height bias (a barometer-fused height's drift), both
    wandering with correlation time ``gnss_bias_tau_s`` (s); white noise on position (m),
    velocity (m/s) and attitude (rad); the estimate's output rate ``rate_hz`` (0: every control
    tick) and its latency ``latency_s``. Drawn from the scenario's seed, each vehicle its own.
    The agents see only the estimate (the vehicles' telemetry); the report is of the truth.
    Default: ideal sensors, the estimate is the truth."""

    gnss_bias_m: float = 0.0
    gnss_bias_tau_s: float = 300.0
    position_noise_m: float = 0.0
    velocity_noise_m_s: float = 0.0
    attitude_noise_rad: float = 0.0
    rate_hz: float = 0.0
    latency_s: float = 0.0
    altitude_bias_m: float = 0.0

    @property
    def lie(self) -> bool:
        """An error term is on: a GNSS or height bias or noise on position, velocity or
        attitude."""
        return any(
            (
                self.gnss_bias_m,
                self.altitude_bias_m,
                self.position_noise_m,
                self.velocity_noise_m_s,
                self.attitude_noise_rad,
            )
        )

    @property
    def ideal(self) -> bool:
        """No error term, no output rate and no latency: the estimate is the truth."""
        return not self.lie and self.rate_hz == 0.0 and self.latency_s == 0.0


@dataclass(frozen=True)
class RadioConfig:
    """[radio]: what the radio between the drones does besides its range (the one model of
    drone_agent/process/radio.py, in ``swarm simulate``'s radio and in the agents' link layer of
    ``swarm up`` alike; each directed link draws from its own stream of the scenario's seed).
    ``bandwidth_bytes_s``: each link's capacity (0: unlimited); a message takes its bytes over
    it, waiting behind the ones before, and the link holds at most ``queue_messages`` waiting
    (more are dropped). ``loss_half_m``: the distance at which half the messages are lost
    (0: none lost to distance), loss rising with distance as log-distance path loss with exponent
    ``path_loss_exponent`` and a fading term of ``fading_db`` (dB, 1 sigma) drawn per message.
    Bursts (Gilbert–Elliott): a link spends ``burst_fraction`` of its messages in a bad state whose
    spells last ``burst_length`` messages on average, losing each with ``burst_loss``.
    ``latency_s``: added one-way latency; ``jitter_s``: the mean of a random (exponential) extra
    delay per message. Default: the ideal radio (range only)."""

    bandwidth_bytes_s: float = 0.0
    queue_messages: int = 8
    loss_half_m: float = 0.0
    path_loss_exponent: float = 3.0
    fading_db: float = 6.0
    burst_fraction: float = 0.0
    burst_length: float = 5.0
    burst_loss: float = 1.0
    latency_s: float = 0.0
    jitter_s: float = 0.0

    @property
    def ideal(self) -> bool:
        """No bandwidth cap, no loss to distance or bursts, no latency: range only."""
        return (
            self.bandwidth_bytes_s == 0.0
            and self.loss_half_m == 0.0
            and (self.burst_fraction == 0.0 or self.burst_loss == 0.0)
            and self.latency_s == 0.0
            and self.jitter_s == 0.0
        )


@dataclass(frozen=True)
class EnvironmentConfig:
    """[environment]: the air the swarm flies in. ``wind_ned_m_s``: the mean wind (m/s, NED: the
    velocity the air moves with; a wind from the west is ``[0, w, 0]``); ``turbulence_m_s``: the
    gusts' intensity (each component's standard deviation, m/s; von Kármán turbulence carried by
    the wind, sitl_sim/physics/wind.py); ``turbulence_scale_m``: their length scale (m). Default:
    still air."""

    wind_ned_m_s: Vec3 = (0.0, 0.0, 0.0)
    turbulence_m_s: float = 0.0
    turbulence_scale_m: float = 20.0

    @property
    def calm(self) -> bool:
        """No wind and no turbulence."""
        return not any(self.wind_ned_m_s) and self.turbulence_m_s == 0.0


@dataclass(frozen=True)
class RatesConfig:
    """[rates]: physics and control rates (Hz); physics_hz is an integer multiple of control_hz."""

    physics_hz: int = 500
    control_hz: int = 50

    @property
    def physics_steps_per_control(self) -> int:
        """Physics steps per control tick."""
        return self.physics_hz // self.control_hz

    @property
    def dt_control_s(self) -> float:
        """Control period (s)."""
        return 1.0 / self.control_hz


@dataclass(frozen=True)
class GainsConfig:
    """[gains]: outer-loop kp, kd (9,) in descriptor order (1/s², 1/s; the orientation entries
    3..5 are not used: orientation has its own gains, below); attitude PD (roll, pitch, yaw);
    flat-axis PD; null-space damping (1/s); limits: tilt (deg), thrust as a fraction of the
    weight (min) and of the maximum thrust (max), smallest variance used in the inversion (m²).
    The formation's orientation (roll, pitch, yaw about its own axes): PD ``orientation_kp``
    (1/s²), ``orientation_kd`` (1/s, default 1.8 sqrt(kp)), and the limits of that feedback: the
    speed (m/s) and acceleration (m/s²) it may give the formation's RMS radius."""

    kp: tuple[float, ...] = PAPER_KP
    kd: tuple[float, ...] = tuple(1.8 * math.sqrt(k) for k in PAPER_KP)
    attitude_kp: Vec3 = (324.0, 324.0, 144.0)
    attitude_kd: Vec3 = (34.2, 34.2, 22.8)
    flat_kp: float = 1.75
    flat_kd: float = 1.75
    null_damping_per_s: float = 1.0
    max_tilt_deg: float = 35.0
    min_thrust_ratio: float = 0.2
    max_thrust_ratio: float = 0.85
    min_variance_m2: float = 0.05
    orientation_kp: Vec3 = ORIENTATION_KP
    orientation_kd: Vec3 = tuple(1.8 * math.sqrt(k) for k in ORIENTATION_KP)  # type: ignore[assignment]
    orientation_max_speed_m_s: float = 1.0
    orientation_max_accel_m_s2: float = 1.0


@dataclass(frozen=True)
class ConsensusConfig:
    """[consensus]: gain rho, tanh slope c, coupling f (ALGORITHM.md §3); degree-normalised rho;
    heard-set timeout (control ticks); partner-dead timeout (s); ground warm-up before arming (s);
    message delay (control ticks); the step cap that keeps large, dense radio graphs stable
    (``max_step_gain``, drone_agent/core/consensus/scalar.py; 0 turns it off); the channel scale (m)
    below which the estimator's ``tanh`` stays linear (``channel_scale_m``, the same module); when
    an agent's estimate counts as settled before take-off (``settle``, :data:`SETTLE_RULES`):
    ``"agree"`` its disagreement with its neighbours is below 2 %, ``"plateau"`` it is below 2 % or
    has stopped falling (sensors that lie keep it above 2 % for ever), ``"auto"`` (the default)
    plateau where [sensors] add an error (bias or noise), agree otherwise."""

    rho: float = 2.0
    c: float = 1.0
    f: float = 2.0
    degree_normalised: bool = False
    heard_timeout_ticks: int = 5
    dead_timeout_s: float = 0.5
    warmup_s: float = 3.0
    delay_ticks: int = 1
    max_step_gain: float = 1.4
    channel_scale_m: float = 10.0
    settle: str = "auto"


#: [consensus] settle: the take-off readiness rules (drone_agent/core/flight_phase.py)
SETTLE_RULES = ("auto", "agree", "plateau")


@dataclass(frozen=True)
class CommsConfig:
    """[comms]: radio range (m): drones farther apart do not hear each other."""

    range_m: float = 10.0


@dataclass(frozen=True)
class SafetyConfig:
    """[safety]: the distance (m) every formation of the plan and of operator commands must keep
    between drones (protocols/model/formation_fit.py), and every agent's separation layer keeps from
    the neighbours it hears (drone_agent/core/separation/filter.py); the geofence: north and east
    within ``± geofence_m`` of the origin, altitude up to ``ceiling_m`` (the ground station refuses
    commands that leave it, the agents' separation layer stops drones at it)."""

    min_separation_m: float = 1.0
    geofence_m: float = 1000.0
    ceiling_m: float = 60.0


@dataclass(frozen=True)
class AgentSection:
    """[agent]: the formation controller every agent flies (docs/controllers.md).

    ``controller``: ``"package.module:Name"``, a class implementing the controller interface
    (drone_agent/core/controller.py); None: the paper's cooperative controller. ``path``: folders
    its module is looked for in before ``sys.path``, relative to the scenario file (default: the
    scenario's own folder). ``options``: the ``[agent.options]`` table, handed to the
    controller as it is (its own gains, say)."""

    controller: str | None = None
    path: tuple[str, ...] = (".",)
    options: tuple[tuple[str, Any], ...] = ()


@dataclass(frozen=True)
class DroneConfig:
    """One [[drones]] entry: initial position (NED, m; z <= 0) and heading (deg)."""

    position_ned_m: Vec3
    yaw_deg: float = 0.0


@dataclass(frozen=True)
class DescriptorDerivative:
    """A waypoint's ``rate`` (per s) or ``accel`` (per s²) table: centre (m), angles (deg),
    variances (m²), each per s or s². Keys left out are 0."""

    centre_ned_m: Vec3 = (0.0, 0.0, 0.0)
    roll_deg: float = 0.0
    pitch_deg: float = 0.0
    yaw_deg: float = 0.0
    variance_m2: Vec3 = (0.0, 0.0, 0.0)

    def vector(self) -> FloatArray:
        """As a descriptor-vector derivative (9,), angles in radians."""
        angles = np.radians([self.roll_deg, self.pitch_deg, self.yaw_deg])
        return np.concatenate([self.centre_ned_m, angles, self.variance_m2])


@dataclass(frozen=True)
class WaypointConfig:
    """One [[trajectory.waypoints]] entry: time (s), centre (NED, m), orientation (deg), variances
    (m², converted from spread_m when the file gave spreads), optional rate and accel."""

    t_s: float
    centre_ned_m: Vec3
    variance_m2: Vec3
    roll_deg: float = 0.0
    pitch_deg: float = 0.0
    yaw_deg: float = 0.0
    rate: DescriptorDerivative | None = None
    accel: DescriptorDerivative | None = None

    def waypoint(self) -> Waypoint:
        """As a trajectory Waypoint (descriptor vector order, radians)."""
        value = DescriptorDerivative(
            self.centre_ned_m, self.roll_deg, self.pitch_deg, self.yaw_deg, self.variance_m2
        ).vector()
        rate = None if self.rate is None else self.rate.vector()
        accel = None if self.accel is None else self.accel.vector()
        return Waypoint(self.t_s, value, rate, accel)


@dataclass(frozen=True)
class Scenario:
    """A whole scenario. Drone i (0-based, file order) has MAVLink system id i + 1.

    ``duration_s`` (s) defaults to the last waypoint's time; metrics ignore tracking error before
    ``settle_s`` (s). ``seed`` seeds every random generator of a run.
    """

    source: str
    name: str
    duration_s: float
    drones: tuple[DroneConfig, ...]
    waypoints: tuple[WaypointConfig, ...]
    seed: int = 0
    settle_s: float = 20.0
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    rates: RatesConfig = field(default_factory=RatesConfig)
    gains: GainsConfig = field(default_factory=GainsConfig)
    consensus: ConsensusConfig = field(default_factory=ConsensusConfig)
    comms: CommsConfig = field(default_factory=CommsConfig)
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    faults: tuple[Fault, ...] = ()
    #: [home]: where the NED origin is on the map (protocols/model/geodesy.py)
    home: GeoPoint = field(default_factory=GeoPoint)
    version: int = 1
    #: [agent]: the formation controller (None: the paper's)
    agent: AgentSection = field(default_factory=AgentSection)
    #: [environment]: wind and turbulence (default: still air)
    environment: EnvironmentConfig = field(default_factory=EnvironmentConfig)
    #: [vehicles]: how the vehicles differ (default: all alike)
    vehicles: FleetConfig = field(default_factory=FleetConfig)
    #: [sensors]: the vehicles' state estimates (default: the truth)
    sensors: SensorsConfig = field(default_factory=SensorsConfig)
    #: [radio]: the radio's limits besides its range (default: none)
    radio: RadioConfig = field(default_factory=RadioConfig)

    @property
    def n_drones(self) -> int:
        """Number of drones N."""
        return len(self.drones)

    def positions_ned_m(self) -> FloatArray:
        """Initial positions (N, 3), NED, m."""
        return np.array([d.position_ned_m for d in self.drones], dtype=float)

    def trajectory(self) -> DescriptorTrajectory:
        """The descriptor trajectory a_d(t) (seq 0) through the waypoints, angles in radians; a
        plan written airborne from its start climbs to it from the ground first
        (protocols.model.plan_timing.from_the_ground)."""
        written = [w.waypoint() for w in self.waypoints]
        return DescriptorTrajectory.from_waypoints(from_the_ground(written), seq=0)


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate the scenario file at ``path``.

    Raises:
        ScenarioError: missing/unreadable file, invalid TOML (with line and column), or any field
            that is missing, unknown, of the wrong type, not finite or out of range.
    """
    source = str(path)
    try:
        text = Path(path).read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise ScenarioError(f"{source}: no such file") from None
    except UnicodeDecodeError as e:
        raise ScenarioError(f"{source}: not UTF-8 text ({e.reason} at byte {e.start})") from None
    except OSError as e:
        raise ScenarioError(f"{source}: cannot read: {e.strerror or e}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ScenarioError(f"{source}: invalid TOML: {e}") from None
    return parse_scenario(data, source)


def parse_scenario(data: dict[str, Any], source: str) -> Scenario:
    """Validate already-parsed TOML ``data``; ``source`` names it in error messages."""
    top = Table(data, source, "")
    if not top.has("version"):
        raise top.error(f"missing (required; supported: {_supported()})", "version")
    version = top.integer("version")
    if version not in SUPPORTED_VERSIONS:
        raise top.error(f"{version} is not supported (supported: {_supported()})", "version")
    top.allow(
        ("version", "name", "duration_s", "seed", "settle_s", "vehicle", "rates", "gains",
         "consensus", "comms", "safety", "drones", "trajectory", "faults", "home", "agent",
         "environment", "vehicles", "sensors", "radio")
    )  # fmt: skip
    drones = _drones(top)
    waypoints = _waypoints(top.table("trajectory", ("waypoints",)))
    if top.has("duration_s"):
        duration_s = top.number("duration_s", gt=0)
    elif waypoints[-1].t_s > 0:
        duration_s = waypoints[-1].t_s
    else:
        raise top.error("missing (required when the last waypoint is at t = 0)", "duration_s")
    safety = top.table("safety").section(
        SafetyConfig,
        {"min_separation_m": {"ge": 0}, "geofence_m": {"gt": 0}, "ceiling_m": {"gt": 0}},
    )
    _check_formations(top, drones, waypoints, safety)
    vehicle = _vehicle(top.table("vehicle"))
    environment = _environment(top.table("environment"), vehicle)
    return Scenario(
        source=source,
        name=top.string("name", Path(source).stem),
        duration_s=duration_s,
        drones=drones,
        waypoints=waypoints,
        seed=top.integer("seed", 0, ge=0),
        settle_s=top.number("settle_s", 20.0, ge=0),
        vehicle=vehicle,
        rates=_rates(top.table("rates")),
        gains=_gains(top.table("gains")),
        consensus=_consensus(top.table("consensus")),
        comms=top.table("comms").section(CommsConfig, {"range_m": {"gt": 0}}),
        safety=safety,
        faults=tuple(_fault(t, len(drones), duration_s) for t in top.tables("faults")),
        home=top.table("home").section(GeoPoint, HOME_BOUNDS),
        version=version,
        agent=_agent(top.table("agent", ("controller", "path", "options"))),
        environment=environment,
        vehicles=top.table("vehicles").section(FleetConfig, _FLEET_BOUNDS),
        sensors=top.table("sensors").section(SensorsConfig, _SENSORS_BOUNDS),
        radio=top.table("radio").section(RadioConfig, _RADIO_BOUNDS),
    )


def _check_formations(
    top: Table,
    drones: tuple[DroneConfig, ...],
    waypoints: tuple[WaypointConfig, ...],
    safety: SafetyConfig,
) -> None:
    """Every waypoint's formation must hold the drones, from where they start, at least
    ``safety.min_separation_m`` apart (the cooperative field maps their layout affinely)."""
    if len(drones) < 2 or safety.min_separation_m <= 0:
        return
    start = np.array([d.position_ned_m for d in drones], dtype=float)
    for k, w in enumerate(waypoints):
        problem = fit_problem(start, w.waypoint().value, safety.min_separation_m)
        if problem is not None:
            raise top.error(f"at t = {w.t_s:g} s {problem}", f"trajectory.waypoints[{k}]")


#: ``package.module:Name``: dotted identifiers, a colon, an identifier
_REFERENCE = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*")


def _agent(t: Table) -> AgentSection:
    controller = t.string("controller") if t.has("controller") else None
    if controller is not None and not _REFERENCE.fullmatch(controller):
        raise t.error(
            f'{controller!r} is not a controller reference ("package.module:ClassName")',
            "controller",
        )
    path: tuple[str, ...] = (".",)
    if t.has("path"):
        items = t.array("path")
        for k, item in enumerate(items):
            if not isinstance(item, str) or not item:
                raise t.error("must be a non-empty string (a folder)", f"path[{k}]")
        path = tuple(items)
    options = t.table("options")
    return AgentSection(controller, path, tuple(sorted(options.data.items())))


def _supported() -> str:
    return ", ".join(str(v) for v in SUPPORTED_VERSIONS)


#: [home]: a latitude off the poles (longitude is undefined there), an altitude a drone can fly.
HOME_BOUNDS = {
    "lat_deg": {"gt": -90.0, "lt": 90.0},
    "lon_deg": {"ge": -180.0, "le": 180.0},
    "alt_m": {"ge": -500.0, "le": 9000.0},
}
_VEHICLE_BOUNDS: dict[str, dict[str, float]] = {
    **{name: {"gt": 0.0} for name in VehicleConfig.__dataclass_fields__},
    "drag_xy_per_s": {"ge": 0.0, "le": 10.0},
    "drag_z_per_s": {"ge": 0.0, "le": 10.0},
    "motor_tau_s": {"ge": 0.0, "le": 0.5},
}
_FLEET_BOUNDS: dict[str, dict[str, float]] = {
    "mass_spread": {"ge": 0.0, "le": 0.3},
    "thrust_spread": {"ge": 0.0, "le": 0.3},
    "motor_tau_spread": {"ge": 0.0, "le": 0.3},
}
#: [sensors]: up to what a poor GNSS gives (tens of metres of bias are no formation's), a rate of
#: at least 1 Hz when given, at most a second of latency
_SENSORS_BOUNDS: dict[str, dict[str, float]] = {
    "gnss_bias_m": {"ge": 0.0, "le": 20.0},
    "altitude_bias_m": {"ge": 0.0, "le": 20.0},
    "gnss_bias_tau_s": {"gt": 0.0, "le": 1e5},
    "position_noise_m": {"ge": 0.0, "le": 10.0},
    "velocity_noise_m_s": {"ge": 0.0, "le": 5.0},
    "attitude_noise_rad": {"ge": 0.0, "le": 0.5},
    "rate_hz": {"ge": 0.0, "le": 1000.0},
    "latency_s": {"ge": 0.0, "le": 1.0},
}
_RADIO_BOUNDS: dict[str, dict[str, float]] = {
    "bandwidth_bytes_s": {"ge": 0.0},
    "queue_messages": {"ge": 0, "le": 10_000},
    "loss_half_m": {"ge": 0.0, "le": 1e5},
    "path_loss_exponent": {"ge": 1.0, "le": 6.0},
    "fading_db": {"gt": 0.0, "le": 30.0},
    "burst_fraction": {"ge": 0.0, "lt": 1.0},
    "burst_length": {"ge": 1.0, "le": 1e6},
    "burst_loss": {"ge": 0.0, "le": 1.0},
    "latency_s": {"ge": 0.0, "le": 5.0},
    "jitter_s": {"ge": 0.0, "le": 5.0},
}
_ENVIRONMENT_BOUNDS: dict[str, dict[str, float]] = {
    "turbulence_m_s": {"ge": 0.0, "le": 10.0},
    "turbulence_scale_m": {"ge": 0.5, "le": 1e4},
}
_GAINS_BOUNDS: dict[str, dict[str, float]] = {
    "attitude_kp": {"gt": 0},
    "max_tilt_deg": {"gt": 0, "lt": 90},
    "min_thrust_ratio": {"ge": 0, "lt": 1},
    "max_thrust_ratio": {"gt": 0, "le": 1},
    "min_variance_m2": {"gt": 0},
    "orientation_max_speed_m_s": {"gt": 0},
    "orientation_max_accel_m_s2": {"gt": 0},
}
_CONSENSUS_BOUNDS = {
    "rho": {"gt": 0},
    "c": {"gt": 0},
    "f": {"gt": 0},
    "heard_timeout_ticks": {"ge": 1},
    "dead_timeout_s": {"gt": 0},
    "warmup_s": {"ge": 0},
    "delay_ticks": {"ge": 0},
    "max_step_gain": {"ge": 0, "lt": 2},
    "channel_scale_m": {"gt": 0},
}


def _consensus(t: Table) -> ConsensusConfig:
    settle = t.string("settle", "auto")
    if settle not in SETTLE_RULES:
        raise t.error(f"must be one of {', '.join(SETTLE_RULES)}, got {settle!r}", "settle")
    config: ConsensusConfig = t.section(ConsensusConfig, _CONSENSUS_BOUNDS, settle=settle)
    return config


def _vehicle(t: Table) -> VehicleConfig:
    vehicle: VehicleConfig = t.section(VehicleConfig, _VEHICLE_BOUNDS)
    if vehicle.thrust_to_weight <= 1.0:
        raise t.error("must be > 1 (the vehicle must lift itself)", "thrust_to_weight")
    return vehicle


def _environment(t: Table, vehicle: VehicleConfig) -> EnvironmentConfig:
    env: EnvironmentConfig = t.section(EnvironmentConfig, _ENVIRONMENT_BOUNDS)
    if math.hypot(*env.wind_ned_m_s) > 30.0:
        raise t.error("above 30 m/s no small quadcopter flies", "wind_ned_m_s")
    if not env.calm and vehicle.drag_xy_per_s == 0.0 and vehicle.drag_z_per_s == 0.0:
        raise t.error(
            "the air moves a vehicle only through its drag, and [vehicle] has none: give "
            "[vehicle] drag_xy_per_s and drag_z_per_s (a small quadcopter: 0.4 and 0.15)",
            "wind_ned_m_s" if any(env.wind_ned_m_s) else "turbulence_m_s",
        )
    return env


def _rates(t: Table) -> RatesConfig:
    rates: RatesConfig = t.section(RatesConfig, {"physics_hz": {"ge": 1}, "control_hz": {"ge": 1}})
    if rates.physics_hz % rates.control_hz:
        raise t.error(
            f"{rates.physics_hz} is not an integer multiple of control_hz = {rates.control_hz}",
            "physics_hz",
        )
    return rates


def _gains(t: Table) -> GainsConfig:
    kp = t.numbers("kp", 9, PAPER_KP, ge=0)
    kd = t.numbers("kd", 9, tuple(1.8 * math.sqrt(k) for k in kp), ge=0)
    okp = t.vec3("orientation_kp", ORIENTATION_KP, gt=0)
    okd = t.vec3("orientation_kd", tuple(1.8 * math.sqrt(k) for k in okp), gt=0)
    bounds = {"ge": 0.0}  # every gain not in _GAINS_BOUNDS
    names = GainsConfig.__dataclass_fields__
    return t.section(
        GainsConfig,
        {n: _GAINS_BOUNDS.get(n, bounds) for n in names},
        kp=kp,
        kd=kd,
        orientation_kp=okp,
        orientation_kd=okd,
    )


def _drones(top: Table) -> tuple[DroneConfig, ...]:
    if not top.has("drones"):
        raise top.error("missing (required: [[drones]] tables with position_ned_m)", "drones")
    tables = top.tables("drones", ("position_ned_m", "yaw_deg"))
    if not MIN_DRONES <= len(tables) <= MAX_DRONES:
        raise top.error(
            f"need {MIN_DRONES}..{MAX_DRONES} drones (MAVLink system ids 1..{MAX_DRONES}), "
            f"got {len(tables)}",
            "drones",
        )
    drones = []
    for t in tables:
        pos = t.vec3("position_ned_m")
        if pos[2] > 0:
            raise t.error(
                f"z must be <= 0 (on or above the ground), got {pos[2]}", "position_ned_m"
            )
        drones.append(DroneConfig(pos, t.number("yaw_deg", 0.0)))
    x = np.array([d.position_ned_m for d in drones])
    gap = np.linalg.norm(x[:, None, :] - x[None, :, :], axis=-1)  # N <= MAX_DRONES: <= 1.5 MB
    pairs = np.argwhere(np.triu(gap < MIN_SEPARATION_M, k=1))
    close = [(int(i), int(j)) for i, j in pairs]
    if close:
        i, j = min(close)
        raise tables[j].error(
            f"{np.linalg.norm(x[i] - x[j]):.3g} m from drones[{i}] (minimum {MIN_SEPARATION_M} m)",
            "position_ned_m",
        )
    return tuple(drones)


_DERIVATIVE_KEYS = ("centre_ned_m", "roll_deg", "pitch_deg", "yaw_deg", "variance_m2")


def _waypoints(t: Table) -> tuple[WaypointConfig, ...]:
    if not t.has("waypoints"):
        raise t.error("missing (required: at least one [[trajectory.waypoints]])", "waypoints")
    tables = t.tables("waypoints", ("t_s", "spread_m", "rate", "accel", *_DERIVATIVE_KEYS))
    if not tables:
        raise t.error("needs at least one waypoint", "waypoints")
    out: list[WaypointConfig] = []
    for k, w in enumerate(tables):
        t_s = w.number("t_s", ge=0)
        if out and not t_s > out[-1].t_s:
            raise w.error(f"{t_s:g} is not after waypoints[{k - 1}].t_s = {out[-1].t_s:g}", "t_s")
        if w.has("spread_m") == w.has("variance_m2"):
            raise w.error("give the shape as exactly one of spread_m or variance_m2", here=True)
        if w.has("spread_m"):
            sx, sy, sz = w.vec3("spread_m", ge=0)
            variance = (sx * sx, sy * sy, sz * sz)
        else:
            variance = w.vec3("variance_m2", ge=0)
        out.append(
            WaypointConfig(
                t_s=t_s,
                centre_ned_m=w.vec3("centre_ned_m"),
                variance_m2=variance,
                roll_deg=w.number("roll_deg", 0.0, gt=-90, lt=90),
                pitch_deg=w.number("pitch_deg", 0.0, gt=-90, lt=90),
                yaw_deg=w.number("yaw_deg", 0.0),
                rate=_derivative(w, "rate"),
                accel=_derivative(w, "accel"),
            )
        )
    return tuple(out)


def _derivative(w: Table, key: str) -> DescriptorDerivative | None:
    if not w.has(key):
        return None
    t = w.table(key)
    if t.has("spread_m"):
        raise t.error("not allowed: the descriptor is the variance; give variance_m2", "spread_m")
    return t.section(DescriptorDerivative)


#: The keys of each fault kind (the ``kind`` of its class in protocols.faults) besides t_s, kind
_FAULT_KEYS = {
    Dropout.kind: ("drone",),
    Crash.kind: ("drone",),
    LinkCut.kind: ("drones", "duration_s", "one_way"),
    Loss.kind: ("probability", "duration_s", "drones"),
    Delay.kind: ("delay_ms", "duration_s", "drones"),
    Partition.kind: ("groups", "duration_s"),
}


def _fault(t: Table, n: int, duration_s: float) -> Fault:
    """A ``[[faults]]`` table: the command of its ``kind`` with its start time ``t_s``."""
    kind = t.string("kind")
    if kind not in _FAULT_KEYS:
        raise t.error(f"'{kind}' is not a fault kind (one of: {', '.join(_FAULT_KEYS)})", "kind")
    t.allow(("t_s", "kind", *_FAULT_KEYS[kind]))
    t_s = t.number("t_s", ge=0)
    if t_s > duration_s:
        raise t.error(
            f"{t_s:g} is after the end of the scenario (duration_s = {duration_s:g})", "t_s"
        )
    dur = t.optional_number("duration_s", gt=0)
    if kind in (Dropout.kind, Crash.kind):
        drone = t.index("drone", n)
        return Dropout(drone, t_s=t_s) if kind == Dropout.kind else Crash(drone, t_s=t_s)
    if kind == LinkCut.kind:
        i, j = t.pair("drones", n)
        return LinkCut(i, j, t.boolean("one_way", False), dur, t_s=t_s)
    pair = t.pair("drones", n) if t.has("drones") else None
    if kind == Loss.kind:
        return Loss(t.number("probability", ge=0, lt=1), pair, dur, t_s=t_s)
    if kind == Delay.kind:
        return Delay(t.number("delay_ms", ge=0), pair, dur, t_s=t_s)
    return Partition(t.groups("groups", n), dur, t_s=t_s)

"""The simulated world: N vehicles stepped together at the physics rate. Pure (no clock, no I/O).

One :meth:`World.step` advances simulated time by one control period ``1 / control_hz``: at every
physics step (``physics_hz``) each vehicle's autopilot command (:mod:`sitl_sim.vehicle.guidance`)
goes through its inner loop (attitude controller + mixer,
:func:`sitl_sim.physics.inner_loop.inner_loop`), dead motors are stopped, and the vectorised 6-DOF
dynamics with ground contact advance the state
(:func:`sitl_sim.physics.dynamics.step_with_contact`):
:class:`sitl_sim.physics.kernel.PhysicsKernel` does the three in one fused call, with the same
arithmetic (and a whole period's steps in one call while no vehicle's command depends on the state
within it). Then the autopilots update (failsafes, touchdowns, crashes) and scheduled crashes (a
scenario's fault timeline) fire.

Where a vehicle's motors lag (``VehicleParams.motor_tau_s``, each vehicle's own with
``config.vehicle_scales``' third factor), its rotors' speeds are state the World keeps
(:attr:`World.rotor_speed_rad_s`), each physics step starting from the last one's: a simulator
shard's vehicles step as they do in the whole world.

Each control period also drains each vehicle's battery by the current its rotors drew
(:mod:`sitl_sim.vehicle.battery`, reported in SYS_STATUS). ``config.home`` places the NED origin on
the map (protocols/model/geodesy.py), for the telemetry only: the world itself is flat.

``config.dialect`` chooses, once, the autopilot firmware the vehicles emulate: PX4 (the
simulator's own :class:`~sitl_sim.vehicle.autopilot.Autopilot` and
:class:`~sitl_sim.vehicle.guidance.Guidance`) or ArduCopter (:mod:`sitl_sim.vehicle.copter`, whose
EKF is ready ``config.ekf_ready_s`` after start).

``config.air`` is the wind and turbulence (:mod:`sitl_sim.physics.wind`): each period every
vehicle samples the air's velocity where it is, and its body drag (``VehicleParams``) pulls it
towards that velocity over the period's physics steps. Still air (the default) is not sampled.

``config.sensors`` is what each vehicle's autopilot believes about itself
(:mod:`sitl_sim.vehicle.estimate`: a GNSS + EKF's wandering bias, noise, output rate and latency):
:meth:`World.estimate` is what its telemetry reports and its agent sees, the state stays the truth
(the physics, the autopilot's own touchdown and failsafe logic, the report).

Time is the control tick ``k``: ``t_s = k / control_hz``. The only randomness is the optional
position noise of the telemetry, drawn from the injected generator every tick for all vehicles,
the turbulence, drawn once from ``config.air_seed``, and the state estimates' errors, drawn from
``config.sensors_seed``, so a seed fixes a run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from protocols.mavlink.conventions import Dialect
from protocols.model.frames import FloatArray
from protocols.model.geodesy import GeoPoint
from sitl_sim.physics.attitude_control import euler_from_quat_batch
from sitl_sim.physics.dynamics import POS, QUAT, RATES, VEL, initial_state
from sitl_sim.physics.kernel import PhysicsKernel
from sitl_sim.physics.vehicle_params import VehicleParams
from sitl_sim.physics.wind import Air, WindField
from sitl_sim.vehicle.autopilot import Autopilot, AutopilotConfig, VehicleEvent
from sitl_sim.vehicle.battery import Battery, BatteryConfig
from sitl_sim.vehicle.copter import CopterAutopilot, CopterGuidance
from sitl_sim.vehicle.estimate import Sensors, StateEstimate
from sitl_sim.vehicle.guidance import Guidance
from sitl_sim.vehicle.tunables import FleetAttitudeGains

#: ArduCopter dialect: simulated seconds after start before the EKF and GPS are ready.
DEFAULT_EKF_READY_S = 2.0


@dataclass(frozen=True)
class WorldConfig:
    """Rates (Hz; physics a multiple of control), autopilot defaults, telemetry position noise
    (standard deviation, m), scheduled crashes ``(t_s, vehicle index)``, where the NED origin is
    on the map, the batteries, the autopilot firmware emulated (``dialect``), for ArduCopter
    the simulated seconds after start before its EKF and GPS are ready, and the air the
    vehicles fly in (``air``; its turbulence drawn from ``air_seed``, the same in every shard
    and runner of a flight) and how each vehicle differs from the nominal one
    (``vehicle_scales``: its mass and thrust factors, and its motors' time constant factor
    third where those differ)."""

    physics_hz: int = 500
    control_hz: int = 50
    autopilot: AutopilotConfig = field(default_factory=AutopilotConfig)
    position_noise_m: float = 0.0
    crashes: tuple[tuple[float, int], ...] = ()
    home: GeoPoint = field(default_factory=GeoPoint)
    battery: BatteryConfig = field(default_factory=BatteryConfig)
    dialect: Dialect = Dialect.PX4
    ekf_ready_s: float = DEFAULT_EKF_READY_S
    air: Air = field(default_factory=Air)
    air_seed: int = 0
    #: each vehicle's (mass, thrust[, motor time constant]) factors
    #: (sitl_sim/physics/vehicle_params.py, ``vehicle_scales``); empty: every vehicle is the
    #: nominal one
    vehicle_scales: tuple[tuple[float, ...], ...] = ()
    #: what the vehicles' state estimates get wrong (sitl_sim/vehicle/estimate.py; the default:
    #: nothing), drawn from ``sensors_seed``, each vehicle from its own stream named by its index
    #: in the swarm: ``first_vehicle`` is this world's vehicle 0's (a simulator shard's first)
    sensors: Sensors = field(default_factory=Sensors)
    sensors_seed: int = 0
    first_vehicle: int = 0

    def validate(self) -> WorldConfig:
        """Raise ValueError naming the field unless the rates and noise are usable."""
        if self.control_hz < 1 or self.physics_hz < self.control_hz:
            raise ValueError("physics_hz must be >= control_hz >= 1")
        if self.physics_hz % self.control_hz:
            raise ValueError(
                f"physics_hz {self.physics_hz} is not a multiple of control_hz {self.control_hz}"
            )
        if not (np.isfinite(self.position_noise_m) and self.position_noise_m >= 0.0):
            raise ValueError("position_noise_m must be finite and >= 0")
        if self.dialect not in tuple(Dialect):
            raise ValueError(f"dialect must be one of {[d.value for d in Dialect]}")
        if not (math.isfinite(self.ekf_ready_s) and self.ekf_ready_s >= 0.0):
            raise ValueError("ekf_ready_s must be finite and >= 0")
        self.air.validate()
        self.sensors.validate()
        if self.first_vehicle < 0:
            raise ValueError("first_vehicle must be >= 0")
        return self


@dataclass(frozen=True)
class Snapshot:
    """Telemetry of every vehicle at tick ``tick`` as plain lists (one entry per vehicle):
    position NED (m, with noise), velocity NED (m/s), (roll, pitch, yaw) rad, body rates
    (p, q, r) rad/s; ``time_boot_ms`` the simulated time in ms."""

    tick: int
    time_boot_ms: int
    position_ned_m: list[list[float]]
    velocity_ned_m_s: list[list[float]]
    euler_rad: list[list[float]]
    rates_rad_s: list[list[float]]
    #: the same values as arrays (N, 3) each, in that order (None: made from the lists), for the
    #: telemetry of every vehicle at once (sitl_sim/mavlink_edge/telemetry_out.py)
    arrays: tuple[FloatArray, FloatArray, FloatArray, FloatArray] | None = None

    def columns(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Position, velocity, attitude and rates of every vehicle, (N, 3) arrays each."""
        if self.arrays is not None:
            return self.arrays
        return tuple(  # type: ignore[return-value]
            np.array(v, dtype=np.float64).reshape(-1, 3)
            for v in (self.position_ned_m, self.velocity_ned_m_s, self.euler_rad, self.rates_rad_s)
        )


class World:
    """N vehicles, their autopilots and simulated time."""

    def __init__(
        self,
        params: VehicleParams,
        gains: FleetAttitudeGains,
        positions_ned_m: FloatArray,
        yaw_rad: FloatArray,
        config: WorldConfig,
        rng: np.random.Generator,
    ) -> None:
        self.config = config.validate()
        self.params = params
        self.gains = gains
        self.rng = rng
        self.state = initial_state(positions_ned_m, yaw_rad)
        self.n = self.state.shape[1]
        #: where each vehicle started (N, 3) NED m
        self.start_ned_m: FloatArray = self.state[POS].T.copy()
        self.substeps = config.physics_hz // config.control_hz
        self.dt_physics_s = 1.0 / config.physics_hz
        self.autopilot, self.guidance = _flight_core(
            config, self.n, np.asarray(yaw_rad, float), params, self.dt_physics_s
        )
        #: a period whose command is steady (:attr:`Guidance.steady`) runs its physics steps in
        #: one kernel call (the same numbers as one call each); PX4's guidance only (ArduCopter's
        #: commands depend on the state in more ways: sitl_sim/vehicle/copter.py)
        self._fused = config.dialect == Dialect.PX4
        self.tick = 0
        #: rotor speeds (4, N) rad/s of the last physics step (0 before the first): as commanded,
        #: or where the motors lag, the speeds they reached (the next step starts from them)
        self.rotor_speed_rad_s = np.zeros((4, self.n))
        #: the physics sub-step (inner loop + RK4 + contact), fused
        scales = config.vehicle_scales
        if scales and len(scales) != self.n:
            raise ValueError(f"vehicle_scales: {len(scales)} vehicles' factors for {self.n}")
        #: each vehicle's true parameters (its autopilot knows only the nominal ``params``)
        self.fleet = [params.scaled(*f) for f in scales] if scales else [params] * self.n
        self.kernel = PhysicsKernel(
            params, self.n, self.dt_physics_s, gains, self.fleet if scales else None
        )
        self._thrust_coeff = np.array([v.thrust_coeff for v in self.fleet])
        #: the air the vehicles fly in (None: still air), sampled where each one is every period
        self.wind = None if config.air.calm else WindField(config.air, config.air_seed)
        self.battery = Battery(self.n, config.battery)
        #: what each vehicle's autopilot believes about itself (None: the truth, ideal sensors)
        self.estimator = (
            None
            if config.sensors.ideal
            else StateEstimate(
                config.sensors,
                self.n,
                config.control_hz,
                config.sensors_seed,
                range(config.first_vehicle, config.first_vehicle + self.n),
            )
        )
        self._estimate: tuple[FloatArray, FloatArray, FloatArray] | None = None
        self._estimate_now()
        self._crashes = sorted(config.crashes)
        self.pending_events: list[VehicleEvent] = self.autopilot.update(
            0.0, self.state[2], np.zeros(self.n)
        )

    @property
    def t_s(self) -> float:
        """Simulated time (s) of the current tick."""
        return self.tick / self.config.control_hz

    def time_boot_ms(self, tick: int | None = None) -> int:
        """``time_boot_ms`` stamped on the telemetry of ``tick`` (default: the current one)."""
        return round((self.tick if tick is None else tick) * 1000 / self.config.control_hz)

    def tick_of_ms(self, time_boot_ms: int) -> int | None:
        """The tick whose telemetry carries ``time_boot_ms``, None if no tick does."""
        tick = round(time_boot_ms * self.config.control_hz / 1000)
        return tick if self.time_boot_ms(tick) == time_boot_ms else None

    def step(self) -> list[VehicleEvent]:
        """Advance one control period; the events of the period (plus any pending ones)."""
        ap, kernel = self.autopilot, self.kernel
        self.guidance.prepare(self.state)
        kernel.use_gains(self.gains.kp_col(), self.gains.kd_col())
        if self.wind is not None:  # the air where each vehicle is, held over the period
            kernel.use_air(self.wind.at(self.state[POS], self.t_s))
        enable = ap.armed & ap.motor_ok  # (4, N): disarmed vehicles and dead motors stopped
        impact = np.zeros(self.n)
        state, rotor = self.state, self.rotor_speed_rad_s
        if self._fused and self.guidance.steady:  # one command for the period: one kernel call
            euler, thrust = self.guidance.command(state)
            state, rotor, touchdowns = kernel.substeps(
                state, euler, thrust, enable, self.substeps, rotor
            )
            for touchdown in touchdowns:
                np.maximum(impact, touchdown, out=impact)
        else:
            for _ in range(self.substeps):
                euler, thrust = self.guidance.command(state)
                state, rotor, touched = kernel.substep(state, euler, thrust, enable, rotor)
                if touched is not None:
                    np.maximum(impact, touched, out=impact)
        self.rotor_speed_rad_s = rotor
        self.state = state
        thrust_n = self._thrust_coeff * np.einsum("rn,rn->n", rotor, rotor)
        self.battery.drain(ap.armed, thrust_n, 1.0 / self.config.control_hz)
        self.tick += 1
        events, self.pending_events = self.pending_events, []
        events += ap.update(self.t_s, state[2], impact)
        while self._crashes and self._crashes[0][0] <= self.t_s + 1e-9:
            _, vehicle = self._crashes.pop(0)
            events += ap.motor_failure(vehicle, None, off=True)
        self._estimate_now()
        return events

    def _estimate_now(self) -> None:
        """The vehicles' state estimate of the current tick (once a tick, in tick order)."""
        if self.estimator is not None:
            state = self.state
            self._estimate = self.estimator.update(
                self.tick, state[POS], state[VEL], euler_from_quat_batch(state[QUAT])
            )

    def estimate(self) -> tuple[FloatArray, FloatArray, FloatArray] | None:
        """What the vehicles' autopilots believe at the current tick: position (3, N) NED m,
        velocity (3, N) NED m/s and (roll, pitch, yaw) (3, N) rad, as their telemetry reports it;
        None when their sensors are ideal (the estimate is the true state)."""
        return self._estimate

    def snapshot(self) -> Snapshot:
        """Telemetry of the current tick: the vehicles' state estimates (their true state with
        ideal sensors), plus the position noise of ``config.position_noise_m`` (drawn here)."""
        estimate = self._estimate
        if estimate is None:
            pos, vel = self.state[POS], self.state[VEL]
            euler = euler_from_quat_batch(self.state[QUAT])
        else:
            pos, vel, euler = estimate
        if self.config.position_noise_m > 0.0:
            pos = pos + self.rng.normal(0.0, self.config.position_noise_m, pos.shape)
        arrays = (pos.T, vel.T, euler.T, self.state[RATES].T)
        return Snapshot(
            tick=self.tick,
            time_boot_ms=self.time_boot_ms(),
            position_ned_m=arrays[0].tolist(),
            velocity_ned_m_s=arrays[1].tolist(),
            euler_rad=arrays[2].tolist(),
            rates_rad_s=arrays[3].tolist(),
            arrays=tuple(np.array(a, dtype=np.float64) for a in arrays),  # type: ignore[arg-type]
        )

    def commanded(self) -> tuple[FloatArray, FloatArray]:
        """The attitude (3, N) ZYX rad and normalised thrust (N,) last given to the inner loop."""
        return self.guidance.euler_rad, self.guidance.thrust


def _flight_core(
    config: WorldConfig, n: int, yaw_rad: FloatArray, params: VehicleParams, dt_s: float
) -> tuple[Autopilot, Guidance]:
    """The autopilots and guidance of ``config.dialect``'s firmware (chosen here, once)."""
    hover = params.hover_thrust_n / params.max_thrust_n
    if config.dialect == Dialect.ARDUPILOT:
        copter = CopterAutopilot(n, config.autopilot, yaw_rad, hover, config.ekf_ready_s)
        return copter, CopterGuidance(copter, hover, dt_s)
    autopilot = Autopilot(n, config.autopilot, yaw_rad)
    return autopilot, Guidance(autopilot, hover)

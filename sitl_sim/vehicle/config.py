"""Vehicle parameters, inner-loop gains, the air, how the vehicles differ and what their state
estimates get wrong, from a scenario's [vehicle], [gains], [environment], [vehicles] and [sensors]
sections."""

from __future__ import annotations

import dataclasses

from protocols.model.frames import G_M_S2
from protocols.scenario.scenario_file import Scenario
from sitl_sim.physics.attitude_control import AttitudeGains
from sitl_sim.physics.vehicle_params import VehicleParams
from sitl_sim.physics.vehicle_params import vehicle_scales as draw_scales
from sitl_sim.physics.wind import Air
from sitl_sim.vehicle.estimate import Sensors


def vehicle_params(scenario: Scenario) -> VehicleParams:
    """The motor model follows from the thrust-to-weight ratio and the top rotor speed:
    ``c = T/W m g / (4 w_max^2)``, ``a = (yaw moment per thrust) c / D``."""
    v = scenario.vehicle
    c = v.thrust_to_weight * v.mass_kg * G_M_S2 / (4.0 * v.rotor_speed_max_rad_s**2)
    return VehicleParams(
        mass_kg=v.mass_kg,
        ixx=v.ixx,
        iyy=v.iyy,
        izz=v.izz,
        arm_m=v.arm_m,
        thrust_coeff=c,
        drag_coeff=v.yaw_moment_per_thrust_m * c / v.arm_m,
        rotor_speed_max_rad_s=v.rotor_speed_max_rad_s,
        body_drag_xy_n_s_m=v.drag_xy_per_s * v.mass_kg,
        body_drag_z_n_s_m=v.drag_z_per_s * v.mass_kg,
        motor_tau_s=v.motor_tau_s,
    ).validate()


def attitude_gains(scenario: Scenario) -> AttitudeGains:
    """The attitude PD of the vehicles' inner loop."""
    g = scenario.gains
    return AttitudeGains(kp=g.attitude_kp, kd=g.attitude_kd).validate()


def air(scenario: Scenario) -> Air:
    """The wind and turbulence the vehicles fly in."""
    e = scenario.environment
    return Air(e.wind_ned_m_s, e.turbulence_m_s, e.turbulence_scale_m).validate()


def sensors(scenario: Scenario) -> Sensors:
    """What the vehicles' state estimates get wrong (the default: nothing)."""
    return Sensors(**dataclasses.asdict(scenario.sensors)).validate()  # the section's fields


def vehicle_scales(scenario: Scenario) -> tuple[tuple[float, ...], ...]:
    """Each of the scenario's vehicles' (mass, thrust) factors, and its motors' time constant
    factor third where the motors lag and their time constants differ (empty: all alike)."""
    f = scenario.vehicles
    tau_spread = f.motor_tau_spread if scenario.vehicle.motor_tau_s > 0.0 else 0.0
    return draw_scales(scenario.n_drones, f.mass_spread, f.thrust_spread, scenario.seed, tau_spread)

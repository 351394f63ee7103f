"""An agent's configuration from a scenario's [gains], [consensus], [rates], [safety], [sensors]
and [agent] sections."""

from __future__ import annotations

import math

from drone_agent.core.agent_core import AgentConfig
from drone_agent.core.consensus.scalar import ConsensusParams
from drone_agent.core.controller import ControllerSetup
from drone_agent.core.controller_load import check_controller, controller_class
from drone_agent.core.cooperative import CooperativeGains
from drone_agent.core.separation.layer import SeparationConfig
from drone_agent.core.thrust_attitude import ThrustLimits
from protocols.model.frames import G_M_S2
from protocols.scenario.scenario_file import Scenario


def agent_config(scenario: Scenario) -> AgentConfig:
    """Gains, limits, consensus parameters and the controller every agent of the scenario uses.

    Raises:
        ControllerError: the scenario's ``[agent] controller`` cannot fly
            (drone_agent/core/controller_load.py): one line naming the file and the field.
    """
    g, c, v = scenario.gains, scenario.consensus, scenario.vehicle
    consensus = ConsensusParams(
        rho=c.rho,
        c=c.c,
        f=c.f,
        dt_s=scenario.rates.dt_control_s,
        degree_normalised=c.degree_normalised,
        heard_timeout_ticks=c.heard_timeout_ticks,
        history_ticks=max(25, c.heard_timeout_ticks + c.delay_ticks + 5),
        max_step_gain=c.max_step_gain,
        channel_scale_m=c.channel_scale_m,
    )
    gains = CooperativeGains(
        kp=tuple(g.kp),
        kd=tuple(g.kd),
        flat_kp=g.flat_kp,
        flat_kd=g.flat_kd,
        null_damping_per_s=g.null_damping_per_s,
        min_variance_m2=g.min_variance_m2,
        orientation_kp=g.orientation_kp,
        orientation_kd=g.orientation_kd,
        orientation_max_speed_m_s=g.orientation_max_speed_m_s,
        orientation_max_accel_m_s2=g.orientation_max_accel_m_s2,
    )
    limits = ThrustLimits(
        mass_kg=v.mass_kg,
        max_thrust_n=v.thrust_to_weight * v.mass_kg * G_M_S2,
        min_thrust_ratio=g.min_thrust_ratio,
        max_thrust_ratio=g.max_thrust_ratio,
        max_tilt_rad=math.radians(g.max_tilt_deg),
    )
    safety = scenario.safety
    separation = SeparationConfig(
        min_separation_m=safety.min_separation_m,
        geofence_m=safety.geofence_m,
        ceiling_m=safety.ceiling_m,
    )
    cls = controller_class(scenario)
    options = scenario.agent.options
    if scenario.agent.controller is not None:  # a user's: built and tried once, before flying
        check_controller(
            scenario, cls, ControllerSetup(gains, limits, consensus.dt_s, dict(options))
        )
    return AgentConfig(
        consensus=consensus,
        gains=gains,
        limits=limits,
        warmup_s=c.warmup_s,
        settle_plateau=c.settle == "plateau" or (c.settle == "auto" and scenario.sensors.lie),
        settle_window_ticks=max(1, round(1.0 / scenario.rates.dt_control_s)),  # 1 s
        separation=separation,
        controller=cls,
        controller_options=options,
    )

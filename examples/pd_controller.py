"""A plain PD formation controller, flown in place of the paper's by naming it in a scenario:

    [agent]
    controller = "pd_controller:PDFormation"   # this file, beside the scenario
    options = { kp = 1.0, kd = 1.8 }            # optional (these are the defaults)

Each drone maps its offset from its estimate of the swarm's centre onto the planned formation
(whitened by the estimated covariance Sigma, then scaled by the planned spreads along the plan's
axes) and flies to that slot with a PD, the plan's centre acceleration fed forward::

    target_i = mu_d + R_d S_d^1/2 R_d^T Sigma^-1/2 (x_i - mu)
    a_i      = mu_d'' + kp (target_i - x_i) + kd (mu_d' - v_i)

The slots of the whole swarm have exactly the planned centre and covariance, whatever the
lattice looks like. A commanded-flat axis (variance 0) puts every slot in the plane. Thrust and
attitude: the base class's mapping (the paper's, with the scenario's limits).
"""

from __future__ import annotations

import numpy as np

from drone_agent.core.controller import Controller, ControllerInputs, ControllerSetup
from protocols.model.descriptor_vector import CENTRE, SHAPE
from protocols.model.frames import FloatArray

#: Estimated variances below this (m^2) count as this much: a flat swarm's height.
MIN_VARIANCE_M2 = 0.05


class PDFormation(Controller):
    """PD to each drone's slot in the planned formation (module doc)."""

    def __init__(self, setup: ControllerSetup) -> None:
        super().__init__(setup)
        self.kp = float(setup.options.get("kp", 1.0))  # 1/s^2
        self.kd = float(setup.options.get("kd", 1.8))  # 1/s: damping 0.9 at kp = 1

    def acceleration(self, inputs: ControllerInputs) -> FloatArray:
        x, v, axes, plan_axes = (
            inputs.position_ned_m,
            inputs.velocity_ned_m_s,
            inputs.axes,
            inputs.plan_axes,
        )
        offset = x - inputs.estimate.centre_ned_m
        # whitened: Sigma^-1/2 p, the symmetric root (no turn, even where two variances tie)
        spread = np.sqrt(np.maximum(inputs.variances_m2, MIN_VARIANCE_M2))
        white = np.einsum("kij,kj->ki", axes, np.einsum("kji,kj->ki", axes, offset) / spread)
        # coloured in the plan's axes: R_d sqrt(S_d) R_d^T
        in_plan = np.einsum("kji,kj->ki", plan_axes, white)
        planned = np.sqrt(np.maximum(inputs.plan[:, SHAPE], 0.0)) * in_plan
        slot = inputs.plan[:, CENTRE] + np.einsum("kij,kj->ki", plan_axes, planned)
        return (
            inputs.plan_accel[:, CENTRE]
            + self.kp * (slot - x)
            + self.kd * (inputs.plan_rate[:, CENTRE] - v)
        )

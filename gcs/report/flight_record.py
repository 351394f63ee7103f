"""The record of one flight: what the in-process reference flight (and later the ground station)
collects at the control rate, and what metrics, plots and logs are made from.

Arrays are sampled at the times ``t_s`` (T,); N is the number of drones in the scenario (index i has
MAVLink system id i + 1). Descriptor vectors follow protocols.model.descriptor_vector order.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from protocols.scenario.scenario_file import LinkCut, Scenario

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class LinkFault:
    """A link cut between drones ``i`` and ``j`` over ``[t0_s, t1_s)``; ``one_way``: only i -> j."""

    t0_s: float
    t1_s: float
    i: int
    j: int
    one_way: bool = False


@dataclass
class FlightRecord:
    """Time series of a flight.

    - ``t_s`` (T,): simulated time, s.
    - ``position_ned_m`` (T, N, 3), ``velocity_ned_m_s`` (T, N, 3).
    - ``euler_rad`` (T, N, 3): roll, pitch, yaw of each vehicle.
    - ``thrust_n`` (T, N): collective thrust; ``moments_nm`` (T, N, 3): roll, pitch, yaw moments.
    - ``desired`` (T, 9): the commanded descriptors a_d(t).
    - ``estimate`` (T, N, 9): each agent's estimate of the descriptors (NaN while it is not alive).
    - ``member`` (T, N): the drone counts as part of the swarm (its agent alive, vehicle not lost).
    - ``airborne`` (T, N): the vehicle is off the ground.
    - ``neighbours`` (T, N): number of neighbours each agent integrates with.
    - ``armed`` (T, N): the vehicle is armed; ``body_rates_rad_s`` (T, N, 3): p, q, r.
    - ``lost_at_s``: drones lost by the end and when; ``returns``: (drone, left s, back s) for
      each absence a drone came back from (its agent restarted).
    - ``neighbour_ids``: sample index k -> {drone: the neighbours whose messages its agent
      integrated at k}, only at the samples where they were kept (``swarm simulate``: those of
      its status stride; empty when not kept), for live agents.
    - ``reported``: where the vehicles' state estimates are not the truth (a scenario's
      [sensors]), what their telemetry reported: position, velocity and (roll, pitch, yaw),
      (T, N, 3) each (None: the truth above); ``quat_wxyz`` (T, N, 4) then the true attitude.
    """

    t_s: FloatArray
    position_ned_m: FloatArray
    velocity_ned_m_s: FloatArray
    euler_rad: FloatArray
    thrust_n: FloatArray
    moments_nm: FloatArray
    desired: FloatArray
    estimate: FloatArray
    member: BoolArray
    airborne: BoolArray
    neighbours: npt.NDArray[np.int_]
    link_faults: list[LinkFault] = field(default_factory=list)
    lost_at_s: dict[int, float] = field(default_factory=dict)
    armed: BoolArray | None = None
    body_rates_rad_s: FloatArray | None = None
    returns: list[tuple[int, float, float]] = field(default_factory=list)
    neighbour_ids: dict[int, dict[int, tuple[int, ...]]] = field(default_factory=dict)
    reported: tuple[FloatArray, FloatArray, FloatArray] | None = None
    quat_wxyz: FloatArray | None = None

    @property
    def n_drones(self) -> int:
        return int(self.position_ned_m.shape[1])


def scenario_link_cuts(scenario: Scenario) -> list[LinkFault]:
    """The link cuts of the scenario, for shading plots."""
    return [
        LinkFault(
            f.t_s,
            f.t_s + (f.duration_s or scenario.duration_s - f.t_s),
            f.i,
            f.j,
            f.one_way,
        )
        for f in scenario.faults
        if isinstance(f, LinkCut)
    ]

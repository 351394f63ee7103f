"""The separation layer of K agents at run time: each agent's view of where its neighbours are,
kept from the consensus messages it hears, and the filter of drone_agent/separation.py applied to
its commanded acceleration. Pure and I/O-free; state per agent, as the estimator's.

Each agent keeps the newest consensus message of every sender it heard (its position and
velocity ride on the message, wire schema 2) and, each tick, hands the filter those at most
``max_age_rounds`` old, extrapolated to now at their velocity (drone_agent/neighbours.py). What
an agent's own message must carry for its neighbours (its position and velocity of the tick) is
set by the core.

The filter keeps ``[safety] min_separation_m`` (plus its margin) from every neighbour heard, an
altitude floor for drones already above it (0.5 m: below the 1 m where a landing swarm is handed
to the autopilot's LAND mode, so the floor never fights a landing) and the geofence of
``[safety]``. Reciprocal: each agent of a pair takes half; far from everyone it returns the
command unchanged, bit for bit.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from drone_agent.consensus import ConsensusMessage
from drone_agent.neighbours import latest_by_sender, neighbour_arrays, neighbours_from_inbox
from drone_agent.separation import (
    AccelBox,
    SeparationParams,
    SeparationResult,
    filter_accelerations,
)
from drone_agent.thrust_attitude import ThrustLimits
from protocols.frames import FloatArray


@dataclass(frozen=True)
class SeparationConfig:
    """What the layer needs: the minimum separation (m), the geofence (north and east within
    ``± geofence_m``, altitude up to ``ceiling_m``), the altitude floor (m; None: off), and
    ``enabled`` (False: commands pass unfiltered, for comparisons)."""

    min_separation_m: float = 1.0
    geofence_m: float = 1000.0
    ceiling_m: float = 60.0
    floor_m: float | None = 0.5
    enabled: bool = True

    def params(self, limits: ThrustLimits) -> SeparationParams:
        """The filter's parameters for a vehicle of ``limits``."""
        fence = (-self.geofence_m, self.geofence_m)
        params = SeparationParams(
            min_separation_m=self.min_separation_m,
            floor_m=self.floor_m,
            fence_north_m=fence,
            fence_east_m=fence,
            ceiling_m=self.ceiling_m,
            accel=AccelBox.from_thrust_limits(limits),
        )
        params.validate()
        return params


class SeparationLayer:
    """The layer of the agents ``ids`` (one row each, the order of every call)."""

    def __init__(
        self,
        config: SeparationConfig,
        limits: ThrustLimits,
        dt_s: float,
        max_age_rounds: int,
    ) -> None:
        self.config = config
        self.params = config.params(limits)
        self.dt_s = dt_s
        self.max_age_rounds = max_age_rounds
        self._heard: dict[int, dict[int, ConsensusMessage]] = {}
        #: ticks in which the filter changed each agent's command
        self.active_ticks: dict[int, int] = {}

    def filter(
        self,
        ids: Sequence[int],
        round_: int,
        positions_ned_m: FloatArray,
        velocities_ned_m_s: FloatArray,
        accel_ned_m_s2: FloatArray,
        inboxes: Sequence[Iterable[ConsensusMessage]],
        common_accel_ned_m_s2: FloatArray | None = None,
    ) -> SeparationResult:
        """Filter the commanded accelerations (K, 3) of agents ``ids`` at round ``round_``, from
        their positions and velocities (K, 3) and the messages each heard this tick (which also
        update its view of the neighbours). ``common_accel_ned_m_s2``: the plan's centre
        acceleration, the same for every agent (the filter's reference)."""
        per_agent = []
        for i, inbox in zip(ids, inboxes, strict=True):
            heard = latest_by_sender(self._heard.get(i, {}), inbox)
            stale = round_ - self.max_age_rounds
            self._heard[i] = {j: m for j, m in heard.items() if m.round >= stale}
            per_agent.append(
                neighbours_from_inbox(
                    self._heard[i].values(), i, round_, self.dt_s, self.max_age_rounds
                )
            )
        nb_pos, nb_vel, mask, _ = neighbour_arrays(per_agent)
        accel = np.asarray(accel_ned_m_s2, dtype=float).reshape(-1, 3)
        if not self.config.enabled:
            k = accel.shape[0]
            none = np.zeros(k, dtype=bool)
            return SeparationResult(
                accel, none, np.full(k, np.inf), np.zeros(k, dtype=np.intp), none, none, none, none
            )
        result = filter_accelerations(
            positions_ned_m,
            velocities_ned_m_s,
            accel,
            nb_pos,
            nb_vel,
            mask,
            self.params,
            common_accel_ned_m_s2=common_accel_ned_m_s2,
        )
        for row in np.flatnonzero(result.active).tolist():
            agent = ids[row]
            self.active_ticks[agent] = self.active_ticks.get(agent, 0) + 1
        return result

    def forget(self, agent: int) -> None:
        """Drop an agent's state (it left)."""
        self._heard.pop(agent, None)

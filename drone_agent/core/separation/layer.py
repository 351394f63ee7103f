"""The separation layer of K agents at run time: each agent's view of where its neighbours are,
kept from the consensus messages it hears, and the filter of drone_agent/core/separation/filter.py
applied to its commanded acceleration. Pure and I/O-free; state per agent, as the estimator's.

Each agent keeps the position, velocity and round of the newest consensus message of every
sender it heard (they ride on the message, wire schema 2) and, each tick, hands the filter those
at most ``max_age_rounds`` old, extrapolated to now at their velocity (the rule and its one
implementation: drone_agent/core/neighbours.py). What an agent's own message must carry for its
neighbours (its position and velocity of the tick) is set by the core.

Cheap when nobody is near: a pre-check (``separation.nobody_near``: each barrier bounded over
the direction it acts in, a few array operations over the heard pairs) clears the agents whose
command every barrier surely leaves alone, and only the others go through the filter. Exact:
a cleared agent's command is the one the filter would return (unchanged, bit for bit).

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

from drone_agent.core.neighbours import NeighbourTable
from drone_agent.core.separation.filter import (
    AccelBox,
    SeparationParams,
    SeparationResult,
    filter_accelerations,
    nobody_near,
)
from drone_agent.core.thrust_attitude import ThrustLimits
from protocols.model.frames import FloatArray
from protocols.wire.consensus_message import ConsensusMessage


@dataclass(frozen=True)
class SeparationConfig:
    """What the layer needs: the minimum separation (m), the geofence (north and east within
    ``± geofence_m``, altitude up to ``ceiling_m``) and the altitude floor (m; None: off). No
    separation layer at all: ``AgentConfig.separation`` None."""

    min_separation_m: float = 1.0
    geofence_m: float = 1000.0
    ceiling_m: float = 60.0
    floor_m: float | None = 0.5

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
    """The layer of a batch of agents: what each agent last heard of each sender
    (:class:`~drone_agent.core.neighbours.NeighbourTable`) and the filter."""

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
        self.table = NeighbourTable(dt_s, max_age_rounds)

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
        update its view of the neighbours: drone_agent/core/neighbours.py).
        ``common_accel_ned_m_s2``: the plan's centre acceleration, the same for every agent
        (the filter's reference).

        The agents the cheap exact pre-check
        (:func:`~drone_agent.core.separation.filter.nobody_near`) clears keep their command, bit for
        bit, as the filter would; only the others go through the filter (its rows are
        independent)."""
        self.table.hear(ids, round_, inboxes)
        pairs = self.table.query(ids, round_)
        x = np.asarray(positions_ned_m, dtype=float).reshape(-1, 3)
        v = np.asarray(velocities_ned_m_s, dtype=float).reshape(-1, 3)
        accel = np.asarray(accel_ned_m_s2, dtype=float).reshape(-1, 3)
        k = accel.shape[0]
        common: FloatArray | None = None
        if common_accel_ned_m_s2 is not None:
            common = np.asarray(common_accel_ned_m_s2, dtype=float)
            if common.shape != (k, 3):  # (the usual (K, 3) as it is: broadcast_to is slow)
                common = np.broadcast_to(common, (k, 3))
        sure, closest = nobody_near(
            x, v, accel, pairs.owner, pairs.position_ned_m, pairs.velocity_ned_m_s, self.params,
            common,
        )  # fmt: skip
        no = np.zeros(k, dtype=bool)
        result = SeparationResult(
            accel_ned_m_s2=accel.copy(),
            active=no,
            closest_m=closest,
            n_constraints=np.zeros(k, dtype=np.intp),
            separation=no.copy(),
            floor=no.copy(),
            fence=no.copy(),
            infeasible=no.copy(),
        )
        if sure.all():
            return result
        unsure = np.flatnonzero(~sure)
        nb_pos, nb_vel, mask, _ = pairs.padded(unsure)
        filtered = filter_accelerations(
            x[unsure],
            v[unsure],
            accel[unsure],
            nb_pos,
            nb_vel,
            mask,
            self.params,
            common_accel_ned_m_s2=None if common is None else common[unsure],
        )
        for name in ("accel_ned_m_s2", "active", "closest_m", "n_constraints", "separation",
                     "floor", "fence", "infeasible"):  # fmt: skip
            getattr(result, name)[unsure] = getattr(filtered, name)
        return result

"""The separation layer of K agents at run time: each agent's view of where its neighbours are,
kept from the consensus messages it hears, and the filter of drone_agent/separation.py applied to
its commanded acceleration. Pure and I/O-free; state per agent, as the estimator's.

Each agent keeps the position, velocity and round of the newest consensus message of every
sender it heard (they ride on the message, wire schema 2) and, each tick, hands the filter those
at most ``max_age_rounds`` old, extrapolated to now at their velocity (the rule of
drone_agent/neighbours.py, here as arrays over the batch for speed). What
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

from drone_agent.separation import (
    AccelBox,
    SeparationParams,
    SeparationResult,
    filter_accelerations,
)
from drone_agent.thrust_attitude import ThrustLimits
from protocols.consensus_message import ConsensusMessage
from protocols.frames import FloatArray
from protocols.mavlink_conventions import MAX_VEHICLES


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
    """The layer of a batch of agents: what each agent last heard of each sender (position,
    velocity and round, as arrays indexed by agent id and sender id) and the filter."""

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
        self._rows: dict[int, int] = {}  # agent id -> row of the arrays below
        self._pos = np.zeros((0, MAX_VEHICLES, 3))
        self._vel = np.zeros((0, MAX_VEHICLES, 3))
        self._round = np.zeros((0, MAX_VEHICLES), dtype=np.int64)

    def _row(self, agent: int) -> int:
        row = self._rows.get(agent)
        if row is None:
            row = self._rows[agent] = len(self._rows)
            grow = (1, MAX_VEHICLES)
            self._pos = np.concatenate([self._pos, np.zeros((*grow, 3))])
            self._vel = np.concatenate([self._vel, np.zeros((*grow, 3))])
            self._round = np.concatenate([self._round, np.full(grow, -(2**62), np.int64)])
        return row

    def _hear(self, rows: list[int], inboxes: Sequence[Iterable[ConsensusMessage]]) -> None:
        """File what the rows heard: per (row, sender) the newest message's motion."""
        who: list[int] = []
        senders: list[int] = []
        rounds: list[int] = []
        motion: list[FloatArray] = []
        for row, inbox in zip(rows, inboxes, strict=True):
            for msg in inbox:
                p, v = msg.position_ned_m, msg.velocity_ned_m_s
                if p is None or not 0 <= msg.sender < MAX_VEHICLES:
                    continue
                who.append(row)
                senders.append(msg.sender)
                rounds.append(msg.round)
                motion.append(p)
                motion.append(np.zeros(3) if v is None else v)
        if not who:
            return
        r, j, q = np.array(who), np.array(senders), np.array(rounds, dtype=np.int64)
        pv = np.array(motion, dtype=float).reshape(-1, 2, 3)
        order = np.argsort(q, kind="stable")  # older first: the newest is written last
        r, j, q, pv = r[order], j[order], q[order], pv[order]
        newer = q >= self._round[r, j]
        r, j, q, pv = r[newer], j[newer], q[newer], pv[newer]
        self._round[r, j] = q
        self._pos[r, j] = pv[:, 0]
        self._vel[r, j] = pv[:, 1]

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
        update its view of the neighbours: each sender's newest message at most
        ``max_age_rounds`` old, its position extrapolated to now at its velocity).
        ``common_accel_ned_m_s2``: the plan's centre acceleration, the same for every agent
        (the filter's reference)."""
        rows = [self._row(i) for i in ids]
        self._hear(rows, inboxes)
        accel = np.asarray(accel_ned_m_s2, dtype=float).reshape(-1, 3)
        k = accel.shape[0]
        age = round_ - self._round[rows]  # (K, MAX_VEHICLES)
        heard = (age >= 0) & (age <= self.max_age_rounds)
        heard[np.arange(k), np.asarray(ids, dtype=np.intp)] = False  # not oneself
        # compact each row's neighbours to the front: (K, M), M = the most any agent heard
        m = max(int(heard.sum(axis=1).max(initial=0)), 1)
        order = np.argsort(~heard, axis=1, kind="stable")[:, :m]
        pick = np.asarray(rows)[:, None], order
        mask = np.take_along_axis(heard, order, axis=1)
        vel = self._vel[pick]
        pos = (
            self._pos[pick] + vel * (np.take_along_axis(age, order, axis=1) * self.dt_s)[..., None]
        )
        result = filter_accelerations(
            positions_ned_m,
            velocities_ned_m_s,
            accel,
            np.where(mask[..., None], pos, 0.0),
            np.where(mask[..., None], vel, 0.0),
            mask,
            self.params,
            common_accel_ned_m_s2=common_accel_ned_m_s2,
        )
        return result

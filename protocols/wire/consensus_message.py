"""The consensus message: what an agent sends its radio neighbours every round (ALGORITHM.md §3).

Defined here, beside its wire encoding (:mod:`protocols.wire.format`), so that every side that
speaks it (the agents' estimator in :mod:`drone_agent.core.consensus.scalar`, the transports, the
in-process radio of ``swarm simulate``) imports it from the protocol rather than from one of its
users.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from protocols.model.frames import FloatArray


@dataclass(frozen=True)
class ConsensusMessage:
    """What an agent sends every round.

    ``gamma`` (18,): the sender's estimate in this round; ``edge_sums``: the running sums
    ``Q_sender,j`` of the sender's increments per neighbour j; ``heard``: who the sender heard
    recently (as of this round); ``degree``: ``len(heard)``, for the degree-normalised gain;
    ``ready_hops``: the sender's settled level (drone_agent.core.flight_phase.SwarmSettled).
    ``position_ned_m`` (3,) and ``velocity_ned_m_s`` (3,): where the sender was and how fast it
    moved in this round (NED), for the receivers' separation layer
    (drone_agent/core/separation/filter.py); None when not known (set by the wire decoder; the
    estimator does not use them). ``incarnation``: which life of the sender's agent sent it (the
    round of its first step; 0 from a sender that does not say); ``edge_incarnations``: per
    neighbour j of ``edge_sums``, the incarnation of j that ``Q_sender,j`` was made with (None: not
    said, every sum is taken). The rules: drone_agent/core/consensus/scalar.py, "incarnations".
    ``takeoff_round``: the control round at which the sender's swarm left the ground, as the
    sender knows it (drone_agent/core/flight_phase.py, TakeoffClock); None: the sender is not flying
    or does not say (a sender of an older build).
    """

    sender: int
    round: int
    gamma: FloatArray
    edge_sums: Mapping[int, FloatArray]
    heard: frozenset[int]
    degree: int
    ready_hops: int = 0
    position_ned_m: FloatArray | None = None
    velocity_ned_m_s: FloatArray | None = None
    incarnation: int = 0
    edge_incarnations: Mapping[int, int] | None = None
    takeoff_round: int | None = None


class EdgeIncarnations(Mapping[int, int]):
    """The partners' incarnations ``tags`` (E,) of an :class:`EdgeSums` over the same ``ids``:
    what :class:`BatchConsensus` puts in its messages' ``edge_incarnations``."""

    __slots__ = ("ids", "tags")

    def __init__(self, ids: npt.NDArray[np.intp], tags: npt.NDArray[np.int64]) -> None:
        self.ids = ids
        self.tags = tags

    def __getitem__(self, neighbour: int) -> int:
        hits = np.flatnonzero(self.ids == neighbour)
        if hits.shape[0] == 0:
            raise KeyError(neighbour)
        return int(self.tags[hits[0]])

    def __iter__(self) -> Iterator[int]:
        return iter(self.ids.tolist())

    def __len__(self) -> int:
        return int(self.ids.shape[0])

    def __repr__(self) -> str:
        return f"EdgeIncarnations({dict(self)!r})"


class EdgeSums(Mapping[int, FloatArray]):
    """``Q_sender,j`` (18,) per neighbour j as a read-only mapping over the rows of one array:
    ``ids`` (E,) the neighbours, ascending, and ``sums`` (E, 18) theirs. What
    :class:`BatchConsensus` puts in its messages' ``edge_sums``: made without a dict per
    message, and read by batched receivers as arrays (any Mapping works as well)."""

    __slots__ = ("_index", "ids", "sums")

    def __init__(self, ids: npt.NDArray[np.intp], sums: FloatArray) -> None:
        self.ids = ids
        self.sums = sums
        self._index: dict[int, int] | None = None

    def __getitem__(self, neighbour: int) -> FloatArray:
        if self._index is None:
            self._index = {j: k for k, j in enumerate(self.ids.tolist())}
        k = self._index.get(neighbour)
        if k is None:
            raise KeyError(neighbour)
        out: FloatArray = self.sums[k]
        return out

    def __iter__(self) -> Iterator[int]:
        return iter(self.ids.tolist())

    def __len__(self) -> int:
        return int(self.ids.shape[0])

    def __repr__(self) -> str:
        return f"EdgeSums({dict(self)!r})"

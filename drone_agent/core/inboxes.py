"""One tick's inboxes of a batch of agents, read once for everything that files them.

In one process a message reaches many agents: the consensus step
(drone_agent/core/consensus/estimator.py) and the separation layer's neighbour table
(drone_agent/core/neighbours.py) both file each distinct message object once, with the position of
every (row, message) value in it. :class:`Inboxes` finds them once a tick for both
(:func:`distinct_messages`, the one way of finding them). Pure.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence, Sized
from itertools import chain
from typing import TypeVar, overload

import numpy as np
import numpy.typing as npt

from protocols.wire.consensus_message import ConsensusMessage

_T = TypeVar("_T")


def distinct_messages(values: list[_T]) -> tuple[list[_T], npt.NDArray[np.intp]]:
    """Each distinct object of ``values`` once (by identity; in an order of no meaning, they are
    only indexed) and the index of each value's object among them (len(values),)."""
    if not values:
        return [], np.zeros(0, dtype=np.intp)
    ids = np.fromiter(map(id, values), np.int64, len(values))
    order = np.argsort(ids, kind="stable")
    first = np.empty(len(values), dtype=bool)
    first[0] = True
    first[1:] = ids[order[1:]] != ids[order[:-1]]
    which = np.empty(len(values), dtype=np.intp)
    which[order] = np.cumsum(first) - 1
    return [values[k] for k in order[first].tolist()], which


class Inboxes(Sequence[list[ConsensusMessage]]):
    """The inboxes of a batch's rows (one list each, in row order; a sequence of them), with
    their values as one list (``flat``, row after row; ``counts`` per row) and, found when
    first asked (:meth:`distinct`), each distinct message with the senders and rounds of them.
    ``distinct``: those already known to whoever filled the inboxes (as :meth:`distinct` gives
    them, in any order: every message of ``flat`` once, and the index of each value's)."""

    def __init__(
        self,
        inboxes: Iterable[Iterable[ConsensusMessage]],
        distinct: tuple[list[ConsensusMessage], npt.NDArray[np.intp]] | None = None,
    ) -> None:
        self.lists = [box if isinstance(box, list) else list(box) for box in inboxes]
        self.flat: list[ConsensusMessage] = list(chain.from_iterable(self.lists))
        self.counts = [len(box) for box in self.lists]
        self._distinct = distinct
        self._senders_rounds: tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]] | None = None

    def distinct(self) -> tuple[list[ConsensusMessage], npt.NDArray[np.intp]]:
        """:func:`distinct_messages` of ``flat`` (found once)."""
        if self._distinct is None:
            self._distinct = distinct_messages(self.flat)
        return self._distinct

    def senders_rounds(self) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        """The sender and round (U,) of each distinct message (found once)."""
        if self._senders_rounds is None:
            messages = self.distinct()[0]
            self._senders_rounds = (
                np.array([m.sender for m in messages], dtype=np.int64),
                np.array([m.round for m in messages], dtype=np.int64),
            )
        return self._senders_rounds

    def __len__(self) -> int:
        return len(self.lists)

    @overload
    def __getitem__(self, index: int) -> list[ConsensusMessage]: ...

    @overload
    def __getitem__(self, index: slice) -> Sequence[list[ConsensusMessage]]: ...

    def __getitem__(
        self, index: int | slice
    ) -> list[ConsensusMessage] | Sequence[list[ConsensusMessage]]:
        return self.lists[index]

    def __iter__(self) -> Iterator[list[ConsensusMessage]]:
        return iter(self.lists)


def alone(
    inboxes: Sequence[Iterable[ConsensusMessage]],
    rows: Sequence[int],
    later: Sequence[Sized],
) -> Inboxes | None:
    """``inboxes`` when they are all there is to file for ``rows`` (an :class:`Inboxes` of one
    list per row, and no row has values ``later[row]`` waiting from an earlier call), else
    None: the caller files the lists with the waiting values itself."""
    if (
        isinstance(inboxes, Inboxes)
        and len(inboxes) == len(rows)
        and not any(later[row] for row in rows)
    ):
        return inboxes
    return None


def as_inboxes(inboxes: Sequence[Iterable[ConsensusMessage]]) -> Inboxes:
    """``inboxes`` as :class:`Inboxes` (itself if it is one)."""
    return inboxes if isinstance(inboxes, Inboxes) else Inboxes(inboxes)

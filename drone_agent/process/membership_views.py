"""One object per membership view in an agent process.

A process's agents mostly share one membership view (the same drones alive), tick after tick. The
batched core and readiness keep a mask per view object (drone_agent/core/consensus/estimator.py,
drone_agent/core/flight_phase.py), so each agent handing over a set of its own, equal to the
others', would have its mask built again every tick: at 125 agents per process of a 250-drone
swarm that was a sixth of the process's time. :class:`Views` hands out the process's one
frozenset for each view.
"""

from __future__ import annotations

from collections.abc import Iterable

#: Views kept at most (drop-outs and returns make new ones; older ones are let go beyond).
MAX_VIEWS = 256


class Views:
    """The frozenset of a process for each membership view it has seen (by content)."""

    def __init__(self) -> None:
        self._views: dict[frozenset[int], frozenset[int]] = {}

    def of(self, drones: Iterable[int]) -> frozenset[int]:
        """``drones`` as the one frozenset of the process for that view."""
        key = frozenset(drones)
        if len(self._views) > MAX_VIEWS:
            self._views.clear()
        return self._views.setdefault(key, key)

"""The garbage collector tuned for a flight: the in-process runner (``swarm simulate``), every
agent process (``swarm agent``) and the simulator (``swarm sim``) fly inside
:func:`flight_collector`.

A flight makes and drops thousands of small objects a tick (messages, setpoints, MAVLink
frames). With CPython's defaults the young generation is collected every 700 allocations, and
each full pass walks everything that outlives the flight (the scenario, the plan, the modules):
about a tenth of the tick at N = 100 in the in-process runner. Garbage is collected all the
same, in larger batches.
"""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager

#: Allocations between two young-generation passes of the garbage collector during a flight
#: (CPython's default is 700; each pass has a fixed cost of its own, about a tenth of a ms).
YOUNG_COLLECTION_EVERY = 5000


@contextmanager
def flight_collector() -> Iterator[None]:
    """The garbage collector tuned for a flight, as it was again after the block: the objects
    that exist now are left out of its passes (``gc.freeze``, unless some are frozen already),
    and its young-generation pass runs every :data:`YOUNG_COLLECTION_EVERY` allocations instead
    of 700."""
    thresholds = gc.get_threshold()
    freeze = gc.get_freeze_count() == 0
    if freeze:
        gc.freeze()
    gc.set_threshold(max(thresholds[0], YOUNG_COLLECTION_EVERY), *thresholds[1:])
    try:
        yield
    finally:
        gc.set_threshold(*thresholds)
        if freeze:
            gc.unfreeze()

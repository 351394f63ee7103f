"""quadswarm's Python API: bring a swarm up, command it, read its state and its report.

.. code-block:: python

    from gcs.api import Swarm

    with Swarm.start(drones=4) as swarm:          # swarm up --drones 4, on free ports
        swarm.takeoff(altitude_m=3).wait()         # returns once the plan says it is there
        swarm.move(north_m=2).wait()
        print(swarm.descriptors().true)
    report = swarm.report                          # the flight as arrays (load_report)
    print(report.positions_ned_m.shape, report.metrics()["tracking"]["centroid_m"])

- :class:`Swarm` (:meth:`Swarm.start`, :meth:`Swarm.connect`): commands with the ``swarm``
  command's names and semantics (takeoff, formation, move, rotate, scale, hold, land, shutdown,
  drill), each refused with :class:`CommandRefused` carrying the reason ``swarm`` prints;
  :meth:`Swarm.status`, :meth:`Swarm.descriptors`, :meth:`Swarm.subscribe`.
- :class:`AsyncSwarm`: the same, awaited.
- :func:`load_report`: a report folder as NumPy arrays (and pandas, with the ``pandas`` extra).
- The pytest plugin (:mod:`gcs.api.pytest_plugin`): a ``swarm`` fixture.

docs/api.md describes it all.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from gcs.api.aio import AsyncCommand, AsyncSwarm
    from gcs.api.errors import (
        CommandRefused,
        Failsafe,
        NoGroundStation,
        StartError,
        Superseded,
        SwarmError,
        UsageError,
        WaitTimeout,
    )
    from gcs.api.report import FlightReport, load_report
    from gcs.api.state import Descriptors, Status
    from gcs.api.swarm import Command, Drill, Swarm

#: Where each name lives: imported when first used, so that ``swarm takeoff`` (which imports
#: ``gcs.api.swarm`` alone) does not pay for asyncio or the report readers.
_HOMES = {
    "AsyncCommand": "aio", "AsyncSwarm": "aio",
    "CommandRefused": "errors", "Failsafe": "errors", "NoGroundStation": "errors",
    "StartError": "errors", "Superseded": "errors", "SwarmError": "errors",
    "UsageError": "errors", "WaitTimeout": "errors",
    "FlightReport": "report", "load_report": "report",
    "Descriptors": "state", "Status": "state",
    "Command": "swarm", "Drill": "swarm", "Swarm": "swarm",
}  # fmt: skip


def __getattr__(name: str) -> Any:
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module 'gcs.api' has no attribute {name!r}")
    return getattr(importlib.import_module(f"gcs.api.{home}"), name)


__all__ = [
    "AsyncCommand",
    "AsyncSwarm",
    "Command",
    "CommandRefused",
    "Descriptors",
    "Drill",
    "Failsafe",
    "FlightReport",
    "NoGroundStation",
    "StartError",
    "Status",
    "Superseded",
    "Swarm",
    "SwarmError",
    "UsageError",
    "WaitTimeout",
    "load_report",
]

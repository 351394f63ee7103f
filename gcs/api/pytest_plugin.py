"""quadswarm's pytest plugin (registered as ``quadswarm`` under the ``pytest11`` entry points):
the ``swarm`` fixture, a factory of swarms for a test.

.. code-block:: python

    def test_the_swarm_moves_north(swarm):
        with swarm(drones=4) as s:                 # swarm up --drones 4, free ports, lockstep
            s.takeoff(altitude_m=3).wait()
            s.move(north_m=2).wait()
        north = s.report.positions_ned_m[-1, :, 0]  # the report, read back on leaving the block
        assert abs(north.mean() - ...) < 0.1

Each call takes :meth:`gcs.api.Swarm.start`'s arguments (default: 4 drones, lockstep, the
report in the test's ``tmp_path``); every swarm a test started is ended when the test ends, as
leaving its ``with`` block does (a session lands, then the report is written). Importing this
module costs nothing: the API is imported when the fixture is used.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

if TYPE_CHECKING:
    from gcs.api.swarm import Swarm


@pytest.fixture
def swarm(tmp_path: Path) -> Iterator[Callable[..., Swarm]]:
    """A factory: ``swarm(scenario=None, drones=4, clock="lockstep", **kwargs)`` starts a swarm
    (:meth:`gcs.api.Swarm.start`) with its report in ``tmp_path/swarm-K``; all end with the test."""
    from gcs.api.swarm import Swarm

    started: list[Swarm] = []

    def start(scenario: str | Path | None = None, **kwargs: Any) -> Swarm:
        if scenario is None:
            kwargs.setdefault("drones", 4)
        kwargs.setdefault("clock", "lockstep")
        kwargs.setdefault("report", tmp_path / f"swarm-{len(started)}")
        one = Swarm.start(scenario, **kwargs)
        started.append(one)
        return one

    try:
        yield start
    finally:
        for one in started:
            one.close()

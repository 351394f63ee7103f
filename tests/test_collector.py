"""The garbage collector tuned for a flight (protocols/runtime/collector.py), shared by the
in-process runner, the agent processes and the simulator: tuned inside the block, as it was
after."""

from __future__ import annotations

import gc

from protocols.runtime.collector import YOUNG_COLLECTION_EVERY, flight_collector


def test_the_collector_is_tuned_inside_a_flight_and_as_it_was_after() -> None:
    before = gc.get_threshold()
    frozen_before = gc.get_freeze_count()
    with flight_collector():
        assert gc.get_threshold()[0] >= YOUNG_COLLECTION_EVERY
        assert gc.get_threshold()[1:] == before[1:]
        if frozen_before == 0:
            assert gc.get_freeze_count() > 0  # what exists now is left out of its passes
    assert gc.get_threshold() == before
    assert gc.get_freeze_count() == frozen_before

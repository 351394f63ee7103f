"""protocols.mavlink.conventions: the MAVLink values the project names are MAVLink's own."""

from __future__ import annotations

from enum import IntEnum

import pytest
from pymavlink.dialects.v20 import common

from protocols.mavlink.conventions import LOST_STATES, MavResult, MavSeverity, MavState


@pytest.mark.parametrize(
    "enum,prefix",
    [(MavState, "MAV_STATE_"), (MavSeverity, "MAV_SEVERITY_"), (MavResult, "MAV_RESULT_")],
)
def test_values_are_mavlinks(enum: type[IntEnum], prefix: str) -> None:
    for member in enum:
        assert getattr(common, prefix + member.name) == member.value


def test_a_vehicle_is_lost_when_crashed_or_terminated() -> None:
    assert 6 in LOST_STATES and 8 in LOST_STATES  # as the integers a HEARTBEAT carries
    assert MavState.CRITICAL not in LOST_STATES  # a failsafe: the vehicle still flies

"""Operator commands: request validation and their effect on the plan (pure, no network)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gcs.station.commands import (
    CommandError,
    Reply,
    Request,
    apply_command,
    decode_reply,
    encode_reply,
    encode_request,
    parse_request,
)
from gcs.station.planner import Envelope, PlanRefused
from protocols.model.trajectory import DescriptorTrajectory, Waypoint
from protocols.wire.plan import FlightCommand, PlanMessage

HOVER = np.array([2.0, 1.5, -2.0, 0.0, 0.0, 0.0, 4.0, 2.25, 0.0])


def _plan() -> PlanMessage:
    zero = np.zeros(9)
    traj = DescriptorTrajectory.from_waypoints(
        [Waypoint(0.0, HOVER, zero, zero), Waypoint(10.0, HOVER, zero, zero)]
    )
    return PlanMessage(traj, FlightCommand.FLY)


def test_requests_round_trip_and_replies_decode() -> None:
    request = Request("formation", {"heading_deg": 30.0, "centre_ned_m": [1.0, 2.0, -3.0]})
    assert parse_request(encode_request(request)) == request
    reply = Reply(True, "ok", 3, ({"drone": 0, "estimate_error_m": math.nan},))
    back = decode_reply(encode_reply(reply))
    assert back.accepted and back.seq == 3 and back.table[0]["estimate_error_m"] is None


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (None, "empty"),
        (b"\xff\xfe", "UTF-8 JSON"),
        (b"[1]", "JSON object"),
        (b'{"command": "hold"}', "version"),
        (b'{"version": 1, "command": "fly"}', "unknown command"),
        (b'{"version": 1, "command": "hold", "args": []}', "args"),
        (b'{"version": 1, "command": "move", "args": {"up": 1}}', "unknown argument"),
        (b'{"version": 1, "command": "scale", "args": {}}', "missing argument 'factor'"),
        (b'{"version": 1, "command": "rotate", "args": {"delta_deg": true}}', "finite number"),
        (b'{"version": 1, "command": "move", "args": {"up_m": 1e999}}', "finite number"),
        (b'{"version": 1, "command": "formation", "args": {"centre_ned_m": [1, 2]}}', "3 numbers"),
        (b"{" + b" " * 5000 + b"}", "exceeds"),
    ],
)
def test_malformed_requests_are_refused_with_a_reason(payload: bytes | None, reason: str) -> None:
    with pytest.raises(CommandError, match=reason):
        parse_request(payload)


def test_commands_make_the_next_plan_or_are_refused() -> None:
    current, env = _plan(), Envelope()
    turned = apply_command(
        parse_request(encode_request(Request("rotate", {"delta_deg": 30.0}))), current, 5.0, env
    )
    assert turned.seq == 1 and turned.command == FlightCommand.FLY
    end = turned.trajectory.evaluate(turned.trajectory.end_s)[0]
    assert math.degrees(end[5]) == pytest.approx(30.0)
    np.testing.assert_allclose(turned.trajectory.evaluate(5.0)[0], HOVER, atol=1e-9)
    scaled = apply_command(Request("scale", {"factor": 1.5}), current, 5.0, env)
    end = scaled.trajectory.evaluate(scaled.trajectory.end_s)[0]
    np.testing.assert_allclose(end[6:8], HOVER[6:8] * 2.25)
    moved = apply_command(Request("move", {"north_m": 3.0, "up_m": 1.0}), current, 5.0, env)
    end = moved.trajectory.evaluate(moved.trajectory.end_s)[0]
    np.testing.assert_allclose(end[:3], [5.0, 1.5, -3.0])
    landing = apply_command(Request("land", {}), current, 5.0, env)
    assert landing.command == FlightCommand.LAND and landing.seq == 1
    with pytest.raises(PlanRefused, match="take off first"):
        apply_command(Request("move", {"north_m": 1.0}), landing, 6.0, env)
    up = apply_command(Request("takeoff", {"altitude_m": 5.0}), landing, 6.0, env)
    assert up.command == FlightCommand.FLY
    with pytest.raises(PlanRefused, match="geofence"):
        apply_command(Request("move", {"north_m": 5000.0}), current, 5.0, env)
    with pytest.raises(PlanRefused, match="too fast"):
        apply_command(Request("rotate", {"delta_deg": 90.0, "duration_s": 0.5}), current, 5.0, env)
    with pytest.raises(PlanRefused, match="positive"):
        apply_command(Request("scale", {"factor": 0.0}), current, 5.0, env)


def test_land_twice_is_refused_and_hold_stops_a_descent_only_high_up() -> None:
    current, env = _plan(), Envelope()
    landing = apply_command(Request("land", {}), current, 5.0, env)
    with pytest.raises(PlanRefused, match="already landing"):
        apply_command(Request("land", {}), landing, 6.0, env)
    # early in the descent (still near the hover altitude): hold stops it and flies on
    held = apply_command(Request("hold", {}), landing, 6.0, env)
    assert held.command == FlightCommand.FLY
    assert held.trajectory.evaluate(held.trajectory.end_s)[0][2] < -1.5
    # near the ground: the vehicles are about to be handed to LAND, a hold is refused
    with pytest.raises(PlanRefused, match="touching down"):
        apply_command(Request("hold", {}), landing, landing.trajectory.end_s, env)

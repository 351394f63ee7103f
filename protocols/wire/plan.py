"""The plan message (Kind.PLAN): the shared descriptor trajectory and what the swarm should do.

Body after the common header (``protocols.wire.format``), little-endian::

    u32 seq              the trajectory's sequence number (a newer plan has a larger one)
    u8  command          FlightCommand: stay on the ground, fly, or land
    u16 n_knots K        K >= 2
    K x f64              knot times t_knots_s, s, strictly increasing
    (K-1) x 9 x 6 f64    quintic coefficients, segment-major, ascending powers (see
                         protocols.model.trajectory)

Everything is float64 so every drone evaluates the identical reference. Plans are larger than
the periodic messages (the paper's 77 knots: 33 KB), hence their own size limit.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from protocols.model.trajectory import N_COEFFS, N_DESCRIPTORS, DescriptorTrajectory
from protocols.wire.format import (
    MAX_U32,
    Kind,
    Reason,
    WireError,
    encode_header,
    expect_length,
    finite_block,
    open_payload,
)

MAX_PLAN_BYTES = 1024 * 1024
_FIXED = struct.Struct("<IBH")
_SEGMENT = N_DESCRIPTORS * N_COEFFS


#: Under a LAND plan the agents fly the formation down until the plan's commanded centre
#: altitude is at or below this (m), then hand their vehicles to the autopilot's LAND mode, which
#: sinks at its land speed (0.7 m/s by default), detects touchdown and disarms.
LAND_HANDOVER_ALTITUDE_M = 1.0


class FlightCommand(IntEnum):
    """What the plan tells the agents to do with their vehicles."""

    GROUND = 0  #: stay disarmed on the ground (consensus runs); airborne vehicles land
    FLY = 1  #: arm once converged and follow the trajectory
    #: follow the trajectory (gcs.station.planner.land: stop, level, descend) down to
    #: LAND_HANDOVER_ALTITUDE_M, then autopilot LAND: touchdown, disarm
    LAND = 2


_COMMANDS = frozenset(int(c) for c in FlightCommand)


@dataclass(frozen=True, eq=False)
class PlanMessage:
    """The plan: a trajectory (with its ``seq``) and the flight command."""

    trajectory: DescriptorTrajectory
    command: FlightCommand = FlightCommand.FLY

    def __post_init__(self) -> None:
        object.__setattr__(self, "command", FlightCommand(self.command))

    @property
    def seq(self) -> int:
        """Sequence number of the plan (its trajectory's)."""
        return self.trajectory.seq

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, PlanMessage):
            return NotImplemented
        a, b = self.trajectory, other.trajectory
        return (
            self.command == other.command
            and a.seq == b.seq
            and np.array_equal(a.t_knots_s, b.t_knots_s)
            and np.array_equal(a.coeffs, b.coeffs)
        )


def encode_plan(plan: PlanMessage, swarm_id: str, *, max_bytes: int = MAX_PLAN_BYTES) -> bytes:
    """The payload of ``plan`` for swarm ``swarm_id``; ValueError if its seq does not fit a u32,
    it has more than 65535 knots or the payload would exceed ``max_bytes``."""
    traj = plan.trajectory
    k = traj.t_knots_s.shape[0]
    if not 0 <= traj.seq <= MAX_U32 or k > 0xFFFF:
        raise ValueError(f"plan seq {traj.seq} or {k} knots do not fit the wire format")
    payload = b"".join(
        (
            encode_header(Kind.PLAN, swarm_id),
            _FIXED.pack(traj.seq, int(plan.command), k),
            finite_block(traj.t_knots_s, (k,), "t_knots_s"),
            finite_block(traj.coeffs, (k - 1, N_DESCRIPTORS, N_COEFFS), "coeffs"),
        )
    )
    if len(payload) > max_bytes:
        raise ValueError(f"plan payload of {len(payload)} bytes exceeds {max_bytes}")
    return payload


def decode_plan(data: bytes, swarm_id: str, *, max_bytes: int = MAX_PLAN_BYTES) -> PlanMessage:
    """Decode a plan payload of swarm ``swarm_id``; WireError for anything malformed, including
    a trajectory that is not valid (knots not increasing, fewer than 2)."""
    off = open_payload(data, Kind.PLAN, swarm_id, max_bytes)
    if len(data) < off + _FIXED.size:
        raise WireError(Reason.TRUNCATED, f"plan: {len(data)} bytes, shorter than its fields")
    seq, command, k = _FIXED.unpack_from(data, off)
    off += _FIXED.size
    if k < 2:
        raise WireError(Reason.BAD_VALUE, f"plan has {k} knots, needs at least 2")
    expect_length(data, off + 8 * (k + (k - 1) * _SEGMENT), "plan")
    floats = np.frombuffer(data, "<f8", k + (k - 1) * _SEGMENT, off)
    if not np.isfinite(floats).all():
        raise WireError(Reason.NOT_FINITE, "plan knots or coefficients are NaN or infinite")
    if command not in _COMMANDS:
        raise WireError(Reason.BAD_VALUE, f"plan command {command}")
    try:
        trajectory = DescriptorTrajectory(
            seq, floats[:k], floats[k:].reshape(k - 1, N_DESCRIPTORS, N_COEFFS)
        )
    except ValueError as exc:
        raise WireError(Reason.BAD_VALUE, f"plan trajectory: {exc}") from None
    return PlanMessage(trajectory, FlightCommand(command))

"""Where an agent's radio neighbours are, from the consensus messages it heard. Pure.

Every consensus message carries its sender's position and velocity (NED; wire schema 2, see
protocols/wire.py). An agent keeps the newest message of each sender (:func:`latest_by_sender`)
and, each tick, turns those heard recently into the neighbour arrays the separation layer takes
(drone_agent/separation.py): :func:`neighbours_from_inbox` for one agent,
:func:`neighbour_arrays` for K agents at once.

Staleness: a message ``age`` rounds old (``round_now - message.round``) is used only while
``age <= max_age_rounds`` (the consensus heard-set timeout, 5 ticks, by default): a neighbour not
heard for longer is as good as gone to the estimator too. Its position is extrapolated to now at
its sent velocity, ``p + v age dt``: with the normal one-tick delay a drone at 3 m/s is 6 cm
further on, after five lost ticks 30 cm, errors the separation margin should not have to absorb.
Velocities are held (no acceleration is sent). A sender of wire schema 1 sends no velocity: it is
taken at rest, not extrapolated, and flagged (``velocity_known`` False).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from protocols.consensus_message import ConsensusMessage
from protocols.frames import FloatArray

BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.intp]


@dataclass(frozen=True)
class Neighbours:
    """The neighbours of one agent at one round, sorted by id.

    ``ids`` (M,); ``position_ned_m`` (M, 3), extrapolated to the round; ``velocity_ned_m_s``
    (M, 3); ``age_rounds`` (M,) of the message used; ``velocity_known`` (M,)."""

    ids: tuple[int, ...]
    position_ned_m: FloatArray
    velocity_ned_m_s: FloatArray
    age_rounds: IntArray
    velocity_known: BoolArray

    def __len__(self) -> int:
        return len(self.ids)


def latest_by_sender(
    store: Mapping[int, ConsensusMessage], inbox: Iterable[ConsensusMessage]
) -> dict[int, ConsensusMessage]:
    """``store`` (sender -> newest message) updated with ``inbox``: a new dict, each sender's
    message with the largest round kept (the first of equal rounds)."""
    out = dict(store)
    for msg in inbox:
        old = out.get(msg.sender)
        if old is None or msg.round > old.round:
            out[msg.sender] = msg
    return out


def neighbours_from_inbox(
    messages: Iterable[ConsensusMessage],
    own: int,
    round_now: int,
    dt_s: float,
    max_age_rounds: int = 5,
    extrapolate: bool = True,
) -> Neighbours:
    """The neighbours of agent ``own`` at round ``round_now`` from ``messages`` (any number per
    sender, the newest used): senders other than ``own`` whose newest message has a position,
    is not from the future and at most ``max_age_rounds`` old; positions extrapolated by
    velocity x age x ``dt_s`` (the round period, s) unless ``extrapolate`` is False."""
    newest = latest_by_sender({}, (m for m in messages if m.round <= round_now))
    ids: list[int] = []
    pos: list[FloatArray] = []
    vel: list[FloatArray] = []
    ages: list[int] = []
    known: list[bool] = []
    for j in sorted(newest):
        msg = newest[j]
        age = round_now - msg.round
        if j == own or msg.position_ned_m is None or age > max_age_rounds:
            continue
        v = msg.velocity_ned_m_s
        velocity = np.zeros(3) if v is None else np.asarray(v, dtype=float).reshape(3)
        position = np.asarray(msg.position_ned_m, dtype=float).reshape(3)
        if extrapolate:
            position = position + velocity * (age * dt_s)
        ids.append(j)
        pos.append(position)
        vel.append(velocity)
        ages.append(age)
        known.append(v is not None)
    return Neighbours(
        ids=tuple(ids),
        position_ned_m=np.reshape(pos, (-1, 3)).astype(float),
        velocity_ned_m_s=np.reshape(vel, (-1, 3)).astype(float),
        age_rounds=np.array(ages, dtype=np.intp),
        velocity_known=np.array(known, dtype=bool),
    )


def neighbour_arrays(
    per_agent: Sequence[Neighbours],
) -> tuple[FloatArray, FloatArray, BoolArray, IntArray]:
    """K agents' neighbours as padded arrays for ``separation.filter_accelerations``: positions
    (K, M, 3), velocities (K, M, 3), mask (K, M), ids (K, M) (-1 in the padding);
    M = the largest count (at least 1)."""
    k = len(per_agent)
    m = max([len(nb) for nb in per_agent] + [1])
    pos, vel = np.zeros((k, m, 3)), np.zeros((k, m, 3))
    mask = np.zeros((k, m), dtype=bool)
    ids = np.full((k, m), -1, dtype=np.intp)
    for i, nb in enumerate(per_agent):
        n = len(nb)
        pos[i, :n], vel[i, :n] = nb.position_ned_m, nb.velocity_ned_m_s
        mask[i, :n], ids[i, :n] = True, nb.ids
    return pos, vel, mask, ids

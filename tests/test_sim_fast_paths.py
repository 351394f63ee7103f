"""The shortcuts of ``swarm simulate``'s hot loop give what the plain code gives."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from drone_agent.agent_core import AgentOutput, Setpoint
from drone_agent.consensus_batch import frozen_factory, frozen_replace
from drone_agent.flight_phase import VehicleView
from drone_agent.link_faults import PairRandom
from drone_agent.moments import SwarmMoments
from gcs.reference.network import DRAW_BLOCK, InProcessNetwork
from protocols.consensus_message import ConsensusMessage


def _message() -> ConsensusMessage:
    return ConsensusMessage(
        sender=3,
        round=17,
        gamma=np.arange(18.0),
        edge_sums={1: np.ones(18)},
        heard=frozenset({1, 2}),
        degree=2,
        position_ned_m=np.zeros(3),
        incarnation=4,
    )


def test_frozen_factory_makes_the_dataclass_instance() -> None:
    msg = _message()
    values = [getattr(msg, f.name) for f in dataclasses.fields(ConsensusMessage)]
    made = frozen_factory(ConsensusMessage)(*values)
    assert type(made) is ConsensusMessage
    assert made == msg and vars(made) == vars(msg)
    with pytest.raises(dataclasses.FrozenInstanceError):
        made.round = 5  # type: ignore[misc]
    assert frozen_factory(VehicleView)(True, True, False, False, 2.0) == VehicleView(
        True, True, False, False, 2.0
    )
    setpoint = frozen_factory(Setpoint)(0.1, -0.2, 0.3, 0.5, False)
    assert setpoint == Setpoint(0.1, -0.2, 0.3, 0.5, False)
    with pytest.raises(TypeError):
        frozen_factory(Setpoint)(0.1, -0.2, 0.3)  # every field is given
    moments = frozen_factory(SwarmMoments)(np.zeros(3), np.ones(3), np.eye(3), np.zeros((3, 3)))
    out = frozen_factory(AgentOutput)(msg, np.zeros(9), moments, setpoint, (1, 2), True, 0.1,
                                      None, False)  # fmt: skip
    assert out.moments is moments and out.setpoint == setpoint and out.separating is False


def test_frozen_replace_is_dataclasses_replace() -> None:
    msg = _message()
    new = frozen_replace(msg, ready_hops=6)
    assert new == dataclasses.replace(msg, ready_hops=6)
    assert msg.ready_hops == 0 and new.ready_hops == 6 and new.gamma is msg.gamma
    with pytest.raises(TypeError):
        frozen_replace(msg, no_such_field=1)


def test_radio_link_draws_are_the_links_own_draws_in_order() -> None:
    """Drawn ahead in blocks, each link's loss draws are those of one ``random()`` per message
    on its own generator (as every agent of ``swarm up`` draws them), also for a link drawn
    twice in one call and across block boundaries."""
    net = InProcessNetwork(6, 10.0, PairRandom(11))
    reference = PairRandom(11)
    rng = np.random.default_rng(2)
    for _ in range(3 * DRAW_BLOCK):
        m = int(rng.integers(1, 10))
        senders, receivers = rng.integers(0, 6, m), rng.integers(0, 6, m)
        got = net._link_draws(senders, receivers)
        want = [reference(int(a), int(b)).random() for a, b in zip(senders, receivers, strict=True)]
        assert np.array_equal(got, want)

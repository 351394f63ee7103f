"""The radio's limits (drone_agent/process/radio.py) against their definitions: loss against
distance (log-distance path loss with Gaussian fading), Gilbert–Elliott bursts (their share and
their lengths), a bandwidth cap's queue (throughput, drops, the wait), latency and jitter (an
exponential tail); each link's draws its own; and the same fates in ``swarm simulate``'s radio
(gcs/reference/network.py) and in an agent's link layer (FaultyTransport), message for message.
Both runners flying it bit for bit alike: tests/test_lockstep_vs_simulate.py."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from drone_agent.process.link_faults import FaultyTransport, LinkFaults, PairRandom, radio_links
from drone_agent.process.radio import LOST, loss_at, message_bytes
from drone_agent.process.transport import SwarmMessageCounters
from gcs.reference.network import InProcessNetwork
from protocols.scenario.scenario_file import RadioConfig, ScenarioError, load_scenario
from protocols.wire.consensus_message import ConsensusMessage
from protocols.wire.format import (
    CONSENSUS_VERSION,
    ConsensusPacket,
    Kind,
    encode_consensus,
    encode_header,
)

DT = 0.02


def _fates(
    config: RadioConfig, n: int, d_m: float = 1.0, size: int = 100, link=(0, 1)
) -> list[int]:
    radio = radio_links(config, DT, seed=7)
    return [radio.admit(link[0], link[1], r, size, d_m) for r in range(n)]


@pytest.mark.parametrize("d_m", [4.0, 8.0, 12.0, 20.0])
def test_loss_rises_with_distance_as_log_distance_path_loss_says(d_m: float) -> None:
    """Half lost at ``loss_half_m``; ``Phi(10 n log10(d / d50) / sigma)`` elsewhere, measured
    over 20,000 messages (binomial 4-sigma bounds)."""
    config = RadioConfig(loss_half_m=10.0, path_loss_exponent=3.0, fading_db=6.0)
    expected = 0.5 * (1 + math.erf(30 * math.log10(d_m / 10.0) / 6.0 / math.sqrt(2)))
    assert loss_at(config, d_m) == pytest.approx(expected)
    n = 20_000
    lost = sum(f == LOST for f in _fates(config, n, d_m)) / n
    assert abs(lost - expected) < 4 * math.sqrt(expected * (1 - expected) / n) + 1e-3
    assert loss_at(config, 10.0) == pytest.approx(0.5)
    assert loss_at(RadioConfig(), 1e4) == 0.0  # no path loss unless asked


def test_gilbert_elliott_bursts_have_their_share_and_their_mean_length() -> None:
    """``burst_fraction`` of the messages in the bad state, in spells of geometric length with
    mean ``burst_length``; every message of a spell lost at ``burst_loss = 1``."""
    config = RadioConfig(burst_fraction=0.2, burst_length=6.0)
    lost = np.array([f == LOST for f in _fates(config, 200_000)])
    assert lost.mean() == pytest.approx(0.2, abs=0.01)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], lost.astype(int), [0]])))
    lengths = edges[1::2] - edges[::2]
    assert lengths.mean() == pytest.approx(6.0, rel=0.05)
    # geometric: P(length = 1) = p_bg = 1/6
    assert (lengths == 1).mean() == pytest.approx(1 / 6, abs=0.02)
    # independent losses of the same rate come in far shorter runs
    flat = np.random.default_rng(0).random(200_000) < 0.2
    e = np.flatnonzero(np.diff(np.concatenate([[0], flat.astype(int), [0]])))
    assert (e[1::2] - e[::2]).mean() < 1.5


def test_a_bandwidth_cap_queues_then_drops_and_carries_its_capacity() -> None:
    """One message a tick of 1,000 bytes on a link of 25,000 bytes/s (half the offered 50,000):
    the link carries its capacity (every other message), drops the rest once its queue of 4 is
    full, and a carried message is late at most by the 4 ahead of it and its own transmission
    (2 ticks each), less the radio's own tick."""
    config = RadioConfig(bandwidth_bytes_s=25_000.0, queue_messages=4)
    fates = _fates(config, 2_000, size=1_000)
    carried = [f for f in fates if f != LOST]
    assert len(carried) == pytest.approx(1_000, abs=10)
    assert max(carried) == 4 * 2 + 2 - 1
    assert fates[:3] == [1, 2, 3]  # the queue builds: 2, 3, 4 ticks' transmission, 1 is the radio's
    # below capacity nothing waits beyond the radio's own tick, nothing is dropped
    assert set(_fates(replace(config, bandwidth_bytes_s=60_000.0), 500, size=1_000)) == {0}
    # a queue of none: a message that finds the link busy is dropped
    assert _fates(replace(config, queue_messages=0), 4, size=1_000) == [1, LOST, 1, LOST]


def test_latency_and_jitter_delay_by_whole_ticks_with_an_exponential_tail() -> None:
    config = RadioConfig(latency_s=0.04, jitter_s=0.06)
    ticks = np.array(_fates(config, 50_000))
    assert ticks.min() == 2  # the latency, 2 ticks
    assert ticks.mean() == pytest.approx((0.04 + 0.06) / DT, abs=0.05)
    # exponential: P(extra > x) = exp(-x / mean), at 3 mean jitters
    beyond = (ticks * DT - 0.04 > 3 * 0.06 + DT / 2).mean()
    assert beyond == pytest.approx(math.exp(-3 - DT / 2 / 0.06), abs=0.01)


def test_each_link_draws_its_own_and_a_seed_repeats() -> None:
    config = RadioConfig(burst_fraction=0.3, loss_half_m=5.0, jitter_s=0.05)
    alone = _fates(config, 300, d_m=4.0, link=(2, 5))
    radio = radio_links(config, DT, seed=7)
    mixed = []
    for r in range(300):  # another link's traffic in between changes nothing on (2, 5)
        radio.admit(3, 5, r, 100, 4.0)
        mixed.append(radio.admit(2, 5, r, 100, 4.0))
    assert mixed == alone
    assert _fates(config, 300, d_m=4.0, link=(5, 2)) != alone  # the other direction: its own
    other_seed = radio_links(config, DT, seed=8)
    assert [other_seed.admit(2, 5, r, 100, 4.0) for r in range(300)] != alone


def _message(sender: int, round_: int, position: tuple[float, float, float]) -> ConsensusMessage:
    gamma = np.linspace(0.0, 1.0, 18) + sender
    sums = {j: np.full(18, 0.5 * j) for j in range(3) if j != sender}
    return ConsensusMessage(
        sender, round_, gamma, sums, frozenset(sums), len(sums),
        position_ned_m=np.array(position), velocity_ned_m_s=np.zeros(3),
    )  # fmt: skip


def test_a_messages_bytes_are_its_wire_fields() -> None:
    m = _message(1, 5, (0.0, 1.0, -2.0))
    payload = encode_consensus(m, (0.0, 1.0, -2.0), "swarm")
    head = len(encode_header(Kind.CONSENSUS, "swarm", CONSENSUS_VERSION))
    assert message_bytes(m) == len(payload) - head


class _Inner:
    """An agent's transport that hands over what it is given (the link layer's inside)."""

    def __init__(self, drone: int) -> None:
        self.drone = drone
        self.inbox: list[ConsensusPacket] = []
        self.rx = 0

    def receive(self) -> list[ConsensusPacket]:
        out, self.inbox = self.inbox, []
        self.rx += len(out)
        return out

    def counters(self) -> SwarmMessageCounters:
        return SwarmMessageCounters(rx=self.rx)

    def publish_consensus(self, message: ConsensusMessage, position: object) -> None:
        pass


def test_simulate_radio_and_the_agents_link_layer_give_the_same_fates() -> None:
    """Three drones on a line 4 m apart sending every round for 400 rounds, through the
    in-process radio and through each receiver's FaultyTransport, with every limit on: the same
    messages arrive at the same rounds, and the link layer counts what its radio dropped (and
    its status's rx leaves them out)."""
    config = RadioConfig(
        bandwidth_bytes_s=60_000.0, queue_messages=2, loss_half_m=7.0, burst_fraction=0.1,
        burst_length=3.0, latency_s=0.02, jitter_s=0.03,
    )  # fmt: skip
    positions = np.array([[0.0, 0.0, -2.0], [4.0, 0.0, -2.0], [8.0, 0.0, -2.0]])
    n, rounds = 3, 400
    net = InProcessNetwork(n, 100.0, PairRandom(0), 1, radio_links(config, DT, seed=3))
    sim: set[tuple[int, int, int, int]] = set()  # (arrival, receiver, sender, round)
    clock = {"now": -1}
    inners = [_Inner(i) for i in range(n)]
    links = [
        FaultyTransport(inners[i], LinkFaults(), PairRandom(0), lambda: clock["now"],
                        radio_links(config, DT, seed=3))
        for i in range(n)
    ]  # fmt: skip
    up: set[tuple[int, int, int, int]] = set()
    for k in range(rounds + 40):
        clock["now"] = k - 1
        for receiver, inbox in enumerate(net.receive(k)):
            sim |= {(k, receiver, m.sender, m.round) for m in inbox}
        for receiver, link in enumerate(links):
            up |= {(k, receiver, p.message.sender, p.message.round) for p in link.receive()}
        if k < rounds:
            messages = [_message(i, k, tuple(positions[i])) for i in range(n)]
            net.send(k, messages, net.in_range(positions), positions)
            for i, link in enumerate(links):
                link.publish_consensus(messages[i], positions[i])
            for receiver in range(n):  # the bus: every other drone's message, next tick
                inners[receiver].inbox += [
                    ConsensusPacket(m, positions[m.sender])
                    for m in messages
                    if m.sender != receiver
                ]
    assert sim == up
    radio_dropped = sum(link.counters().radio for link in links)
    assert 0.1 * 2 * n * rounds < radio_dropped < 0.9 * 2 * n * rounds, radio_dropped
    assert len(up) == 2 * n * rounds - radio_dropped
    # what drone 0's radio let through is what its status says it received, and its status
    # counts what the radio dropped (on the wire from status version 3; the ground station's
    # `swarm status` shows it)
    status = links[0].counters().status()
    assert status.rx == sum(1 for e in up if e[1] == 0)
    assert status.rx_lost_radio == links[0].counters().radio > 0
    from protocols.wire.status import AgentMode, AgentStatus, Health, decode_status, encode_status

    sent = AgentStatus(0, 1, 0.02, AgentMode.FLYING, True, Health.NONE, np.zeros(9), (), status)
    assert decode_status(encode_status(sent, "demo"), "demo").counters == status


def _scenario(tmp_path: Path, section: str) -> Path:
    root = Path(__file__).resolve().parents[1]
    path = tmp_path / "radio.toml"
    path.write_text(
        (root / "scenarios" / "tilt9.toml").read_text() + "\n[radio]\n" + section + "\n"
    )
    return path


def test_the_radio_section_is_read_and_checked(tmp_path: Path) -> None:
    s = load_scenario(_scenario(tmp_path, "bandwidth_bytes_s = 20000\nloss_half_m = 30"))
    assert s.radio == RadioConfig(bandwidth_bytes_s=20_000.0, loss_half_m=30.0)
    assert not s.radio.ideal and RadioConfig().ideal
    for bad, field in (
        ("bandwidth_bytes_s = -1", "radio.bandwidth_bytes_s"),
        ("burst_fraction = 1.0", "radio.burst_fraction"),
        ("burst_length = 0.5", "radio.burst_length"),
        ("queue_messages = 2.5", "radio.queue_messages"),
        ('jitter_s = "a lot"', "radio.jitter_s"),
        ("fading = 3", "fading"),
    ):
        with pytest.raises(ScenarioError, match=field) as err:
            load_scenario(_scenario(tmp_path, bad))
        assert "\n" not in str(err.value)

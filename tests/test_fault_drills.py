"""Live fault drills in an agent process (drone_agent.process.fault_drills) over the in-memory bus:
commands applied to LinkFaults, timed faults undone in simulated time, malformed ones counted;
a scenario's faults and the same commands sent as drills leave the radio the same, tick by tick."""

from __future__ import annotations

import copy
import dataclasses

import pytest

from drone_agent.process.fault_drills import FaultDrills, describe
from drone_agent.process.fault_timeline import actions
from drone_agent.process.link_faults import LinkFaults
from gcs.cli.main import main
from gcs.station.commands import CommandError, Request, encode_request, parse_request
from protocols.bus.memory import MemoryBus
from protocols.faults import (
    Clear,
    Delay,
    FaultCommand,
    LinkCut,
    LinkRestore,
    Loss,
    Partition,
)
from protocols.wire.fault import encode_fault
from protocols.wire.keys import SwarmKeys

SID = "unit"
DT_S = 0.02


class Clock:
    """A settable control round."""

    def __init__(self) -> None:
        self.round = 0

    def __call__(self) -> int:
        return self.round


def _setup() -> tuple[MemoryBus, LinkFaults, Clock, FaultDrills, list[str]]:
    medium, faults, clock = MemoryBus(), LinkFaults(), Clock()
    lines: list[str] = []
    drills = FaultDrills(medium.session(), SID, faults, DT_S, clock, lines.append)
    return medium, faults, clock, drills, lines


def _send(medium: MemoryBus, *commands: FaultCommand) -> None:
    for command in commands:
        medium.deliver(SwarmKeys(SID, 1.0).fault, encode_fault(command, SID))


def test_commands_apply_only_when_polled_and_timed_cuts_end_in_simulated_time() -> None:
    medium, faults, clock, drills, lines = _setup()
    clock.round = 100  # t = 2 s
    _send(medium, LinkCut(0, 4, duration_s=1.0), LinkCut(2, 3, one_way=True))
    assert faults.cut == set()  # the callback only queues
    drills.poll()
    assert faults.cut == {(0, 4), (4, 0), (2, 3)}
    assert drills.applied == 2 and lines[0] == "fault drill at t=2.00s: link_cut 0<->4 for 1 s"
    clock.round = 149
    drills.poll()
    assert (0, 4) in faults.cut
    clock.round = 150  # t = 3 s: one second of simulated time later
    drills.poll()
    assert faults.cut == {(2, 3)}
    _send(medium, LinkRestore(2, 3))
    drills.poll()
    assert faults.cut == set()


def test_loss_delay_partition_and_clear() -> None:
    medium, faults, clock, drills, _ = _setup()
    _send(medium, Loss(0.25), Loss(0.5, (1, 2), duration_s=0.5), Delay(41.0), Delay(100.0, (3, 4)))
    _send(medium, Partition(((0, 1), (2, 3))))
    drills.poll()
    assert faults.loss == 0.25 and faults.loss_for(2, 1) == 0.5
    assert faults.extra_delay_ticks == 2 and faults.delay_for(4, 3) == 5  # ms -> ticks of 20 ms
    assert faults.blocks(1, 2) and not faults.blocks(0, 1)
    clock.round = 25
    drills.poll()  # the link's own loss is over: it loses as every link again
    assert faults.loss_for(2, 1) == 0.25 and faults.link_loss == {}
    _send(medium, Partition(None))
    drills.poll()
    assert faults.partition is None
    _send(medium, LinkCut(5, 6, duration_s=9.0), Clear())
    drills.poll()
    assert faults == LinkFaults()
    clock.round = 10_000
    drills.poll()  # the cleared cut's timed restore is forgotten too
    assert faults == LinkFaults()


def test_malformed_payloads_are_counted_and_ignored() -> None:
    medium, faults, _, drills, lines = _setup()
    key = SwarmKeys(SID, 1.0).fault
    for payload in (b"", b"junk", encode_fault(Clear(), "other"), encode_fault(Clear(), SID)[:-1]):
        medium.deliver(key, payload)
    _send(medium, LinkCut(0, 1))
    drills.poll()
    assert drills.malformed == 4 and drills.applied == 1
    assert faults.cut == {(0, 1), (1, 0)}
    assert sum("ignored" in line for line in lines) == 4
    drills.close()
    _send(medium, Clear())
    drills.poll()
    assert faults.cut == {(0, 1), (1, 0)}  # no longer listening


def test_describe() -> None:
    assert describe(Loss(0.1, (1, 2), 3.0)) == "loss 0.1 on 1<->2 for 3 s"
    assert describe(Delay(20.0)) == "delay 20 ms"
    assert describe(Delay(20.0, (3, 4), 2.0)) == "delay 20 ms on 3<->4 for 2 s"
    assert describe(Partition(((0, 1), (2,)), 5.0)) == "partition 0,1/2 for 5 s"
    assert describe(LinkCut(1, 2, one_way=True)) == "link_cut 1->2"
    assert describe(Partition(((0, 1), (2,)))) == "partition 0,1/2"
    assert describe(Partition(None)) == "partition healed"
    assert describe(Clear()) == "clear"


def test_drill_cli_usage_errors_are_one_line_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    for argv in (
        ["drill", "link-cut", "3", "3"],
        ["drill", "loss", "1.5"],
        ["drill", "loss", "0.1", "--link", "1"],
        ["drill", "delay", "20", "--link", "a,b"],
        ["drill", "partition", "--groups", "0,1/1,2"],
        ["drill", "link-cut", "0", "1", "--for-s", "0"],
        ["drill", "clear", "--zenoh-connect", "tcp/127.0.0.1:1"],
    ):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("swarm: error: ") and err.count("\n") == 1, err


def test_crash_is_an_operator_request_with_a_drone() -> None:
    request = parse_request(encode_request(Request("crash", {"drone": 2})))
    assert request == Request("crash", {"drone": 2.0})
    with pytest.raises(CommandError, match="missing argument 'drone'"):
        parse_request(encode_request(Request("crash", {})))


def test_a_dropout_command_kills_a_hosted_agent_through_the_host() -> None:
    """The DROPOUT fault command (the ground station's dropout drill of a hosted agent) reaches
    the process's ``kill`` callback with the drone; a process without one ignores it."""
    from protocols.bus.interface import Congestion
    from protocols.faults import Dropout
    from protocols.wire.fault import encode_fault

    medium = MemoryBus()
    killed: list[int] = []
    drills = FaultDrills(medium.session(), "s", LinkFaults(), 0.02, lambda: 0,
                         log=lambda _: None, kill=killed.append)  # fmt: skip
    deaf = FaultDrills(medium.session(), "s", LinkFaults(), 0.02, lambda: 0, log=lambda _: None)
    publisher = medium.session().publisher(SwarmKeys("s", 1.0).fault, Congestion.BLOCK)
    publisher.put(encode_fault(Dropout(4), "s"))
    drills.poll()
    deaf.poll()
    assert killed == [4] and drills.applied == 1 and deaf.applied == 1


class Target:
    """What a scenario's fault timeline acts on (drone_agent.process.fault_timeline.FaultTarget)."""

    def __init__(self) -> None:
        self.conditions = LinkFaults()

    def kill_agent(self, drone: int) -> None:
        raise AssertionError(f"no drop-out expected, got {drone}")

    def crash_vehicle(self, drone: int) -> None:
        raise AssertionError(f"no crash expected, got {drone}")


#: link faults a scenario schedules, overlapping: a timed link loss under an every-link one, a
#: link's delay beside every link's, a one-way cut and a two-way one on the same link
SCHEDULE: list[LinkCut | Loss | Delay | Partition] = [
    Loss(0.5, t_s=1.0),
    Loss(0.25, (0, 1), 2.0, t_s=1.5),
    Delay(500.0, (1, 2), 3.0, t_s=2.0),
    Delay(1000.0, t_s=2.25),
    Partition(((0, 1),), 1.0, t_s=3.0),
    LinkCut(3, 4, one_way=True, t_s=4.0),
    LinkCut(4, 3, duration_s=1.25, t_s=4.5),
    Loss(0.75, duration_s=0.5, t_s=5.0),
]


def test_a_scenario_fault_acts_as_the_drill_sent_at_its_time() -> None:
    """Run the scenario's timeline on one radio and send each fault as a drill at its t_s to
    another: the two radios are equal at every tick (one rule: LinkFaults.apply and end)."""
    dt_s = 0.25  # ticks and times exact in binary
    timed = sorted((a for f in SCHEDULE for a in actions(f, dt_s)), key=lambda a: a.t_s)
    target = Target()
    medium, faults, clock = MemoryBus(), LinkFaults(), Clock()
    drills = FaultDrills(medium.session(), SID, faults, dt_s, clock, lambda _: None)
    pending = list(SCHEDULE)
    seen = []
    for k in range(40):
        clock.round, t_s = k, k * dt_s
        while timed and timed[0].t_s <= t_s:
            timed.pop(0).apply(target)
        due = [f for f in pending if f.t_s <= t_s]
        pending = [f for f in pending if f.t_s > t_s]
        _send(medium, *(dataclasses.replace(f, t_s=0.0) for f in due))
        drills.poll()
        assert faults == target.conditions, t_s
        seen.append(copy.deepcopy(faults))
    # the timed ones ended: the two-way cut restored the one-way one too, the every-link loss
    # of 0.75 left none
    assert not timed and not pending and faults == LinkFaults(extra_delay_ticks=4)
    assert seen[6].loss_for(0, 1) == 0.25 and seen[6].loss_for(1, 0) == 0.25
    assert seen[9].delay_for(2, 1) == 2 and seen[9].delay_for(2, 3) == 4
    assert seen[12].blocks(2, 0) and not seen[12].blocks(1, 0)
    assert seen[18].cut == {(3, 4), (4, 3)} and seen[16].cut == {(3, 4)}
    assert seen[21].loss == 0.75 and seen[22].loss == 0.0 and seen[23].cut == set()

"""The agent's flight phases (drone_agent/core/flight_phase.py): the safety invariant over every
flight command, agent phase and vehicle state, and the landing and take-off sequences."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import numpy.typing as npt
import pytest

from drone_agent.core.agent_core import AgentConfig, AgentOutput, Setpoint
from drone_agent.core.consensus.scalar import ConsensusParams
from drone_agent.core.flight_phase import (
    AIRBORNE_ALTITUDE_M,
    REQUESTS,
    Arrivals,
    BatchFlightPhase,
    BatchReadiness,
    FlightPhase,
    Readiness,
    Request,
    VehicleArrays,
    VehicleView,
    _settled_levels,
)
from drone_agent.core.thrust_attitude import ThrustLimits
from protocols.model.frames import G_M_S2
from protocols.wire.consensus_message import ConsensusMessage
from protocols.wire.plan import LAND_HANDOVER_ALTITUDE_M, FlightCommand
from protocols.wire.status import AgentMode

LIMITS = ThrustLimits(mass_kg=0.34, max_thrust_n=2 * 0.34 * G_M_S2)
MIN_THRUST = LIMITS.thrust_range_n[0] / LIMITS.max_thrust_n
FORMATION = Setpoint(0.05, -0.1, 0.3, 0.55, False)
#: A setpoint a broken core might produce: it must never reach an airborne vehicle.
ZERO = Setpoint(0.0, 0.0, 0.0, 0.0, False)


def _vehicle(armed: bool, mode: str, altitude_m: float) -> VehicleView:
    return VehicleView(
        armed=armed,
        in_offboard=mode == "offboard",
        in_land=mode == "land",
        in_hold=mode == "hold",
        altitude_m=altitude_m,
    )


def _phase(history: str) -> FlightPhase:
    """A phase object in one of its internal states, reached the way an agent reaches it."""
    phase = FlightPhase(LIMITS)
    flying = _vehicle(True, "offboard", 5.0)
    if history in ("committed", "handed_over", "landed"):
        phase.decide(FlightCommand.FLY, True, True, FORMATION, 5.0, flying, 0.0)
    if history in ("handed_over", "landed"):
        phase.decide(FlightCommand.LAND, True, True, FORMATION, 0.5, flying, 0.0)
    if history == "landed":
        phase.decide(FlightCommand.LAND, True, True, FORMATION, 0.0, _vehicle(False, "hold", 0), 0)
    return phase


VEHICLES = [
    _vehicle(armed, mode, alt)
    for armed, mode, alt in itertools.product(
        (False, True), ("offboard", "land", "hold", "other"), (0.0, 0.05, 0.5, 1.5, 30.0)
    )
]


@pytest.mark.parametrize("history", ["fresh", "committed", "handed_over", "landed"])
@pytest.mark.parametrize("command", list(FlightCommand))
def test_an_airborne_vehicle_is_never_sent_less_than_the_minimum_thrust(
    history: str, command: FlightCommand
) -> None:
    """Every command x agent phase x (armed, mode, altitude) x core setpoint x readiness x
    commanded altitude: an armed or airborne vehicle always gets at least the minimum thrust;
    zero thrust goes only to a disarmed vehicle on the ground."""
    cases = itertools.product(
        VEHICLES, (None, FORMATION, ZERO), (False, True), (False, True), (0.0, 0.8, 5.0)
    )
    for vehicle, setpoint, arm_allowed, converged, commanded in cases:
        phase = _phase(history)
        order = phase.decide(command, arm_allowed, converged, setpoint, commanded, vehicle, 0.2)
        thrust = order.setpoint.thrust_normalised
        context = (history, command, vehicle, setpoint, arm_allowed, converged, commanded, order)
        if vehicle.armed or vehicle.altitude_m > AIRBORNE_ALTITUDE_M:
            assert thrust >= MIN_THRUST, context
        else:
            assert order.request in (Request.NONE, Request.ARM_OFFBOARD), context
        if thrust == 0.0:
            assert not vehicle.armed and vehicle.altitude_m <= AIRBORNE_ALTITUDE_M, context


def test_land_follows_the_formation_down_then_hands_over_and_lands() -> None:
    phase = _phase("committed")
    flying = _vehicle(True, "offboard", 4.0)
    # high up: the formation flies the landing plan down (the core's setpoint, no request)
    order = phase.decide(FlightCommand.LAND, True, True, FORMATION, 4.0, flying, 0.0)
    assert order.mode == AgentMode.LANDING and order.setpoint == FORMATION
    assert order.request == Request.NONE
    # the plan reaches the hand-over altitude: the autopilot's LAND mode is asked for
    low = _vehicle(True, "offboard", LAND_HANDOVER_ALTITUDE_M)
    order = phase.decide(FlightCommand.LAND, True, True, FORMATION, 0.99, low, 0.0)
    assert order.request == Request.LAND_MODE and order.setpoint == FORMATION
    assert phase.handed_over
    # in LAND: hover-level setpoints only acknowledge the tick
    order = phase.decide(
        FlightCommand.LAND, True, True, FORMATION, 0.5, _vehicle(True, "land", 0.4), 0
    )
    assert order.mode == AgentMode.LANDING and order.request == Request.NONE
    assert order.setpoint.thrust_normalised == pytest.approx(0.5)
    # touchdown, disarmed by the autopilot: LANDED, zero thrust
    ground = _vehicle(False, "hold", 0.0)
    order = phase.decide(FlightCommand.LAND, True, True, FORMATION, 0.0, ground, 0.0)
    assert order.mode == AgentMode.LANDED and order.setpoint.thrust_normalised == 0.0
    assert not phase.committed and not phase.handed_over
    # take-off: a FLY plan arms it again
    order = phase.decide(FlightCommand.FLY, True, True, FORMATION, 0.0, ground, 0.0)
    assert order.mode == AgentMode.READY and order.request == Request.ARM_OFFBOARD
    order = phase.decide(
        FlightCommand.FLY, True, True, FORMATION, 0.2, _vehicle(True, "offboard", 0.1), 0
    )
    assert order.mode == AgentMode.FLYING and order.setpoint == FORMATION


def test_a_low_vehicle_or_one_without_a_setpoint_is_handed_over_at_once() -> None:
    for vehicle, setpoint in ((_vehicle(True, "offboard", 0.2), FORMATION),
                              (_vehicle(True, "offboard", 8.0), None)):  # fmt: skip
        phase = _phase("committed")
        order = phase.decide(FlightCommand.LAND, True, True, setpoint, 8.0, vehicle, 0.0)
        assert order.request == Request.LAND_MODE, (vehicle, setpoint)


def test_take_off_in_mid_descent_takes_the_vehicle_back_from_land() -> None:
    phase = _phase("handed_over")
    order = phase.decide(
        FlightCommand.FLY, True, True, FORMATION, 0.7, _vehicle(True, "land", 0.7), 0
    )
    assert order.mode == AgentMode.FLYING and order.request == Request.ARM_OFFBOARD
    assert order.setpoint == FORMATION


def test_fly_without_a_valid_setpoint_in_the_air_asks_the_autopilot_to_hold() -> None:
    phase = _phase("committed")
    order = phase.decide(FlightCommand.FLY, True, True, None, 5.0, _vehicle(True, "offboard", 5), 0)
    assert order.mode == AgentMode.HOLDING and order.request == Request.HOLD_MODE
    assert order.setpoint.thrust_normalised == pytest.approx(0.5)


def test_on_the_ground_it_waits_for_convergence_and_the_fly_command() -> None:
    phase = FlightPhase(LIMITS)
    ground = _vehicle(False, "hold", 0.0)
    assert phase.decide(FlightCommand.FLY, True, False, FORMATION, 0, ground, 0).mode == (
        AgentMode.WARMUP
    )
    assert phase.decide(FlightCommand.GROUND, True, True, FORMATION, 0, ground, 0).mode == (
        AgentMode.READY
    )
    no_arm = phase.decide(FlightCommand.FLY, False, True, FORMATION, 0, ground, 0)
    assert no_arm.request == Request.NONE and no_arm.setpoint.thrust_normalised == 0.0


def _output(disagreement: float, ready: bool = True, round_: int = 0) -> AgentOutput:
    message = _level_message(0, round_, 0)
    return AgentOutput(message, np.zeros(9), None, None, (), ready, disagreement)  # type: ignore[arg-type]


def _config(settle_ticks: int, heard_timeout_ticks: int = 5) -> AgentConfig:
    params = ConsensusParams(heard_timeout_ticks=heard_timeout_ticks)
    return AgentConfig(params, None, LIMITS, settle_ticks=settle_ticks, settle_tolerance=0.02)  # type: ignore[arg-type]


def test_settling_needs_calm_ticks_with_a_steady_membership() -> None:
    """Alone (no neighbour heard), an agent is ready as soon as its own estimate has settled:
    ``settle_ticks`` calm ticks in a row with the same membership view, warm-up over."""
    readiness = Readiness(_config(settle_ticks=5))
    members = frozenset({0, 1, 2})

    def update(out: AgentOutput, view: frozenset[int]) -> bool:
        return readiness.update(out, [], view, False)

    assert not any(update(_output(0.001), members) for _ in range(5))  # 1st sets members
    assert update(_output(0.001), members) and readiness.agrees
    assert not update(_output(0.001), frozenset({0, 1}))  # a drone left: start again
    assert not readiness.agrees
    assert not any(update(_output(0.001), frozenset({0, 1})) for _ in range(4))
    assert update(_output(0.001), frozenset({0, 1}))
    assert not update(_output(0.05), frozenset({0, 1}))  # disagreeing again
    calm_but_warming_up = [update(_output(0.0, ready=False), members) for _ in range(9)]
    assert not any(calm_but_warming_up) and readiness.agrees  # agrees, says so, does not go
    readiness.reset()  # a new life: nothing carried over
    assert not readiness.agrees and readiness.level == 0 and not readiness.ready


def _first_calm(config: AgentConfig, trace: np.ndarray, view_changes_at: int = -1) -> int | None:
    """The first tick at which an agent alone, fed ``trace`` as its disagreement, agrees."""
    readiness = Readiness(config)
    members, fewer = frozenset({0, 1, 2}), frozenset({0, 1})
    for t, d in enumerate(trace.tolist()):
        readiness.update(_output(d), [], fewer if t >= view_changes_at >= 0 else members, False)
        if readiness.agrees:
            return t
    return None


def test_the_plateau_rule_waits_for_the_disagreement_to_stop_falling_not_for_2_percent() -> None:
    """Sensors that lie keep the disagreement at a floor above 2 % (white noise around 0.15): the
    2 % rule never passes; the plateau rule passes once the start-up transient (falling by more
    than the 0.7 ratio a window) has gone and both windows sit on the floor, then settle_ticks
    calm ticks later. A rise (the first messages, a growing disagreement) does not count, nor a
    floor reached before a membership change: the windows start again. (A slow drift within the
    ratio counts: the floor grows and shrinks with the swarm's spread and speed.)"""
    from dataclasses import replace

    rng = np.random.default_rng(3)
    window, n = 50, 600
    floor = 0.15 * (1.0 + 0.3 * rng.standard_normal(n)).clip(0.2)
    t = np.arange(n)
    # the estimator's start-up: rises as the first messages arrive, falls, gone by ~ t = 200
    transient = 2.0 * (1.0 - np.exp(-t / 5.0)) * np.exp(-t / 40.0)
    trace = floor + transient
    agree = replace(_config(settle_ticks=25), settle_window_ticks=window)
    plateau = replace(agree, settle_plateau=True)
    assert _first_calm(agree, trace) is None
    first = _first_calm(plateau, trace)
    assert first is not None
    # a window's fall below 0.7 ends ~ 40 ln(...) ticks in; two whole windows then 25 calm ticks
    assert 2 * window + 25 <= first <= 400, first
    assert transient[first - 25] < 0.5 * 0.15  # the transient was small against the floor
    growing = 0.15 * np.exp(t / 60.0)  # rising by more than 1 / 0.7 a window: never calm
    assert _first_calm(plateau, growing) is None
    # the view changes at 200, just before it would agree: its windows start again there
    assert first > 200
    later = _first_calm(plateau, trace, view_changes_at=200)
    assert later is not None and later >= 200 + 2 * window - 1 + 24, later
    # ideal sensors: below 2 % passes at once, with or without the plateau rule (same tick)
    calm = np.full(100, 0.001)
    assert _first_calm(agree, calm) == _first_calm(plateau, calm) == 25  # 1st sets members


def test_the_plateau_rule_is_on_where_the_sensors_lie_unless_the_scenario_says() -> None:
    from dataclasses import replace

    from sitl_client import ROOT

    from drone_agent.core.config import agent_config
    from protocols.scenario.scenario_file import ConsensusConfig, SensorsConfig, load_scenario

    paper = load_scenario(ROOT / "scenarios" / "paper.toml")
    lying = replace(paper, sensors=SensorsConfig(gnss_bias_m=0.5))
    late = replace(paper, sensors=SensorsConfig(rate_hz=10.0, latency_s=0.1))
    assert not agent_config(paper).settle_plateau and not agent_config(late).settle_plateau
    assert agent_config(lying).settle_plateau
    for settle, ideal, lie in (("agree", False, False), ("plateau", True, True)):
        c = replace(paper.consensus, settle=settle)
        assert agent_config(replace(paper, consensus=c)).settle_plateau is ideal
        assert agent_config(replace(lying, consensus=c)).settle_plateau is lie
    assert agent_config(paper).settle_window_ticks == 50  # one second at 50 Hz
    assert ConsensusConfig().settle == "auto"


def _level_message(sender: int, round_: int, level: int) -> ConsensusMessage:
    return ConsensusMessage(sender, round_, np.zeros(18), {}, frozenset(), 0, ready_hops=level)


def _flood(
    neighbours: dict[int, list[int]], settled_from: dict[int, int], ticks: int, lost: float = 0.0
) -> dict[int, int | None]:
    """Run the readiness flood on a graph with one-tick message delay, each agent's estimate
    calm from ``settled_from[i]`` on; per agent the first tick at which it knows the whole swarm
    has settled (None if never). ``lost``: share of messages dropped."""
    rng = np.random.default_rng(3)
    members = frozenset(neighbours)
    gates = {i: Readiness(_config(settle_ticks=1)) for i in members}
    first: dict[int, int | None] = dict.fromkeys(members)
    sent: dict[int, ConsensusMessage] = {}
    for k in range(ticks):
        new = {}
        for i, gate in gates.items():
            inbox = [sent[j] for j in neighbours[i] if j in sent and rng.random() >= lost]
            out = _output(0.0 if k >= settled_from[i] else 1.0, round_=k)
            if gate.update(out, inbox, members, False) and first[i] is None:
                first[i] = k
            new[i] = _level_message(i, k, gate.level)
        sent = new
    return first


def test_the_swarm_leaves_the_ground_together_once_the_last_agent_has_settled() -> None:
    """A line of 8 (diameter 7 hops) whose agents settle one after another, the far end last: no
    agent goes before every agent has settled, and all go within the diameter of each other."""
    n = 8
    line = {i: [j for j in (i - 1, i + 1) if 0 <= j < n] for i in range(n)}
    settled_from = {i: 10 + 5 * i for i in range(n)}  # agent 7 settles last, at tick 45
    first = _flood(line, settled_from, 120)
    ticks = [first[i] for i in range(n)]
    assert all(t is not None for t in ticks), ticks
    go = np.array(ticks, dtype=float)
    assert go.min() >= max(settled_from.values()) + 1  # nobody before the last one settled
    assert go.max() - go.min() <= n - 1  # together: within the diameter in ticks
    assert go.max() <= max(settled_from.values()) + n  # and promptly: the cap (N) ticks later
    # 20 % of the messages lost: the last heard level is kept, the outcome is the same
    lossy = _flood(line, settled_from, 120, lost=0.2)
    assert all(t is not None and t > max(settled_from.values()) for t in lossy.values()), lossy


def test_one_unsettled_agent_holds_the_whole_swarm_on_the_ground() -> None:
    n = 6
    ring = {i: [(i - 1) % n, (i + 1) % n] for i in range(n)}
    first = _flood(ring, {i: (10 if i != 3 else 10**6) for i in range(n)}, 200)
    assert all(t is None for t in first.values()), first
    # a member that is not heard from at all (cut off) does not block the others forever once it
    # leaves the membership: alone, an agent goes on its own settling
    alone = Readiness(_config(settle_ticks=1))
    assert [alone.update(_output(0.0, round_=k), [], frozenset({0}), False) for k in (0, 1)] == [
        False,  # (its first tick sets its membership view)
        True,
    ]


def test_readiness_combines_own_settling_and_the_swarm() -> None:
    config = AgentConfig(  # type: ignore[arg-type]
        ConsensusParams(), None, LIMITS, settle_ticks=3, settle_tolerance=0.02
    )
    readiness = Readiness(config)
    members = frozenset({0, 1})
    out = AgentOutput(_level_message(0, 0, 0), np.zeros(9), None, None, (), True, 0.001)  # type: ignore[arg-type]
    for k in range(10):  # settled, but the neighbour is not: level 1, not ready
        msg = replace(out.message, round=k)
        peer_low = [_level_message(1, k - 1, 0)]
        assert not readiness.update(replace(out, message=msg), peer_low, members, False)
    assert readiness.level == 1
    peer_high = [_level_message(1, 10, 2)]
    msg = replace(out.message, round=10)
    assert readiness.update(replace(out, message=msg), peer_high, members, False)
    assert readiness.level == 2


def test_batch_readiness_is_readiness_row_by_row() -> None:
    """BatchReadiness (swarm simulate's and a host's, all agents in one call) gives each row the
    levels and the readiness K one-row Readiness objects give: the rows do not leak into each
    other, over random traffic: losses, late and duplicated messages (a sender twice in one
    inbox), senders outside the membership, membership changes, one view for all rows or one
    per row, rows skipped for a tick, commitments, vehicles not ready and agents that never
    settle."""
    from types import SimpleNamespace

    from drone_agent.core.flight_phase import Arrivals, BatchReadiness

    config = AgentConfig(  # type: ignore[arg-type]
        ConsensusParams(heard_timeout_ticks=3), None, LIMITS, settle_ticks=4, settle_tolerance=0.05
    )
    rng = np.random.default_rng(7)
    k = 12
    scalar = [Readiness(config) for _ in range(k)]
    batch = BatchReadiness(k, config)
    members = frozenset(range(k))
    levels_sent: dict[int, list[int]] = {}
    committed = np.zeros(k, dtype=bool)
    for round_ in range(400):
        if (
            round_ % 57 == 0 and round_ < 300
        ):  # a new membership view (another object, sometimes equal)
            members = frozenset(int(j) for j in np.flatnonzero(rng.random(k) < 0.9)) | {0}
        if round_ == 300:  # a small swarm: its agents become ready
            members = frozenset({0, 1, 2})
        rows = [i for i in range(k) if rng.random() < 0.95]
        receiver, sender, rnds, lvls, inboxes = [], [], [], [], {i: [] for i in range(k)}
        for i in range(k):
            for j in range(k):
                back = int(rng.integers(1, 5))
                if i == j or rng.random() < 0.15 or round_ - back not in levels_sent:
                    continue
                copies = 2 if rng.random() < 0.05 else 1
                for c in range(copies):
                    r = round_ - back - c
                    lvl = levels_sent.get(r, [0] * k)[j]
                    inboxes[i].append(SimpleNamespace(sender=j, round=r, ready_hops=lvl))
                    receiver.append(i)
                    sender.append(j)
                    rnds.append(r)
                    lvls.append(lvl)
        dis = rng.random(k) * 0.052 * (1 + (np.arange(k) == 5) * (round_ < 200))
        fly = rng.random(k) < 0.9
        committed |= rng.random(k) < 0.01
        committed &= rng.random(k) > 0.02
        vehicle_ready = rng.random(k) < 0.97
        per_row = 100 <= round_ < 250  # each row its own view (a host's agents)
        views = [
            members - {int(j) for j in rng.integers(0, k, 1)} if per_row else members
            for _ in range(k)
        ]
        expected = []
        for i in rows:
            out = SimpleNamespace(
                disagreement=float(dis[i]),
                ready_to_fly=bool(fly[i]),
                message=SimpleNamespace(round=round_),
            )
            done = scalar[i].update(
                out, inboxes[i], views[i], bool(committed[i]), bool(vehicle_ready[i])
            )  # type: ignore[arg-type]
            expected.append(done)
        arrivals = Arrivals(
            np.array(receiver, dtype=np.intp),
            np.array(sender, dtype=np.intp),
            np.array(rnds, dtype=np.int64),
            np.array(lvls, dtype=np.int64),
        )
        got = batch.update(
            rows,
            round_,
            dis[rows].tolist(),
            fly[rows].tolist(),
            arrivals,
            [views[i] for i in rows] if per_row else members,
            committed[rows].tolist(),
            vehicle_ready[rows].tolist(),
        )
        assert got.tolist() == expected, round_
        assert batch.level[rows].tolist() == [scalar[i].level for i in rows], round_
        levels_sent[round_] = [scalar[i].level for i in range(k)]
    assert max(max(v) for v in levels_sent.values()) >= 3  # the flood did run
    assert any(s.ready for s in scalar)


def test_batch_takeoff_is_takeoff_clock_row_by_row() -> None:
    """BatchTakeoff (swarm simulate's and a host's) advertises and flies on the take-off rounds K
    one-row TakeoffClock objects do (the rows do not leak into each other), over random traffic:
    losses, rows skipped for a tick, agents taking off at different rounds, landing and flying
    again, silences longer than the timeout."""
    from types import SimpleNamespace

    from drone_agent.core.flight_phase import Arrivals, BatchTakeoff, TakeoffClock

    rng = np.random.default_rng(11)
    k, timeout = 10, 3
    scalar = [TakeoffClock(timeout) for _ in range(k)]
    batch = BatchTakeoff(k, timeout)
    sent: dict[int, list[int | None]] = {}
    committed = np.zeros(k, dtype=bool)
    for round_ in range(500):
        rows = [i for i in range(k) if rng.random() < 0.9]
        receiver, takeoff, inboxes = [], [], {i: [] for i in range(k)}
        quiet = 200 <= round_ < 220  # nobody hears anybody: held rounds expire
        for i in range(k):
            for j in range(k):
                back = int(rng.integers(1, 4))
                if quiet or i == j or rng.random() < 0.3 or round_ - back not in sent:
                    continue
                t = sent[round_ - back][j]
                said = SimpleNamespace(sender=j, round=round_ - back, ready_hops=0, takeoff_round=t)
                inboxes[i].append(said)
                receiver.append(i)
                takeoff.append(-1 if t is None else t)
        committed |= rng.random(k) < 0.02
        committed &= rng.random(k) > (0.05 if round_ > 300 else 0.002)
        expected = [scalar[i].update(round_, bool(committed[i]), inboxes[i]) for i in rows]
        n = len(receiver)
        arrivals = Arrivals(
            np.array(receiver, dtype=np.intp),
            np.zeros(n, dtype=np.intp),
            np.zeros(n, dtype=np.int64),
            np.zeros(n, dtype=np.int64),
            np.array(takeoff, dtype=np.int64),
        )
        got = batch.update(rows, round_, committed[rows].tolist(), arrivals)
        assert got == expected, round_
        assert batch.rounds(range(k)) == [s.round for s in scalar], round_
        sent[round_] = [s.advertised for s in scalar]
    seen = {t for v in sent.values() for t in v if t is not None}
    assert len(seen) >= 2  # a take-off forgotten (landed, silence) and another one


def test_arrivals_of_a_hosts_shared_inboxes_are_those_of_its_lists() -> None:
    """A host's agents' inboxes share their message objects (one message reaches every agent of
    the process in range): read from :class:`Inboxes` (each distinct message once) the arrivals
    are the plain lists' value for value, in the same order."""
    from drone_agent.core.flight_phase import Arrivals
    from drone_agent.core.inboxes import Inboxes

    rng = np.random.default_rng(5)
    messages = [
        ConsensusMessage(s, 40 - int(rng.integers(0, 3)), np.zeros(18), {}, frozenset(), 0,
                         ready_hops=int(rng.integers(0, 4)),
                         takeoff_round=None if s % 3 else 100 + s)
        for s in range(12)
    ]  # fmt: skip
    lists = [[m for m in messages if rng.random() < 0.6] for _ in range(7)]
    lists[3] = []  # a row that heard nobody
    rows = [2, 0, 5, 6, 1, 4, 3]
    plain = Arrivals.of_inboxes(rows, lists)
    shared = Arrivals.of_inboxes(rows, Inboxes(lists))
    assert plain.takeoff is not None and shared.takeoff is not None
    for name in ("receiver", "sender", "round", "level", "takeoff"):
        a, b = getattr(plain, name), getattr(shared, name)
        assert a.dtype == b.dtype and np.array_equal(a, b), name
    assert plain.sender.size == sum(map(len, lists)) and set(plain.takeoff.tolist()) > {-1}


def test_agents_that_leave_apart_agree_on_the_first_take_off_round() -> None:
    """A line of 6 whose agents decide to fly at rounds 10..15 (losses, say): within the line's
    diameter in ticks every one advertises round 10; one that has not left the ground yet flies
    the plan on it too, and a landed swarm forgets it."""
    from drone_agent.core.flight_phase import TakeoffClock

    n = 6
    clocks = [TakeoffClock(heard_timeout_ticks=5) for _ in range(n)]
    sent: list[ConsensusMessage | None] = [None] * n
    for round_ in range(30):
        new: list[ConsensusMessage | None] = []
        for i, clock in enumerate(clocks):
            inbox = [m for j in (i - 1, i + 1) if 0 <= j < n and (m := sent[j]) is not None]
            flies = i < n - 1 and round_ >= 10 + i  # the last one stays on the ground
            clock.update(round_, flies, inbox)
            new.append(
                ConsensusMessage(
                    i, round_, np.zeros(18), {}, frozenset(), 0, takeoff_round=clock.advertised
                )
            )
        sent = new
    assert [c.advertised for c in clocks] == [10] * (n - 1) + [None]
    assert [c.round for c in clocks] == [10] * n
    for round_ in range(30, 40):  # all landed: nobody advertises, the heard round expires
        for clock in clocks:
            clock.update(round_, False, [])
    assert [c.round for c in clocks] == [None] * n


def test_a_batch_decides_as_its_rows_do_one_by_one() -> None:
    """BatchFlightPhase (the in-process runner's: one compiled call for every agent) gives each
    row the order and latches that row's own FlightPhase (a hosted agent's) gives, over random
    commands, vehicles, setpoints (none, the formation's, one below the minimum thrust) and
    latches, tick after tick."""
    rng = np.random.default_rng(7)
    n = 64
    batch = BatchFlightPhase(n, LIMITS)
    alone = [FlightPhase(LIMITS) for _ in range(n)]
    commands = list(FlightCommand)
    setpoints = [None, FORMATION, ZERO, Setpoint(-0.2, 0.1, 1.0, 0.7, True)]
    for _ in range(40):
        rows = sorted(rng.choice(n, size=int(rng.integers(1, n + 1)), replace=False).tolist())
        k = len(rows)
        command = [commands[c] for c in rng.integers(0, len(commands), k)]
        arm = rng.random(k) < 0.8
        converged = rng.random(k) < 0.6
        sps = [setpoints[c] for c in rng.integers(0, len(setpoints), k)]
        up = rng.choice([0.0, 0.2, LAND_HANDOVER_ALTITUDE_M, 3.0], k)
        on_ground = [None, False, True]
        views = [
            VehicleView(
                armed=bool(rng.random() < 0.5),
                in_offboard=bool(rng.random() < 0.5),
                in_land=bool(rng.random() < 0.3),
                in_hold=bool(rng.random() < 0.3),
                altitude_m=float(rng.choice([0.0, 0.05, AIRBORNE_ALTITUDE_M, 0.25, 4.0])),
                on_ground=on_ground[int(rng.integers(0, 3))],
            )
            for _ in range(k)
        ]
        yaw = rng.uniform(-3, 3, k)
        orders = batch.decide(
            rows, [int(c) for c in command], arm, converged, sps, up, VehicleArrays.of(views), yaw
        )
        for p, r in enumerate(rows):
            want = alone[r].decide(
                command[p], bool(arm[p]), bool(converged[p]), sps[p], float(up[p]), views[p],
                float(yaw[p]),
            )  # fmt: skip
            sp = want.setpoint
            assert (AgentMode(int(orders.mode[p])), REQUESTS[int(orders.request[p])]) == (
                want.mode,
                want.request,
            )
            assert orders.setpoint[p].tolist() == [
                sp.roll_rad, sp.pitch_rad, sp.yaw_rad, sp.thrust_normalised
            ]  # fmt: skip
            assert bool(orders.limited[p]) == sp.limited
            assert (batch.committed[r], batch.landed[r], batch.handed_over[r]) == (
                alone[r].committed,
                alone[r].landed,
                alone[r].handed_over,
            )


def _takeoff_rule(
    state: tuple[np.ndarray, np.ndarray, np.ndarray],
    rows: list[int],
    round_: int,
    committed: list[bool],
    receiver: np.ndarray,
    takeoff: np.ndarray | None,
    timeout: int,
) -> list[int | None]:
    """BatchTakeoff.update's rule as numpy wrote it (the reference of the compiled pass):
    ``state`` (advertised, heard, heard_at) is updated in place."""
    advertised, heard_tab, heard_at = state
    r = np.asarray(rows, dtype=np.intp)
    least = np.full(advertised.shape[0], np.iinfo(np.int64).max, dtype=np.int64)
    if takeoff is not None and takeoff.shape[0]:
        says = takeoff >= 0
        np.minimum.at(least, receiver[says], takeoff[says])
    heard_now = least[r] != np.iinfo(np.int64).max
    held, held_at = heard_tab[r], heard_at[r]
    expired = (held >= 0) & (round_ - held_at > timeout)
    heard = np.where(heard_now, least[r], np.where(expired, -1, held))
    heard_tab[r] = heard
    heard_at[r] = np.where(heard_now, round_, held_at)
    own = np.where(advertised[r] >= 0, advertised[r], round_)
    own = np.where(heard >= 0, np.minimum(own, heard), own)
    advertised[r] = np.where(np.asarray(committed, dtype=bool), own, -1)
    return [None if t < 0 else t for t in advertised[r].tolist()]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_batch_takeoff_is_the_numpy_rule(seed: int) -> None:
    """BatchTakeoff.update (one compiled pass) gives the rounds, and keeps the state, of the
    numpy rule it replaced, over random traffic: rows in any order and skipped, several rounds
    per receiver (the least wins), messages without a take-off round, ticks with no take-off
    rounds at all (``takeoff`` None), silences past the timeout, rows landing and flying again."""
    from drone_agent.core.flight_phase import Arrivals, BatchTakeoff

    rng = np.random.default_rng(seed)
    k, timeout = 12, 4
    batch = BatchTakeoff(k, timeout)
    state = (
        np.full(k, -1, dtype=np.int64),
        np.full(k, -1, dtype=np.int64),
        np.zeros(k, dtype=np.int64),
    )
    committed = np.zeros(k, dtype=bool)
    flew = 0
    for round_ in range(600):
        rows = [int(i) for i in rng.permutation(k) if rng.random() < 0.85]
        n = 0 if 250 <= round_ < 270 else int(rng.integers(0, 3 * k))
        receiver = rng.integers(0, k, n).astype(np.intp)
        said = rng.integers(max(0, round_ - 40), round_ + 1, n).astype(np.int64)
        said[rng.random(n) < 0.5] = -1
        takeoff = None if rng.random() < 0.1 else said
        committed |= rng.random(k) < 0.03
        committed &= rng.random(k) > 0.01
        arrivals = Arrivals(
            receiver, np.zeros(n, dtype=np.intp), np.zeros(n, dtype=np.int64),
            np.zeros(n, dtype=np.int64), takeoff,
        )  # fmt: skip
        flags = committed[rows].tolist()
        want = _takeoff_rule(state, rows, round_, flags, receiver, takeoff, timeout)
        assert batch.update(rows, round_, flags, arrivals) == want, round_
        assert batch.advertised.tolist() == state[0].tolist(), round_
        assert batch.rounds(range(k)) == [
            None if t < 0 else t for t in np.where(state[0] >= 0, state[0], state[1]).tolist()
        ], round_
        flew += sum(t is not None for t in want)
    assert flew > 1000  # rows did fly, on rounds heard and their own


class _NumpyReadiness(BatchReadiness):
    """BatchReadiness with its update as numpy wrote it around the compiled flood (the
    reference of the one-pass update; the calm test and the flood's inputs are the class's)."""

    def update(
        self,
        rows: Sequence[int],
        round_: int,
        disagreement: Sequence[float] | npt.NDArray[np.float64],
        ready_to_fly: Sequence[bool] | npt.NDArray[np.bool_],
        arrivals: Arrivals,
        members: frozenset[int] | Sequence[frozenset[int]],
        committed: Sequence[bool],
        vehicle_ready: Sequence[bool] | None = None,
    ) -> npt.NDArray[np.bool_]:
        """BatchReadiness.update before the one-pass kernel."""
        rows_arr = np.asarray(rows, dtype=np.intp)
        one_view, views, calm = self._calm(rows_arr, disagreement, members)
        calm_ticks = np.where(calm, self.calm_ticks[rows_arr] + 1, 0)
        self.calm_ticks[rows_arr] = calm_ticks
        fly = np.asarray(ready_to_fly, dtype=bool)
        flying = np.asarray(committed, dtype=bool)
        agrees = calm_ticks >= self.ticks
        if vehicle_ready is not None:
            agrees &= np.asarray(vehicle_ready, dtype=bool)
        agrees |= flying
        caps, member = self._flood_inputs(rows_arr, arrivals, one_view, views)
        updating = np.zeros(self.k, dtype=bool)
        updating[rows_arr] = True
        level = np.empty(rows_arr.shape[0], dtype=np.int64)
        _settled_levels(
            rows_arr,
            updating,
            np.ascontiguousarray(arrivals.receiver, dtype=np.intp),
            np.ascontiguousarray(arrivals.sender, dtype=np.intp),
            np.ascontiguousarray(arrivals.round, dtype=np.int64),
            np.ascontiguousarray(arrivals.level, dtype=np.int64),
            self._round,
            self._level,
            int(round_) - 1 - self.timeout,
            member,
            np.ascontiguousarray(agrees, dtype=np.bool_),
            caps,
            level,
        )
        self.level[rows_arr] = level
        ready = (level >= caps) & (fly | flying)
        self.ready[rows_arr] = ready
        return ready


@pytest.mark.parametrize("plateau", [False, True])
def test_batch_readiness_is_the_numpy_rule(plateau: bool) -> None:
    """BatchReadiness.update (one compiled pass after the calm test) gives the readiness, the
    levels, the calm counts and the tables of the numpy rule it replaced, over random traffic:
    rows in any order and skipped, late and duplicated messages, senders beyond the table (it
    grows), one view for all rows or one per row, views changing, commitments, vehicles not
    ready, the plateau rule on and off."""
    config = AgentConfig(  # type: ignore[arg-type]
        ConsensusParams(heard_timeout_ticks=3), None, LIMITS, settle_ticks=4,
        settle_tolerance=0.05, settle_plateau=plateau, settle_window_ticks=5,
    )  # fmt: skip
    rng = np.random.default_rng(3 + plateau)
    k = 14
    batch, reference = BatchReadiness(k, config), _NumpyReadiness(k, config)
    members = frozenset(range(k))
    ready_seen = 0
    for round_ in range(400):
        if round_ % 41 == 0:
            members = frozenset(int(j) for j in np.flatnonzero(rng.random(k + 4) < 0.85)) | {0}
        rows = [int(i) for i in rng.permutation(k) if rng.random() < 0.9]
        n = int(rng.integers(0, 8 * k))
        sender = rng.integers(0, k + 4 if round_ > 200 else k, n).astype(np.intp)
        arrivals = Arrivals(
            rng.integers(0, k, n).astype(np.intp), sender,
            (round_ - rng.integers(1, 6, n)).astype(np.int64),
            rng.integers(0, k + 2, n).astype(np.int64),
        )  # fmt: skip
        dis = rng.random(k) * 0.06
        fly, committed = rng.random(k) < 0.9, rng.random(k) < 0.05
        vehicle = None if rng.random() < 0.3 else (rng.random(k) < 0.95)[rows].tolist()
        per_row = 150 <= round_ < 250
        views = [members - {int(rng.integers(0, k))} for _ in rows] if per_row else members
        args = (rows, round_, dis[rows].tolist(), fly[rows].tolist(), arrivals, views,
                committed[rows].tolist(), vehicle)  # fmt: skip
        got, want = batch.update(*args), reference.update(*args)
        assert got.tolist() == want.tolist(), round_
        for name in ("level", "ready", "calm_ticks", "_round", "_level", "_written", "_since"):
            assert getattr(batch, name).tolist() == getattr(reference, name).tolist(), name
        ready_seen += int(got.sum())
    assert ready_seen > 10  # rows did get ready

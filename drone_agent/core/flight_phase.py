"""What an agent does with its vehicle each control tick: the flight phases. Pure.

From the plan's flight command, the agent's readiness, the core's setpoint and what the vehicle
reports (armed, mode, altitude), :meth:`FlightPhase.decide` returns an :class:`Order`: the agent's
mode, the setpoint to send (every tick has one: in lockstep it also acknowledges the tick) and
what to ask of the autopilot (arm and take offboard, LAND mode, HOLD mode).

Phases, by plan command (protocols/wire/plan.py):

- ``FLY``: once the estimator has settled (``converged``) and arming is allowed, fly the
  formation: arm, offboard, the core's setpoint every tick. The decision is latched
  (``committed``) until the vehicle is back on the ground.
- ``LAND``: an airborne vehicle flies the landing plan (stop, level, flatten, descend) with the
  formation until the commanded centre altitude is at or below
  :data:`~protocols.wire.plan.LAND_HANDOVER_ALTITUDE_M` (or its own altitude is below
  :data:`TOUCHDOWN_FLOOR_M`, or it has no valid setpoint), then it is handed to the autopilot's
  LAND mode: level, sink at the land speed, touchdown detector, disarm. Disarmed on the ground it
  is ``LANDED``; a ``FLY`` plan (``swarm takeoff``) arms it and flies again, also in mid-descent.
- ``GROUND``: stay on the ground; an airborne vehicle is handed to LAND at once.

Safety invariant (tested over every command, mode and vehicle state): a vehicle that is armed or
above :data:`AIRBORNE_ALTITUDE_M` is never sent a thrust below the controller's minimum
(``ThrustLimits.min_thrust_ratio`` of its weight). Zero thrust goes only to a disarmed vehicle on
the ground. The only way to stop the motors of a flying vehicle is an explicit kill (the ground
station's crash drill, MAV_CMD_INJECT_FAILURE, or a forced disarm), never an agent's setpoint.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

import numpy as np
import numpy.typing as npt

from drone_agent.core.agent_core import AgentConfig, AgentOutput, Setpoint
from drone_agent.core.inboxes import Inboxes
from drone_agent.core.jit_math import jit
from drone_agent.core.thrust_attitude import ThrustLimits
from protocols.model.frames import G_M_S2, FloatArray
from protocols.runtime.fast_dataclass import frozen_factory
from protocols.wire.consensus_message import ConsensusMessage
from protocols.wire.plan import LAND_HANDOVER_ALTITUDE_M, FlightCommand
from protocols.wire.status import MODE_OF, AgentMode

#: A vehicle above this altitude (m) is airborne whatever it says about arming.
AIRBORNE_ALTITUDE_M = 0.1
#: Under a LAND plan a vehicle this low (m) is handed to the autopilot's LAND mode at once.
TOUCHDOWN_FLOOR_M = 0.3


class Request(Enum):
    """What the agent asks of the autopilot this tick (the adapter rate-limits the asking)."""

    NONE = "none"
    ARM_OFFBOARD = "arm and offboard"
    LAND_MODE = "land mode"
    HOLD_MODE = "hold mode"


@dataclass(frozen=True)
class VehicleView:
    """What the vehicle last reported: armed, whether it flies offboard setpoints or its own
    LAND or HOLD mode, its altitude (m, up, as its state estimate has it) and whether its land
    detector says it is on the ground (EXTENDED_SYS_STATE's landed state; None: it says
    nothing, and the altitude decides)."""

    armed: bool
    in_offboard: bool
    in_land: bool
    in_hold: bool
    altitude_m: float
    on_ground: bool | None = None

    @property
    def airborne(self) -> bool:
        """Armed, or off the ground: its motors must not be cut by a setpoint (the rule's
        :func:`_airborne`)."""
        return bool(_airborne(self.armed, _on_ground_code(self.on_ground), self.altitude_m))


@dataclass(frozen=True)
class Order:
    """This tick's decision: the agent's mode, the setpoint to send, the autopilot request."""

    mode: AgentMode
    setpoint: Setpoint
    request: Request = Request.NONE


#: ``Order(mode, setpoint, request)``, made without the frozen ``__init__`` (every agent makes
#: one a tick)
_new_order = frozen_factory(Order)


def idle_setpoint(yaw_rad: float) -> Setpoint:
    """Level, zero thrust: for a disarmed vehicle on the ground only."""
    return Setpoint(0.0, 0.0, yaw_rad, 0.0, False)


def hover_setpoint(limits: ThrustLimits, yaw_rad: float) -> Setpoint:
    """Level at ``yaw_rad`` with the thrust that carries the weight."""
    return Setpoint(0.0, 0.0, yaw_rad, limits.mass_kg * G_M_S2 / limits.max_thrust_n, False)


class Readiness:
    """One agent's readiness to leave the ground: row ``row`` of a :class:`BatchReadiness` (a
    batch of its own unless ``batch`` is given). The one rule is the batch's; this is a view of
    one row, for an agent that is not ticked with others."""

    def __init__(
        self, config: AgentConfig, batch: BatchReadiness | None = None, row: int = 0
    ) -> None:
        self.batch = batch if batch is not None else BatchReadiness(1, config)
        self.row = row

    @property
    def level(self) -> int:
        """This agent's settled level, advertised as ``ConsensusMessage.ready_hops``."""
        return int(self.batch.level[self.row])

    @property
    def ready(self) -> bool:
        """Whether the swarm was ready to leave the ground at this agent's last update."""
        return bool(self.batch.ready[self.row])

    @property
    def agrees(self) -> bool:
        """Its estimate agrees with its neighbours' (``settle_ticks`` calm ticks)."""
        return self.batch.agrees(self.row)

    def reset(self) -> None:
        """Start again: a new life of the agent (no calm tick, nothing heard)."""
        self.batch.reset(self.row)

    def update(
        self,
        out: AgentOutput,
        inbox: Sequence[ConsensusMessage],
        members: frozenset[int],
        committed: bool,
        vehicle_ready: bool = True,
    ) -> bool:
        """:meth:`BatchReadiness.update` of this row: its tick's core output, the inbox it was
        computed from, its membership view, whether it already flies and whether its vehicle can
        fly; whether the swarm is ready to leave the ground."""
        ready = self.batch.update(
            (self.row,),
            out.message.round,
            (out.disagreement,),
            (out.ready_to_fly,),
            Arrivals.of_inboxes((self.row,), (inbox,), with_takeoff=False),
            members,
            (committed,),
            (vehicle_ready,),
        )
        return bool(ready[0])


#: Round of an empty slot of :class:`BatchReadiness`'s table (no message is this old).
_NO_ROUND = -(2**62)

#: The plateau rule (:class:`BatchReadiness`): the disagreement has stopped falling when its mean
#: over the last window is at least this fraction of the window before's (and at most its inverse)
PLATEAU_RATIO = 0.7


class BatchReadiness:
    """The one rule for leaving the ground, of K agents at once (rows ``0..k-1``): ``swarm
    simulate``'s agents in one call a tick, a ``swarm agent`` process's agents in one call per
    pass (drone_agent/process/host.py); :class:`Readiness` is one row of it. A row is ready when
    its warm-up is over, its own estimate has settled and so has every agent's.

    **Its own estimate settled** (the condition to arm, with the plan's FLY): the estimator
    agreeing with its neighbours (disagreement below ``settle_tolerance``) for ``settle_ticks``
    ticks in a row while its membership view stayed the same (a drone joining or leaving restarts
    the count), its vehicle ready to fly (its autopilot dialect's checks:
    drone_agent/process/dialects.py; an agent whose vehicle is not ready does not agree, so
    nobody leaves without it) and the warm-up over (``AgentOutput.ready_to_fly``). The agreement
    counts during the warm-up too, so that word of a settled swarm crosses it before the warm-up
    ends: measured on a 10 x 10 grid whose plan starts climbing at the end of its 5 s warm-up,
    waiting for the warm-up first kept it on the ground for 33 s, because the climbing reference
    then kept the estimates from agreeing to 2 % until the drop-outs of the scenario were over.

    **Every agent settled** (climb together), known to each agent from its radio neighbours alone:
    a flood of settled levels over the consensus messages. Each tick an agent advertises a level
    on its consensus message (``ready_hops``)::

        level_i = 0                                   if i does not agree
                = min(cap, 1 + min_j level_j)         otherwise (j: neighbours heard recently)

    with ``cap`` the number of live members in its view. ``level_i >= h`` means every agent within
    ``h - 1`` hops of i had settled within the last ``h`` ticks; since no radio graph of ``cap``
    drones has a diameter of ``cap`` hops or more, ``level_i == cap`` means the whole (connected)
    swarm has settled. Once the last agent settles, every level rises by one per tick, so all
    agents reach the cap within the graph's diameter in ticks of each other (a 10 x 10 grid at
    range 6 m: 6 ticks, 0.12 s) and ``cap`` ticks after that last agent (2 s at N = 100, 50 Hz):
    the swarm leaves the ground together instead of drone by drone as each settles (measured
    before this rule on a sparse 5-drone line: the centre armed at 3.0 s, the ends at 6.2 s). Per
    sender the newest (round, level) heard is kept (the first copy of its highest round); a
    sender not heard for the heard timeout, or out of the view, is forgotten.

    An agent that already flies (``committed``) counts as settled, so a late joiner waits only for
    itself and is not held on the ground by a formation manoeuvring above it. An agent with no
    neighbour (alone, or cut off) reaches the cap on its own settling.

    **Sensors that lie** (``settle_plateau``: [consensus] settle, on by default where [sensors]
    add an error): each agent's input to the estimator carries its own sensors' noise every tick,
    so the disagreement never falls below a floor set by that noise (5 cm of position noise: 10 to
    25 %, against the 2 % of ideal sensors; 1 cm already keeps it above 2 %) and the swarm would
    stay on the ground for ever. A tick is then calm also when the disagreement has stopped
    falling: its mean over the last ``settle_window_ticks`` is within a factor
    :data:`PLATEAU_RATIO` of its mean over the window before (both windows since the membership
    view last changed). The estimator's start-up transient falls faster than that (by more than
    half a second on the paper's swarm) and a rise (first messages, a neighbour's jump) is faster
    too, so neither counts; noise around its floor does. Ideal sensors keep the 2 % rule alone."""

    def __init__(self, k: int, config: AgentConfig) -> None:
        self.k = k
        self.ticks = config.settle_ticks
        self.tolerance = config.settle_tolerance
        self.plateau = config.settle_plateau
        self.window = config.settle_window_ticks
        #: the plateau rule's disagreement history, a ring of two windows per row, its samples
        #: written and those since the membership view last changed
        self._history = np.zeros((k, 2 * self.window if self.plateau else 0))
        self._written = np.zeros(k, dtype=np.int64)
        self._since = np.zeros(k, dtype=np.int64)
        self.timeout = config.consensus.heard_timeout_ticks
        self.calm_ticks = np.zeros(k, dtype=np.int64)
        self._members: list[frozenset[int] | None] = [None] * k
        self.level = np.zeros(k, dtype=np.int64)
        self.ready = np.zeros(k, dtype=bool)
        self._m = 0
        self._round = np.zeros((k, 0), dtype=np.int64)  # newest round heard [row, sender]
        self._level = np.zeros((k, 0), dtype=np.int64)  # its level
        self._mask: tuple[frozenset[int] | None, npt.NDArray[np.bool_]] = (None, np.zeros(0, bool))
        self.update((), 0, (), (), NO_ARRIVALS, frozenset(), ())  # its compiled pass loaded now

    def _grow(self, m: int) -> None:
        pad = max(m, 2 * self._m) - self._m
        self._round = np.hstack([self._round, np.full((self.k, pad), _NO_ROUND, np.int64)])
        self._level = np.hstack([self._level, np.zeros((self.k, pad), np.int64)])
        self._m += pad

    def _member_masks(self, views: list[frozenset[int]]) -> npt.NDArray[np.bool_]:
        """The membership views as masks (len(views), M), one per distinct view (most rows share
        one view object, tick after tick)."""
        masks = np.empty((len(views), self._m), dtype=bool)
        for p, view in enumerate(views):
            masks[p] = self._member_mask(view)
        return masks

    def _member_mask(self, members: frozenset[int]) -> npt.NDArray[np.bool_]:
        view, mask = self._mask
        if view is not members or mask.shape[0] != self._m:
            mask = np.zeros(self._m, dtype=bool)
            mask[[j for j in members if 0 <= j < self._m]] = True
            self._mask = (members, mask)
        return mask

    def agrees(self, row: int) -> bool:
        """Row ``row``'s estimate agrees with its neighbours' (``settle_ticks`` calm ticks)."""
        return bool(self.calm_ticks[row] >= self.ticks)

    def reset(self, row: int) -> None:
        """Row ``row`` starts again (a new life of its agent): no calm tick, nothing heard."""
        self.calm_ticks[row] = 0
        self._since[row] = 0
        self._members[row] = None
        self.level[row] = 0
        self.ready[row] = False
        self._round[row] = _NO_ROUND
        self._level[row] = 0

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
        """Rows ``rows`` (distinct) at round ``round_`` (their outputs' message round), with
        their outputs' ``disagreement`` and ``ready_to_fly``, the messages that arrived
        (``arrivals``, in each row's inbox order; those to other rows are ignored), the
        membership view (one for all rows, or one per row), whether each already flies and
        whether each one's vehicle can fly (None: all can); whether each is ready (also
        :attr:`ready`, and the new levels :attr:`level`, by row)."""
        rows_arr = np.asarray(rows, dtype=np.intp)
        n_rows = rows_arr.shape[0]
        one_view, views, calm = self._calm(rows_arr, disagreement, members)
        caps, member = self._flood_inputs(rows_arr, arrivals, one_view, views)
        ready = np.empty(n_rows, dtype=np.bool_)
        _readiness_rows(
            rows_arr,
            calm,
            np.asarray(ready_to_fly, dtype=np.bool_),
            np.asarray(committed, dtype=np.bool_),
            np.ones(n_rows, dtype=np.bool_)
            if vehicle_ready is None
            else np.asarray(vehicle_ready, dtype=np.bool_),
            int(self.ticks),
            self.calm_ticks,
            np.ascontiguousarray(arrivals.receiver, dtype=np.intp),
            np.ascontiguousarray(arrivals.sender, dtype=np.intp),
            np.ascontiguousarray(arrivals.round, dtype=np.int64),
            np.ascontiguousarray(arrivals.level, dtype=np.int64),
            self._round,
            self._level,
            int(round_) - 1 - self.timeout,
            member,
            caps,
            self.level,
            self.ready,
            ready,
        )
        return ready

    def _calm(
        self,
        rows: npt.NDArray[np.intp],
        disagreement: Sequence[float] | npt.NDArray[np.float64],
        members: frozenset[int] | Sequence[frozenset[int]],
    ) -> tuple[frozenset[int] | None, list[frozenset[int]], npt.NDArray[np.bool_]]:
        """:meth:`update`'s calm test: the one view of all rows (None: one per row), each row's
        view, and whether each row is calm this tick (below the tolerance, or on its plateau,
        with the same membership view as at its last update, which is recorded)."""
        n_rows = rows.shape[0]
        rows_list = rows.tolist()
        one_view: frozenset[int] | None = None
        if isinstance(members, frozenset):
            one_view, views = members, [members] * n_rows
        else:
            views = list(members)
        last = self._members
        if one_view is not None and all(last[r] is one_view for r in rows_list):  # usual
            same = np.ones(n_rows, dtype=bool)
        else:
            same = np.fromiter(
                (
                    (m is v or m == v)
                    for m, v in zip((last[r] for r in rows_list), views, strict=True)
                ),
                dtype=bool,
                count=n_rows,
            )
            for r, v in zip(rows_list, views, strict=True):
                last[r] = v
        values = np.asarray(disagreement, dtype=float)
        below = values < self.tolerance
        if self.plateau:
            below |= self._stopped_falling(rows, values, same)
        return one_view, views, below & same

    def _flood_inputs(
        self,
        rows: npt.NDArray[np.intp],
        arrivals: Arrivals,
        one_view: frozenset[int] | None,
        views: list[frozenset[int]],
    ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_]]:
        """The settled-level flood's inputs besides the arrivals: the tables grown to every
        sender and row (the newest (round, level) per sender is kept, the first copy of its
        highest round), each row's cap (its view's size, at least 1) and the membership masks
        (one for all rows, or one per row)."""
        receiver, sender = arrivals.receiver, arrivals.sender
        if sender.shape[0]:
            top = max(int(sender.max()), int(receiver.max()))
            if top >= self._m:
                self._grow(top + 1)
        n_rows = rows.shape[0]
        if n_rows and int(rows.max()) >= self._m:
            self._grow(int(rows.max()) + 1)
        if one_view is not None:
            caps = np.full(n_rows, max(len(one_view), 1), dtype=np.int64)
            return caps, self._member_mask(one_view)[None]
        caps = np.fromiter((max(len(v), 1) for v in views), dtype=np.int64, count=n_rows)
        return caps, self._member_masks(views)

    def _stopped_falling(
        self,
        rows: npt.NDArray[np.intp],
        values: npt.NDArray[np.float64],
        same: npt.NDArray[np.bool_],
    ) -> npt.NDArray[np.bool_]:
        """The plateau rule: each row's disagreement written to its history; whether its mean
        over the last window is within :data:`PLATEAU_RATIO` of the window before's (two whole
        windows since the membership view changed)."""
        span = 2 * self.window
        written = self._written[rows]
        self._history[rows, written % span] = values
        written += 1
        self._written[rows] = written
        since = np.where(same, self._since[rows] + 1, 1)
        self._since[rows] = since
        back = (written[:, None] - 1 - np.arange(span)[None, :]) % span
        recent_prev = self._history[rows[:, None], back].reshape(-1, 2, self.window).sum(axis=2)
        recent, prev = recent_prev[:, 0], recent_prev[:, 1]
        flat = (recent >= PLATEAU_RATIO * prev) & (PLATEAU_RATIO * recent <= prev)
        return flat & (since >= span)


@dataclass(frozen=True)
class Arrivals:
    """The consensus messages that arrived at a tick, as arrays (M,) in delivery order (each
    receiver's messages in its inbox order): ``receiver`` row, the message's ``sender``,
    ``round``, ``level`` (its ``ready_hops``) and ``takeoff`` (its ``takeoff_round``, -1 for
    None; None: no message says one)."""

    receiver: npt.NDArray[np.intp]
    sender: npt.NDArray[np.intp]
    round: npt.NDArray[np.int64]
    level: npt.NDArray[np.int64]
    takeoff: npt.NDArray[np.int64] | None = None

    @staticmethod
    def of_inboxes(
        rows: Sequence[int],
        inboxes: Sequence[Sequence[ConsensusMessage]],
        with_takeoff: bool = True,
    ) -> Arrivals:
        """The arrivals of the inboxes of rows ``rows`` (one inbox each, in order); their
        take-off rounds too unless not ``with_takeoff``. Given as
        :class:`~drone_agent.core.inboxes.Inboxes` (a host's agents, whose inboxes share most
        messages: each reaches every agent of the process in range), each distinct message is
        read once and its values indexed out (a 50-agent process read ~16 values an agent-tick
        one by one: 8 % of its time)."""
        if isinstance(inboxes, Inboxes):
            messages, which = inboxes.distinct()
            counts: Sequence[int] = inboxes.counts
        else:
            messages = [m for inbox in inboxes for m in inbox]
            which, counts = None, [len(b) for b in inboxes]
        n = len(messages)
        receiver = np.repeat(np.asarray(rows, dtype=np.intp), counts)
        sender = np.fromiter((m.sender for m in messages), dtype=np.intp, count=n)
        rounds = np.fromiter((m.round for m in messages), dtype=np.int64, count=n)
        levels = np.fromiter((m.ready_hops for m in messages), dtype=np.int64, count=n)
        takeoff = None
        if with_takeoff:
            said = (m.takeoff_round for m in messages)
            takeoff = np.fromiter((_NO_TAKEOFF if t is None else t for t in said), np.int64, n)
        if which is not None:
            sender, rounds, levels = sender[which], rounds[which], levels[which]
            takeoff = None if takeoff is None else takeoff[which]
        return Arrivals(receiver, sender, rounds, levels, takeoff)


class TakeoffClock:
    """One agent's take-off clock: row ``row`` of a :class:`BatchTakeoff` (a batch of its own
    unless ``batch`` is given), for an agent not ticked with others. The rule is the batch's."""

    def __init__(
        self, heard_timeout_ticks: int, batch: BatchTakeoff | None = None, row: int = 0
    ) -> None:
        self.batch = batch if batch is not None else BatchTakeoff(1, heard_timeout_ticks)
        self.row = row

    @property
    def advertised(self) -> int | None:
        """The round this flying agent advertises (None when it does not fly)."""
        t = int(self.batch.advertised[self.row])
        return None if t < 0 else t

    @property
    def round(self) -> int | None:
        """The take-off round the plan is flown on: its own while it flies, else the least one
        heard lately, else None (the swarm has not left the ground)."""
        return self.batch.round_of(self.row)

    def reset(self) -> None:
        """A new life of the agent: no round advertised or heard."""
        self.batch.reset(self.row)

    def update(self, round_: int, committed: bool, inbox: Sequence[ConsensusMessage]) -> int | None:
        """This tick's round, whether the agent flies (after this tick's decision) and the
        messages that arrived; the round to advertise (None: none)."""
        arrivals = Arrivals.of_inboxes((self.row,), (inbox,))
        return self.batch.update((self.row,), round_, (committed,), arrivals)[0]


#: No take-off round (:class:`BatchTakeoff`'s arrays).
_NO_TAKEOFF = -1
#: No message (a tick's arrivals).
NO_ARRIVALS = Arrivals(
    np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp),
    np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64),
)  # fmt: skip
#: no take-off round heard now (:func:`_takeoff_update`)
_UNHEARD = int(np.iinfo(np.int64).max)


class BatchTakeoff:
    """The round the swarm left the ground, agreed by K agents at once (rows ``0..k-1``): the
    clock the plan is flown on (protocols/model/plan_timing.py). ``swarm simulate``'s agents in
    one call a tick, a ``swarm agent`` process's in one call per pass; :class:`TakeoffClock` is
    one row of it.

    An agent that flies (``committed``) advertises a take-off round on its consensus messages
    (``takeoff_round``): the round it decided to fly, lowered to the least one its neighbours
    advertise. Agents that leave together decide at the same round (the settled-level flood,
    :class:`BatchReadiness`, brings every agent to the cap at the same round when no message is
    lost); where losses split them by a few ticks, the least round floods through the flying
    swarm within its diameter in ticks, while the plan's climb is still at rest. An agent that
    does not fly (on the ground, or climbing back to rejoin) flies the plan on the least round
    its neighbours advertise (heard within the heard timeout): a drone re-armed after a rejoin
    joins the swarm's clock, not one of its own. Landed, it forgets its round: the next take-off
    has its own. Call :meth:`update` once per tick after the flight phase decided; put
    :attr:`advertised` on the tick's consensus message; :meth:`rounds` is what the next tick's
    plan time uses."""

    def __init__(self, k: int, heard_timeout_ticks: int) -> None:
        self.timeout = heard_timeout_ticks
        self.advertised = np.full(k, _NO_TAKEOFF, dtype=np.int64)
        self._heard = np.full(k, _NO_TAKEOFF, dtype=np.int64)
        self._heard_at = np.zeros(k, dtype=np.int64)
        self.update((), 0, (), NO_ARRIVALS)  # its compiled pass loaded now, not at a first tick

    def reset(self, row: int) -> None:
        """Row ``row`` starts again (a new life of its agent): no round advertised or heard."""
        self.advertised[row] = _NO_TAKEOFF
        self._heard[row] = _NO_TAKEOFF
        self._heard_at[row] = 0

    def round_of(self, row: int) -> int | None:
        """:meth:`rounds` of one row."""
        t = int(self.advertised[row])
        if t < 0:
            t = int(self._heard[row])
        return None if t < 0 else t

    def rounds(self, rows: Sequence[int]) -> list[int | None]:
        """The take-off round each row of ``rows`` flies the plan on: its own while it flies,
        else the least one heard lately, else None (the swarm has not left the ground)."""
        r = np.asarray(rows, dtype=np.intp)
        out = np.where(self.advertised[r] >= 0, self.advertised[r], self._heard[r])
        return [None if t < 0 else t for t in out.tolist()]

    def update(
        self,
        rows: Sequence[int],
        round_: int,
        committed: Sequence[bool],
        arrivals: Arrivals,
    ) -> list[int | None]:
        """Rows ``rows`` (distinct) at round ``round_``, whether each flies (after this tick's
        decision) and the messages that arrived (those to other rows are ignored); the rounds
        each advertises (None: none). A flying row advertises the round it decided to fly,
        lowered to the least one heard; a row that does not fly advertises none and flies the
        plan on the least one heard within the heard timeout."""
        r = np.asarray(rows, dtype=np.intp)
        out = np.empty(r.shape[0], dtype=np.int64)
        takeoff = arrivals.takeoff
        if takeoff is None:
            takeoff = np.full(arrivals.receiver.shape[0], _NO_TAKEOFF, dtype=np.int64)
        _takeoff_update(
            r, int(round_), np.asarray(committed, dtype=np.bool_),
            np.asarray(arrivals.receiver, dtype=np.intp), np.asarray(takeoff, dtype=np.int64),
            int(self.timeout), self.advertised, self._heard, self._heard_at, out,
        )  # fmt: skip
        return [None if t < 0 else t for t in out.tolist()]


@jit
def _takeoff_update(  # type: ignore[no-untyped-def]
    rows, round_, flies, receiver, takeoff, timeout, advertised, heard, heard_at, out
):
    """:meth:`BatchTakeoff.update` in one pass (a dozen numpy calls and ``np.minimum.at`` took
    ~130 us a tick at 25 drones): the least take-off round each row heard now, then per row of
    ``rows`` the round it holds (``heard``, ``heard_at``, forgotten after ``timeout`` rounds of
    silence) and the one it advertises (``out``, -1 for none). A receiver outside the table is
    not filed."""
    k = advertised.shape[0]
    none = _UNHEARD
    least = np.full(k, none, dtype=np.int64)
    for t in range(receiver.shape[0]):
        said, at = takeoff[t], receiver[t]
        if said >= 0 and 0 <= at < k and said < least[at]:
            least[at] = said
    for i in range(rows.shape[0]):
        r = rows[i]
        held = heard[r]
        if least[r] != none:
            held = least[r]
            heard_at[r] = round_
        elif held >= 0 and round_ - heard_at[r] > timeout:
            held = _NO_TAKEOFF
        heard[r] = held
        own = advertised[r] if advertised[r] >= 0 else round_
        if held >= 0 and held < own:
            own = held
        advertised[r] = own if flies[i] else _NO_TAKEOFF
        out[i] = advertised[r]


#: :class:`Request` by its code in the compiled rule (:func:`_decide_row`)
REQUESTS = (Request.NONE, Request.ARM_OFFBOARD, Request.LAND_MODE, Request.HOLD_MODE)
_R_NONE, _R_ARM_OFFBOARD, _R_LAND, _R_HOLD = 0, 1, 2, 3
#: the setpoint an order sends, by its code in the compiled rule: the core's, the hover one
#: (:func:`hover_setpoint`), the idle one (:func:`idle_setpoint`)
_SENT_CORE, _SENT_HOVER, _SENT_IDLE = 0, 1, 2
_FLY, _GROUND = int(FlightCommand.FLY), int(FlightCommand.GROUND)
_M_WARMUP, _M_READY, _M_FLYING = int(AgentMode.WARMUP), int(AgentMode.READY), int(AgentMode.FLYING)
_M_LANDING, _M_HOLDING = int(AgentMode.LANDING), int(AgentMode.HOLDING)
_M_LANDED = int(AgentMode.LANDED)
#: a vehicle's land detector as the compiled rule takes it: -1 says nothing, 0 off, 1 on the ground
ON_GROUND_UNKNOWN = -1


@jit
def _airborne(armed, on_ground, altitude_m):  # type: ignore[no-untyped-def]
    """Armed, or off the ground: its motors must not be cut by a setpoint. Off the ground: as its
    land detector says where it says (``on_ground`` 0 or 1; -1 says nothing), else above
    :data:`AIRBORNE_ALTITUDE_M` (a vehicle whose estimate wanders by more than that reports its
    landed state)."""
    if armed:
        return True
    if on_ground >= 0:
        return on_ground == 0
    return altitude_m > AIRBORNE_ALTITUDE_M


@jit
def _decide_row(  # type: ignore[no-untyped-def]
    command,
    arm_allowed,
    converged,
    has_setpoint,
    thrust,
    commanded_altitude_m,
    armed,
    in_offboard,
    in_land,
    in_hold,
    altitude_m,
    on_ground,
    committed,
    landed,
    handed_over,
    min_thrust,
):
    """The one rule of a tick's order (:meth:`FlightPhase.decide`, module doc), on one agent's
    numbers: ``command`` a FlightCommand's value, the core's setpoint's thrust (read only with
    ``has_setpoint``), ``on_ground`` as :func:`_airborne` takes it, and the phase's three
    latches. Returns (mode, request, sent, committed, landed, handed_over): :class:`AgentMode`'s
    value, the :data:`REQUESTS` code, the setpoint to send (``_SENT_*``), the new latches."""
    airborne = _airborne(armed, on_ground, altitude_m)
    sent = _SENT_CORE
    mode = _M_WARMUP
    request = _R_NONE
    decided = False
    if command == _FLY:
        if has_setpoint and arm_allowed and (committed or converged):
            committed, landed = True, False
            decided = True
            if armed and in_offboard:
                handed_over = False
                mode = _M_FLYING
            else:  # arming, or taking the vehicle back from a failsafe or from LAND
                mode = _M_FLYING if armed else _M_READY
                request = _R_ARM_OFFBOARD
        elif airborne:  # nothing valid to fly: the autopilot holds its altitude
            decided = True
            mode, sent = _M_HOLDING, _SENT_HOVER
            request = _R_NONE if in_hold else _R_HOLD
    elif airborne:  # LAND or GROUND
        decided = True
        mode = _M_LANDING
        if in_land:  # handed over (or its own failsafe): it lands and disarms
            handed_over = True
            sent = _SENT_HOVER
        elif (
            command == _GROUND
            or commanded_altitude_m <= LAND_HANDOVER_ALTITUDE_M
            or altitude_m <= TOUCHDOWN_FLOOR_M
            or not has_setpoint
        ):
            handed_over = True
            request = _R_LAND
            sent = _SENT_CORE if has_setpoint else _SENT_HOVER
    if not decided:  # disarmed on the ground
        handed_over = False
        if committed:
            committed, landed = False, True
        sent = _SENT_IDLE
        mode = _M_LANDED if landed else _M_READY if converged else _M_WARMUP
    # the invariant: an airborne vehicle gets at least the minimum thrust
    if sent == _SENT_CORE and airborne and not thrust >= min_thrust:
        sent = _SENT_HOVER
    return mode, request, sent, committed, landed, handed_over


@jit
def _decide_rows(  # type: ignore[no-untyped-def]
    rows,
    command,
    arm_allowed,
    converged,
    has_setpoint,
    setpoint,
    limited,
    commanded_altitude_m,
    armed,
    in_offboard,
    in_land,
    in_hold,
    altitude_m,
    on_ground,
    yaw_rad,
    committed,
    landed,
    handed_over,
    min_thrust,
    hover_thrust,
    mode_out,
    request_out,
    setpoint_out,
    limited_out,
):
    """:func:`_decide_row` for each of ``rows`` (the batch's latches, indexed by row, updated in
    place), the p-th row's inputs and outputs at p: ``setpoint`` and ``setpoint_out`` (P, 4)
    roll, pitch, yaw, thrust (the hover and idle ones level at ``yaw_rad``)."""
    for p in range(rows.shape[0]):
        r = rows[p]
        mode, request, sent, committed[r], landed[r], handed_over[r] = _decide_row(
            command[p], arm_allowed[p], converged[p], has_setpoint[p], setpoint[p, 3],
            commanded_altitude_m[p], armed[p], in_offboard[p], in_land[p], in_hold[p],
            altitude_m[p], on_ground[p], committed[r], landed[r], handed_over[r], min_thrust,
        )  # fmt: skip
        mode_out[p], request_out[p] = mode, request
        if sent == _SENT_CORE:
            setpoint_out[p, :] = setpoint[p, :]
            limited_out[p] = limited[p]
        else:
            setpoint_out[p, 0], setpoint_out[p, 1], setpoint_out[p, 2] = 0.0, 0.0, yaw_rad[p]
            setpoint_out[p, 3] = hover_thrust if sent == _SENT_HOVER else 0.0
            limited_out[p] = False


@dataclass(frozen=True)
class BatchOrders:
    """A :meth:`BatchFlightPhase.decide` call's orders, the p-th of its rows at p: ``mode``
    (P,) :class:`AgentMode` values, ``request`` (P,) :data:`REQUESTS` codes, ``setpoint`` (P, 4)
    roll, pitch, yaw (rad) and normalised thrust, ``limited`` (P,)."""

    mode: npt.NDArray[np.int64]
    request: npt.NDArray[np.int64]
    setpoint: FloatArray
    limited: npt.NDArray[np.bool_]


class BatchFlightPhase:
    """The flight phases of ``n`` agents (the module doc's rule, :func:`_decide_row`), as
    arrays: the latches ``committed``, ``landed`` and ``handed_over`` (n,), and one compiled
    call per tick for the rows that decide (:meth:`decide`). :class:`FlightPhase` is a view of
    one row."""

    def __init__(self, n: int, limits: ThrustLimits) -> None:
        warm_up(limits)
        self.limits = limits
        #: decided to fly; latched until the vehicle is disarmed on the ground again
        self.committed = np.zeros(n, dtype=np.bool_)
        #: has landed (disarmed on the ground after flying) and not flown since
        self.landed = np.zeros(n, dtype=np.bool_)
        #: the vehicle was handed to the autopilot's LAND mode: its disarm is expected
        self.handed_over = np.zeros(n, dtype=np.bool_)
        #: the least thrust (0..1 of the maximum) an airborne vehicle may be sent
        self.min_thrust = limits.thrust_range_n[0] / limits.max_thrust_n
        #: the thrust of :func:`hover_setpoint`
        self.hover_thrust = hover_setpoint(limits, 0.0).thrust_normalised

    def reset(self, row: int) -> None:
        """Row ``row`` starts afresh (a new agent of that drone)."""
        self.committed[row] = self.landed[row] = self.handed_over[row] = False

    def decide(
        self,
        rows: Sequence[int],
        command: npt.ArrayLike,
        arm_allowed: npt.ArrayLike,
        converged: npt.ArrayLike,
        setpoints: Sequence[Setpoint | None],
        commanded_altitude_m: npt.ArrayLike,
        vehicles: VehicleArrays,
        yaw_rad: npt.ArrayLike,
    ) -> BatchOrders:
        """Each of ``rows``' order of this tick, its inputs at the same place in the others (a
        :class:`FlightCommand` value each, the core's checked setpoint or None, the plan's
        centre altitude (m, up), what its vehicle reports, its heading)."""
        k = len(rows)
        has = np.array([s is not None for s in setpoints], dtype=np.bool_)
        sp = np.zeros((k, 4))
        lim = np.zeros(k, dtype=np.bool_)
        for p, s in enumerate(setpoints):
            if s is not None:
                sp[p] = (s.roll_rad, s.pitch_rad, s.yaw_rad, s.thrust_normalised)
                lim[p] = s.limited
        orders = BatchOrders(
            np.zeros(k, dtype=np.int64),
            np.zeros(k, dtype=np.int64),
            np.zeros((k, 4)),
            np.zeros(k, dtype=np.bool_),
        )
        c = np.ascontiguousarray  # one compiled form: every array C-ordered
        _decide_rows(
            c(rows, dtype=np.int64),
            c(command, dtype=np.int64),
            c(arm_allowed, dtype=np.bool_),
            c(converged, dtype=np.bool_),
            has,
            sp,
            lim,
            c(commanded_altitude_m, dtype=np.float64),
            c(vehicles.armed, dtype=np.bool_),
            c(vehicles.in_offboard, dtype=np.bool_),
            c(vehicles.in_land, dtype=np.bool_),
            c(vehicles.in_hold, dtype=np.bool_),
            c(vehicles.altitude_m, dtype=np.float64),
            c(vehicles.on_ground, dtype=np.int64),
            c(yaw_rad, dtype=np.float64),
            self.committed,
            self.landed,
            self.handed_over,
            self.min_thrust,
            self.hover_thrust,
            orders.mode,
            orders.request,
            orders.setpoint,
            orders.limited,
        )
        return orders


@dataclass(frozen=True)
class VehicleArrays:
    """What P vehicles last reported (:class:`VehicleView`'s fields as arrays): ``armed``,
    ``in_offboard``, ``in_land``, ``in_hold`` (P,) bool, ``altitude_m`` (P,) m up, ``on_ground``
    (P,) -1 (the vehicle says nothing: the altitude decides), 0 or 1."""

    armed: npt.NDArray[np.bool_]
    in_offboard: npt.NDArray[np.bool_]
    in_land: npt.NDArray[np.bool_]
    in_hold: npt.NDArray[np.bool_]
    altitude_m: FloatArray
    on_ground: npt.NDArray[np.int64]

    @classmethod
    def of(cls, views: Sequence[VehicleView]) -> VehicleArrays:
        """The arrays of ``views``."""
        return cls(
            np.array([v.armed for v in views], dtype=np.bool_),
            np.array([v.in_offboard for v in views], dtype=np.bool_),
            np.array([v.in_land for v in views], dtype=np.bool_),
            np.array([v.in_hold for v in views], dtype=np.bool_),
            np.array([v.altitude_m for v in views], dtype=np.float64),
            np.array([_on_ground_code(v.on_ground) for v in views], dtype=np.int64),
        )

    def view(self, p: int) -> VehicleView:
        """The p-th vehicle's :class:`VehicleView` (the inverse of :meth:`of`)."""
        g = int(self.on_ground[p])
        return VehicleView(
            bool(self.armed[p]),
            bool(self.in_offboard[p]),
            bool(self.in_land[p]),
            bool(self.in_hold[p]),
            float(self.altitude_m[p]),
            None if g == ON_GROUND_UNKNOWN else bool(g),
        )


def _on_ground_code(on_ground: bool | None) -> int:
    return ON_GROUND_UNKNOWN if on_ground is None else int(bool(on_ground))


class FlightPhase:
    """One agent's flight phase (see the module doc): row ``row`` of a :class:`BatchFlightPhase`
    (a batch of its own unless ``batch`` is given), started afresh. Call :meth:`decide` once per
    tick (or the batch's for several rows at once)."""

    def __init__(
        self, limits: ThrustLimits, batch: BatchFlightPhase | None = None, row: int = 0
    ) -> None:
        self.limits = limits
        self.batch = batch if batch is not None else BatchFlightPhase(1, limits)
        self.row = row
        self.batch.reset(row)

    @property
    def committed(self) -> bool:
        """Decided to fly; latched until the vehicle is disarmed on the ground again."""
        return bool(self.batch.committed[self.row])

    @property
    def landed(self) -> bool:
        """Has landed (disarmed on the ground after flying) and not flown since."""
        return bool(self.batch.landed[self.row])

    @property
    def handed_over(self) -> bool:
        """The vehicle was handed to the autopilot's LAND mode: its disarm is expected."""
        return bool(self.batch.handed_over[self.row])

    @property
    def min_thrust_normalised(self) -> float:
        """The least thrust (0..1 of the maximum) an airborne vehicle may be sent."""
        return self.batch.min_thrust

    def decide(
        self,
        command: FlightCommand,
        arm_allowed: bool,
        converged: bool,
        setpoint: Setpoint | None,
        commanded_altitude_m: float,
        vehicle: VehicleView,
        yaw_rad: float,
    ) -> Order:
        """The order of this tick.

        ``converged``: the estimator has settled (the adapter's rule); ``setpoint``: the core's
        checked setpoint, None if it has none; ``commanded_altitude_m``: the plan's centre
        altitude now (m, up); ``yaw_rad``: the vehicle's heading, for level setpoints.
        """
        b, r = self.batch, self.row
        thrust = 0.0 if setpoint is None else float(setpoint.thrust_normalised)
        mode, request, sent, committed, landed, handed = _decide_row(
            int(command), bool(arm_allowed), bool(converged), setpoint is not None, thrust,
            float(commanded_altitude_m), bool(vehicle.armed), bool(vehicle.in_offboard),
            bool(vehicle.in_land), bool(vehicle.in_hold), float(vehicle.altitude_m),
            _on_ground_code(vehicle.on_ground), bool(b.committed[r]), bool(b.landed[r]),
            bool(b.handed_over[r]), b.min_thrust,
        )  # fmt: skip
        b.committed[r], b.landed[r], b.handed_over[r] = committed, landed, handed
        if sent == _SENT_CORE:
            assert setpoint is not None  # (the rule sends the core's only when there is one)
            order_setpoint = setpoint
        elif sent == _SENT_HOVER:
            order_setpoint = hover_setpoint(self.limits, yaw_rad)
        else:
            order_setpoint = idle_setpoint(yaw_rad)
        return _new_order(MODE_OF[mode], order_setpoint, REQUESTS[request])


_warm = False


def warm_up(limits: ThrustLimits) -> None:
    """Load the flight phase's compiled rule in both its forms (one row, a batch) once per
    process, compiling it first if numba's cache does not have it: a first tick must not pay it
    (as drone_agent.core.agent_core.warm_up). Called by :class:`BatchFlightPhase`."""
    global _warm
    if _warm:
        return
    _warm = True
    view = VehicleView(False, False, False, False, 0.0)
    FlightPhase(limits).decide(FlightCommand.GROUND, False, False, None, 0.0, view, 0.0)
    BatchFlightPhase(1, limits).decide(
        [0], [int(FlightCommand.GROUND)], [False], [False], [None], [0.0],
        VehicleArrays.of([view]), [0.0],
    )  # fmt: skip


@jit
def _readiness_rows(  # type: ignore[no-untyped-def]
    rows,
    calm,
    fly,
    flying,
    vehicle_ready,
    ticks,
    calm_ticks,
    receiver,
    sender,
    rounds,
    levels,
    round_table,
    level_table,
    oldest,
    member,
    caps,
    level_out,
    ready_out,
    ready,
):
    """:meth:`BatchReadiness.update` after its calm test, in one pass (it was two dozen numpy
    calls around :func:`_settled_levels`): each row's calm ticks in a row (``calm``: calm this
    tick), whether it agrees (``ticks`` of them and its vehicle ready, or it flies already), the
    flood's levels (:func:`_settled_levels`) into ``level_out`` by row, and whether it is ready
    (``ready`` in row order, ``ready_out`` by row): at the cap and its warm-up over or flying."""
    n = rows.shape[0]
    agrees = np.empty(n, dtype=np.bool_)
    for p in range(n):
        r = rows[p]
        count = calm_ticks[r] + 1 if calm[p] else 0
        calm_ticks[r] = count
        agrees[p] = (count >= ticks and vehicle_ready[p]) or flying[p]
    updating = np.zeros(round_table.shape[0], dtype=np.bool_)
    for p in range(n):
        updating[rows[p]] = True
    level = np.empty(n, dtype=np.int64)
    _settled_levels(rows, updating, receiver, sender, rounds, levels, round_table, level_table,
                    oldest, member, agrees, caps, level)  # fmt: skip
    for p in range(n):
        r = rows[p]
        level_out[r] = level[p]
        ready[p] = level[p] >= caps[p] and (fly[p] or flying[p])
        ready_out[r] = ready[p]


@jit
def _settled_levels(  # type: ignore[no-untyped-def]
    rows,
    updating,
    receiver,
    sender,
    rounds,
    levels,
    round_table,
    level_table,
    oldest,
    member,
    agrees,
    caps,
    out,
):
    """:meth:`BatchReadiness.update`'s flood: the arrivals filed in delivery order (per (row,
    sender) the first copy of its highest round, newer than the one held), senders not heard
    since round ``oldest`` or not in the row's view (``member`` (P, M), or (1, M): one view for
    every row) dropped, and each row's
    level: 0 unless it agrees, else ``min(cap, 1 + the lowest level held)`` (``cap`` with
    none; ``caps`` (P,))."""
    for t in range(receiver.shape[0]):
        r, j = receiver[t], sender[t]
        if updating[r] and rounds[t] > round_table[r, j]:
            round_table[r, j] = rounds[t]
            level_table[r, j] = levels[t]
    shared = member.shape[0] - 1  # 0: one view for all rows
    for p in range(rows.shape[0]):
        r = rows[p]
        cap = caps[p]
        lowest = cap
        v = min(p, shared)
        for j in range(round_table.shape[1]):
            if round_table[r, j] < oldest or not member[v, j]:
                round_table[r, j] = _NO_ROUND
            elif round_table[r, j] != _NO_ROUND:
                lowest = min(lowest, level_table[r, j])
        out[p] = min(cap, 1 + lowest) if agrees[p] else 0

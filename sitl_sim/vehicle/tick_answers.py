"""Whether each vehicle's agent keeps up with the control ticks. Pure.

Every control tick the simulator sends each agent its vehicle's state stamped with the tick's
``time_boot_ms``, and the agent answers with a setpoint echoing that stamp (the lockstep
handshake, protocols/mavlink/conventions.py). In realtime nothing waits for the answer: an agent
that falls behind answers late or skips ticks, its vehicle flies stale setpoints and, past the
offboard timeout, fails safe. This tracker makes that visible:

- a tick is *answered in time* when its echo arrives before the next tick's state goes out;
  ticks left unanswered count as missed once the agent answers again (a silence that never ends
  is an agent that died, a drop-out, not an overload); the ticks before an agent's first answer
  are not counted (an agent still starting, e.g. a hundred of them joining the swarm in the
  first pass of their processes, is not late: its vehicle waits on the ground, disarmed, as the
  lag below reads it too);
- the *lag* of an agent is how many ticks its vehicle has gone without a fresh answer: sampled
  as each tick goes out (the newest tick sent, minus the newest tick echoed, minus one: 0 for an
  agent that answered the previous tick), and, like the misses, counted once the agent answers
  again;
- only *active* agents count: those that echoed at least once in the interval.

:meth:`TickAnswers.interval` returns the figures of the interval since the last call and starts a
new one (the simulator calls it once per status line). In lockstep every tick is answered by
construction (time waits), so the figures only matter in realtime.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

IntArray = npt.NDArray[np.int64]

#: An agent (or the swarm) that answers fewer ticks in time than this, or whose vehicle went
#: this long (ms) without a fresh answer, is late / overloaded: a risk of failsafes (the offboard
#: timeout is 500 ms). A well-fed swarm answers > 99 % in time with a lag of one tick or less.
OVERLOAD_SHARE = 0.9
OVERLOAD_LAG_MS = 200.0


@dataclass(frozen=True)
class AnswerStats:
    """One interval: per vehicle (N,), the ticks expected and answered in time and the worst lag
    (ticks); ``active`` (N,) the vehicles whose agent echoed in the interval."""

    expected: IntArray
    in_time: IntArray
    worst_lag_ticks: IntArray
    active: npt.NDArray[np.bool_]
    period_ms: float = 20.0

    def share(self, vehicle: int) -> float | None:
        """Share of vehicle ``vehicle``'s ticks answered in time; None if it had none."""
        if not self.active[vehicle] or self.expected[vehicle] == 0:
            return None
        return float(self.in_time[vehicle] / self.expected[vehicle])

    @property
    def swarm_share(self) -> float | None:
        """Share of the active agents' ticks answered in time; None with no active agent."""
        expected = int(self.expected[self.active].sum())
        return None if expected == 0 else float(self.in_time[self.active].sum() / expected)

    @property
    def worst_lag(self) -> int:
        """The worst lag (ticks) of any active agent."""
        return int(self.worst_lag_ticks[self.active].max(initial=0))

    def lag_ms(self, vehicle: int) -> float:
        return float(self.worst_lag_ticks[vehicle]) * self.period_ms

    def late(self, vehicle: int) -> bool:
        """Vehicle ``vehicle``'s agent answered too few ticks in time or left it too long."""
        share = self.share(vehicle)
        if share is None:
            return False
        return share < OVERLOAD_SHARE or self.lag_ms(vehicle) >= OVERLOAD_LAG_MS

    @property
    def overloaded(self) -> bool:
        """The active agents together answered too few ticks in time, or one lagged too long."""
        share = self.swarm_share
        if share is None:
            return False
        return share < OVERLOAD_SHARE or self.worst_lag * self.period_ms >= OVERLOAD_LAG_MS


class TickAnswers:
    """The answer bookkeeping of ``n`` vehicles (see the module doc)."""

    def __init__(self, n: int, period_ms: float = 20.0) -> None:
        self.n = n
        self.period_ms = period_ms
        self._current = np.full(n, -1, dtype=np.int64)  # the tick each vehicle awaits an echo of
        self._answered = np.zeros(n, dtype=bool)  # ... and whether it came in time
        self._missed = np.zeros(n, dtype=np.int64)  # ticks gone unanswered since the last echo
        self._pending_lag = np.zeros(n, dtype=np.int64)  # worst lag since the last echo
        self._newest_sent = np.full(n, -1, dtype=np.int64)
        self._newest_echo = np.full(n, -1, dtype=np.int64)
        self._reset()

    def _reset(self) -> None:
        self._expected = np.zeros(self.n, dtype=np.int64)
        self._in_time = np.zeros(self.n, dtype=np.int64)
        self._lag = np.zeros(self.n, dtype=np.int64)
        self._active = np.zeros(self.n, dtype=bool)

    def sent(self, tick: int, vehicles: Iterable[int]) -> None:
        """Tick ``tick``'s state went to the agents of ``vehicles``: the tick they awaited so far
        is missed unless it was answered, the new tick is awaited."""
        idx = np.fromiter(vehicles, dtype=np.int64)
        if idx.size == 0:
            return
        started = self._newest_echo[idx] >= 0  # (an agent not started yet is not late)
        unanswered = idx[started & (self._current[idx] >= 0) & ~self._answered[idx]]
        self._missed[unanswered] += 1
        self._current[idx] = tick
        self._answered[idx] = False
        self._newest_sent[idx] = tick
        known = idx[self._newest_echo[idx] >= 0]
        lag = tick - self._newest_echo[known] - 1
        self._pending_lag[known] = np.maximum(self._pending_lag[known], lag)

    def echo(self, vehicle: int, tick: int | None) -> None:
        """Vehicle ``vehicle``'s agent echoed ``tick`` (None: not a tick stamp)."""
        if tick is None or not 0 <= vehicle < self.n or tick > self._newest_sent[vehicle]:
            return
        self._active[vehicle] = True
        self._newest_echo[vehicle] = max(self._newest_echo[vehicle], tick)
        # the agent is alive: the ticks it let pass were missed, the lag it built up was real
        self._expected[vehicle] += self._missed[vehicle]
        self._missed[vehicle] = 0
        self._lag[vehicle] = max(self._lag[vehicle], self._pending_lag[vehicle])
        self._pending_lag[vehicle] = 0
        if tick == self._current[vehicle] and not self._answered[vehicle]:
            self._answered[vehicle] = True
            self._expected[vehicle] += 1
            self._in_time[vehicle] += 1

    def interval(self) -> AnswerStats:
        """The figures since the last call; starts a new interval."""
        stats = AnswerStats(
            self._expected.copy(),
            self._in_time.copy(),
            self._lag.copy(),
            self._active.copy(),
            self.period_ms,
        )
        self._reset()
        return stats

"""The lockstep barrier (protocols/mavlink/conventions.py, "Lockstep handshake"). Pure.

Simulated time advances one control period once every vehicle in the barrier has echoed the
current tick: its agent's SET_ATTITUDE_TARGET carries the ``time_boot_ms`` of the tick's telemetry.

- A vehicle joins with its agent's first echo of a recent tick (at most ``join_window_ticks``
  old); if the echo is of the current tick it also counts for it, else the vehicle is awaited
  from the next tick on.
- A member is awaited at a tick only if that tick's state was sent to its agent (it cannot echo
  a tick it never saw, e.g. when its agent asked for a lower telemetry rate).
- A member awaited for longer than ``drop_timeout_s`` of wall-clock time leaves the barrier (its
  vehicle then failsafes in simulated time); it may rejoin with a later echo. A vehicle that goes
  silent (a wreck) leaves at once.

Wall-clock times are passed in, so the logic is testable without waiting.
"""

from __future__ import annotations

from collections.abc import Iterable


class LockstepBarrier:
    """Which vehicles' agents hold simulated time, and which of them the current tick awaits."""

    def __init__(self, drop_timeout_s: float, join_window_ticks: int = 50) -> None:
        if not drop_timeout_s > 0:
            raise ValueError("drop_timeout_s must be > 0")
        self.drop_timeout_s = drop_timeout_s
        self.join_window_ticks = join_window_ticks
        self.members: set[int] = set()
        self.awaiting: set[int] = set()
        self.tick = -1
        self._opened_wall_s = 0.0

    def open_tick(self, tick: int, sent_to: Iterable[int], wall_s: float) -> None:
        """Tick ``tick``'s state went to the agents of ``sent_to`` at ``wall_s``."""
        self.tick = tick
        self.awaiting = self.members.intersection(sent_to)
        self._opened_wall_s = wall_s

    def echo(self, vehicle: int, echoed_tick: int | None) -> bool:
        """An agent echoed ``echoed_tick`` (None: not a tick stamp). True if it joined now."""
        if echoed_tick is None or echoed_tick > self.tick:
            return False
        if vehicle in self.members:
            if echoed_tick == self.tick:
                self.awaiting.discard(vehicle)
            return False
        if self.tick - echoed_tick > self.join_window_ticks:
            return False
        self.members.add(vehicle)
        return True

    @property
    def complete(self) -> bool:
        """Every awaited member has echoed the current tick."""
        return not self.awaiting

    def deadline_wall_s(self) -> float | None:
        """Wall-clock time at which the awaited members are dropped (None: nobody awaited)."""
        return self._opened_wall_s + self.drop_timeout_s if self.awaiting else None

    def expire(self, wall_s: float) -> list[int]:
        """Drop the members still awaited at ``wall_s`` past the timeout; the dropped ones."""
        deadline = self.deadline_wall_s()
        if deadline is None or wall_s < deadline:
            return []
        dropped = sorted(self.awaiting)
        self.members.difference_update(dropped)
        self.awaiting.clear()
        return dropped

    def leave(self, vehicle: int) -> None:
        """Vehicle ``vehicle`` leaves at once (it crashed and went silent)."""
        self.members.discard(vehicle)
        self.awaiting.discard(vehicle)

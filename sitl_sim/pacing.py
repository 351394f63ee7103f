"""Pacing simulated time to the wall clock, and measuring the real-time factor. Pure.

The realtime clock runs tick ``k`` no earlier than ``base + (k - k0) * period / speedup`` of wall
time. When the simulator falls behind by more than ``max_lag_s`` it re-bases instead of running
a burst of catch-up ticks: simulated time then simply runs slower than requested, which the
real-time factor shows. Lockstep uses the same pacer while no agent holds the barrier.
"""

from __future__ import annotations


class Pacer:
    """Wall-clock deadlines (s) of control ticks of ``period_s`` simulated seconds."""

    def __init__(self, period_s: float, speedup: float, max_lag_s: float = 0.25) -> None:
        if not (period_s > 0 and speedup > 0):
            raise ValueError("period_s and speedup must be > 0")
        self.wall_period_s = period_s / speedup
        self.max_lag_s = max_lag_s
        self._base_tick = 0
        self._base_wall_s = 0.0

    def rebase(self, tick: int, wall_s: float) -> None:
        """Tick ``tick`` runs at ``wall_s``; later ticks follow at the paced rate."""
        self._base_tick, self._base_wall_s = tick, wall_s

    def deadline(self, tick: int) -> float:
        """Earliest wall-clock time (s) at which tick ``tick`` may run."""
        return self._base_wall_s + (tick - self._base_tick) * self.wall_period_s

    def keep_up(self, tick: int, wall_s: float) -> None:
        """Re-base if tick ``tick`` starts more than ``max_lag_s`` after its deadline."""
        if wall_s - self.deadline(tick) > self.max_lag_s:
            self.rebase(tick, wall_s)


class RateMeter:
    """Real-time factor (simulated seconds per wall second) over the last report interval."""

    def __init__(self, sim_s: float, wall_s: float) -> None:
        self._sim_s, self._wall_s = sim_s, wall_s

    def sample(self, sim_s: float, wall_s: float) -> float:
        """The factor since the previous sample (0 if no wall time passed); starts a new one."""
        d_wall = wall_s - self._wall_s
        rtf = (sim_s - self._sim_s) / d_wall if d_wall > 0 else 0.0
        self._sim_s, self._wall_s = sim_s, wall_s
        return rtf

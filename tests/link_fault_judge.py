"""Did each link fault act on the agents? Judged from the agents' statuses in a flight.tlog (the
neighbours each agent integrated, its estimate of the descriptors), the same way for ``swarm
simulate`` (statuses at 5 Hz) and ``swarm up`` (the ground station's record of every status):

- **loss** p on every link: the share of neighbour messages integrated falls to about 1 - p during
  the fault, and is whole before it;
- **delay** d: the rounds come late, so right after the fault starts each agent integrates
  nothing for about d (no neighbour value of its own rounds has arrived), then integrates
  every neighbour again, late, for the rest of the fault;
- **link cut** i-j (also one-way: a link heard one way is down for both ends): j is absent from
  i's integrated neighbours and i from j's for the fault's span, present before it;
- **partition** into halves: no agent integrates a neighbour of the other half; each half's agents
  agree with each other while the halves' estimates part (each side estimates its own half while
  the formation changes), and they agree again once it ends.

Each judge returns the figures it measured and raises AssertionError naming the fault when the
fault did not act; :func:`judge_link_faults` runs them all.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from gcs.report.tlog import TlogTrack, VehicleTrack

#: Time the agents need to see a link go (the heard-set timeout is a few rounds) or come back, s.
SETTLE_S = 0.3


@dataclass(frozen=True)
class Statuses:
    """Per agent (index = system id - 1): status times (S,), integrated neighbours, estimates."""

    t_s: dict[int, np.ndarray]
    neighbours: dict[int, list[tuple[int, ...]]]
    estimate: dict[int, np.ndarray]

    @classmethod
    def of(cls, track: TlogTrack, drones: Sequence[int]) -> Statuses:
        t, nb, est = {}, {}, {}
        for i in drones:
            v: VehicleTrack = track.vehicles[i + 1]
            ids = [v.neighbour_ids(k) for k in range(v.status_t_s.size)]
            assert all(x is not None for x in ids), f"drone {i}: statuses without neighbour ids"
            t[i], nb[i], est[i] = v.status_t_s, ids, v.status[:, :9]
        return cls(t, nb, est)  # type: ignore[arg-type]

    def between(self, i: int, t0: float, t1: float) -> np.ndarray:
        """Indices of agent i's statuses with t0 <= t <= t1."""
        t = self.t_s[i]
        return np.nonzero((t >= t0) & (t <= t1))[0]

    def period_s(self) -> float:
        """The statuses' period (the median gap), s."""
        return float(np.median(np.concatenate([np.diff(t) for t in self.t_s.values()])))

    def estimate_at(self, i: int, t: float) -> np.ndarray:
        """Agent i's latest estimate at or before t."""
        k = int(np.searchsorted(self.t_s[i], t + 1e-3, side="right")) - 1
        assert k >= 0, (i, t)
        return self.estimate[i][k]


def integrated_share(s: Statuses, t0: float, t1: float, before_s: float = 1.5) -> float:
    """Neighbour messages integrated over ``[t0, t1]`` as a share of those integrated in the
    ``before_s`` before ``t0`` (per status, all agents)."""

    def mean(a: float, b: float) -> float:
        counts = [len(s.neighbours[i][k]) for i in s.t_s for k in s.between(i, a, b)]
        assert counts, (a, b)
        return float(np.mean(counts))

    return mean(t0, t1) / mean(t0 - before_s, t0 - 0.05)


def judge_loss(s: Statuses, t0: float, t1: float, probability: float) -> float:
    """The loss rate the agents saw (1 - share integrated); near ``probability``."""
    seen = 1.0 - integrated_share(s, t0 + SETTLE_S, t1)
    assert abs(seen - probability) < 0.1, f"loss {probability:g}: the agents lost {seen:.2f}"
    return seen


def judge_delay(s: Statuses, t0: float, t1: float, delay_s: float) -> float:
    """Each agent's first stretch without any neighbour integrated after ``t0`` (s, measured from
    the last status with neighbours before it to the first one after it, so at most a status
    period long); about the delay. The longest stretch is returned."""
    period = s.period_s()
    spans = []
    for i in s.t_s:
        ks = s.between(i, t0 - period, t1)
        counts = np.array([len(s.neighbours[i][k]) for k in ks])
        silent = np.nonzero(counts == 0)[0]
        assert silent.size, f"delay {delay_s * 1e3:g} ms: agent {i} never waited for a late round"
        first = silent[0]
        resumed = first + np.argmax(counts[first:] > 0)
        assert counts[first:].max() > 0, f"delay: agent {i} never integrated again"
        t_ks = s.t_s[i][ks]
        span = float(t_ks[resumed] - t_ks[first - 1]) if first else float("inf")
        assert t_ks[first] <= t0 + period + 1e-6, (
            f"delay: agent {i} first waited at {t_ks[first]:.2f} s, not when it began at {t0:g} s"
        )
        assert delay_s - 1e-6 <= span <= delay_s + 3 * period + 1e-6, (
            f"delay {delay_s * 1e3:g} ms: agent {i} waited {span:.2f} s"
        )
        # late, not lost: every neighbour integrated again for the rest of the fault
        late = s.between(i, t0 + delay_s + 3 * period + SETTLE_S, t1)
        whole = max(len(s.neighbours[i][k]) for k in s.between(i, t0 - 1.0, t0 - 0.05))
        assert late.size and all(len(s.neighbours[i][k]) == whole for k in late), (
            f"delay: agent {i} did not integrate its {whole} neighbours late"
        )
        spans.append(span)
    return max(spans)


def judge_cut(s: Statuses, t0: float, t1: float, i: int, j: int) -> float:
    """The share of i's and j's statuses over the cut that still integrated the other (0), after
    both integrated each other before it."""
    for a, b in ((i, j), (j, i)):
        before = s.between(a, t0 - 1.0, t0 - 0.05)
        assert all(b in s.neighbours[a][k] for k in before), f"cut {i}-{j}: not linked before"
    during = [
        b in s.neighbours[a][k]
        for a, b in ((i, j), (j, i))
        for k in s.between(a, t0 + SETTLE_S, t1 - 0.05)
    ]
    assert during, (i, j, t0, t1)
    share = float(np.mean(during))
    assert share == 0.0, f"cut {i}-{j}: still integrated in {share:.0%} of statuses"
    return share


def judge_partition(
    s: Statuses, t0: float, t1: float, halves: tuple[Sequence[int], Sequence[int]]
) -> tuple[float, float]:
    """(largest gap between the halves' mean estimates, largest spread inside a half) over the
    partition (m or m², the worst descriptor); no neighbour across the halves integrated."""
    a, b = (list(h) for h in halves)
    for x, other in ((a, b), (b, a)):
        for i in x:
            across = [set(s.neighbours[i][k]) & set(other) for k in s.between(i, t0 + SETTLE_S, t1)]
            assert not any(across), f"partition: agent {i} integrated {across} across it"

    def split(t: float) -> tuple[float, float]:
        ea = np.array([s.estimate_at(i, t) for i in a])
        eb = np.array([s.estimate_at(i, t) for i in b])
        gap = float(np.abs(ea.mean(axis=0) - eb.mean(axis=0)).max())
        inside = float(max(np.ptp(ea, axis=0).max(), np.ptp(eb, axis=0).max()))
        return gap, inside

    during = [split(t) for t in np.arange(t0 + 1.0, t1, 0.2)]
    gap = max(g for g, _ in during)
    inside = max(w for _, w in during)
    assert gap > 0.1 and gap > 2.0 * inside, (
        f"partition: the halves' estimates stayed together (gap {gap:.3f}, inside {inside:.3f})"
    )
    after, _ = split(t1 + 0.5)
    assert after < 0.05, f"partition: the halves still apart {after:.3f} after it ended"
    return gap, inside

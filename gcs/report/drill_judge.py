"""The drill catalogue of ``swarm drills run`` and the judge of each drill. Pure: numpy and the
project's own types, no processes, no Zenoh, no clock.

A drill (:class:`DrillSpec`) is a list of steps at simulated times relative to its start, a
fault that lasts ``fault_s``, then an observation window of ``observe_s``; each drill starts from
steady flight. What it is judged on (:class:`Criteria`) is stated per drill and shown by
``swarm drills list``. What is measured (:func:`measure`, over the drill's :class:`Window` of
samples rebuilt from the ground station's flight.tlog and events.jsonl):

- **formation error**: the members' centroid against the plan's (m), and each spread (the RMS
  distance from the centre along the plan's axes, the square root of a variance) against the
  plan's, relative; axes the plan keeps flat (spread under 0.2 m) have no relative error;
- **estimate error** of an agent, relative to the formation's size: its centre estimate's error
  over sqrt(s1 + s2 + s3) and each variance estimate's error over s1 + s2 + s3 (true values);
- **converged**: centroid within 5 cm and every spread within 2 % of the plan, and every member
  agent's estimate within 2 %; **time to re-converge**: from the end of the fault to the start of
  the run of converged samples that lasts to the window's end, at least ``HOLD_S`` long (None:
  not converged at the end);
- **minimum separation** between airborne drones, **drones lost** (members at the start that are
  not at the end), **messages rejected** by reason and **processes that ended** (given by the
  runner, which counts them).

Members: as the ground station's report has them (:func:`gcs.report.from_logs.membership`): from
an ``agent_joined`` event until the ``dropout_detected`` or ``crash``, and again after a later
``agent_joined`` (a restarted agent rejoins; a crashed drone never does).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from gcs.report.metrics import descriptors_of, separation
from protocols.model.descriptor_vector import CENTRE, SHAPE
from protocols.model.frames import FloatArray

BoolArray = npt.NDArray[np.bool_]
#: Formation converged: centroid within this of the plan (m) ...
CENTROID_TOL_M = 0.05
#: ... every spread within this of the plan's (relative) ...
SPREAD_TOL = 0.02
#: ... and every member's estimate within this of the truth (relative to the formation's size).
ESTIMATE_TOL = 0.02
#: A spread under this (m) is a flat axis: no relative error.
FLAT_SPREAD_M = 0.2
#: Converged samples must last this long (s) to count as re-converged.
HOLD_S = 1.0
#: Drones of the rejoin drill: estimate within 2 % within this long of its return (s), ...
REJOIN_ESTIMATE_S = 10.0
#: ... back within this distance (m) of its place in the steady formation ...
REJOIN_SLOT_M = 0.2
#: ... within this long of its return (s).
REJOIN_SLOT_S = 30.0
#: An absence shorter than this (s) is a liveliness flap, not a drop-out (:func:`bridge_flaps`).
FLAP_S = 1.0
#: The move of the link-fault drills takes this long (s).
MOVE_S = 4.0
#: How much the link-fault drills stretch the formation (then shrink it back in the next).
STRETCH = 1.25
#: In how long (s): within the operator envelope's shape rate (4.6 s needed), inside the fault.
STRETCH_S = 6.0


@dataclass(frozen=True)
class Step:
    """One action of a drill at ``at_s`` simulated seconds after its start. ``kind``:

    - ``fault``: a link fault (``args["fault"]``: a protocols.wire.fault command; a partition
      with ``args["split"] = "north"`` is resolved by the runner with :func:`split_north`);
    - ``gcs``: a ground-station drill request (``args["name"]``: crash, dropout, gcs-restart;
      ``args["drone"]``);
    - ``garbage``: ``args["count"]`` malformed, foreign and wrong-version payloads on the
      consensus keys of every cell a drone is in;
    - ``flood``: ``args["count"]`` operator requests to the ground station, as fast as it answers;
    - ``move``: the operator's ``move`` (``args``: its arguments, east_m and duration_s).
    """

    at_s: float
    kind: str
    args: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Criteria:
    """What a drill must show to pass (None: not judged).

    ``max_centroid_m`` / ``max_spread``: peak formation error over the window (m, relative);
    ``max_centroid_rise_m``: how far the centroid error may rise above its value at the drill's
    start (a drill that takes a drone out moves the others' centroid at once by the lost drone's
    offset over N - 1: that jump is geometry; the controller must close it, not add to it);
    ``max_spread_rise``: the same for the spread error (the jump is the lost drone's share of the
    spread, which depends on where the survivors of earlier drills stand: 0.3 for a drone on the
    rim of 8);
    ``max_estimate``: peak member estimate error over the window (relative); ``reconverge_s``:
    re-converged at most this long after the fault ended; ``min_separation_m``; ``lost``: exactly
    these drones lost; ``rejected``: each of these reasons counted at least once; ``may_end``:
    process roles allowed to end ("agent 3", "gcs"); ``answered``: least share of the flood's
    requests answered; ``rejoin``: this drone leaves and comes back (the REJOIN_* bars)."""

    max_centroid_m: float | None = 0.5
    max_centroid_rise_m: float | None = None
    max_spread: float | None = 0.25
    max_spread_rise: float | None = None
    max_estimate: float | None = None
    reconverge_s: float | None = 20.0
    min_separation_m: float | None = 1.0
    lost: frozenset[int] = frozenset()
    rejected: tuple[str, ...] = ()
    may_end: frozenset[str] = frozenset()
    answered: float | None = None
    rejoin: int | None = None

    def lines(self) -> list[str]:
        """The criteria in words (``swarm drills list``)."""
        out = []
        if self.max_centroid_m is not None:
            out.append(f"peak centroid error <= {self.max_centroid_m:g} m")
        if self.max_centroid_rise_m is not None:
            out.append(
                f"centroid error never more than {self.max_centroid_rise_m:g} m above its jump "
                "when the drone leaves (the others' centroid moves at once by its offset / (N-1))"
            )
        if self.max_spread is not None:
            out.append(f"peak spread error <= {100 * self.max_spread:g} %")
        if self.max_spread_rise is not None:
            out.append(
                f"spread error never more than {100 * self.max_spread_rise:g} % above its jump "
                "when the drone leaves"
            )
        if self.max_estimate is not None:
            out.append(f"every estimate within {100 * self.max_estimate:g} % throughout")
        if self.reconverge_s is not None:
            out.append(
                f"re-converged (estimates {100 * ESTIMATE_TOL:g} %, formation "
                f"{100 * CENTROID_TOL_M:g} cm / {100 * SPREAD_TOL:g} %) within "
                f"{self.reconverge_s:g} s of the fault's end"
            )
        if self.min_separation_m is not None:
            out.append(f"separation >= {self.min_separation_m:g} m")
        lost = ", ".join(map(str, sorted(self.lost))) or "none"
        out.append(f"drones lost: {lost}")
        if self.rejected:
            out.append(f"rejected and counted: {', '.join(self.rejected)}")
        ends = ", ".join(sorted(self.may_end))
        out.append(f"no process ends{f' but {ends}' if ends else ''}")
        if self.answered is not None:
            out.append(f"at least {100 * self.answered:g} % of the requests answered")
        if self.rejoin is not None:
            out.append(
                f"drone {self.rejoin} rejoins: estimate within {100 * ESTIMATE_TOL:g} % within "
                f"{REJOIN_ESTIMATE_S:g} s of its return, within {REJOIN_SLOT_M:g} m of its place "
                f"within {REJOIN_SLOT_S:g} s"
            )
        return out


@dataclass(frozen=True)
class DrillSpec:
    """A drill: ``steps`` from steady flight, the fault over after ``fault_s``, then watched for
    ``observe_s`` more (simulated s)."""

    name: str
    summary: str
    steps: tuple[Step, ...]
    fault_s: float
    observe_s: float
    criteria: Criteria

    @property
    def length_s(self) -> float:
        return self.fault_s + self.observe_s


def catalogue(n_drones: int, loss: float = 0.5) -> tuple[DrillSpec, ...]:
    """The drills for a swarm of ``n_drones`` (at least 4) in the order they run; ``loss``: the
    probability of the big loss drill (0.5; higher to probe the estimator's limit).

    The link-fault drills move the formation 1 m and stretch it by 25 % (east and wider, then
    back west and narrower in the next one) while the fault lasts: in a still hover every
    estimate stays right without a single message, and so does it in a move alone (the agents
    take their consensus channels in the plan's frame, which a move carries along), so only a
    formation that changes shape shows whether the estimator holds."""
    from protocols.faults import Clear, Delay, LinkCut, Loss, Partition, Restart

    if n_drones < 4:
        raise ValueError(f"the drills need at least 4 drones, got {n_drones}")
    last = n_drones - 1
    crashed, dropped, restarted = last, last - 1, n_drones // 2
    hold = Criteria(max_estimate=0.05)
    # a lost drone's absence jumps the others' centroid by its offset / (N - 1) (0.35-0.56 m
    # for a corner of the 3 x 3 grid) and their spread by its share (up to 0.3 for a drone on
    # the rim of the 8 the dropout left, wherever they settled): judged is that the swarm closes
    # both without overshoot
    losing = Criteria(
        max_centroid_m=None, max_centroid_rise_m=0.1, max_spread=None, max_spread_rise=0.05
    )
    # split in two, each group averages its own half only: while the formation changes shape
    # no estimator can know the other half's (9.7 % seen with a 25 % stretch); judged are the
    # formation while split and the re-convergence after the heal
    split = Criteria(max_centroid_m=0.1, max_spread=0.15)
    fault, watch = 8.0, 8.0
    east = [1.0]

    def moving(*steps: Step) -> tuple[Step, ...]:
        east[0] = -east[0]
        move = {"east_m": -east[0], "duration_s": MOVE_S}
        stretch = {"factor": STRETCH if east[0] < 0 else 1.0 / STRETCH, "duration_s": STRETCH_S}
        return (*steps, Step(1.0, "move", move), Step(1.0, "scale", stretch))

    def link(
        name: str, summary: str, *steps: Step, observe_s: float = watch, judged: Criteria = hold
    ) -> DrillSpec:
        return DrillSpec(
            name,
            f"{summary}; the formation moves 1 m and stretches 25 % meanwhile",
            moving(*steps),
            fault,
            observe_s,
            judged,
        )

    big = f"loss-{round(100 * loss)}"
    return (
        link("link-cut", "cut the link 0 <-> 1 for 8 s",
             Step(0.0, "fault", {"fault": LinkCut(0, 1, False, fault)})),
        link("one-way-link", "cut 0 -> 1 only (1 stops hearing 0) for 8 s",
             Step(0.0, "fault", {"fault": LinkCut(0, 1, True, fault)})),
        link("loss-20", "drop 20 % of the messages on every link for 8 s",
             Step(0.0, "fault", {"fault": Loss(0.2, None, fault)})),
        link(big, f"drop {100 * loss:g} % of the messages on every link for 8 s",
             Step(0.0, "fault", {"fault": Loss(loss, None, fault)})),
        link("delay-100ms", "delay every message by 100 ms for 8 s",
             Step(0.0, "fault", {"fault": Delay(100.0, None)}),
             Step(fault, "fault", {"fault": Clear()})),
        link("partition", "split the swarm into a northern and a southern group for 8 s, heal",
             Step(0.0, "fault", {"fault": Partition(None), "split": "north"}),
             Step(fault, "fault", {"fault": Partition(None)}), observe_s=12.0, judged=split),
        DrillSpec(
            "garbage",
            "2 s of malformed, wrong-version and foreign messages on the consensus keys",
            (Step(0.0, "garbage", {"count": 400, "spread_s": 2.0}),),
            2.0, 5.0,
            replace(hold, rejected=("malformed", "wrong_version", "wrong_swarm")),
        ),
        DrillSpec(
            "command-flood",
            "300 operator requests at once: status, malformed and unknown ones",
            (Step(0.0, "flood", {"count": 300}),),
            2.0, 5.0,
            replace(hold, rejected=("gcs: malformed request",), answered=0.95),
        ),
        DrillSpec(
            "gcs-restart",
            "the ground station stops and swarm up starts it again",
            (Step(0.0, "gcs", {"name": "gcs-restart"}),),
            2.0, 8.0,
            replace(hold, may_end=frozenset({"gcs"})),
        ),
        DrillSpec(
            "dropout",
            f"SIGKILL drone {dropped}'s agent",
            (Step(0.0, "gcs", {"name": "dropout", "drone": dropped}),),
            0.0, 25.0,
            replace(losing, lost=frozenset({dropped}), may_end=frozenset({f"agent {dropped}"})),
        ),
        DrillSpec(
            "crash",
            f"stop every motor of drone {crashed}",
            (Step(0.0, "gcs", {"name": "crash", "drone": crashed}),),
            0.0, 25.0,
            replace(losing, lost=frozenset({crashed}), may_end=frozenset({f"agent {crashed}"})),
        ),
        DrillSpec(
            "restart",
            f"kill drone {restarted}'s agent, a new one 3 s later (swarm drill restart): it "
            "rejoins",
            (Step(0.0, "fault", {"fault": Restart(restarted, 3.0)}),),
            3.0, 30.0,
            Criteria(rejoin=restarted),
        ),
    )  # fmt: skip


def split_north(positions_ned_m: Mapping[int, Sequence[float]]) -> tuple[tuple[int, ...], ...]:
    """Two groups of drones: the northern half and the rest (by north coordinate, then id)."""
    order = sorted(positions_ned_m, key=lambda d: (-float(positions_ned_m[d][0]), d))
    half = len(order) // 2
    return tuple(sorted(order[:half])), tuple(sorted(order[half:]))


# -- membership ----------------------------------------------------------------------------------
def bridge_flaps(member: BoolArray, t_s: FloatArray, max_gap_s: float = FLAP_S) -> BoolArray:
    """``member`` (T, N) with every absence shorter than ``max_gap_s`` that ends with the drone
    back filled in: a liveliness flap (the ground station saw an agent's token go and come back
    at once, e.g. a lease missed on a busy machine) is no drop-out; its vehicle flew on."""
    out = member.copy()
    for i in range(member.shape[1]):
        col = member[:, i]
        k = 1
        while k < col.size:
            if col[k - 1] and not col[k]:
                end = k
                while end < col.size and not col[end]:
                    end += 1
                if end < col.size and t_s[end] - t_s[k] < max_gap_s:
                    out[k:end, i] = True
                k = end
            k += 1
    return out


def joins(events: Iterable[Mapping[str, Any]], drone: int) -> list[float]:
    """Times (s) of drone ``drone``'s ``agent_joined`` events."""
    return sorted(
        float(e["t_s"])
        for e in events
        if e.get("kind") == "agent_joined" and e.get("drone") == drone
    )


# -- measurements ------------------------------------------------------------------------------
@dataclass(frozen=True)
class Window:
    """Samples of one drill: ``t_s`` (T,); ``position_ned_m`` (T, N, 3) NaN where unknown;
    ``estimate`` (T, N, 9) NaN where none; ``desired`` (T, 9) the plan; ``member`` and
    ``airborne`` (T, N). The fault starts at ``t_start_s`` and ends at ``t_recover_s``."""

    t_s: FloatArray
    position_ned_m: FloatArray
    estimate: FloatArray
    desired: FloatArray
    member: BoolArray
    airborne: BoolArray
    t_start_s: float
    t_recover_s: float


@dataclass(frozen=True)
class Series:
    """Per sample: centroid error (m), worst relative spread error, worst member estimate error
    (relative), and whether the swarm is converged (module doc); NaN where not measurable."""

    t_s: FloatArray
    centroid_m: FloatArray
    spread: FloatArray
    estimate: FloatArray
    estimate_by_drone: FloatArray
    converged: BoolArray


def series(w: Window) -> Series:
    """The formation and estimate errors of every sample of ``w``."""
    pos = w.position_ned_m
    known = np.all(np.isfinite(pos), axis=-1)
    truth = descriptors_of(pos, w.member & known, w.desired)
    truth[np.any(w.member & ~known, axis=1)] = np.nan  # a member not heard: not measurable
    with np.errstate(invalid="ignore"):
        centroid = np.linalg.norm(truth[:, CENTRE] - w.desired[:, CENTRE], axis=1)
        want = np.sqrt(np.maximum(w.desired[:, SHAPE], 0.0))
        got = np.sqrt(np.maximum(truth[:, SHAPE], 0.0))
        rel = np.abs(got - want) / np.where(want < FLAT_SPREAD_M, np.nan, want)
        spread = np.where(np.all(np.isnan(rel), axis=1), 0.0, np.nanmax(_nan_to(rel, -1.0), axis=1))
        spread = np.where(np.all(np.isfinite(truth[:, SHAPE]), axis=1), spread, np.nan)
        trace = np.sum(truth[:, SHAPE], axis=1)
        e = w.estimate - truth[:, None, :]
        est = np.maximum(
            np.linalg.norm(e[..., CENTRE], axis=-1) / np.sqrt(trace)[:, None],
            np.max(np.abs(e[..., SHAPE]), axis=-1) / trace[:, None],
        )
    est = np.where(w.member, est, np.nan)  # a missing estimate of a member: NaN, not converged
    members = w.member.any(axis=1)
    worst = np.where(
        members, np.max(np.where(w.member, _nan_to(est, np.inf), -np.inf), axis=1), np.nan
    )
    converged = (
        (centroid < CENTROID_TOL_M) & (spread < SPREAD_TOL) & (worst < ESTIMATE_TOL) & members
    )
    return Series(w.t_s, centroid, spread, worst, est, np.asarray(converged, dtype=bool))


def _nan_to(x: FloatArray, value: float) -> FloatArray:
    return np.where(np.isnan(x), value, x)


def reconverge_time(s: Series, t_from_s: float, hold_s: float = HOLD_S) -> float | None:
    """Seconds from ``t_from_s`` to the start of the run of converged samples that lasts to the
    end of ``s`` (at least ``hold_s``); None if there is none."""
    idx = np.flatnonzero(s.t_s >= t_from_s - 5e-4)
    if idx.size == 0:
        return None
    bad = np.flatnonzero(~s.converged[idx])
    start = int(bad[-1]) + 1 if bad.size else 0
    if start >= idx.size or s.t_s[idx[-1]] - s.t_s[idx[start]] < hold_s - 1e-9:
        return None
    return max(0.0, float(s.t_s[idx[start]] - t_from_s))


@dataclass(frozen=True)
class Measurement:
    """What one drill showed (module doc); ``rejected``: reason -> messages; ``ended``: process
    roles that ended during the drill; ``extra``: drill-specific facts (requests answered, the
    rejoin's times)."""

    peak_centroid_m: float | None
    peak_spread: float | None
    peak_estimate: float | None
    reconverge_s: float | None
    min_separation_m: float | None
    lost: tuple[int, ...]
    rejected: Mapping[str, int] = field(default_factory=dict)
    ended: tuple[str, ...] = ()
    extra: Mapping[str, Any] = field(default_factory=dict)
    start_centroid_m: float | None = None  # the centroid error at the drill's first sample
    start_spread: float | None = None  # the spread error at the drill's first sample
    #: when each peak was (s after the drill's start): where to look in the record of a failure
    peak_at_s: Mapping[str, float] = field(default_factory=dict)


def _peak(x: FloatArray) -> float | None:
    finite = x[np.isfinite(x)]
    return float(finite.max()) if finite.size else None


def _peak_at(t_s: FloatArray, x: FloatArray, t0_s: float) -> float | None:
    """Seconds after ``t0_s`` of the first sample at the peak of ``x`` (None: none finite)."""
    if not np.isfinite(x).any():
        return None
    return round(float(t_s[int(np.nanargmax(x))] - t0_s), 3)


def measure(
    w: Window,
    rejected: Mapping[str, int] | None = None,
    ended: Sequence[str] = (),
    extra: Mapping[str, Any] | None = None,
    leaving: Iterable[int] = (),
) -> Measurement:
    """The measurements of one drill's window (module doc). The ``leaving`` drones (those the
    drill takes out: a crashed vehicle falls for a while before the ground station hears of its
    crash) are left out of the formation and estimate errors from the drill's start."""
    during = w.t_s >= w.t_start_s - 5e-4
    first = int(np.argmax(during)) if during.any() else 0
    lost = tuple(int(i) for i in np.flatnonzero(w.member[first] & ~w.member[-1]))
    judged = w.member.copy()
    for i in leaving:
        judged[during, i] = False
    s = series(replace(w, member=judged))
    sep, _ = separation(w.t_s[during], w.position_ned_m[during], w.airborne[during])
    t = w.t_s[during]
    peaks = {
        name: at
        for name, x in (
            ("centroid", s.centroid_m[during]),
            ("spread", s.spread[during]),
            ("estimate", s.estimate[during]),
        )
        if (at := _peak_at(t, x, w.t_start_s)) is not None
    }
    return Measurement(
        peak_centroid_m=_peak(s.centroid_m[during]),
        start_centroid_m=_peak(s.centroid_m[first : first + 1]),
        start_spread=_peak(s.spread[first : first + 1]),
        peak_at_s=peaks,
        peak_spread=_peak(s.spread[during]),
        peak_estimate=_peak(s.estimate[during]),
        reconverge_s=reconverge_time(s, w.t_recover_s),
        min_separation_m=sep["min_m"],
        lost=lost,
        rejected=dict(rejected or {}),
        ended=tuple(ended),
        extra=dict(extra or {}),
    )


def rejoin_facts(w: Window, drone: int, t_back_s: float | None) -> dict[str, Any]:
    """The rejoin drill's figures for ``drone`` back at ``t_back_s`` (its new ``agent_joined``,
    None: it did not come back): seconds from its return until its estimate is within
    ESTIMATE_TOL (and stays) and until it is within REJOIN_SLOT_M of where it flew before the
    drill (and stays); None where that did not happen."""
    out: dict[str, Any] = {"returned_s": t_back_s, "estimate_s": None, "slot_s": None}
    if t_back_s is None:
        return out
    s = series(w)
    before = np.flatnonzero(w.t_s < w.t_start_s)
    after = w.t_s >= t_back_s - 5e-4
    est_ok = s.estimate_by_drone[:, drone] < ESTIMATE_TOL
    out["estimate_s"] = _settled_after(w.t_s, est_ok, after, t_back_s)
    if before.size:
        slot = w.position_ned_m[before[-1], drone]
        near = np.linalg.norm(w.position_ned_m[:, drone] - slot, axis=-1) < REJOIN_SLOT_M
        out["slot_s"] = _settled_after(w.t_s, near & w.member[:, drone], after, t_back_s)
    return out


def _settled_after(t: FloatArray, ok: BoolArray, after: BoolArray, t0: float) -> float | None:
    idx = np.flatnonzero(after)
    if idx.size == 0:
        return None
    bad = np.flatnonzero(~ok[idx])
    start = int(bad[-1]) + 1 if bad.size else 0
    return None if start >= idx.size else float(t[idx[start]] - t0)


# -- verdicts ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class DrillResult:
    """A drill's verdict: ``failures`` (empty: PASS) says which criteria were not met."""

    spec: DrillSpec
    measurement: Measurement
    failures: tuple[str, ...]
    t_start_s: float = float("nan")

    @property
    def passed(self) -> bool:
        return not self.failures


def judge_window(
    spec: DrillSpec,
    w: Window,
    rejected: Mapping[str, int] | None = None,
    ended: Sequence[str] = (),
    extra: Mapping[str, Any] | None = None,
) -> DrillResult:
    """Measure the drill's window ``w`` and judge it: the drones the drill takes out (its
    criteria's ``lost``) are left out of the formation from the drill's start, so that the jump
    their absence makes is seen at its first sample (``start_centroid_m``), not when the ground
    station hears of it."""
    m = measure(w, rejected, ended, extra, leaving=spec.criteria.lost)
    return judge(spec, m, w.t_start_s)


def judge(spec: DrillSpec, m: Measurement, t_start_s: float = float("nan")) -> DrillResult:
    """Compare ``m`` with the drill's criteria."""
    c, fail = spec.criteria, []
    if m.extra.get("steady_at_start") is False:
        fail.append("not steady at its start")
    if m.extra.get("gone_before_start"):
        fail.append(f"drones gone before its start: {m.extra['gone_before_start']}")
    for said, reason in (("accepted", "reply"), ("move_accepted", "move")):
        if m.extra.get(said) is False:
            fail.append(f"refused by the ground station: {m.extra.get(reason)}")

    def over(
        value: float | None, limit: float | None, what: str, unit: str = "", peak: str = ""
    ) -> None:
        if limit is None:
            return
        if value is None:
            fail.append(f"{what}: not measured")
        elif value > limit:
            notes = []
            if (at := m.peak_at_s.get(peak)) is not None:
                notes.append(f"at {at:+.2f} s")
            if peak == "spread" and m.start_spread is not None:
                notes.append(f"{m.start_spread:.3g} at the drill's start")
            said = f" ({'; '.join(notes)})" if notes else ""
            fail.append(f"{what} {value:.3g}{unit} > {limit:g}{unit}{said}")

    over(m.peak_centroid_m, c.max_centroid_m, "peak centroid error", " m", "centroid")
    if c.max_centroid_rise_m is not None:
        rise = (
            None
            if m.peak_centroid_m is None or m.start_centroid_m is None
            else m.peak_centroid_m - m.start_centroid_m
        )
        over(
            rise, c.max_centroid_rise_m, "centroid error rose above its start by", " m", "centroid"
        )
    over(m.peak_spread, c.max_spread, "peak spread error", "", "spread")
    if c.max_spread_rise is not None:
        rise = (
            None
            if m.peak_spread is None or m.start_spread is None
            else m.peak_spread - m.start_spread
        )
        over(rise, c.max_spread_rise, "spread error rose above its start by", "", "spread")
    over(m.peak_estimate, c.max_estimate, "peak estimate error", "", "estimate")
    if c.reconverge_s is not None:
        if m.reconverge_s is None:
            fail.append("did not re-converge")
        else:
            over(m.reconverge_s, c.reconverge_s, "re-converged after", " s")
    if c.min_separation_m is not None and (
        m.min_separation_m is None or m.min_separation_m < c.min_separation_m
    ):
        fail.append(f"separation {m.min_separation_m} m < {c.min_separation_m:g} m")
    if set(m.lost) != set(c.lost):
        fail.append(f"drones lost {sorted(m.lost)}, expected {sorted(c.lost)}")
    for reason in c.rejected:
        if m.rejected.get(reason, 0) <= 0:
            fail.append(f"no message rejected as {reason}")
    unexpected = [r for r in m.ended if r not in c.may_end]
    if unexpected:
        fail.append(f"processes ended: {', '.join(unexpected)}")
    if c.answered is not None:
        share = m.extra.get("answered_share")
        if share is None or share < c.answered:
            fail.append(f"requests answered {share}, expected >= {c.answered:g}")
    if c.rejoin is not None:
        if m.extra.get("returned_s") is None:
            fail.append(f"drone {c.rejoin} did not rejoin")
        else:
            over(
                m.extra.get("estimate_s"),
                REJOIN_ESTIMATE_S,
                "rejoined estimate within 2 % after",
                " s",
            )
            over(m.extra.get("slot_s"), REJOIN_SLOT_S, "back in its place after", " s")
    return DrillResult(spec, m, tuple(fail), t_start_s)


# -- output ------------------------------------------------------------------------------------
def _f(value: float | None, fmt: str, scale: float = 1.0) -> str:
    return "-" if value is None else format(value * scale, fmt)


def table(results: Sequence[DrillResult]) -> list[str]:
    """The table of verdicts and figures, then one line per failed criterion."""
    head = (
        f"{'drill':<14} {'verdict':<7} {'centroid':>8} {'spread':>7} {'estim.':>7} "
        f"{'reconv':>7} {'min sep':>7} {'lost':>5} {'rejected':>9} {'ended':<10}"
    )
    units = (
        f"{'':<14} {'':<7} {'peak m':>8} {'peak %':>7} {'peak %':>7} "
        f"{'s':>7} {'m':>7} {'':>5} {'messages':>9} {'processes':<10}"
    )
    lines = [head, units]
    for r in results:
        m = r.measurement
        lines.append(
            f"{r.spec.name:<14} {'PASS' if r.passed else 'FAIL':<7} "
            f"{_f(m.peak_centroid_m, '.3f'):>8} {_f(m.peak_spread, '.1f', 100):>7} "
            f"{_f(m.peak_estimate, '.1f', 100):>7} {_f(m.reconverge_s, '.1f'):>7} "
            f"{_f(m.min_separation_m, '.2f'):>7} {','.join(map(str, m.lost)) or '-':>5} "
            f"{sum(m.rejected.values()):>9} {','.join(m.ended) or '-':<10}"
        )
    for r in results:
        for failure in r.failures:
            lines.append(f"FAIL {r.spec.name}: {failure}")
    return lines


def to_json(results: Sequence[DrillResult], info: Mapping[str, Any]) -> dict[str, Any]:
    """``drills.json``: the run's ``info`` and per drill its criteria, figures and verdict."""
    from gcs.report.events import jsonable

    drills = []
    for r in results:
        m = r.measurement
        drills.append(
            {
                "name": r.spec.name,
                "summary": r.spec.summary,
                "criteria": r.spec.criteria.lines(),
                "t_start_s": r.t_start_s,
                "passed": r.passed,
                "failures": list(r.failures),
                "peak_centroid_error_m": m.peak_centroid_m,
                "start_centroid_error_m": m.start_centroid_m,
                "peak_spread_error": m.peak_spread,
                "start_spread_error": m.start_spread,
                "peak_at_s": dict(m.peak_at_s),
                "peak_estimate_error": m.peak_estimate,
                "time_to_reconverge_s": m.reconverge_s,
                "min_separation_m": m.min_separation_m,
                "drones_lost": list(m.lost),
                "rejected": dict(m.rejected),
                "processes_ended": list(m.ended),
                **dict(m.extra),
            }
        )
    out: dict[str, Any] = jsonable(
        {**info, "passed": all(r.passed for r in results), "drills": drills}
    )
    return out

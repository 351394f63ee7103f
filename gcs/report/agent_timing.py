"""Did the agents keep up? The report's answer, from the ground station's own logs. Pure.

In realtime the simulator measures, once per status interval, each agent's share of control ticks
answered in time and its worst lag (sitl_sim/vehicle/tick_answers.py), sends both to the ground
station as NAMED_VALUE_FLOAT (logged in flight.tlog), and an "Agent late" STATUSTEXT for an agent
below 90 % (an ``overload`` event in events.jsonl). :func:`timing_metrics` turns them into the
report's ``agent_timing`` block and explains each failsafe: a vehicle fails safe when its setpoints
stop; if its agent had left the swarm (a drop-out, a drill), that is why; else if its agent was
reported late just before, the machine could not keep up; else the agent stopped.
Lockstep runs have no timing figures (time waits for the agents).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from gcs.report.tlog import TlogTrack
from sitl_sim.mavlink_edge.messages import AGENT_IN_TIME, AGENT_LAG_MS
from sitl_sim.vehicle.tick_answers import OVERLOAD_LAG_MS, OVERLOAD_SHARE

#: A failsafe is blamed on an overload reported at most this long (s) before or after it.
BLAME_WINDOW_S = 3.0
#: An overload is *sustained* when more than this share of the one-second intervals fell below
#: OVERLOAD_SHARE (or a lag reached OVERLOAD_LAG_MS); fewer are brief dips, reported as such.
SUSTAINED_SHARE = 0.1


def timing_metrics(track: TlogTrack, events: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The ``agent_timing`` block: per-drone worst share in time and lag, the swarm's share per
    one-second interval (worst, mean), whether it was overloaded (any interval below
    OVERLOAD_SHARE, or a lag of OVERLOAD_LAG_MS) and whether for long (``sustained``: more than
    SUSTAINED_SHARE of the intervals, or that lag), and the failsafes with their cause."""
    per_drone: dict[str, dict[str, float | None]] = {}
    shares: dict[float, list[float]] = {}
    for sysid, v in sorted(track.vehicles.items()):
        in_time, lag = v.named.get(AGENT_IN_TIME), v.named.get(AGENT_LAG_MS)
        if in_time is None or in_time.size == 0:
            continue
        per_drone[str(sysid - 1)] = {
            "in_time_min": round(float(in_time[:, 1].min()), 4),
            "in_time_mean": round(float(in_time[:, 1].mean()), 4),
            "worst_lag_ms": None if lag is None or not lag.size else float(lag[:, 1].max()),
        }
        for t, share in in_time:
            shares.setdefault(round(float(t), 3), []).append(float(share))
    swarm = [float(np.mean(s)) for s in shares.values()]
    lags = [d["worst_lag_ms"] for d in per_drone.values() if d["worst_lag_ms"] is not None]
    overloaded_intervals = sum(1 for s in swarm if s < OVERLOAD_SHARE)
    long_lag = max(lags, default=0.0) >= OVERLOAD_LAG_MS
    return {
        "measured": bool(per_drone),
        "in_time_min": min(swarm) if swarm else None,
        "in_time_mean": round(float(np.mean(swarm)), 4) if swarm else None,
        "intervals": len(swarm),
        "overloaded_intervals": overloaded_intervals,
        "worst_lag_ms": max(lags, default=None),
        "overloaded": overloaded_intervals > 0 or long_lag,
        "sustained": long_lag or overloaded_intervals > SUSTAINED_SHARE * len(swarm),
        "per_drone": per_drone,
        "failsafes": explain_failsafes(events),
    }


def explain_failsafes(events: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Each drone's first failsafe event with its cause: ``agent left`` when its agent had left
    the swarm before it (a drop-out, a drill, a crash: ``dropout_detected`` with no
    ``agent_joined`` since), whatever lateness was reported around it; else ``overload`` when
    its agent was reported late within BLAME_WINDOW_S of it (the report comes at the end of the
    simulator's status interval, so it may follow the failsafe); else ``no setpoints`` (its agent
    stopped answering without leaving)."""
    late: dict[int, list[tuple[float, str]]] = {}
    failsafes: dict[int, Mapping[str, Any]] = {}
    left: dict[int, float] = {}  # drone -> when its agent left, until it joins again
    left_before: dict[int, float] = {}  # drone -> when its agent had left, at its failsafe
    for e in events:
        drone, kind = e.get("drone"), e.get("kind")
        if not isinstance(drone, int):
            continue
        t_e = float(e.get("t_s", 0.0))
        if kind == "overload":
            late.setdefault(drone, []).append((t_e, str(e.get("text", ""))))
        elif kind == "dropout_detected":
            left.setdefault(drone, t_e)
        elif kind == "agent_joined":
            left.pop(drone, None)
        elif kind == "failsafe" and drone not in failsafes:
            failsafes[drone] = e
            if drone in left and left[drone] <= t_e:
                left_before[drone] = left[drone]
    out: list[dict[str, Any]] = []
    for drone, e in sorted(failsafes.items(), key=lambda item: float(item[1].get("t_s", 0.0))):
        t = float(e.get("t_s", 0.0))
        # the report of the interval the failsafe fell in comes after it: prefer that one
        near = sorted(
            (t_late < t, abs(t_late - t), text)
            for t_late, text in late.get(drone, [])
            if abs(t_late - t) <= BLAME_WINDOW_S
        )
        blamed = [text for _before, _gap, text in near]
        if drone in left_before:
            cause, detail = (
                "agent left",
                f"its agent had left the swarm at {left_before[drone]:.1f} s",
            )
        elif blamed:
            cause, detail = "overload", blamed[0]
        else:
            cause, detail = "no setpoints", "its agent stopped or left the swarm"
        out.append(
            {"drone": drone, "t_s": t, "text": e.get("text"), "cause": cause, "detail": detail}
        )
    return out


def summary_lines(timing: Mapping[str, Any] | None) -> list[str]:
    """Lines for the printed summary (none when nothing was measured and nothing failed safe)."""
    if not timing:
        return []
    lines: list[str] = []
    if timing.get("measured"):
        worst = min((d["in_time_min"] for d in timing["per_drone"].values()), default=float("nan"))
        lags = [
            d["worst_lag_ms"] for d in timing["per_drone"].values() if d["worst_lag_ms"] is not None
        ]
        lines.append(
            f"  agents in time (realtime)    worst agent {worst:.1%} of ticks, "
            f"worst lag {max(lags, default=0.0):.0f} ms"
        )
        if timing.get("overloaded") and not timing.get("sustained", True):
            lines.append(
                f"  behind realtime briefly: {timing['overloaded_intervals']} of "
                f"{timing.get('intervals')} one-second intervals below {OVERLOAD_SHARE:.0%} of the "
                f"ticks in time ({timing.get('in_time_mean') or 0.0:.1%} in time over the run, "
                f"worst lag {timing.get('worst_lag_ms') or 0.0:.0f} ms); for results that do not "
                "depend on the machine's load use --clock lockstep"
            )
        elif timing.get("overloaded"):
            lines.append(
                f"  OVERLOAD: the agents fell behind realtime ({timing['overloaded_intervals']} "
                f"one-second intervals below {OVERLOAD_SHARE:.0%} of the ticks in time, worst lag "
                f"{timing.get('worst_lag_ms') or 0.0:.0f} ms): this machine cannot fly this swarm "
                "in realtime; use --clock lockstep (results do not depend on load)"
            )
    for f in timing.get("failsafes", []):
        lines.append(
            f"  drone {f['drone']} failed safe at {f['t_s']:.1f} s: "
            + ("its agent fell behind (" + f["detail"] + ")" if f["cause"] == "overload"
               else f["detail"])
        )  # fmt: skip
    return lines

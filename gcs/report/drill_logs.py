"""The logs of a drills run read for the judge (:mod:`gcs.report.drill_judge`): a drill's
:class:`~gcs.report.drill_judge.Window` from the ground station's flight.tlog, events.jsonl and
plan (trajectory.json), and the run's plot ``drills.png``.

Sampling: a uniform grid of simulated time at the telemetry rate of ``swarm up``, sample-and-hold
as the report does (:mod:`gcs.report.from_logs`); members as the report has them, liveliness
flaps bridged (:func:`gcs.report.drill_judge.bridge_flaps`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gcs.report.drill_judge import DrillResult, Window, bridge_flaps, series
from gcs.report.events import read_events
from gcs.report.log_record import MAX_AGE_S, hold, membership
from gcs.report.tlog import TlogTrack, read_tlog
from gcs.report.trajectory_file import read_trajectory

#: Samples per simulated second of the judged record (the telemetry rate of swarm up).
RATE_HZ = 25.0


def _plan(folder: Path) -> Any:
    for _ in range(20):
        try:
            return read_trajectory(folder / "trajectory.json")
        except (OSError, ValueError, KeyError):
            time.sleep(0.05)
    raise ValueError(f"no plan in {folder / 'trajectory.json'}")


def window_from_logs(
    folder: Path,
    n: int,
    t_from: float,
    t_to: float,
    t_start: float,
    t_recover: float,
    track: TlogTrack | None = None,
) -> tuple[Window, list[dict[str, Any]]]:
    """A :class:`Window` of the report folder's flight.tlog (or ``track``, read from it),
    events.jsonl and plan."""
    if track is None:
        track = read_tlog(folder / "flight.tlog")
    events = read_events(folder / "events.jsonl")
    t = np.arange(max(0.0, t_from), t_to + 1e-9, 1.0 / RATE_HZ)
    if t.size < 2:
        raise ValueError("no samples")
    pos = track.resample(t, n, max_age_s=MAX_AGE_S)
    est = np.full((t.size, n, 9), np.nan)
    for sysid, v in track.vehicles.items():
        if 1 <= sysid <= n:
            est[:, sysid - 1] = hold(t, v.status_t_s, v.status, MAX_AGE_S)[:, :9]
    member = bridge_flaps(membership(events, t, n)[0], t)
    with np.errstate(invalid="ignore"):
        airborne = np.isfinite(pos[..., 2]) & (-pos[..., 2] > 0.3)
    desired = _plan(folder).evaluate_many(t)[0]
    return Window(t, pos, est, desired, member, airborne, t_start, t_recover), events


def plot_drills(
    folder: Path,
    results: Sequence[DrillResult],
    n: int,
    path: Path,
    track: TlogTrack | None = None,
) -> None:
    """Formation and estimate errors over the whole run, each drill's window shaded
    (``track``: the run's flight.tlog already read)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not results:
        return
    end = max(r.t_start_s + r.spec.length_s for r in results)
    try:
        w, _ = window_from_logs(folder, n, 0.0, end, 0.0, 0.0, track)
    except (OSError, ValueError):
        return
    s = series(w)
    fig, axes = plt.subplots(3, 1, figsize=(12, 8), sharex=True)
    for ax, values, label in (
        (axes[0], s.centroid_m, "centroid error (m)"),
        (axes[1], 100 * s.spread, "spread error (%)"),
        (axes[2], 100 * s.estimate, "worst estimate error (%)"),
    ):
        ax.plot(s.t_s, values, lw=0.8)
        ax.set_ylabel(label)
        ax.set_yscale("symlog", linthresh=0.05 if ax is axes[0] else 2.0)
        for r in results:
            colour = "tab:green" if r.passed else "tab:red"
            ax.axvspan(r.t_start_s, r.t_start_s + r.spec.length_s, color=colour, alpha=0.12)
    for r in results:
        axes[0].text(
            r.t_start_s, axes[0].get_ylim()[1], r.spec.name, rotation=90, va="top", fontsize=7
        )
    axes[-1].set_xlabel("simulated time (s)")
    fig.suptitle("swarm drills run: green PASS, red FAIL")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

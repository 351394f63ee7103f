"""How far a flown formation was from the plan over a time window, from a report folder alone.

The true formation of the chosen drones (their positions in flight.tlog, sampled every
``step_s``) against the plan as flown (trajectory.json): the worst distance of its centre from
the plan's (m) and the worst relative error of its length and width spreads. Used to judge holds
and to set flights on different vehicles side by side (tests, bench/autopilots.py).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gcs.report.tlog import read_tlog
from gcs.report.trajectory_file import read_trajectory
from protocols.model.descriptor_vector import CENTRE, SHAPE
from protocols.model.descriptors import descriptors


@dataclass(frozen=True)
class WindowErrors:
    """Worst centre error (m) and worst relative length/width spread error in a window."""

    centre_m: float
    spread: float


def window_errors(
    report: Path,
    drones: Sequence[int],
    t0_s: float,
    t1_s: float,
    n_drones: int | None = None,
    step_s: float = 0.2,
) -> WindowErrors:
    """:class:`WindowErrors` of ``drones`` (0-based) between ``t0_s`` and ``t1_s``."""
    track = read_tlog(report / "flight.tlog")
    plan = read_trajectory(report / "trajectory.json")
    grid = np.arange(t0_s, t1_s, step_s)
    pos = track.resample(grid, n_drones)[:, list(drones)]
    centre, spread = 0.0, 0.0
    for k, t in enumerate(grid):
        want = plan.evaluate(float(t))[0]
        got = descriptors(pos[k], want)
        centre = max(centre, float(np.linalg.norm(got[CENTRE] - want[CENTRE])))
        spreads = np.sqrt(np.maximum(got[SHAPE][:2], 0.0))
        spread = max(spread, float(np.max(np.abs(spreads / np.sqrt(want[SHAPE][:2]) - 1.0))))
    return WindowErrors(centre, spread)

"""The time series of a :class:`~gcs.view.scene.Scene` in Rerun: each descriptor's command, true
value and the agents' estimates, the angles' errors, and the swarm's health.

Entities, on the timeline ``sim_time`` (values as the report's descriptors.png plots them):

- ``descriptors/<name>/commanded``, ``.../actual`` (the true, centralised value) and
  ``.../estimates`` (one series per agent, at most :data:`MAX_ESTIMATE_SERIES` agents evenly
  spread over the swarm, on the trail rows of :mod:`gcs.view.rerun_log`), for each
  :data:`DESCRIPTOR_PLOTS` name: the centre north and east (m), the altitude (-D, m), heading,
  pitch and roll (deg, within half a turn of the command; none where the heading is undefined:
  length and width spreads equal) and the length, width and height variances (m²);
- ``descriptors/<angle>/error``: true minus commanded angle (deg, wrapped);
- ``separation/min_m``, ``consensus/error_m``, ``links/neighbours_mean``.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import rerun as rr

from gcs.view.scene import Scene
from protocols.model.frames import FloatArray, wrap_pi

TIMELINE = "sim_time"
#: (index in the descriptor vector, entity name under ``descriptors/``, plot title), in the order
#: of descriptors.png's panels: centre, orientation, variances.
DESCRIPTOR_PLOTS = (
    (0, "centre_n", "north [m]"),
    (1, "centre_e", "east [m]"),
    (2, "altitude", "altitude [m]"),
    (5, "yaw", "heading [°]"),
    (4, "pitch", "pitch [°]"),
    (3, "roll", "roll [°]"),
    (6, "s_length", "length s_l [m²]"),
    (7, "s_width", "width s_w [m²]"),
    (8, "s_height", "height s_h [m²]"),
)
ANGLES = (3, 4, 5)
#: At most this many agents' estimates drawn per descriptor (evenly spread over the swarm).
MAX_ESTIMATE_SERIES = 32
#: The command black, the true value blue, the agents' estimates magenta (as their centre
#: estimates in the 3-D view), the angles' errors red.
COMMANDED_RGB, ACTUAL_RGB = (20, 20, 20), (60, 120, 230)
ESTIMATE_RGB, ERROR_RGB = (200, 80, 200), (220, 60, 40)


def estimate_agents(n_drones: int) -> npt.NDArray[np.int64]:
    """The drone indices whose estimates are drawn: all up to :data:`MAX_ESTIMATE_SERIES`, else
    that many evenly spread."""
    if n_drones <= MAX_ESTIMATE_SERIES:
        return np.arange(n_drones)
    return np.floor(np.arange(MAX_ESTIMATE_SERIES) * (n_drones / MAX_ESTIMATE_SERIES)).astype(
        np.int64
    )


def log_series_setup(rec: rr.RecordingStream, n_drones: int) -> None:
    """The series' names, colours and widths (static)."""
    agents = estimate_agents(n_drones)
    for k, name, _ in DESCRIPTOR_PLOTS:
        path = f"descriptors/{name}"
        rec.log(f"{path}/commanded", rr.SeriesLines(colors=[COMMANDED_RGB], widths=[1.0],
                names=["command"]), static=True)  # fmt: skip
        rec.log(f"{path}/actual", rr.SeriesLines(colors=[ACTUAL_RGB], widths=[3.0],
                names=["true"]), static=True)  # fmt: skip
        rec.log(f"{path}/estimates", rr.SeriesLines(colors=[ESTIMATE_RGB] * agents.size,
                widths=[0.75] * agents.size, names=[f"agent {i + 1}" for i in agents]),
                static=True)  # fmt: skip
        if k in ANGLES:
            rec.log(f"{path}/error", rr.SeriesLines(colors=[ERROR_RGB], widths=[1.5],
                    names=[f"{name} error"]), static=True)  # fmt: skip


def _index(t_s: FloatArray) -> list[rr.TimeColumn]:
    return [rr.TimeColumn(TIMELINE, duration=np.asarray(t_s, dtype=float))]


def scalar_series(rec: rr.RecordingStream, path: str, t_s: FloatArray, values: FloatArray) -> None:
    """One series: the finite ``values`` (T,) at ``t_s`` (T,)."""
    ok = np.isfinite(values)
    if ok.any():
        rec.send_columns(
            path, indexes=_index(t_s[ok]), columns=rr.Scalars.columns(scalars=values[ok])
        )


def shown(
    values: FloatArray, desired: FloatArray, k: int, heading_ok: npt.NDArray[np.bool_]
) -> FloatArray:
    """Descriptor ``k``'s ``values`` (T,) or (T, M) as plotted, against the command ``desired``
    (T,): altitude up; angles in degrees within half a turn of the command (of themselves where
    there is none), NaN where the heading is undefined (``heading_ok`` (T,) False)."""
    if k == 2:
        return -values
    if k not in ANGLES:
        return values
    shape = (-1,) + (1,) * (values.ndim - 1)
    ref, ok = desired.reshape(shape), heading_ok.reshape(shape)
    unwrapped = np.where(np.isfinite(ref), ref + wrap_pi(values - ref), values)
    return np.where(ok, np.degrees(unwrapped), np.nan)


def log_series(
    rec: rr.RecordingStream, scene: Scene, start: int, rows: npt.NDArray[np.int64]
) -> None:
    """The samples ``start:`` of every series; the agents' estimates on the sample ``rows``."""
    t = scene.t_s[start:]
    ok = scene.heading_ok[start:]
    agents = estimate_agents(scene.n_drones)
    for k, name, _ in DESCRIPTOR_PLOTS:
        desired = scene.desired[start:, k]
        path = f"descriptors/{name}"
        scalar_series(rec, f"{path}/commanded", t, shown(desired, desired, k, np.ones_like(ok)))
        scalar_series(rec, f"{path}/actual", t, shown(scene.actual[start:, k], desired, k, ok))
        if k in ANGLES:
            error = wrap_pi(scene.actual[start:, k] - desired)
            scalar_series(rec, f"{path}/error", t, np.where(ok, np.degrees(error), np.nan))
        if rows.size:
            est = scene.estimate[rows][:, agents, k]
            values = shown(est, scene.desired[rows, k], k, scene.heading_ok[rows])
            rec.send_columns(
                f"{path}/estimates",
                indexes=_index(scene.t_s[rows]),
                columns=rr.Scalars.columns(scalars=values.ravel()).partition(
                    [agents.size] * rows.size
                ),
            )
    scalar_series(rec, "separation/min_m", t, scene.min_separation_m[start:])
    scalar_series(rec, "consensus/error_m", t, scene.consensus_error_m[start:])
    scalar_series(rec, "links/neighbours_mean", t, scene.neighbours_mean[start:])

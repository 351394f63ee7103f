"""Can a formation hold its drones at the minimum separation? Pure, I/O-free.

The cooperative controller (ALGORITHM.md §4) moves every drone by one affine field of its offset
from the swarm centre: a command of new axes R' and variances s' takes the offset p_i of a drone
in the current frame (axes R, variances s) to

    p_i' = R' diag(sqrt(s' / s)) R^T p_i

(an axis that is flat now, s below ``min_variance_m2``, stays flat: a coplanar swarm cannot grow
a thickness). So where the drones will be, and how close the closest two, follows from where
they are now: :func:`formation_positions`. :func:`fit_problem` says why a formation cannot hold
the drones ``min_separation_m`` apart (the ground station refuses such a command, the scenario
loader such a waypoint), or None.
"""

from __future__ import annotations

import numpy as np

from protocols.model.descriptor_vector import CENTRE, SHAPE
from protocols.model.descriptors import align_axes, covariance, desired_axes
from protocols.model.frames import FloatArray

#: Below this variance (m^2) an axis counts as flat (the controller's own guard, ALGORITHM.md §2).
FLAT_VARIANCE_M2 = 0.05


def formation_positions(positions_ned_m: FloatArray, target: FloatArray) -> FloatArray:
    """Where drones now at ``positions_ned_m`` (N, 3) stand in the formation ``target`` (9,)."""
    x = np.asarray(positions_ned_m, dtype=float)
    centre, sigma = covariance(x)
    axes_to = desired_axes(target)
    axes_now, s_now = align_axes(sigma, axes_to)
    s_to = np.maximum(np.asarray(target[SHAPE], dtype=float), 0.0)
    flat = s_now < FLAT_VARIANCE_M2
    gain = np.where(flat, 0.0, np.sqrt(s_to / np.where(flat, 1.0, s_now)))
    offsets = (x - centre) @ axes_now  # (N, 3) in the current frame
    return np.asarray(target[CENTRE], dtype=float) + (offsets * gain) @ axes_to.T


def closest_pair(positions_ned_m: FloatArray) -> tuple[float, tuple[int, int]]:
    """The smallest distance (m) between two of the positions (N, 3), and which two."""
    x = np.asarray(positions_ned_m, dtype=float)
    if x.shape[0] < 2:
        return float("inf"), (0, 0)
    d = np.linalg.norm(x[:, None, :] - x[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    k = int(np.argmin(d))
    i, j = divmod(k, x.shape[0])
    return float(d[i, j]), (min(i, j), max(i, j))


def fit_problem(
    positions_ned_m: FloatArray, target: FloatArray, min_separation_m: float
) -> str | None:
    """Why the formation ``target`` cannot hold the drones now at ``positions_ned_m``
    ``min_separation_m`` apart (one line), or None if it can."""
    spacing, (i, j) = closest_pair(formation_positions(positions_ned_m, target))
    if spacing >= min_separation_m:
        return None
    spread = np.sqrt(np.maximum(np.asarray(target[SHAPE], dtype=float), 0.0))
    n = np.asarray(positions_ned_m).shape[0]
    return (
        f"a formation {spread[0]:.1f} m x {spread[1]:.1f} m x {spread[2]:.1f} m (spreads) cannot "
        f"hold {n} drones {min_separation_m:g} m apart: drones {i} and {j} would be "
        f"{spacing:.2f} m apart; make it larger"
    )

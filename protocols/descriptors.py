"""Swarm descriptors from drone positions (ALGORITHM.md §2). Pure, I/O-free.

The descriptors of a set of positions ``x_i`` (NED, m) are the centre ``mu`` (mean), and the
eigen-decomposition of the population covariance ``Sigma = (1/N) sum p_i p_i^T = R diag(s) R^T``
with ``p_i = x_i - mu``. ``R``'s columns are the swarm's length, width and height axes, assigned to
the *desired* axes (never sorted by eigenvalue), so that a width crossing the length does not swap
them. Orientation is the ZYX angles of ``R``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from protocols.descriptor_vector import CENTRE, I_PITCH, I_ROLL, I_YAW, SHAPE
from protocols.frames import FloatArray, rot_zyx, zyx_from_rot

#: Heading is reported undefined while |s1 - s2| / (s1 + s2) is below this (ALGORITHM.md §2).
HEADING_TIE_RATIO = 0.05


@dataclass(frozen=True)
class SwarmFrame:
    """Centre, principal axes and variances of a swarm, from moments.

    ``axes`` (3, 3): columns r1, r2, r3 (length, width, height axes) in NED, a proper rotation.
    ``variances_m2`` (3,): s1, s2, s3 along those axes.
    """

    centre_ned_m: FloatArray
    axes: FloatArray
    variances_m2: FloatArray

    def vector(self) -> FloatArray:
        """The descriptor vector ``a`` (9,) in protocols.descriptor_vector order."""
        yaw, pitch, roll = zyx_from_rot(self.axes)
        a = np.empty(9)
        a[CENTRE] = self.centre_ned_m
        a[I_ROLL], a[I_PITCH], a[I_YAW] = roll, pitch, yaw
        a[SHAPE] = self.variances_m2
        return a


def align_axes(sigma: FloatArray, desired_axes: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Eigen-decompose the symmetric ``sigma`` (3, 3) with eigenvectors assigned to desired axes.

    Each desired axis (column of ``desired_axes``, a rotation) gets the unused eigenvector most
    aligned with it, signed along it; the third axis is the cross product of the first two, so the
    result is a proper rotation. Returns ``(R (3, 3), s (3,))`` with ``sigma = R diag(s) R^T``.
    Equal eigenvalues give a valid (if arbitrary within the tie) frame, never NaN.
    """
    sym = 0.5 * (sigma + sigma.T)
    _, evecs = np.linalg.eigh(sym)
    overlap = np.abs(desired_axes.T @ evecs)  # [desired k, eigen j]
    order = [-1, -1]
    free = [0, 1, 2]
    # Assign the most confident pair first, then the next among what is left.
    for _ in range(2):
        pairs = [(k, j) for k in (0, 1) if order[k] < 0 for j in free]
        best = max(pairs, key=lambda kj: overlap[kj])
        order[best[0]] = best[1]
        free.remove(best[1])
    r1 = evecs[:, order[0]] * np.sign(desired_axes[:, 0] @ evecs[:, order[0]] or 1.0)
    r2 = evecs[:, order[1]] * np.sign(desired_axes[:, 1] @ evecs[:, order[1]] or 1.0)
    r3 = np.cross(r1, r2)
    axes = np.column_stack([r1, r2, r3])
    s = np.array([r1 @ sym @ r1, r2 @ sym @ r2, r3 @ sym @ r3])
    return axes, s


def frame_from_moments(
    centre_ned_m: FloatArray, sigma: FloatArray, desired_axes: FloatArray
) -> SwarmFrame:
    """Swarm frame from a centre (3,) and covariance (3, 3), axes assigned to ``desired_axes``."""
    axes, s = align_axes(sigma, desired_axes)
    return SwarmFrame(np.asarray(centre_ned_m, dtype=float), axes, s)


def covariance(positions_ned_m: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Centre (3,) and population covariance (3, 3) of positions (N, 3)."""
    x = np.asarray(positions_ned_m, dtype=float)
    mu = x.mean(axis=0)
    p = x - mu
    return mu, (p.T @ p) / x.shape[0]


def swarm_frame(positions_ned_m: FloatArray, desired_axes: FloatArray | None = None) -> SwarmFrame:
    """Descriptors of positions (N, 3). ``desired_axes`` defaults to the world axes."""
    mu, sigma = covariance(positions_ned_m)
    return frame_from_moments(mu, sigma, np.eye(3) if desired_axes is None else desired_axes)


def descriptors(positions_ned_m: FloatArray, desired: FloatArray | None = None) -> FloatArray:
    """Descriptor vector ``a`` (9,) of positions (N, 3), axes assigned to the desired orientation.

    ``desired`` is a desired descriptor vector (9,) whose roll/pitch/yaw define the axes to assign
    eigenvectors to; None means the world axes (yaw = pitch = roll = 0).
    """
    axes = None if desired is None else desired_axes(desired)
    return swarm_frame(positions_ned_m, axes).vector()


def desired_axes(a_desired: FloatArray) -> FloatArray:
    """Rotation (3, 3) whose columns are the desired length, width and height axes."""
    return rot_zyx(float(a_desired[I_YAW]), float(a_desired[I_PITCH]), float(a_desired[I_ROLL]))


def heading_defined(variances_m2: FloatArray) -> bool:
    """False while length and width variances are within 5 % of each other (heading undefined)."""
    s1, s2 = float(variances_m2[0]), float(variances_m2[1])
    return abs(s1 - s2) >= HEADING_TIE_RATIO * max(s1 + s2, 1e-12)

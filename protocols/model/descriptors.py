"""Swarm descriptors from drone positions (ALGORITHM.md §2). Pure, I/O-free.

The descriptors of a set of positions ``x_i`` (NED, m) are the centre ``mu`` (mean), and the
eigen-decomposition of the population covariance ``Sigma = (1/N) sum p_i p_i^T = R diag(s) R^T``
with ``p_i = x_i - mu``. ``R``'s columns are the swarm's length, width and height axes, assigned to
the *desired* axes (never sorted by eigenvalue), so that a width crossing the length does not swap
them. Orientation is the ZYX angles of ``R``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from protocols.model.descriptor_vector import CENTRE, I_PITCH, I_ROLL, I_YAW, SHAPE
from protocols.model.frames import (
    FloatArray,
    rot_zyx,
    rot_zyx_batch,
    zyx_from_rot,
    zyx_from_rot_batch,
)
from protocols.runtime.compiled import compiled as dispatcher_of
from protocols.runtime.compiled import jit, loaded

#: Heading is reported undefined while |s1 - s2| / (s1 + s2) is below this (ALGORITHM.md §2).
HEADING_TIE_RATIO = 0.05

try:  # numpy's own kernel of np.linalg.eigh, without its per-call checks (a third of its cost
    # on a few 3 x 3 matrices, which the agents' core decomposes every tick)
    from numpy.linalg import _umath_linalg

    def _eigenvectors(sym: FloatArray) -> FloatArray:
        """``np.linalg.eigh(sym)[1]`` of finite symmetric float64 matrices (K, 3, 3), the same
        bits (its lower triangle, as eigh's default); NaN where LAPACK would not converge (a
        warning), where eigh raises."""
        vectors: FloatArray = _umath_linalg.eigh_lo(sym, signature="d->dd")[1]
        return vectors

except ImportError:  # pragma: no cover - a numpy without it

    def _eigenvectors(sym: FloatArray) -> FloatArray:
        vectors: FloatArray = np.linalg.eigh(sym)[1]
        return vectors


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
        """The descriptor vector ``a`` (9,) in protocols.model.descriptor_vector order."""
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

    One matrix is the scenario checks', the ground station's and the report's case: unless this
    process has loaded numba already (it flies: ``swarm simulate``, an agent), the plain
    assignment, bit for bit the compiled one, so that those processes do not load numba (its
    first use costs ~0.6 s of CPU, more than they would ever save).
    """
    axes, s = align_axes_batch(
        np.asarray(sigma, dtype=float)[None], desired_axes[None], compiled=loaded()
    )
    return axes[0], s[0]


def align_axes_batch(
    sigma: FloatArray, desired_axes: FloatArray, *, compiled: bool = True
) -> tuple[FloatArray, FloatArray]:
    """:func:`align_axes` of K matrices at once: ``sigma`` and ``desired_axes`` (K, 3, 3) ->
    ``(R (K, 3, 3), s (K, 3))``, one stacked eigen-decomposition; ``compiled``: the assignment
    compiled by numba (the agents' core) or the plain one (the same bits).

    The assignment is greedy, most confident first: of the overlaps ``|d_k . e_j|`` of the first
    two desired axes (k = 0, 1) with the three eigenvectors, the largest pair (k, j) is taken (the
    first in (k, j) order on a tie), then the other desired axis takes the largest of the two
    eigenvectors left. A matrix that is not finite gives NaN axes and variances.
    """
    k_n = sigma.shape[0]
    sym = 0.5 * (sigma + np.swapaxes(sigma, 1, 2))
    finite = np.isfinite(sym.reshape(k_n, 9)).all(axis=1)
    if finite.all():
        evecs = _eigenvectors(sym)
    else:
        evecs = np.full((k_n, 3, 3), np.nan)
        if finite.any():
            evecs[finite] = _eigenvectors(sym[finite])
    overlap = np.abs(np.swapaxes(desired_axes, 1, 2) @ evecs)  # [K, desired k, eigen j]
    axes = np.empty((k_n, 3, 3))
    assign = _assign_axes_compiled if compiled else _assign_axes
    assign(overlap, evecs, np.ascontiguousarray(desired_axes, dtype=np.float64), axes)
    s = (axes * (sym @ axes)).sum(axis=1)
    return axes, s


def _assign_axes(
    overlap: FloatArray, evecs: FloatArray, desired_axes: FloatArray, axes: FloatArray
) -> None:
    """:func:`align_axes_batch`'s assignment (its doc), a loop over the K rows compiled by
    numba (:data:`_assign_axes_compiled`): from the overlaps ``|d_k . e_j|`` (K, 3, 3) of the
    desired axes with the eigenvectors (the columns of ``evecs`` (K, 3, 3)), the axes into
    ``axes`` (K, 3, 3): the two chosen eigenvectors signed along their desired axes, then their
    cross product. The choices are ``np.argmax``'s (the first largest; the first NaN, if any)."""
    for k in range(overlap.shape[0]):
        first, top = 0, overlap[k, 0, 0]
        if top == top:
            for i in range(1, 6):
                v = overlap[k, i // 3, i % 3]
                if v != v:
                    first = i
                    break
                if v > top:
                    first, top = i, v
        k1, j1 = first // 3, first % 3
        j2 = -1
        top = -np.inf
        for j in range(3):
            if j == j1:
                continue
            v = overlap[k, 1 - k1, j]
            if v != v:
                j2 = j
                break
            if j2 < 0 or v > top:
                j2, top = j, v
        for col in range(2):
            c = j1 if (col == 0) == (k1 == 0) else j2
            along = 0.0
            for m in range(3):
                along += desired_axes[k, m, col] * evecs[k, m, c]
            sign = -1.0 if along < 0.0 else 1.0
            for m in range(3):
                axes[k, m, col] = evecs[k, m, c] * sign
        # r1 x r2
        axes[k, 0, 2] = axes[k, 1, 0] * axes[k, 2, 1] - axes[k, 2, 0] * axes[k, 1, 1]
        axes[k, 1, 2] = axes[k, 2, 0] * axes[k, 0, 1] - axes[k, 0, 0] * axes[k, 2, 1]
        axes[k, 2, 2] = axes[k, 0, 0] * axes[k, 1, 1] - axes[k, 1, 0] * axes[k, 0, 1]


#: :func:`_assign_axes` compiled (protocols/runtime/compiled.py: on first use, cached), its
#: arithmetic IEEE's term by term as written (no ``fastmath``), so the axes are those of the plain
#: function to the last bit; the plain function stays callable (the tests' reference).
_assign_axes_compiled = jit(_assign_axes, error_model="numpy")


def _compiled() -> Callable[..., None]:
    """numba's dispatcher of :func:`_assign_axes` (compiled on first use)."""
    out: Callable[..., None] = dispatcher_of(_assign_axes_compiled)
    return out


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


def desired_axes_batch(a_desired: FloatArray) -> FloatArray:
    """:func:`desired_axes` of K descriptor vectors (K, 9): rotations (K, 3, 3)."""
    return rot_zyx_batch(a_desired[:, I_YAW], a_desired[:, I_PITCH], a_desired[:, I_ROLL])


def frame_vector_batch(centre_ned_m: FloatArray, axes: FloatArray, s: FloatArray) -> FloatArray:
    """:meth:`SwarmFrame.vector` of K frames: centres (K, 3), axes (K, 3, 3), variances (K, 3)
    -> descriptor vectors (K, 9)."""
    yaw, pitch, roll = zyx_from_rot_batch(axes)
    a = np.empty((centre_ned_m.shape[0], 9))
    a[:, CENTRE] = centre_ned_m
    a[:, I_ROLL], a[:, I_PITCH], a[:, I_YAW] = roll, pitch, yaw
    a[:, SHAPE] = s
    return a


def heading_defined(variances_m2: FloatArray) -> bool:
    """False while length and width variances are within 5 % of each other (heading undefined)."""
    s1, s2 = float(variances_m2[0]), float(variances_m2[1])
    return abs(s1 - s2) >= HEADING_TIE_RATIO * max(s1 + s2, 1e-12)

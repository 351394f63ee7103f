"""The consensus channels of one drone and the swarm statistics recovered from their averages.

ALGORITHM.md §3: every drone knows the shared reference centre mu_d(t) and its rate. With
``y = x_i - mu_d`` and ``y_dot = v_i - mu_d_dot`` each drone contributes 18 channels::

    zeta_i = [ y (3), sym6(y y^T) (6), y_dot (3), sym6(y_dot y^T + y y_dot^T) (6) ]

whose swarm averages m1, M2, m3, M4 give ``mu = mu_d + m1``, ``Sigma = M2 - m1 m1^T``,
``mu_dot = mu_d_dot + m3``, ``Sigma_dot = M4 - m3 m1^T - m1 m3^T``. Centring on the shared reference
avoids the cancellation of raw moments far from the origin.

In the plan's frame (issue 15): given the plan's axes R_d (columns: length, width, height axes in
NED) and its angular rate omega_d about them (``R_d_dot = R_d W_d``), the channels are taken of
``z = R_d^T y`` and ``z_dot = R_d^T y_dot - W_d z``, the offset and its rate as seen from the
plan's own turning frame. A formation that turns with the plan has constant channels there, so
the consensus tracks constants instead of chasing a turning second moment (on a sparse radio
graph that chase left the estimated heading 1-3 deg behind during a turn). The averages go back
exactly: ``m1 = R_d m1'``, ``M2 = R_d M2' R_d^T``, ``m3 = R_d (m3' + W_d m1')``,
``M4 = R_d (M4' + W_d M2' - M2' W_d) R_d^T``. Every agent evaluates the same plan at the same
round time, so every agent uses the same frame. Pure and I/O-free.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from protocols.frames import FloatArray

N_CHANNELS = 18
#: Order of the 6 entries of a symmetric 3x3 matrix: xx, yy, zz, xy, xz, yz.
_SYM_I = np.array([0, 1, 2, 0, 0, 1])
_SYM_J = np.array([0, 1, 2, 1, 2, 2])


def sym6(m: FloatArray) -> FloatArray:
    """The 6 independent entries (xx, yy, zz, xy, xz, yz) of a symmetric matrix (3, 3)."""
    return m[_SYM_I, _SYM_J]


def unsym6(v: FloatArray) -> FloatArray:
    """Symmetric matrix (3, 3) from its 6 entries (xx, yy, zz, xy, xz, yz)."""
    m = np.empty((3, 3))
    m[_SYM_I, _SYM_J] = v
    m[_SYM_J, _SYM_I] = v
    return m


def channels(
    position_ned_m: FloatArray,
    velocity_ned_m_s: FloatArray,
    ref_centre_ned_m: FloatArray,
    ref_centre_rate_ned_m_s: FloatArray,
) -> FloatArray:
    """The 18 consensus channels zeta_i (18,) of one drone (see module docstring)."""
    x = np.asarray(position_ned_m, dtype=float)[None, :]
    v = np.asarray(velocity_ned_m_s, dtype=float)[None, :]
    out: FloatArray = channels_batch(x, v, ref_centre_ned_m, ref_centre_rate_ned_m_s)[0]
    return out


def channels_batch(
    positions_ned_m: FloatArray,
    velocities_ned_m_s: FloatArray,
    ref_centre_ned_m: FloatArray,
    ref_centre_rate_ned_m_s: FloatArray,
    plan_frame: tuple[FloatArray, FloatArray] | None = None,
) -> FloatArray:
    """Channels (N, 18) of N drones at once (positions and velocities (N, 3)); ``plan_frame``:
    the plan's axes (N, 3, 3) and angular rate about them (N, 3) (module doc), None: NED."""
    y = np.asarray(positions_ned_m, dtype=float) - ref_centre_ned_m
    yd = np.asarray(velocities_ned_m_s, dtype=float) - ref_centre_rate_ned_m_s
    if plan_frame is not None:
        axes, omega = plan_frame
        y = (y[:, None, :] @ axes)[:, 0]  # R^T y, row-wise
        yd = (yd[:, None, :] @ axes)[:, 0] - np.cross(omega, y)
    out = np.empty((y.shape[0], N_CHANNELS))
    out[:, 0:3] = y
    out[:, 3:9] = y[:, _SYM_I] * y[:, _SYM_J]
    out[:, 9:12] = yd
    out[:, 12:18] = yd[:, _SYM_I] * y[:, _SYM_J] + y[:, _SYM_I] * yd[:, _SYM_J]
    return out


@dataclass(frozen=True)
class SwarmMoments:
    """Centre, covariance and their rates, NED: mu (3,) m, sigma (3, 3) m^2, rates per second
    (with a leading K axis on every field when it holds K agents' views, as from
    :func:`moments_from_averages_batch`)."""

    centre_ned_m: FloatArray
    centre_rate_ned_m_s: FloatArray
    sigma_m2: FloatArray
    sigma_rate_m2_s: FloatArray


def moments_from_averages(
    averages: FloatArray, ref_centre_ned_m: FloatArray, ref_centre_rate_ned_m_s: FloatArray
) -> SwarmMoments:
    """Swarm moments from the (estimated) averages of the 18 channels."""
    batch = moments_from_averages_batch(
        np.asarray(averages, dtype=float)[None, :],
        np.asarray(ref_centre_ned_m, dtype=float)[None, :],
        np.asarray(ref_centre_rate_ned_m_s, dtype=float)[None, :],
    )
    return SwarmMoments(
        batch.centre_ned_m[0],
        batch.centre_rate_ned_m_s[0],
        batch.sigma_m2[0],
        batch.sigma_rate_m2_s[0],
    )


def moments_from_averages_batch(
    averages: FloatArray,
    ref_centre_ned_m: FloatArray,
    ref_centre_rate_ned_m_s: FloatArray,
    plan_frame: tuple[FloatArray, FloatArray] | None = None,
) -> SwarmMoments:
    """As :func:`moments_from_averages` for K agents at once: averages (K, 18), references
    (K, 3), ``plan_frame`` as in :func:`channels_batch` ((K, 3, 3), (K, 3)); the fields of the
    result carry the leading K axis ((K, 3) and (K, 3, 3))."""
    m1 = averages[:, 0:3]
    m3 = averages[:, 9:12]
    m2 = np.empty((averages.shape[0], 3, 3))
    m2[:, _SYM_I, _SYM_J] = averages[:, 3:9]
    m2[:, _SYM_J, _SYM_I] = averages[:, 3:9]
    m4 = np.empty_like(m2)
    m4[:, _SYM_I, _SYM_J] = averages[:, 12:18]
    m4[:, _SYM_J, _SYM_I] = averages[:, 12:18]
    if plan_frame is not None:  # back from the plan's turning frame (module doc)
        axes, omega = plan_frame
        axes_t = np.swapaxes(axes, 1, 2)
        m3 = ((m3 + np.cross(omega, m1))[:, None, :] @ axes_t)[:, 0]
        turn = _skew_batch(omega) @ m2
        m4 = axes @ (m4 + turn + np.swapaxes(turn, 1, 2)) @ axes_t
        m2 = axes @ m2 @ axes_t
        m1 = (m1[:, None, :] @ axes_t)[:, 0]
    sigma = m2 - m1[:, :, None] * m1[:, None, :]
    sigma_rate = m4 - m3[:, :, None] * m1[:, None, :] - m1[:, :, None] * m3[:, None, :]
    return SwarmMoments(
        centre_ned_m=ref_centre_ned_m + m1,
        centre_rate_ned_m_s=ref_centre_rate_ned_m_s + m3,
        sigma_m2=sigma,
        sigma_rate_m2_s=sigma_rate,
    )


def _skew_batch(v: FloatArray) -> FloatArray:
    """Skew-symmetric matrices (K, 3, 3) of vectors (K, 3)."""
    out = np.zeros((v.shape[0], 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return out


def true_moments(positions_ned_m: FloatArray, velocities_ned_m_s: FloatArray) -> SwarmMoments:
    """The exact moments of positions and velocities (N, 3): what a perfect estimator returns."""
    x = np.asarray(positions_ned_m, dtype=float)
    v = np.asarray(velocities_ned_m_s, dtype=float)
    mu, mu_dot = x.mean(axis=0), v.mean(axis=0)
    p, pd = x - mu, v - mu_dot
    n = x.shape[0]
    return SwarmMoments(mu, mu_dot, (p.T @ p) / n, (pd.T @ p + p.T @ pd) / n)

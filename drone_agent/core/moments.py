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
round time, so every agent uses the same frame. The batched forms are compiled loops over the
drones (drone_agent/core/jit_math.py). Pure and I/O-free.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drone_agent.core.jit_math import f64, jit
from protocols.model.frames import FloatArray

N_CHANNELS = 18
#: Order of the 6 entries of a symmetric 3x3 matrix: xx, yy, zz, xy, xz, yz.
_SYM_I = (0, 1, 2, 0, 0, 1)
_SYM_J = (0, 1, 2, 1, 2, 2)


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
    y = f64(np.asarray(positions_ned_m, dtype=float) - ref_centre_ned_m)
    yd = f64(np.asarray(velocities_ned_m_s, dtype=float) - ref_centre_rate_ned_m_s)
    out = np.empty((y.shape[0], N_CHANNELS))
    if plan_frame is None:
        _channel_rows(y, yd, _NO_FRAME[0], _NO_FRAME[1], False, out)
    else:
        axes, omega = plan_frame
        _channel_rows(y, yd, f64(axes), f64(omega), True, out)
    return out


#: Placeholders of the compiled loops' frame arguments when there is no plan frame.
_NO_FRAME = (np.zeros((1, 3, 3)), np.zeros((1, 3)))


@jit
def _channel_rows(y_all, yd_all, axes, omega, turning, out):  # type: ignore[no-untyped-def]
    """The channels of each drone into ``out`` (N, 18) from its offset and offset rate from the
    reference (N, 3) each; with ``turning`` taken in the plan's frame (module doc)."""
    z, zd = np.empty(3), np.empty(3)
    for r in range(y_all.shape[0]):
        y, yd = y_all[r], yd_all[r]
        if turning:
            rot, w = axes[r], omega[r]
            for i in range(3):  # R^T y, R^T y_dot
                z[i] = y[0] * rot[0, i] + y[1] * rot[1, i] + y[2] * rot[2, i]
                zd[i] = yd[0] * rot[0, i] + yd[1] * rot[1, i] + yd[2] * rot[2, i]
            zd[0] = zd[0] - (w[1] * z[2] - w[2] * z[1])  # - W z = - omega x z
            zd[1] = zd[1] - (w[2] * z[0] - w[0] * z[2])
            zd[2] = zd[2] - (w[0] * z[1] - w[1] * z[0])
        else:
            for i in range(3):
                z[i] = y[i]
                zd[i] = yd[i]
        for i in range(3):
            out[r, i] = z[i]
            out[r, 9 + i] = zd[i]
        for c in range(6):
            i, j = _SYM_I[c], _SYM_J[c]
            out[r, 3 + c] = z[i] * z[j]
            out[r, 12 + c] = zd[i] * z[j] + z[i] * zd[j]


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
    k = averages.shape[0]
    m1, m3 = np.empty((k, 3)), np.empty((k, 3))
    sigma, sigma_rate = np.empty((k, 3, 3)), np.empty((k, 3, 3))
    if plan_frame is None:
        _moment_rows(f64(averages), _NO_FRAME[0], _NO_FRAME[1], False, m1, m3, sigma, sigma_rate)
    else:
        axes, omega = f64(plan_frame[0]), f64(plan_frame[1])
        _moment_rows(f64(averages), axes, omega, True, m1, m3, sigma, sigma_rate)
    return SwarmMoments(
        centre_ned_m=ref_centre_ned_m + m1,
        centre_rate_ned_m_s=ref_centre_rate_ned_m_s + m3,
        sigma_m2=sigma,
        sigma_rate_m2_s=sigma_rate,
    )


@jit
def _moment_rows(averages, axes, omega, turning, m1_out, m3_out, sigma, sigma_rate):  # type: ignore[no-untyped-def]
    """Each row's m1, m3 (the centre and its rate from the reference), Sigma and Sigma_dot from
    its channel averages; with ``turning`` back from the plan's frame (module doc)."""
    m1, m3, t1 = np.empty(3), np.empty(3), np.empty(3)
    m2, m4, x, tmp = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    for r in range(averages.shape[0]):
        avg = averages[r]
        for c in range(6):
            i, j = _SYM_I[c], _SYM_J[c]
            m2[i, j] = avg[3 + c]
            m2[j, i] = avg[3 + c]
            m4[i, j] = avg[12 + c]
            m4[j, i] = avg[12 + c]
        for i in range(3):
            m1[i] = avg[i]
            m3[i] = avg[9 + i]
        if turning:
            rot, w = axes[r], omega[r]
            # m3 = R (m3' + omega x m1')
            t1[0] = m3[0] + (w[1] * m1[2] - w[2] * m1[1])
            t1[1] = m3[1] + (w[2] * m1[0] - w[0] * m1[2])
            t1[2] = m3[2] + (w[0] * m1[1] - w[1] * m1[0])
            for i in range(3):
                m3[i] = t1[0] * rot[i, 0] + t1[1] * rot[i, 1] + t1[2] * rot[i, 2]
            # M4 = R (M4' + W M2' + (W M2')^T) R^T, M2 = R M2' R^T, m1 = R m1'
            for i in range(3):
                for c in range(3):
                    x[i, c] = _skew_dot(w, m2, i, c)
            for i in range(3):
                for c in range(3):
                    tmp[i, c] = m4[i, c] + x[i, c] + x[c, i]
            _rotate(rot, tmp, m4)
            for i in range(3):
                t1[i] = m1[i]
                for c in range(3):
                    tmp[i, c] = m2[i, c]
            _rotate(rot, tmp, m2)
            for i in range(3):
                m1[i] = t1[0] * rot[i, 0] + t1[1] * rot[i, 1] + t1[2] * rot[i, 2]
        for i in range(3):
            m1_out[r, i] = m1[i]
            m3_out[r, i] = m3[i]
            for c in range(3):
                sigma[r, i, c] = m2[i, c] - m1[i] * m1[c]
                sigma_rate[r, i, c] = m4[i, c] - m3[i] * m1[c] - m1[i] * m3[c]


@jit
def _skew_dot(w, m, i, c):  # type: ignore[no-untyped-def]
    """``(skew(w) @ m)[i, c]`` (skew(w) = [[0, -w2, w1], [w2, 0, -w0], [-w1, w0, 0]])."""
    if i == 0:
        return 0.0 * m[0, c] + -w[2] * m[1, c] + w[1] * m[2, c]
    if i == 1:
        return w[2] * m[0, c] + 0.0 * m[1, c] + -w[0] * m[2, c]
    return -w[1] * m[0, c] + w[0] * m[1, c] + 0.0 * m[2, c]


@jit
def _rotate(rot, m, out):  # type: ignore[no-untyped-def]
    """``out = (R @ m) @ R^T`` (3, 3)."""
    t = np.empty((3, 3))
    for i in range(3):
        for c in range(3):
            t[i, c] = rot[i, 0] * m[0, c] + rot[i, 1] * m[1, c] + rot[i, 2] * m[2, c]
    for i in range(3):
        for c in range(3):
            out[i, c] = t[i, 0] * rot[c, 0] + t[i, 1] * rot[c, 1] + t[i, 2] * rot[c, 2]


def true_moments(positions_ned_m: FloatArray, velocities_ned_m_s: FloatArray) -> SwarmMoments:
    """The exact moments of positions and velocities (N, 3): what a perfect estimator returns."""
    x = np.asarray(positions_ned_m, dtype=float)
    v = np.asarray(velocities_ned_m_s, dtype=float)
    mu, mu_dot = x.mean(axis=0), v.mean(axis=0)
    p, pd = x - mu, v - mu_dot
    n = x.shape[0]
    return SwarmMoments(mu, mu_dot, (p.T @ p) / n, (pd.T @ p + p.T @ pd) / n)

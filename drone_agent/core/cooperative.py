"""The cooperative motion controller: each drone's own block of the pseudo-inverse.

ALGORITHM.md §4.

The rows of the descriptor Jacobian are mutually orthogonal, so ``beta# = beta^T (beta beta^T)^-1``
splits per drone, and drone i's virtual acceleration is an affine field of its own offset
``p_i = x_i - mu`` from the (estimated) centre::

    v_i = w_mu + R A R^T p_i  (+ flat-axis PD, + null-space damping)

with A symmetric in the swarm frame: ``A_kk = w_sk / (2 s_k)`` and, for the pair (j, k) rotating
about the third axis m, ``A_jk = [(s_k - s_j) Omega_jk - kd_m (Sigma'_dot_jk - (s_k - s_j) W_jk)]
/ (s_j + s_k)`` where ``Omega = skew(alpha)`` is the commanded angular acceleration of the swarm
frame, ``W = skew(omega_d)`` its desired angular rate and ``Sigma'_dot = R^T Sigma_dot R``. It uses
only the drone's own state and the estimated descriptors: it does not depend on N.

Null-space damping ``-k_null (p_dot - R B R^T p)`` (ALGORITHM.md §4) with one change: along a
commanded-flat axis ``B_kk = 0``. There ``B_kk = Sigma'_dot_kk / (2 s_min)`` would "explain" any
estimated thickening with a 10 /s gain and push every drone further from the plane; on sparse
radio graphs (25 drones, 6 m range) the estimate noise was enough to split the swarm vertically
after take-off. The flat-axis PD alone holds that axis.

Terms the field leaves out (issue 15). With ``Sigma' = R^T Sigma R = S`` (diagonal), swarm-frame
rate ``W = skew(omega)`` (``R_dot = R W``) and ``M = R^T Sigma_dot R = [W, S] + S_dot``, the
kinematics of the descriptors are::

    R^T Sigma_ddot R = [W, M] + [W_dot, S] + [W, S_dot] + S_ddot        ([X, Y] = XY - YX)

while the field gives ``R^T Sigma_ddot R = A S + S A + 2 P'`` with ``P' = R^T (1/N sum p_dot
p_dot^T) R``, the 2 p_dot p_dot^T term. Matching them for the commanded ``W_dot`` and ``S_ddot``
needs ``A S + S A = [W_dot_cmd, S] + S_ddot_cmd + C`` with ``C = [W, M] + [W, S_dot] - 2 P'``. For
a formation that moves as the plan does, ``p_dot = R G R^T p`` with ``G = W + S_dot S^-1 / 2``
(lattice coordinates fixed: p = R S^1/2 q), ``P' = G S G^T`` and ``C`` simplifies to::

    C = W^2 S + S W^2 + [W, S_dot] - S_dot^2 S^-1 / 2
    C_kk = 2 (omega_k^2 - |omega|^2) s_k - s_dot_k^2 / (2 s_k)
    C_jk = omega_j omega_k (s_j + s_k) + W_jk (s_dot_k - s_dot_j)

(:func:`_plan_rate_terms_into`), taken with the plan's rate omega_d and variance rates; ``A_kk``
gains ``C_kk / (2 s_k)`` and ``A_jk`` gains ``C_jk / (s_j + s_k)``. A pure rotation gives
``A = W^2`` (centripetal); a stretch at constant rate gives ``A_kk = -s_dot^2 / (4 s^2)``. The
plan's angular acceleration is ``omega_dot = E eta_ddot + E_dot eta_dot``
(:func:`euler_rate_derivative_batch`; the E_dot term was left out too).

The plan's whole field. The drones of that formation accelerate as ``p_ddot = R F R^T p`` with
``F = W_dot + W^2 + W S_dot S^-1 + S_ddot^1/2 S^-1/2``, which is not symmetric: A is its
symmetric part in the sense ``A S + S A = F S + S F^T``. The rest, ``N = F - A`` with ``N_jk =
s_j D_jk / (s_j + s_k)``, ``N_kj = -s_k D_jk / (s_j + s_k)``, ``D_jk = 2 W_dot_jk + W_jk (s_dot_j /
s_j + s_dot_k / s_k)``, has ``N S`` antisymmetric: it moves neither mu nor Sigma, it turns the
lattice with the formation (:func:`_add_plan_null_field`). With both, every drone's command is its
own acceleration on the plan (tests/test_cooperative.py checks it against finite differences).

Orientation feedback: its own PD (``CooperativeGains.orientation_*``) on the rotation error and on
the rate error ``omega - omega_d`` read from ``Sigma_dot'_jk - (s_k - s_j) W_d,jk = (s_k - s_j)
(W - W_d)_jk``, with the rate it asks for and its acceleration limited (per axis, at the
formation's RMS radius ``sqrt(s_j + s_k)`` in the plane of the pair). The explained motion of the
null-space damping is ``G p`` with ``G = W_d + G_s``, ``G_s`` symmetric with ``G_s S + S G_s =
Sigma_dot' - [W_d, S]``, and the flat-axis PD damps ``h_dot - (W_d p)_h``, the rate beyond the
plan's own turn: a formation turning with the plan is not braked (the flat-axis PD damped every
tilt rate of a planar formation with its 1.75 /s before, the 12-15 s lag of issue 15), and mu
and Sigma are still untouched by that damping to first order.

The field is one compiled loop over the drones (drone_agent/core/jit_math.py). Pure and I/O-free.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from drone_agent.core.jit_math import f64, jit, nmax, nmin
from drone_agent.core.moments import SwarmMoments
from protocols.model.descriptors import align_axes_batch, desired_axes_batch
from protocols.model.frames import FloatArray

PAPER_KP = (0.5, 0.5, 1.75, 0.15, 0.15, 0.15, 0.5, 0.5, 0.5)
#: Orientation PD gains (roll, pitch, yaw about the swarm axes): natural frequency 0.71 rad/s,
#: damping 0.9 (the paper's 0.15 gave 0.39 rad/s; 1.0 tracked no better with the plan's rates
#: fed forward and made the paper flight's shape error twice as large).
ORIENTATION_KP = (0.5, 0.5, 0.5)
ORIENTATION_KD = (1.8 * 0.5**0.5,) * 3
#: Off-diagonal pairs (j, k) of the swarm frame and the axis m each pair rotates about.
_PAIRS = ((1, 2, 0), (0, 2, 1), (0, 1, 2))


@dataclass(frozen=True)
class CooperativeGains:
    """Outer-loop gains, descriptor order (mu_x, mu_y, mu_z, roll, pitch, yaw, s1, s2, s3).

    ``kd`` defaults to 1.8 sqrt(kp) (ALGORITHM.md §6); the orientation entries of ``kp``/``kd``
    (3..5) are not used: orientation has its own gains. ``flat_kp``/``flat_kd``: local PD that
    holds a drone on a commanded-flat axis (1/s^2, 1/s); ``null_damping_per_s``: null-space
    damping; ``min_variance_m2``: guard below which a commanded variance counts as flat.

    Orientation (roll, pitch, yaw about the swarm's own axes): PD gains ``orientation_kp``
    (1/s^2) and ``orientation_kd`` (1/s) on the rotation error and rate error, with limits on
    the feedback only (the plan's own rate and acceleration are fed forward in full): the rate
    the position error asks for moves the formation's RMS radius in that plane at most
    ``orientation_max_speed_m_s``, and the feedback's angular acceleration accelerates it at most
    ``orientation_max_accel_m_s2`` (about 6 deg of tilt at the RMS radius, twice that at the
    edge of a grid), so take-off transients and large commands stay inside the tilt limit.
    """

    kp: tuple[float, ...] = PAPER_KP
    kd: tuple[float, ...] = tuple(1.8 * np.sqrt(k) for k in PAPER_KP)
    flat_kp: float = 1.75
    flat_kd: float = 1.75
    null_damping_per_s: float = 1.0
    min_variance_m2: float = 0.05
    orientation_kp: tuple[float, float, float] = ORIENTATION_KP
    orientation_kd: tuple[float, float, float] = ORIENTATION_KD
    orientation_max_speed_m_s: float = 1.0
    orientation_max_accel_m_s2: float = 1.0


def skew(a: FloatArray) -> FloatArray:
    """Skew-symmetric matrix (3, 3) of a vector (3,): ``skew(a) @ b == cross(a, b)``."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def euler_rate_matrix(roll: float, pitch: float) -> FloatArray:
    """E (3, 3) mapping ZYX Euler-angle rates (roll, pitch, yaw) to body rates (p, q, r)."""
    out: FloatArray = euler_rate_matrix_batch(np.array([roll]), np.array([pitch]))[0]
    return out


def shape_matrix(
    variances_m2: FloatArray,
    w_shape: FloatArray,
    alpha: FloatArray,
    damping: FloatArray | None = None,
    min_variance_m2: float = 0.0,
    flat: tuple[bool, bool, bool] = (False, False, False),
) -> FloatArray:
    """The symmetric matrix A (3, 3) of the affine field, in the swarm frame.

    ``w_shape`` (3,): commanded variance accelerations (m^2/s^2); ``alpha`` (3,): commanded angular
    acceleration of the swarm frame about its own axes (rad/s^2); ``damping`` (3,): numerators
    added to each pair (j, k) of axis m (the terms of the module doc), default 0. Flat axes get
    no variance row (``A_kk = 0``).
    """
    a: FloatArray = shape_matrix_batch(
        np.asarray(variances_m2, dtype=float)[None],
        np.asarray(w_shape, dtype=float)[None],
        np.asarray(alpha, dtype=float)[None],
        np.zeros((1, 3)) if damping is None else np.asarray(damping, dtype=float)[None],
        min_variance_m2,
        np.asarray(flat, dtype=bool)[None],
    )[0]
    return a


# The pairs of _PAIRS (j, k per m) and the sign of skew(v)[j, k] = _SIGN[m] v[m].
_J, _K = (1, 0, 0), (2, 2, 1)
_SIGN = (-1.0, 1.0, -1.0)


@jit
def _shape_row(s, w_shape, alpha, damping, s_min, flat, a):  # type: ignore[no-untyped-def]
    """:func:`shape_matrix` into ``a`` (3, 3): one drone's A from its variances ``s``, commanded
    variance accelerations ``w_shape``, angular acceleration ``alpha``, pair numerators
    ``damping`` (3,) each, the variance guard and the flat axes (3,) bool."""
    for i in range(3):
        a[i, i] = 0.0 if flat[i] else w_shape[i] / (2.0 * nmax(s[i], s_min))
    for m in range(3):
        j, k = _J[m], _K[m]
        value = ((s[k] - s[j]) * (alpha[m] * _SIGN[m]) + damping[m]) / nmax(s[j] + s[k], s_min)
        a[j, k] = value
        a[k, j] = value


@jit
def _shape_rows(s, w_shape, alpha, damping, s_min, flat, out):  # type: ignore[no-untyped-def]
    """:func:`_shape_row` of each row."""
    for r in range(s.shape[0]):
        _shape_row(s[r], w_shape[r], alpha[r], damping[r], s_min, flat[r], out[r])


def shape_matrix_batch(
    variances_m2: FloatArray,
    w_shape: FloatArray,
    alpha: FloatArray,
    damping: FloatArray,
    min_variance_m2: float,
    flat: npt.NDArray[np.bool_],
) -> FloatArray:
    """:func:`shape_matrix` of K agents: every argument with a leading K axis ((K, 3); ``flat``
    (K, 3) bool) -> A (K, 3, 3)."""
    out = np.zeros((variances_m2.shape[0], 3, 3))
    _shape_rows(
        f64(variances_m2),
        f64(w_shape),
        f64(alpha),
        f64(damping),
        float(min_variance_m2),
        np.ascontiguousarray(flat, dtype=np.bool_),
        out,
    )
    return out


@functools.lru_cache(maxsize=16)
def _gain_vector(gains: CooperativeGains) -> FloatArray:
    """The gains the compiled field reads, in :func:`_field_rows`'s order (30,)."""
    return np.array(
        [
            *gains.kp,
            *gains.kd,
            gains.min_variance_m2,
            *gains.orientation_kp,
            *gains.orientation_kd,
            gains.orientation_max_speed_m_s,
            gains.orientation_max_accel_m_s2,
            gains.flat_kp,
            gains.flat_kd,
            gains.null_damping_per_s,
        ],
        dtype=np.float64,
    )


def virtual_acceleration_batch(
    positions_ned_m: FloatArray,
    velocities_ned_m_s: FloatArray,
    swarm: SwarmMoments,
    reference: tuple[FloatArray, FloatArray, FloatArray],
    gains: CooperativeGains,
    frame: tuple[FloatArray, FloatArray, FloatArray] | None = None,
) -> FloatArray:
    """:func:`virtual_acceleration` of K drones, each with its own estimate and plan value:
    positions and velocities (K, 3), ``swarm`` with fields (K, 3) and (K, 3, 3), ``reference``
    (K, 9) each. ``frame``: ``(R_d, R, s)`` if already known (desired axes (K, 3, 3), the
    estimate's axes assigned to them (K, 3, 3) and variances (K, 3)). Returns v (K, 3).

    One compiled loop over the drones (:func:`_field_rows`): at the few drones of an agent
    process, numpy's per-call overhead was most of the field's cost."""
    a_d, ad_dot, ad_ddot = reference
    if frame is None:
        r_d = desired_axes_batch(a_d)
        axes, s = align_axes_batch(swarm.sigma_m2, r_d)
    else:
        r_d, axes, s = frame
    out = np.empty((a_d.shape[0], 3))
    _field_rows(
        f64(positions_ned_m),
        f64(velocities_ned_m_s),
        f64(swarm.centre_ned_m),
        f64(swarm.centre_rate_ned_m_s),
        f64(swarm.sigma_rate_m2_s),
        f64(a_d),
        f64(ad_dot),
        f64(ad_ddot),
        f64(r_d),
        f64(axes),
        f64(s),
        _gain_vector(gains),
        out,
    )
    return out


@jit
def _field_rows(  # type: ignore[no-untyped-def]
    x, v, centre, centre_rate, sigma_rate, a_d, ad_dot, ad_ddot, r_d, axes, s_all, g, out
):
    """The field of each drone r into ``out[r]`` (the module doc, term by term)."""
    kp, kd, s_min = g[0:9], g[9:18], g[18]
    okp, okd = g[19:22], g[22:25]
    max_speed, max_accel, flat_kp, flat_kd, k_null = g[25], g[26], g[27], g[28], g[29]
    rf = np.empty((3, 3))
    tmp = np.empty((3, 3))
    turn = np.empty((3, 3))  # R^T R_d
    a = np.empty((3, 3))
    gm = np.empty((3, 3))
    e = np.empty((3, 3))
    flat = np.empty(3, dtype=np.bool_)
    sg, pair_sum, w_s = np.empty(3), np.empty(3), np.empty(3)
    body_rate, body_accel, e_dot = np.empty(3), np.empty(3), np.empty(3)
    omega, alpha, twist, alpha_cmd = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    c_diag, c_pairs, p_s, pd_s, vs = np.empty(3), np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    for r in range(x.shape[0]):
        rot, s, sr = axes[r], s_all[r], sigma_rate[r]
        # Sigma_dot' = R^T Sigma_dot R
        for i in range(3):
            for c in range(3):
                tmp[i, c] = rot[0, i] * sr[0, c] + rot[1, i] * sr[1, c] + rot[2, i] * sr[2, c]
        for i in range(3):
            for c in range(3):
                rf[i, c] = tmp[i, 0] * rot[0, c] + tmp[i, 1] * rot[1, c] + tmp[i, 2] * rot[2, c]
        for i in range(3):
            flat[i] = a_d[r, 6 + i] < s_min
            sg[i] = nmax(s[i], s_min)
            w_s[i] = (
                ad_ddot[r, 6 + i]
                - kd[6 + i] * (rf[i, i] - ad_dot[r, 6 + i])
                - kp[6 + i] * (s[i] - a_d[r, 6 + i])
            )
        for m in range(3):
            pair_sum[m] = nmax(s[_J[m]] + s[_K[m]], s_min)
        # the plan's angular rate and acceleration (omega = E eta_dot, omega_dot = E eta_ddot +
        # E_dot eta_dot) in the desired frame, then about the estimated swarm axes
        _euler_rate_matrix_into(a_d[r, 3], a_d[r, 4], e)
        _euler_rate_derivative_into(a_d[r, 3], a_d[r, 4], ad_dot[r, 3:6], e_dot)
        for i in range(3):
            body_rate[i] = e[i, 0] * ad_dot[r, 3] + e[i, 1] * ad_dot[r, 4] + e[i, 2] * ad_dot[r, 5]
            body_accel[i] = (
                e[i, 0] * ad_ddot[r, 3] + e[i, 1] * ad_ddot[r, 4] + e[i, 2] * ad_ddot[r, 5]
            ) + e_dot[i]
        for i in range(3):
            for c in range(3):
                turn[i, c] = (
                    rot[0, i] * r_d[r, 0, c] + rot[1, i] * r_d[r, 1, c] + rot[2, i] * r_d[r, 2, c]
                )
        for i in range(3):
            omega[i] = (
                turn[i, 0] * body_rate[0] + turn[i, 1] * body_rate[1] + turn[i, 2] * body_rate[2]
            )
            alpha[i] = (
                turn[i, 0] * body_accel[0] + turn[i, 1] * body_accel[1] + turn[i, 2] * body_accel[2]
            )
        # rotation feedback per axis m of the pair (j, k): the rate error read from Sigma_dot'
        # (Sigma_dot'_jk = (s_k - s_j) [W]_jk + ...), a PD with limits on the feedback; the
        # rotation error vee((R_d^T R - R^T R_d) / 2) is turn's antisymmetric part
        for m in range(3):
            j, k = _J[m], _K[m]
            spread = (s[k] - s[j]) * _SIGN[m]
            twist[m] = spread * omega[m]
            guard = (-1.0 if spread < 0.0 else 1.0) * nmax(abs(spread), s_min)
            rate_error = (rf[j, k] - twist[m]) / guard
            radius = np.sqrt(pair_sum[m])  # RMS radius of the formation in the pair's plane
            max_rate = max_speed / radius
            max_alpha = max_accel / radius
            rotation_error = 0.5 * (turn[j, k] - turn[k, j]) * -_SIGN[m]
            wanted = nmin(nmax(okp[m] / okd[m] * rotation_error, -max_rate), max_rate)
            feedback = nmin(nmax(-okd[m] * (rate_error + wanted), -max_alpha), max_alpha)
            alpha_cmd[m] = alpha[m] + feedback
        _plan_rate_terms_into(s, sg, omega, ad_dot[r, 6:9], c_diag, c_pairs)
        for i in range(3):
            w_s[i] = w_s[i] + c_diag[i]
        _shape_row(s, w_s, alpha_cmd, c_pairs, s_min, flat, a)
        _add_plan_null_field(s, sg, pair_sum, omega, alpha, ad_dot[r, 6:9], a)
        # the explained motion p_dot = G p: the plan's rotation W_d plus the symmetric G_s that
        # makes G Sigma' + Sigma' G^T the estimated Sigma_dot' (so the damping below leaves mu
        # and Sigma alone to first order, and a formation turning with the plan is not braked);
        # the flat-axis PD holds a flat axis: no spreading rate there is "explained" (its
        # 1/(2 s_min) gain turned estimate noise into a growing split)
        for i in range(3):
            gm[i, i] = 0.0 if flat[i] else rf[i, i] / (2.0 * sg[i])
        for m in range(3):
            j, k = _J[m], _K[m]
            sym = (rf[j, k] - twist[m]) / pair_sum[m]
            gm[j, k] = sym + omega[m] * _SIGN[m]
            gm[k, j] = sym - omega[m] * _SIGN[m]
        # p and p_dot in the swarm frame
        for i in range(3):
            p_s[i] = (
                rot[0, i] * (x[r, 0] - centre[r, 0])
                + rot[1, i] * (x[r, 1] - centre[r, 1])
                + rot[2, i] * (x[r, 2] - centre[r, 2])
            )
            pd_s[i] = (
                rot[0, i] * (v[r, 0] - centre_rate[r, 0])
                + rot[1, i] * (v[r, 1] - centre_rate[r, 1])
                + rot[2, i] * (v[r, 2] - centre_rate[r, 2])
            )
        for i in range(3):
            a_p = a[i, 0] * p_s[0] + a[i, 1] * p_s[1] + a[i, 2] * p_s[2]
            unexplained = pd_s[i] - (gm[i, 0] * p_s[0] + gm[i, 1] * p_s[1] + gm[i, 2] * p_s[2])
            if flat[i]:
                # the flat-axis PD damps the offset rate beyond the plan's own turn (not G p:
                # its estimated part, times the lever of a drone far out, broke the 250-drone
                # grid at a drop-out)
                n, f = (i + 1) % 3, (i + 2) % 3
                planned = pd_s[i] - (omega[n] * p_s[f] - omega[f] * p_s[n])
                a_p = a_p - (flat_kp * p_s[i] + flat_kd * planned)
            vs[i] = a_p - k_null * unexplained
        for i in range(3):
            out[r, i] = (
                ad_ddot[r, i]
                - kd[i] * (centre_rate[r, i] - ad_dot[r, i])
                - kp[i] * (centre[r, i] - a_d[r, i])
            ) + (rot[i, 0] * vs[0] + rot[i, 1] * vs[1] + rot[i, 2] * vs[2])


@jit
def _add_plan_null_field(s, sg, pair_sum, omega, alpha, s_dot, a):  # type: ignore[no-untyped-def]
    """Add to ``a`` (3, 3) the null-space part N of the plan's field (module doc, "The plan's
    whole field"): ``N_jk = s_j D_jk / (s_j + s_k)``, ``N_kj = -s_k D_jk / (s_j + s_k)`` with
    ``D = 2 skew(alpha) + skew(omega) (Ṡ S⁻¹ + S⁻¹ Ṡ)`` entrywise on the pairs. ``N S`` is
    antisymmetric: it moves no drone's share of mu or Sigma, it turns the lattice with them."""
    for m in range(3):
        j, k = _J[m], _K[m]
        d = (2.0 * alpha[m] + omega[m] * (s_dot[j] / sg[j] + s_dot[k] / sg[k])) * _SIGN[m]
        d = d / pair_sum[m]
        a[j, k] = a[j, k] + nmax(s[j], 0.0) * d
        a[k, j] = a[k, j] + -nmax(s[k], 0.0) * d


@jit
def _plan_rate_terms_into(s, sg, omega, s_dot, diag, pairs):  # type: ignore[no-untyped-def]
    """The terms of ``Rᵀ Σ̈ R`` that the affine field leaves out, for a formation moving as the
    plan does (module doc, "Terms the field leaves out"): ``C = W²S + SW² + [W, Ṡ] − Ṡ² S⁻¹ / 2``
    with ``W = skew(omega)``. Variances ``s`` (3,) (``sg`` the guarded ones), the plan's angular
    rate about the swarm axes ``omega`` and variance rates ``s_dot``. Writes the diagonal
    ``C_kk`` into ``diag`` and the pairs ``C_jk`` into ``pairs``, indexed by m as :data:`_PAIRS`."""
    w0, w1, w2 = omega[0] * omega[0], omega[1] * omega[1], omega[2] * omega[2]
    total = w0 + w1 + w2
    diag[0] = 2.0 * (w0 - total) * s[0] - s_dot[0] * s_dot[0] / (2.0 * sg[0])
    diag[1] = 2.0 * (w1 - total) * s[1] - s_dot[1] * s_dot[1] / (2.0 * sg[1])
    diag[2] = 2.0 * (w2 - total) * s[2] - s_dot[2] * s_dot[2] / (2.0 * sg[2])
    for m in range(3):
        j, k = _J[m], _K[m]
        pairs[m] = omega[j] * omega[k] * (s[j] + s[k]) + omega[m] * _SIGN[m] * (s_dot[k] - s_dot[j])


@jit
def _euler_rate_matrix_into(roll, pitch, e):  # type: ignore[no-untyped-def]
    """:func:`euler_rate_matrix` into ``e`` (3, 3)."""
    sr, cr = np.sin(roll), np.cos(roll)
    sp, cp = np.sin(pitch), np.cos(pitch)
    e[0, 0], e[0, 1], e[0, 2] = 1.0, 0.0, -sp
    e[1, 0], e[1, 1], e[1, 2] = 0.0, cr, sr * cp
    e[2, 0], e[2, 1], e[2, 2] = 0.0, -sr, cr * cp


@jit
def _euler_rate_derivative_into(roll, pitch, eta_dot, out):  # type: ignore[no-untyped-def]
    """``E_dot eta_dot`` (3,) into ``out``: the part of the body angular acceleration
    ``omega_dot = E eta_ddot + E_dot eta_dot`` that the Euler-angle rates ``eta_dot`` = (roll,
    pitch, yaw rates) give by turning E itself (ALGORITHM.md §1, eq. 38)."""
    sr, cr = np.sin(roll), np.cos(roll)
    sp, cp = np.sin(pitch), np.cos(pitch)
    rd, pd, yd = eta_dot[0], eta_dot[1], eta_dot[2]
    out[0] = -cp * pd * yd
    out[1] = -sr * rd * pd + cr * cp * rd * yd - sr * sp * pd * yd
    out[2] = -cr * rd * pd - sr * cp * rd * yd - cr * sp * pd * yd


@jit
def _euler_rows(roll, pitch, eta_dot, e, e_dot):  # type: ignore[no-untyped-def]
    for r in range(roll.shape[0]):
        _euler_rate_matrix_into(roll[r], pitch[r], e[r])
        _euler_rate_derivative_into(roll[r], pitch[r], eta_dot[r], e_dot[r])


def euler_rate_matrix_batch(roll: FloatArray, pitch: FloatArray) -> FloatArray:
    """:func:`euler_rate_matrix` of K angle pairs (K,): (K, 3, 3)."""
    n = roll.shape[0]
    e = np.empty((n, 3, 3))
    _euler_rows(f64(roll), f64(pitch), np.zeros((n, 3)), e, np.empty((n, 3)))
    return e


def euler_rate_derivative_batch(
    roll: FloatArray, pitch: FloatArray, eta_dot: FloatArray
) -> FloatArray:
    """``E_dot eta_dot`` (K, 3) of K angle pairs (K,) and Euler-angle rates (K, 3)
    (:func:`_euler_rate_derivative_into`)."""
    n = roll.shape[0]
    out = np.empty((n, 3))
    _euler_rows(f64(roll), f64(pitch), f64(eta_dot), np.empty((n, 3, 3)), out)
    return out


def pinv_block(offset_m: FloatArray, axes: FloatArray, variances_m2: FloatArray) -> FloatArray:
    """Drone i's block (3, 9) of beta#: maps w = [w_mu (3), alpha (3), w_s (3)] to v_i.

    ``alpha`` is the angular acceleration of the swarm frame about its own axes. ``offset_m`` is
    p_i = x_i - mu (3,), ``axes`` R (3, 3), ``variances_m2`` s (3,), all distinct.
    """
    block = np.zeros((3, 9))
    block[:, 0:3] = np.eye(3)
    p_swarm = axes.T @ offset_m
    for col in range(6):
        w = np.zeros(6)
        w[col] = 1.0
        a = shape_matrix(variances_m2, w[3:6], w[0:3])
        block[:, 3 + col] = axes @ (a @ p_swarm)
    return block


def pinv_block_zyx(offset_m: FloatArray, axes: FloatArray, variances_m2: FloatArray) -> FloatArray:
    """As :func:`pinv_block`, for the descriptor vector with ZYX angles (roll, pitch, yaw) rows."""
    from protocols.model.frames import zyx_from_rot

    _, pitch, roll = zyx_from_rot(axes)
    block = pinv_block(offset_m, axes, variances_m2)
    block[:, 3:6] = block[:, 3:6] @ euler_rate_matrix(roll, pitch)
    return block


def virtual_acceleration(
    position_ned_m: FloatArray,
    velocity_ned_m_s: FloatArray,
    swarm: SwarmMoments,
    reference: tuple[FloatArray, FloatArray, FloatArray],
    gains: CooperativeGains,
) -> FloatArray:
    """Drone i's commanded acceleration v_i (3,) NED m/s^2 (gravity not included).

    ``swarm``: the estimated moments; ``reference``: a_d, a_d_dot, a_d_ddot (9,) each.
    """
    batch = SwarmMoments(*(np.asarray(f, dtype=float)[None] for f in _moment_fields(swarm)))
    v: FloatArray = virtual_acceleration_batch(
        np.asarray(position_ned_m, dtype=float)[None],
        np.asarray(velocity_ned_m_s, dtype=float)[None],
        batch,
        (reference[0][None], reference[1][None], reference[2][None]),
        gains,
    )[0]
    return v


def _moment_fields(m: SwarmMoments) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The fields of ``m`` in declaration order."""
    return m.centre_ned_m, m.centre_rate_ned_m_s, m.sigma_m2, m.sigma_rate_m2_s

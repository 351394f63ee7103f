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

(:func:`plan_rate_terms`), taken with the plan's rate omega_d and variance rates; ``A_kk`` gains
``C_kk / (2 s_k)`` and ``A_jk`` gains ``C_jk / (s_j + s_k)``. A pure rotation gives ``A = W^2``
(centripetal); a stretch at constant rate gives ``A_kk = -s_dot^2 / (4 s^2)``. The plan's angular
acceleration is ``omega_dot = E eta_ddot + E_dot eta_dot`` (:func:`euler_rate_derivative_batch`;
the E_dot term was left out too).

The plan's whole field. The drones of that formation accelerate as ``p_ddot = R F R^T p`` with
``F = W_dot + W^2 + W S_dot S^-1 + S_ddot^1/2 S^-1/2``, which is not symmetric: A is its
symmetric part in the sense ``A S + S A = F S + S F^T``. The rest, ``N = F - A`` with ``N_jk =
s_j D_jk / (s_j + s_k)``, ``N_kj = -s_k D_jk / (s_j + s_k)``, ``D_jk = 2 W_dot_jk + W_jk (s_dot_j /
s_j + s_dot_k / s_k)``, has ``N S`` antisymmetric: it moves neither mu nor Sigma, it turns the
lattice with the formation (:func:`plan_null_field`). With both, every drone's command is its
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

Pure and I/O-free.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from drone_agent.moments import SwarmMoments
from protocols.descriptor_vector import CENTRE, ORIENTATION, SHAPE
from protocols.descriptors import align_axes_batch, desired_axes_batch
from protocols.frames import FloatArray

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


# The pairs of _PAIRS as index arrays (j, k per m), and the positions of (j, k), (k, j) and the
# diagonal in a 3 x 3 matrix flattened to 9 (row-major).
_J, _K = np.array([1, 0, 0]), np.array([2, 2, 1])
_UPPER, _LOWER, _DIAGONAL = np.array([5, 2, 1]), np.array([7, 6, 3]), slice(None, None, 4)
#: ``skew(v)[j, k] = _SKEW_SIGN[m] * v[m]`` for each pair (j, k, m).
_SKEW_SIGN = np.array([-1.0, 1.0, -1.0])


def _skew_pairs(v: FloatArray) -> FloatArray:
    """``skew(v)[j, k]`` (K, 3) for each pair (j, k, m) of :data:`_PAIRS`, indexed by m."""
    out: FloatArray = v * _SKEW_SIGN
    return out


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
    s = variances_m2
    sg = np.maximum(s, min_variance_m2)
    a = np.zeros((s.shape[0], 9))
    a[:, _DIAGONAL] = np.divide(w_shape, 2.0 * sg, out=np.zeros_like(sg), where=~flat)
    num = (s[:, _K] - s[:, _J]) * _skew_pairs(alpha) + damping
    a[:, _UPPER] = a[:, _LOWER] = num / np.maximum(s[:, _J] + s[:, _K], min_variance_m2)
    return a.reshape(-1, 3, 3)


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
    from protocols.frames import zyx_from_rot

    _, pitch, roll = zyx_from_rot(axes)
    block = pinv_block(offset_m, axes, variances_m2)
    block[:, 3:6] = block[:, 3:6] @ euler_rate_matrix(roll, pitch)
    return block


def rotation_error(axes: FloatArray, axes_desired: FloatArray) -> FloatArray:
    """Rotation error (3,) about the swarm axes: ``vee((R_d^T R - R^T R_d) / 2)`` (rad, small)."""
    out: FloatArray = rotation_error_batch(axes[None], axes_desired[None])[0]
    return out


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
    estimate's axes assigned to them (K, 3, 3) and variances (K, 3)). Returns v (K, 3)."""
    a_d, ad_dot, ad_ddot = reference
    kp, kd = np.asarray(gains.kp), np.asarray(gains.kd)
    s_min = gains.min_variance_m2
    if frame is None:
        r_d = desired_axes_batch(a_d)
        axes, s = align_axes_batch(swarm.sigma_m2, r_d)
    else:
        r_d, axes, s = frame
    axes_t = np.swapaxes(axes, 1, 2)
    sigma_rate = axes_t @ swarm.sigma_rate_m2_s @ axes
    rate_flat = sigma_rate.reshape(-1, 9)

    w_mu = (
        ad_ddot[:, CENTRE]
        - kd[CENTRE] * (swarm.centre_rate_ned_m_s - ad_dot[:, CENTRE])
        - kp[CENTRE] * (swarm.centre_ned_m - a_d[:, CENTRE])
    )
    s_d, s_d_dot, s_d_ddot = a_d[:, SHAPE], ad_dot[:, SHAPE], ad_ddot[:, SHAPE]
    w_s = s_d_ddot - kd[SHAPE] * (rate_flat[:, _DIAGONAL] - s_d_dot) - kp[SHAPE] * (s - s_d)
    flat = s_d < s_min
    sg = np.maximum(s, s_min)
    pair_sum = np.maximum(s[:, _J] + s[:, _K], s_min)  # s_j + s_k, indexed by m

    # the plan's angular rate and acceleration (body of the desired frame: omega = E eta_dot,
    # omega_dot = E eta_ddot + E_dot eta_dot), then in the estimated swarm frame
    eta_dot, eta_ddot = ad_dot[:, ORIENTATION], ad_ddot[:, ORIENTATION]
    e_d = euler_rate_matrix_batch(a_d[:, 3], a_d[:, 4])
    body_d = e_d @ _columns(eta_dot, eta_ddot)
    body_d[:, :, 1] += euler_rate_derivative_batch(a_d[:, 3], a_d[:, 4], eta_dot)
    angular = (axes_t @ r_d) @ body_d
    omega_d, alpha_d = angular[:, :, 0], angular[:, :, 1]

    # rotation feedback, per axis m of the pair (j, k): the rate error from the estimated
    # Sigma_dot' (Sigma_dot'_jk = (s_k - s_j) [W]_jk + ...), a PD with limits on the feedback
    spread = (s[:, _K] - s[:, _J]) * _SKEW_SIGN  # [skew(v)]_jk (s_k - s_j) = spread_m v_m
    twist = spread * omega_d
    guard = np.where(spread < 0.0, -1.0, 1.0) * np.maximum(np.abs(spread), s_min)
    rate_error = (rate_flat[:, _UPPER] - twist) / guard
    radius = np.sqrt(pair_sum)  # RMS radius of the formation in the plane of the pair
    okp, okd = np.asarray(gains.orientation_kp), np.asarray(gains.orientation_kd)
    max_rate = gains.orientation_max_speed_m_s / radius
    max_alpha = gains.orientation_max_accel_m_s2 / radius
    # np.clip's arithmetic (NaN stays NaN) without its wrapper's overhead
    wanted_rate = np.minimum(
        np.maximum(okp / okd * rotation_error_batch(axes, r_d), -max_rate), max_rate
    )
    alpha_fb = np.minimum(np.maximum(-okd * (rate_error + wanted_rate), -max_alpha), max_alpha)
    comp_diag, comp_pairs = plan_rate_terms(s, sg, omega_d, s_d_dot)
    a = shape_matrix_batch(s, w_s + comp_diag, alpha_d + alpha_fb, comp_pairs, s_min, flat)

    p = positions_ned_m - swarm.centre_ned_m
    p_dot = velocities_ned_m_s - swarm.centre_rate_ned_m_s
    offsets = axes_t @ _columns(p, p_dot)  # p and p_dot in the swarm frame
    p_swarm, p_dot_swarm = offsets[:, :, 0], offsets[:, :, 1]
    # the explained motion p_dot = G p: the plan's rotation W_d plus the symmetric G_s that
    # makes G Sigma' + Sigma' G^T the estimated Sigma_dot' (so the damping below leaves mu and
    # Sigma alone to first order, and a formation turning with the plan is not braked)
    g = np.zeros((p.shape[0], 9))
    g[:, _UPPER] = (rate_flat[:, _UPPER] - twist) / pair_sum + _skew_pairs(omega_d)
    g[:, _LOWER] = (rate_flat[:, _UPPER] - twist) / pair_sum - _skew_pairs(omega_d)
    # the flat-axis PD holds a flat axis: no spreading rate there is "explained" (its
    # 1/(2 s_min) gain turned estimate noise into a growing split)
    g[:, _DIAGONAL] = np.where(flat, 0.0, rate_flat[:, _DIAGONAL] / (2.0 * sg))
    a = a + plan_null_field(s, sg, pair_sum, omega_d, alpha_d, s_d_dot)
    fields = np.concatenate([a, g.reshape(-1, 3, 3)], axis=1) @ offsets[:, :, :1]  # A p, G p
    v_swarm = fields[:, :3, 0]
    unexplained = p_dot_swarm - fields[:, 3:, 0]
    # the flat-axis PD damps the offset rate beyond the plan's own turn (not G p: its estimated
    # part, times the lever of a drone far out, broke the 250-drone grid at a drop-out)
    planned = p_dot_swarm - _cross_rows(omega_d, p_swarm)
    v_swarm = np.where(flat, v_swarm - (gains.flat_kp * p_swarm + gains.flat_kd * planned), v_swarm)
    v_swarm = v_swarm - gains.null_damping_per_s * unexplained
    out: FloatArray = w_mu + _matvec(axes, v_swarm)
    return out


def plan_null_field(
    s: FloatArray,
    sg: FloatArray,
    pair_sum: FloatArray,
    omega: FloatArray,
    alpha: FloatArray,
    s_dot: FloatArray,
) -> FloatArray:
    """The null-space part N (K, 3, 3) of the plan's field (module doc, "The plan's whole
    field"): ``N_jk = s_j D_jk / (s_j + s_k)``, ``N_kj = -s_k D_jk / (s_j + s_k)`` with
    ``D = 2 skew(alpha) + skew(omega) (Ṡ S⁻¹ + S⁻¹ Ṡ)`` entrywise on the pairs. ``N S`` is
    antisymmetric: it moves no drone's share of mu or Sigma, it turns the lattice with them."""
    ratio = s_dot / sg
    d = _skew_pairs(2.0 * alpha + omega * (ratio[:, _J] + ratio[:, _K])) / pair_sum
    s_pos = np.maximum(s, 0.0)
    n = np.zeros((s.shape[0], 9))
    n[:, _UPPER] = s_pos[:, _J] * d
    n[:, _LOWER] = -s_pos[:, _K] * d
    return n.reshape(-1, 3, 3)


def plan_rate_terms(
    s: FloatArray, sg: FloatArray, omega: FloatArray, s_dot: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The terms of ``Rᵀ Σ̈ R`` that the affine field leaves out, for a formation moving as the
    plan does (module doc, "Terms the field leaves out"): ``C = W²S + SW² + [W, Ṡ] − Ṡ² S⁻¹ / 2``
    with ``W = skew(omega)``. Variances ``s`` (K, 3) (``sg`` the guarded ones), the plan's angular
    rate about the swarm axes ``omega`` (K, 3) and variance rates ``s_dot`` (K, 3). Returns the
    diagonal ``C_kk`` (K, 3) and the pairs ``C_jk`` (K, 3), indexed by m as :data:`_PAIRS`."""
    w2 = omega * omega
    diag = 2.0 * (w2 - w2.sum(axis=1, keepdims=True)) * s - s_dot * s_dot / (2.0 * sg)
    pairs = omega[:, _J] * omega[:, _K] * (s[:, _J] + s[:, _K]) + _skew_pairs(omega) * (
        s_dot[:, _K] - s_dot[:, _J]
    )
    return diag, pairs


#: ``(a x b)_i = a_(i+1) b_(i+2) - a_(i+2) b_(i+1)``
_NEXT, _AFTER = [1, 2, 0], [2, 0, 1]


def _cross_rows(a: FloatArray, b: FloatArray) -> FloatArray:
    """Row-wise cross products of (K, 3) arrays: ``np.cross(a, b)``'s arithmetic (the same
    products and difference per component) without its axis handling."""
    out: FloatArray = a[:, _NEXT] * b[:, _AFTER] - a[:, _AFTER] * b[:, _NEXT]
    return out


def _columns(u: FloatArray, w: FloatArray) -> FloatArray:
    """Vectors (K, 3) u and w as the two columns of (K, 3, 2)."""
    out = np.empty((u.shape[0], 3, 2))
    out[:, :, 0] = u
    out[:, :, 1] = w
    return out


def _matvec(m: FloatArray, v: FloatArray) -> FloatArray:
    """Row-wise ``m[k] @ v[k]``: matrices (K, 3, 3), vectors (K, 3) -> (K, 3)."""
    out: FloatArray = (m @ v[:, :, None])[:, :, 0]
    return out


def euler_rate_matrix_batch(roll: FloatArray, pitch: FloatArray) -> FloatArray:
    """:func:`euler_rate_matrix` of K angle pairs (K,): (K, 3, 3)."""
    sr, cr = np.sin(roll), np.cos(roll)
    sp, cp = np.sin(pitch), np.cos(pitch)
    e = np.zeros((roll.shape[0], 3, 3))
    e[:, 0, 0] = 1.0
    e[:, 0, 2] = -sp
    e[:, 1, 1] = cr
    e[:, 1, 2] = sr * cp
    e[:, 2, 1] = -sr
    e[:, 2, 2] = cr * cp
    return e


def euler_rate_derivative_batch(
    roll: FloatArray, pitch: FloatArray, eta_dot: FloatArray
) -> FloatArray:
    """``E_dot eta_dot`` (K, 3): the part of the body angular acceleration ``omega_dot = E eta_ddot
    + E_dot eta_dot`` that the Euler-angle rates ``eta_dot`` = (roll, pitch, yaw rates) (K, 3)
    give by turning E itself (ALGORITHM.md §1, eq. 38)."""
    sr, cr = np.sin(roll), np.cos(roll)
    sp, cp = np.sin(pitch), np.cos(pitch)
    rd, pd, yd = eta_dot[:, 0], eta_dot[:, 1], eta_dot[:, 2]
    out = np.empty_like(eta_dot)
    out[:, 0] = -cp * pd * yd
    out[:, 1] = -sr * rd * pd + cr * cp * rd * yd - sr * sp * pd * yd
    out[:, 2] = -cr * rd * pd - sr * cp * rd * yd - cr * sp * pd * yd
    return out


def rotation_error_batch(axes: FloatArray, axes_desired: FloatArray) -> FloatArray:
    """:func:`rotation_error` of K frames (K, 3, 3) -> (K, 3)."""
    # (R^T R_d) = (R_d^T R)^T: the vee of half their difference, entries (2, 1), (0, 2), (1, 0)
    p = (np.swapaxes(axes_desired, 1, 2) @ axes).reshape(-1, 9)
    out: FloatArray = 0.5 * (p[:, [7, 2, 3]] - p[:, [5, 6, 1]])
    return out

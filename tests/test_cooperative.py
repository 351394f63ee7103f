"""The cooperative controller's per-drone pseudo-inverse block against numerical pseudo-inverses
of the descriptor Jacobian, and the closed-loop properties of the affine field."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from drone_agent.core.cooperative import (
    CooperativeGains,
    euler_rate_derivative_batch,
    euler_rate_matrix,
    pinv_block,
    pinv_block_zyx,
    virtual_acceleration,
)
from drone_agent.core.moments import SwarmMoments, true_moments
from protocols.model.descriptors import align_axes, covariance, descriptors
from protocols.model.frames import FloatArray, rot_zyx


def _formation(n: int, seed: int) -> FloatArray:
    """A random 3-D formation with clearly distinct variances."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, 3)) * np.array([4.0, 2.5, 1.0])
    return x @ rot_zyx(0.7, -0.2, 0.3).T + np.array([10.0, -3.0, -5.0])


def _body_map(x_flat: FloatArray, r0: FloatArray) -> FloatArray:
    """Descriptor map with the orientation as the rotation vector of R0^T R (body increments)."""
    x = x_flat.reshape(-1, 3)
    mu, sigma = covariance(x)
    axes, s = align_axes(sigma, r0)
    rotvec = Rotation.from_matrix(r0.T @ axes).as_rotvec()
    return np.concatenate([mu, rotvec, s])


def _zyx_map(x_flat: FloatArray, r0: FloatArray) -> FloatArray:
    x = x_flat.reshape(-1, 3)
    yaw, pitch, roll = Rotation.from_matrix(r0).as_euler("ZYX")
    a = descriptors(x, np.array([0, 0, 0, roll, pitch, yaw, 0, 0, 0]))
    return a


def _numerical_pinv(fun, x0: FloatArray, r0: FloatArray, h: float = 1e-6) -> FloatArray:
    x_flat = x0.ravel()
    jac = np.empty((9, x_flat.size))
    for k in range(x_flat.size):
        dx = np.zeros_like(x_flat)
        dx[k] = h
        jac[:, k] = (fun(x_flat + dx, r0) - fun(x_flat - dx, r0)) / (2 * h)
    return np.linalg.pinv(jac)


@pytest.mark.parametrize("n,seed", [(4, 0), (5, 1), (9, 2), (16, 3), (40, 4)])
def test_pinv_block_matches_numerical_pseudo_inverse(n: int, seed: int) -> None:
    x = _formation(n, seed)
    mu, sigma = covariance(x)
    axes, s = align_axes(sigma, np.eye(3))
    pinv = _numerical_pinv(_body_map, x, axes)
    for i in range(n):
        block = pinv_block(x[i] - mu, axes, s)
        np.testing.assert_allclose(block, pinv[3 * i : 3 * i + 3], atol=1e-6)


@pytest.mark.parametrize("n,seed", [(4, 5), (9, 6), (25, 7)])
def test_pinv_block_zyx_matches_numerical_pseudo_inverse(n: int, seed: int) -> None:
    x = _formation(n, seed)
    mu, sigma = covariance(x)
    axes, s = align_axes(sigma, rot_zyx(0.7, -0.2, 0.3))
    pinv = _numerical_pinv(_zyx_map, x, axes)
    for i in range(n):
        np.testing.assert_allclose(
            pinv_block_zyx(x[i] - mu, axes, s), pinv[3 * i : 3 * i + 3], atol=1e-6
        )


def test_block_does_not_depend_on_n() -> None:
    """Same offset, same descriptors, different swarm sizes: the same command."""
    axes = rot_zyx(0.3, 0.1, -0.2)
    s = np.array([6.0, 3.0, 1.0])
    p = np.array([1.0, -2.0, 0.5])
    reference = pinv_block(p, axes, s)
    for n in (4, 50, 500):
        x = _formation(n, n)
        mu, sigma = covariance(x)
        # rescale the random formation to the same descriptors exactly
        ax0, s0 = align_axes(sigma, axes)
        z = (x - mu) @ ax0 / np.sqrt(s0) * np.sqrt(s) @ axes.T
        _, sig2 = covariance(z)
        ax2, s2 = align_axes(sig2, axes)
        np.testing.assert_allclose(pinv_block(p, ax2, s2), reference, atol=1e-9)


#: Simulated seconds a flight's descriptors must keep passing the test's bars before it stops.
HELD_S = 5


def _ideal_swarm_flight(
    gains: CooperativeGains,
    a_goal: FloatArray,
    seconds: float,
    passes: Callable[[FloatArray], bool] | None = None,
) -> FloatArray:
    """Double-integrator drones under the controller with exact moments: returns final a. With
    ``passes`` (the test's bars on a), the flight stops early once a has passed them at every
    whole second for HELD_S seconds (the bars are still the caller's to assert)."""
    x = _formation(9, 11)
    v = np.zeros_like(x)
    dt = 0.01
    per_s = round(1.0 / dt)
    ref = (a_goal, np.zeros(9), np.zeros(9))
    held = 0
    for k in range(1, int(seconds / dt) + 1):
        moments = true_moments(x, v)
        acc = np.array([virtual_acceleration(x[i], v[i], moments, ref, gains) for i in range(9)])
        v = v + acc * dt
        x = x + v * dt
        if passes is not None and k % per_s == 0:
            held = held + 1 if passes(descriptors(x, a_goal)) else 0
            if held > HELD_S:
                break
    return descriptors(x, a_goal)


def _within(a: FloatArray, goal: FloatArray, tol: tuple[float, float, float]) -> bool:
    """Centre, angles and variances of ``a`` within ``tol`` of ``goal`` (absolute)."""
    err = np.abs(a - goal)
    return bool(err[0:3].max() <= tol[0] and err[3:6].max() <= tol[1] and err[6:9].max() <= tol[2])


def test_closed_loop_reaches_commanded_descriptors() -> None:
    """With exact descriptors, the field steers a double-integrator swarm to a new centre,
    heading and shape (a 3-D formation, every descriptor commanded)."""
    a_goal = np.array([3.0, 4.0, -6.0, 0.1, -0.05, 0.5, 9.0, 4.0, 1.5])
    passes = lambda a: _within(a, a_goal, (0.02, 0.01, 0.05))  # noqa: E731 (the bars below)
    a_final = _ideal_swarm_flight(CooperativeGains(), a_goal, 60.0, passes)
    np.testing.assert_allclose(a_final[0:3], a_goal[0:3], atol=0.02)
    np.testing.assert_allclose(a_final[3:6], a_goal[3:6], atol=0.01)
    np.testing.assert_allclose(a_final[6:9], a_goal[6:9], atol=0.05)


def test_flat_axis_is_held_by_local_pd() -> None:
    """A commanded-flat height (s3 = 0) flattens the swarm without NaN."""
    a_goal = np.array([0.0, 0.0, -5.0, 0.0, 0.0, 0.0, 10.0, 6.0, 0.0])

    def passes(a: FloatArray) -> bool:  # the bars below
        err = np.abs(a - a_goal)
        flat = bool(np.all(np.isfinite(a)) and a[8] < 1e-3)
        return flat and bool(err[6:8].max() <= 0.05 and err[0:3].max() <= 0.02)

    a_final = _ideal_swarm_flight(CooperativeGains(), a_goal, 60.0, passes)
    assert np.all(np.isfinite(a_final))
    assert a_final[8] < 1e-3
    np.testing.assert_allclose(a_final[6:8], a_goal[6:8], atol=0.05)
    np.testing.assert_allclose(a_final[0:3], a_goal[0:3], atol=0.02)


def test_an_estimated_spreading_rate_does_not_push_a_flat_axis_apart() -> None:
    """Regression: the null-space damping explained a flat axis's spreading rate with a gain of
    1 / (2 s_min) = 10 /s, so estimate noise in the vertical spread rate pushed every drone further
    from the plane, and sparse 25-drone swarms split vertically after take-off. Along a commanded-
    flat axis only the local PD acts: a drone above the plane is sent back towards it."""
    mu = np.array([0.0, 0.0, -3.0])
    sigma = np.diag([12.0, 10.0, 0.01])
    spreading = np.diag([0.0, 0.0, 0.5])  # the estimate says the swarm is thickening
    swarm = SwarmMoments(mu, np.zeros(3), sigma, spreading)
    a_d = np.array([0.0, 0.0, -3.0, 0.0, 0.0, 0.0, 12.0, 10.0, 0.0])
    reference = (a_d, np.zeros(9), np.zeros(9))
    gains = CooperativeGains()
    above = mu + np.array([0.0, 0.0, -0.5])  # NED: 0.5 m above the centre, at rest
    v = virtual_acceleration(above, np.zeros(3), swarm, reference, gains)
    # back down (NED +z) with the flat-axis PD's stiffness, not away from the plane
    assert v[2] > 0.0
    assert v[2] == pytest.approx(gains.flat_kp * 0.5, rel=0.05)


def _whitened(n: int, seed: int, flat: bool) -> FloatArray:
    """Lattice coordinates q (n, 3): zero mean, (1/n) sum q q^T = I (the third row 0 if flat)."""
    q = np.random.default_rng(seed).normal(size=(n, 3))
    k = 2 if flat else 3
    q[:, k:] = 0.0
    q -= q.mean(axis=0)
    chol = np.linalg.cholesky(q[:, :k].T @ q[:, :k] / n)
    q[:, :k] = q[:, :k] @ np.linalg.inv(chol).T
    return q


def _moving_plan(t: float, flat: bool) -> FloatArray:
    """A plan that moves every descriptor at once: centre, roll, pitch, heading, variances."""
    return np.array(
        [
            1.0 + 0.3 * t * t,
            -2.0 + np.sin(t),
            -5.0 - 0.2 * t,
            0.2 * np.sin(0.7 * t),
            0.1 - 0.3 * np.cos(0.5 * t),
            0.4 + 0.6 * t + 0.3 * t * t,
            6.0 + np.sin(0.8 * t),
            3.0 + 0.5 * t,
            0.0 if flat else 1.2 + 0.3 * np.cos(t),
        ]
    )


@pytest.mark.parametrize("flat", [False, True], ids=["3-D", "planar"])
def test_plan_rates_give_each_drone_its_true_acceleration(flat: bool) -> None:
    """The derivation of the module doc against finite differences: drones placed exactly on a
    formation that follows a plan moving every descriptor (p_i = R(t) S(t)^1/2 q_i), estimate
    exact: each drone's command is its own second difference (the compensated terms, E_dot and
    the plan's null-space field all in), not just the right Sigma_ddot."""
    q, h = _whitened(12, 3, flat), 1e-4

    def positions(t: float) -> FloatArray:
        a = _moving_plan(t, flat)
        r = rot_zyx(a[5], a[4], a[3])
        return a[:3] + (r @ (np.sqrt(a[6:])[:, None] * q.T)).T

    for t in (0.3, 0.8, 1.7):
        x, xp, xm = positions(t), positions(t + h), positions(t - h)
        v, acc = (xp - xm) / (2 * h), (xp - 2 * x + xm) / h**2
        a, ap, am = _moving_plan(t, flat), _moving_plan(t + h, flat), _moving_plan(t - h, flat)
        ref = (a, (ap - am) / (2 * h), (ap - 2 * a + am) / h**2)
        m = true_moments(x, v)
        out = np.array(
            [virtual_acceleration(x[i], v[i], m, ref, CooperativeGains()) for i in range(12)]
        )
        np.testing.assert_allclose(out, acc, atol=2e-6 * np.abs(acc).max())
        # and without the plan's rates the error is large (the test can fail)
        still = (a, np.zeros(9), np.zeros(9))
        off = np.array(
            [virtual_acceleration(x[i], v[i], m, still, CooperativeGains()) for i in range(12)]
        )
        assert np.abs(off - acc).max() > 0.1


def test_euler_rate_derivative_against_finite_differences() -> None:
    """omega_dot = E eta_ddot + E_dot eta_dot (ALGORITHM.md §1, eq. 38) for the plan above."""
    h = 1e-4

    def omega(t: float) -> FloatArray:
        a = _moving_plan(t, False)
        rate = (_moving_plan(t + h, False) - _moving_plan(t - h, False)) / (2 * h)
        out: FloatArray = euler_rate_matrix(a[3], a[4]) @ rate[3:6]
        return out

    t, d = 0.9, 1e-3
    a = _moving_plan(t, False)
    rate = (_moving_plan(t + h, False) - _moving_plan(t - h, False)) / (2 * h)
    accel = (_moving_plan(t + h, False) - 2 * a + _moving_plan(t - h, False)) / h**2
    got = (
        euler_rate_matrix(a[3], a[4]) @ accel[3:6]
        + euler_rate_derivative_batch(a[3:4], a[4:5], rate[None, 3:6])[0]
    )
    np.testing.assert_allclose(got, (omega(t + d) - omega(t - d)) / (2 * d), atol=1e-6)
    # E itself: R^T R_dot = skew(E eta_dot)
    r = [rot_zyx(*_moving_plan(s, False)[[5, 4, 3]]) for s in (t - h, t, t + h)]
    w = r[1].T @ (r[2] - r[0]) / (2 * h)
    np.testing.assert_allclose([w[2, 1], w[0, 2], w[1, 0]], omega(t), atol=1e-6)

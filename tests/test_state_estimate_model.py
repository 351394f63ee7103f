"""The state estimate a GNSS + EKF autopilot reports (sitl_sim/vehicle/estimate.py) against its
definition: the ideal sensor is the truth itself, the white noises have their standard deviation,
zero mean and no memory, the GNSS bias is the Gauss–Markov process (stationary spread, random-walk
growth over short lags, lag-1 autocorrelation ``a``), the output rate holds the estimate between
its refresh ticks, the latency delays the truth by its ticks, one seed gives one run bit for bit,
and unusable settings fail naming their field."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import numpy as np
import pytest

from sitl_sim.vehicle.estimate import Sensors, StateEstimate

HZ = 50
DT = 1.0 / HZ


def _truth(tick: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A true state that differs at every tick and vehicle (yaw inside (-pi, pi])."""
    base = tick + np.arange(n)[None, :] * 1e-3 + np.arange(3)[:, None] * 0.1
    euler = np.vstack([0.01 * np.sin(base[0]), 0.01 * np.cos(base[1]), np.sin(0.1 * base[2])])
    return 10.0 * base, 0.5 * base, euler


def _fly(
    sensors: Sensors, n: int, ticks: int, seed: int = 0, truth: bool = True
) -> tuple[StateEstimate, np.ndarray, np.ndarray]:
    """The estimates (ticks, 9, N) and the truths (ticks, 9, N) of ``ticks`` ticks (a zero truth
    unless ``truth``)."""
    model = StateEstimate(sensors, n, HZ, seed)
    est = np.empty((ticks, 9, n))
    true = np.zeros((ticks, 9, n))
    for k in range(ticks):
        state = _truth(k, n) if truth else (np.zeros((3, n)),) * 3
        true[k] = np.concatenate(state)
        est[k] = np.concatenate(model.update(k, *state))
    return model, est, true


# --- the ideal sensor ------------------------------------------------------------------------


def test_the_ideal_sensor_returns_the_truth_itself() -> None:
    assert Sensors().ideal
    assert Sensors(gnss_bias_tau_s=10.0).ideal  # a time constant of no bias is no error
    model = StateEstimate(Sensors(), 4, HZ, 1)
    for k in range(5):
        state = _truth(k, 4)
        out = model.update(k, *state)
        assert all(a is b for a, b in zip(out, state, strict=True))
    assert not model.bias_m.any()


#: every field of Sensors but the bias's correlation time: an error term, each >= 0
ERROR_TERMS = [
    "gnss_bias_m",
    "position_noise_m",
    "velocity_noise_m_s",
    "attitude_noise_rad",
    "rate_hz",
    "latency_s",
]


@pytest.mark.parametrize("field", ERROR_TERMS)
def test_any_error_term_makes_the_sensor_not_ideal(field: str) -> None:
    assert not replace(Sensors(), **{field: 0.1}).ideal


# --- white noise -----------------------------------------------------------------------------

N, TICKS = 200, 500


@pytest.mark.parametrize(
    ("field", "rows"),
    [("position_noise_m", slice(0, 3)), ("velocity_noise_m_s", slice(3, 6))],
)
def test_white_noise_has_its_spread_zero_mean_and_no_memory(field: str, rows: slice) -> None:
    sigma = 0.7
    _, est, true = _fly(replace(Sensors(), **{field: sigma}), N, TICKS)
    err = est - true
    noisy, clean = err[:, rows], np.delete(err, np.arange(9)[rows], axis=1)
    _check_white(noisy, sigma)
    assert np.abs(clean).max() < 1e-9  # the other components carry no error


def test_attitude_noise_has_its_spread_and_the_yaw_stays_wrapped() -> None:
    sigma = 0.05
    n = N
    model = StateEstimate(Sensors(attitude_noise_rad=sigma), n, HZ, 3)
    yaw = np.linspace(-math.pi, math.pi, n)  # vehicles pointing all round, some at +-pi
    yaw[0] = math.pi
    truth = np.vstack([np.full(n, 0.1), np.full(n, -0.2), yaw])
    zero = np.zeros((3, n))
    err = np.empty((TICKS, 3, n))
    yaw_at_pi = np.empty(TICKS)
    for k in range(TICKS):
        pos, vel, euler = model.update(k, zero, zero, truth)
        yaw_at_pi[k] = euler[2, 0]
        assert (euler[2] > -math.pi).all() and (euler[2] <= math.pi).all()
        assert not pos.any() and not vel.any()
        diff = euler - truth
        diff[2] = (diff[2] + math.pi) % (2.0 * math.pi) - math.pi  # the yaw error, unwrapped
        err[k] = diff
    _check_white(err, sigma)
    # the vehicle pointing at pi reads about pi or, wrapped, about -pi: about half the time each
    assert (np.abs(np.abs(yaw_at_pi) - math.pi) < 0.5).all()
    assert 0.4 < (yaw_at_pi < 0.0).mean() < 0.6


def _check_white(err: np.ndarray, sigma: float) -> None:
    """``err`` (ticks, 3, N): each component's std within 3 % of ``sigma``, mean within 4
    standard errors of 0, no correlation from one tick to the next nor between components."""
    samples = err.shape[0] * err.shape[2]
    per_axis = err.transpose(1, 0, 2).reshape(3, -1)
    assert np.allclose(per_axis.std(axis=1), sigma, rtol=0.03)
    assert (np.abs(per_axis.mean(axis=1)) < 4.0 * sigma / math.sqrt(samples)).all()
    for axis in range(3):
        lag1 = np.corrcoef(err[1:, axis].ravel(), err[:-1, axis].ravel())[0, 1]
        assert abs(lag1) < 0.02, lag1
    cross = np.corrcoef(per_axis)
    assert (np.abs(cross[np.triu_indices(3, 1)]) < 0.02).all(), cross


# --- the GNSS bias ---------------------------------------------------------------------------


def test_the_bias_is_stationary_at_its_spread() -> None:
    """Across many vehicles the bias's std is ``gnss_bias_m`` north and east and
    ``altitude_bias_m`` down at the first tick (drawn from the stationary distribution) and
    still after many correlation times."""
    sigma, n = 2.0, 3000
    model = StateEstimate(
        Sensors(gnss_bias_m=sigma, altitude_bias_m=0.5, gnss_bias_tau_s=0.2), n, HZ, 5
    )
    zero = np.zeros((3, n))
    for k in range(100):  # 2 s: ten correlation times
        pos, vel, euler = model.update(k, zero, zero, zero)
        assert np.array_equal(pos, model.bias_m)  # no noise: the position error is the bias
        assert not vel.any() and not euler.any()  # the bias is the position's only
        if k in (0, 99):
            b = model.bias_m
            assert np.allclose(b.std(axis=1), [sigma, sigma, 0.5], rtol=0.05), (k, b.std(axis=1))
            assert (np.abs(b.mean(axis=1)) < 4.0 * sigma / math.sqrt(n)).all()


def test_the_bias_wanders_like_a_random_walk_over_short_lags() -> None:
    """For lags ``m dt << tau`` the variance of the bias's increments is ``2 sigma^2 m dt /
    tau`` (and exactly ``2 sigma^2 (1 - a^m)``)."""
    sigma, tau = 3.0, 300.0
    both = Sensors(gnss_bias_m=sigma, altitude_bias_m=sigma, gnss_bias_tau_s=tau)
    _, est, _ = _fly(both, N, TICKS, 11, truth=False)
    b = est[:, 0:3]  # (ticks, 3, N)
    a = math.exp(-DT / tau)
    for m in (1, 10, 50):  # 0.02 s to 1 s, against a 300 s correlation time
        var = (b[m:] - b[:-m]).var()
        assert var == pytest.approx(2.0 * sigma**2 * m * DT / tau, rel=0.10), m
        assert var == pytest.approx(2.0 * sigma**2 * (1.0 - a**m), rel=0.10), m
    assert b.std() == pytest.approx(sigma, rel=0.10)


def test_the_bias_lag_one_autocorrelation_is_the_decay() -> None:
    sigma, tau = 1.0, 0.5  # a = exp(-0.04) = 0.96
    both = Sensors(gnss_bias_m=sigma, altitude_bias_m=sigma, gnss_bias_tau_s=tau)
    model, est, _ = _fly(both, N, TICKS, 13, False)
    b = est[:, 0:3]
    a = math.exp(-DT / tau)
    assert model.decay == pytest.approx(a)
    lag1 = np.corrcoef(b[1:].ravel(), b[:-1].ravel())[0, 1]
    assert lag1 == pytest.approx(a, abs=0.01)
    lag10 = np.corrcoef(b[10:].ravel(), b[:-10].ravel())[0, 1]
    assert lag10 == pytest.approx(a**10, abs=0.03)


# --- output rate -----------------------------------------------------------------------------


def test_the_estimate_is_held_between_refreshes() -> None:
    """50 Hz control, 10 Hz output: refreshed at ticks 0, 5, 10, ..., the very same values in
    between; the bias advances every tick even while the estimate is held."""
    sensors = Sensors(position_noise_m=0.1, attitude_noise_rad=0.01, gnss_bias_m=1.0, rate_hz=10)
    model = StateEstimate(sensors, 7, HZ, 2)
    last: np.ndarray | None = None
    biases = []
    for k in range(40):
        est = np.concatenate(model.update(k, *_truth(k, 7)))
        biases.append(model.bias_m)
        assert model.refreshes(k) == (k % 5 == 0)
        if k % 5:
            assert last is not None and np.array_equal(est, last)
        else:
            assert last is None or not (est == last).any()
        last = est
    assert all(not np.array_equal(b0, b1) for b0, b1 in itertools.pairwise(biases))


@pytest.mark.parametrize(
    ("rate_hz", "expected"),
    [
        (0.0, list(range(12))),  # every tick
        (50.0, list(range(12))),  # the control rate: every tick
        (200.0, list(range(12))),  # above it: every tick
        (20.0, [0, 3, 5, 8, 10]),  # floor(k * 0.4) changes
        (5.0, [0, 10]),
    ],
)
def test_the_refresh_ticks_follow_the_rate(rate_hz: float, expected: list[int]) -> None:
    model = StateEstimate(Sensors(position_noise_m=1.0, rate_hz=rate_hz), 3, HZ, 0)
    changed = []
    last = None
    for k in range(12):
        pos, _, _ = model.update(k, *(np.zeros((3, 3)),) * 3)
        if last is None or not np.array_equal(pos, last):
            changed.append(k)
        last = pos
    assert changed == expected
    assert [k for k in range(12) if model.refreshes(k)] == expected


def test_a_decimal_rate_refreshes_where_its_decimal_value_says() -> None:
    model = StateEstimate(Sensors(rate_hz=0.3), 1, 3, 0)  # one refresh every 10 ticks
    assert [k for k in range(31) if model.refreshes(k)] == [0, 10, 20, 30]


# --- latency ---------------------------------------------------------------------------------


def test_the_latency_delays_the_truth_by_its_ticks() -> None:
    """Latency 0.1 s at 50 Hz: the estimate at tick k is the truth of tick k - 5 (tick 0's
    before tick 5), exactly."""
    model, est, true = _fly(Sensors(latency_s=0.1), 5, 30)
    assert model.latency_ticks == 5
    for k in range(30):
        assert np.array_equal(est[k], true[max(k - 5, 0)]), k


def test_latency_and_rate_together_hold_the_delayed_truth() -> None:
    _, est, true = _fly(Sensors(latency_s=0.06, rate_hz=10.0), 4, 30)  # 3 ticks, every 5th
    for k in range(30):
        assert np.array_equal(est[k], true[max(k - k % 5 - 3, 0)]), k


def test_the_estimate_is_a_copy_of_the_model_s_state() -> None:
    model = StateEstimate(Sensors(rate_hz=10.0), 2, HZ, 0)
    pos, _, _ = model.update(0, *_truth(0, 2))
    pos += 100.0  # the caller's arrays are its own
    again, _, _ = model.update(1, *_truth(1, 2))
    assert np.array_equal(again, _truth(0, 2)[0])


# --- seeds -----------------------------------------------------------------------------------

NOISY = Sensors(
    gnss_bias_m=1.5,
    gnss_bias_tau_s=60.0,
    position_noise_m=0.3,
    velocity_noise_m_s=0.1,
    attitude_noise_rad=0.02,
    rate_hz=25.0,
    latency_s=0.04,
)


def test_one_seed_gives_one_run_bit_for_bit() -> None:
    _, first, _ = _fly(NOISY, 6, 60, seed=42)
    _, again, _ = _fly(NOISY, 6, 60, seed=42)
    _, other, _ = _fly(NOISY, 6, 60, seed=43)
    assert np.array_equal(first, again)
    assert not (first == other).any()  # every value drawn anew


def test_the_draws_do_not_depend_on_the_state_nor_on_the_other_terms() -> None:
    """Another truth flies the same errors; turning the white noise off leaves the bias's
    draws as they were."""
    a, est_a, true_a = _fly(NOISY, 6, 60, seed=9)
    b, est_b, true_b = _fly(NOISY, 6, 60, seed=9, truth=False)
    assert np.array_equal(a.bias_m, b.bias_m)
    # (the truths differ, so the sums round differently: equal to rounding)
    delayed = np.array([max(k - k % 2 - 2, 0) for k in range(60)])
    assert np.allclose(est_a - true_a[delayed], est_b - true_b[delayed], atol=1e-9)
    quiet = replace(NOISY, position_noise_m=0.0, velocity_noise_m_s=0.0, attitude_noise_rad=0.0)
    c, _, _ = _fly(quiet, 6, 60, seed=9)
    assert np.array_equal(a.bias_m, c.bias_m)


def test_a_negative_seed_is_usable() -> None:
    _, est, _ = _fly(NOISY, 2, 3, seed=-1)
    assert np.isfinite(est).all()


# --- validation ------------------------------------------------------------------------------

NON_NEGATIVE = ERROR_TERMS


@pytest.mark.parametrize("field", [*NON_NEGATIVE, "gnss_bias_tau_s"])
@pytest.mark.parametrize("value", [-0.5, math.nan, math.inf])
def test_unusable_values_fail_naming_their_field(field: str, value: float) -> None:
    sensors = replace(Sensors(), **{field: value})
    with pytest.raises(ValueError, match=field):
        sensors.validate()
    with pytest.raises(ValueError, match=field):
        StateEstimate(sensors, 1, HZ, 0)


@pytest.mark.parametrize("value", [0.0, -1.0])
def test_the_bias_time_constant_must_be_positive(value: float) -> None:
    with pytest.raises(ValueError, match="gnss_bias_tau_s"):
        Sensors(gnss_bias_tau_s=value).validate()


def test_zero_is_usable_everywhere_but_the_time_constant() -> None:
    assert Sensors(**dict.fromkeys(NON_NEGATIVE, 0.0)).validate().ideal


def test_the_model_checks_its_arguments_and_the_tick_order() -> None:
    with pytest.raises(ValueError, match="n must be"):
        StateEstimate(Sensors(), 0, HZ, 0)
    with pytest.raises(ValueError, match="control_hz"):
        StateEstimate(Sensors(), 1, 0, 0)
    model = StateEstimate(NOISY, 2, HZ, 0)
    with pytest.raises(ValueError, match="tick 1 out of order"):
        model.update(1, *_truth(1, 2))
    with pytest.raises(ValueError, match=r"\(3, 2\)"):
        model.update(0, *_truth(0, 3))

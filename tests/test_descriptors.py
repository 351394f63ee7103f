"""Swarm descriptors from positions, the consensus channels, and thrust/attitude from an
acceleration: against closed-form answers and invariances."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from drone_agent.core.moments import (
    channels_batch,
    moments_from_averages,
    moments_from_averages_batch,
    true_moments,
)
from drone_agent.core.thrust_attitude import ThrustLimits, attitude_thrust
from protocols.model.descriptors import descriptors, heading_defined, swarm_frame
from protocols.model.frames import E3, G_M_S2, FloatArray, rot_zyx

_positions = arrays(
    np.float64,
    st.tuples(st.integers(3, 12), st.just(3)),
    elements=st.floats(-50, 50, allow_nan=False, allow_subnormal=False),
)


def _box(half_lengths: tuple[float, float, float]) -> FloatArray:
    """The 8 corners of a box centred at 0: variance along axis k is half_length_k^2."""
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    return signs * np.array(half_lengths)


@settings(max_examples=60, deadline=None)
@given(
    x=_positions,
    seed=st.integers(0, 1000),
    shift=arrays(np.float64, (3,), elements=st.floats(-1e3, 1e3, allow_nan=False)),
)
@example(  # a line at exactly 45 deg between two desired axes: which one gets it is a tie
    x=np.array([[36.875, 0.0, 36.875], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]), seed=0, shift=np.zeros(3)
)
def test_invariant_to_order_and_translation(x: FloatArray, seed: int, shift: FloatArray) -> None:
    """Centre and variances do not depend on the drones' order or a translation. The variances
    are compared as a set: where an eigenvector is exactly as aligned with two desired axes, the
    assignment is a tie broken by rounding (align_axes), and a permutation may break it the
    other way."""
    a = descriptors(x)
    perm = np.random.default_rng(seed).permutation(x.shape[0])
    b = descriptors(x[perm] + shift)
    assert np.all(np.isfinite(a))
    np.testing.assert_allclose(b[:3], a[:3] + shift, atol=1e-6)
    scale = max(1.0, float(np.abs(a[6:]).max()))
    np.testing.assert_allclose(np.sort(b[6:]), np.sort(a[6:]), atol=1e-6 * scale)


@pytest.mark.parametrize(
    "yaw,pitch,roll", [(0.0, 0.0, 0.0), (0.6, 0.0, 0.0), (-2.5, 0.3, -0.2), (1.2, -0.4, 0.5)]
)
@pytest.mark.parametrize("scale", [0.5, 1.0, 3.0])
def test_exact_for_rotated_and_scaled_box(
    yaw: float, pitch: float, roll: float, scale: float
) -> None:
    half = (3.0 * scale, 2.0 * scale, 1.0 * scale)
    centre = np.array([12.0, -7.0, -5.0])
    x = _box(half) @ rot_zyx(yaw, pitch, roll).T + centre
    desired = np.array([0, 0, 0, roll, pitch, yaw, 0, 0, 0], float)
    a = descriptors(x, desired)
    np.testing.assert_allclose(a[:3], centre, atol=1e-9)
    np.testing.assert_allclose(a[3:6], [roll, pitch, yaw], atol=1e-9)
    np.testing.assert_allclose(a[6:], np.square(half), rtol=1e-9)


def test_width_crossing_length_does_not_swap_axes() -> None:
    """Assign eigenvectors to the desired axes, never sort: width > length keeps yaw 0."""
    x = _box((2.0, 3.0, 0.5))
    a = descriptors(x, np.zeros(9))
    assert abs(a[5]) < 1e-12
    np.testing.assert_allclose(a[6:], [4.0, 9.0, 0.25])


def test_flat_formation_and_equal_variances_are_finite() -> None:
    grid = np.array([[i, j, 0.0] for i in (0, 2, 4) for j in (0, 2, 4)])  # square: s1 = s2
    a = descriptors(grid)
    assert np.all(np.isfinite(a))
    np.testing.assert_allclose(a[6:], [8 / 3, 8 / 3, 0.0], atol=1e-12)
    assert not heading_defined(a[6:])
    line = np.array([[i, 0.0, 0.0] for i in range(5)])  # two zero variances
    assert np.all(np.isfinite(descriptors(line)))
    same = np.zeros((4, 3))  # every drone at one point
    assert np.all(np.isfinite(descriptors(same)))


def test_frame_is_a_proper_rotation() -> None:
    x = np.random.default_rng(1).normal(size=(20, 3))
    r = swarm_frame(x).axes
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)


@settings(max_examples=40, deadline=None)
@given(x=_positions, v=_positions, ref=arrays(np.float64, (6,), elements=st.floats(-100, 100)))
def test_moments_from_channel_averages_are_exact(
    x: FloatArray, v: FloatArray, ref: FloatArray
) -> None:
    n = min(len(x), len(v))
    x, v = x[:n], v[:n] / 10
    avg = channels_batch(x, v, ref[:3], ref[3:]).mean(axis=0)
    got = moments_from_averages(avg, ref[:3], ref[3:])
    want = true_moments(x, v)
    scale = 1.0 + float(np.abs(x - ref[:3]).max()) ** 2
    np.testing.assert_allclose(got.centre_ned_m, want.centre_ned_m, atol=1e-9 * scale)
    np.testing.assert_allclose(got.sigma_m2, want.sigma_m2, atol=1e-9 * scale)
    np.testing.assert_allclose(got.centre_rate_ned_m_s, want.centre_rate_ned_m_s, atol=1e-9)
    np.testing.assert_allclose(got.sigma_rate_m2_s, want.sigma_rate_m2_s, atol=1e-9 * scale)


LIMITS = ThrustLimits(mass_kg=0.34, max_thrust_n=6.67)


@settings(max_examples=80, deadline=None)
@given(v=arrays(np.float64, (3,), elements=st.floats(-2.0, 2.0)), yaw=st.floats(-3.1, 3.1))
def test_attitude_thrust_realises_the_acceleration(v: FloatArray, yaw: float) -> None:
    """Within the limits: g e3 - (T/m) R e3 == v, with the commanded heading."""
    sp = attitude_thrust(v, yaw, LIMITS)
    assert not sp.limited
    r = rot_zyx(sp.yaw_rad, sp.pitch_rad, sp.roll_rad)
    np.testing.assert_allclose(G_M_S2 * E3 - sp.thrust_n / LIMITS.mass_kg * r[:, 2], v, atol=1e-9)


@settings(max_examples=80, deadline=None)
@given(v=arrays(np.float64, (3,), elements=st.floats(-100.0, 100.0)), yaw=st.floats(-3.1, 3.1))
def test_attitude_thrust_respects_limits(v: FloatArray, yaw: float) -> None:
    sp = attitude_thrust(v, yaw, LIMITS)
    t_min, t_max = LIMITS.thrust_range_n
    assert t_min - 1e-9 <= sp.thrust_n <= t_max + 1e-9
    tilt = np.arccos(np.cos(sp.roll_rad) * np.cos(sp.pitch_rad))
    assert tilt <= LIMITS.max_tilt_rad + 1e-9


@settings(max_examples=40, deadline=None)
@given(
    x=_positions,
    v=_positions,
    ref=arrays(np.float64, (6,), elements=st.floats(-100, 100)),
    angles=arrays(np.float64, (6,), elements=st.floats(-1.5, 1.5)),
)
def test_moments_from_channels_in_the_plans_turning_frame_are_exact(
    x: FloatArray, v: FloatArray, ref: FloatArray, angles: FloatArray
) -> None:
    """Channels taken in a turning plan frame (axes R_d, rate omega_d) give the same moments."""
    n = min(len(x), len(v))
    x, v = x[:n], v[:n] / 10
    frame = (rot_zyx(*angles[:3])[None], angles[3:][None])
    avg = channels_batch(x, v, ref[:3], ref[3:], (frame[0].repeat(n, 0), frame[1].repeat(n, 0)))
    got = moments_from_averages_batch(avg.mean(axis=0)[None], ref[None, :3], ref[None, 3:], frame)
    want = true_moments(x, v)
    scale = 1.0 + float(np.abs(x - ref[:3]).max()) ** 2
    np.testing.assert_allclose(got.centre_ned_m[0], want.centre_ned_m, atol=1e-9 * scale)
    np.testing.assert_allclose(got.sigma_m2[0], want.sigma_m2, atol=1e-9 * scale)
    np.testing.assert_allclose(
        got.centre_rate_ned_m_s[0], want.centre_rate_ned_m_s, atol=1e-8 * scale
    )
    np.testing.assert_allclose(got.sigma_rate_m2_s[0], want.sigma_rate_m2_s, atol=1e-8 * scale)


def test_compiled_axis_assignment_is_the_plain_one_to_the_bit() -> None:
    """align_axes_batch's assignment loop, compiled, gives the plain Python function's axes
    bit for bit: random, flat, tied (equal variances) and NaN covariances, any desired axes."""
    from protocols.model.descriptors import _assign_axes, _compiled
    from protocols.model.frames import rot_zyx_batch

    rng = np.random.default_rng(7)
    for trial in range(200):
        k_n = int(rng.integers(1, 6))
        a = rng.normal(size=(k_n, 3, 3))
        sigma = a @ np.swapaxes(a, 1, 2)
        if trial % 4 == 1:
            sigma[:, 2, :] = sigma[:, :, 2] = 0.0
        if trial % 4 == 2:
            sigma = np.broadcast_to(np.eye(3), (k_n, 3, 3)).copy()
        desired = rot_zyx_batch(*rng.uniform(-3.0, 3.0, size=(3, k_n)))
        if trial % 3 == 0:
            desired = np.broadcast_to(np.eye(3), (k_n, 3, 3)).copy()
        evecs = np.linalg.eigh(sigma)[1]
        if trial % 5 == 0:
            evecs[0] = np.nan
        overlap = np.abs(np.swapaxes(desired, 1, 2) @ evecs)
        plain, compiled = np.empty((k_n, 3, 3)), np.empty((k_n, 3, 3))
        _assign_axes(overlap, evecs, desired, plain)
        _compiled()(overlap, evecs, desired, compiled)
        assert plain.tobytes() == compiled.tobytes()


def test_loading_a_scenario_or_writing_a_report_does_not_load_numba() -> None:
    """The scenario checks (every ``swarm`` command that reads a scenario: up, gcs, scenario
    check) and the report's true descriptors take one matrix at a time with the plain assignment:
    numba's first use costs ~0.6 s of CPU, which only the processes that fly should pay."""
    root = Path(__file__).resolve().parents[1]
    code = (
        "import sys, numpy as np\n"
        "from protocols.scenario.scenario_file import load_scenario\n"
        "from gcs.report.metrics import descriptors_of\n"
        "load_scenario('scenarios/paper.toml')\n"
        "pos = np.random.default_rng(0).normal(size=(5, 4, 3))\n"
        "a = descriptors_of(pos, np.ones((5, 4), bool), np.zeros((5, 9)))\n"
        "assert np.isfinite(a).all()\n"
        "print('numba' in sys.modules)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=root, timeout=120
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "False"

"""protocols.model.frames: rotations against closed-form answers, and each conversion's versions
(plain floats, numpy, compiled) as the one formula they are."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocols.model.frames import (
    FloatArray,
    quat_from_zyx,
    rot_zyx,
    rot_zyx_batch,
    wxyz_from_zyx,
    yaw_from_quat_batch,
    yaw_from_wxyz,
    zyx_from_quat,
    zyx_from_quat_batch,
    zyx_from_rot,
    zyx_from_rot_batch,
    zyx_from_wxyz,
)
from protocols.runtime.same_code import same_code

zyx_angles = st.tuples(
    st.floats(-math.pi + 1e-3, math.pi - 1e-3), st.floats(-1.5, 1.5), st.floats(-3.1, 3.1)
)


def _rot_of_quat(q: FloatArray) -> FloatArray:
    """The rotation matrix of a unit quaternion (w, x, y, z), the textbook formula."""
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def test_rotations_about_one_axis() -> None:
    """Yaw +90 deg turns north into east; pitch +90 deg turns the nose (body x) up (-z, NED);
    roll +90 deg turns the right wing (body y) down (+z)."""
    np.testing.assert_allclose(rot_zyx(math.pi / 2, 0, 0) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(rot_zyx(0, math.pi / 2, 0) @ [1, 0, 0], [0, 0, -1], atol=1e-15)
    np.testing.assert_allclose(rot_zyx(0, 0, math.pi / 2) @ [0, 1, 0], [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(quat_from_zyx(math.pi / 2, 0, 0), [0.5**0.5, 0, 0, 0.5**0.5])


@given(zyx_angles)
def test_quaternion_and_matrix_are_one_rotation(zyx: tuple[float, float, float]) -> None:
    q = quat_from_zyx(*zyx)
    assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_allclose(_rot_of_quat(q), rot_zyx(*zyx), atol=1e-14)
    assert zyx_from_rot(rot_zyx(*zyx)) == pytest.approx(zyx, abs=1e-9)


@given(zyx_angles)
def test_angles_come_back_in_the_order_they_went_in(zyx: tuple[float, float, float]) -> None:
    assert zyx_from_quat(quat_from_zyx(*zyx)) == pytest.approx(zyx, abs=1e-9)
    assert zyx_from_wxyz(*wxyz_from_zyx(*zyx)) == pytest.approx(zyx, abs=1e-9)
    assert yaw_from_wxyz(*wxyz_from_zyx(*zyx)) == zyx_from_wxyz(*wxyz_from_zyx(*zyx))[0]


def test_pitch_is_clamped_past_the_pole() -> None:
    """Round-off past +-90 deg pitch (|2(wy - zx)| a hair above 1) gives +-pi/2, not NaN."""
    q = (0.7071068, 0.0, 0.7071068, 0.0)  # 2wy = 1.0000001
    assert zyx_from_wxyz(*q)[1] == math.pi / 2
    assert zyx_from_quat(np.array(q))[1] == math.pi / 2
    assert zyx_from_quat_batch(np.array(q)[:, None])[1][0] == math.pi / 2


def test_numpy_versions_are_the_float_formula() -> None:
    """One formula: the numpy versions agree with the float ones (to round-off: numpy's arctan2
    and arcsin may differ from the C library's in the last bit), one by one and in batches to
    the last bit (a quaternion converted alone is the same as in a batch)."""
    rng = np.random.default_rng(3)
    zyx = rng.uniform(-3.0, 3.0, (3, 500))
    zyx[1] *= 0.5
    q = quat_from_zyx(zyx[0], zyx[1], zyx[2])
    floats = np.array([wxyz_from_zyx(*zyx[:, k]) for k in range(500)]).T
    np.testing.assert_allclose(q, floats, rtol=0, atol=1e-15)
    one_by_one = np.array([quat_from_zyx(*zyx[:, k]) for k in range(500)]).T
    assert np.array_equal(q, one_by_one)
    batch = np.array(zyx_from_quat_batch(q))
    assert np.array_equal(batch, np.array([zyx_from_quat(q[:, k]) for k in range(500)]).T)
    assert np.array_equal(yaw_from_quat_batch(q), batch[0])
    floats_back = np.array([zyx_from_wxyz(*q[:, k]) for k in range(500)]).T
    np.testing.assert_allclose(batch, floats_back, rtol=0, atol=4e-16 * 8)
    np.testing.assert_allclose(batch, zyx, rtol=0, atol=1e-9)
    rot = rot_zyx_batch(zyx[0], zyx[1], zyx[2])
    assert np.array_equal(rot[7], rot_zyx(*zyx[:, 7]))
    assert np.array_equal(np.array(zyx_from_rot_batch(rot))[:, 7], zyx_from_rot(rot[7]))


def test_the_compiled_conversion_is_the_plain_one_to_the_last_bit() -> None:
    from sitl_sim.vehicle import setpoint_jit

    rng = np.random.default_rng(4)
    q = rng.normal(size=(300, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    for row in q:
        assert setpoint_jit._zyx(*row) == zyx_from_wxyz(*row)


def test_same_code_binds_other_names_and_leaves_the_function_alone() -> None:
    def halve(v: float) -> float:
        return math.floor(v / 2)

    numpy_halve = same_code(halve, math=np)
    assert numpy_halve(np.array([3.0, 5.0])).tolist() == [1.0, 2.0]
    assert halve(3.0) == 1 and numpy_halve.__name__ == "halve"

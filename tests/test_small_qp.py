"""The closest point of a polyhedron in R³, against scipy, and its best effort when empty."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog, minimize

from drone_agent.core.separation.small_qp import project

pytestmark = pytest.mark.timeout(120)


def test_closed_forms() -> None:
    u0 = np.array([1.0, 2.0, 3.0])
    inside = project(u0, np.array([[1.0, 0.0, 0.0]]), np.array([0.0]))
    assert inside.feasible and inside.u.tolist() == u0.tolist()
    one = project(u0, np.array([[2.0, 0.0, 0.0]]), np.array([4.0]))  # x >= 2
    assert one.feasible and one.u.tolist() == [2.0, 2.0, 3.0]
    corner = project(u0, -np.eye(3), np.array([0.0, 0.0, 0.0]))  # the negative octant
    assert corner.feasible and np.allclose(corner.u, 0.0)
    edge = project(u0, np.array([[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), np.zeros(2))
    assert np.allclose(edge.u, [0.0, 0.0, 3.0])


def test_empty_polyhedron_keeps_the_hard_rows_and_says_so() -> None:
    g = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    b = np.array([2.0, -1.0, -1.0, -1.0])  # x >= 2 and x <= 1 (soft); |z| <= 1 (hard)
    out = project(np.array([0.0, 0.0, 5.0]), g, b, np.array([True, True, False, False]))
    assert not out.feasible
    assert abs(out.u[2]) <= 1.0 + 1e-9 and 1.0 <= out.u[0] <= 2.0  # worst shortfall 0.5


unit = (
    st.tuples(*[st.floats(-1.0, 1.0)] * 3).map(np.array).filter(lambda v: np.linalg.norm(v) > 0.1)
)


@settings(max_examples=300, deadline=None)
@given(
    rows=st.lists(st.tuples(unit, st.floats(-3.0, 3.0)), min_size=1, max_size=9),
    u0=st.tuples(*[st.floats(-5.0, 5.0)] * 3).map(np.array),
)
def test_matches_scipy_whenever_feasible(
    rows: list[tuple[np.ndarray, float]], u0: np.ndarray
) -> None:
    g = np.array([r[0] for r in rows])
    b = np.array([r[1] for r in rows])
    box = np.vstack((np.eye(3), -np.eye(3)))  # keep the problem bounded for linprog
    g, b = np.vstack((g, box)), np.concatenate((b, np.full(6, -10.0)))
    out = project(u0, g, b)
    lp = linprog(np.zeros(3), A_ub=-g, b_ub=-b, bounds=[(None, None)] * 3)
    if lp.status != 0:
        assert not out.feasible
        return
    assert out.feasible and np.all(g @ out.u >= b - 1e-7)
    ref = minimize(lambda x: float((x - u0) @ (x - u0)), lp.x, jac=lambda x: 2 * (x - u0),
                   constraints=[{"type": "ineq", "fun": lambda x: g @ x - b,
                                 "jac": lambda x: g}], method="SLSQP",
                   options={"ftol": 1e-12, "maxiter": 500})  # fmt: skip
    assert float((out.u - u0) @ (out.u - u0)) <= ref.fun + 1e-6

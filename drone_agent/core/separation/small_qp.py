"""The closest point of a polyhedron in R³: ``min |u - u0|²  s.t.  G u >= b``. Pure numpy.

Used by the separation layer (drone_agent/core/separation/filter.py) to filter one agent's
acceleration with a handful of half-space constraints. Exact, with no iteration count to tune: in R³
the closest point lies in the relative interior of a face whose affine hull is cut out by at most
three linearly independent rows, so it is the nearest *feasible* one among the projections of ``u0``
onto the affine sets of every subset of one, two or three rows (a 3 x 3 solve each, batched).
Rows are brought in by constraint generation (start with the rows ``u0`` violates, add the rows
the candidate violates, repeat), so the enumeration stays small when there are many rows.

When no point satisfies every row, the rows marked ``soft`` give way: the answer satisfies the
other (hard) rows and, among the candidates that do, has the smallest largest soft violation
(then the smallest distance). That is a best effort, not an exact minimax, and is reported.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import numpy.typing as npt

from protocols.model.frames import FloatArray

IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]

#: Relative tolerance of "a row holds" (of 1 + |b|).
TOLERANCE = 1e-9


@dataclass(frozen=True)
class Projection:
    """``u`` (3,): the answer; ``feasible``: it satisfies every row (within TOLERANCE)."""

    u: FloatArray
    feasible: bool


@lru_cache(maxsize=64)
def _subsets(n: int, size: int) -> IntArray:
    """Every ``size``-subset of range(n), one per row (C(n, size), size)."""
    combos = list(itertools.combinations(range(n), size))
    return np.array(combos, dtype=np.intp).reshape(len(combos), size)


@np.errstate(divide="ignore", invalid="ignore", over="ignore")  # det of parallel rows
def _candidates(u0: FloatArray, g: FloatArray, b: FloatArray) -> FloatArray:
    """Projections (C, 3) of ``u0`` onto the affine sets of every subset of 1, 2 or 3 rows
    (degenerate subsets left out)."""
    out = [u0[None, :]]
    n = len(b)
    resid = b - g @ u0
    norm2 = np.einsum("ij,ij->i", g, g)
    ok = norm2 > 1e-24
    out.append(u0 + g[ok] * (resid[ok] / norm2[ok])[:, None])
    if n >= 2:
        idx = _subsets(n, 2)
        gs = g[idx]  # (P, 2, 3)
        gram = gs @ gs.transpose(0, 2, 1)
        det = np.linalg.det(gram)
        good = np.abs(det) > 1e-12 * np.prod(norm2[idx], axis=1) + 1e-300
        lam = np.linalg.solve(gram[good], resid[idx][good][..., None])
        out.append(u0 + np.einsum("pki,pk->pi", gs[good], lam[..., 0]))
    if n >= 3:
        idx = _subsets(n, 3)
        gs = g[idx]  # (T, 3, 3)
        det = np.linalg.det(gs)
        scale = np.sqrt(np.prod(norm2[idx], axis=1))
        good = np.abs(det) > 1e-9 * scale + 1e-300
        out.append(np.linalg.solve(gs[good], b[idx][good][..., None])[..., 0])
    return np.concatenate(out)


def _violation(u: FloatArray, g: FloatArray, b: FloatArray) -> FloatArray:
    """How much each candidate (C, 3) falls short of each row, beyond the tolerance (C, R)."""
    return np.maximum(b - u @ g.T - TOLERANCE * (1.0 + np.abs(b)), 0.0)


def _closest(u0: FloatArray, g: FloatArray, b: FloatArray, soft: BoolArray) -> Projection:
    cand = _candidates(u0, g, b)
    short = _violation(cand, g, b)
    dist = np.einsum("ij,ij->i", cand - u0, cand - u0)
    feasible = ~short.any(axis=1)
    if feasible.any():
        k = int(np.flatnonzero(feasible)[np.argmin(dist[feasible])])
        return Projection(cand[k], True)
    hard_ok = ~short[:, ~soft].any(axis=1)
    if not hard_ok.any():  # only with an empty hard set; the caller's box makes that impossible
        hard_ok = np.ones(len(cand), dtype=bool)
    worst = short[:, soft].max(axis=1, initial=0.0)
    order = np.lexsort((dist, worst, ~hard_ok))
    return Projection(cand[int(order[0])], False)


def project(
    u0: FloatArray, g: FloatArray, b: FloatArray, soft: BoolArray | None = None
) -> Projection:
    """The point closest to ``u0`` (3,) with ``g @ u >= b`` (rows (R, 3), (R,)); see the module
    docstring for the infeasible case (``soft`` (R,): rows that may give way, default all)."""
    u0 = np.asarray(u0, dtype=float)
    soft = np.ones(len(b), dtype=bool) if soft is None else np.asarray(soft, dtype=bool)
    tol = TOLERANCE * (1.0 + np.abs(b))
    working = g @ u0 < b - tol
    if not working.any():
        return Projection(u0.copy(), True)
    while True:
        rows = np.flatnonzero(working)
        result = _closest(u0, g[rows], b[rows], soft[rows])
        broken = (g @ result.u < b - tol) & ~working
        if not broken.any():
            feasible = result.feasible and bool(np.all(g @ result.u >= b - tol))
            return Projection(result.u, feasible)
        working |= broken

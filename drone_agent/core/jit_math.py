"""What the compiled loops of the agent core share (numba, ``cache=True``: compiled once per
install, loaded from the cache by every later process).

The hot per-drone maths of the core (cooperative field, moments, thrust and attitude, the
consensus pairing, the neighbour table, the separation pre-check) are loops over the drones
compiled with numba, replacing numpy code whose per-call overhead was most of its cost at the
few drones of an agent process. No ``fastmath``: the arithmetic is IEEE's, term by term as
written. ``error_model="numpy"``: a division by zero gives inf or NaN as numpy's did, never an
exception.

Compiled through :func:`protocols.runtime.compiled.jit`, the project's one way to compile (lazy:
numba is imported and the function compiled, or loaded from its cache, on its first call; its
callees compiled with it), with ``error_model="numpy"``. Pure and I/O-free.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from protocols.model.frames import FloatArray
from protocols.runtime import compiled


def jit(fn: Callable[..., Any]) -> Any:
    """The decorator of every compiled loop of the core (module doc)."""
    return compiled.jit(fn, error_model="numpy")


@jit
def nmax(a: float, b: float) -> float:
    """``np.maximum`` of two floats (a NaN wins)."""
    if a != a or b != b:
        return a + b
    return a if a >= b else b


@jit
def nmin(a: float, b: float) -> float:
    """``np.minimum`` of two floats (a NaN wins)."""
    if a != a or b != b:
        return a + b
    return a if a <= b else b


def f64(a: Any) -> FloatArray:
    """``a`` as a C-contiguous float64 array (no copy when it is one already)."""
    return np.ascontiguousarray(a, dtype=np.float64)

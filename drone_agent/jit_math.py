"""What the compiled loops of the agent core share (numba, ``cache=True``: compiled once per
install, loaded from the cache by every later process).

The hot per-drone maths of the core (cooperative field, moments, thrust and attitude, the
consensus pairing, the neighbour table, the separation pre-check) are loops over the drones
compiled with numba, replacing numpy code whose per-call overhead was most of its cost at the
few drones of an agent process. No ``fastmath``: the arithmetic is IEEE's, term by term as
written. ``error_model="numpy"``: a division by zero gives inf or NaN as numpy's did, never an
exception.

Compiled when first called, not when imported: every ``swarm`` command imports the agent core
(the CLI's subcommands), few run it, and numba's import (~0.15 s of CPU) and its first use
(~0.35 s: its registries, with scipy's BLAS) should be paid only by the processes that fly.
A :func:`jit` function is a plain Python function until its first call from Python, which
compiles it (or loads it from the cache) together with the compiled functions it calls, and
puts the compiled function in their modules' namespaces in its place. Pure and I/O-free.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from protocols.frames import FloatArray


class _Lazy:
    """A function compiled by numba on its first call (module doc)."""

    def __init__(self, fn: Callable[..., Any]) -> None:
        self.fn = fn
        self.__doc__ = fn.__doc__
        self.__name__ = fn.__name__
        self._compiled: Any = None

    def compiled(self) -> Any:
        """The numba dispatcher of the function (made on the first call)."""
        if self._compiled is None:
            import numba

            namespace = self.fn.__globals__
            for name in self.fn.__code__.co_names:  # the compiled functions it calls
                value = namespace.get(name)
                if isinstance(value, _Lazy) and value is not self:
                    namespace[name] = value.compiled()
            self._compiled = numba.njit(cache=True, error_model="numpy")(self.fn)
            if namespace.get(self.__name__) is self:
                namespace[self.__name__] = self._compiled
        return self._compiled

    def __call__(self, *args: Any) -> Any:
        return self.compiled()(*args)


def jit(fn: Callable[..., Any]) -> Any:
    """The decorator of every compiled loop of the core (module doc)."""
    return _Lazy(fn)


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

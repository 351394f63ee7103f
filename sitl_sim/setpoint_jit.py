"""The setpoint checks of sitl_sim/setpoint.py over many vehicles at once (numba).

:func:`check_all` runs :func:`sitl_sim.setpoint.checked_setpoint` (and the
:func:`~sitl_sim.setpoint.euler_zyx` it calls) compiled from their own code, not from a copy:
the rule has one implementation, read by the simulator's vehicles one message at a time and by
``swarm simulate``'s hundred vehicles in one call. The same floating point operations in the
same order (no ``fastmath``; ``math``'s functions are the C library's, as CPython's), so the
values are those of the plain functions to the last bit. Compiled on first use and cached beside
this file.
"""

from __future__ import annotations

import types
from collections.abc import Callable
from typing import Any

import numba

from sitl_sim import setpoint


def _compiled(fn: Callable[..., Any], **helpers: Any) -> Any:
    """``fn`` compiled by numba, the functions it calls by name resolved to ``helpers``
    (compiled ones) instead of its module's plain ones: its own code, another scope."""
    scope = dict(fn.__globals__, **helpers)
    same = types.FunctionType(fn.__code__, scope, fn.__name__, fn.__defaults__)
    same.__qualname__ = fn.__qualname__
    return numba.njit(cache=True, inline="always")(same)


_euler_zyx = _compiled(setpoint.euler_zyx)
_checked = _compiled(setpoint.checked_setpoint, euler_zyx=_euler_zyx)


@numba.njit(cache=True)
def check_all(quats, thrusts, codes, unit, euler):  # type: ignore[no-untyped-def]
    """:func:`sitl_sim.setpoint.validate_attitude_targets` into ``codes`` (K,), ``unit``
    (K, 4) and ``euler`` (K, 3)."""
    for k in range(thrusts.shape[0]):
        code, qw, qx, qy, qz, roll, pitch, yaw = _checked(
            quats[k, 0], quats[k, 1], quats[k, 2], quats[k, 3], thrusts[k]
        )
        codes[k] = code
        if code == 0:
            unit[k, 0], unit[k, 1], unit[k, 2], unit[k, 3] = qw, qx, qy, qz
            euler[k, 0], euler[k, 1], euler[k, 2] = roll, pitch, yaw

"""A function's own code in another scope: :func:`same_code`.

The numpy forms of the frames' formulas (protocols/model/frames.py) and the compiled callees of
:func:`protocols.runtime.compiled.jit` run a function's own code with some of its global names
bound to other objects, so that a formula is written once."""

from __future__ import annotations

import types
from collections.abc import Callable
from typing import Any


def same_code(fn: Callable[..., Any], **names: Any) -> Any:
    """``fn``'s own code (the same formula, operation for operation) with the global ``names``
    bound to other objects: numpy's functions in place of math's, or compiled helpers (numba)
    in place of the plain functions ``fn`` calls. Not a copy of the formula: another scope."""
    scope = dict(fn.__globals__, **names)
    same = types.FunctionType(fn.__code__, scope, fn.__name__, fn.__defaults__)
    same.__qualname__ = fn.__qualname__
    same.__doc__ = fn.__doc__
    return same

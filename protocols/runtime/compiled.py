"""The one way the project compiles a function with numba: :func:`jit`.

Every compiled function of the project goes through here, so that each follows the same rules:

- **Lazy.** A :func:`jit` function is a :class:`Compiled` holding the plain Python function; numba
  is imported and the function compiled (or loaded from numba's cache) on its first call, not
  when its module is imported. Every ``swarm`` command imports modules that hold compiled
  functions, few run them, and numba's import (~0.15 s of CPU) and its first use (~0.35 s) should
  be paid only by the processes that fly.
- **Cached.** ``cache=True`` always: compiled once per install (or per edit of the source), loaded
  from ``__pycache__`` beside the source by every later process.
- **The same arithmetic.** The options given are numba's (``error_model``, ``inline``, ...), passed
  through as they are; no ``fastmath`` unless a caller asks, so the arithmetic is IEEE's, term by
  term as written, and a compiled function gives the plain one's bits (``math``'s functions are
  the C library's, as CPython's).
- **Compiled callees.** The compiled function runs the plain one's own code
  (:func:`protocols.runtime.same_code.same_code`: the same code in another scope) with the global
  names it calls that are :class:`Compiled` bound to their compiled functions, and with ``calls``
  (name -> function) bound to the compiled form of the functions given: so a plain function that
  other plain code also calls (a formula in :mod:`protocols.model.frames`) is compiled as it is, not
  copied.
- **No detour after the first call.** A :func:`jit` function defined with the decorator in a
  module is, after its first call, replaced in that module's namespace by the compiled function
  itself, so that the module's own Python calls go straight to numba's dispatcher. Code that
  keeps a reference (``from m import f``) goes through :meth:`Compiled.__call__`, one Python call
  more; :func:`compiled` gives the dispatcher of either form.

The plain function stays callable as ``f.py_func`` (numba's dispatchers have the same
attribute): the tests' reference. :func:`loaded` says whether this process has numba loaded, for
code that takes the plain path when it has not (one matrix in a process that never flies).

One caveat of numba's cache: it is keyed on the function's file, line and argument types, not
on the scope, so one plain function must be compiled with one set of ``calls`` only.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any

from protocols.runtime.same_code import same_code


class Compiled:
    """A function compiled by numba on its first call (module doc)."""

    def __init__(
        self, fn: Callable[..., Any], calls: dict[str, Any] | None, options: dict[str, Any]
    ) -> None:
        self.py_func = fn
        self.__doc__ = fn.__doc__
        self.__name__ = fn.__name__
        self.__qualname__ = fn.__qualname__
        self.__module__ = fn.__module__
        self._calls = dict(calls or {})
        self._options = options
        self._dispatcher: Any = None

    def dispatcher(self) -> Any:
        """numba's dispatcher of the function (compiled, or loaded from the cache, the first
        time), with its callees compiled first."""
        if self._dispatcher is None:
            numba = import_numba()
            namespace = self.py_func.__globals__
            names = {
                name: compiled(value)
                for name in self.py_func.__code__.co_names
                if isinstance(value := namespace.get(name), Compiled) and value is not self
            }
            names.update({name: compiled(fn) for name, fn in self._calls.items()})
            code = same_code(self.py_func, **names) if names else self.py_func
            self._dispatcher = numba.njit(cache=True, **self._options)(code)
            if namespace.get(self.__name__) is self:
                namespace[self.__name__] = self._dispatcher
        return self._dispatcher

    def __call__(self, *args: Any) -> Any:
        return self.dispatcher()(*args)

    def __repr__(self) -> str:
        state = "compiled" if self._dispatcher is not None else "not compiled yet"
        return f"<Compiled {self.__module__}.{self.__qualname__} ({state})>"


def jit(
    fn: Callable[..., Any] | None = None, *, calls: dict[str, Any] | None = None, **options: Any
) -> Any:
    """``fn`` compiled by numba on its first call (module doc): ``@jit``, ``@jit(**options)`` or
    ``jit(fn, calls={...}, **options)``. ``options`` are numba's ``njit`` options (``cache`` is
    always True); ``calls`` binds global names ``fn`` calls to other functions (plain ones are
    compiled with :func:`jit` and no options)."""
    if "cache" in options:
        raise TypeError("jit: cache is always True")

    def wrap(f: Callable[..., Any]) -> Compiled:
        return Compiled(f, calls, options)

    return wrap if fn is None else wrap(fn)


def compiled(fn: Any) -> Any:
    """numba's dispatcher of ``fn``: a :class:`Compiled` (compiling it first if need be), a
    dispatcher already (a :class:`Compiled` replaced in its module after its first call) as it
    is, or a plain function compiled with :func:`jit` and no options."""
    if isinstance(fn, Compiled):
        return fn.dispatcher()
    if hasattr(fn, "py_func"):
        return fn
    return jit(fn).dispatcher()


#: scipy's BLAS and LAPACK modules, which numba imports as it loads its array functions only to
#: offer ``np.dot`` and ``np.linalg`` inside compiled code (no compiled function here uses them)
_BLAS_MODULES = ("scipy.linalg.cython_blas", "scipy.linalg.cython_lapack")


def import_numba() -> Any:
    """numba, imported and its compiler's functions loaded, without scipy's linear algebra.

    numba loads its array functions (on the first compile or cache load) and, with them, checks
    for BLAS by importing ``scipy.linalg``: ~0.15-0.35 s of every process that flies, a quarter
    of numba's start (and ``numpy.f2py`` with it). No compiled function of the project calls
    BLAS or LAPACK (``np.dot``, ``np.linalg``, ``@``: plain numpy code does), so the check is
    answered "not there" while numba loads: those two modules read as missing
    (``sys.modules[name] = None``) for that moment only, and scipy imports them as usual
    afterwards (e.g. :mod:`protocols.scenario.layout`'s ``scipy.sparse``). A compiled function
    that called BLAS would fail to compile saying numba has no ``np.dot`` (tests compile every
    one of them)."""
    if "numba" in sys.modules and "numba.np.arraymath" in sys.modules:
        return sys.modules["numba"]
    blocked = [name for name in _BLAS_MODULES if name not in sys.modules]
    for name in blocked:
        sys.modules[name] = None  # type: ignore[assignment]
    try:
        import numba
        from numba.core.registry import cpu_target

        cpu_target.target_context.refresh()  # loads numba.np.arraymath (and its BLAS check)
    finally:
        for name in blocked:
            if sys.modules.get(name, "") is None:
                del sys.modules[name]
    return numba


def loaded() -> bool:
    """Whether this process has numba loaded (it has compiled or loaded a function, or imported
    numba otherwise): a process that has not may prefer a plain function for a small case."""
    return "numba" in sys.modules

"""protocols/runtime/compiled.py: the one way the project compiles with numba (lazy, cached, the
plain function's own code with its compiled callees)."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np

from protocols.runtime.compiled import Compiled, compiled, jit

ROOT = Path(__file__).resolve().parents[1]


def test_defining_a_compiled_function_does_not_load_numba() -> None:
    """A module that defines compiled functions can be imported (and the functions made) in a
    process that never calls them without numba being loaded."""
    code = (
        "import sys\n"
        "from protocols.runtime.compiled import jit, loaded\n"
        "f = jit(lambda x: x + 1.0)\n"
        "g = jit(error_model='numpy')(lambda x: x)\n"
        "import drone_agent.core.jit_math, protocols.model.descriptors, sitl_sim.physics.kernel\n"
        "print(loaded(), 'numba' in sys.modules)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["False", "False"]


def test_numba_loads_without_scipys_linear_algebra_which_imports_as_usual_after() -> None:
    """import_numba: numba's BLAS check does not import scipy.linalg (a quarter of numba's
    start); compiled code runs; scipy.linalg imports as usual afterwards."""
    code = (
        "import sys\n"
        "from protocols.runtime.compiled import compiled, import_numba\n"
        "from drone_agent.core.jit_math import nmax\n"
        "import_numba()\n"
        "print(compiled(nmax)(1.5, 3.0), 'scipy.linalg' in sys.modules, "
        "'numpy.f2py' in sys.modules)\n"
        "import scipy.linalg.cython_blas, scipy.linalg\n"
        "print(scipy.linalg.norm([3.0, 4.0]))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["3.0", "False", "False", "5.0"]


def _hyp(a: float, b: float) -> float:
    return math.sqrt(a * a + b * b)


_hyp_jit = jit(_hyp, inline="always")


def _plain_caller(x: float, y: float) -> float:
    return _hyp(x, y) / 3.0 + math.atan2(y, x)


@jit(error_model="numpy")
def _rows(a, out):  # type: ignore[no-untyped-def]
    for k in range(a.shape[0]):
        out[k] = _hyp_jit(a[k, 0], a[k, 1]) / a[k, 2]


def test_a_compiled_function_gives_the_plain_bits_and_calls_compiled_callees() -> None:
    """The compiled loop (its callee compiled by name) and the plain one agree to the bit, a
    division by zero gives inf as numpy's (error_model passed through), and ``calls`` compiles
    a plain function's plain callee in its place without touching its module."""
    a = np.random.default_rng(3).normal(size=(50, 3))
    a[0, 2] = 0.0
    plain, fast = np.empty(50), np.empty(50)
    assert isinstance(_rows, Compiled) or hasattr(_rows, "py_func")
    with np.errstate(divide="ignore"):
        _rows.py_func(a, plain)
    _rows(a, fast)
    assert plain.tobytes() == fast.tobytes()
    assert math.isinf(fast[0])
    # after its first call, the module's name is the dispatcher itself
    assert not isinstance(globals()["_rows"], Compiled)
    assert compiled(globals()["_rows"]) is globals()["_rows"]
    caller = jit(_plain_caller, calls={"_hyp": _hyp_jit})
    got = [caller(x, y) for x, y in a[:, :2]]
    want = [_plain_caller(x, y) for x, y in a[:, :2]]
    assert np.array(got).tobytes() == np.array(want).tobytes()
    assert globals()["_hyp"] is _hyp and isinstance(_hyp_jit, Compiled)

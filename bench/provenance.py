"""Where a benchmark's figures come from: the checkout's commit and the machine's load, and the
one way a benchmark writes its result file (:func:`write_result`), so that every file says both."""

from __future__ import annotations

import datetime
import json
import os
import subprocess
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def commit(root: Path = ROOT) -> str | None:
    """The commit of the checkout at ``root`` (this one by default; with "+changes" when it has
    uncommitted changes); None outside git."""
    try:
        head = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=root, capture_output=True, text=True,
        ).stdout.strip()  # fmt: skip
    except OSError:
        return None
    return None if not head else head + ("+changes" if dirty else "")


def load_average() -> list[float]:
    """The 1, 5 and 15 minute load averages."""
    return [round(x, 2) for x in os.getloadavg()]


def machine_speed(repeats: int = 5) -> dict[str, float]:
    """How fast this machine runs the kind of code the tool is made of, now: the best of
    ``repeats`` timings of a fixed pure-Python loop (``python_ms``: a million additions) and of a
    fixed run of small numpy calls (``numpy_us``: one call on a (25, 18) array, as the agents'
    core makes hundreds a tick). The same code's figures measured on two days compare only
    beside these: a shared virtual machine runs the same code up to three times slower on one
    day than on another."""
    import time

    import numpy as np

    def loop() -> None:
        total = 0
        for i in range(1_000_000):
            total += i

    a = np.ones((25, 18))

    def small() -> None:
        for _ in range(1000):
            np.abs(a).max(axis=1)

    best: dict[str, float] = {}
    for name, fn, scale in (("python_ms", loop, 1e3), ("numpy_us", small, 1e3)):
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        best[name] = round(min(times) * scale, 2)  # numpy: per call, in microseconds
    return best


def write_result(path: Path, result: dict[str, Any], indent: int = 2) -> None:
    """Write ``result`` as JSON to ``path`` with where it was measured: ``commit`` (the
    checkout's, unless the result names its own), ``load_average`` (the machine's now, unless
    the result recorded it when it started), ``machine_speed`` (:func:`machine_speed`, unless
    the result recorded it) and ``written_utc``."""
    stamped = {
        "commit": commit(),
        "load_average": load_average(),
        "machine_speed": machine_speed(),
        **result,
        "written_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(stamped, indent=indent) + "\n", encoding="utf-8")

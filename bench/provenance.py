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


def commit() -> str | None:
    """The checkout's commit (with "+changes" when it has uncommitted changes); None outside
    git."""
    try:
        head = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=ROOT, capture_output=True, text=True,
        ).stdout.strip()  # fmt: skip
    except OSError:
        return None
    return None if not head else head + ("+changes" if dirty else "")


def load_average() -> list[float]:
    """The 1, 5 and 15 minute load averages."""
    return [round(x, 2) for x in os.getloadavg()]


def write_result(path: Path, result: dict[str, Any], indent: int = 2) -> None:
    """Write ``result`` as JSON to ``path`` with where it was measured: ``commit`` (the
    checkout's, unless the result names its own), ``load_average`` (the machine's now, unless
    the result recorded it when it started) and ``written_utc``."""
    stamped = {
        "commit": commit(),
        "load_average": load_average(),
        **result,
        "written_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(stamped, indent=indent) + "\n", encoding="utf-8")

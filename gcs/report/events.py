"""Append-only events log, one JSON object per line: ``{"t_s": ..., "kind": ..., ...fields}``.

``t_s`` is simulated time in seconds. Kinds in use (others are allowed): ``run_start``,
``run_end``, ``command``, ``fault``, ``link_cut``, ``link_restored``, ``dropout_detected``,
``failsafe``. Each line is flushed as soon as it is written, so a crashed run keeps everything up
to its last event and at most a truncated last line, which ``read_events`` skips.

Values are made JSON-able on the way in: numpy scalars and arrays become numbers and lists, paths
strings, dataclasses dicts, and non-finite floats ``null`` (strict JSON has no NaN).
"""

from __future__ import annotations

import dataclasses
import json
import math
import threading
from pathlib import Path
from types import TracebackType
from typing import Any, TextIO

import numpy as np

KINDS: frozenset[str] = frozenset(
    {
        "run_start",
        "run_end",
        "command",
        "fault",
        "link_cut",
        "link_restored",
        "dropout_detected",
        "failsafe",
    }
)


class EventLog:
    """JSON-lines events log opened for appending; use as a context manager. Thread-safe."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file: TextIO | None = None
        self._lock = threading.Lock()

    def __enter__(self) -> EventLog:
        self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def open(self) -> None:
        """Open for appending (creating the file and its folder); done by ``__enter__``."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = self.path.open("a", encoding="utf-8")

    def close(self) -> None:
        """Close the file (idempotent)."""
        with self._lock:
            if self._file is not None:
                self._file.close()
                self._file = None

    def record(self, t_s: float, kind: str, **fields: Any) -> dict[str, Any]:
        """Append the event ``{"t_s": t_s, "kind": kind, **fields}`` and flush; returns it."""
        if not kind:
            raise ValueError("an event needs a non-empty kind")
        event = jsonable({"t_s": float(t_s), "kind": kind, **fields})
        line = json.dumps(event, allow_nan=False, separators=(",", ":"))
        with self._lock:
            if self._file is None:
                raise RuntimeError("EventLog is not open (use it as a context manager)")
            self._file.write(line + "\n")
            self._file.flush()
        return dict(event)


def jsonable(value: Any) -> Any:
    """``value`` with numpy types, paths, dataclasses and tuples turned into plain JSON types."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, np.generic):
        return jsonable(value.item())
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if value is None or isinstance(value, str | int | bool):
        return value
    if isinstance(value, Path):
        return str(value)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return jsonable(dataclasses.asdict(value))
    raise TypeError(f"cannot write {type(value).__name__} to the events log")


def read_events(path: str | Path) -> list[dict[str, Any]]:
    """All events of a JSON-lines log, in file order.

    Blank lines are skipped, and so is an unparseable *last* line (a write cut short by a crash);
    an unparseable line elsewhere raises ``ValueError`` naming the line.
    """
    lines = Path(path).read_text(encoding="utf-8").splitlines()
    events: list[dict[str, Any]] = []
    last = max((k for k, line in enumerate(lines) if line.strip()), default=-1)
    for k, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            event = json.loads(line)
        except json.JSONDecodeError as err:
            if k == last:
                break
            raise ValueError(f"{path}:{k + 1}: not a JSON event: {err}") from err
        if not isinstance(event, dict):
            raise ValueError(f"{path}:{k + 1}: an event must be a JSON object")
        events.append(event)
    return events

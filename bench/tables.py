"""Benchmark results as plain-text tables (``python -m bench.run`` and the benchmarks run
alone print them)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any


def format_rows(name: str, rows: Sequence[dict[str, Any]]) -> str:
    """A plain-text table of flat dicts, one line per row."""
    columns = list(rows[0])
    cells = [[_cell(row.get(c)) for c in columns] for row in rows]
    widths = [max(len(c), *(len(r[i]) for r in cells)) for i, c in enumerate(columns)]
    lines = [name, "  ".join(c.rjust(w) for c, w in zip(columns, widths, strict=True))]
    lines += ["  ".join(v.rjust(w) for v, w in zip(r, widths, strict=True)) for r in cells]
    return "\n".join(lines)


def _cell(value: Any) -> str:
    return f"{value:,}" if isinstance(value, int) and not isinstance(value, bool) else str(value)

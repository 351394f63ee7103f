"""What ``swarm sweep`` writes: ``sweep.json`` (the rows, the bars and where each first breaks),
``sweep.md`` (a table per factor: each value's figures, the mean over its seeds) and a plot per
factor of the bars' figures against its values (``sweep_<factor>.png``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from gcs.reference.sweep import BARS, FACTORS, alone, breaks

#: the figures of the table and plots, with their units
FIGURES = (
    ("centroid_rms_m", "centre RMS (m)"),
    ("shape_rms_m2", "shape RMS (m²)"),
    ("heading_rms_deg", "heading RMS (deg)"),
    ("consensus_rms_m", "consensus RMS (m)"),
    ("min_separation_m", "min separation (m)"),
    ("collisions", "collisions"),
    ("drones_lost", "drones lost"),
    ("drones_lost_unplanned", "lost, unplanned"),
    ("max_tilt_deg", "max tilt (deg)"),
)


def _mean(rows: list[dict[str, Any]], figure: str) -> float:
    values = [float(r[figure]) for r in rows if r[figure] is not None]
    return sum(values) / len(values) if values else float("nan")


def _worst(rows: list[dict[str, Any]], figure: str) -> float:
    at_least = any(b.figure == figure and not b.at_most for b in BARS)
    values = [float(r[figure]) for r in rows if r[figure] is not None]
    if not values:
        return float("nan")
    return min(values) if at_least else max(values)


def write_sweep(
    out: Path,
    scenario: str,
    vary: dict[str, list[float]],
    rows: list[dict[str, Any]],
    command: str,
) -> list[Path]:
    """Write the sweep's files into ``out``; their paths."""
    first_breaks = breaks(rows, vary)
    data = {
        "scenario": scenario,
        "command": command,
        "factors": {n: {"values": v, "unit": FACTORS[n].unit} for n, v in vary.items()},
        "bars": [str(b) for b in BARS],
        "breaks": first_breaks,
        "rows": rows,
    }
    json_path = out / "sweep.json"
    json_path.write_text(json.dumps(data, indent=2) + "\n")
    lines = [f"# swarm sweep of {scenario}", "", f"`{command}`", ""]
    lines += ["Bars: " + "; ".join(str(b) for b in BARS) + ".", ""]
    for name, values in vary.items():
        unit = FACTORS[name].unit
        lines += [f"## {name} ({unit})" if unit else f"## {name}", ""]
        others = [f"{n} = {v[0]:g}" for n, v in vary.items() if n != name]
        if others:
            lines += [f"With {', '.join(others)} (the first values).", ""]
        by_factor = alone(rows, vary, name)
        broken = {bar: v for bar, v in first_breaks[name].items() if v is not None}
        lines.append(
            "First breaks: "
            + ("; ".join(f"{bar} at {v:g}" for bar, v in broken.items()) or "no bar breaks")
            + "."
        )
        lines += ["", "| " + name + " | runs | " + " | ".join(t for _, t in FIGURES) + " |"]
        lines.append("|" + " --- |" * (len(FIGURES) + 2))
        for v in values:
            mine = [r for r in by_factor if r[name] == v]
            cells = [f"{_mean(mine, f):.3g} (worst {_worst(mine, f):.3g})" for f, _ in FIGURES]
            lines.append(f"| {v:g} | {len(mine)} | " + " | ".join(cells) + " |")
        lines.append("")
    if len(vary) > 1:
        lines += ["## Every flight", ""]
        lines += ["| " + " | ".join([*vary, "seed", *(t for _, t in FIGURES)]) + " |"]
        lines.append("|" + " --- |" * (len(vary) + 1 + len(FIGURES)))
        for r in rows:
            cells = [f"{r[n]:g}" for n in vary] + [str(r["seed"])]
            cells += ["n/a" if r[f] is None else f"{r[f]:.3g}" for f, _ in FIGURES]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    md_path = out / "sweep.md"
    md_path.write_text("\n".join(lines))
    return [json_path, md_path, *_plots(out, vary, rows)]


def _plots(out: Path, vary: dict[str, list[float]], rows: list[dict[str, Any]]) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    shown = [(b, dict(FIGURES)[b.figure]) for b in BARS if b.figure in dict(FIGURES)]
    for name, values in vary.items():
        mine = alone(rows, vary, name)
        fig, axes = plt.subplots(1, len(shown), figsize=(3.2 * len(shown), 3.0))
        for ax, (bar, title) in zip(axes, shown, strict=True):
            for r in mine:
                if r[bar.figure] is not None:
                    ax.plot(r[name], r[bar.figure], ".", color="0.6")
            means = [_mean([r for r in mine if r[name] == v], bar.figure) for v in values]
            ax.plot(values, means, "o-", color="C0", label="mean over seeds")
            ax.axhline(bar.limit, color="C3", ls="--", label=f"bar {bar}")
            ax.set_xlabel(f"{name} ({FACTORS[name].unit})" if FACTORS[name].unit else name)
            ax.set_title(title, fontsize=9)
        axes[0].legend(fontsize=7)
        fig.tight_layout()
        path = out / f"sweep_{name}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths

"""The same flight on three vehicles: our simulator in PX4's dialect, our simulator in ArduCopter's
dialect, and ArduPilot's own ArduCopter SITL (when ``ARDUPILOT_SITL`` or ``--ardupilot-bin`` names
a binary). ``python -m bench.autopilots [--ardupilot-bin PATH] [--out FILE]``; also
``python -m bench.run --only autopilots``.

Each flies ``scenarios/ardupilot4.toml`` with the plain ``swarm up`` command on the default ports
(``--land-at-end``: it lands at the end), and is judged from its report: the worst centre and
spread errors in the two holds (gcs/report/holds.py), the tracking and consensus RMS after the
settling time (metrics.json), the minimum separation, the real-time factor, and for ArduCopter
SITL how long its vehicles took to be ready. docs/autopilots.md quotes the committed result,
bench/results_autopilots.json.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bench.provenance import write_result
from gcs.report.holds import window_errors

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "scenarios" / "ardupilot4.toml"
#: The scenario's holds (s): at 5 m before the move, and after it.
HOLDS = ((20.0, 23.0), (45.0, 53.0))


def fly(name: str, extra: Sequence[str], report: Path) -> dict[str, Any]:
    """One flight of the scenario with ``swarm up ... extra``; its row."""
    argv = [sys.executable, "-m", "gcs.cli", "up", str(SCENARIO), "--land-at-end",
            "--report", str(report), *extra]  # fmt: skip
    done = subprocess.run(
        argv, cwd=ROOT, env={**os.environ, "MAVLINK20": "1"}, capture_output=True, text=True,
        timeout=900,
    )  # fmt: skip
    if done.returncode != 0:
        return {"vehicle": name, "error": done.stderr.strip().splitlines()[-1:]}
    metrics = json.loads((report / "metrics.json").read_text())
    row: dict[str, Any] = {"vehicle": name}
    for k, (t0, t1) in enumerate(HOLDS):
        found = window_errors(report, range(4), t0, t1, n_drones=4)
        row[f"hold{k + 1}_centre_m"] = round(found.centre_m, 4)
        row[f"hold{k + 1}_spread_pct"] = round(100.0 * found.spread, 2)
    tracking = metrics["tracking"]
    row["centroid_rms_m"] = round(tracking["centroid_m"]["rms"], 4)
    row["heading_rms_deg"] = round(tracking["heading_deg"]["rms"], 3)
    row["consensus_rms_m"] = round(metrics["consensus"]["centroid_m"]["rms"], 4)
    row["min_separation_m"] = round(metrics["separation"]["min_m"], 2)
    row["real_time_factor"] = metrics.get("real_time_factor")
    ready = re.search(r"all \d+ vehicles ready after (\d+) s", done.stderr)
    row["ready_after_s"] = int(ready.group(1)) if ready else None
    return row


def autopilots(binary: str | None = None) -> dict[str, Any]:
    """Fly the three (the last only with a binary); rows as :func:`fly` makes them."""
    binary = binary or os.environ.get("ARDUPILOT_SITL") or None
    cases: list[tuple[str, list[str]]] = [
        ("our simulator, PX4 dialect (lockstep)", []),
        ("our simulator, ArduCopter dialect (lockstep)", ["--dialect", "ardupilot"]),
    ]
    if binary:
        cases.append(("ArduCopter SITL (real time)", ["--ardupilot-bin", binary]))
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-autopilots-") as tmp:
        for k, (name, extra) in enumerate(cases):
            rows.append(fly(name, extra, Path(tmp) / f"run{k}"))
            print(rows[-1], flush=True)
    return {
        "scenario": str(SCENARIO.relative_to(ROOT)),
        "holds_s": HOLDS,
        "ardupilot_binary": bool(binary),
        "rows": rows,
    }


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.autopilots", description=__doc__)
    parser.add_argument("--ardupilot-bin", default=None, help="arducopter (sitl board) to fly")
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "results_autopilots.json")
    args = parser.parse_args(argv)
    result = autopilots(args.ardupilot_bin)
    write_result(args.out, result, indent=2)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

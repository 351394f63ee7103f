"""The README's operator session, timed: ``python -m bench.session [--out FILE] [--repeats K]``;
also ``python -m bench.run --only session``.

Each run types what a newcomer types, in an empty folder with every default (default ports,
lockstep, the layout ``swarm up`` picks): ``swarm up --drones 16``, ``swarm takeoff --altitude-m
3`` once every agent is READY, ``swarm shutdown`` once the simulated time reaches 60 s, and
waits for ``swarm up`` to exit. Measured per run: the real-time factor from the take-off to the
shutdown (simulated over wall seconds), and the wall seconds from ``swarm shutdown`` to the end
of ``swarm up`` (the landing, then the report: tlog read, metrics, plots, flight.rrd). The
committed result is bench/results_session.json (median of the repeats, with the commit and the
machine's load).
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bench.provenance import commit, load_average, write_result

ROOT = Path(__file__).resolve().parents[1]
N_DRONES = 16
SESSION_S = 60.0
ENV = {**os.environ, "MAVLINK20": "1", "MPLBACKEND": "Agg"}


def _swarm(cwd: Path, *words: str) -> str:
    done = subprocess.run(
        [sys.executable, "-m", "gcs.cli", *words], cwd=cwd, env=ENV, capture_output=True,
        text=True, timeout=120,
    )  # fmt: skip
    return done.stdout


def _status(cwd: Path) -> tuple[float, list[str]]:
    """Simulated time and each drone's mode, from ``swarm status`` (-1 and [] without a reply)."""
    out = _swarm(cwd, "status")
    found = re.search(r"t = ([-\d.]+) s", out)
    if found is None:
        return -1.0, []
    rows = [line.split() for line in out.splitlines()[2:]]
    modes = [w[2] for w in rows if len(w) > 3 and w[0].isdigit()]
    return float(found.group(1)), modes


def one_session(cwd: Path) -> dict[str, Any]:
    """One session in ``cwd``; its row."""
    with (cwd / "swarm-up.out").open("wb") as sink:
        up = subprocess.Popen(
            [sys.executable, "-m", "gcs.cli", "up", "--drones", str(N_DRONES)],
            cwd=cwd, env=ENV, stdout=sink, stderr=subprocess.STDOUT,
        )  # fmt: skip
        try:
            started = time.monotonic()
            while True:
                t_s, modes = _status(cwd)
                if len(modes) == N_DRONES and all(m == "READY" for m in modes):
                    break
                if up.poll() is not None or time.monotonic() - started > 300:
                    return {"error": "no READY swarm"}
                time.sleep(0.5)
            t_takeoff, wall_takeoff = t_s, time.monotonic()
            _swarm(cwd, "takeoff", "--altitude-m", "3")
            while t_s < SESSION_S:
                time.sleep(0.5)
                t_s, _ = _status(cwd)
            wall_shutdown = time.monotonic()
            rtf = (t_s - t_takeoff) / (wall_shutdown - wall_takeoff)
            _swarm(cwd, "shutdown")
            code = up.wait(600)
            after = time.monotonic() - wall_shutdown
        finally:
            if up.poll() is None:
                up.kill()
                up.wait()
    return {
        "exit_code": code,
        "real_time_factor_flying": round(rtf, 2),
        # the session as its user lives it: simulated time over wall time from the command
        "real_time_factor_whole": round(t_s / (wall_shutdown - started), 2),
        "shutdown_to_exit_s": round(after, 2),
        "started_to_ready_s": round(wall_takeoff - started, 2),
    }


def session(repeats: int = 3) -> dict[str, Any]:
    rows = []
    for _ in range(repeats):
        with tempfile.TemporaryDirectory(prefix="bench-session-") as tmp:
            rows.append(one_session(Path(tmp)))
            print(rows[-1], flush=True)
    good = [r for r in rows if "error" not in r]
    median = {
        key: statistics.median(r[key] for r in good)
        for key in ("real_time_factor_flying", "shutdown_to_exit_s", "started_to_ready_s")
    } if good else {}  # fmt: skip
    return {
        "what": f"swarm up --drones {N_DRONES}, takeoff, shutdown at t = {SESSION_S:g} s",
        "commit": commit(),
        "load_average": load_average(),
        "cores": os.cpu_count(),
        "median": median,
        "rows": rows,
    }


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.session", description=__doc__)
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "results_session.json")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    result = session(args.repeats)
    write_result(args.out, result, indent=2)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The paper's controller beside examples/pd_controller.py on the paper's flight, in both runners:
``python -m bench.controllers [--duration-s S]``.

Flies ``scenarios/paper.toml`` (the paper's controller) and ``examples/pd_paper.toml`` (the same
flight, ``[agent] controller = "pd_controller:PDFormation"``) with ``swarm simulate`` and with
``swarm up --clock lockstep`` (free ports, a Zenoh peer and a swarm id of its own, so it runs
beside anything), and reads each report's metrics.json: steady tracking of the centre, the shape
and the heading (RMS after the settling time, leaving out the 10 s after the drone is lost),
the consensus error, the fault that hit the formation hardest (the drone lost: its peak shape
error and the time until the formation was back, metrics.json's re-convergence), the minimum
separation, the largest tilt and the setpoints refused (what
``swarm simulate`` counts; ``swarm up``'s report has no count: –); and
how far the two runners' flights are apart (largest LOCAL_POSITION_NED gap of any drone the
scenario does not lose). Writes ``bench/results_controllers.json`` and prints a Markdown table
(docs/controllers.md quotes it).
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bench.provenance import write_result
from bench.runners_gap import ROOT, _swarm, gaps
from bench.sitl import _free_block
from protocols.bus.zenoh_bus import ZenohBus, ZenohSettings, free_loopback_endpoint
from protocols.faults import Crash, Dropout
from protocols.scenario.scenario_file import load_scenario

OUT_JSON = ROOT / "bench" / "results_controllers.json"
FLIGHTS = (
    ("paper's (CooperativeController)", ROOT / "scenarios" / "paper.toml"),
    ("examples/pd_controller.py (PDFormation)", ROOT / "examples" / "pd_paper.toml"),
)


def figures(metrics: dict[str, Any]) -> dict[str, Any]:
    """The figures of one report's metrics.json this bench compares."""
    steady = metrics["tracking_steady"]
    # the fault that hit the formation hardest (the paper's flight: the drone lost at 30 s)
    worst = max(metrics["reconvergence"], key=lambda r: r["peak_centroid_error_m"] or 0.0)
    return {
        "centroid_rms_m": steady["centroid_m"]["rms"],
        "shape_rms_m2": steady["shape_m2"]["rms"],
        "heading_rms_deg": steady["heading_deg"]["rms"],
        "consensus_rms_m": metrics["consensus_steady"]["centroid_m"]["rms"],
        "min_separation_m": metrics["separation"]["min_m"],
        "max_tilt_deg": metrics["max_tilt_deg"]["value"],
        "collisions": metrics["collisions"]["count"],
        "rejected_setpoints": metrics.get("rejected_setpoints"),
        "worst_fault": worst["description"],
        "worst_fault_peak_shape_m2": worst["peak_shape_error_m2"],
        "worst_fault_reconverge_s": worst["time_to_reconverge_s"],
    }


def fly(scenario: Path, work: Path, endpoint: str, duration_s: float | None) -> dict[str, Any]:
    """Both runners' figures for ``scenario``, flown in ``work``, and the gap between them."""
    extra = ["--duration-s", str(duration_s)] if duration_s else []
    spec = load_scenario(scenario)
    lost = {f.drone + 1 for f in spec.faults if isinstance(f, Dropout | Crash)}
    sim_s = _swarm("simulate", str(scenario), "--report", "sim", "--no-plots", *extra, cwd=work)
    base, gcs_port = _free_block(spec.n_drones), _free_block(1)
    up_s = _swarm(
        *("up", str(scenario), "--clock", "lockstep", "--report", "up", *extra),
        *("--base-port", str(base), "--gcs-port", str(gcs_port)),
        *("--swarm-id", f"ctl{os.getpid()}", "--zenoh-connect", endpoint),
        cwd=work,
    )
    per = gaps(work / "sim" / "flight.tlog", work / "up" / "flight.tlog")
    out: dict[str, Any] = {"simulate_wall_s": round(sim_s, 1), "up_wall_s": round(up_s, 1)}
    for runner in ("sim", "up"):
        metrics = json.loads((work / runner / "metrics.json").read_text())
        out[runner] = figures(metrics)
    out["runners_max_gap_m"] = max((g[0] for s, g in per.items() if s not in lost), default=None)
    return out


def table(results: dict[str, Any]) -> list[str]:
    """The Markdown table of ``results`` (one row per controller and runner)."""
    lines = [
        "| controller | runner | centre RMS (m) | shape RMS (m²) | heading RMS (deg) "
        "| after the loss: peak shape error (m²), back in (s) "
        "| min separation (m) | max tilt (deg) | refused setpoints |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, flight in results["flights"].items():
        for runner, label in (("sim", "swarm simulate"), ("up", "swarm up (lockstep)")):
            f = flight[runner]
            refused = "–" if f["rejected_setpoints"] is None else f["rejected_setpoints"]
            lines.append(
                f"| {name} | {label} | {f['centroid_rms_m']:.4f} | {f['shape_rms_m2']:.4f} "
                f"| {f['heading_rms_deg']:.3f} "
                f"| {_n(f['worst_fault_peak_shape_m2'])}, {_s(f['worst_fault_reconverge_s'])} "
                f"| {f['min_separation_m']:.2f} "
                f"| {f['max_tilt_deg']:.1f} | {refused} |"
            )
    return lines


def _n(value: float | None) -> str:
    return "–" if value is None else f"{value:.2f}"


def _s(seconds: float | None) -> str:
    return "–" if seconds is None else f"{seconds:.1f}"


def main(argv: Sequence[str] | None = None) -> int:
    """CLI entry point (module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration-s", type=float, default=None)
    parser.add_argument("--out", type=Path, default=OUT_JSON)
    args = parser.parse_args(argv)
    results: dict[str, Any] = {"load_1min_at_start": round(os.getloadavg()[0], 2), "flights": {}}
    endpoint = free_loopback_endpoint()
    with ZenohBus.open(ZenohSettings(listen=(endpoint,))), tempfile.TemporaryDirectory() as tmp:
        for k, (name, scenario) in enumerate(FLIGHTS):
            work = Path(tmp) / str(k)
            work.mkdir()
            flight = fly(scenario, work, endpoint, args.duration_s)
            flight["scenario"] = str(scenario.relative_to(ROOT))
            results["flights"][name] = flight
    for line in table(results):
        print(line)
    gaps_m = {name: f["runners_max_gap_m"] for name, f in results["flights"].items()}
    print(f"largest gap between the runners' flights (drones not lost), m: {gaps_m}")
    write_result(args.out, results, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""``swarm sweep``: fly a grid of in-process flights of one scenario, varying factors, and say
where the swarm stops holding (gcs/reference/sweep.py)."""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

EPILOG = """examples:
  swarm sweep scenarios/paper.toml --vary wind_m_s=0,1,2,3,4 --seeds 2 --out sweep
  swarm sweep scenarios/tilt9.toml --vary wind_m_s=0,3 --vary turbulence_m_s=0,1 --out sw

factors (--vary NAME=V1,V2,...):
  wind_m_s             the mean wind's speed, m/s (from the scenario's direction, else from
                       the west; a scenario without drag gets a small quadcopter's)
  wind_from_deg        the compass direction the wind blows from, deg
  turbulence_m_s       the gusts' intensity, m/s
  turbulence_scale_m   the gusts' length scale, m
  drag_xy_per_s        the vehicles' drag in their x-y plane, 1/s
  mass_spread          how the vehicles' masses differ (relative, 1 sigma; 0.05: 5 %)
  thrust_spread        how the vehicles' rotor thrust differs (relative, 1 sigma)
  motor_tau_s          the motors' time constant (rotor speed lag), s (0: none)
  loss                 packet loss on every link, from the start (0..0.99)
  gnss_bias_m          the vehicles' wandering GNSS position bias, m (1 sigma)
  position_noise_m     white noise on the vehicles' position estimates, m
  estimate_latency_s   how late the vehicles' state estimates are, s
  estimate_rate_hz     how often the state estimates are refreshed, Hz (0: every tick)
  altitude_bias_m      the vehicles' wandering height bias, m (1 sigma)
  velocity_noise_m_s   white noise on the vehicles' velocity estimates, m/s
  bandwidth_bytes_s    each radio link's capacity, bytes/s (0: unlimited)
  loss_half_m          the distance at which the radio loses half the messages, m
  burst_fraction       the share of messages in the radio's loss bursts (0..0.99)
  radio_latency_s      the radio's added latency, s
  jitter_s             the radio's mean random extra delay, s

Each flight is `swarm simulate`'s, into OUT/<factors>_seed=<k>/ (no plots); OUT gets sweep.json
(a row per flight: its factors, seed and figures), sweep.md (a table per factor) and a plot per
factor of the bars' figures against it, with where each bar first breaks."""


class SweepCliError(Exception):
    """A user mistake, said in one line."""


def add_parser(sub: Any) -> None:
    # (the factors are listed here, not read from gcs.reference.sweep: building the parsers
    # imports no machinery; tests/test_sweep.py checks the two agree)
    p = sub.add_parser(
        "sweep",
        help="how far the swarm holds: fly a grid of factor values in process, plot the bars",
        description="Fly a scenario in process once per combination of the factors' values "
        "and seed, in parallel, and write each flight's figures, a table and plots.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("scenario", type=Path, help="scenario file (TOML), e.g. scenarios/paper.toml")
    p.add_argument("--vary", action="append", default=[], metavar="NAME=V1,V2,...",
                   help="a factor and its values (repeat for more factors)")  # fmt: skip
    p.add_argument("--seeds", type=int, default=1, metavar="K",
                   help="flights per combination, seeds S..S+K-1 (default 1)")  # fmt: skip
    p.add_argument("--seed", type=int, default=None, metavar="S",
                   help="the first seed (default: the scenario's)")  # fmt: skip
    p.add_argument("--duration-s", type=float, default=None, metavar="S",
                   help="fly only the first S seconds of the scenario")  # fmt: skip
    p.add_argument("--jobs", type=int, default=None, metavar="J",
                   help="flights at once (default: the machine's cores)")  # fmt: skip
    p.add_argument("--out", type=Path, required=True, metavar="DIR",
                   help="folder for the flights, sweep.json, sweep.md and the plots")  # fmt: skip


def run(args: argparse.Namespace, argv: Sequence[str] | None = None) -> int:
    from gcs.reference.sweep import SweepError, grid, parse_vary
    from protocols.scenario.scenario_file import ScenarioError, load_scenario

    try:
        vary = parse_vary(args.vary)
    except SweepError as exc:
        raise SweepCliError(str(exc)) from None
    if args.seeds < 1:
        raise SweepCliError(f"--seeds must be at least 1, got {args.seeds}")
    jobs = args.jobs if args.jobs is not None else os.cpu_count() or 1
    if jobs < 1:
        raise SweepCliError(f"--jobs must be at least 1, got {args.jobs}")
    try:
        base = load_scenario(args.scenario)
    except ScenarioError as exc:
        raise SweepCliError(str(exc)) from None
    if args.duration_s is not None and not base.settle_s < args.duration_s <= base.duration_s:
        raise SweepCliError(
            f"--duration-s must be in ({base.settle_s:g}, {base.duration_s:g}]: the figures are "
            f"judged from the scenario's settle_s ({base.settle_s:g} s) on"
        )
    runs = grid(vary, args.seeds, base.seed if args.seed is None else args.seed)
    try:  # every run's scenario must validate before any flies
        for r in runs:
            _check(r.scenario(base, args.duration_s))
    except (ScenarioError, ValueError) as exc:
        raise SweepCliError(str(exc)) from None
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SweepCliError(f"--out {args.out}: cannot create it: {exc.strerror or exc}") from None
    print(f"swarm sweep: {len(runs)} flights of {base.name} on {min(jobs, len(runs))} "
          f"process(es) into {args.out}", file=sys.stderr)  # fmt: skip
    rows = _fly_all(runs, base, args.duration_s, args.out, jobs)
    from gcs.report.sweep_report import write_sweep

    command = "swarm " + shlex.join(list(argv) if argv is not None else sys.argv[1:])
    files = write_sweep(args.out, str(args.scenario), vary, rows, command)
    print((args.out / "sweep.md").read_text())
    print("wrote " + ", ".join(str(f) for f in files))
    return 0


def _check(scenario: Any) -> None:
    """The run's scenario as a file would be checked (its air and vehicle)."""
    from sitl_sim.vehicle.config import air, vehicle_params

    air(scenario)
    vehicle_params(scenario)


def _fly_all(runs: list[Any], base: Any, duration_s: float | None, out: Path, jobs: int) -> list:
    from gcs.reference.sweep import fly

    rows: list[dict[str, Any]] = []
    if jobs == 1 or len(runs) == 1:
        for k, r in enumerate(runs, 1):
            rows.append(fly(r, base, duration_s, out))
            print(f"  {k}/{len(runs)} {r.name}", file=sys.stderr)
        return rows
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    # spawn: no fork of a process that may hold threads (numba, a Zenoh session elsewhere)
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=min(jobs, len(runs)), mp_context=context) as pool:
        futures = [pool.submit(fly, r, base, duration_s, out) for r in runs]
        for k, (r, f) in enumerate(zip(runs, futures, strict=True), 1):
            rows.append(f.result())
            print(f"  {k}/{len(runs)} {r.name}", file=sys.stderr)
    return rows

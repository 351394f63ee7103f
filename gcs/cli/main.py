"""The ``swarm`` command line. User mistakes end with a one-line error and exit code 2."""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

os.environ.setdefault("MAVLINK20", "1")  # before anything imports pymavlink

from drone_agent.process.agent_cli import add_parser as add_agent_parser
from gcs.cli.drill import add_parser as add_drill_parser
from gcs.cli.drills import add_parser as add_drills_parser
from gcs.cli.gcs import add_parser as add_gcs_parser
from gcs.cli.keys import add_parser as add_keys_parser
from gcs.cli.operator import OPERATOR_COMMANDS
from gcs.cli.operator import add_parsers as add_operator_parsers
from gcs.cli.router import add_parser as add_router_parser
from gcs.cli.scenario import add_parser as add_scenario_parser
from gcs.cli.sweep import add_parser as add_sweep_parser
from gcs.cli.up import add_parsers as add_up_parsers
from gcs.cli.view import VIEW_COMMANDS
from gcs.cli.view import add_parsers as add_view_parsers
from sitl_sim.sim_cli import add_sim_parser

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


class CliError(Exception):
    """A user mistake: printed as one line, exit code 2."""


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="swarm",
        description=(
            "quadswarm: fly a quadcopter swarm as one body. Each drone estimates the swarm's "
            "centre, orientation and shape from its neighbours (consensus) and steers itself so "
            "the whole swarm follows one shared descriptor trajectory."
        ),
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sim = sub.add_parser(
        "simulate",
        help="fly a scenario in one process (no network) and write a report",
        description=(
            "Fly a scenario with every vehicle, agent and radio link in one process, through the "
            "same estimator and controllers as the distributed system, with the scenario's faults "
            "(drop-outs, crashes, link cuts, loss, delay). Writes flight.tlog (MAVLink 2), "
            "events.jsonl, metrics.json, trajectory.json, PNG plots and, with Rerun installed, "
            "flight.rrd (swarm replay opens it) into the report folder."
        ),
    )
    sim.add_argument("scenario", type=Path, help="scenario file (TOML), e.g. scenarios/paper.toml")
    sim.add_argument(
        "--report",
        type=Path,
        default=Path("report"),
        metavar="DIR",
        help="report folder, created if missing (default: ./report)",
    )
    sim.add_argument(
        "--duration-s", type=float, metavar="S", help="fly only the first S seconds of the scenario"
    )
    sim.add_argument("--seed", type=int, help="override the scenario's random seed")
    sim.add_argument(
        "--tlog-hz",
        type=float,
        default=25.0,
        metavar="HZ",
        help="telemetry rate written to flight.tlog (default 25, at least 10)",
    )
    sim.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    sim.add_argument(
        "--no-recording",
        action="store_true",
        help="skip flight.rrd (~1 s for a short flight; swarm replay makes it from the tlog "
        "when it opens the report)",
    )
    sim.add_argument(
        "--progress",
        choices=("auto", "on", "off"),
        default="auto",
        help="progress bar on stderr (auto: only on a terminal)",
    )
    add_sim_parser(sub)
    add_agent_parser(sub)
    add_gcs_parser(sub)
    add_operator_parsers(sub)
    add_up_parsers(sub)
    add_drill_parser(sub)
    add_drills_parser(sub)
    add_scenario_parser(sub)
    add_view_parsers(sub)
    add_router_parser(sub)
    add_keys_parser(sub)
    add_sweep_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``swarm`` console command."""
    parser = _parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return EXIT_USAGE
    try:
        if args.command == "simulate":
            return _simulate(args)
        if args.command == "sim":
            return _sim(args)
        if args.command == "agent":
            return _agent(args)
        if args.command == "gcs":
            return _gcs(args)
        if args.command in OPERATOR_COMMANDS:
            return _operator(args)
        if args.command in ("up", "demo"):
            return _up(args)
        if args.command == "drill":
            return _drill(args)
        if args.command == "drills":
            return _drills(args)
        if args.command == "scenario":
            return _scenario(args)
        if args.command in VIEW_COMMANDS:
            return _view(args)
        if args.command == "router":
            return _router(args)
        if args.command == "keys":
            return _keys(args)
        if args.command == "sweep":
            return _sweep(args, argv)
    except CliError as exc:
        print(f"swarm: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("swarm: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    parser.print_help()
    return EXIT_USAGE


def _up(args: argparse.Namespace) -> int:
    from gcs.cli.supervisor import SupervisorError
    from gcs.cli.up import run

    try:
        return run(args)
    except SupervisorError as exc:
        raise CliError(str(exc)) from None


def _simulate(args: argparse.Namespace) -> int:
    from drone_agent.core.config import agent_config
    from gcs.cli.compiled import warm_compiled
    from gcs.reference.simulate import simulate
    from gcs.report.summary import summary_lines
    from protocols.scenario.scenario_file import ScenarioError, load_scenario

    try:
        scenario = load_scenario(args.scenario)
        agent_config(scenario)  # its [agent] controller found and tried once
    except ScenarioError as exc:
        raise CliError(str(exc)) from None
    if args.duration_s is not None:
        if not 0 < args.duration_s <= scenario.duration_s:
            raise CliError(f"--duration-s must be in (0, {scenario.duration_s:g}]")
        scenario = dataclasses.replace(scenario, duration_s=args.duration_s)
    if args.seed is not None:
        scenario = dataclasses.replace(scenario, seed=args.seed)
    if not 10.0 <= args.tlog_hz <= scenario.rates.control_hz:
        raise CliError(
            f"--tlog-hz must be between 10 and the control rate ({scenario.rates.control_hz} Hz)"
        )
    _check_writable(args.report)
    warm_compiled("swarm simulate", True, True, Path(args.scenario))
    show = args.progress == "on" or (args.progress == "auto" and sys.stderr.isatty())
    bar: Any = None
    if show:
        from tqdm import tqdm

        bar = tqdm(
            total=round(scenario.duration_s),
            unit="sim s",
            desc=scenario.name,
            file=sys.stderr,
            bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.0f}/"
            "{total:.0f} sim s [{elapsed}<{remaining}, {rate_fmt}]",
        )

    def progress(t_s: float) -> None:
        if bar is not None and t_s - bar.n >= 1.0:
            bar.update(int(t_s - bar.n))

    try:
        result = simulate(
            scenario,
            args.report,
            progress,
            tlog_hz=args.tlog_hz,
            plots=not args.no_plots,
            recording=not args.no_recording,
        )
    finally:
        if bar is not None:
            bar.close()
    for line in summary_lines(result.metrics, result.files):
        print(line)
    return 0


def _sim(args: argparse.Namespace) -> int:
    from sitl_sim.sim_cli import run_sim
    from sitl_sim.sim_config import SimConfigError

    try:
        return run_sim(args)
    except SimConfigError as exc:
        raise CliError(str(exc)) from None


def _agent(args: argparse.Namespace) -> int:
    from drone_agent.process.agent_cli import AgentCliError, run

    try:
        return run(args)
    except AgentCliError as exc:
        raise CliError(str(exc)) from None


def _gcs(args: argparse.Namespace) -> int:
    from gcs.cli.gcs import GcsCliError, run

    _check_writable(args.report)
    try:
        return run(args)
    except GcsCliError as exc:
        raise CliError(str(exc)) from None


def _operator(args: argparse.Namespace) -> int:
    from gcs.cli.operator import OperatorError, run

    try:
        return run(args)
    except OperatorError as exc:
        raise CliError(str(exc)) from None


def _drill(args: argparse.Namespace) -> int:
    from gcs.cli.drill import DrillError, run

    try:
        return run(args)
    except DrillError as exc:
        raise CliError(str(exc)) from None


def _drills(args: argparse.Namespace) -> int:
    from gcs.cli.drills import DrillsError, run

    try:
        return run(args)
    except DrillsError as exc:
        raise CliError(str(exc)) from None


def _scenario(args: argparse.Namespace) -> int:
    from gcs.cli.scenario import ScenarioCliError, run

    try:
        return run(args)
    except ScenarioCliError as exc:
        raise CliError(str(exc)) from None


def _view(args: argparse.Namespace) -> int:
    from gcs.cli.view import ViewError, run

    try:
        return run(args)
    except ViewError as exc:
        raise CliError(str(exc)) from None


def _router(args: argparse.Namespace) -> int:
    from gcs.cli.router import RouterError, run

    try:
        return run(args)
    except RouterError as exc:
        raise CliError(str(exc)) from None


def _keys(args: argparse.Namespace) -> int:
    from gcs.cli.keys import KeysError, run

    try:
        return run(args)
    except KeysError as exc:
        raise CliError(str(exc)) from None


def _sweep(args: argparse.Namespace, argv: Sequence[str] | None) -> int:
    from gcs.cli.sweep import SweepCliError, run

    try:
        return run(args, argv)
    except SweepCliError as exc:
        raise CliError(str(exc)) from None


def _check_writable(report: Path) -> None:
    try:
        report.mkdir(parents=True, exist_ok=True)
        probe = report / ".write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise CliError(f"cannot write the report folder {report}: {exc.strerror or exc}") from None


if __name__ == "__main__":
    raise SystemExit(main())

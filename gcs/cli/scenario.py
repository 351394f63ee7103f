"""``swarm scenario new`` and ``swarm scenario check``: write a scenario from a few options, and
validate and sum up a scenario file. Exit codes: 0 done, 2 a mistake (one line naming the field
or option; never a traceback)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from protocols.scenario.layout_names import LAYOUTS
from protocols.scenario.outdoor import BREEZE_M_S, GUSTS_M_S, OUTDOOR_SENSORS

TEMPLATE_HELP = (
    "hover: take off and hold; "
    "paper: the paper's style, forward along north at 1 m/s while the width breathes; "
    "survey: a lawnmower sweep of the centre (20 m legs along north, one swarm width apart); "
    "turn-and-stretch: hold, then a 20 m move north with a 30 deg turn and a 15 %% stretch, hold"
)


class ScenarioCliError(Exception):
    """A mistake in the options or the file: one line, exit code 2."""


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``swarm scenario`` with its ``new`` and ``check`` commands."""
    p = sub.add_parser(
        "scenario",
        help="write a scenario from a few options (new), or validate and sum one up (check)",
        description=(
            "Scenario files (TOML) say where the drones start, the plan of the swarm's centre, "
            "heading and spreads, and the faults to inject. 'new' writes one from a layout, a "
            "manoeuvre template and a list of faults; 'check' validates one and sums it up."
        ),
    )
    cmds = p.add_subparsers(dest="scenario_command", metavar="new|check", required=True)
    new = cmds.add_parser(
        "new",
        help="generate a validated, commented scenario file",
        description=(
            "Generate a scenario: N drones on the ground in a layout, the consensus warm-up, a "
            "rest-to-rest climb, then a manoeuvre template, with faults at sensible times. The "
            "file is validated before it is written (formations keep [safety] "
            "min_separation_m, the radio graph at the start is connected, the plan stays inside "
            "the ground station's geofence) and records this command at its top. Example: "
            "swarm scenario new --drones 25 --layout grid --faults dropout,crash,loss -o g.toml"
        ),
    )
    new.add_argument("--drones", type=int, required=True, metavar="N", help="2..250 drones")
    new.add_argument(
        "--layout",
        choices=LAYOUTS,
        default="grid",
        help="where they start: grid (rows along east), line (along north), circle (a ring), "
        "random (a seeded Poisson-disc blob, connected at the radio range); default grid",
    )
    new.add_argument(
        "--spacing-m",
        type=float,
        default=2.5,
        metavar="M",
        help="distance between neighbouring drones on the ground, m (the least for random; "
        "default 2.5)",
    )
    new.add_argument(
        "--range-m",
        type=float,
        default=6.0,
        metavar="M",
        help="radio range, m: drones closer than this hear each other (default 6)",
    )
    new.add_argument(
        "--template",
        choices=("hover", "paper", "survey", "turn-and-stretch"),
        default="turn-and-stretch",
        help=f"the manoeuvre (default turn-and-stretch). {TEMPLATE_HELP}",
    )
    new.add_argument(
        "--faults",
        default="",
        metavar="LIST",
        help="comma list of dropout[=K] (K agents die after take-off), crash[=K] (K vehicles' "
        "motors stop mid-manoeuvre), loss[=P] (every link loses a share P, default 0.2, from the "
        "end of the climb); e.g. dropout,crash,loss. Default: none",
    )
    new.add_argument(
        "--duration-s",
        type=float,
        metavar="S",
        help="simulated seconds (default: what the template needs, plus a hold)",
    )
    new.add_argument(
        "--altitude-m",
        type=float,
        metavar="M",
        help="flight altitude, m above the ground (default 3; 5 for paper)",
    )
    new.add_argument(
        "--min-separation-m",
        type=float,
        default=1.0,
        metavar="M",
        help="[safety] min_separation_m: every formation of the plan must keep the drones this "
        "far apart (default 1)",
    )
    new.add_argument(
        "--wind",
        metavar="SPEED@FROM",
        help="a steady wind: speed m/s and the compass direction it blows from, deg (e.g. "
        "3@270: 3 m/s from the west); adds the vehicles' drag (default: still air)",
    )
    new.add_argument(
        "--turbulence",
        type=float,
        default=0.0,
        metavar="M_S",
        help="gusts' intensity, m/s (each component's standard deviation; e.g. 0.5)",
    )
    new.add_argument(
        "--outdoor",
        choices=OUTDOOR_SENSORS,
        help="a small quadcopter outdoors (docs/scenarios.md cites the values): vehicles 2 %% "
        "apart in mass, a 1 Mbit/s class radio with loss, bursts and jitter, each vehicle on its "
        "EKF's estimate with an RTK GNSS (rtk: 2 cm) or a consumer one (gnss: 2 m that wanders); "
        "and, without --wind, a light breeze (3 m/s from the west, 0.5 m/s gusts). Default: "
        "ideal vehicles, sensors and radio",
    )
    new.add_argument("--seed", type=int, default=0, help="random seed: random layout, fault "
                     "drones, and the run's own draws (default 0)")  # fmt: skip
    new.add_argument("--name", help="the scenario's name (default TEMPLATE-LAYOUTN)")
    new.add_argument(
        "-o",
        "--output",
        type=Path,
        metavar="FILE",
        help="write the scenario here and print its summary (default: print the TOML)",
    )
    new.add_argument("--force", action="store_true", help="overwrite FILE if it exists")
    check = cmds.add_parser(
        "check",
        help="validate a scenario file and print a summary",
        description=(
            "Validate a scenario file and print what it flies: drones and their closest spacing, "
            "duration, the radio graph at the start (connected? neighbours per drone), the "
            "closest two drones in the plan's formations, faults and waypoints. A mistake is one "
            "line naming the file and the field, exit code 2."
        ),
    )
    check.add_argument("file", type=Path, help="scenario file (TOML), e.g. scenarios/grid16.toml")


def run(args: argparse.Namespace) -> int:
    """Carry out ``swarm scenario new`` or ``check``; ScenarioCliError for a user mistake."""
    if args.scenario_command == "new":
        return _new(args)
    return _check(args.file)


def _new(args: argparse.Namespace) -> int:
    from gcs.report.scenario_summary import envelope_problem, summary_lines
    from protocols.scenario.generator import (
        GeneratorError,
        GeneratorOptions,
        generate,
        parse_faults,
    )

    out: Path | None = args.output
    if out is not None and out.exists() and not args.force:
        raise ScenarioCliError(f"{out} exists; give --force to overwrite it")
    try:
        options = GeneratorOptions(
            drones=args.drones,
            layout=args.layout,
            spacing_m=args.spacing_m,
            range_m=args.range_m,
            template=args.template,
            faults=parse_faults(args.faults),
            duration_s=args.duration_s,
            seed=args.seed,
            altitude_m=args.altitude_m,
            min_separation_m=args.min_separation_m,
            name=args.name,
            **_air(args.wind, args.turbulence, args.outdoor),
            outdoor=args.outdoor,
        )
        generated = generate(options, None if out is None else str(out))
    except GeneratorError as exc:
        raise ScenarioCliError(_as_flag(str(exc))) from None
    problem = envelope_problem(generated.scenario)
    if problem is not None:
        raise ScenarioCliError(f"the plan leaves the ground station's envelope {problem}")
    if out is None:
        sys.stdout.write(generated.text)
        return 0
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(generated.text, encoding="utf-8")
    except OSError as exc:
        raise ScenarioCliError(f"cannot write {out}: {exc.strerror or exc}") from None
    print(f"wrote {out}")
    for line in summary_lines(generated.scenario):
        print(line)
    return 0


def _as_flag(message: str) -> str:
    """``spacing_m: ...`` (the generator names its options) -> ``--spacing-m: ...``."""
    name, sep, rest = message.partition(": ")
    if sep and name.isidentifier():
        return f"--{name.replace('_', '-')}: {rest}"
    return message


def _check(path: Path) -> int:
    from drone_agent.core.config import agent_config
    from gcs.report.scenario_summary import envelope_problem, summary_lines, takeoff_lines
    from protocols.scenario.scenario_file import ScenarioError, load_scenario

    try:
        scenario = load_scenario(path)
        agent_config(scenario)  # its [agent] controller found and tried once
    except ScenarioError as exc:
        raise ScenarioCliError(str(exc)) from None
    problem = envelope_problem(scenario)
    if problem is not None:
        raise ScenarioCliError(
            f"{path}: trajectory.waypoints: the plan leaves the ground station's envelope {problem}"
        )
    for line in summary_lines(scenario):
        print(line)
    print("take-off   measuring when the swarm is ready (flying it in process) ...", flush=True)
    from gcs.reference.simulate import READY_LIMIT_S, ready_time_s

    for line in takeoff_lines(scenario, ready_time_s(scenario), READY_LIMIT_S):
        print(line)
    return 0


def _air(wind: str | None, turbulence: float, outdoor: str | None) -> dict[str, float]:
    """The generator's wind and gusts: ``--wind`` and ``--turbulence``; outdoors without a
    ``--wind``, a light breeze and its gusts (protocols/scenario/outdoor.py)."""
    if outdoor is not None and wind is None:
        gusts = turbulence if turbulence > 0.0 else GUSTS_M_S
        return {"wind_m_s": BREEZE_M_S, "wind_from_deg": 270.0, "turbulence_m_s": gusts}
    return {**_wind(wind), "turbulence_m_s": turbulence}


def _wind(text: str | None) -> dict[str, float]:
    """``--wind SPEED@FROM`` as the generator's options (speed m/s, from deg)."""
    from protocols.scenario.generator import GeneratorError

    if text is None:
        return {}
    speed, _, frm = text.partition("@")
    try:
        wind_m_s, wind_from_deg = float(speed), float(frm or 270.0)
    except ValueError:
        raise GeneratorError(
            f"--wind {text!r}: expected SPEED@FROM, m/s and degrees (e.g. 3@270)"
        ) from None
    return {"wind_m_s": wind_m_s, "wind_from_deg": wind_from_deg}

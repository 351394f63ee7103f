"""Scenario generator behind ``swarm scenario new``: options in, a commented TOML scenario out.

Pure: no files, no clock; randomness comes from ``numpy.random.default_rng(seed)``.
:func:`generate` lays the drones out (protocols/scenario/layout.py), writes the plan of a
manoeuvre template as waypoints of the scenario file's own fields, places the requested faults,
renders a TOML text with a comment on every section (the generator's command line at the top) and
validates it through :func:`protocols.scenario.scenario_file.parse_scenario`, so what it returns
always loads.

The plans of the manoeuvre templates (hover, paper, survey, turn-and-stretch) are
protocols/scenario/templates.py's.

Faults (``--faults``, a comma list of ``dropout[=K]``, ``crash[=K]``, ``loss[=P]``): K agents die
(their vehicles fail safe and land) 2 s apart from 2 s after the climb, K vehicles crash 2 s apart
from the middle of the manoeuvre, and every link loses a share P (default 0.2) of its messages
from the end of the climb to the end. Drones to lose are drawn with the seed among those whose
loss leaves the radio graph at the start connected.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from protocols.model.frames import FloatArray
from protocols.scenario.layout import (
    LAYOUTS,
    LayoutError,
    is_cut_free,
    layout_positions,
    min_spacing,
    radio_graph,
)
from protocols.scenario.outdoor import OUTDOOR_SENSORS, VEHICLE, outdoor_lines
from protocols.scenario.scenario_file import MAX_DRONES, MIN_DRONES, Scenario, parse_scenario
from protocols.scenario.templates import (
    SESSION_TEMPLATE,
    TEMPLATES,
    GeneratorError,
    Plan,
    PlanRequest,
    build_plan,
)

__all__ = [
    "TEMPLATES",
    "FaultRequest",
    "Generated",
    "GeneratorError",
    "GeneratorOptions",
    "generate",
    "parse_faults",
]

FAULT_KINDS = ("dropout", "crash", "loss")
DEFAULT_LOSS = 0.2


@dataclass(frozen=True)
class FaultRequest:
    """How many agents drop out and vehicles crash, and the packet loss on every link (0: none)."""

    dropouts: int = 0
    crashes: int = 0
    loss: float = 0.0

    def spec(self) -> str:
        """Back to the ``--faults`` syntax (empty when no fault)."""
        parts = [f"dropout={self.dropouts}"] if self.dropouts else []
        parts += [f"crash={self.crashes}"] if self.crashes else []
        parts += [f"loss={self.loss:g}"] if self.loss else []
        return ",".join(parts)


def parse_faults(text: str) -> FaultRequest:
    """``dropout,crash,loss`` -> one of each, 20 % loss; ``dropouts=2,loss=0.3``; ``none`` / ``""``.

    Raises GeneratorError naming ``faults`` for an unknown kind or a bad count or share.
    """
    counts = {"dropout": 0, "crash": 0}
    loss = 0.0
    for raw in (p.strip() for p in text.split(",")):
        if not raw or raw == "none":
            continue
        name, _, value = raw.partition("=")
        kind = {"dropouts": "dropout", "crashes": "crash"}.get(name.strip(), name.strip())
        if kind not in FAULT_KINDS:
            raise GeneratorError(
                f"faults: '{name}' is not a fault kind (one of: {', '.join(FAULT_KINDS)})"
            )
        try:
            number = float(value) if value else None
        except ValueError:
            raise GeneratorError(f"faults: '{raw}': '{value}' is not a number") from None
        if kind == "loss":
            loss = DEFAULT_LOSS if number is None else number
            if not 0 < loss < 1:
                raise GeneratorError(f"faults: '{raw}': the loss share must be in (0, 1)")
        else:
            k = 1 if number is None else number
            if k != int(k) or k < 0:
                raise GeneratorError(f"faults: '{raw}': the count must be a whole number >= 0")
            counts[kind] += int(k)
    return FaultRequest(counts["dropout"], counts["crash"], loss)


@dataclass(frozen=True)
class GeneratorOptions:
    """What ``swarm scenario new`` takes (units in the names; angles none here)."""

    drones: int
    layout: str = "grid"
    spacing_m: float = 2.5
    range_m: float = 6.0
    template: str = "turn-and-stretch"
    faults: FaultRequest = field(default_factory=FaultRequest)
    duration_s: float | None = None
    seed: int = 0
    altitude_m: float | None = None
    min_separation_m: float = 1.0
    name: str | None = None
    #: a steady wind: its speed (m/s) and the compass direction it blows from (deg)
    wind_m_s: float = 0.0
    wind_from_deg: float = 270.0
    #: the gusts' intensity (m/s, each component's standard deviation)
    turbulence_m_s: float = 0.0
    #: a small quadcopter outdoors (protocols/scenario/outdoor.py): its GNSS ("rtk" or "gnss"),
    #: or None: the ideal vehicles, sensors and radio
    outdoor: str | None = None

    @property
    def windy(self) -> bool:
        """Whether the scenario has wind or gusts (and then the vehicles' drag)."""
        return self.wind_m_s > 0.0 or self.turbulence_m_s > 0.0

    def wind_ned_m_s(self) -> tuple[float, float, float]:
        """The wind's velocity NED (m/s): it blows towards ``wind_from_deg + 180``."""
        to = math.radians(self.wind_from_deg + 180.0)
        n, e = self.wind_m_s * math.cos(to), self.wind_m_s * math.sin(to)
        return round(n, 6) + 0.0, round(e, 6) + 0.0, 0.0

    def command_line(self, out: str | None = None) -> str:
        """The ``swarm scenario new`` command that makes this scenario again (every option)."""
        args = [
            f"--drones {self.drones}",
            f"--layout {self.layout}",
            f"--spacing-m {self.spacing_m:g}",
            f"--range-m {self.range_m:g}",
            f"--template {self.template}",
        ]
        if self.faults.spec():
            args.append(f"--faults {self.faults.spec()}")
        if self.duration_s is not None:
            args.append(f"--duration-s {self.duration_s:g}")
        if self.altitude_m is not None:
            args.append(f"--altitude-m {self.altitude_m:g}")
        if self.min_separation_m != 1.0:
            args.append(f"--min-separation-m {self.min_separation_m:g}")
        if self.wind_m_s > 0.0:
            args.append(f"--wind {self.wind_m_s:g}@{self.wind_from_deg:g}")
        if self.turbulence_m_s > 0.0:
            args.append(f"--turbulence {self.turbulence_m_s:g}")
        if self.outdoor is not None:
            args.append(f"--outdoor {self.outdoor}")
        if self.name is not None:
            args.append(f"--name {self.name}")
        args.append(f"--seed {self.seed}")
        if out is not None:
            args.append(f"-o {out}")
        return "swarm scenario new " + " ".join(args)


@dataclass(frozen=True)
class Generated:
    """The TOML text, the scenario it loads as, and the start positions (N, 3) NED m."""

    text: str
    scenario: Scenario
    positions_ned_m: FloatArray


def generate(
    options: GeneratorOptions, out: str | None = None, command: str | None = None
) -> Generated:
    """Build, render and validate the scenario of ``options``; ``out`` is the path the header's
    command line names; ``command``: the command line the header records instead of the
    ``swarm scenario new`` one (``swarm up --drones N`` for a session). Raises GeneratorError
    naming the option that cannot be met."""
    o = options
    _check_options(o)
    rng = np.random.default_rng(o.seed)
    try:
        positions = layout_positions(o.layout, o.drones, o.spacing_m, rng, reach_m=o.range_m)
    except LayoutError as exc:
        raise GeneratorError(str(exc)) from None
    graph = radio_graph(positions, o.range_m)
    if not graph.connected:
        raise GeneratorError(
            f"range_m: at {o.range_m:g} m the radio graph at the start has {graph.components} "
            f"parts (the {o.layout} layout's spacing is {o.spacing_m:g} m); give a longer range"
        )
    consensus = _consensus(o.drones, graph.degree_min)
    request = PlanRequest(o.template, o.altitude_m, o.duration_s)
    plan = build_plan(request, positions, o.spacing_m, consensus["warmup_s"])
    faults = _faults(o.faults, graph.adjacency, plan, rng)
    text = render(o, out, positions, plan, faults, consensus, command)
    source = out or "<generated>"
    try:
        scenario = parse_scenario(tomllib.loads(text), source)
    except ValueError as exc:  # ScenarioError: e.g. a formation too tight for min_separation_m
        raise GeneratorError(f"the generated scenario does not validate: {exc}") from None
    return Generated(text, scenario, positions)


def _check_options(o: GeneratorOptions) -> None:
    if not MIN_DRONES <= o.drones <= MAX_DRONES:
        raise GeneratorError(f"drones: need {MIN_DRONES}..{MAX_DRONES}, got {o.drones}")
    if o.layout not in LAYOUTS:
        raise GeneratorError(f"layout: '{o.layout}' is not one of {', '.join(LAYOUTS)}")
    if o.template not in (*TEMPLATES, SESSION_TEMPLATE):
        raise GeneratorError(f"template: '{o.template}' is not one of {', '.join(TEMPLATES)}")
    for name, value in (("spacing_m", o.spacing_m), ("range_m", o.range_m)):
        if not (math.isfinite(value) and value > 0):
            raise GeneratorError(f"{name}: must be a positive number, got {value:g}")
    if not (math.isfinite(o.min_separation_m) and o.min_separation_m >= 0):
        raise GeneratorError(f"min_separation_m: must be >= 0, got {o.min_separation_m:g}")
    if o.spacing_m < o.min_separation_m:
        raise GeneratorError(
            f"spacing_m: {o.spacing_m:g} m is below the minimum separation "
            f"({o.min_separation_m:g} m)"
        )
    if o.altitude_m is not None and not 1.0 <= o.altitude_m <= 50.0:
        raise GeneratorError(f"altitude_m: must be in 1..50 m, got {o.altitude_m:g}")
    if o.duration_s is not None and not (math.isfinite(o.duration_s) and o.duration_s > 0):
        raise GeneratorError(f"duration_s: must be a positive number, got {o.duration_s:g}")
    if o.seed < 0:
        raise GeneratorError(f"seed: must be >= 0, got {o.seed}")
    if not (math.isfinite(o.wind_m_s) and 0.0 <= o.wind_m_s <= 30.0):
        raise GeneratorError(f"wind: the speed must be in 0..30 m/s, got {o.wind_m_s:g}")
    if not math.isfinite(o.wind_from_deg):
        raise GeneratorError(
            f"wind: the direction must be a number of degrees, got {o.wind_from_deg:g}"
        )
    if not (math.isfinite(o.turbulence_m_s) and 0.0 <= o.turbulence_m_s <= 10.0):
        raise GeneratorError(f"turbulence: must be in 0..10 m/s, got {o.turbulence_m_s:g}")
    if o.outdoor is not None and o.outdoor not in OUTDOOR_SENSORS:
        raise GeneratorError(f"outdoor: one of {', '.join(OUTDOOR_SENSORS)}, got {o.outdoor!r}")
    lost = o.faults.dropouts + o.faults.crashes
    if lost > o.drones - 2:
        raise GeneratorError(
            f"faults: {lost} drones lost leave fewer than 2 of {o.drones} to fly on"
        )


def _consensus(n: int, degree_min: int) -> dict[str, float]:
    """The estimator's defaults hold on any graph (its step cap and channel scale,
    drone_agent/core/consensus/scalar.py); beyond 9 drones, or on a sparse graph, the plan rests
    longer on the ground: the swarm leaves it only once every estimate has settled and word of it
    has crossed the swarm (N ticks, drone_agent/flight_phase.SwarmSettled), so the climb starts
    about then: 3 s + 0.03 s per drone (6 s at 100, 10.5 s at 250; measured settling 1.4 and 3.6 s
    on a 2.5 m grid at range 6 m, bench/settling.py, plus N ticks of 20 ms)."""
    if n <= 9 and degree_min == n - 1:
        return {"warmup_s": 3.0}
    return {"warmup_s": math.ceil(2.0 * (3.0 + 0.03 * n)) / 2.0}  # to the half second


# --- faults ------------------------------------------------------------------------------------


def _faults(
    request: FaultRequest, adjacency: np.ndarray, plan: Plan, rng: np.random.Generator
) -> list[tuple[float, str, str]]:
    """(t_s, kind, fields as TOML lines) of each fault, in time order."""
    n = adjacency.shape[0]
    lost: set[int] = set()
    out: list[tuple[float, str, str]] = []

    def pick() -> int:
        candidates = [i for i in rng.permutation(n) if i not in lost]
        for i in candidates:
            if is_cut_free(adjacency, lost | {int(i)}):
                lost.add(int(i))
                return int(i)
        raise GeneratorError("faults: every drone left is a cut vertex of the radio graph")

    for k in range(request.dropouts):
        t = plan.airborne_s + 2.0 + 2.0 * k
        i = pick()
        out.append((t, "dropout", f"drone = {i}  # its agent dies; MAVLink system id {i + 1}"))
    for k in range(request.crashes):
        t = plan.manoeuvre_mid_s + 2.0 * k
        i = pick()
        out.append((t, "crash", f"drone = {i}  # its motors stop; MAVLink system id {i + 1}"))
    if request.loss:
        out.append((plan.airborne_s, "loss", f"probability = {request.loss:g}  # every link"))
    late = [f for f in out if f[0] >= plan.duration_s]
    if late:
        raise GeneratorError(
            f"faults: a {late[0][1]} at {late[0][0]:g} s falls after the end "
            f"({plan.duration_s:g} s); give a longer duration_s"
        )
    return sorted(out, key=lambda f: f[0])


# --- rendering ---------------------------------------------------------------------------------


def fmt(x: float) -> str:
    """A TOML float, at most 6 decimals, ``-0`` written as 0."""
    s = f"{round(x, 6) + 0.0:.6f}".rstrip("0")
    return s + "0" if s.endswith(".") else s


def vec(xs: Sequence[float]) -> str:
    """A TOML array of floats."""
    return "[" + ", ".join(fmt(x) for x in xs) + "]"


def render(
    o: GeneratorOptions,
    out: str | None,
    positions: FloatArray,
    plan: Plan,
    faults: list[tuple[float, str, str]],
    consensus: dict[str, float],
    command: str | None = None,
) -> str:
    """The commented TOML text of a generated scenario (``command``: the header's command line,
    default the ``swarm scenario new`` one that makes it again)."""
    name = o.name or f"{o.template}-{o.layout}{o.drones}"
    graph = radio_graph(positions, o.range_m)
    lines = [
        f"# {name}: {o.drones} drones, {o.layout} layout, {plan.summary}.",
        "# Generated by:",
        f"#   {command or o.command_line(out)}",
        "# Edit the command and run it again rather than editing this file;",
        "# `swarm scenario check FILE` validates a scenario and sums it up.",
        "",
        "version = 1",
        f'name = "{name}"',
        f"duration_s = {fmt(plan.duration_s)}  # simulated seconds; the last waypoint is held",
        f"seed = {o.seed}  # seeds every random draw of a run (packet loss, ...)",
        f"settle_s = {fmt(plan.airborne_s + 5.0)}  # metrics judge tracking from here on",
        "",
        "# Radio: drones closer than range_m hear each other. At the start the graph is",
        f"# connected, degree {graph.degree_min}..{graph.degree_max} "
        f"(mean {graph.degree_mean:.1f}).",
        "[comms]",
        f"range_m = {fmt(o.range_m)}",
        "",
        "# Every formation of the plan must keep the drones this far apart (checked on load).",
        "[safety]",
        f"min_separation_m = {fmt(o.min_separation_m)}",
        "",
        *_consensus_lines(consensus),
        *_air_lines(o),
        *([] if o.outdoor is None else outdoor_lines(o.outdoor)),
        f"# Drones on the ground (NED m), {o.layout} layout, at least "
        f"{fmt(min_spacing(positions))} m apart (spacing {fmt(o.spacing_m)} m).",
        "# Drone i (0-based, file order) is MAVLink system id i + 1.",
    ]
    for p in positions:
        lines.append(f"[[drones]]\nposition_ned_m = {vec(p)}\n")
    lines += [
        "# The plan: waypoints of the swarm's centre (NED m: north, east, down; -z is up),",
        "# heading (yaw_deg, clockwise from north) and spreads (RMS distance of the drones from",
        "# the centre along its length, width and height, m). Without rates, a value equal at two",
        "# waypoints is held between them and a rising one rises monotonically (rest to rest).",
    ]
    for p in plan.points:
        if p.note:
            lines.append(f"# t = {fmt(p.t_s)} s: {p.note}")
        lines += [
            "[[trajectory.waypoints]]",
            f"t_s = {fmt(p.t_s)}",
            f"centre_ned_m = {vec(p.centre_ned_m)}",
            f"yaw_deg = {fmt(p.yaw_deg)}",
            f"spread_m = {vec(p.spread_m)}",
            "",
        ]
    if faults:
        lines.append("# Faults, in simulated seconds.")
    for t, kind, fields in faults:
        lines += ["[[faults]]", f"t_s = {fmt(t)}", f'kind = "{kind}"', fields, ""]
    return "\n".join(lines).rstrip("\n") + "\n"


def _air_lines(o: GeneratorOptions) -> list[str]:
    """[vehicle] drag (in moving air) and motors (outdoors: protocols/scenario/outdoor.py), and
    [environment] of a windy scenario (nothing in still air, ideal vehicles)."""
    vehicle = []
    if o.windy:
        vehicle += [
            "# The vehicles' drag (m/s^2 per m/s of airspeed, a small quadcopter's rotor drag):",
            "# the air moves them through it.",
            "drag_xy_per_s = 0.4",
            "drag_z_per_s = 0.15",
        ]
    if o.outdoor is not None:
        vehicle += [
            "# Their motors: each rotor's speed follows its command with this time constant (s).",
            *(f"{k} = {v!r}" for k, v in VEHICLE.items()),
        ]
    lines = ["[vehicle]", *vehicle, ""] if vehicle else []
    if not o.windy:
        return lines
    return [
        *lines,
        f"# The air: {fmt(o.wind_m_s)} m/s from {fmt(o.wind_from_deg)} deg, gusts of "
        f"{fmt(o.turbulence_m_s)} m/s (von Karman, carried by the wind).",
        "[environment]",
        f"wind_ned_m_s = {vec(o.wind_ned_m_s())}",
        f"turbulence_m_s = {fmt(o.turbulence_m_s)}",
        "turbulence_scale_m = 20.0",
        "",
    ]


def _consensus_lines(consensus: dict[str, float]) -> list[str]:
    if set(consensus) == {"warmup_s"} and consensus["warmup_s"] == 3.0:
        return [
            "# Consensus: ALGORITHM.md §6 defaults (a small swarm on a dense radio graph).",
            "[consensus]",
            "warmup_s = 3.0  # s on the ground before arming, estimates agreeing",
            "",
        ]
    return [
        "# Consensus for more than 9 drones or a sparse radio graph: the defaults (their step",
        "# cap and channel scale hold on any graph) and a longer rest on the ground: the swarm",
        "# leaves it together once every estimate has settled (N ticks after the last one).",
        "[consensus]",
        f"warmup_s = {fmt(consensus['warmup_s'])}",
        "",
    ]

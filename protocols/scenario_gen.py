"""Scenario generator behind ``swarm scenario new``: options in, a commented TOML scenario out.

Pure: no files, no clock; randomness comes from ``numpy.random.default_rng(
seed)``. :func:`generate` lays the drones out (protocols/scenario_layout.py), writes the plan of a
manoeuvre template as waypoints of the scenario file's own fields, places the requested faults,
renders a TOML text with a comment on every section (the generator's command line at the top) and
validates it through :func:`protocols.scenario.parse_scenario`, so what it returns always loads.

The plan of every template starts the same way: the swarm rests on the ground for the consensus
warm-up (the agents agree on the descriptors before arming, ALGORITHM.md §3 rule 7), then climbs
rest to rest to ``altitude_m``. The formation is the layout itself: the start's centre and spreads
along north and east, flat (height spread 0), yaw 0. Where length and width tie (a square grid, a
ring: the heading would be undefined, protocols/descriptors.py) the length is commanded 10 %
longer, so the heading is defined and nobody comes closer than on the ground.

Templates (times after the climb; the last waypoint is held to ``duration_s``):

- ``hover``: hold the take-off formation;
- ``paper``: the paper's flight style: forward along north at 1 m/s while the width breathes
  (variance +-30 %, one sine period over the flight);
- ``survey``: a lawnmower sweep of the centre: legs of 20 m (or the swarm's length if longer)
  along north, lanes one swarm width (plus a spacing) apart along east, rest at each corner;
- ``turn-and-stretch``: hold 5 s; then in 20 s a 20 m move north with a 30 deg turn and a 15 %
  stretch of the length spread; hold (issue 10's large-swarm flight).

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

from protocols.descriptors import covariance
from protocols.frames import FloatArray
from protocols.scenario import Scenario, parse_scenario
from protocols.scenario_layout import (
    LAYOUTS,
    LayoutError,
    is_cut_free,
    layout_positions,
    min_spacing,
    radio_graph,
)

TEMPLATES = ("hover", "paper", "survey", "turn-and-stretch")
FAULT_KINDS = ("dropout", "crash", "loss")
MIN_DRONES, MAX_DRONES = 2, 250
DEFAULT_LOSS = 0.2
#: Length and width spreads closer than this ratio count as a tie (heading undefined).
_TIE_RATIO = 0.1
_TIE_STRETCH = 1.1
_FINAL_HOLD_S = 5.0
_CRUISE_M_S = 0.8  # survey legs: mean speed (peak 1.875x on a rest-to-rest segment)
Vec3 = tuple[float, float, float]


class GeneratorError(ValueError):
    """Options the generator cannot meet; the message starts with the option's name."""


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
        if self.name is not None:
            args.append(f"--name {self.name}")
        args.append(f"--seed {self.seed}")
        if out is not None:
            args.append(f"-o {out}")
        return "swarm scenario new " + " ".join(args)


@dataclass(frozen=True)
class PlanPoint:
    """One waypoint: time (s), centre (NED m), yaw (deg), spreads (m), and what it is for."""

    t_s: float
    centre_ned_m: Vec3
    yaw_deg: float
    spread_m: Vec3
    note: str = ""


@dataclass(frozen=True)
class Plan:
    """A template's waypoints and when its faults go off: after the climb (``airborne_s``) and in
    the middle of the manoeuvre (``manoeuvre_mid_s``)."""

    points: tuple[PlanPoint, ...]
    duration_s: float
    airborne_s: float
    manoeuvre_mid_s: float
    summary: str


@dataclass(frozen=True)
class Generated:
    """The TOML text, the scenario it loads as, and the start positions (N, 3) NED m."""

    text: str
    scenario: Scenario
    positions_ned_m: FloatArray


def generate(options: GeneratorOptions, out: str | None = None) -> Generated:
    """Build, render and validate the scenario of ``options``; ``out`` is the path the header's
    command line names. Raises GeneratorError naming the option that cannot be met."""
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
    plan = _plan(o, positions, consensus["warmup_s"])
    faults = _faults(o.faults, graph.adjacency, plan, rng)
    text = render(o, out, positions, plan, faults, consensus)
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
    if o.template not in TEMPLATES:
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
    lost = o.faults.dropouts + o.faults.crashes
    if lost > o.drones - 2:
        raise GeneratorError(
            f"faults: {lost} drones lost leave fewer than 2 of {o.drones} to fly on"
        )


def _consensus(n: int, degree_min: int) -> dict[str, float]:
    """ALGORITHM.md §6: the defaults for <= 9 drones on a dense graph (everyone hears everyone),
    the degree-normalised gain at its maximum (rho c = 8) and a longer warm-up beyond."""
    if n <= 9 and degree_min == n - 1:
        return {"warmup_s": 3.0}
    return {"degree_normalised": True, "rho": 8.0, "warmup_s": 5.0}


# --- templates ---------------------------------------------------------------------------------


def _start(positions: FloatArray) -> tuple[Vec3, Vec3]:
    """The start's centre (on the ground) and the spreads (m) to fly: the layout's own along
    north and east, the length 10 % longer where they tie, flat."""
    centre, sigma = covariance(positions)
    s_north, s_east = math.sqrt(max(sigma[0, 0], 0.0)), math.sqrt(max(sigma[1, 1], 0.0))
    if abs(s_north - s_east) < _TIE_RATIO * (s_north + s_east):
        s_north = max(s_north, s_east) * _TIE_STRETCH
    return (float(centre[0]), float(centre[1]), 0.0), (s_north, s_east, 0.0)


def _plan(o: GeneratorOptions, positions: FloatArray, warmup_s: float) -> Plan:
    default_alt = 5.0 if o.template == "paper" else 3.0
    alt = default_alt if o.altitude_m is None else o.altitude_m
    (n0, e0, _), spread = _start(positions)
    climb_s = max(4.0, 2.0 * alt)
    up = warmup_s + climb_s
    ground = (n0, e0, 0.0)
    head = [
        PlanPoint(0.0, ground, 0.0, spread, "on the ground: consensus warm-up before arming"),
        PlanPoint(warmup_s, ground, 0.0, spread, "warm-up over: arm and climb"),
        PlanPoint(up, (n0, e0, -alt), 0.0, spread, f"at {alt:g} m: take-off done"),
    ]
    builder = {
        "hover": _hover,
        "paper": _paper,
        "survey": _survey,
        "turn-and-stretch": _turn_and_stretch,
    }[o.template]
    return builder(o, head, spread, extent_m=_extent(positions, o.spacing_m))


def _extent(positions: FloatArray, spacing_m: float) -> tuple[float, float]:
    """Footprint (m) of the swarm along north and east: its span plus one spacing."""
    span = positions.max(axis=0) - positions.min(axis=0)
    return float(span[0]) + spacing_m, float(span[1]) + spacing_m


def _duration(o: GeneratorOptions, needed_s: float, default_s: float) -> float:
    if o.duration_s is None:
        return max(needed_s, default_s)
    if o.duration_s < needed_s:
        raise GeneratorError(
            f"duration_s: the {o.template} template needs at least {needed_s:g} s "
            f"with these options, got {o.duration_s:g}"
        )
    return o.duration_s


def _hover(
    o: GeneratorOptions, head: list[PlanPoint], spread: Vec3, extent_m: tuple[float, float]
) -> Plan:
    up = head[-1].t_s
    d = _duration(o, up + 10.0, up + 20.0)
    top = head[-1]
    end = PlanPoint(d, top.centre_ned_m, 0.0, spread, "hold to the end")
    return Plan((*head, end), d, up, 0.5 * (up + d), "take off and hover")


def _turn_and_stretch(
    o: GeneratorOptions, head: list[PlanPoint], spread: Vec3, extent_m: tuple[float, float]
) -> Plan:
    up = head[-1].t_s
    n0, e0, z = head[-1].centre_ned_m
    go, there = up + 5.0, up + 25.0
    d = _duration(o, there + _FINAL_HOLD_S, there + 10.0)
    stretched = (spread[0] * 1.15, spread[1], spread[2])
    points = (
        *head,
        PlanPoint(go, (n0, e0, z), 0.0, spread, "hold 5 s, then move"),
        PlanPoint(
            there, (n0 + 20.0, e0, z), 30.0, stretched,
            "20 m north in 20 s, turned 30 deg, length spread +15 %",
        ),
        PlanPoint(d, (n0 + 20.0, e0, z), 30.0, stretched, "hold to the end"),
    )  # fmt: skip
    return Plan(points, d, up, 0.5 * (go + there), "take off, move 20 m with a turn and stretch")


def _paper(
    o: GeneratorOptions, head: list[PlanPoint], spread: Vec3, extent_m: tuple[float, float]
) -> Plan:
    up = head[-1].t_s
    n0, e0, z = head[-1].centre_ned_m
    d = _duration(o, up + 20.0, 120.0)
    cruise_end = d - _FINAL_HOLD_S
    span = cruise_end - up
    points = list(head)
    steps = max(2, math.ceil(span / 5.0))
    for k in range(1, steps + 1):
        t = up + span * k / steps
        phase = math.sin(2.0 * math.pi * (t - up) / span)
        width = spread[1] * math.sqrt(1.0 + 0.3 * phase)
        note = "forward at 1 m/s, width breathing" if k == 1 else ""
        points.append(PlanPoint(t, (n0 + (t - up), e0, z), 0.0, (spread[0], width, 0.0), note))
    points.append(PlanPoint(d, points[-1].centre_ned_m, 0.0, points[-1].spread_m, "hold"))
    return Plan(tuple(points), d, up, 0.5 * (up + cruise_end), "paper-style forward flight")


def _survey(
    o: GeneratorOptions, head: list[PlanPoint], spread: Vec3, extent_m: tuple[float, float]
) -> Plan:
    up = head[-1].t_s
    n0, e0, z = head[-1].centre_ned_m
    leg = max(20.0, math.ceil(extent_m[0]))
    lane = round(extent_m[1], 1)
    t_leg = float(max(8, math.ceil(leg / _CRUISE_M_S)))
    t_lane = float(max(5, math.ceil(lane / _CRUISE_M_S)))
    needed = up + 2 * t_leg + t_lane + _FINAL_HOLD_S
    d = _duration(o, needed, up + 4 * t_leg + 3 * t_lane + _FINAL_HOLD_S)
    legs = 1 + int((d - _FINAL_HOLD_S - up - t_leg) // (t_leg + t_lane))
    points = list(head)
    t, north, east = up, n0, e0
    for k in range(legs):
        if k:
            t, east = t + t_lane, east + lane
            points.append(PlanPoint(t, (north, east, z), 0.0, spread, f"next lane, {lane:.1f} m"))
        t, north = t + t_leg, (n0 + leg if k % 2 == 0 else n0)
        points.append(PlanPoint(t, (north, east, z), 0.0, spread, f"leg {k + 1}: {leg:.0f} m"))
    points.append(PlanPoint(d, (north, east, z), 0.0, spread, "hold to the end"))
    mid = 0.5 * (up + points[-2].t_s)
    return Plan(tuple(points), d, up, mid, f"lawnmower survey, {legs} legs")


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
) -> str:
    """The commented TOML text of a generated scenario."""
    name = o.name or f"{o.template}-{o.layout}{o.drones}"
    graph = radio_graph(positions, o.range_m)
    lines = [
        f"# {name}: {o.drones} drones, {o.layout} layout, {plan.summary}.",
        "# Generated by:",
        f"#   {o.command_line(out)}",
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


def _consensus_lines(consensus: dict[str, float]) -> list[str]:
    if set(consensus) == {"warmup_s"} and consensus["warmup_s"] == 3.0:
        return [
            "# Consensus: ALGORITHM.md §6 defaults (a small swarm on a dense radio graph).",
            "[consensus]",
            "warmup_s = 3.0  # s on the ground before arming, estimates agreeing",
            "",
        ]
    return [
        "# Consensus on a sparse radio graph (ALGORITHM.md §3 rule 6): the degree-normalised",
        "# gain at its maximum (rho c = 8) and a longer warm-up on the ground before arming.",
        "[consensus]",
        "degree_normalised = true",
        f"rho = {fmt(consensus['rho'])}",
        f"warmup_s = {fmt(consensus['warmup_s'])}",
        "",
    ]

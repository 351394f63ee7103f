"""``swarm sweep``: how far the swarm holds, measured. A grid of in-process flights (``swarm
simulate``'s) of one scenario, each with other values of a few factors and seeds, and one row of
figures per flight.

A factor is a named change of the scenario (:data:`FACTORS`): the wind's speed and direction, the
gusts, the vehicles' drag, how the vehicles differ, their sensors' errors, the radio's limits,
packet loss on every link from the start. Each flight's row holds the factors' values under their
names, its seed and its figures (:func:`row_of`), among them ``centroid_rms_m``. :data:`BARS` are
the figures a swarm must meet to hold (the centre tracked within half a metre, the estimates
agreeing within ten centimetres, the drones apart, nobody lost but those the scenario drops or
crashes on purpose); :func:`breaks` says, per factor, the first value at which a bar breaks.

Pure but for the flights themselves (each one :func:`gcs.reference.simulate.simulate` into its
own folder); the runs are independent and seeded, so they run in parallel, in any order, with the
same rows.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from protocols.faults import Crash, Dropout, Loss

if TYPE_CHECKING:  # (the `swarm` parser lists the factors: no scenario machinery imported)
    from protocols.scenario.scenario_file import Scenario, VehicleConfig


def _with_wind(
    scenario: Scenario, speed: float | None = None, origin: float | None = None
) -> Scenario:
    """The scenario with its wind's speed (m/s) or the compass direction it blows from (deg)
    changed; a still scenario's wind blows from the west."""
    n, e, _ = scenario.environment.wind_ned_m_s
    old_speed = math.hypot(n, e)
    old_from = (math.degrees(math.atan2(-e, -n)) + 360.0) % 360.0 if old_speed > 0 else 270.0
    speed = old_speed if speed is None else speed
    origin = old_from if origin is None else origin
    to = math.radians(origin + 180.0)
    wind = (round(speed * math.cos(to), 9) + 0.0, round(speed * math.sin(to), 9) + 0.0, 0.0)
    return _environment(scenario, wind_ned_m_s=wind)


def _environment(scenario: Scenario, **changes: Any) -> Scenario:
    env = dataclasses.replace(scenario.environment, **changes)
    vehicle = scenario.vehicle
    if not env.calm and vehicle.drag_xy_per_s == 0.0 and vehicle.drag_z_per_s == 0.0:
        vehicle = dataclasses.replace(vehicle, drag_xy_per_s=DRAG_XY, drag_z_per_s=DRAG_Z)
    return dataclasses.replace(scenario, environment=env, vehicle=vehicle)


def _vehicle(scenario: Scenario, **changes: Any) -> Scenario:
    vehicle: VehicleConfig = dataclasses.replace(scenario.vehicle, **changes)
    return dataclasses.replace(scenario, vehicle=vehicle)


def _fleet(scenario: Scenario, **changes: Any) -> Scenario:
    return dataclasses.replace(scenario, vehicles=dataclasses.replace(scenario.vehicles, **changes))


def _sensors(scenario: Scenario, **changes: Any) -> Scenario:
    return dataclasses.replace(scenario, sensors=dataclasses.replace(scenario.sensors, **changes))


def _radio(scenario: Scenario, **changes: Any) -> Scenario:
    return dataclasses.replace(scenario, radio=dataclasses.replace(scenario.radio, **changes))


def _loss(scenario: Scenario, probability: float) -> Scenario:
    if probability == 0.0:
        return scenario
    return dataclasses.replace(scenario, faults=(*scenario.faults, Loss(probability, t_s=0.0)))


#: A small quadcopter's rotor drag (1/s), given to a scenario without drag that a factor puts in
#: moving air (docs/scenarios.md).
DRAG_XY, DRAG_Z = 0.4, 0.15


@dataclass(frozen=True)
class Factor:
    """A named change of a scenario: ``apply(scenario, value)``, values within ``bounds``."""

    name: str
    unit: str
    help: str
    apply: Callable[[Scenario, float], Scenario]
    bounds: tuple[float, float]


FACTORS: dict[str, Factor] = {
    f.name: f
    for f in (
        Factor("wind_m_s", "m/s", "the mean wind's speed (from the scenario's direction, "
               "else from the west)", lambda s, v: _with_wind(s, speed=v), (0.0, 30.0)),
        Factor("wind_from_deg", "deg", "the compass direction the wind blows from",
               lambda s, v: _with_wind(s, origin=v), (0.0, 360.0)),
        Factor("turbulence_m_s", "m/s", "the gusts' intensity",
               lambda s, v: _environment(s, turbulence_m_s=v), (0.0, 10.0)),
        Factor("turbulence_scale_m", "m", "the gusts' length scale",
               lambda s, v: _environment(s, turbulence_scale_m=v), (0.5, 1e4)),
        Factor("drag_xy_per_s", "1/s", "the vehicles' drag in their x-y plane",
               lambda s, v: _vehicle(s, drag_xy_per_s=v), (0.0, 10.0)),
        Factor("mass_spread", "", "how the vehicles' masses differ (relative, 1 sigma)",
               lambda s, v: _fleet(s, mass_spread=v), (0.0, 0.3)),
        Factor("thrust_spread", "", "how the vehicles' rotor thrust differs (relative)",
               lambda s, v: _fleet(s, thrust_spread=v), (0.0, 0.3)),
        Factor("motor_tau_s", "s", "the motors' time constant (rotor speed lag; 0: none)",
               lambda s, v: _vehicle(s, motor_tau_s=v), (0.0, 0.5)),
        Factor("loss", "", "packet loss on every link, from the start",
               _loss, (0.0, 0.99)),
        Factor("gnss_bias_m", "m", "the vehicles' wandering GNSS position bias (1 sigma)",
               lambda s, v: _sensors(s, gnss_bias_m=v), (0.0, 20.0)),
        Factor("position_noise_m", "m", "white noise on the vehicles' position estimates",
               lambda s, v: _sensors(s, position_noise_m=v), (0.0, 10.0)),
        Factor("estimate_latency_s", "s", "how late the vehicles' state estimates are",
               lambda s, v: _sensors(s, latency_s=v), (0.0, 1.0)),
        Factor("estimate_rate_hz", "Hz", "how often the state estimates are refreshed "
               "(0: every control tick)", lambda s, v: _sensors(s, rate_hz=v), (0.0, 1000.0)),
        Factor("altitude_bias_m", "m", "the vehicles' wandering height bias (1 sigma)",
               lambda s, v: _sensors(s, altitude_bias_m=v), (0.0, 20.0)),
        Factor("velocity_noise_m_s", "m/s", "white noise on the vehicles' velocity estimates",
               lambda s, v: _sensors(s, velocity_noise_m_s=v), (0.0, 5.0)),
        Factor("bandwidth_bytes_s", "B/s", "each radio link's capacity (0: unlimited)",
               lambda s, v: _radio(s, bandwidth_bytes_s=v), (0.0, 1e9)),
        Factor("loss_half_m", "m", "the distance at which the radio loses half the messages "
               "(0: none lost to distance)", lambda s, v: _radio(s, loss_half_m=v), (0.0, 1e5)),
        Factor("burst_fraction", "", "the share of messages in the radio's loss bursts",
               lambda s, v: _radio(s, burst_fraction=v), (0.0, 0.99)),
        Factor("radio_latency_s", "s", "the radio's added latency",
               lambda s, v: _radio(s, latency_s=v), (0.0, 5.0)),
        Factor("jitter_s", "s", "the radio's mean random extra delay",
               lambda s, v: _radio(s, jitter_s=v), (0.0, 5.0)),
    )
}  # fmt: skip


@dataclass(frozen=True)
class Bar:
    """A figure a swarm must meet: ``figure`` at most (or at least) ``limit``."""

    figure: str
    limit: float
    at_most: bool = True

    def met(self, value: float | None) -> bool:
        """Whether ``value`` meets the bar (None, not measured: nothing to judge, met)."""
        if value is None:
            return True
        return value <= self.limit if self.at_most else value >= self.limit

    def __str__(self) -> str:
        return f"{self.figure} {'<=' if self.at_most else '>='} {self.limit:g}"


#: The swarm holds: its centre tracked and its estimates agreeing, the drones apart, none lost.
BARS = (
    Bar("centroid_rms_m", 0.5),
    Bar("consensus_rms_m", 0.1),
    Bar("collisions", 0),
    Bar("drones_lost_unplanned", 0),
    Bar("min_separation_m", 0.5, at_most=False),
)


class SweepError(ValueError):
    """A sweep that cannot run as asked (the message names the flag)."""


def parse_vary(texts: Sequence[str]) -> dict[str, list[float]]:
    """``--vary NAME=V1,V2,...`` flags -> the factors' values, in order."""
    out: dict[str, list[float]] = {}
    for text in texts:
        name, sep, values = text.partition("=")
        if not sep or not values:
            raise SweepError(f"--vary {text!r}: expected NAME=V1,V2,... (e.g. wind_m_s=0,2,4)")
        if name not in FACTORS:
            raise SweepError(f"--vary {text!r}: unknown factor {name!r} (known: "
                             f"{', '.join(FACTORS)})")  # fmt: skip
        if name in out:
            raise SweepError(f"--vary {name}: given twice")
        factor = FACTORS[name]
        try:
            numbers = [float(v) for v in values.split(",")]
        except ValueError:
            raise SweepError(f"--vary {text!r}: the values must be numbers") from None
        low, high = factor.bounds
        bad = [v for v in numbers if not (math.isfinite(v) and low <= v <= high)]
        if bad:
            raise SweepError(
                f"--vary {name}: {bad[0]:g} is outside {low:g}..{high:g} {factor.unit}"
            )
        out[name] = numbers
    if not out:
        raise SweepError("give at least one --vary NAME=V1,V2,...")
    return out


@dataclass(frozen=True)
class Run:
    """One flight of the grid: the factors' values and the seed."""

    values: tuple[tuple[str, float], ...]
    seed: int

    @property
    def name(self) -> str:
        parts = [f"{k}={v:g}" for k, v in self.values]
        return "_".join([*parts, f"seed={self.seed}"])

    def scenario(self, base: Scenario, duration_s: float | None) -> Scenario:
        """``base`` with this run's factors, seed and duration."""
        s = dataclasses.replace(base, seed=self.seed)
        if duration_s is not None:
            s = dataclasses.replace(s, duration_s=min(duration_s, s.duration_s))
        for name, value in self.values:
            s = FACTORS[name].apply(s, value)
        return s


def grid(vary: dict[str, list[float]], seeds: int, first_seed: int) -> list[Run]:
    """Every combination of the factors' values, each with ``seeds`` seeds."""
    names = list(vary)
    return [
        Run(tuple(zip(names, combo, strict=True)), first_seed + k)
        for combo in itertools.product(*(vary[n] for n in names))
        for k in range(seeds)
    ]


def row_of(run: Run, metrics: dict[str, Any], planned_losses: int = 0) -> dict[str, Any]:
    """The run's factors and seed, and its figures from its ``metrics.json``;
    ``planned_losses``: the drones its scenario drops or crashes on purpose (not counted in
    ``drones_lost_unplanned``)."""
    steady, consensus = metrics["tracking_steady"], metrics["consensus_steady"]
    return {
        **dict(run.values),
        "seed": run.seed,
        "centroid_rms_m": steady["centroid_m"]["rms"],
        "shape_rms_m2": steady["shape_m2"]["rms"],
        "heading_rms_deg": steady["heading_deg"]["rms"],
        "consensus_rms_m": consensus["centroid_m"]["rms"],
        "min_separation_m": metrics["separation"]["min_m"],
        "collisions": metrics["collisions"]["count"],
        "drones_lost": len(metrics["drones_lost"]),
        "drones_lost_unplanned": max(0, len(metrics["drones_lost"]) - planned_losses),
        "max_tilt_deg": metrics["max_tilt_deg"]["value"],
        "messages_lost": metrics["messages"]["lost"],
    }


def fly(run: Run, base: Scenario, duration_s: float | None, out: Path) -> dict[str, Any]:
    """Fly one run into ``out / run.name``; its row."""
    from gcs.reference.simulate import simulate

    scenario = run.scenario(base, duration_s)
    planned = {f.drone for f in scenario.faults if isinstance(f, Dropout | Crash)}
    result = simulate(scenario, out / run.name, plots=False, recording=False)
    return row_of(run, result.metrics, len(planned))


def alone(
    rows: list[dict[str, Any]], vary: dict[str, list[float]], name: str
) -> list[dict[str, Any]]:
    """The rows in which only factor ``name`` varies: every other factor at its first value."""
    others = {n: v[0] for n, v in vary.items() if n != name}
    return [r for r in rows if all(r[n] == v for n, v in others.items())]


def breaks(rows: list[dict[str, Any]], vary: dict[str, list[float]]) -> dict[str, dict[str, Any]]:
    """Per factor and bar, the first value (in the order given) at which some flight misses the
    bar while the other factors stay at their first values; None if none does."""
    out: dict[str, dict[str, Any]] = {}
    for name, values in vary.items():
        mine = alone(rows, vary, name)
        out[name] = {}
        for bar in BARS:
            first = None
            for v in values:
                if any(r[name] == v and not bar.met(r[bar.figure]) for r in mine):
                    first = v
                    break
            out[name][str(bar)] = first
    return out

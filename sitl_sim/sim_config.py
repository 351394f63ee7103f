"""Configuration of a ``swarm sim`` run: typed, validated, with one-line errors naming the problem.

Vehicles come from ``--drones N`` (default vehicle, gains and rates; on the ground on a 2 m grid)
or from a scenario file (initial positions and yaw, [vehicle], [gains], [rates], seed, and its
``crash`` faults as a timeline; the other faults act on agents and radio links, not here).
"""

from __future__ import annotations

import dataclasses
import math
import socket
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from protocols.faults import Crash
from protocols.mavlink.conventions import (
    DEFAULT_GCS_PORT,
    LOCKSTEP_DROP_TIMEOUT_S,
    MAX_VEHICLES,
    Dialect,
    port_clash,
    vehicle_ports,
)
from protocols.mavlink.signing import SigningKeyError, load_signing_key
from protocols.model.frames import FloatArray
from protocols.model.geodesy import GeoPoint
from protocols.scenario.scenario_file import HOME_BOUNDS, ScenarioError, load_scenario
from protocols.scenario.schema import check_number
from sitl_sim.mavlink_edge.streams import AGENT_RATES_HZ, GCS_RATES_HZ
from sitl_sim.physics.attitude_control import AttitudeGains
from sitl_sim.physics.vehicle_params import VehicleParams
from sitl_sim.physics.wind import Air
from sitl_sim.vehicle.config import air, attitude_gains, sensors, vehicle_params, vehicle_scales
from sitl_sim.vehicle.estimate import Sensors
from sitl_sim.vehicle.world import WorldConfig

Address = tuple[str, int]
GRID_SPACING_M = 2.0
CLOCKS = ("realtime", "lockstep")


class SimConfigError(ValueError):
    """A mistake in the simulator's options: one line, shown to the user as is."""


@dataclass(frozen=True)
class NetConfig:
    """Where the vehicles listen (``bind_host``, :func:`~protocols.mavlink.conventions.
    vehicle_port` of ``base_port``: None is the default layout), where telemetry for the
    ground station goes (None: nowhere), the signing key and the default stream rates (Hz; the
    defaults here are PX4's: for ArduCopter take sitl_sim.launch.stream_rates)."""

    bind_host: str = "127.0.0.1"
    base_port: int | None = None
    gcs: Address | None = ("127.0.0.1", DEFAULT_GCS_PORT)
    signing_key: bytes | None = None
    #: drone index of the first vehicle (a shard of a swarm, sitl_sim/shard.py): vehicle i is
    #: drone first_drone + i, on that drone's port
    first_drone: int = 0
    agent_rates_hz: Mapping[int, float] = field(default_factory=lambda: dict(AGENT_RATES_HZ))
    gcs_rates_hz: Mapping[int, float] = field(default_factory=lambda: dict(GCS_RATES_HZ))


@dataclass(frozen=True)
class ClockConfig:
    """``mode`` realtime or lockstep; ``speedup`` (realtime, and lockstep while no agent holds
    the barrier); lockstep: agents silent for ``drop_timeout_s`` wall seconds leave the barrier,
    and tick 0 waits up to ``join_timeout_s`` for ``wait_agents`` agents; ``duration_s``: stop
    after that much simulated time (None: run until stopped)."""

    mode: str = "realtime"
    speedup: float = 1.0
    drop_timeout_s: float = LOCKSTEP_DROP_TIMEOUT_S
    join_timeout_s: float = 10.0
    wait_agents: int = 1
    duration_s: float | None = None
    #: realtime: tick 0 runs at this Unix time (s), not when agents have spoken, so that
    #: simulator shards on several hosts share one clock (sitl_sim/shard.py)
    start_at_unix_s: float | None = None


@dataclass(frozen=True)
class SimConfig:
    """Everything a run needs: vehicles (system ids, parameters, gains, initial positions (N, 3)
    NED m and yaw (N,) rad), the world's rates and faults, network, clock and seed. The autopilot
    dialect on the wire is ``world.dialect`` (:class:`~protocols.mavlink.conventions.Dialect`,
    with ``world.ekf_ready_s`` for ArduCopter); ``net``'s rates must then be that dialect's
    (sitl_sim.launch.stream_rates)."""

    sysids: tuple[int, ...]
    params: VehicleParams
    gains: AttitudeGains
    positions_ned_m: FloatArray
    yaw_rad: FloatArray
    world: WorldConfig
    net: NetConfig = field(default_factory=NetConfig)
    clock: ClockConfig = field(default_factory=ClockConfig)
    seed: int = 0

    @property
    def n(self) -> int:
        """Number of vehicles."""
        return len(self.sysids)

    @property
    def dialect(self) -> Dialect:
        """The autopilot dialect the vehicles speak (``world.dialect``)."""
        return Dialect(self.world.dialect)


def grid_positions(n: int, spacing_m: float = GRID_SPACING_M) -> FloatArray:
    """(n, 3) NED positions (m) on the ground: rows of ``ceil(sqrt(n))``, ``spacing_m`` apart."""
    side = max(1, math.ceil(math.sqrt(n)))
    cells = np.arange(n)
    return np.stack([spacing_m * (cells // side), spacing_m * (cells % side), np.zeros(n)], axis=1)


def vehicles_from_scenario(
    path: str | Path,
    seed: int | None = None,
) -> tuple[
    VehicleParams,
    AttitudeGains,
    FloatArray,
    FloatArray,
    int,
    int,
    int,
    list[Crash],
    GeoPoint,
    Air,
    tuple[tuple[float, ...], ...],
    Sensors,
]:
    """(params, gains, positions (N, 3), yaw (N,) rad, physics Hz, control Hz, seed, crashes,
    home, air, each vehicle's (mass, thrust[, motor lag]) factors, the sensors); ``seed`` in place
    of the scenario's (``--seed``), for every draw."""
    try:
        scenario = load_scenario(path)
    except ScenarioError as exc:
        raise SimConfigError(str(exc)) from None
    if seed is not None:
        scenario = dataclasses.replace(scenario, seed=seed)
    yaw = np.radians([d.yaw_deg for d in scenario.drones])
    crashes = [f for f in scenario.faults if isinstance(f, Crash)]
    return (
        vehicle_params(scenario),
        attitude_gains(scenario),
        scenario.positions_ned_m(),
        yaw,
        scenario.rates.physics_hz,
        scenario.rates.control_hz,
        scenario.seed,
        crashes,
        scenario.home,
        air(scenario),
        vehicle_scales(scenario),
        sensors(scenario),
    )


def parse_home(text: str) -> GeoPoint:
    """``--home LAT,LON,ALT`` (degrees, degrees, m) -> a GeoPoint within the scenario's bounds."""
    parts = text.split(",")
    if len(parts) != 3:
        raise SimConfigError(f"--home {text!r}: expected LAT,LON,ALT (e.g. 47.3977,8.5456,488)")
    values: list[float] = []
    for name, part in zip(("lat_deg", "lon_deg", "alt_m"), parts, strict=True):
        try:
            number = float(part)
        except ValueError:
            raise SimConfigError(f"--home {text!r}: {part.strip()!r} is not a number") from None
        try:
            values.append(check_number(number, "--home", name, **HOME_BOUNDS[name]))
        except ScenarioError as exc:
            raise SimConfigError(str(exc)) from None
    return GeoPoint(*values)


def check_count(n: int) -> None:
    """At least one vehicle and at most MAX_VEHICLES (system ids 1..250)."""
    if not 1 <= n <= MAX_VEHICLES:
        raise SimConfigError(
            f"{n} vehicles: between 1 and {MAX_VEHICLES} (system ids 1..{MAX_VEHICLES})"
        )


def parse_sysids(text: str | None, n: int) -> tuple[int, ...]:
    """System ids from ``"1,2,5"`` (one per vehicle, 1..250, no repeats); default 1..n."""
    if text is None:
        return tuple(range(1, n + 1))
    try:
        ids = tuple(int(part) for part in text.split(","))
    except ValueError:
        raise SimConfigError(f"--sysids {text!r}: a comma-separated list of integers") from None
    if len(ids) != n:
        raise SimConfigError(f"--sysids gives {len(ids)} system ids for {n} vehicles")
    seen: dict[int, int] = {}
    for i, sysid in enumerate(ids):
        if not 1 <= sysid <= MAX_VEHICLES:
            raise SimConfigError(f"--sysids: system id {sysid} outside 1..{MAX_VEHICLES}")
        if sysid in seen:
            raise SimConfigError(
                f"two vehicles with system id {sysid} (vehicles {seen[sysid]} and {i})"
            )
        seen[sysid] = i
    return ids


def parse_gcs_url(text: str) -> Address | None:
    """``udp:HOST:PORT`` (also ``udpout:``) -> (IPv4 address, port); ``none`` -> None."""
    if text.strip().lower() == "none":
        return None
    scheme, _, rest = text.partition(":")
    host, _, port_text = rest.rpartition(":")
    if scheme not in ("udp", "udpout") or not host or not port_text.isdigit():
        raise SimConfigError(f"--gcs {text!r}: expected udp:HOST:PORT (or none)")
    port = int(port_text)
    if not 1 <= port <= 65535:
        raise SimConfigError(f"--gcs {text!r}: port {port} outside 1..65535")
    try:
        info = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)
    except OSError:
        raise SimConfigError(f"--gcs {text!r}: cannot resolve host {host!r}") from None
    return str(info[0][4][0]), port


def check_ports(base_port: int | None, n: int, gcs_port: int | None = None) -> None:
    """The n vehicle ports must exist, differ, and leave the GCS port free."""
    clash = port_clash(vehicle_ports(n, base_port), gcs_port)
    if clash is not None:
        raise SimConfigError(clash)


def read_signing_key(path: str | Path | None) -> bytes | None:
    """The 32-byte key of ``path`` (None: no signing)."""
    if path is None:
        return None
    try:
        return load_signing_key(path)
    except SigningKeyError as exc:
        raise SimConfigError(f"--signing-key {exc}") from None


def check_rates(physics_hz: int, control_hz: int) -> None:
    """Physics must be a whole multiple of the control rate."""
    if control_hz < 1 or physics_hz < 1 or physics_hz % control_hz:
        raise SimConfigError(
            f"--physics-hz {physics_hz} must be a positive multiple of --control-hz {control_hz}"
        )


def check_positive(name: str, value: float) -> None:
    """A flag that must be a finite number > 0."""
    if not (math.isfinite(value) and value > 0):
        raise SimConfigError(f"{name} must be a number > 0, got {value:g}")


def crash_timeline(crashes: Sequence[Crash]) -> tuple[tuple[float, int], ...]:
    """Scenario crash faults as ``(t_s, vehicle index)``."""
    return tuple((c.t_s, c.drone) for c in crashes)

"""From ``swarm sim`` flags to a configured world, and the lines the command prints.

Every check that can fail on a user's input happens here, before any socket is opened, and
raises :class:`~sitl_sim.sim_config.SimConfigError` with one line naming the flag or file.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from protocols.mavlink.conventions import Dialect, describe_ports, vehicle_ports
from protocols.model.frames import FloatArray
from protocols.model.geodesy import GeoPoint
from sitl_sim.mavlink_edge.dialect import tunables_for
from sitl_sim.mavlink_edge.streams import (
    AGENT_RATES_HZ,
    AGENT_STATE_STREAMS,
    COPTER_AGENT_RATES_HZ,
    COPTER_AGENT_STATE_STREAMS,
    COPTER_GCS_RATES_HZ,
    COPTER_GCS_STATE_STREAMS,
    EXTENDED_SYS_STATE,
    GCS_RATES_HZ,
    GCS_STATE_STREAMS,
    ODOMETRY,
)
from sitl_sim.physics.attitude_control import AttitudeGains
from sitl_sim.physics.vehicle_params import VehicleParams
from sitl_sim.physics.wind import Air
from sitl_sim.server import Status
from sitl_sim.shard import DroneRange, parse_drones
from sitl_sim.sim_config import (
    ClockConfig,
    NetConfig,
    SimConfig,
    SimConfigError,
    check_count,
    check_ports,
    check_positive,
    check_rates,
    crash_timeline,
    grid_positions,
    parse_gcs_url,
    parse_home,
    parse_sysids,
    read_signing_key,
    vehicles_from_scenario,
)
from sitl_sim.vehicle.autopilot import AutopilotConfig
from sitl_sim.vehicle.estimate import Sensors
from sitl_sim.vehicle.failsafe import FailsafeConfig
from sitl_sim.vehicle.tunables import FleetAttitudeGains, Tunables
from sitl_sim.vehicle.world import DEFAULT_EKF_READY_S, World, WorldConfig


@dataclass(frozen=True)
class _Vehicles:
    """What the scenario (or the defaults for ``--drones``) says about the vehicles."""

    params: VehicleParams
    gains: AttitudeGains
    positions_ned_m: FloatArray
    yaw_rad: FloatArray
    physics_hz: int
    control_hz: int
    seed: int
    crashes: tuple[tuple[float, int], ...]
    home: GeoPoint
    air: Air = field(default_factory=Air)
    #: each vehicle's (mass, thrust[, motor lag]) factors, the whole fleet's (empty: all alike)
    scales: tuple[tuple[float, ...], ...] = ()
    sensors: Sensors = field(default_factory=Sensors)


def build_config(args: argparse.Namespace) -> SimConfig:
    """Validate the parsed flags of ``swarm sim``; SimConfigError on the first mistake."""
    v, shard = _vehicles(args)
    n = len(v.positions_ned_m)
    first = 0 if shard is None else shard.first
    check_count(n)
    physics_hz = args.physics_hz if args.physics_hz is not None else v.physics_hz
    control_hz = args.control_hz if args.control_hz is not None else v.control_hz
    check_rates(physics_hz, control_hz)
    _check_numbers(args)
    gcs = parse_gcs_url(args.gcs)
    # a GCS on this machine must not share a port with a vehicle
    local_gcs = gcs is not None and (gcs[0].startswith("127.") or gcs[0] == args.bind)
    check_ports(args.base_port, first + n, gcs[1] if gcs is not None and local_gcs else None)
    key_file = args.signing_key
    if key_file is None and getattr(args, "secrets", None) is not None:
        key_file = args.secrets / "mavlink.key"
    autopilot = AutopilotConfig(failsafe=FailsafeConfig(offboard_timeout_s=args.offboard_timeout))
    dialect, ekf_ready_s = _dialect(args)
    agent_rates, gcs_rates = stream_rates(dialect, args.agent_rate_hz, args.gcs_rate_hz)
    if not v.sensors.ideal:
        # the report's truth beside what the vehicles believe, and each tick the land detector's
        # word to the agents before the tick's state (their estimated altitude wanders)
        gcs_rates[ODOMETRY] = args.gcs_rate_hz
        agent_rates = {EXTENDED_SYS_STATE: args.agent_rate_hz, **agent_rates}
    seed = v.seed if args.seed is None else args.seed
    return SimConfig(
        sysids=parse_sysids(args.sysids, n) if shard is None else _shard_sysids(args, shard),
        params=v.params,
        gains=v.gains,
        positions_ned_m=v.positions_ned_m,
        yaw_rad=v.yaw_rad,
        world=WorldConfig(
            physics_hz,
            control_hz,
            autopilot,
            args.position_noise_m,
            v.crashes,
            v.home if args.home is None else parse_home(args.home),
            dialect=dialect,
            ekf_ready_s=ekf_ready_s,
            air=v.air,
            air_seed=seed,
            vehicle_scales=v.scales,
            sensors=v.sensors,
            sensors_seed=seed,
            first_vehicle=first,
        ),
        net=NetConfig(
            bind_host=args.bind,
            base_port=args.base_port,
            gcs=gcs,
            signing_key=read_signing_key(key_file),
            first_drone=first,
            agent_rates_hz=agent_rates,
            gcs_rates_hz=gcs_rates,
        ),
        clock=ClockConfig(
            mode=args.clock,
            speedup=args.speedup,
            drop_timeout_s=args.lockstep_timeout,
            join_timeout_s=args.join_timeout,
            wait_agents=_wait_agents(args),
            duration_s=args.duration_s,
            start_at_unix_s=_start_at(args),
        ),
        seed=seed,
    )


def _vehicles(args: argparse.Namespace) -> tuple[_Vehicles, DroneRange | None]:
    """The vehicles served, and the drone range when this simulator is a shard."""
    if args.scenario is None and args.drones is None:
        raise SimConfigError("give --drones N (or LO-HI) or --scenario FILE")
    count, shard = parse_drones(args.drones) if args.drones is not None else (None, None)
    if args.scenario is not None and count is not None:
        raise SimConfigError("with --scenario, --drones takes a range LO-HI of its drones")
    if args.scenario is None:
        n = shard.last + 1 if shard is not None else count if count is not None else 0
        check_count(n)
        grid = grid_positions(n)
        v = _Vehicles(
            VehicleParams(), AttitudeGains(), grid, np.zeros(n), 500, 50, 0, (), GeoPoint()
        )
        return (v, None) if shard is None else (_slice(v, shard), shard)
    (params, gains, positions, yaw, physics_hz, control_hz, seed, faults, home, air, scales,
     sensors) = vehicles_from_scenario(args.scenario, args.seed)  # fmt: skip
    crashes = crash_timeline(faults)
    v = _Vehicles(
        params, gains, positions, yaw, physics_hz, control_hz, seed, crashes, home, air, scales,
        sensors,
    )  # fmt: skip
    if shard is None:
        return v, None
    if shard.last >= len(positions):
        raise SimConfigError(
            f"--drones {shard.first}-{shard.last}: the scenario has drones 0-{len(positions) - 1}"
        )
    return _slice(v, shard), shard


def _start_at(args: argparse.Namespace) -> float | None:
    start_at: float | None = getattr(args, "start_at", None)
    if start_at is not None and args.clock != "realtime":
        raise SimConfigError("--start-at needs --clock realtime (lockstep starts with its agents)")
    return start_at


def _slice(v: _Vehicles, shard: DroneRange) -> _Vehicles:
    """The vehicles of ``shard`` only (crashes renumbered to the shard's indices)."""
    rows = slice(shard.first, shard.last + 1)
    crashes = tuple((t, d - shard.first) for t, d in v.crashes if d in shard)
    return dataclasses.replace(
        v,
        positions_ned_m=v.positions_ned_m[rows],
        yaw_rad=v.yaw_rad[rows],
        crashes=crashes,
        scales=v.scales[rows],
    )


def _shard_sysids(args: argparse.Namespace, shard: DroneRange) -> tuple[int, ...]:
    if args.sysids is not None:
        raise SimConfigError("--sysids cannot be combined with a --drones range")
    return tuple(range(shard.first + 1, shard.last + 2))


def _check_numbers(args: argparse.Namespace) -> None:
    """Every numeric flag in its range."""
    positive = ("speedup", "offboard_timeout", "lockstep_timeout", "join_timeout",
                "agent_rate_hz", "gcs_rate_hz")  # fmt: skip
    for flag in positive:
        check_positive("--" + flag.replace("_", "-"), float(getattr(args, flag)))
    if args.duration_s is not None:
        check_positive("--duration-s", args.duration_s)
    if not (np.isfinite(args.position_noise_m) and args.position_noise_m >= 0):
        raise SimConfigError("--position-noise-m must be a number >= 0")
    if args.wait_agents is not None and args.wait_agents < 0:
        raise SimConfigError("--wait-agents must be >= 0")


def _dialect(args: argparse.Namespace) -> tuple[Dialect, float]:
    """--dialect (default px4) and --ekf-ready-s (ArduCopter only; default 2 s)."""
    try:
        dialect = Dialect(getattr(args, "dialect", None) or Dialect.PX4)
    except ValueError:
        names = ", ".join(d.value for d in Dialect)
        raise SimConfigError(f"--dialect {args.dialect!r}: one of {names}") from None
    ekf_ready_s = getattr(args, "ekf_ready_s", None)
    if ekf_ready_s is None:
        return dialect, DEFAULT_EKF_READY_S
    if dialect != Dialect.ARDUPILOT:
        raise SimConfigError("--ekf-ready-s is for --dialect ardupilot (PX4 is ready at once)")
    if not (np.isfinite(ekf_ready_s) and ekf_ready_s >= 0):
        raise SimConfigError(f"--ekf-ready-s must be a number >= 0, got {ekf_ready_s:g}")
    return dialect, float(ekf_ready_s)


def stream_rates(
    dialect: Dialect, agent_rate_hz: float, gcs_rate_hz: float
) -> tuple[dict[int, float], dict[int, float]]:
    """The default stream rates (Hz) of the agent links and of the GCS link in ``dialect``, the
    state messages at ``agent_rate_hz`` and ``gcs_rate_hz`` (``NetConfig``'s rates; for a
    :class:`NetConfig` built by hand for ArduCopter, so that GLOBAL_POSITION_INT, the lockstep's
    tick message, reaches the agents: sitl_sim/mavlink_edge/dialect.py)."""
    if dialect == Dialect.ARDUPILOT:
        return (
            _rates(COPTER_AGENT_RATES_HZ, COPTER_AGENT_STATE_STREAMS, agent_rate_hz),
            _rates(COPTER_GCS_RATES_HZ, COPTER_GCS_STATE_STREAMS, gcs_rate_hz),
        )
    return (
        _rates(AGENT_RATES_HZ, AGENT_STATE_STREAMS, agent_rate_hz),
        _rates(GCS_RATES_HZ, GCS_STATE_STREAMS, gcs_rate_hz),
    )


def _rates(
    defaults: Mapping[int, float], state_streams: Sequence[int], state_hz: float
) -> dict[int, float]:
    """``defaults`` with the messages ``state_streams`` at ``state_hz`` (Hz)."""
    rates = dict(defaults)
    rates.update(dict.fromkeys(state_streams, state_hz))
    return rates


def build_world(config: SimConfig) -> tuple[World, Tunables]:
    """The world of ``config`` (seeded) and its parameter table."""
    gains = FleetAttitudeGains(config.gains, config.n)
    world = World(
        config.params,
        gains,
        config.positions_ned_m,
        config.yaw_rad,
        config.world,
        np.random.default_rng(config.seed),
    )
    return world, tunables_for(world, gains, list(config.sysids))


#: How the start line begins: printed once the vehicles' ports are bound (`swarm up` starts the
#: agents on it, gcs/cli/supervisor.py).
START_LINE_PREFIX = "swarm sim: "


def start_line(config: SimConfig) -> str:
    """What is listening where, printed once at start-up."""
    net, clock = config.net, config.clock
    ports = vehicle_ports(net.first_drone + config.n, net.base_port)[net.first_drone :]
    ports_text = f"{net.bind_host}:{describe_ports(ports)}"
    gcs = "none" if net.gcs is None else f"udp:{net.gcs[0]}:{net.gcs[1]}"
    ids = f"{config.sysids[0]}..{config.sysids[-1]}" if config.n > 1 else str(config.sysids[0])
    signed = ", signed" if net.signing_key is not None else ""
    dialect = Dialect(config.world.dialect)
    speaks = f"dialect {dialect.value}"
    if dialect == Dialect.ARDUPILOT:
        speaks += f" (EKF ready after {config.world.ekf_ready_s:g} s)"
    return (
        f"{START_LINE_PREFIX}{config.n} vehicles (system ids {ids}) on UDP {ports_text}, GCS {gcs}"
        f"{signed}; "
        f"clock {clock.mode} x{clock.speedup:g}, physics {config.world.physics_hz} Hz, "
        f"control {config.world.control_hz} Hz; {speaks}"
    )


def status_line(s: Status) -> str:
    """The one-line status printed every second; in realtime how well the agents keep up, and
    a warning with what to do when they do not."""
    lockstep = "" if s.lockstep_members is None else f" | lockstep {s.lockstep_members} agents"
    timing = ""
    if s.in_time is not None:
        timing = f" | agents in time {s.in_time:6.1%} lag {s.worst_lag_ms or 0.0:.0f} ms"
        if s.overloaded:
            timing += (
                " | OVERLOAD: the agents cannot keep up in realtime on this machine;"
                " vehicles may fail safe (try --clock lockstep, or fewer processes)"
            )
    return (
        f"sim {s.sim_s:9.2f} s | wall {s.wall_s:8.1f} s | rtf {s.rtf:5.2f} | armed {s.armed} "
        f"flying {s.flying} failsafe {s.failsafe} crashed {s.crashed} | rx {s.rx} tx {s.tx} "
        f"rejected {s.rejected}{lockstep}{timing}"
    )


def _wait_agents(args: argparse.Namespace) -> int:
    """--wait-agents, defaulting to 1 in lockstep (the first agent starts time) and to 0 in
    realtime (time starts at once)."""
    if args.wait_agents is not None:
        return int(args.wait_agents)
    return 1 if args.clock == "lockstep" else 0

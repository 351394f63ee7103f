"""``swarm up --ardupilot-bin PATH``: fly ArduPilot's own ArduCopter SITL instead of our simulator.

ArduPilot is not part of this project: build ``arducopter`` for the ``sitl`` board from
ArduPilot's sources (docs/autopilots.md) and point ``--ardupilot-bin`` (or ``ARDUPILOT_SITL``) at
it. One ``arducopter`` process per drone, each with

- its system id (``--sysid i+1``) and instance number (``-I i``: its own TCP and simulator ports),
- its home where the scenario puts the drone: the drone's start position about the scenario's
  ``[home]`` (protocols/model/geodesy.py) and its heading, so that the scenario's layout holds,
- ``--serial0 udpclient:127.0.0.1:PORT``: its agent's link (the drone's usual port; the agent
  binds it, ``swarm agent --vehicle-listen``), ``--serial1 udpclient:127.0.0.1:GCS``: the ground
  station's,
- ArduPilot's copter defaults (``Tools/autotest/default_params/copter.parm`` beside the binary's
  build tree, or ``--ardupilot-defaults``) and the project's own few (the telemetry rates the
  ground station records, :data:`GCS_STREAM_PARAMS`), written into its working folder
  ``REPORT/logs/ardupilot-I`` (eeprom, ArduPilot's own logs; wiped at each start).

The instances run on ArduPilot's own physics model (``--model quad``) in real time, each on its
own clock from its own boot. Before the swarm starts, :func:`wait_ready` waits until every vehicle
is ready to fly (EKF using GPS, a 3-D fix, pre-arm checks passing, GUID_OPTIONS set: the agents'
own rule, drone_agent/process/dialects.py), however long that takes; the swarm's clock starts then
(``--swarm-epoch``), so the scenario's plan starts with every vehicle able to follow it.

What does not work (yet), and why: ``--clock lockstep`` (ArduPilot's SITL steps its own physics:
a lockstep would need our simulator as its physics through ``--model JSON``, where SITL waits for
each physics step; the agents' rounds would then have to follow that clock), ``--speedup`` other
than 1 (each instance would run its clock faster on its own; the swarm clock is the wall clock).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from gcs.cli.supervisor import Child, SupervisorError
from protocols.mavlink.conventions import Dialect, sysid_of

if TYPE_CHECKING:  # numpy: imported when a swarm comes up, not by the parser
    from protocols.scenario.scenario_file import Scenario

#: The environment variable naming the ArduCopter SITL binary (``--ardupilot-bin`` wins).
ENV = "ARDUPILOT_SITL"
#: ArduPilot's copter defaults, relative to the source tree the binary was built in
#: (``build/sitl/bin/arducopter``).
COPTER_DEFAULTS = Path("Tools/autotest/default_params/copter.parm")
#: The ground station's telemetry on SERIAL1, the second MAVLink channel (Hz): positions and
#: attitude as our simulator sends them (25 Hz), the rest slow; EXTRA3 carries
#: EKF_STATUS_REPORT. ArduPilot 4.7 names these MAV2_*, earlier releases SR1_*: both are written
#: (a release ignores the names it does not have).
_STREAMS = {
    "POSITION": 25, "EXTRA1": 25, "EXTRA2": 2, "EXTRA3": 2, "EXT_STAT": 2,
    "RAW_SENS": 0, "RC_CHAN": 0, "RAW_CTRL": 0,
}  # fmt: skip
GCS_STREAM_PARAMS = {
    f"{prefix}_{stream}": rate for prefix in ("MAV2", "SR1") for stream, rate in _STREAMS.items()
}
#: How long (wall s) the vehicles may take to become ready before swarm up gives up.
READY_TIMEOUT_S = 300.0


def find_binary(flag: Path | None) -> Path | None:
    """The ArduCopter binary of ``--ardupilot-bin`` or ``ARDUPILOT_SITL``, None if neither;
    SupervisorError if it is named but cannot be run."""
    named = flag if flag is not None else (Path(os.environ[ENV]) if os.environ.get(ENV) else None)
    if named is None:
        return None
    where = "--ardupilot-bin" if flag is not None else ENV
    if not named.is_file() or not os.access(named, os.X_OK):
        raise SupervisorError(
            f"{where} {named}: no executable file there; build ArduCopter SITL "
            "(./waf configure --board sitl && ./waf copter in ArduPilot's sources) and give "
            "build/sitl/bin/arducopter"
        )
    return named.resolve()


def default_params(binary: Path) -> Path | None:
    """ArduPilot's copter defaults in the source tree ``binary`` was built in, if found."""
    for parent in binary.parents:
        candidate = parent / COPTER_DEFAULTS
        if candidate.is_file():
            return candidate
    return None


def homes(scenario: Scenario) -> list[tuple[float, float, float, float]]:
    """Each drone's start as ArduPilot's ``--home``: latitude, longitude (deg), altitude (m MSL),
    heading (deg), from its start position about the scenario's home."""
    from protocols.model.geodesy import ned_to_geodetic

    start = scenario.positions_ned_m()
    lat, lon, alt = ned_to_geodetic(scenario.home, start)
    return [
        (float(lat[i]), float(lon[i]), float(alt[i]), float(d.yaw_deg) % 360.0)
        for i, d in enumerate(scenario.drones)
    ]


def vehicle_children(
    binary: Path,
    scenario: Scenario,
    ports: Sequence[int],
    gcs_port: int,
    logs: Path,
    defaults: Path | None,
) -> list[Child]:
    """One ``arducopter`` child per drone (module doc); its parameter file is written now."""
    children = []
    for i, (lat, lon, alt, yaw) in enumerate(homes(scenario)):
        folder = logs / f"ardupilot-{i}"
        folder.mkdir(parents=True, exist_ok=True)
        params = folder / "quadswarm.parm"
        params.write_text("".join(f"{k} {v}\n" for k, v in GCS_STREAM_PARAMS.items()))
        files = ",".join(str(p) for p in (defaults, params) if p is not None)
        argv = [
            str(binary), "-w", "--model", "quad", "--speedup", "1", "-I", str(i),
            "--sysid", str(sysid_of(i)), "--home", f"{lat:.9f},{lon:.9f},{alt:.3f},{yaw:.1f}",
            "--defaults", files,
            "--serial0", f"udpclient:127.0.0.1:{ports[i]}",
            "--serial1", f"udpclient:127.0.0.1:{gcs_port}",
        ]  # fmt: skip
        children.append(Child(f"arducopter {i}", argv, folder / "arducopter.log", cwd=folder))
    return children


def wait_ready(
    scenario: Scenario,
    ports: Sequence[int],
    vehicles: Sequence[Child],
    progress: Callable[[str], None] | None,
    timeout_s: float = READY_TIMEOUT_S,
) -> None:
    """Wait until every vehicle is ready to fly by its agents' own rule
    (drone_agent/process/dialects.py, read on each vehicle's agent port before the agents start),
    saying which are not and why. SupervisorError if an instance ends or the timeout passes."""
    from drone_agent.core.config import agent_config
    from drone_agent.process.vehicle_link import VehicleLink
    from protocols.model.frames import G_M_S2

    limits = agent_config(scenario).limits
    t2w = limits.max_thrust_n / (limits.mass_kg * G_M_S2)
    links = [
        VehicleLink(
            i, "127.0.0.1", port, dialect=Dialect.ARDUPILOT, thrust_to_weight=t2w, listen=True
        )
        for i, port in enumerate(ports)
    ]
    start = time.monotonic()
    said = -1e9
    try:
        while True:
            now = time.monotonic()
            for link, child in zip(links, vehicles, strict=True):
                if not child.running:
                    raise SupervisorError(
                        f"{child.role} ended before it was ready: {child.last_line()} "
                        f"(log: {child.log})"
                    )
                link.poll()
                link.service_dialect(now)
            waiting = [(link.index, link.dialect.not_ready_reason) for link in links]
            waiting = [(i, why) for i, why in waiting if why]
            if not waiting:
                if progress is not None:
                    took = now - start
                    progress(f"ardupilot: all {len(links)} vehicles ready after {took:.0f} s")
                return
            if now - start > timeout_s:
                i, why = waiting[0]
                raise SupervisorError(
                    f"{len(waiting)} ArduCopter vehicle(s) not ready after {timeout_s:g} s "
                    f"(drone {i}: {why}); see {vehicles[i].log}"
                )
            if progress is not None and now - said >= 5.0:
                said = now
                i, why = waiting[0]
                progress(
                    f"ardupilot: waiting for {len(waiting)} of {len(links)} vehicles to be ready "
                    f"({now - start:.0f} s; drone {i}: {why})"
                )
            time.sleep(0.05)
    finally:
        for link in links:
            link.close()

"""``swarm simulate``: fly a scenario in one process and write its report folder.

Writes ``flight.tlog`` (MAVLink 2 telemetry of every vehicle), ``events.jsonl``, ``metrics.json``,
``trajectory.json`` (the plan's knots and coefficients), the paper-style PNG plots and, where
Rerun is installed, ``flight.rrd`` (its recording, made from the files above:
gcs/view/recording.py).
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from gcs.reference.flight import FlightEvent, ReferenceFlight
from gcs.report.events import EventLog
from gcs.report.flight_record import FlightRecord
from gcs.report.metrics import compute_metrics
from gcs.report.tlog import TlogWriter
from gcs.report.trajectory_file import write_trajectory
from gcs.view.recording import report_recording
from protocols.model.plan_timing import takeoff_metrics
from protocols.scenario.scenario_file import Scenario

#: MAVLink MAV_STATE values used in heartbeats.
MAV_STATE_STANDBY, MAV_STATE_ACTIVE, MAV_STATE_EMERGENCY = 3, 4, 6
#: MAV_SEVERITY values used in status texts.
SEVERITY_CRITICAL, SEVERITY_WARNING, SEVERITY_INFO = 2, 4, 6
#: Rate (Hz) of the agents' statuses in the tlog (the ground station logs what they publish).
STATUS_HZ = 5.0
#: The flight's own events about a drone that go into the tlog as a STATUSTEXT, by severity (the
#: vehicles' events carry theirs, and their text, as the simulator sends them).
_EVENT_SEVERITY = {
    "fault": SEVERITY_WARNING,
    "agent_left": SEVERITY_WARNING,
}


@dataclass(frozen=True)
class SimulationResult:
    """What a run produced: the record, its events, the metrics and the files written."""

    record: FlightRecord
    events: list[FlightEvent]
    metrics: dict[str, Any]
    files: list[Path]


def simulate(
    scenario: Scenario,
    report_dir: Path,
    progress: Callable[[float], None] | None = None,
    tlog_hz: float = 25.0,
    plots: bool = True,
    recording: bool = True,
) -> SimulationResult:
    """Fly ``scenario`` in process and write the report into ``report_dir`` (created); with
    ``recording``, also ``flight.rrd`` where Rerun is installed (:mod:`gcs.view.recording`),
    without it none (an earlier flight's is removed: ``swarm replay`` makes it from the tlog)."""
    report_dir.mkdir(parents=True, exist_ok=True)
    flight = ReferenceFlight(scenario)
    startup = _process_age_s()
    wall0 = time.perf_counter()
    record = flight.run(progress, links_every=status_stride(scenario.rates.dt_control_s))
    wall = time.perf_counter() - wall0
    files = [
        _write_tlog(record, flight.events, report_dir / "flight.tlog", tlog_hz, flight.silent_from),
        _write_events(flight.events, report_dir / "events.jsonl"),
        write_trajectory(flight.flown_plan(), report_dir / "trajectory.json"),
    ]
    faults = [
        (e.t_s, str(e.fields.get("description", e.kind)))
        for e in flight.events
        if e.kind == "fault"
    ]
    metrics = compute_metrics(
        record,
        settle_s=scenario.settle_s,
        faults=faults,
        max_thrust_n=flight.params.max_thrust_n,
        extra={
            "scenario": scenario.name,
            "source": scenario.source,
            "seed": scenario.seed,
            "mode": "in-process reference (swarm simulate)",
            "wall_time_s": round(wall, 3),
            # how long the process had run when the flight started (imports, compiled code,
            # scenario; the flight's set-up): swarm simulate's start-up
            "startup_s": None if startup is None else round(startup, 2),
            "real_time_factor": round(scenario.duration_s / wall, 3) if wall > 0 else None,
            "settle_s": scenario.settle_s,
            "takeoff": takeoff_metrics(flight.takeoff_s, flight.plan),
            "messages": {
                "sent": flight.network.sent,
                "delivered": flight.network.delivered,
                "lost": flight.network.lost,
                # of which the radio's limits dropped (drone_agent/process/radio.py), by why
                **(
                    {}
                    if flight.network.radio is None
                    else {"radio_lost": dataclasses.asdict(flight.network.radio.counts)}
                ),
            },
            "rejected_setpoints": sum(a.rejected_setpoints for a in flight.agents.values()),
        },
    )
    metrics_path = report_dir / "metrics.json"
    metrics_path.write_text(json.dumps(metrics, indent=2) + "\n")
    files.append(metrics_path)
    if plots:
        from gcs.report.plots import write_plots  # matplotlib: ~0.3 s, paid only when plotting

        files += write_plots(record, report_dir)
    if (rrd := report_recording(report_dir, scenario.n_drones, recording)) is not None:
        files.append(rrd)
    return SimulationResult(record, flight.events, metrics, files)


def _process_age_s() -> float | None:
    """Seconds since this process started (Linux: /proc/self/stat's start time, in clock ticks
    since boot); None where that cannot be read."""
    try:
        fields = Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()
        started_s = int(fields[19]) / os.sysconf("SC_CLK_TCK")  # field 22 of the line
        return time.clock_gettime(time.CLOCK_BOOTTIME) - started_s
    except (OSError, ValueError, IndexError, AttributeError):
        return None


def status_stride(dt_s: float) -> int:
    """Every how many samples ``dt_s`` apart an agent's status is logged (:data:`STATUS_HZ`)."""
    return max(1, round(1.0 / (STATUS_HZ * dt_s)))


def _write_tlog(
    record: FlightRecord,
    events: list[FlightEvent],
    path: Path,
    hz: float,
    silent_from: dict[int, float],
) -> Path:
    """Telemetry of every vehicle at ``hz`` (system id = index + 1), heartbeats at 1 Hz, each
    live agent's status (estimate, neighbour count and ids; as the ground station logs it, mode
    unknown: NaN) at :data:`STATUS_HZ`, and a STATUSTEXT for each event about a drone (a
    vehicle's own, as it sent it). Vehicles in ``silent_from`` stop after that time."""
    t = record.t_s
    stride = max(1, round(1.0 / (hz * (t[1] - t[0])))) if t.size > 1 else 1
    status_every = status_stride(t[1] - t[0]) if t.size > 1 else 1
    hb_stride = max(1, round(1.0 / (t[1] - t[0]))) if t.size > 1 else 1
    rates = record.body_rates_rad_s
    armed = record.armed
    reported, quat = record.reported, record.quat_wxyz
    pending = sorted(events, key=lambda e: e.t_s)
    with TlogWriter(path) as log:
        for k in range(0, t.size):
            while pending and pending[0].t_s <= t[k]:
                ev = pending.pop(0)
                drone = ev.fields.get("drone")
                said = _statustext(ev)
                if isinstance(drone, int) and said is not None:
                    log.write_statustext(ev.t_s, drone + 1, *said)
            if k % stride and k % hb_stride and k % status_every:
                continue
            if k % stride == 0:  # this tick's samples as lists of floats, once for every drone
                sample = [
                    values[k].tolist()
                    for values in (
                        (record.position_ned_m, record.velocity_ned_m_s, record.euler_rad)
                        if reported is None
                        else reported  # what the vehicles reported, then their true state
                    )
                ]
                body_k = rates[k].tolist() if rates is not None else [[0.0] * 3] * record.n_drones
            for i in range(record.n_drones):
                if t[k] > silent_from.get(i, np.inf):
                    continue
                if k % hb_stride == 0:
                    is_armed = bool(armed[k, i]) if armed is not None else True
                    state = (
                        MAV_STATE_EMERGENCY
                        if not record.member[k, i]
                        else MAV_STATE_ACTIVE
                        if is_armed
                        else MAV_STATE_STANDBY
                    )
                    log.write_heartbeat(float(t[k]), i + 1, is_armed, state)
                if k % stride == 0:
                    log.write_vehicle_sample(
                        float(t[k]), i + 1, sample[0][i], sample[1][i], sample[2][i], body_k[i]
                    )
                    if reported is not None and quat is not None:
                        log.write_truth(
                            float(t[k]), i + 1, record.position_ned_m[k, i],
                            record.velocity_ned_m_s[k, i], quat[k, i], np.array(body_k[i]),
                        )  # fmt: skip
                if k % status_every == 0 and np.all(np.isfinite(record.estimate[k, i])):
                    on = float(armed[k, i]) if armed is not None else 1.0
                    values = [*record.estimate[k, i], record.neighbours[k, i], np.nan, on]
                    ids = record.neighbour_ids.get(k, {}).get(i)  # None: not kept
                    log.write_agent_status(float(t[k]), i + 1, np.array(values, dtype=float), ids)
    return path


def _statustext(event: FlightEvent) -> tuple[int, str] | None:
    """The (severity, text) of ``event``'s STATUSTEXT, None if it has none: a vehicle's event
    as its vehicle said it, a fault or an agent leaving as the flight says it."""
    severity, text = event.fields.get("severity"), event.fields.get("text")
    if isinstance(severity, int) and isinstance(text, str):
        return severity, text[:150]
    if event.kind not in _EVENT_SEVERITY:
        return None
    why = event.fields.get("reason", event.fields.get("description", ""))
    return _EVENT_SEVERITY[event.kind], f"{event.kind}: {why}"[:150]


def _write_events(events: list[FlightEvent], path: Path) -> Path:
    with EventLog(path) as log:
        for e in events:
            log.record(e.t_s, e.kind, **e.fields)
    return path


#: How long ``swarm scenario check`` waits for a scenario's swarm to be ready (simulated s).
READY_LIMIT_S = 60.0


def ready_time_s(scenario: Scenario, limit_s: float = READY_LIMIT_S) -> float | None:
    """When the scenario's swarm is ready to leave the ground (s): measured by flying it in
    process, without its faults, until its agents agree to take off (the one readiness rule,
    drone_agent/core/flight_phase.py); None if not within ``limit_s``. The plan does not change it:
    a plan that starts on the ground is held until then (protocols/model/plan_timing.py)."""
    calm = replace(scenario, faults=(), duration_s=max(scenario.duration_s, limit_s))
    return ReferenceFlight(calm).run_until_takeoff(limit_s)

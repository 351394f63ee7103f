"""A flight's report folder as data: :func:`load_report`.

The flight is rebuilt from the report's own files, by the code that wrote its ``metrics.json``
(:func:`gcs.report.from_logs.build_record`, :func:`gcs.report.from_logs.record_metrics`):
``flight.tlog`` (every vehicle's telemetry and every agent's status), ``events.jsonl``,
``trajectory.json`` (the plan as flown). Samples lie on one grid of simulated time at the
telemetry rate, held from the newest sample (an agent's estimate: at most 1 s old, else NaN).

Arrays: T samples, N drones (index i is MAVLink system id i + 1); NED metres, radians,
descriptor rows in the order of :data:`protocols.model.descriptor_vector.NAMES`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from gcs.api.errors import UsageError
from gcs.report.flight_record import FlightRecord
from protocols.model.frames import FloatArray
from protocols.model.trajectory import DescriptorTrajectory

if TYPE_CHECKING:
    import pandas as pd

    from protocols.scenario.scenario_file import Scenario

#: The telemetry rate of a report's record (Hz): ``swarm up``'s and ``swarm simulate``'s default.
REPORT_RATE_HZ = 25.0
#: Where ``swarm up --drones N`` writes its session's scenario, in the report folder.
SESSION_SCENARIO = Path("logs") / "session.toml"


@dataclass(frozen=True)
class FlightReport:
    """One flight as arrays (module doc).

    - ``t_s`` (T,) simulated s.
    - ``positions_ned_m`` (T, N, 3), ``velocities_ned_m_s`` (T, N, 3).
    - ``attitudes_rad`` (T, N, 3): roll, pitch, yaw of each vehicle.
    - ``thrust_n`` (T, N), collective thrust from the rotor forces.
    - ``estimates`` (T, N, 9): each agent's estimate of the descriptors (NaN: no status).
    - ``plan`` (T, 9): the commanded descriptors; ``true_descriptors`` (T, 9): those of the
      member drones' positions (NaN with fewer than two).
    - ``member`` (T, N): in the swarm; ``airborne`` (T, N): off the ground.
    - ``events``: ``events.jsonl``, one dict per event (``t_s``, ``kind``, fields).
    - ``trajectory``: the plan as flown; ``metrics_file``: ``metrics.json`` as written;
      ``record``: the :class:`~gcs.report.flight_record.FlightRecord` all this comes from.
    """

    folder: Path
    t_s: FloatArray
    positions_ned_m: FloatArray
    velocities_ned_m_s: FloatArray
    attitudes_rad: FloatArray
    thrust_n: FloatArray
    estimates: FloatArray
    plan: FloatArray
    true_descriptors: FloatArray
    member: npt.NDArray[np.bool_]
    airborne: npt.NDArray[np.bool_]
    events: list[dict[str, Any]]
    trajectory: DescriptorTrajectory
    metrics_file: dict[str, Any]
    record: FlightRecord
    settle_s: float = 0.0
    max_thrust_n: float | None = None

    @property
    def n_drones(self) -> int:
        return int(self.positions_ned_m.shape[1])

    def metrics(self) -> dict[str, Any]:
        """``metrics.json``'s figures computed from this flight by the code that wrote it
        (tracking, consensus, re-convergence, separation, ...); the run's own facts (wall time,
        layout, real-time factor) are only in :attr:`metrics_file`."""
        from gcs.report.from_logs import record_metrics

        return record_metrics(self.record, self.settle_s, {}, self.max_thrust_n)

    def events_of(self, kind: str) -> list[dict[str, Any]]:
        """The events of one ``kind`` (``command``, ``takeoff``, ``crash``, ...), in order."""
        return [e for e in self.events if e.get("kind") == kind]

    def to_pandas(self) -> pd.DataFrame:
        """The samples as a pandas DataFrame indexed by (``t_s``, ``drone``): position,
        velocity, attitude, thrust, estimate (``est_`` + descriptor name), member, airborne.
        Needs pandas (``pip install 'quadswarm[pandas]'``)."""
        try:
            import pandas as pd
        except ImportError:
            raise UsageError("to_pandas needs pandas: pip install 'quadswarm[pandas]'") from None
        from protocols.model.descriptor_vector import NAMES

        t, n = self.t_s.size, self.n_drones
        columns: dict[str, Any] = {}
        for k, name in enumerate(("north_m", "east_m", "down_m")):
            columns[name] = self.positions_ned_m[..., k].ravel()
        for k, name in enumerate(("vn_m_s", "ve_m_s", "vd_m_s")):
            columns[name] = self.velocities_ned_m_s[..., k].ravel()
        for k, name in enumerate(("roll_rad", "pitch_rad", "yaw_rad")):
            columns[name] = self.attitudes_rad[..., k].ravel()
        columns["thrust_n"] = self.thrust_n.ravel()
        for k, name in enumerate(NAMES):
            columns[f"est_{name}"] = self.estimates[..., k].ravel()
        columns["member"] = self.member.ravel()
        columns["airborne"] = self.airborne.ravel()
        index = pd.MultiIndex.from_arrays(
            [np.repeat(self.t_s, n), np.tile(np.arange(n), t)], names=["t_s", "drone"]
        )
        return pd.DataFrame(columns, index=index)


def load_report(
    folder: str | Path, scenario: str | Path | Scenario | None = None, rate_hz: float | None = None
) -> FlightReport:
    """The flight of the report ``folder`` (written by ``swarm up``, ``swarm demo`` or
    ``swarm simulate``) as arrays. ``scenario``: the scenario flown (a path or a loaded one; an
    operator session's is found in the folder), for the vehicles' parameters and the drone count;
    without it they are the defaults and the drones the telemetry heard. ``rate_hz``: the
    record's sample rate (default the telemetry rate, 25 Hz). UsageError naming what is missing.

    For a ``swarm up`` report, :meth:`FlightReport.metrics` equals its ``metrics.json``. A
    ``swarm simulate`` report's ``metrics.json`` was computed in the process at the control rate:
    from the 25 Hz log, tracking and separation agree with it within 2 % and the same drones are
    lost (give its ``scenario``: the drop-outs and crashes say who was in the swarm); consensus
    figures come from the agents' 5 Hz statuses and differ where the estimates move fast."""
    from gcs.report.events import read_events
    from gcs.report.log_record import build_record
    from gcs.report.metrics import true_descriptors
    from gcs.report.tlog import read_tlog
    from gcs.report.trajectory_file import read_trajectory
    from protocols.scenario.scenario_file import Scenario, load_scenario
    from sitl_sim.physics.vehicle_params import VehicleParams
    from sitl_sim.vehicle.config import vehicle_params

    root = Path(folder)
    for name in ("flight.tlog", "trajectory.json"):
        if not (root / name).is_file():
            raise UsageError(f"{root} is not a flight's report: it has no {name}")
    if scenario is None and (root / SESSION_SCENARIO).is_file():
        scenario = root / SESSION_SCENARIO
    if scenario is not None and not isinstance(scenario, Scenario):
        try:
            scenario = load_scenario(scenario)
        except (ValueError, OSError) as exc:
            raise UsageError(str(exc)) from None
    events = read_events(root / "events.jsonl") if (root / "events.jsonl").exists() else []
    metrics_file: dict[str, Any] = {}
    if (root / "metrics.json").is_file():
        metrics_file = json.loads((root / "metrics.json").read_text())
    track = read_tlog(root / "flight.tlog")
    heard = [s for s, v in track.vehicles.items() if v.t_s.size and 1 <= s <= 250]
    n = scenario.n_drones if scenario is not None else max(heard, default=0)
    plan = read_trajectory(root / "trajectory.json")
    rate = REPORT_RATE_HZ if rate_hz is None else rate_hz
    members = _membership(events, scenario, n)
    record = build_record(
        root / "flight.tlog", root / "events.jsonl", plan, n, rate, _end_s(events), scenario, track,
        events + members,
    )  # fmt: skip
    if record is None:
        raise UsageError(f"{root}: its flight.tlog holds no vehicle's telemetry")
    params = vehicle_params(scenario) if scenario is not None else VehicleParams()
    settle = metrics_file.get("settle_s")
    if not isinstance(settle, int | float):
        settle = scenario.settle_s if scenario is not None else 0.0
    return FlightReport(
        folder=root,
        t_s=record.t_s,
        positions_ned_m=record.position_ned_m,
        velocities_ned_m_s=record.velocity_ned_m_s,
        attitudes_rad=record.euler_rad,
        thrust_n=record.thrust_n,
        estimates=record.estimate,
        plan=record.desired,
        true_descriptors=true_descriptors(record),
        member=record.member,
        airborne=record.airborne,
        events=events,
        trajectory=plan,
        metrics_file=metrics_file,
        record=record,
        settle_s=float(settle),
        max_thrust_n=params.max_thrust_n,
    )


def _membership(
    events: list[dict[str, Any]], scenario: Scenario | None, n: int
) -> list[dict[str, Any]]:
    """Who was in the swarm, as events, for a ``swarm simulate`` report, whose events do not say
    it (the ground station logs each agent joining and leaving): every drone from the start
    until its scenario's drop-out or crash, as ``swarm simulate`` counts them. Nothing for a
    ground station's report."""
    simulated = any(e.get("kind") == "run_start" and "drones" in e for e in events)
    if not simulated or any(e.get("kind") == "agent_joined" for e in events):
        return []
    from protocols.faults import Crash, Dropout

    out: list[dict[str, Any]] = [{"t_s": 0.0, "kind": "agent_joined", "drone": i} for i in range(n)]
    for fault in scenario.faults if scenario is not None else ():
        if isinstance(fault, Dropout | Crash):
            kind = "crash" if isinstance(fault, Crash) else "dropout_detected"
            out.append({"t_s": fault.t_s, "kind": kind, "drone": fault.drone})
    return sorted(out, key=lambda e: float(e["t_s"]))


def _end_s(events: list[dict[str, Any]]) -> float:
    """Where the record ends: the ground station's ``report_end_s`` at its run's end, else the
    run's planned end, else the last sample."""
    for kind, key in (("run_end", "report_end_s"), ("run_start", "end_s")):
        said = [e.get(key) for e in events if e.get("kind") == kind]
        values = [float(v) for v in said if isinstance(v, int | float)]
        if values:
            return values[-1]
    return math.inf

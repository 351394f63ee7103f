"""What ``swarm scenario check`` says about a scenario: a summary, and whether its plan stays
inside the operator envelope (the ground station's geofence, tilt and spread limits). Pure.

The envelope (gcs/station/planner.py, its defaults) is what the ground station holds operator
commands to; a scenario's own plan is not a command, but a plan outside it would be refused the
moment an operator tried to continue it, so ``check`` and ``new`` hold scenarios to it too.
"""

from __future__ import annotations

import math

import numpy as np

from gcs.station.planner import Envelope, PlanRefused, check_target, envelope_of
from protocols.faults import Crash, Delay, Dropout, Fault, LinkCut, Loss, Partition
from protocols.model.formation_fit import closest_pair, formation_positions
from protocols.model.frames import G_M_S2
from protocols.model.plan_timing import departure_s, lead_in_s
from protocols.scenario.layout import radio_graph
from protocols.scenario.scenario_file import Scenario, WaypointConfig

#: Plan samples per simulated second for the envelope check.
ENVELOPE_SAMPLES_PER_S = 2.0
#: Waypoints listed in full up to this many; beyond, the first and last few.
MAX_WAYPOINT_ROWS = 12


def envelope_problem(scenario: Scenario, envelope: Envelope | None = None) -> str | None:
    """Why the scenario's plan leaves ``envelope`` (default: the ground station's), or None.

    The waypoints are checked as written, then the plan is sampled at every knot and twice a
    second to ``duration_s`` or its end, whichever is later (a plan written in the air from its
    start is flown later, after a climb)."""
    env = envelope or envelope_of(scenario.safety)
    for w in scenario.waypoints:  # as written first: the message names the file's time
        try:
            check_target(w.waypoint().value, env)
        except PlanRefused as exc:
            return f"at t = {w.t_s:g} s: {exc}"
    plan = scenario.trajectory()
    end_s = max(scenario.duration_s, plan.end_s)
    n = max(2, math.ceil(end_s * ENVELOPE_SAMPLES_PER_S) + 1)
    t = np.union1d(np.linspace(0.0, end_s, n), plan.t_knots_s)
    values = plan.evaluate_many(t)[0]
    for t_s, a in zip(t, values, strict=True):
        try:
            check_target(a, env)
        except PlanRefused as exc:
            return f"at t = {t_s:g} s: {exc}"
    return None


def closest_in_formation(scenario: Scenario) -> tuple[float, float]:
    """The smallest predicted distance (m) between two drones over the plan's waypoints, and the
    waypoint time (s) where it occurs (protocols/model/formation_fit.py: the field maps the
    start)."""
    start = scenario.positions_ned_m()
    best, when = math.inf, 0.0
    for w in scenario.waypoints:
        d, _ = closest_pair(formation_positions(start, w.waypoint().value))
        if d < best:
            best, when = d, w.t_s
    return best, when


def describe_fault(fault: Fault) -> str:
    """One line per fault, e.g. ``t = 30 s: crash of drone 1 (system id 2)``."""
    until = getattr(fault, "duration_s", None)
    span = f" for {until:g} s" if until is not None else ""
    head = f"t = {fault.t_s:g} s: "
    if isinstance(fault, Dropout | Crash):
        what = "agent drop-out" if isinstance(fault, Dropout) else "vehicle crash"
        return head + f"{what}, drone {fault.drone} (system id {fault.drone + 1})"
    if isinstance(fault, LinkCut):
        way = " one way" if fault.one_way else ""
        return head + f"link cut {fault.i}-{fault.j}{way}{span}"
    if isinstance(fault, Loss | Delay):
        pair = fault.link
        where = "every link" if pair is None else f"link {pair[0]}-{pair[1]}"
        if isinstance(fault, Loss):
            return head + f"{fault.probability:.0%} loss on {where}{span}"
        return head + f"{fault.delay_ms:g} ms delay on {where}{span}"
    assert isinstance(fault, Partition)
    return head + f"partition into {len(fault.groups)} groups (+ the rest){span}"


def _envelope_line(scenario: Scenario) -> str:
    problem = envelope_problem(scenario)
    if problem is not None:
        return f"the plan leaves the ground station's envelope {problem}"
    env = envelope_of(scenario.safety)
    return (
        f"the plan stays inside the ground station's geofence (north "
        f"{env.fence_north_m[0]:g}..{env.fence_north_m[1]:g} m, east "
        f"{env.fence_east_m[0]:g}..{env.fence_east_m[1]:g} m, altitude "
        f"{env.fence_altitude_m[0]:g}..{env.fence_altitude_m[1]:g} m) and spreads "
        f"<= {env.max_spread_m:g} m"
    )


def _fleet_line(sc: Scenario) -> str:
    """All alike, or how the vehicles' mass and thrust spread (1 sigma); their motors' time
    constant and its spread where the motors lag."""
    f, tau_s = sc.vehicles, sc.vehicle.motor_tau_s
    motors = f", motors' time constant {1000 * tau_s:g} ms" if tau_s > 0.0 else ""
    tau_spread = f.motor_tau_spread if tau_s > 0.0 else 0.0
    if f.mass_spread == 0.0 and f.thrust_spread == 0.0 and tau_spread == 0.0:
        return f"all alike ({sc.vehicle.mass_kg:g} kg{motors})"
    within = f" within {100 * tau_spread:g} %" if tau_spread > 0.0 else ""
    return (
        f"{sc.vehicle.mass_kg:g} kg, each one's mass within {100 * f.mass_spread:g} % and thrust "
        f"within {100 * f.thrust_spread:g} %{motors}{within} (1 sigma, drawn from the seed)"
    )


def _sensors_lines(sc: Scenario, tightest_m: float) -> list[str]:
    """Ideal, or what the vehicles' estimates get wrong; a warning where the GNSS bias is large
    against the plan's closest spacing (each drone flies its own believed place)."""
    s = sc.sensors
    if s.ideal:
        return ["sensors    ideal: the agents fly on the true state"]
    rate = "every tick" if s.rate_hz == 0.0 else f"{s.rate_hz:g} Hz"
    lines = [
        f"sensors    GNSS bias {s.gnss_bias_m:g} m (height {s.altitude_bias_m:g} m) wandering over "
        f"{s.gnss_bias_tau_s:g} s; noise {s.position_noise_m:g} m, {s.velocity_noise_m_s:g} m/s, "
        f"{s.attitude_noise_rad:g} rad; {rate}, {1000 * s.latency_s:g} ms late"
    ]
    if s.gnss_bias_m > tightest_m / BIAS_SPACING_RATIO:
        closer = 2.0 * math.sqrt(2.0) * s.gnss_bias_m
        lines.append(
            f"  WARNING: a GNSS bias of {s.gnss_bias_m:g} m against formations {tightest_m:.2f} m "
            f"apart: each drone flies its own believed place, so two may come {closer:.1f} m "
            f"closer than planned (2 sigma); space them {BIAS_SPACING_RATIO:g} x the bias apart "
            "or fly RTK (docs/scenarios.md)"
        )
    return lines


#: ``swarm scenario check`` warns where the plan's closest spacing is below this many GNSS biases
#: (docs/scenarios.md: a 2 m bias on a 2.5 m grid collided, on an 8 m grid it held)
BIAS_SPACING_RATIO = 4.0


def _radio_line(sc: Scenario) -> str:
    """Range only, or the radio's limits."""
    r = sc.radio
    if r.ideal:
        return f"range {sc.comms.range_m:g} m only"
    parts = []
    if r.bandwidth_bytes_s > 0.0:
        parts.append(f"{r.bandwidth_bytes_s / 1000:g} kB/s a link, queue {r.queue_messages}")
    if r.loss_half_m > 0.0:
        parts.append(f"half lost at {r.loss_half_m:g} m (exponent {r.path_loss_exponent:g}, "
                     f"fading {r.fading_db:g} dB)")  # fmt: skip
    if r.burst_fraction > 0.0 and r.burst_loss > 0.0:
        parts.append(f"{100 * r.burst_fraction:g} % in bursts of {r.burst_length:g}")
    if r.latency_s > 0.0 or r.jitter_s > 0.0:
        parts.append(f"latency {1000 * r.latency_s:g} ms + jitter {1000 * r.jitter_s:g} ms")
    return "; ".join(parts)


def _air_line(sc: Scenario) -> str:
    """Still air, or the wind (speed, where from, NED), the gusts, the drag and the tilt a vehicle
    needs to hold its place against the wind (drag times wind speed, against gravity)."""
    env, v = sc.environment, sc.vehicle
    if env.calm:
        drag = "" if v.drag_xy_per_s == 0 else f"; drag {v.drag_xy_per_s:g} / {v.drag_z_per_s:g} /s"
        return "still" + drag
    n, e, d = env.wind_ned_m_s
    speed = math.hypot(n, e, d)
    origin = (math.degrees(math.atan2(-e, -n)) + 360.0) % 360.0
    tilt = math.degrees(math.atan2(v.drag_xy_per_s * math.hypot(n, e), G_M_S2))
    return (
        f"wind {speed:.1f} m/s from {origin:.0f} deg (NED {n:g}, {e:g}, {d:g}), gusts "
        f"{env.turbulence_m_s:g} m/s over {env.turbulence_scale_m:g} m; drag "
        f"{v.drag_xy_per_s:g} / {v.drag_z_per_s:g} /s: holding station takes {tilt:.1f} deg of tilt"
    )


def summary_lines(scenario: Scenario) -> list[str]:
    """The human-readable summary ``swarm scenario check`` prints."""
    sc = scenario
    x = sc.positions_ned_m()
    graph = radio_graph(x, sc.comms.range_m)
    spacing, (i, j) = closest_pair(x)
    linked = "connected" if graph.connected else f"NOT connected: {graph.components} parts"
    cons = sc.consensus
    gain = f"degree-normalised rho {cons.rho:g}" if cons.degree_normalised else f"rho {cons.rho:g}"
    tightest, when = closest_in_formation(sc)
    lines = [
        f"{sc.source}: valid (version {sc.version}), name '{sc.name}'",
        f"drones     {sc.n_drones}; closest two on the ground {spacing:.2f} m apart "
        f"(drones {i} and {j})",
        f"duration   {sc.duration_s:g} s (metrics from {sc.settle_s:g} s), seed {sc.seed}",
        f"radio      range {sc.comms.range_m:g} m: {linked} at the start; neighbours per drone "
        f"min {graph.degree_min} / mean {graph.degree_mean:.1f} / max {graph.degree_max}",
        f"consensus  {gain}, c {cons.c:g}, warm-up {cons.warmup_s:g} s on the ground",
        f"safety     min separation {sc.safety.min_separation_m:g} m; the plan's formations "
        f"keep the drones at least {tightest:.2f} m apart (at t = {when:g} s)",
        f"envelope   {_envelope_line(sc)}",
        f"air        {_air_line(sc)}",
        f"vehicles   {_fleet_line(sc)}",
        *_sensors_lines(sc, tightest),
        f"radio link {_radio_line(sc)}",
        f"faults     {len(sc.faults) or 'none'}",
        *(f"  {describe_fault(f)}" for f in sorted(sc.faults, key=lambda f: f.t_s)),
        f"waypoints  {len(sc.waypoints)}, t = {sc.waypoints[0].t_s:g}..{sc.waypoints[-1].t_s:g} s",
        "  t_s       centre N, E (m)   alt (m)  yaw (deg)  spreads L, W, H (m)",
    ]
    rows: list[WaypointConfig | None] = list(sc.waypoints)
    if len(rows) > MAX_WAYPOINT_ROWS:
        keep = MAX_WAYPOINT_ROWS // 2
        rows = [*rows[:keep], None, *rows[-keep:]]
    for w in rows:
        if w is None:
            lines.append(f"  ... {len(sc.waypoints) - 2 * (MAX_WAYPOINT_ROWS // 2)} more")
            continue
        n, e, z = w.centre_ned_m
        spreads = ", ".join(f"{math.sqrt(max(v, 0.0)):.2f}" for v in w.variance_m2)
        lines.append(
            f"  {w.t_s:<8g}  {n:7.2f}, {e:7.2f}  {0.0 - z:7.2f}  {w.yaw_deg:9.1f}  {spreads}"
        )
    return lines


def takeoff_lines(scenario: Scenario, ready_s: float | None, limit_s: float) -> list[str]:
    """What ``swarm scenario check`` says of the take-off, given when the swarm was measured
    ready to leave the ground (``ready_s``; None: not within ``limit_s``): the time, and a
    warning when the plan moves before it (it is then flown late:
    protocols/model/plan_timing.py)."""
    plan = scenario.trajectory()
    hold = departure_s(plan, plan.start_s)
    if ready_s is None:
        agree_only = scenario.consensus.settle == "agree"
        why = (
            '[sensors] error, radio graph, consensus gains: with [consensus] settle = "agree" '
            "the agents leave together once their estimates agree to 2 %, which noise on the "
            'vehicles\' positions keeps them from; settle = "auto" lets them leave once the '
            "disagreement has stopped falling"
            if scenario.sensors.lie and agree_only
            else "radio graph, consensus gains"
        )
        return [
            f"take-off   WARNING: the swarm was not ready to leave the ground within "
            f"{limit_s:g} s (measured in process): its estimates do not settle ({why})"
        ]
    lines = [
        f"take-off   the swarm is ready to leave the ground at t = {ready_s:.2f} s (measured "
        f"in process: {scenario.n_drones} drones, this radio graph, warm-up "
        f"{scenario.consensus.warmup_s:g} s)"
    ]
    altitude = -scenario.waypoints[0].centre_ned_m[2]
    if late := lead_in_s(altitude):
        lines.append(
            f"  NOTE: the plan starts {altitude:.1f} m up: the swarm climbs to it from the "
            f"ground first, in {late:g} s, and flies its waypoints that much later"
        )
    # hold is None only for a plan airborne from its start, which a scenario's never is
    if hold is not None and hold < ready_s:
        lines.append(
            f"  WARNING: the plan starts moving at t = {hold:g} s, before the swarm can be "
            f"ready: it will be flown about {ready_s - hold:.2f} s late (held on the ground "
            f"and re-timed to the take-off). To fly it on the scenario's clock, rest on the "
            f"ground until t = {math.ceil(ready_s):g} s"
        )
    return lines

"""Cost of the simulator's part of one 50 Hz control tick: 10 physics sub-steps with inner loops.

``python -m bench.physics_tick`` (or ``python -m bench.run --only physics_tick``).

For N = 9, 25, 100, 250 vehicles hovering on a grid (attitude setpoints that change every tick, so
the attitude loop works), it times one control tick, i.e. 10 sub-steps of 2 ms, four ways:

- ``reference``: ``inner_loop`` + ``step_with_contact`` per sub-step, as the simulator ran before
  the fused kernel (the readable reference functions, still in sitl_sim/);
- ``kernel``: :class:`sitl_sim.physics.kernel.PhysicsKernel` (same arithmetic, fused);
- ``world_reference`` / ``world``: the whole tick of ``swarm sim``'s
:class:`~sitl_sim.vehicle.world.World`
  (autopilot guidance, the 10 sub-steps, autopilot update) with the reference loop and with
  :meth:`World.step`,

each with every vehicle airborne (``airborne``) and with one vehicle resting on the ground, motors
off, as a crashed drone does for the rest of a flight (``one_down``: ground contact every step).

Timing: each figure is the **median of ``REPEATS`` repeats**, a repeat being the mean over
``TICKS`` control ticks (the variants take turns within a repeat); the minimum is reported too.
The machine has 2 cores that other engineers use at the same time, so single runs are noisy:
compare medians. The JSON goes to ``bench/results_physics_tick.json`` (``bench/run.py``: into its
``--out`` file).

:func:`profile` also times, before/after, one control tick per part of ``swarm simulate``
(agents, physics, the rest) at N = 9 (the paper scenario, its first 40 s: take-off, link cuts,
the crash at 30 s) and N = 100 (a 10 x 10 grid 2.5 m apart hovering at 3 m, range 6 m; its first
6 s), and of ``swarm sim`` (World.step, telemetry out, MAVLink in) at N = 9 and 100 flat out
next to bench/sitl.py's agent-playing client; the text goes to ``bench/physics_tick_profile.txt``
and into the JSON. All of it takes about 2 minutes.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time
import tomllib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench.provenance import write_result
from protocols.model.frames import FloatArray, wxyz_from_zyx
from sitl_sim.physics import kernel as physics_kernel
from sitl_sim.physics.attitude_control import AttitudeGains
from sitl_sim.physics.dynamics import initial_state, step_with_contact
from sitl_sim.physics.inner_loop import inner_loop
from sitl_sim.physics.kernel import PhysicsKernel
from sitl_sim.physics.vehicle_params import VehicleParams
from sitl_sim.vehicle.autopilot import Mode, VehicleEvent
from sitl_sim.vehicle.setpoint import AttitudeSetpoint, validate_attitude_target
from sitl_sim.vehicle.tunables import FleetAttitudeGains
from sitl_sim.vehicle.world import World, WorldConfig

SIZES = (9, 25, 100, 250)
SUBSTEPS = 10
DT_S = 0.002
TICKS = 40
REPEATS = 7
#: The issue's budget for the simulator's part of a control tick (µs): 20x real time at 50 Hz
#: leaves 1 ms a tick for everything at N = 9; 5x leaves 4 ms at N = 100.
BUDGET_US = {9: 300.0, 100: 1500.0}
ROOT = Path(__file__).resolve().parents[1]
OUT_JSON = ROOT / "bench" / "results_physics_tick.json"
OUT_PROFILE = ROOT / "bench" / "physics_tick_profile.txt"

Tick = Callable[[int], None]
#: (prepare, tick): ``prepare(k)`` is left out of the timing (e.g. handing the World its
#: setpoints, as the server's dispatcher does), ``tick(k)`` is timed.
Timed = tuple[Tick | None, Tick]


# -- the fleets ---------------------------------------------------------------------------------
def _grid(n: int, altitude_m: float) -> FloatArray:
    side = int(np.ceil(np.sqrt(n)))
    k = np.arange(n)
    return np.stack([2.5 * (k // side), 2.5 * (k % side), np.full(n, -altitude_m)], axis=1)


def _setpoint(n: int, tick: int) -> tuple[FloatArray, FloatArray]:
    """Attitude (3, N) and thrust (N,) of control tick ``tick``: small, different per vehicle."""
    phase = 0.05 * tick + np.arange(n)
    euler = np.stack([0.05 * np.sin(phase), 0.05 * np.cos(phase), 0.3 * np.sin(0.3 * phase)])
    return euler, 0.5 + 0.02 * np.sin(phase)


def _substep_ticks(n: int, one_down: bool) -> dict[str, Timed]:
    """``tick(k)`` functions running 10 sub-steps: the reference functions and the kernel."""
    params, gains = VehicleParams(), AttitudeGains()
    positions = _grid(n, 3.0)
    armed = np.ones(n, dtype=bool)
    if one_down:
        positions[0, 2] = 0.0
        armed[0] = False
    start = initial_state(positions)
    kernel = PhysicsKernel(params, n, DT_S, gains)
    state = {"reference": start, "kernel": start}

    def reference(k: int) -> None:
        euler, thrust = _setpoint(n, k)
        s = state["reference"]
        for _ in range(SUBSTEPS):
            rotor = inner_loop(s, euler, thrust, params, gains, armed)
            s = step_with_contact(s, rotor, params, DT_S).state
        state["reference"] = s

    def fused(k: int) -> None:
        euler, thrust = _setpoint(n, k)
        s = state["kernel"]
        for _ in range(SUBSTEPS):
            s = kernel.substep(s, euler, thrust, armed)[0]
        state["kernel"] = s

    return {"reference": (None, reference), "kernel": (None, fused)}


def reference_world_step(w: World) -> list[VehicleEvent]:
    """:meth:`World.step` as it was before the kernel: inner_loop, dead motors stopped and
    step_with_contact at every sub-step."""
    ap = w.autopilot
    w.guidance.prepare(w.state)
    impact = np.zeros(w.n)
    state = w.state
    for _ in range(w.substeps):
        euler, thrust = w.guidance.command(state)
        rotor = inner_loop(state, euler, thrust, w.params, w.gains, ap.armed)
        if not ap.motor_ok.all():
            rotor[~ap.motor_ok] = 0.0
        result = step_with_contact(state, rotor, w.params, w.dt_physics_s)
        w.rotor_speed_rad_s = rotor
        state = result.state
        np.maximum(impact, result.impact_speed_m_s, out=impact)
    w.state = state
    w.tick += 1
    events, w.pending_events = w.pending_events, []
    events += ap.update(w.t_s, state[2], impact)
    while w._crashes and w._crashes[0][0] <= w.t_s + 1e-9:
        _, vehicle = w._crashes.pop(0)
        events += ap.motor_failure(vehicle, None, off=True)
    return events


def _flying_world(n: int, one_down: bool) -> World:
    """A World whose vehicles fly in OFFBOARD at 3 m (vehicle 0 crashed on the ground)."""
    positions = _grid(n, 3.0)
    if one_down:
        positions[0, 2] = 0.0
    w = World(
        VehicleParams(),
        FleetAttitudeGains(AttitudeGains(), n),
        positions,
        np.zeros(n),
        WorldConfig(),
        np.random.default_rng(0),
    )
    ap = w.autopilot
    for i in range(n):
        _give_setpoint(w, i, 0)
        if one_down and i == 0:
            continue
        ap.landed[i] = True
        ap.arm(i, 0.0)
        ap.set_mode(i, Mode.OFFBOARD, 0.0)
    if one_down:
        ap.motor_failure(0, None, off=True)
    return w


def _give_setpoint(w: World, i: int, tick: int) -> None:
    euler, thrust = _setpoint(w.n, tick)
    quat = wxyz_from_zyx(float(euler[2, i]), float(euler[1, i]), float(euler[0, i]))
    sp = validate_attitude_target(quat, float(thrust[i]))
    assert isinstance(sp, AttitudeSetpoint)
    w.autopilot.setpoint(i, sp, w.t_s)


def _world_ticks(n: int, one_down: bool) -> dict[str, Timed]:
    worlds = {"world_reference": _flying_world(n, one_down), "world": _flying_world(n, one_down)}

    def timed(name: str) -> Timed:
        w = worlds[name]

        def prepare(k: int) -> None:
            for i in range(w.n):
                _give_setpoint(w, i, k)

        def tick(k: int) -> None:
            if name == "world_reference":
                reference_world_step(w)
            else:
                w.step()

        return prepare, tick

    return {name: timed(name) for name in worlds}


def _time_ticks(variants: dict[str, Timed]) -> dict[str, tuple[float, float]]:
    """Median and minimum (µs) over REPEATS of the mean cost of one tick over TICKS, for every
    variant; the variants take turns within each repeat, so that a change of the machine's load
    falls on all of them."""
    clock = time.perf_counter
    samples: dict[str, list[float]] = {name: [] for name in variants}
    for repeat in range(REPEATS + 1):  # the first is a warm-up
        for name, (prepare, tick) in variants.items():
            spent = 0.0
            for j in range(TICKS):
                k = repeat * TICKS + j
                if prepare is not None:
                    prepare(k)
                t0 = clock()
                tick(k)
                spent += clock() - t0
            if repeat:
                samples[name].append(spent / TICKS * 1e6)
    return {name: (statistics.median(v), min(v)) for name, v in samples.items()}


def physics_tick(profile_out: Path | None = OUT_PROFILE) -> dict[str, Any]:
    """The benchmark registered in bench/run.py: :func:`tick_costs`, then :func:`profile`, whose
    text goes to ``profile_out`` (None: not run) and into the result as ``profile``."""
    result = tick_costs()
    if profile_out is not None:
        text = profile()
        profile_out.write_text(text + "\n")
        result["profile"] = text.splitlines()
        result["profile_file"] = str(profile_out)
    return result


def tick_costs() -> dict[str, Any]:
    """The per-control-tick figures (µs) for every size, variant and case; JSON-able."""
    rows: list[dict[str, Any]] = []
    for n in SIZES:
        for case in ("airborne", "one_down"):
            one_down = case == "one_down"
            ticks = {**_substep_ticks(n, one_down), **_world_ticks(n, one_down)}
            for variant, (median, best) in _time_ticks(ticks).items():
                rows.append(
                    {
                        "n": n,
                        "case": case,
                        "variant": variant,
                        "us_per_tick_median": round(median, 1),
                        "us_per_tick_min": round(best, 1),
                    }
                )
    by = {(r["n"], r["case"], r["variant"]): r["us_per_tick_median"] for r in rows}
    speedups = {
        f"n{n}_{case}": {
            "substeps": round(by[n, case, "reference"] / by[n, case, "kernel"], 2),
            "world": round(by[n, case, "world_reference"] / by[n, case, "world"], 2),
        }
        for n in SIZES
        for case in ("airborne", "one_down")
    }
    return {
        "what": "µs per 50 Hz control tick: 10 physics sub-steps (2 ms) with inner loops "
        "(reference functions vs the fused kernel), and swarm sim's World tick (before/after; "
        "handing the World its setpoints is not timed)",
        "timing": f"median (and min) of {REPEATS} repeats, each the mean over {TICKS} ticks; "
        "2-core machine shared with other work",
        "sizes": list(SIZES),
        "rows": rows,
        "speedup_median": speedups,
        "target": {f"n{n}_kernel_airborne_us": v for n, v in BUDGET_US.items()},
        "target_met": all(by[n, "airborne", "kernel"] <= v for n, v in BUDGET_US.items()),
    }


# -- swarm simulate, per part ---------------------------------------------------------------------
def hover_scenario_text(n: int, duration_s: float) -> str:
    """N drones on a grid 2.5 m apart hovering at 3 m, range 6 m (as bench/end_to_end.py)."""
    from bench.end_to_end import scenario_text

    return scenario_text(n, duration_s)


def _profile_flight(scenario: Any, reference: bool) -> dict[str, float]:
    """Wall µs per control tick of one in-process flight, per part."""
    import drone_agent.core.agent_core as agent_core
    import gcs.reference.flight as rf

    parts: dict[str, float] = {}
    undo: list[tuple[Any, str, Any]] = []

    def wrap(owner: Any, name: str, key: str) -> None:
        original = owner.__dict__[name]

        def timed(*args: Any, **kwargs: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return original(*args, **kwargs)
            finally:
                parts[key] = parts.get(key, 0.0) + time.perf_counter() - t0

        undo.append((owner, name, original))
        setattr(owner, name, timed)

    flight_cls = rf.ReferenceFlight
    if reference:  # the vehicles' period as World.step ran it before the kernel
        undo.append((World, "step", World.__dict__["step"]))
        World.step = reference_world_step  # type: ignore[method-assign, assignment]
    else:
        wrap(physics_kernel.PhysicsKernel, "substep", _KERNEL)
        wrap(physics_kernel.PhysicsKernel, "substeps", _KERNEL)
    wrap(World, "step", _PHYSICS)
    wrap(agent_core.AgentCore, "tick", _AGENTS)
    wrap(flight_cls, "_control_tick", _CONTROL)
    try:
        flight = flight_cls(scenario)
        t0 = time.perf_counter()
        flight.run()
        wall = time.perf_counter() - t0
    finally:
        for owner, name, original in reversed(undo):
            setattr(owner, name, original)
    ticks = round(scenario.duration_s / scenario.rates.dt_control_s) + 1
    out = {key: value / ticks * 1e6 for key, value in parts.items()}
    out[_WHOLE] = wall / ticks * 1e6
    out[_REST] = out[_WHOLE] - out[_CONTROL] - out[_PHYSICS]
    if _KERNEL in out:
        out[_BOOKKEEPING] = out[_PHYSICS] - out[_KERNEL]
    out[_RTF] = scenario.duration_s / wall
    return out


_WHOLE = "one control tick, all of it"
_CONTROL = "control tick: agents, radio, recording"
_AGENTS = "  of which the agents (AgentCore.tick, N calls)"
_PHYSICS = "vehicles: World.step (10 sub-steps, autopilots)"
_KERNEL = "  of which PhysicsKernel.substep(s) (all of that)"
_BOOKKEEPING = "  of which the autopilots (guidance, update, events)"
_REST = "the rest (fault timeline, loop)"
_RTF = "real-time factor"
_ROWS = (_WHOLE, _CONTROL, _AGENTS, _PHYSICS, _KERNEL, _BOOKKEEPING, _REST)


def profile() -> str:
    """A text table: where one control tick of ``swarm simulate`` goes, per part, before/after."""
    from protocols.scenario.scenario_file import load_scenario, parse_scenario

    paper = dataclasses.replace(load_scenario(ROOT / "scenarios" / "paper.toml"), duration_s=40.0)
    hover = parse_scenario(tomllib.loads(hover_scenario_text(100, 6.0)), "hover100.toml")
    lines = [
        "Where one 50 Hz control tick of `swarm simulate` goes, per part (wall µs per tick, one",
        "run each; 2-core machine shared with other work, so +-10 %). 'before': the physics",
        "sub-step as inner_loop + step_with_contact; 'after': the fused PhysicsKernel.",
        "Produced by `python -m bench.physics_tick` (bench/physics_tick.py).",
        "",
    ]
    for label, scenario in (("N = 9, paper, first 40 s", paper), ("N = 100, hover, 6 s", hover)):
        before = _profile_flight(scenario, reference=True)
        after = _profile_flight(scenario, reference=False)
        lines.append(f"{label}:")
        lines.append(f"  {'µs per control tick':52s} {'before':>9s} {'after':>9s}")
        for key in _ROWS:
            cells = [f"{d[key]:9.0f}" if key in d else " " * 9 for d in (before, after)]
            lines.append(f"  {key:52s} {cells[0]} {cells[1]}")
        rtf = [f"{d[_RTF]:9.2f}" for d in (before, after)]
        lines.append(f"  {_RTF:52s} {rtf[0]} {rtf[1]}")
        lines.append("")
    lines += [
        "Where one control tick of `swarm sim` goes (the simulator process, realtime clock flat",
        "out at --speedup 1000, bench/sitl.py's client playing the agents: SET_ATTITUDE_TARGET at",
        "50 Hz wall per vehicle, so at 5-25x real time only some ticks carry a setpoint; in",
        "lockstep every tick carries N). 'before': World.step through the reference functions;",
        f"'after': with the kernel. {SERVER_MEASURE_S:g} s measured after {SERVER_WARMUP_S:g} s; "
        "the faster of",
        "two runs each (a run that shares the cores with another job reads up to 3x slower).",
        "",
    ]
    for n in (9, 100):
        runs = [(_server_parts(n, True), _server_parts(n, False)) for _ in range(2)]
        before = min((r[0] for r in runs), key=lambda d: d[_WHOLE])
        after = min((r[1] for r in runs), key=lambda d: d[_WHOLE])
        lines.append(f"N = {n}:")
        lines.append(f"  {'µs per control tick':52s} {'before':>9s} {'after':>9s}")
        for key in _SERVER_ROWS:
            cells = [f"{d[key]:9.0f}" if key in d else " " * 9 for d in (before, after)]
            lines.append(f"  {key:52s} {cells[0]} {cells[1]}")
        rtf = [f"{d[_RTF]:9.2f}" for d in (before, after)]
        lines.append(f"  {_RTF:52s} {rtf[0]} {rtf[1]}")
        lines.append("")
    return "\n".join(lines)


SERVER_WARMUP_S = 8.0
SERVER_MEASURE_S = 8.0
_S_WORLD = "World.step (guidance, 10 sub-steps, autopilot)"
_S_OUT = "telemetry out (snapshot, build, encode, send)"
_S_IN = "agent MAVLink in (decode, validate, apply)"
_S_REST = "the rest (select, pacing, GCS input, flush)"
_SERVER_ROWS = (_WHOLE, _S_WORLD, _S_OUT, _S_IN, _S_REST)


def _server_parts(n: int, reference: bool) -> dict[str, float]:
    """Run ``swarm sim --drones n --speedup 1000`` in this process next to the client process of
    bench/sitl.py; wall µs per control tick per part over SERVER_MEASURE_S."""
    import io
    import os
    import subprocess
    import sys
    import threading

    from bench.sitl import _free_block
    from sitl_sim import server, sim_cli
    from sitl_sim.mavlink_edge import dispatch

    parts: dict[str, float] = {}
    undo: list[tuple[Any, str, Any]] = []

    def wrap(owner: Any, name: str, key: str) -> None:
        original = owner.__dict__[name]

        def timed(*args: Any, **kwargs: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return original(*args, **kwargs)
            finally:
                parts[key] = parts.get(key, 0.0) + time.perf_counter() - t0

        undo.append((owner, name, original))
        setattr(owner, name, timed)

    if reference:
        undo.append((World, "step", World.__dict__["step"]))
        World.step = reference_world_step  # type: ignore[method-assign, assignment]
    wrap(World, "step", _S_WORLD)
    wrap(server.SimServer, "_emit", _S_OUT)
    wrap(dispatch.Dispatcher, "agent_datagram", _S_IN)
    servers: list[server.SimServer] = []
    undo.append((server.SimServer, "__init__", server.SimServer.__dict__["__init__"]))
    original_init = server.SimServer.__init__

    def init(self: server.SimServer, *args: Any, **kwargs: Any) -> None:
        original_init(self, *args, **kwargs)
        servers.append(self)

    server.SimServer.__init__ = init  # type: ignore[method-assign]
    base, gcs = _free_block(n), _free_block(1)
    parser = argparse.ArgumentParser()
    sim_cli.add_sim_parser(parser.add_subparsers())
    sim_argv = ["sim", "--drones", str(n), "--base-port", str(base), "--gcs",
                f"udp:127.0.0.1:{gcs}", "--offboard-timeout", "2", "--speedup", "1000"]  # fmt: skip
    args = parser.parse_args(sim_argv)
    seconds = SERVER_WARMUP_S + SERVER_MEASURE_S + 2.0
    client_argv = [sys.executable, "-m", "bench.sitl", "client", "--drones", str(n), "--base-port",
                   str(base), "--gcs-port", str(gcs), "--seconds", str(seconds)]  # fmt: skip
    client = subprocess.Popen(
        client_argv,
        stdout=subprocess.DEVNULL,
        env={**os.environ, "MAVLINK20": "1"},
        cwd=ROOT,
    )
    measured: dict[str, float] = {}

    def measure() -> None:
        while not servers:
            time.sleep(0.05)
        sim = servers[0]
        time.sleep(SERVER_WARMUP_S)
        parts.clear()
        t0, k0 = time.perf_counter(), sim.world.tick
        time.sleep(SERVER_MEASURE_S)
        spent, wall, ticks = dict(parts), time.perf_counter() - t0, sim.world.tick - k0
        measured.update({key: value / ticks * 1e6 for key, value in spent.items()})
        measured[_WHOLE] = wall / ticks * 1e6
        measured[_S_REST] = measured[_WHOLE] - sum(spent.values()) / ticks * 1e6
        measured[_RTF] = ticks / sim.world.config.control_hz / wall
        sim.stop()

    thread = threading.Thread(target=measure, daemon=True)
    thread.start()
    try:
        sim_cli.run_sim(args, out=io.StringIO())
    finally:
        for owner, name, original in reversed(undo):
            setattr(owner, name, original)
        client.wait(60)
    thread.join(5)
    return measured


def main(argv: Sequence[str] | None = None) -> int:
    """Run the tick benchmark and the profile; write the JSON and the profile text."""
    parser = argparse.ArgumentParser(prog="python -m bench.physics_tick", description=__doc__)
    parser.add_argument("--out", type=Path, default=OUT_JSON)
    parser.add_argument("--profile-out", type=Path, default=OUT_PROFILE)
    parser.add_argument("--no-profile", action="store_true")
    args = parser.parse_args(argv)
    result = physics_tick(None if args.no_profile else args.profile_out)
    for row in result["rows"]:
        print(row)
    print("\n".join(result.get("profile", [])))
    write_result(args.out, result, indent=2)
    print(f"wrote {args.out}" + ("" if args.no_profile else f" and {args.profile_out}"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

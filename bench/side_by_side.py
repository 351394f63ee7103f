"""``swarm simulate`` beside the peers that are installed, on the same swarm sizes.

``python -m bench.side_by_side [--sizes 9,25,100] [--seconds 20] [--peer-python PATH]
[--out bench/results_side_by_side.json]``

Each run is a fresh child process on one core (``taskset -c 0`` where the machine has it), the
same N-drone grid (2.5 m apart) holding its place for the same simulated seconds, physics at
500 Hz and control at 50 Hz where the runner lets us say so:

- ``quadswarm``: ``swarm simulate`` of ``swarm scenario new --drones N --template hover``
  (take-off, climb to 3 m, hold: the consensus estimator, the cooperative controller, the
  separation layer, every vehicle's autopilot, the radio in memory and the recording of
  flight.tlog, events and metrics; no PNG plots, no flight.rrd: the peers write neither), cut to
  the seconds asked;
- ``crazyflow`` (JAX + MuJoCo, compiled): ``Sim(n_drones=N, control=Control.state)``, the
  drones set on the grid on the ground and each commanded to its place 3 m up, 50 Hz state
  commands, 500 Hz physics;
- ``gym-pybullet-drones`` (PyBullet): ``CtrlAviary`` with one ``DSLPIDControl`` a drone, the
  same targets, 50 Hz control, 500 Hz physics.

The peers fly physics and a position controller only (no consensus, no estimator, no separation
layer), so their loop is less work than ours: the ratio says what the whole of ours costs against
the bare loop of theirs. A peer is flown by ``--peer-python`` (default: this interpreter) when it
imports there, and listed as not installed otherwise (``pip install crazyflow``; gym-pybullet-
drones from its repository). Per run: the whole process's wall time (start-up, imports,
compilation and the flight) and the flight loop's alone (for crazyflow without its first three
ticks, whose calls compile, reported apart as ``first_step_s``); for crazyflow also the same
flight as one compiled scan (``scan_s``: one state command, every step in one call, timed on its
second call: no orchestrator in its loop, the fastest it flies); real-time factors are the
simulated seconds over them. Writes the JSON with the commit and the machine's load, and its
table beside it (the same name, ``.md``).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bench.provenance import commit, load_average, write_result

ROOT = Path(__file__).resolve().parents[1]
OUT_JSON = ROOT / "bench" / "results_side_by_side.json"
SIZES = (9, 25, 100)
SPACING_M, ALTITUDE_M = 2.5, 3.0

#: each peer: the module it imports as, and the child's script (argv: N, seconds, spacing,
#: altitude); the script prints one JSON object: loop_s, and first_step_s where it compiles, and
#: scan_s where the whole flight can run as one compiled call
PEERS: dict[str, tuple[str, str]] = {
    "crazyflow": (
        "crazyflow",
        textwrap.dedent(
            """
            import json, sys, time
            import numpy as np
            from crazyflow.control import Control
            from crazyflow.sim import Sim
            n = int(sys.argv[1])
            seconds, spacing, alt = (float(a) for a in sys.argv[2:5])
            WARM = 3
            side = int(np.ceil(np.sqrt(n)))
            grid = np.array([(spacing * (i // side), spacing * (i % side)) for i in range(n)])
            common = dict(n_worlds=1, n_drones=n, control=Control.state, freq=500, device="cpu")
            try:
                sim = Sim(**common, state_freq=50)
            except TypeError:  # (older releases name it control_freq)
                sim = Sim(**common, control_freq=50)
            sim.reset()
            pos = np.zeros((1, n, 3))
            pos[0, :, 0:2] = grid
            sim.data = sim.data.replace(states=sim.data.states.replace(pos=pos))  # on the ground
            width = 16  # [x, y, z, v (3), a (3), q xyzw (4), w (3)]; 13 in early releases
            try:
                sim.state_control(np.zeros((1, n, width)))
            except AssertionError:
                width = 13
            cmd = np.zeros((1, n, width))
            cmd[0, :, 0:2] = grid
            cmd[0, :, 2] = alt
            if width == 16:
                cmd[0, :, 12] = 1.0  # level, yaw 0
            per = sim.freq // 50
            t0 = time.perf_counter()
            for _ in range(WARM):  # compiled on the first calls (the second compiles again)
                sim.state_control(cmd)
                sim.step(per)
            np.asarray(sim.data.states.pos)
            first = time.perf_counter() - t0
            ticks = int(round(seconds * 50))
            t0 = time.perf_counter()
            for _ in range(ticks - WARM):
                sim.state_control(cmd)
                sim.step(per)
            z = np.asarray(sim.data.states.pos)[0, :, 2]  # (waits for the last step)
            loop = time.perf_counter() - t0
            out = {"loop_s": loop, "first_step_s": first, "min_altitude_m": float(z.min())}
            # the same flight as one compiled scan: one command, every step in one call (its
            # first call compiles; the second, from the ground again, is timed)
            for timed in (False, True):
                sim.reset()
                sim.data = sim.data.replace(states=sim.data.states.replace(pos=pos))
                sim.state_control(cmd)
                t0 = time.perf_counter()
                sim.step(ticks * per)
                z = np.asarray(sim.data.states.pos)[0, :, 2]
                if timed:
                    out["scan_s"] = time.perf_counter() - t0
            print(json.dumps(out))
            """
        ),
    ),
    "gym-pybullet-drones": (
        "gym_pybullet_drones",
        textwrap.dedent(
            """
            import json, sys, time
            import numpy as np
            from gym_pybullet_drones.control.DSLPIDControl import DSLPIDControl
            from gym_pybullet_drones.envs.CtrlAviary import CtrlAviary
            from gym_pybullet_drones.utils.enums import DroneModel, Physics
            n = int(sys.argv[1])
            seconds, spacing, alt = (float(a) for a in sys.argv[2:5])
            side = int(np.ceil(np.sqrt(n)))
            start = np.array([(spacing * (i // side), spacing * (i % side), 0.1) for i in range(n)])
            target = start.copy()
            target[:, 2] = alt
            env = CtrlAviary(drone_model=DroneModel.CF2X, num_drones=n, initial_xyzs=start,
                             physics=Physics.PYB, pyb_freq=500, ctrl_freq=50, gui=False)
            ctrl = [DSLPIDControl(drone_model=DroneModel.CF2X) for _ in range(n)]
            action = np.zeros((n, 4))
            ticks = int(round(seconds * 50))
            t0 = time.perf_counter()
            for _ in range(ticks):
                out = env.step(action)
                obs = out[0]
                for j in range(n):
                    action[j], _, _ = ctrl[j].computeControlFromState(
                        control_timestep=env.CTRL_TIMESTEP, state=obs[j], target_pos=target[j])
            loop = time.perf_counter() - t0
            env.close()
            print(json.dumps({"loop_s": loop, "min_altitude_m": float(min(o[2] for o in obs))}))
            """
        ),
    ),
}


def _one_core() -> list[str]:
    taskset = shutil.which("taskset")
    return [taskset, "-c", "0"] if taskset else []


def installed(python: str, module: str) -> bool:
    """Whether ``module`` imports in ``python``."""
    done = subprocess.run(
        [python, "-c", f"import {module}"], capture_output=True, text=True, timeout=300
    )
    return done.returncode == 0


def ours(n: int, seconds: float, folder: Path) -> dict[str, Any]:
    """``swarm simulate`` of an N-drone hover grid for ``seconds``: whole process and loop."""
    from protocols.scenario.generator import GeneratorOptions, generate

    scenario = folder / f"hover{n}.toml"
    options = GeneratorOptions(n, "grid", spacing_m=SPACING_M, template="hover")
    scenario.write_text(generate(options, str(scenario)).text)
    report = folder / f"report{n}"
    argv = [sys.executable, "-m", "gcs.cli", "simulate", str(scenario), "--duration-s",
            f"{seconds:g}", "--report", str(report), "--no-plots", "--no-recording",
            "--progress", "off"]  # fmt: skip
    t0 = time.perf_counter()
    done = subprocess.run(
        [*_one_core(), *argv], capture_output=True, text=True, cwd=ROOT, timeout=3600
    )
    whole = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(f"swarm simulate failed: {done.stderr[-500:]}")
    metrics = json.loads((report / "metrics.json").read_text())
    return {
        "whole_s": round(whole, 3),
        "loop_s": metrics["wall_time_s"],
        "startup_s": metrics.get("startup_s"),  # the process's age when the loop started
        "min_separation_m": metrics["separation"]["min_m"],
        "collisions": metrics["collisions"]["count"],
    }


def peer(python: str, name: str, n: int, seconds: float, folder: Path) -> dict[str, Any]:
    """A peer's run of the same grid: whole process and loop (its script's own timing), in
    ``folder`` (MuJoCo leaves its log in the working folder)."""
    _, script = PEERS[name]
    argv = [python, "-c", script, str(n), f"{seconds:g}", f"{SPACING_M:g}", f"{ALTITUDE_M:g}"]
    t0 = time.perf_counter()
    done = subprocess.run(
        [*_one_core(), *argv], capture_output=True, text=True, cwd=folder, timeout=3600
    )
    whole = time.perf_counter() - t0
    if done.returncode != 0:
        return {"error": done.stderr.strip().splitlines()[-1] if done.stderr.strip() else "failed"}
    out: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    return {"whole_s": round(whole, 3), **{k: round(v, 4) for k, v in out.items()}}


def side_by_side(
    sizes: Sequence[int] = SIZES, seconds: float = 20.0, python: str | None = None
) -> dict[str, Any]:
    """Every size, ours and each installed peer, one after the other."""
    python = python or sys.executable
    load = load_average()
    present = {name: installed(python, module) for name, (module, _) in PEERS.items()}
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            runs = {"quadswarm": ours(n, seconds, Path(tmp))}
            for name, there in present.items():
                if there:
                    runs[name] = peer(python, name, n, seconds, Path(tmp))
            base = runs["quadswarm"]
            for name, run in runs.items():
                row: dict[str, Any] = {"n": n, "runner": name, **run}
                if "loop_s" in run:
                    row["rtf_loop"] = round(seconds / run["loop_s"], 2)
                    row["rtf_whole"] = round(seconds / run["whole_s"], 2)
                    row["ours_loop_over_theirs"] = round(base["loop_s"] / run["loop_s"], 2)
                rows.append(row)
                print(json.dumps(row), flush=True)
    return {
        "seconds": seconds,
        "commit": commit(),
        "load_average": load,
        "one_core": bool(_one_core()),
        "peers_installed": present,
        "rows": rows,
    }


def table(result: dict[str, Any]) -> str:
    """The markdown table of a result."""
    lines = [
        f"`python -m bench.side_by_side` at {result['commit']}, {result['seconds']:g} simulated s, "
        f"load {result['load_average']}; peers installed: "
        + ", ".join(f"{k} {'yes' if v else 'no'}" for k, v in result["peers_installed"].items()),
        "",
        "| N | runner | whole process (s) | loop (s) | loop real-time factor | ours / theirs "
        "| one compiled scan (s) |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in result["rows"]:
        if "loop_s" not in r:
            lines.append(f"| {r['n']} | {r['runner']} | failed: {r.get('error')} | | | | |")
            continue
        lines.append(
            f"| {r['n']} | {r['runner']} | {r['whole_s']:.2f} | {r['loop_s']:.2f} | "
            f"{r['rtf_loop']:.1f}x | {r['ours_loop_over_theirs']:.2f} | "
            + (f"{r['scan_s']:.2f} |" if "scan_s" in r else "|")
        )
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default=",".join(map(str, SIZES)), help="comma list of N")
    parser.add_argument("--seconds", type=float, default=20.0, help="simulated seconds")
    parser.add_argument("--peer-python", default=None, help="the interpreter the peers are in")
    parser.add_argument("--out", type=Path, default=OUT_JSON, help="the JSON written")
    args = parser.parse_args(argv)
    sizes = [int(s) for s in args.sizes.split(",") if s]
    result = side_by_side(sizes, args.seconds, args.peer_python)
    write_result(args.out, result, indent=2)
    text = table(result)
    args.out.with_suffix(".md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Real-time factor of ``swarm sim`` under load, and the per-drone physics step against RotorPy.

For N = 9, 50, 100, 250: ``swarm sim --drones N`` (realtime clock, 50 Hz ATTITUDE and
LOCAL_POSITION_NED to every agent in simulated time, 10 Hz to the GCS), once paced at x1 (does it
keep up, and at what CPU share?) and once flat out (``--speedup 1000``: the real-time factor it
can reach), runs next to a client process
(``python -m bench.sitl client``) that plays every agent: it streams SET_ATTITUDE_TARGET at 50 Hz
per vehicle (thrust 0, arm, OFFBOARD, a short climb, then hover thrust), receives all agent and GCS
telemetry, and counts it. The real-time factor is simulated over wall time between the
simulator's status lines after a warm-up; the simulator's CPU share comes from /proc.

The physics comparison times one step (2 ms) of the simulator's inner loop + RK4 with ground
contact, per drone at N = 1 and N = 100, against RotorPy's ``Multirotor.step`` (one vehicle,
scipy ``solve_ivp``; RotorPy also models rotor dynamics and aerodynamic drag) in the same run.
RotorPy is optional (``pip install rotorpy``): without it that part is skipped with a note.
"""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"  # before any pymavlink import (DEPENDENCIES.md)

import argparse
import copy
import json
import select
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

SIZES = (9, 50, 100, 250)
WARMUP_S = 5.0
#: The client's programme (wall s): thrust 0 while arming and switching to OFFBOARD, a climb at
#: 0.6, then hover thrust 0.5.
CLIMB_S = (3.0, 3.5)
MEASURE_S = 10.0
TARGET_N, TARGET_RTF = 100, 1.0
#: A speed-up the simulator cannot reach: it runs flat out, and the factor it reaches is its
#: capacity (the realtime clock at x1 can only show whether it keeps up).
FREE_RUN_SPEEDUP = 1000.0
HOST = "127.0.0.1"
_ROOT = Path(__file__).resolve().parents[1]
_ENV = {**os.environ, "MAVLINK20": "1"}


def sitl_rtf() -> dict[str, Any]:
    """Run every size and the physics comparison; a JSON-able dict with ``rows``."""
    rows = []
    for n in SIZES:
        paced = _run_size(n, speedup=1.0)
        flat_out = _run_size(n, speedup=FREE_RUN_SPEEDUP)
        rows.append(
            {
                "n": n,
                "rtf_paced_x1": paced["rtf"],
                "sim_cpu_x1": paced["sim_cpu_share"],
                "agent_hz_per_vehicle": paced["agent_hz_per_vehicle"],
                "gcs_datagrams_per_s": paced["gcs_datagrams_per_s"],
                "flying": paced["flying"],
                "rtf_max": flat_out["rtf"],
                "sim_cpu_max": flat_out["sim_cpu_share"],
            }
        )
    physics = physics_vs_rotorpy()
    at_target = next(r for r in rows if r["n"] == TARGET_N)
    return {
        "warmup_s": WARMUP_S,
        "measure_s": MEASURE_S,
        "rows": rows,
        "physics_step": physics,
        "target": {"n": TARGET_N, "rtf": TARGET_RTF},
        "target_met": at_target["rtf_max"] >= TARGET_RTF,
    }


# -- one size ----------------------------------------------------------------------------------
def _run_size(n: int, speedup: float) -> dict[str, Any]:
    """One run of ``swarm sim --drones n --speedup speedup`` with the client."""
    base, gcs_port = _free_block(n), _free_block(1)
    seconds = WARMUP_S + MEASURE_S + 1.0
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "sim.out"
        sim_cmd = [sys.executable, "-m", "gcs.cli", "sim", "--drones", str(n), "--base-port",
                   str(base), "--gcs", f"udp:{HOST}:{gcs_port}", "--offboard-timeout", "2",
                   "--speedup", str(speedup)]  # fmt: skip
        client_cmd = [sys.executable, "-m", "bench.sitl", "client", "--drones", str(n),
                      "--base-port", str(base), "--gcs-port", str(gcs_port),
                      "--seconds", str(seconds)]  # fmt: skip
        with out.open("wb") as fo:
            sim = subprocess.Popen(
                sim_cmd, stdout=fo, stderr=subprocess.STDOUT, env=_ENV, cwd=_ROOT
            )
        try:
            client = subprocess.Popen(
                client_cmd, stdout=subprocess.PIPE, text=True, env=_ENV, cwd=_ROOT
            )
            time.sleep(WARMUP_S)
            cpu0, wall0 = _cpu_seconds(sim.pid), time.monotonic()
            stdout, _ = client.communicate(timeout=120)
            cpu1, wall1 = _cpu_seconds(sim.pid), time.monotonic()
        finally:
            sim.terminate()
            sim.wait(30)
        status = _status_lines(out.read_text())
    cpu = None if cpu0 is None or cpu1 is None else (cpu1 - cpu0) / (wall1 - wall0)
    counts = json.loads(stdout.strip().splitlines()[-1]) if client.returncode == 0 else {}
    window = [s for s in status if WARMUP_S <= s["wall"] <= WARMUP_S + MEASURE_S + 0.5]
    rtf = _rtf(window)
    last = window[-1] if window else {}
    return {
        "n": n,
        "rtf": round(rtf, 3),
        "sim_cpu_share": None if cpu is None else round(cpu, 2),
        "agent_hz_per_vehicle": counts.get("agent_hz_per_vehicle"),
        "gcs_datagrams_per_s": counts.get("gcs_datagrams_per_s"),
        "armed": last.get("armed"),
        "flying": last.get("flying"),
    }


def _rtf(window: list[dict[str, float]]) -> float:
    """Least-squares slope of simulated against wall time over the status lines."""
    if len(window) < 3:
        return 0.0
    wall = np.array([s["wall"] for s in window])
    sim = np.array([s["sim"] for s in window])
    return float(np.polyfit(wall, sim, 1)[0])


def _status_lines(text: str) -> list[dict[str, float]]:
    """The simulator's status lines as numbers: sim, wall (s), armed, flying."""
    out = []
    for line in text.splitlines():
        if not line.startswith("sim "):
            continue
        words = line.replace("|", " ").split()
        out.append(
            {
                "sim": float(words[1]),
                "wall": float(words[4]),
                "armed": float(words[words.index("armed") + 1]),
                "flying": float(words[words.index("flying") + 1]),
            }
        )
    return out


def _cpu_seconds(pid: int) -> float | None:
    """User + system CPU seconds of process ``pid`` (Linux /proc), None elsewhere."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _free_block(n: int) -> int:
    """First of ``n`` consecutive free UDP ports (gcs.api.launch.free_udp_block)."""
    from gcs.api.launch import free_udp_block

    return free_udp_block(n, HOST, attempts=100)


# -- the client process --------------------------------------------------------------------------
def run_client(n: int, base_port: int, gcs_port: int, seconds: float) -> dict[str, Any]:
    """Play the agents of ``n`` vehicles for ``seconds``; counts of what arrived."""
    from pymavlink.dialects.v20 import common as mavlink

    codecs = [mavlink.MAVLink(None, srcSystem=i + 1, srcComponent=191) for i in range(n)]

    def frame(i: int, msg: Any) -> bytes:
        return bytes(msg.pack(codecs[i]))

    level = [1.0, 0.0, 0.0, 0.0]
    setpoints = {
        thrust: [frame(i, mavlink.MAVLink_set_attitude_target_message(
            0, i + 1, 1, 7, level, 0.0, 0.0, 0.0, thrust)) for i in range(n)]
        for thrust in (0.0, 0.6, 0.5)
    }  # fmt: skip
    arm = [frame(i, mavlink.MAVLink_command_long_message(i + 1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
           for i in range(n)]  # fmt: skip
    offboard = [frame(i, mavlink.MAVLink_command_long_message(
        i + 1, 1, 176, 0, 1, 6, 0, 0, 0, 0, 0)) for i in range(n)]  # fmt: skip
    agent = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    for s in (agent, gcs):
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 23)
        s.setblocking(False)
    agent.bind((HOST, 0))
    gcs.bind((HOST, gcs_port))
    addresses = [(HOST, base_port + i) for i in range(n)]
    received = {agent: 0, gcs: 0}
    start = time.monotonic()
    next_send, counting_from = start, start + WARMUP_S
    while (now := time.monotonic()) < start + seconds:
        if now >= next_send:
            t = now - start
            thrust = 0.6 if CLIMB_S[0] <= t < CLIMB_S[1] else 0.5 if t >= CLIMB_S[1] else 0.0
            frames = setpoints[thrust]
            # commands are repeated (idempotent): the simulator may still be starting
            k = round(t / 0.02)
            extra = arm if t < CLIMB_S[0] and k % 25 == 0 else None
            extra = offboard if t < CLIMB_S[0] and k % 25 == 12 else extra
            for i, address in enumerate(addresses):
                agent.sendto(frames[i], address)
                if extra is not None:
                    agent.sendto(extra[i], address)
            next_send += 0.02
        ready, _, _ = select.select([agent, gcs], [], [], max(0.0, next_send - time.monotonic()))
        for s in ready:
            while True:
                try:
                    s.recv(65535)
                except BlockingIOError:
                    break
                if time.monotonic() >= counting_from:
                    received[s] += 1
    measured = seconds - WARMUP_S
    return {
        "agent_hz_per_vehicle": round(received[agent] / measured / n, 1),
        "gcs_datagrams_per_s": round(received[gcs] / measured, 1),
    }


# -- physics -----------------------------------------------------------------------------------
def physics_vs_rotorpy(repeats: int = 3, steps: int = 400) -> dict[str, Any]:
    """Per-drone time (µs) of one 2 ms physics step: ours at N = 1 and 100, and RotorPy's."""
    ours = {f"ours_n{n}_us": _our_step_us(n, repeats, steps) for n in (1, 100)}
    try:
        rotorpy_us = _rotorpy_step_us(repeats, steps // 4)
    except ImportError:
        return {**ours, "rotorpy_us": None,
                "note": "rotorpy not importable: pip install rotorpy to compare"}  # fmt: skip
    return {
        **ours,
        "rotorpy_us": round(rotorpy_us, 1),
        "rotorpy_over_ours_n1": round(rotorpy_us / ours["ours_n1_us"], 1),
        "rotorpy_over_ours_n100": round(rotorpy_us / ours["ours_n100_us"], 1),
        "note": "RotorPy Multirotor.step (crazyflie params, solve_ivp, aero and motor lag) for "
        "one vehicle vs our inner loop + RK4 + ground contact, per drone",
    }


def _our_step_us(n: int, repeats: int, steps: int) -> float:
    from sitl_sim.physics.attitude_control import AttitudeGains
    from sitl_sim.physics.dynamics import initial_state, step_with_contact
    from sitl_sim.physics.inner_loop import inner_loop
    from sitl_sim.physics.vehicle_params import VehicleParams

    params, gains = VehicleParams(), AttitudeGains()
    state0 = initial_state(np.stack([np.arange(n) * 2.0, np.zeros(n), np.full(n, -5.0)], axis=1))
    level, hover = np.zeros((3, n)), np.full(n, 0.5)
    armed = np.ones(n, dtype=bool)
    best = np.inf
    for _ in range(repeats):
        state = state0.copy()
        t0 = time.perf_counter()
        for _ in range(steps):
            rotor = inner_loop(state, level, hover, params, gains, armed)
            state = step_with_contact(state, rotor, params, 0.002).state
        best = min(best, (time.perf_counter() - t0) / steps / n)
    return round(best * 1e6, 2)


def _rotorpy_step_us(repeats: int, steps: int) -> float:
    from rotorpy.vehicles.crazyflie_params import quad_params
    from rotorpy.vehicles.multirotor import Multirotor

    vehicle = Multirotor(quad_params)
    best = np.inf
    for _ in range(repeats):
        state = copy.deepcopy(vehicle.initial_state)
        control = {"cmd_motor_speeds": np.array(state["rotor_speeds"], dtype=float)}
        t0 = time.perf_counter()
        for _ in range(steps):
            state = vehicle.step(state, control, 0.002)
        best = min(best, (time.perf_counter() - t0) / steps)
    return float(best * 1e6)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m bench.sitl client ...`` (the load generator) or ``python -m bench.sitl``."""
    parser = argparse.ArgumentParser(prog="python -m bench.sitl")
    sub = parser.add_subparsers(dest="command")
    client = sub.add_parser("client", help="play the agents of N vehicles")
    client.add_argument("--drones", type=int, required=True)
    client.add_argument("--base-port", type=int, required=True)
    client.add_argument("--gcs-port", type=int, required=True)
    client.add_argument("--seconds", type=float, required=True)
    args = parser.parse_args(argv)
    if args.command == "client":
        result = run_client(args.drones, args.base_port, args.gcs_port, args.seconds)
    else:
        result = sitl_rtf()
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The messaging floor of one process per drone: what N Zenoh sessions on this machine cost
for the consensus traffic alone, with no estimator, controller, MAVLink, simulator or ground
station. It bounds what ``swarm up --agents-per-process 1`` can reach on two cores whatever the
agents' own code costs.

``python -m bench.messaging_floor [--rounds R]`` (about 3 minutes; on request:
``python -m bench.run --only messaging_floor``). Writes ``bench/results_messaging_floor.json``.

N worker processes (``subprocess``, never forked after a session opened), one Zenoh peer session
each, meshed over TCP on loopback (each listens on its own port and connects to those before it;
multicast scouting off), as ``swarm agent`` processes are. Per round each publishes one consensus
sample of ``PAYLOAD_BYTES`` on its own key (congestion DROP, not express: a lockstep agent's
QUEUED) and drains every sample that came (a pulled ring channel, as the agents' hub does):

- ``lockstep``: then publishes an express round-done marker and waits, on a pipe written by a
  marker callback, until every other process's marker of the round has come (the agents' round
  gate); as fast as that goes: ``rounds_per_s`` / 50 is the best real-time factor such a swarm
  can fly at;
- ``realtime``: paced by the wall clock at 50 Hz (the control rate); ``late`` counts rounds that
  started behind their time.

Topology ``mesh`` (the peers, as above) or ``router``: every process a Zenoh client of one router
(``swarm router``, the project's, a process of its own), which fans the samples out; its CPU per
round once it has started (the clients' joining and the warm-up included: a slight
overestimate) at the case's rate is ``router_cores``.

Measured over the rounds after the first ``WARM_ROUNDS``: each process's CPU time (all threads,
Zenoh's included) per round, and ``cores``: the N processes' CPU per wall second. Real agents
send more than this (a status every other tick, liveliness, larger messages with many
neighbours) and do their maths besides: the figures are a floor.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import select
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
OUT_JSON = ROOT / "bench" / "results_messaging_floor.json"
CONTROL_HZ = 50
#: a consensus message of an agent with eight neighbours is about 1.4 kB (protocols/wire.py)
PAYLOAD_BYTES = 1000
WARM_ROUNDS = 50
#: (mode, processes, topology): the issue's per-drone targets (lockstep 3x at N = 9, realtime at
#: N = 25), and whether a router instead of the mesh changes them
CASES = (
    ("lockstep", 9, "mesh"),
    ("lockstep", 25, "mesh"),
    ("realtime", 25, "mesh"),
    ("lockstep", 9, "router"),
    ("realtime", 25, "router"),
)


def _free_tcp_ports(n: int) -> list[int]:
    socks = []
    try:
        for _ in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.bind(("127.0.0.1", 0))
            socks.append(s)
        return [int(s.getsockname()[1]) for s in socks]
    finally:
        for s in socks:
            s.close()


def worker(
    index: int, ports: list[int], mode: str, rounds: int, tag: str, router: str | None = None
) -> dict[str, Any]:
    """One process of a case (module docstring); returns its figures. ``router``: the endpoint
    of the router it is a client of (None: a peer of the mesh on ``ports``)."""
    import zenoh

    n = len(ports)
    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    if router is not None:
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", json.dumps([router]))
    else:
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{ports[index]}"]))
        conf.insert_json5(
            "connect/endpoints", json.dumps([f"tcp/127.0.0.1:{p}" for p in ports[:index]])
        )
    session = zenoh.open(conf)
    data = session.declare_subscriber(f"{tag}/c/*", zenoh.handlers.RingChannel(256))
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_w, False)
    markers: dict[int, int] = {}

    def on_marker(sample: Any) -> None:
        k = int(sample.payload.to_bytes())
        markers[k] = markers.get(k, 0) + 1
        with contextlib.suppress(BlockingIOError):
            os.write(wake_w, b"x")

    marker_sub = session.declare_subscriber(f"{tag}/m/*", on_marker)
    cc = zenoh.CongestionControl
    # to the other sessions only, as an agent process's hub publishes (its own agents get their
    # siblings' messages from it directly)
    pub = session.declare_publisher(
        f"{tag}/c/{index}",
        congestion_control=cc.DROP,
        express=False,
        allowed_destination=zenoh.Locality.REMOTE,
    )
    mark = session.declare_publisher(f"{tag}/m/{index}", congestion_control=cc.BLOCK, express=True)
    payload = bytes(PAYLOAD_BYTES)
    # the mesh forms by gossip; then every process starts together (round -1's markers)
    time.sleep(2.0)
    mark.put(b"-1")
    deadline = time.monotonic() + 30.0
    while markers.get(-1, 0) < n - 1 and time.monotonic() < deadline:
        select.select([wake_r], [], [], 0.1)
        mark.put(b"-1")  # until all are there (an early one's went to no one)
    time.sleep(0.2)
    got = late = 0
    c0 = w0 = 0.0
    t_next = time.monotonic()
    for k in range(rounds):
        if k == WARM_ROUNDS:
            c0, w0, got, late = time.process_time(), time.monotonic(), 0, 0
        pub.put(payload)
        if mode == "lockstep":
            mark.put(str(k).encode())
            stuck = time.monotonic() + 30.0
            while markers.get(k, 0) < n - 1:
                if time.monotonic() > stuck:  # a process died or the mesh never formed
                    raise SystemExit(f"process {index}: round {k}'s markers did not all come")
                select.select([wake_r], [], [], 0.5)
                with contextlib.suppress(BlockingIOError):
                    os.read(wake_r, 4096)
        else:
            t_next += 1.0 / CONTROL_HZ
            wait = t_next - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            else:
                late += 1
        while data.try_recv() is not None:
            got += 1
    c1, w1 = time.process_time(), time.monotonic()
    measured = rounds - WARM_ROUNDS
    time.sleep(0.5)  # the others' last rounds
    marker_sub.undeclare()
    session.close()
    return {
        "rounds_per_s": measured / (w1 - w0),
        "cpu_ms_per_round": 1e3 * (c1 - c0) / measured,
        "received_per_round": got / measured,
        "late": late,
    }


def run_case(mode: str, n: int, rounds: int, topology: str = "mesh") -> dict[str, Any]:
    """``n`` worker processes of ``mode`` in ``topology`` (module docstring)."""
    import psutil

    ports = _free_tcp_ports(n + 1)
    tag = f"floor{os.getpid()}x{n}{mode[0]}{topology[0]}"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    load = os.getloadavg()[0]
    router = started = None
    case = [mode, str(rounds), tag, ",".join(map(str, ports[:n]))]
    if topology == "router":
        endpoint = f"tcp/127.0.0.1:{ports[n]}"
        router = subprocess.Popen(
            [sys.executable, "-m", "gcs.cli", "router", "--listen", endpoint],
            cwd=ROOT,
            env=env,
            stderr=subprocess.DEVNULL,
        )
        time.sleep(1.5)  # listening before the clients connect (they would retry, later)
        case.append(endpoint)
        started = psutil.Process(router.pid).cpu_times()
    try:
        procs = [
            subprocess.Popen(
                [sys.executable, "-m", "bench.messaging_floor", "worker", str(i), *case],
                cwd=ROOT,
                env=env,
                stdout=subprocess.PIPE,
                text=True,
            )
            for i in range(n)
        ]
        outs = []
        for i, p in enumerate(procs):
            lines = p.communicate(timeout=900)[0].strip().splitlines()
            if p.returncode != 0 or not lines:
                raise RuntimeError(f"{mode} x {n}: worker {i} failed (exit {p.returncode})")
            outs.append(json.loads(lines[-1]))
        router_ms = None  # the router's CPU per round (the clients' joining included)
        if router is not None and started is not None:
            times = psutil.Process(router.pid).cpu_times()
            spent = times.user + times.system - started.user - started.system
            router_ms = 1e3 * spent / rounds
    finally:
        if router is not None:
            router.terminate()
            router.wait(timeout=30)
    rps = sum(o["rounds_per_s"] for o in outs) / n
    cpu_ms = sum(o["cpu_ms_per_round"] for o in outs) / n
    return {
        "mode": mode,
        "processes": n,
        "topology": topology,
        "rounds_per_s": round(rps, 1),
        "best_rtf": round(rps / CONTROL_HZ, 2),
        "cpu_ms_per_process_round": round(cpu_ms, 3),
        "cores": round(n * cpu_ms * rps / 1000.0, 2),
        "router_cores": None if router_ms is None else round(router_ms * rps / 1000.0, 2),
        "received_per_round": round(sum(o["received_per_round"] for o in outs) / n, 1),
        "late_rounds": sum(o["late"] for o in outs),
        "load_1min": round(load, 1),
    }


def messaging_floor(rounds: int = 1000) -> dict[str, Any]:
    """Every case of :data:`CASES`; writes :data:`OUT_JSON`."""
    rows = []
    for mode, n, topology in CASES:
        row = run_case(mode, n, rounds, topology)
        print(json.dumps(row), file=sys.stderr, flush=True)
        rows.append(row)
    result = {"rounds": rounds, "payload_bytes": PAYLOAD_BYTES, "rows": rows}
    OUT_JSON.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    return result


def main(argv: list[str] | None = None) -> int:
    """CLI (module docstring); ``worker I MODE ROUNDS TAG PORTS [ROUTER]`` is one process of a
    case."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "worker":
        index, mode, rounds, tag, ports = argv[1:6]  # (run_case's order)
        router = argv[6] if len(argv) > 6 else None
        listed = [int(p) for p in ports.split(",")]
        figures = worker(int(index), listed, mode, int(rounds), tag, router)
        print(json.dumps(figures), flush=True)
        return 0
    parser = argparse.ArgumentParser(prog="python -m bench.messaging_floor", description=__doc__)
    parser.add_argument("--rounds", type=int, default=1000, help="rounds per case (default 1000)")
    args = parser.parse_args(argv)
    if args.rounds <= 2 * WARM_ROUNDS:
        parser.error(f"--rounds must be above {2 * WARM_ROUNDS} (the first {WARM_ROUNDS} warm up)")
    print(json.dumps(messaging_floor(args.rounds), indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

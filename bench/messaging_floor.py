"""The messaging floor of one process per drone: what N Zenoh sessions on this machine cost
for the consensus traffic alone, with no estimator, controller, MAVLink, simulator or ground
station. It bounds what ``swarm up --agents-per-process 1`` can reach on two cores whatever the
agents' own code costs.

``python -m bench.messaging_floor [--rounds R]`` (about 3 minutes; on request:
``python -m bench.run --only messaging_floor``). Writes ``bench/results_messaging_floor.json``.

N worker processes (``subprocess``, never forked after a session opened), one Zenoh session each
with the settings ``swarm agent`` takes by default (drone_agent.process.agent_cli.zenoh_settings:
the first listens on a rendezvous endpoint on loopback, the others connect to it and mesh by gossip;
lockstep's longer lease and deeper send queue), through the agents' Zenoh adapter. Per round
each publishes one consensus sample of ``PAYLOAD_BYTES`` on its own key, to the other sessions
only (QUEUED in lockstep, express DROP in realtime, as an agent process's hub), and drains every
sample that came (a pulled ring channel, as the hub does):

- ``lockstep``: then publishes an express round-done marker (as the round book) and waits, on a
  pipe written by a marker callback, until every other process's marker of the round has come
  (the agents' round gate); as fast as that goes: ``rounds_per_s`` / 50 is the best real-time
  factor such a swarm can fly at;
- ``realtime``: paced by the wall clock at 50 Hz (the control rate); ``late`` counts rounds that
  started behind their time.

Topology ``mesh`` (the peers, as above) or ``router``: every process a Zenoh client of one router
(``swarm router``, the project's, a process of its own), which fans the samples out; its CPU per
wall second over the first process's measured rounds (sampled every 50 ms) is
``router_cores``.

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
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from bench.provenance import write_result

ROOT = Path(__file__).resolve().parents[1]
OUT_JSON = ROOT / "bench" / "results_messaging_floor.json"
CONTROL_HZ = 50
#: a consensus message of an agent with eight neighbours is about 1.4 kB (protocols/wire/format.py)
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


def _settings(mode: str, first: bool, endpoint: str, router: bool) -> Any:
    """The Zenoh settings ``swarm agent`` takes in ``mode`` (drone_agent.process.agent_cli): a peer
    listening on the rendezvous ``endpoint`` (the ``first``) or connected to it, or a client of
    the router there."""
    from drone_agent.process.agent_cli import zenoh_settings

    if router:
        listen, connect = None, [endpoint]
    else:
        listen, connect = ([endpoint], []) if first else (["tcp/127.0.0.1:0"], [endpoint])
    return zenoh_settings(
        argparse.Namespace(
            zenoh_listen=listen,
            zenoh_connect=connect,
            zenoh_mode="client" if router else "peer",
            lockstep=mode == "lockstep",
            secrets=None,
        )
    )


def worker(
    index: int, n: int, mode: str, rounds: int, tag: str, endpoint: str, router: bool
) -> dict[str, Any]:
    """One of the ``n`` processes of a case (module docstring); returns its figures. Its
    session: :func:`_settings`, through the agents' Zenoh adapter (protocols.bus.zenoh_bus):
    the consensus publisher as an agent process's hub declares it (to other sessions only;
    QUEUED in lockstep, express DROP in realtime), the markers as its round book does (express
    DROP)."""
    from drone_agent.process.host import REPEAT_MARKERS_S
    from protocols.bus.interface import Congestion
    from protocols.bus.zenoh_bus import ZenohBus

    bus = ZenohBus.open(_settings(mode, index == 0, endpoint, router))
    data = bus.subscribe(f"{tag}/c/*", 256)
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_r, False)
    os.set_blocking(wake_w, False)
    # the newest round each other process has finished (a marker says all rounds up to its
    # own are done, as the agents' round book reads them: a lost one is made up by the next)
    done: dict[int, int] = {}

    def on_marker(_key: str, payload: bytes) -> None:
        k, sender = map(int, payload.split(b","))
        if sender != index and k > done.get(sender, -2):  # (its own comes back too)
            done[sender] = k
        with contextlib.suppress(BlockingIOError):
            os.write(wake_w, b"x")

    def heard(k: int) -> int:
        return sum(r >= k for r in list(done.values()))

    bus.subscribe_callback(f"{tag}/m/*", on_marker)
    congestion = Congestion.QUEUED if mode == "lockstep" else Congestion.DROP
    pub = bus.publisher(f"{tag}/c/{index}", congestion, remote_only=True)
    mark = bus.publisher(f"{tag}/m/{index}", Congestion.DROP)
    payload = bytes(PAYLOAD_BYTES)
    # the mesh forms by gossip; then every process starts together (round -1's markers)
    time.sleep(2.0)
    mark.put(b"-1,%d" % index)
    deadline = time.monotonic() + 30.0
    while heard(-1) < n - 1 and time.monotonic() < deadline:
        select.select([wake_r], [], [], 0.1)
        mark.put(b"-1,%d" % index)  # until all are there (an early one's went to no one)
    time.sleep(0.2)
    got = late = 0
    c0 = w0 = 0.0
    t_next = time.monotonic()
    for k in range(rounds):
        if k == WARM_ROUNDS:
            c0, w0, got, late = time.process_time(), time.monotonic(), 0, 0
        pub.put(payload)
        if mode == "lockstep":
            marker = b"%d,%d" % (k, index)
            mark.put(marker)
            stuck = time.monotonic() + 30.0
            while heard(k) < n - 1:
                if time.monotonic() > stuck:  # a process died or the mesh never formed
                    raise SystemExit(f"process {index}: round {k}'s markers did not all come")
                # express DROP loses a marker now and then: sent again, as the agents' host
                # does (drone_agent/process/host.py, REPEAT_MARKERS_S)
                if not select.select([wake_r], [], [], REPEAT_MARKERS_S)[0]:
                    mark.put(marker)
                with contextlib.suppress(BlockingIOError):
                    os.read(wake_r, 4096)
        else:
            t_next += 1.0 / CONTROL_HZ
            wait = t_next - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            else:
                late += 1
        got += len(data.drain())
    c1, w1 = time.process_time(), time.monotonic()
    measured = rounds - WARM_ROUNDS
    time.sleep(0.5)  # the others' last rounds
    bus.close()
    return {
        "rounds_per_s": measured / (w1 - w0),
        "cpu_ms_per_round": 1e3 * (c1 - c0) / measured,
        "received_per_round": got / measured,
        "late": late,
        "window": [w0, w1],
    }


def run_case(mode: str, n: int, rounds: int, topology: str = "mesh") -> dict[str, Any]:
    """``n`` worker processes of ``mode`` in ``topology`` (module docstring)."""
    import psutil

    from protocols.bus.zenoh_bus import free_loopback_endpoint

    endpoint = free_loopback_endpoint()  # the rendezvous, or the router's
    tag = f"floor{os.getpid()}x{n}{mode[0]}{topology[0]}"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    load = os.getloadavg()[0]
    router = None
    if topology == "router":
        router = subprocess.Popen(
            [sys.executable, "-m", "gcs.cli", "router", "--listen", endpoint],
            cwd=ROOT,
            env=env,
            stderr=subprocess.DEVNULL,
        )
        time.sleep(1.5)  # listening before the clients connect (they would retry, later)
    case = [str(n), mode, str(rounds), tag, endpoint, topology]
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
        samples = []  # the router's (time, CPU s) while the workers run
        while router is not None and any(p.poll() is None for p in procs):
            t = psutil.Process(router.pid).cpu_times()
            samples.append((time.monotonic(), t.user + t.system))
            time.sleep(0.05)
        outs = []
        for i, p in enumerate(procs):
            lines = p.communicate(timeout=900)[0].strip().splitlines()
            if p.returncode != 0 or not lines:
                raise RuntimeError(f"{mode} x {n}: worker {i} failed (exit {p.returncode})")
            outs.append(json.loads(lines[-1]))
        router_cores = None  # over worker 0's measured rounds (time.monotonic is system-wide)
        if samples:
            w0, w1 = outs[0]["window"]
            inside = [(t, c) for t, c in samples if w0 <= t <= w1]
            if len(inside) >= 2:
                (ta, ca), (tb, cb) = inside[0], inside[-1]
                router_cores = round((cb - ca) / (tb - ta), 2)
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
        "router_cores": router_cores,
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
    write_result(OUT_JSON, result, indent=2)
    return result


def main(argv: list[str] | None = None) -> int:
    """CLI (module docstring); ``worker I N MODE ROUNDS TAG ENDPOINT TOPOLOGY`` is one process
    of a case."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "worker":
        index, n, mode, rounds, tag, endpoint, topology = argv[1:8]  # (run_case's order)
        figures = worker(int(index), int(n), mode, int(rounds), tag, endpoint, topology == "router")
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

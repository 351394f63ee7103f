"""Consensus over Zenoh on loopback: one-way latency and CPU per agent per tick.

For each configuration (9 agents in 3 processes, 50 agents in 2 processes) the agents are hosted
in worker processes, one Zenoh session each (peers meshed by gossip from one seed endpoint), and
publish their consensus message (with an edge sum per in-range neighbour: 8 in the interior of
the 6 m grid, 10 m range) at the control rate through the real transport (``AgentLink``: cell
keys, encoding, range filter, decoding).

- *Latency*: each message carries its send time (``time.monotonic()``, system-wide on Linux) in
  ``gamma[0]``. One probe agent per worker polls ``receive()`` every ``POLL_S`` and records
  arrival minus send time, so figures include up to ``POLL_S`` of polling delay (upper bounds).
- *CPU*: the other agents call ``receive()`` once per tick, as an agent would. CPU per agent per
  tick is the workers' process CPU time (all threads, Zenoh's included) over the measured
  window, divided by agents x ticks.
- *Delivered*: messages the probe received over those its in-range neighbours sent.

Run alone: ``python -m bench.zenoh_latency [--duration-s 5]``.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

SPACING_M = 6.0
RANGE_M = 10.0
RATE_HZ = 50.0
POLL_S = 0.0002
WARMUP_S = 1.0
CONFIGS = ((9, 3), (50, 2))  # (agents, processes)
TARGET_P99_MS = 2.0
_ROOT = Path(__file__).resolve().parents[1]


def grid_positions(n: int) -> list[tuple[float, float, float]]:
    """Positions (NED, m) of ``n`` drones on a square grid ``SPACING_M`` apart at 10 m up."""
    side = math.ceil(math.sqrt(n))
    return [(SPACING_M * (i // side), SPACING_M * (i % side), -10.0) for i in range(n)]


def _neighbours(positions: list[tuple[float, float, float]], i: int) -> list[int]:
    return [j for j, p in enumerate(positions) if j != i and math.dist(p, positions[i]) < RANGE_M]


def probe_drone(n: int) -> int:
    """The drone with the most neighbours (the first such one): the latency probe."""
    positions = grid_positions(n)
    return max(range(n), key=lambda i: (len(_neighbours(positions, i)), -i))


def run_worker(
    drones: list[int], n: int, settings: Any, start_at: float, duration_s: float, probe: bool
) -> dict[str, Any]:
    """Host ``drones`` on one session from ``start_at`` for ``duration_s`` (monotonic s).

    A host receives once per tick; the probe (one drone) polls every ``POLL_S`` and records
    latencies and which (sender, round) arrived."""
    from drone_agent.process.transport_link import AgentLink, LinkSettings
    from protocols.bus.zenoh_bus import ZenohBus
    from protocols.wire.consensus_message import ConsensusMessage

    positions = grid_positions(n)
    edges = {i: {j: np.full(18, 0.5) for j in _neighbours(positions, i)} for i in drones}
    bus = ZenohBus.open(settings)
    links = [AgentLink(bus, i, positions[i], LinkSettings("bench", RANGE_M)) for i in drones]
    latencies: list[float] = []
    arrived: set[tuple[int, int]] = set()
    published: list[int] = []  # rounds sent in the measured window
    dt = 1.0 / RATE_HZ
    first_round = round(WARMUP_S / dt)
    cpu0, t0 = 0.0, 0.0
    time.sleep(max(0.0, start_at - time.monotonic()))
    while (round_ := round((time.monotonic() - start_at) / dt)) * dt < duration_s:
        if round_ >= first_round:
            if not published:
                cpu0, t0 = time.process_time(), time.monotonic()
            published.append(round_)
        for link in links:
            gamma = np.zeros(18)
            gamma[0] = time.monotonic()
            heard = frozenset(edges[link.drone])
            msg = ConsensusMessage(link.drone, round_, gamma, edges[link.drone], heard, len(heard))
            link.publish_consensus(msg, positions[link.drone])
        next_tick = start_at + (round_ + 1) * dt
        if not probe:
            for link in links:
                link.receive()
            time.sleep(max(0.0, next_tick - time.monotonic()))
            continue
        while (now := time.monotonic()) < next_tick:
            for packet in links[0].receive():
                if packet.message.round >= first_round:
                    latencies.append(now - float(packet.message.gamma[0]))
                    arrived.add((packet.message.sender, packet.message.round))
            time.sleep(POLL_S)
    cpu_s, wall_s = time.process_time() - cpu0, time.monotonic() - t0
    for link in links:
        link.close()
    bus.close()
    if not published:
        raise RuntimeError("the worker started after the measured window")
    return {"latencies_s": latencies, "cpu_s": cpu_s, "wall_s": wall_s, "rounds": published,
            "agents": len(drones), "arrived": sorted(arrived)}  # fmt: skip


def _delivered_pct(probe: int, n: int, groups: list[list[int]], results: list[Any]) -> float:
    """Messages the probe got over those its in-range neighbours sent in the window (leaving
    out the last rounds, which may still be on their way)."""
    last = max(results[-1]["rounds"]) - 5
    rounds_of = {i: set(r["rounds"]) for g, r in zip(groups, results, strict=True) for i in g}
    neighbours = _neighbours(grid_positions(n), probe)
    sent = {(j, q) for j in neighbours for q in rounds_of[j] if q < last}
    got = {(j, q) for j, q in results[-1]["arrived"]} & sent
    return 100.0 * len(got) / max(len(sent), 1)


def measure(
    n_agents: int,
    n_processes: int,
    duration_s: float,
    session_args: Callable[[int], list[str]] | None = None,
) -> dict[str, Any]:
    """One configuration: start the hosts and the probe, gather and summarise their results.

    ``session_args(k)``: the Zenoh flags of worker ``k`` (default: peers meshed from worker 0's
    endpoint; bench/zenoh_router.py gives clients of a router)."""
    from protocols.bus.zenoh_bus import free_loopback_endpoint

    seed = free_loopback_endpoint()
    start_at = time.monotonic() + 2.0 + 0.3 * n_processes
    probe = probe_drone(n_agents)
    hosted = [i for i in range(n_agents) if i != probe]
    groups = [list(map(int, g)) for g in np.array_split(hosted, n_processes)] + [[probe]]
    workers = []
    for k, group in enumerate(groups):
        args = [sys.executable, "-m", "bench.zenoh_latency", "--worker", ",".join(map(str, group))]
        args += [
            "--n",
            str(n_agents),
            "--start-at",
            repr(start_at),
            "--duration-s",
            str(duration_s),
        ]
        if session_args is not None:
            args += session_args(k)
        else:
            args += ["--listen", seed] if k == 0 else ["--connect", seed]
        args += ["--probe"] if k == len(groups) - 1 else []
        workers.append(subprocess.Popen(args, cwd=_ROOT, stdout=subprocess.PIPE, text=True))
    results = []
    for w in workers:
        out, _ = w.communicate(timeout=duration_s + 60)
        if w.returncode != 0:
            raise RuntimeError(f"benchmark worker failed with exit code {w.returncode}")
        results.append(json.loads(out.strip().splitlines()[-1]))
    hosts, probe_result = results[:-1], results[-1]
    lat_ms = 1e3 * np.array(probe_result["latencies_s"])
    cpu_s = sum(r["cpu_s"] for r in hosts)
    return {
        "agents": n_agents,
        "processes": f"{n_processes}+probe",
        "rate_hz": RATE_HZ,
        "samples": int(lat_ms.size),
        "p50_ms": round(float(np.percentile(lat_ms, 50)), 3),
        "p99_ms": round(float(np.percentile(lat_ms, 99)), 3),
        "max_ms": round(float(lat_ms.max()), 3),
        "delivered_pct": round(_delivered_pct(probe, n_agents, groups, results), 2),
        "cpu_us_per_agent_tick": round(
            1e6 * cpu_s / sum(r["agents"] * len(r["rounds"]) for r in hosts), 1
        ),
        "cpu_pct_core_per_agent": round(
            100.0 * cpu_s / (max(r["wall_s"] for r in hosts) * len(hosted)), 2
        ),
    }


def zenoh_latency(duration_s: float = 5.0) -> dict[str, Any]:
    """The benchmark entry of ``bench.run``: both configurations, as table rows."""
    rows = [measure(n, p, duration_s) for n, p in CONFIGS]
    return {
        "rows": rows,
        "note": f"latency includes up to {POLL_S * 1e3:.1f} ms of receiver polling",
        "target": f"p99 < {TARGET_P99_MS} ms",
        "target_met": all(r["p99_ms"] < TARGET_P99_MS for r in rows),
    }


def main(argv: list[str] | None = None) -> int:
    """Worker mode (``--worker IDS``) or the whole benchmark, printed as a table."""
    parser = argparse.ArgumentParser(prog="python -m bench.zenoh_latency", description=__doc__)
    parser.add_argument("--worker", help="comma-separated drone ids to host (internal)")
    parser.add_argument("--n", type=int, default=9)
    parser.add_argument("--start-at", type=float, default=0.0)
    parser.add_argument("--duration-s", type=float, default=5.0)
    parser.add_argument("--listen", default=None)
    parser.add_argument("--connect", default=None)
    parser.add_argument("--probe", action="store_true", help="poll and record latencies")
    parser.add_argument("--client", action="store_true", help="a client of --connect (router)")
    parser.add_argument("--secrets", default=None, help="agent credential of a secured router")
    args = parser.parse_args(argv)
    if args.worker is None:
        from bench.tables import format_rows

        result = zenoh_latency(args.duration_s)
        print(format_rows("zenoh_latency", result["rows"]))
        print(f"{result['note']}; target {result['target']} met: {result['target_met']}")
        return 0
    from protocols.bus.zenoh_bus import ZenohSettings
    from protocols.bus.zenoh_config import role_secrets

    if args.client:
        settings = ZenohSettings(
            mode="client",
            listen=(),
            connect=(args.connect,),
            secrets=role_secrets(args.secrets, "agent"),
        )
    else:
        settings = ZenohSettings(
            listen=(args.listen,) if args.listen else ("tcp/127.0.0.1:0",),
            connect=(args.connect,) if args.connect else (),
        )
    drones = [int(x) for x in args.worker.split(",")]
    result = run_worker(drones, args.n, settings, args.start_at, args.duration_s, args.probe)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Consensus through a Zenoh router vs peer to peer, and what TLS with authentication costs.

The agents of ``bench.zenoh_latency`` (9 agents in 3 processes + a probe process, 50 Hz, one-way
latency of the consensus messages measured by the probe) in three set-ups on loopback:

- ``peer``: peers meshed by gossip (the single-host default);
- ``router``: every process a client of ``swarm router`` (plain TCP), as on several hosts;
- ``router+tls``: the same, secured (``swarm keys init``): TLS with client certificates,
  user/password and the swarm's access control checked by the router on every message.

Each row: latency p50/p99/max (ms, with up to 0.2 ms of receiver polling), messages delivered,
the agent processes' CPU per agent per tick, and the router's CPU (% of a core) over the window.
Then the time to open a client session (TCP vs TLS + authentication, median of 10): what a
short-lived operator command pays.

Run alone: ``python -m bench.zenoh_router [--duration-s 5]``.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from bench.zenoh_latency import WARMUP_S, measure

AGENTS, PROCESSES = 9, 3
SESSION_OPENS = 10
_ROOT = Path(__file__).resolve().parents[1]


def _cpu_s(pid: int) -> float:
    """User + system CPU time (s) of process ``pid`` so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@contextlib.contextmanager
def _router(endpoint: str, secrets: Path | None) -> Iterator[subprocess.Popen[bytes]]:
    argv = [sys.executable, "-m", "gcs.cli", "router", "--listen", endpoint]
    argv += ["--secrets", str(secrets)] if secrets is not None else []
    proc = subprocess.Popen(argv, cwd=_ROOT, stderr=subprocess.PIPE)
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline().decode()
        if "listening" not in line:
            raise RuntimeError(f"the router did not start: {line.strip()}")
        yield proc
    finally:
        proc.terminate()
        proc.wait(15)


def _row(name: str, duration_s: float, secrets: Path | None) -> dict[str, Any]:
    from protocols.bus.zenoh_bus import free_loopback_endpoint

    if name == "peer":
        return {"setup": name, **measure(AGENTS, PROCESSES, duration_s), "router_cpu_pct": None}
    endpoint = free_loopback_endpoint()
    if secrets is not None:
        endpoint = endpoint.replace("tcp/", "tls/")
    flags = ["--client", "--connect", endpoint]
    flags += ["--secrets", str(secrets)] if secrets is not None else []
    with _router(endpoint, secrets) as router:
        cpu0, t0 = _cpu_s(router.pid), time.monotonic()
        row = measure(AGENTS, PROCESSES, duration_s, lambda _k: flags)
        cpu = _cpu_s(router.pid) - cpu0
        wall = time.monotonic() - t0
    # the router's CPU over the whole run (start-up of the agents, warm-up and window)
    return {"setup": name, **row, "router_cpu_pct": round(100.0 * cpu / wall, 1)}


def _open_times_ms(endpoint: str, secrets: Path | None) -> float:
    from protocols.bus.zenoh_bus import open_client
    from protocols.bus.zenoh_config import role_secrets

    times = []
    for _ in range(SESSION_OPENS):
        t = time.perf_counter()
        bus = open_client(endpoint, role_secrets(secrets, "operator", "bench"))
        times.append(1e3 * (time.perf_counter() - t))
        bus.close()
    return round(statistics.median(times), 1)


def session_open(secrets: Path) -> dict[str, Any]:
    """Median time (ms) to open a client session to a router: plain TCP vs TLS + auth."""
    from protocols.bus.zenoh_bus import free_loopback_endpoint

    out: dict[str, Any] = {}
    for name, folder in (("tcp_ms", None), ("tls_auth_ms", secrets)):
        endpoint = free_loopback_endpoint()
        if folder is not None:
            endpoint = endpoint.replace("tcp/", "tls/")
        with _router(endpoint, folder):
            out[name] = _open_times_ms(endpoint, folder)
    return out


def zenoh_router(duration_s: float = 5.0, repeats: int = 3) -> dict[str, Any]:
    """The benchmark entry of ``bench.run``: the three set-ups taking turns ``repeats`` times
    (a shared machine's load moves all of them alike); per set-up the run with the median p99."""
    from protocols.secrets.swarm_secrets import init_secrets

    folder = Path(tempfile.mkdtemp(prefix="quadswarm-bench-"))
    setups = {"peer": None, "router": None, "router+tls": folder / "secrets"}
    runs: dict[str, list[dict[str, Any]]] = {name: [] for name in setups}
    try:
        init_secrets(folder / "secrets", "bench")
        for _ in range(repeats):
            for name, secrets in setups.items():
                runs[name].append(_row(name, duration_s, secrets))
        opens = session_open(folder / "secrets")
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    rows = []
    for got in runs.values():
        ordered = sorted(got, key=lambda r: r["p99_ms"])
        rows.append({**ordered[len(ordered) // 2], "p50_ms_runs": [r["p50_ms"] for r in got],
                     "p99_ms_runs": [r["p99_ms"] for r in got]})  # fmt: skip
    return {
        "rows": rows,
        "session_open": opens,
        "note": f"{AGENTS} agents in {PROCESSES} processes + probe, loopback; warm-up "
        f"{WARMUP_S:g} s; latency includes up to 0.2 ms of receiver polling; {repeats} runs "
        "per set-up, taking turns; the row is the run with the median p99",
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.zenoh_router", description=__doc__)
    parser.add_argument("--duration-s", type=float, default=5.0)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    from bench.tables import format_rows

    result = zenoh_router(args.duration_s, args.repeats)
    print(format_rows("zenoh_router", result["rows"]))
    opens = result["session_open"]
    print(f"client session open: tcp {opens['tcp_ms']} ms, tls+auth {opens['tls_auth_ms']} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""A lockstep agent's Zenoh session keeps its consensus messages under load: a deeper send
queue and a longer wait before DROP gives up (drone_agent/agent_cli.py, ZenohSettings)."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from drone_agent.agent_cli import (
    LOCKSTEP_DROP_WAIT_US,
    LOCKSTEP_TX_QUEUE_BATCHES,
    zenoh_runtime,
    zenoh_settings,
)
from drone_agent.zenoh_config import AGENT_RUNTIME, RUNTIME_ENV
from drone_agent.zenoh_transport import ZenohBus, ZenohSettings


def _args(lockstep: bool) -> argparse.Namespace:
    return argparse.Namespace(
        zenoh_listen=["tcp/127.0.0.1:0"],
        zenoh_connect=[],
        zenoh_mode="peer",
        secrets=None,
        swarm_id="t",
        lockstep=lockstep,
    )


def test_lockstep_sessions_queue_deeper_and_wait_longer() -> None:
    lockstep, realtime = zenoh_settings(_args(True)), zenoh_settings(_args(False))
    assert lockstep.tx_queue_batches == LOCKSTEP_TX_QUEUE_BATCHES > 2
    assert lockstep.drop_wait_us == LOCKSTEP_DROP_WAIT_US
    assert realtime.tx_queue_batches is None and realtime.drop_wait_us is None
    conf = lockstep.config()
    assert json.loads(conf.get_json("transport/link/tx/queue/size/data")) == 16
    queue = "transport/link/tx/queue/congestion_control/drop/wait_before_drop"
    assert json.loads(conf.get_json(queue)) == LOCKSTEP_DROP_WAIT_US
    with ZenohBus.open(lockstep):  # Zenoh takes the configuration
        pass


@pytest.mark.parametrize("batches", [0, 65])
def test_a_queue_depth_out_of_range_is_refused(batches: int) -> None:
    with pytest.raises(ValueError, match="tx_queue_batches"):
        ZenohSettings(tx_queue_batches=batches)


def test_a_lockstep_agent_runs_zenoh_on_one_thread_unless_told_otherwise() -> None:
    env: dict[str, str] = {}
    assert zenoh_runtime(_args(False), env) is None and env == {}
    assert zenoh_runtime(_args(True), env) == AGENT_RUNTIME == env[RUNTIME_ENV]
    own = {RUNTIME_ENV: "(rx: (worker_threads: 3))"}
    assert zenoh_runtime(_args(True), own) == "(rx: (worker_threads: 3))"


_THREADS = """
import collections, glob, sys, time
from drone_agent.transport import Congestion
from drone_agent.zenoh_config import use_agent_runtime
from drone_agent.zenoh_transport import ZenohBus, ZenohSettings, free_loopback_endpoint
use_agent_runtime()
endpoint = free_loopback_endpoint()
with ZenohBus.open(ZenohSettings(listen=(endpoint,))) as a, \\
        ZenohBus.open(ZenohSettings(connect=(endpoint,))) as b:
    inbox = b.subscribe("t/**", 1024)
    queued, express = a.publisher("t/q", Congestion.QUEUED), a.publisher("t/e", Congestion.DROP)
    deadline = time.monotonic() + 20
    while not inbox.drain() and time.monotonic() < deadline:  # b's subscription known to a
        express.put(b"-")
        time.sleep(0.05)
    got = []
    for i in range(300):
        (queued if i % 3 else express).put(str(i).encode())
    while time.monotonic() < deadline:
        got += [p for _, p in inbox.drain() if p != b"-"]
        if len(got) >= 300:
            break
        time.sleep(0.01)
    names = [open(p).read().strip() for p in glob.glob("/proc/self/task/*/comm")]
    print(" ".join(p.decode() for p in got))
    print(" ".join(sorted(collections.Counter(n.split("-")[0] for n in names))))
"""


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="thread names from /proc")
def test_one_zenoh_thread_still_delivers_a_sessions_samples_in_order() -> None:
    done = subprocess.run(
        [sys.executable, "-c", _THREADS],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])},
    )
    assert done.returncode == 0, done.stderr[-2000:]
    samples, pools = done.stdout.splitlines()
    # every sample, in the order sent, express (marker-like) and queued (consensus-like) alike
    assert samples.split() == [str(i) for i in range(300)]
    # Zenoh's pools all handed over to app: no rx, tx, acc or net threads
    assert set(pools.split()) == {"app", "python"}, pools

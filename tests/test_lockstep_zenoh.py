"""A lockstep agent's Zenoh session keeps its consensus messages under load: a deeper send
queue and a longer wait before DROP gives up (drone_agent/process/agent_cli.py, ZenohSettings)."""

from __future__ import annotations

import argparse
import json
import time

import pytest

from drone_agent.process.agent_cli import (
    LOCKSTEP_DROP_WAIT_US,
    LOCKSTEP_TX_QUEUE_BATCHES,
    zenoh_settings,
)
from protocols.bus.interface import Congestion
from protocols.bus.zenoh_bus import ZenohBus, ZenohSettings, free_loopback_endpoint


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


def test_a_sessions_queued_and_express_samples_arrive_in_send_order() -> None:
    """The round gate's premise (drone_agent/process/round_gate.py): a lockstep session's consensus
    messages (QUEUED) reach another session before the round-done marker (express) put after
    them. Lockstep sessions as the agents open them (a deep queue, a long wait before a drop):
    with Zenoh's defaults (2 batches, 1 ms before a drop) this test failed once at load 18."""
    endpoint = free_loopback_endpoint()
    lockstep = {
        "tx_queue_batches": LOCKSTEP_TX_QUEUE_BATCHES,
        "drop_wait_us": LOCKSTEP_DROP_WAIT_US,
    }
    with (
        ZenohBus.open(ZenohSettings(listen=(endpoint,), **lockstep)) as a,
        ZenohBus.open(ZenohSettings(connect=(endpoint,), **lockstep)) as b,
    ):
        inbox = b.subscribe("t/**", 1024)
        queued = a.publisher("t/q", Congestion.QUEUED)
        express = a.publisher("t/e", Congestion.DROP)
        deadline = time.monotonic() + 20
        while not inbox.drain() and time.monotonic() < deadline:  # b's subscription known to a
            express.put(b"-")
            time.sleep(0.05)
        for i in range(300):
            (queued if i % 3 else express).put(str(i).encode())
        got: list[bytes] = []
        while len(got) < 300 and time.monotonic() < deadline:
            got += [p for _, p in inbox.drain() if p != b"-"]
            time.sleep(0.01)
    sent = [str(i).encode() for i in range(300)]
    assert got == sent, f"{len(got)} of 300 arrived; first out of order: " + str(
        next(((i, g) for i, (g, s) in enumerate(zip(got, sent, strict=False)) if g != s), None)
    )

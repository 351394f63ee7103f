"""A lockstep agent's Zenoh session keeps its consensus messages under load: a deeper send
queue and a longer wait before DROP gives up (drone_agent/agent_cli.py, ZenohSettings)."""

from __future__ import annotations

import argparse
import json

import pytest

from drone_agent.agent_cli import (
    LOCKSTEP_DROP_WAIT_US,
    LOCKSTEP_TX_QUEUE_BATCHES,
    zenoh_settings,
)
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

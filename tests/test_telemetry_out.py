"""The simulator's telemetry of a tick, every vehicle's at once (sitl_sim/mavlink_edge/
telemetry_out.py, protocols/mavlink/frame_batch.py), is byte for byte what sending each vehicle's
due messages one by one gives."""

from __future__ import annotations

import argparse
import os
import random
from typing import Any

import numpy as np
import pytest

os.environ["MAVLINK20"] = "1"

from pymavlink.dialects.v20 import common as mavlink

from protocols.mavlink.fast import pack_payload
from protocols.mavlink.frame_batch import frames_of
from protocols.mavlink.signing import setup_signing
from sitl_sim.launch import build_config, build_world
from sitl_sim.mavlink_edge import channel as channel_module
from sitl_sim.mavlink_edge.channel import MAX_DATAGRAM_BYTES, Endpoint
from sitl_sim.network import Network
from sitl_sim.physics.dynamics import POS, QUAT, RATES, VEL
from sitl_sim.server import SimServer
from sitl_sim.sim_cli import add_sim_parser
from tests.sitl_client import free_port_block

ATTITUDE = mavlink.MAVLINK_MSG_ID_ATTITUDE
GLOBAL_POSITION_INT = mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT


class _Codec:
    def __init__(self, sysid: int, seq: int) -> None:
        self.srcSystem, self.srcComponent, self.seq = sysid, 1, seq


def test_frames_are_the_one_by_one_frames() -> None:
    rng = random.Random(3)
    classes = [mavlink.MAVLink_attitude_message, mavlink.MAVLink_actuator_output_status_message,
               mavlink.MAVLink_heartbeat_message, mavlink.MAVLink_statustext_message]  # fmt: skip
    rows: list[list[int]] = [[] for _ in range(7)]
    buffer, want = bytearray(), []
    for _ in range(400):
        cls = rng.choice(classes)
        size = cls.unpacker.size
        payload = bytes(rng.choice([0, 0, rng.randrange(256)]) for _ in range(size))
        if rng.random() < 0.1:
            payload = bytes(size)  # all zero: one byte kept
        seq, sysid = rng.randrange(256), rng.randrange(1, 255)
        want.append(pack_payload(cls, payload, _Codec(sysid, seq)))
        for row, value in zip(rows, (len(buffer), size, cls.id, cls.crc_extra, seq, sysid, 1),
                              strict=True):  # fmt: skip
            row.append(value)
        buffer += payload
    data, ends = frames_of(np.frombuffer(bytes(buffer), dtype=np.uint8),
                           *(np.array(r, dtype=np.int64) for r in rows))  # fmt: skip
    assert [data[a:b] for a, b in zip([0, *ends[:-1]], ends, strict=True)] == want


class _Socket:
    def setblocking(self, _flag: bool) -> None:
        pass


@pytest.mark.parametrize("seed", range(5))
def test_queueing_frames_together_is_queueing_them_one_by_one(seed: int) -> None:
    rng = random.Random(seed)
    together = Endpoint(_Socket(), None, None, set())  # type: ignore[arg-type]
    alone = Endpoint(_Socket(), None, None, set())  # type: ignore[arg-type]
    for _ in range(60):
        sizes = [rng.choice((20, 40, 150, 600, 1100, MAX_DATAGRAM_BYTES)) for _ in range(
            rng.randrange(1, 8))]  # fmt: skip
        data = bytes(rng.randrange(256) for _ in range(sum(sizes) + 7))
        first = rng.randrange(8)
        ends = list(np.cumsum([first, *sizes])[1:])
        together.queue_frames(data, ends, first)
        for a, b in zip([first, *ends[:-1]], ends, strict=True):
            alone.queue(data[a:b])
        assert together._batches == alone._batches
        if rng.random() < 0.3:
            together._batches.clear()
            alone._batches.clear()


def _server(dialect: str, n: int, signing: bool) -> tuple[SimServer, Network]:
    parser = argparse.ArgumentParser()
    add_sim_parser(parser.add_subparsers())
    argv = ["sim", "--drones", str(n), "--base-port", str(free_port_block(n)), "--clock",
            "lockstep", "--quiet", "--gcs", "udp:127.0.0.1:9", "--dialect", dialect]  # fmt: skip
    config = build_config(parser.parse_args(argv))
    network = Network(config.net, config.sysids)
    network.open()
    world, tunables = build_world(config)
    server = SimServer(world, tunables, network, config.clock)
    for i, endpoint in enumerate(network.agent_endpoints):
        if i not in (2, 9):  # two vehicles without an agent yet
            endpoint.peer = ("127.0.0.1", 9)
    if signing:  # three vehicles sign (pymavlink signs their frames)
        for i in (1, 5, 6):
            for channel in (network.agent_channels[i], network.gcs_channels[i]):
                setup_signing(channel.codec, bytes(range(32)), 1)
    return server, network


def _one_by_one(server: SimServer) -> list[int]:
    """The tick's telemetry sent message by message (as the simulator did)."""
    world, tick = server.world, server.world.tick
    server._snapshot = world.snapshot()
    silent = world.autopilot.silent
    sent_to = []
    for side, is_agent in ((server.agent, True), (server.gcs, False)):
        for i, channel in enumerate(side.channels):
            if silent[i] or not channel.active:
                continue
            due = side.streams.of(i).due(tick)
            for msg_id in due:
                channel.send(server._builders[msg_id](i))
            if is_agent and server._tick_message in due:
                sent_to.append(i)
    return sent_to


def _fly(dialect: str, signing: bool, together: bool, sent: list[Any]) -> list[Any]:
    server, network = _server(dialect, 12, signing)
    base = network.config.base_port
    rng = np.random.default_rng(7)
    # vehicles 3 (agent link) and 5 (GCS link) follow schedules of their own
    server.agent.streams.own(3).set_interval_us(ATTITUDE, 60_000)
    server.gcs.streams.own(5).set_interval_us(GLOBAL_POSITION_INT, 20_000)
    rows_at = server._telemetry._rows
    attitude_rows = rows_at.get(ATTITUDE)
    answers = []
    try:
        for k in range(160):
            server.world.step()
            state = server.world.state
            state[POS] += rng.normal(0.0, 0.3, state[POS].shape)
            state[VEL] = rng.normal(0.0, 2.0, state[VEL].shape)
            state[RATES] = rng.normal(0.0, 1.0, state[RATES].shape)
            quat = rng.normal(0.0, 1.0, state[QUAT].shape)
            state[QUAT] = quat / np.linalg.norm(quat, axis=0)
            server.world.autopilot.silent[:] = False
            server.world.autopilot.silent[7] = k % 50 < 20  # silent for a while
            if attitude_rows is not None:  # now and then a value struct packs but rows refuse
                rows_at[ATTITUDE] = (lambda: None) if k % 7 == 3 else attitude_rows
            answers.append(server._emit() if together else _one_by_one(server))
            network.flush()
    finally:
        network.close()
    per: dict[Any, list[bytes]] = {}
    for port, data in sent:
        per.setdefault(port - base if 0 <= port - base < 12 else "gcs", []).append(data)
    return [answers, per]


def _captured(monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    sent: list[Any] = []

    def flush(self: Endpoint) -> None:
        batches, self._batches = self._batches, []
        if self.peer is not None:
            port = self.sock.getsockname()[1]
            sent.extend((port, bytes(b)) for b in batches)

    monkeypatch.setattr(channel_module.Endpoint, "flush", flush)
    return sent


@pytest.mark.parametrize("dialect", ["px4", "ardupilot"])
def test_a_ticks_telemetry_is_what_sending_it_message_by_message_gives(
    dialect: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    sent = _captured(monkeypatch)
    one_by_one = _fly(dialect, False, False, sent)
    sent.clear()
    together = _fly(dialect, False, True, sent)
    assert together == one_by_one
    answers, per = together
    assert sum(map(len, answers)) > 1000 and len(per["gcs"]) > 100
    assert set(per) == {"gcs"} | set(range(12)) - {2, 9}


def test_signing_vehicles_send_their_frames_signed_among_the_others(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    sent = _captured(monkeypatch)
    _, per = _fly("px4", True, True, sent)
    for key, datagrams in per.items():
        flags = {data[2] for data in datagrams}  # the first frame's incompatibility flags
        assert flags == ({1} if key in (1, 5, 6) else {0, 1} if key == "gcs" else {0}), key

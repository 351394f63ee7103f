"""The MAVLink edge: datagram decoding with counts, batching, and the messages a vehicle sends."""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"

import socket

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl_sim.mavlink_edge import messages
from sitl_sim.mavlink_edge.channel import MAX_DATAGRAM_BYTES, Endpoint, decode_datagram, new_codec
from sitl_sim.mavlink_edge.messages import RxCounters
from sitl_sim.vehicle.autopilot import Autopilot, AutopilotConfig, Mode

KEY = bytes(range(32))


def _setpoint_frame(codec: object, thrust: float = 0.5) -> bytes:
    msg = mavlink.MAVLink_set_attitude_target_message(
        100, 1, 1, 7, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, thrust
    )
    return bytes(msg.pack(codec))


def _sender(key: bytes | None = None) -> object:
    return new_codec(1, 191, key)


def test_two_frames_in_one_datagram() -> None:
    tx = _sender()
    data = _setpoint_frame(tx) + _setpoint_frame(tx, 0.7)
    decoded = decode_datagram(new_codec(1, 1, None), data)
    assert [m.thrust for m in decoded.messages] == pytest.approx([0.5, 0.7])
    assert decoded.malformed == decoded.signature_rejected == 0


@pytest.mark.parametrize(
    "mangle",
    [
        lambda f: b"\x00\x01junk" + f,  # junk before a good frame
        lambda f: f[:-3],  # truncated
        lambda f: f[:-1] + bytes([f[-1] ^ 0xFF]),  # bad CRC
        lambda f: bytes(300) + f,  # oversized junk
    ],
    ids=["junk-prefix", "truncated", "bad-crc", "oversized"],
)
def test_damaged_datagrams_are_counted_not_raised(mangle: object) -> None:
    rx = new_codec(1, 1, None)
    decoded = decode_datagram(rx, mangle(_setpoint_frame(_sender())))  # type: ignore[operator]
    assert decoded.malformed >= 1
    # the parser is clean for the next datagram
    assert len(decode_datagram(rx, _setpoint_frame(_sender())).messages) == 1


def test_random_bytes_never_raise() -> None:
    rng = np.random.default_rng(3)
    rx = new_codec(1, 1, None)
    for size in rng.integers(1, 2000, 200):
        data = rng.integers(0, 256, int(size), dtype=np.uint8).tobytes()
        decode_datagram(rx, data)
    assert len(decode_datagram(rx, _setpoint_frame(_sender())).messages) == 1


def test_signing_rejects_unsigned_and_wrong_key_but_accepts_the_right_key() -> None:
    rx = new_codec(1, 1, KEY)
    unsigned = decode_datagram(rx, _setpoint_frame(_sender()))
    wrong = decode_datagram(rx, _setpoint_frame(_sender(bytes(32))))
    right = decode_datagram(rx, _setpoint_frame(_sender(KEY)))
    assert (unsigned.signature_rejected, wrong.signature_rejected) == (1, 1)
    assert not unsigned.messages and not wrong.messages
    assert len(right.messages) == 1 and right.messages[0].get_signed()


def test_radio_status_passes_unsigned() -> None:
    rx = new_codec(1, 1, KEY)
    radio = mavlink.MAVLink_radio_status_message(200, 190, 100, 2, 3, 0, 0)
    decoded = decode_datagram(rx, bytes(radio.pack(_sender())))
    assert [m.get_type() for m in decoded.messages] == ["RADIO_STATUS"]


def test_endpoint_batches_frames_into_datagrams_below_the_limit() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as listener:
        listener.bind(("127.0.0.1", 0))
        listener.settimeout(2.0)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
        outbox: set[Endpoint] = set()
        endpoint = Endpoint(sock, new_codec(1, 1, None), listener.getsockname(), outbox)
        tx = new_codec(1, 1, None)
        frame = _setpoint_frame(tx)
        count = 3 * MAX_DATAGRAM_BYTES // len(frame)
        for _ in range(count):
            endpoint.queue(frame)
        assert outbox == {endpoint}
        endpoint.flush()
        sizes = []
        while sum(sizes) < count * len(frame):
            sizes.append(len(listener.recv(65535)))
        endpoint.close()
    assert all(s <= MAX_DATAGRAM_BYTES and s % len(frame) == 0 for s in sizes)
    assert len(sizes) == endpoint.tx_datagrams == 4


def test_heartbeat_says_px4_quadrotor_mode_and_armed_state() -> None:
    ap = Autopilot(2, AutopilotConfig(), np.zeros(2))
    ap.arm(1, 0.0)
    ap.set_mode(0, Mode.LAND, 0.0)
    hb0, hb1 = messages.heartbeat(ap, 0), messages.heartbeat(ap, 1)
    assert hb0.type == mavlink.MAV_TYPE_QUADROTOR and hb0.autopilot == mavlink.MAV_AUTOPILOT_PX4
    assert hb0.custom_mode == (4 << 16) | (6 << 24) and not hb0.base_mode & 128
    assert hb1.base_mode & 128 and hb1.base_mode & 1
    assert hb1.system_status == mavlink.MAV_STATE_ACTIVE
    assert hb0.system_status == mavlink.MAV_STATE_STANDBY


def test_sys_status_carries_the_counters_and_saturates() -> None:
    ap = Autopilot(1, AutopilotConfig(), np.zeros(1))
    counters = RxCounters(rx=100, malformed=70_000, setpoint_rejected=3, signature_rejected=4)
    counters.wrong_target = 5
    msg = messages.sys_status(ap, 0, counters, 0.25)
    assert (msg.errors_count1, msg.errors_count2, msg.errors_count3, msg.errors_count4) == (
        65535,
        3,
        4,
        5,
    )
    assert msg.errors_comm == 65535 and msg.load == 250 and msg.drop_rate_comm <= 10_000


def test_every_built_message_encodes_and_decodes() -> None:
    tx, rx = new_codec(3, 1, None), new_codec(255, 190, None)
    built = [
        messages.statustext(4, "x" * 80),
        messages.autopilot_version(3),
        messages.command_ack(400, 0, 255, 190),
        messages.param_value("COM_OF_LOSS_T", 0.5, 9, 13),
        messages.timesync(123, 456),
        messages.message_interval(30, 20_000),
    ]
    decoded = [decode_datagram(rx, bytes(m.pack(tx))).messages[0] for m in built]
    assert len(decoded[0].text) == 50
    assert decoded[1].uid == 3 and bytes(decoded[1].flight_custom_version) == b"quadswrm"
    assert decoded[3].param_id == "COM_OF_LOSS_T"
    assert decoded[3].param_type == mavlink.MAV_PARAM_TYPE_REAL32


def test_a_wrongly_signed_frame_cannot_block_the_signed_stream() -> None:
    """pymavlink alone records the timestamp of a badly signed frame; ours does not."""
    rx = new_codec(1, 1, KEY)
    good = _sender(KEY)
    attacker = _sender(bytes(32))
    attacker.signing.link_id = good.signing.link_id  # same stream: (link, system, component)
    attacker.signing.timestamp = good.signing.timestamp + 10**9  # far in the future
    assert decode_datagram(rx, _setpoint_frame(attacker)).signature_rejected == 1
    assert len(decode_datagram(rx, _setpoint_frame(good)).messages) == 1
    replay = _setpoint_frame(good)
    assert len(decode_datagram(rx, replay).messages) == 1
    assert decode_datagram(rx, replay).signature_rejected == 1  # a replay is refused

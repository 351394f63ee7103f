"""UDP endpoints and MAVLink channels: the simulator's only contact with sockets and encoding.

An :class:`Endpoint` is one bound, non-blocking UDP socket with a receive codec. Outgoing packets
are queued and sent batched, several MAVLink frames per datagram (as PX4 does), when the
simulator flushes at the end of a tick. An agent endpoint answers whoever sent the last valid
MAVLink frame to it; the GCS endpoint sends to a fixed address.

A :class:`Channel` is one vehicle's voice on one endpoint: its own codec (system id, component 1,
sequence numbers, signing) over a shared or private endpoint.

Each datagram is parsed on its own (a truncated frame cannot swallow the next datagram), with
pymavlink's robust parsing: junk, bad CRCs and leftovers come back as counts, never exceptions.
"""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"  # before any pymavlink import (DEPENDENCIES.md)

import socket
import sys
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from protocols.mavlink.conventions import AUTOPILOT_COMPID, SIGNING_LINK_ID
from protocols.mavlink.fast import fast_receive_ok, pack, parse
from protocols.mavlink.signing import setup_signing

Address = tuple[str, int]
#: Messages decoded as their fields alone (protocols/mavlink/fast.py ``fields_of``)
_LIGHT = frozenset({mavlink.MAVLink_set_attitude_target_message})
#: Largest datagram the simulator sends (bytes): below the loopback and Ethernet MTUs.
MAX_DATAGRAM_BYTES = 1200
_RECV_BYTES = 65535
#: Linux's IP_RECVERR (not exported by the socket module): ICMP errors on an unconnected UDP
#: socket are reported, with the address they concern, on its error queue.
IP_RECVERR = 11


def report_unreachable(sock: socket.socket) -> bool:
    """Ask the kernel to report ICMP errors (port unreachable: the peer's socket closed) on
    ``sock``; False where the platform cannot (then a dead peer is noticed by timeouts only)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        sock.setsockopt(socket.IPPROTO_IP, IP_RECVERR, 1)
    except OSError:
        return False
    return True


_SIGNATURE_REASON = "Invalid signature"
#: How far (10 µs units: one minute) a new signed stream may lag our timestamp (as pymavlink).
_NEW_STREAM_SLACK = 6_000_000


@dataclass(frozen=True)
class Decoded:
    """The messages of one datagram and how many frames in it were rejected, by reason."""

    messages: list[Any]
    malformed: int
    signature_rejected: int


def new_codec(sysid: int, compid: int, signing_key: bytes | None) -> Any:
    """A pymavlink MAVLink 2 codec (no socket) for ``sysid``/``compid``, signing if keyed."""
    codec = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    codec.robust_parsing = True
    if signing_key is not None:
        setup_signing(codec, signing_key, SIGNING_LINK_ID)
    return codec


def decode_datagram(codec: Any, data: bytes) -> Decoded:
    """Parse one datagram with ``codec``; the parser is reset afterwards. A datagram of whole,
    unsigned, valid MAVLink 2 frames to a codec without a key is parsed without pymavlink's
    byte-by-byte parser (protocols/mavlink/fast.py: the same messages; a setpoint as its fields
    alone, every agent's every tick, which the dispatcher reads as it reads the object)."""
    if fast_receive_ok(codec):
        fast = parse(data, _LIGHT)
        if fast is not None:
            return Decoded(fast, 0, 0)
    messages: list[Any] = []
    malformed = signature = 0
    try:
        parsed = codec.parse_buffer(data) or []
    except Exception:  # pymavlink raises MAVError or struct.error on some junk
        parsed, malformed = [], 1
    for msg in parsed:
        if msg.get_type() != "BAD_DATA":
            messages.append(msg)
        elif getattr(msg, "reason", "") == _SIGNATURE_REASON:
            signature += 1
        else:
            malformed += 1
    if codec.buf_len() > 0:  # a truncated frame at the end of the datagram
        malformed += 1
    codec.buf = bytearray()
    codec.buf_index = 0
    codec.expected_length = mavlink.HEADER_LEN_V1 + 2
    return Decoded(messages, malformed, signature)


class Endpoint:
    """A bound, non-blocking UDP socket with a receive codec and a batching send queue.

    ``outbox``: a set shared by the endpoints of a simulator; an endpoint with queued frames puts
    itself in it, so a flush visits only those. ``peer_gone``: the peer's port was reported
    closed (ICMP port unreachable, with :func:`report_unreachable` on the socket): the peer is
    forgotten until it speaks again; the owner resets the flag once it has acted on it.
    """

    def __init__(
        self,
        sock: socket.socket,
        rx_codec: Any,
        peer: Address | None = None,
        outbox: set[Endpoint] | None = None,
    ) -> None:
        sock.setblocking(False)
        self.sock = sock
        self.outbox = outbox
        self.rx_codec = rx_codec
        self.peer = peer
        self.tx_datagrams = 0
        self.tx_errors = 0
        self.peer_gone = False
        self._batches: list[bytearray] = []

    def fileno(self) -> int:
        """The socket's file descriptor (for selectors)."""
        return self.sock.fileno()

    def close(self) -> None:
        """Close the socket (idempotent)."""
        self.sock.close()

    def receive(self, limit: int = 256) -> list[tuple[bytes, Address]]:
        """Up to ``limit`` pending datagrams with their source addresses."""
        out: list[tuple[bytes, Address]] = []
        recv = self.sock.recvfrom
        for _ in range(limit):
            try:
                data, addr = recv(_RECV_BYTES)
            except (BlockingIOError, InterruptedError):
                break
            except ConnectionRefusedError:  # ICMP port unreachable: whose port?
                self._unreachable()
                continue
            except OSError:
                continue
            out.append((data, addr))
        return out

    def _unreachable(self) -> None:
        """Read the error queue: if the closed port is the peer's, the peer is gone."""
        for _ in range(64):
            try:
                _, _, _, addr = self.sock.recvmsg(1, 512, socket.MSG_ERRQUEUE)
            except OSError:
                return
            if addr == self.peer:
                self.peer = None
                self.peer_gone = True

    def queue(self, packet: bytes) -> None:
        """Queue one encoded frame for the next :meth:`flush`."""
        batches = self._batches
        if not batches and self.outbox is not None:
            self.outbox.add(self)
        if batches and len(batches[-1]) + len(packet) <= MAX_DATAGRAM_BYTES:
            batches[-1] += packet
        else:
            batches.append(bytearray(packet))

    def queue_frames(self, data: bytes, ends: list[int], start: int) -> None:
        """Queue the frames ``data[start:ends[0]]``, ``data[ends[0]:ends[1]]``, ... as
        :meth:`queue` one by one would (several at once where they fit in one datagram)."""
        if not ends:
            return
        batches = self._batches
        if not batches and self.outbox is not None:
            self.outbox.add(self)
        end = ends[-1]
        if batches and len(batches[-1]) + end - start <= MAX_DATAGRAM_BYTES:
            batches[-1] += data[start:end]  # all fit in the datagram under way
        elif not batches and end - start <= MAX_DATAGRAM_BYTES:
            batches.append(bytearray(data[start:end]))
        else:
            for stop in ends:
                self.queue(data[start:stop])
                start = stop

    def flush(self) -> None:
        """Send the queued frames to the peer (dropped when there is none)."""
        batches, self._batches = self._batches, []
        if self.peer is None:
            return
        send, peer = self.sock.sendto, self.peer
        for batch in batches:
            try:
                send(batch, peer)
                self.tx_datagrams += 1
            except OSError:  # full buffer or unreachable peer: UDP may drop, so do we
                self.tx_errors += 1


class Channel:
    """Vehicle ``sysid``'s autopilot (component 1) speaking on ``endpoint``."""

    def __init__(self, endpoint: Endpoint, sysid: int, signing_key: bytes | None) -> None:
        self.endpoint = endpoint
        self.codec = new_codec(sysid, AUTOPILOT_COMPID, signing_key)
        self.tx = 0

    @property
    def active(self) -> bool:
        """Whether there is anyone to send to."""
        return self.endpoint.peer is not None

    def send(self, msg: Any) -> None:
        """Encode ``msg`` (a pymavlink message object) and queue it."""
        codec = self.codec
        self.endpoint.queue(pack(msg, codec))
        codec.seq = (codec.seq + 1) & 0xFF
        self.tx += 1

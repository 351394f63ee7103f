"""Lockstep across simulator shards: every shard steps to tick k + 1 only once every shard holds
tick k's setpoints of its own live agents.

Each shard has a UDP socket (``--shard-sync HOST:PORT``) and knows the others' (``--shard-peers``).
Once its own lockstep barrier is complete for tick k it announces ``k`` to every peer (again every
:data:`RESEND_S` while it waits: UDP may drop it) and waits until every peer has announced ``k``
or later. A peer that has spoken and then stays silent for ``timeout_s`` wall seconds is dropped
(its shard ended or died) and the others go on, as an agent that stops answering leaves a
shard's barrier.

The datagram is 12 bytes: ``b"QSS1"`` and the tick as a little-endian int64; anything else is
ignored. Pure apart from its socket; the wall clock is injected.
"""

from __future__ import annotations

import contextlib
import socket
import struct
from collections.abc import Callable, Sequence

MAGIC = b"QSS1"
_FORMAT = struct.Struct("<4sq")
RESEND_S = 0.05

Address = tuple[str, int]


def parse_address(text: str, flag: str) -> Address:
    """``HOST:PORT`` -> (host, port); ValueError naming ``flag``."""
    host, sep, port = text.strip().rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"{flag} {text!r}: expected HOST:PORT")
    return socket.gethostbyname(host), int(port)


class ShardSync:
    """This shard's side of the shards' tick agreement."""

    def __init__(
        self,
        bind: Address,
        peers: Sequence[Address],
        wall_clock: Callable[[], float],
        timeout_s: float = 10.0,
    ) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind(bind)
        except OSError as exc:
            self.sock.close()
            where = f"{bind[0]}:{bind[1]}"
            raise ValueError(f"cannot bind the shard sync port {where}: {exc}") from None
        self.sock.setblocking(False)
        self.wall, self.timeout_s = wall_clock, timeout_s
        now = wall_clock()
        #: peer -> (latest tick it announced, wall time it was last heard)
        self.peers: dict[Address, tuple[int, float]] = {p: (-1, now) for p in peers}
        self._announced = -1
        self._sent_at = -1.0

    def close(self) -> None:
        self.sock.close()

    def announce(self, tick: int) -> None:
        """Tell every peer that this shard holds tick ``tick`` (re-sent every RESEND_S)."""
        now = self.wall()
        if tick == self._announced and now - self._sent_at < RESEND_S:
            return
        data = _FORMAT.pack(MAGIC, tick)
        for peer in self.peers:
            # a peer not up yet (ICMP unreachable): the resend reaches it later
            with contextlib.suppress(OSError):
                self.sock.sendto(data, peer)
        self._announced, self._sent_at = tick, now

    def receive(self) -> None:
        """Take every pending announcement."""
        now = self.wall()
        while True:
            try:
                data, addr = self.sock.recvfrom(64)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                continue  # an ICMP error of an earlier send
            if len(data) != _FORMAT.size or addr not in self.peers:
                continue
            magic, tick = _FORMAT.unpack(data)
            if magic == MAGIC:
                latest, _ = self.peers[addr]
                self.peers[addr] = (max(latest, tick), now)

    def ready(self, tick: int) -> bool:
        """Whether every remaining peer holds ``tick``; drops peers silent for ``timeout_s`` once
        they have spoken (a shard still gathering its own agents for tick 0 is waited for)."""
        now = self.wall()
        for peer, (latest, heard) in list(self.peers.items()):
            if 0 <= latest < tick and now - heard > self.timeout_s:
                del self.peers[peer]
        return all(latest >= tick for latest, _ in self.peers.values())

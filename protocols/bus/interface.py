"""The message bus every role uses: a byte-level publish/subscribe session (:class:`Bus`).

A :class:`Bus` is one Zenoh session (``protocols.bus.zenoh_bus.ZenohBus``) or a session on the
in-memory twin (``protocols.bus.memory.MemoryBus``): publishers, pulled subscriptions, liveliness
tokens, a queryable and queries, on key expressions of ``protocols.wire.keys``.

Threading: subscription inboxes are filled by the bus (Zenoh's threads, or the publisher's thread
on the memory bus) and drained on the reader's own thread. Callbacks given to a Bus must only
store what they get (no decoding, no blocking).
"""

from __future__ import annotations

from collections.abc import Callable
from enum import StrEnum
from types import TracebackType
from typing import Protocol, Self


class Congestion(StrEnum):
    """What a publisher does when the network cannot keep up: DROP for periodic, loss-tolerant
    messages (consensus, status), BLOCK for messages that must arrive (plans, commands).

    DROP messages are *express* (each goes out at once, in a send batch of its own), except
    QUEUED: DROP, but the message waits in the link's current batch until a DROP message of
    the same session flushes it (or the link is idle). Lockstep consensus messages are QUEUED
    and the round-done marker that follows them is DROP: a process's whole pass leaves in one
    batch behind its marker, instead of one batch per message, which on a loaded machine filled
    Zenoh's send queue and dropped messages the marker then vouched for."""

    DROP = "drop"
    BLOCK = "block"
    QUEUED = "queued"


class ClosesOnExit:
    """Mixin for things with a ``close()``: ``with thing:`` closes it on the way out."""

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class Closeable(Protocol):
    """Something declared on a bus; ``close()`` undeclares it (idempotent)."""

    def close(self) -> None: ...


class Publisher(Closeable, Protocol):
    """Publishes on one key."""

    def put(self, payload: bytes) -> None: ...


class Inbox(Closeable, Protocol):
    """A pulled subscription: samples wait until drained (up to a capacity, oldest dropped)."""

    def drain(self) -> list[tuple[str, bytes]]:
        """The ``(key, payload)`` samples received since the last call, oldest first."""
        ...


class Bus(Closeable, Protocol):
    """A byte-level publish/subscribe session on key expressions (``*`` one chunk, ``**`` any)."""

    def publisher(
        self, key: str, congestion: Congestion, *, remote_only: bool = False
    ) -> Publisher:
        """Declare a publisher on the concrete key ``key``; ``remote_only``: its samples go to
        other sessions only, never to this session's own subscriptions."""
        ...

    def subscribe(self, key_expr: str, capacity: int) -> Inbox:
        """Subscribe to ``key_expr``; samples wait in the inbox (at most ``capacity``)."""
        ...

    def subscribe_callback(
        self, key_expr: str, on_sample: Callable[[str, bytes], None]
    ) -> Closeable:
        """Subscribe to ``key_expr``; ``on_sample(key, payload)`` runs on the bus's thread."""
        ...

    def declare_token(self, key: str) -> Closeable:
        """A liveliness token on ``key``: alive until closed or until this session dies."""
        ...

    def is_closed(self) -> bool:
        """Whether the session is closed (callback subscriptions then fall silent)."""
        ...

    def watch_liveliness(self, key_expr: str, on_change: Callable[[str, bool], None]) -> Closeable:
        """``on_change(key, alive)`` for every token matching ``key_expr``: first for those
        already alive (history), then on every change."""
        ...

    def serve(self, key: str, answer: Callable[[], bytes | None]) -> Closeable:
        """A queryable on ``key`` that replies with ``answer()`` (no reply when None)."""
        ...

    def query(self, key: str, on_reply: Callable[[bytes], None], timeout_s: float) -> None:
        """Ask every queryable on ``key``; ``on_reply(payload)`` for each reply, without blocking
        (replies may come after this returns, until ``timeout_s`` s)."""
        ...

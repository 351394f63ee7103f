"""The in-memory twin of the Zenoh bus: synchronous, deterministic, no sockets or threads.

A :class:`MemoryBus` is the shared medium of one process or test; each :meth:`MemoryBus.session`
is one :class:`~protocols.bus.interface.Bus`, as a Zenoh session is (several hosted agents share a
session; closing a session is what a killed process does: its tokens vanish at once). It keeps the
semantics the agents rely on:

- key expressions with ``*`` (one chunk) and ``**`` (any number of chunks);
- a ``put`` reaches every matching subscription, of every session, the sender's included, before
  it returns; pulled inboxes keep at most their capacity, dropping the oldest (as Zenoh's ring
  channel); congestion control never drops here;
- liveliness is per key: watchers hear ``alive`` when the first token of a key appears and
  ``not alive`` when the last one goes, and on declaration get every key already alive (history);
- queries are answered synchronously by every matching queryable that has something to say.
"""

from __future__ import annotations

import threading
from collections import Counter, deque
from collections.abc import Callable
from functools import lru_cache
from typing import Generic, TypeVar

from protocols.bus.interface import Closeable, ClosesOnExit, Congestion, Inbox, Publisher

T = TypeVar("T")
H = TypeVar("H", bound="_Handle")


@lru_cache(maxsize=65536)
def key_matches(key_expr: str, key: str) -> bool:
    """Whether the concrete ``key`` matches ``key_expr`` (chunks separated by ``/``; ``*``
    matches one chunk, ``**`` zero or more)."""
    return _match(tuple(key_expr.split("/")), tuple(key.split("/")))


def _match(expr: tuple[str, ...], key: tuple[str, ...]) -> bool:
    if not expr:
        return not key
    if expr[0] == "**":
        return any(_match(expr[1:], key[i:]) for i in range(len(key) + 1))
    return bool(key) and expr[0] in ("*", key[0]) and _match(expr[1:], key[1:])


class _Handle:
    """A declaration; ``close`` runs its undo once."""

    def __init__(self, undo: Callable[[], None]) -> None:
        self._undo: Callable[[], None] | None = undo

    @property
    def closed(self) -> bool:
        return self._undo is None

    def close(self) -> None:
        undo, self._undo = self._undo, None
        if undo is not None:
            undo()


class _Inbox(_Handle):
    def __init__(self, capacity: int) -> None:
        super().__init__(lambda: None)
        self.samples: deque[tuple[str, bytes]] = deque(maxlen=capacity)

    def push(self, key: str, payload: bytes) -> None:
        self.samples.append((key, payload))

    def drain(self) -> list[tuple[str, bytes]]:
        if self.closed:
            raise RuntimeError("cannot receive: the subscription is closed")
        out = list(self.samples)
        self.samples.clear()
        return out


class _Publisher(_Handle):
    def __init__(self, bus: MemoryBus, key: str, not_to: object = None) -> None:
        super().__init__(lambda: None)
        self._bus, self._key, self._not_to = bus, key, not_to

    def put(self, payload: bytes) -> None:
        if self.closed:
            raise RuntimeError(f"cannot publish: the publisher on {self._key} is closed")
        self._bus.deliver(self._key, bytes(payload), self._not_to)


class _Registry(Generic[T]):
    """Entries ``(key expression, item)`` under the bus's lock."""

    def __init__(self, lock: threading.RLock) -> None:
        self._lock = lock
        self._items: dict[int, tuple[str, T]] = {}
        self._next = 0

    def add(self, expr: str, item: T) -> Callable[[], None]:
        """Add an entry; returns the function that removes it."""
        with self._lock:
            self._next += 1
            i = self._next
            self._items[i] = (expr, item)

        def remove() -> None:
            with self._lock:
                self._items.pop(i, None)

        return remove

    def matching(self, key: str) -> list[T]:
        """Items whose expression matches the concrete ``key``, in declaration order."""
        with self._lock:
            return [item for expr, item in self._items.values() if key_matches(expr, key)]

    def matched_by(self, expr: str) -> list[T]:
        """Items whose (concrete) key matches ``expr``, in declaration order."""
        with self._lock:
            return [item for key, item in self._items.values() if key_matches(expr, key)]


class MemoryBus:
    """The shared in-memory medium. Thread-safe, but delivers on the publisher's thread."""

    def __init__(self) -> None:
        self._lock = threading.RLock()
        #: subscriptions: (the session that made it, or None; its sink)
        self._sinks: _Registry[tuple[object, Callable[[str, bytes], None]]] = _Registry(self._lock)
        self._watchers: _Registry[Callable[[str, bool], None]] = _Registry(self._lock)
        self._queryables: _Registry[Callable[[], bytes | None]] = _Registry(self._lock)
        self._tokens: Counter[str] = Counter()

    def session(self) -> MemorySession:
        """A new session on this medium (one per simulated process)."""
        return MemorySession(self)

    def deliver(self, key: str, payload: bytes, not_to: object = None) -> None:
        """Hand ``payload`` published on ``key`` to every matching subscription (but those of
        session ``not_to``: a remote-only publisher's own)."""
        for owner, sink in self._sinks.matching(key):
            if owner is None or owner is not not_to:
                sink(key, payload)

    def subscribe(
        self, key_expr: str, sink: Callable[[str, bytes], None], owner: object = None
    ) -> Callable[[], None]:
        """Register ``sink(key, payload)`` for ``key_expr`` (of session ``owner``); returns its
        undo."""
        return self._sinks.add(key_expr, (owner, sink))

    def token(self, key: str) -> Callable[[], None]:
        """Declare a liveliness token on ``key``; returns its undo."""
        with self._lock:
            self._tokens[key] += 1
            first = self._tokens[key] == 1
        if first:
            self._notify(key, True)

        def undo() -> None:
            with self._lock:
                self._tokens[key] -= 1
                last = self._tokens[key] == 0
                if last:
                    del self._tokens[key]
            if last:
                self._notify(key, False)

        return undo

    def _notify(self, key: str, alive: bool) -> None:
        for on_change in self._watchers.matching(key):
            on_change(key, alive)

    def watch(self, key_expr: str, on_change: Callable[[str, bool], None]) -> Callable[[], None]:
        """Register a liveliness watcher (told about live keys first); returns its undo."""
        with self._lock:
            undo = self._watchers.add(key_expr, on_change)
            alive = sorted(k for k in self._tokens if key_matches(key_expr, k))
        for key in alive:
            on_change(key, True)
        return undo

    def serve(self, key: str, answer: Callable[[], bytes | None]) -> Callable[[], None]:
        """Register a queryable on ``key``; returns its undo."""
        return self._queryables.add(key, answer)

    def query(self, key_expr: str, on_reply: Callable[[bytes], None]) -> None:
        """Ask every matching queryable now; ``on_reply`` for each answer that is not None."""
        for answer in self._queryables.matched_by(key_expr):
            if (payload := answer()) is not None:
                on_reply(payload)


class MemorySession(ClosesOnExit):
    """One session on a :class:`MemoryBus`: a :class:`~protocols.bus.interface.Bus`. Closing it
    undeclares everything declared through it (tokens vanish at once)."""

    def __init__(self, bus: MemoryBus) -> None:
        self._bus = bus
        self._handles: list[_Handle] = []
        self._closed = False

    def _keep(self, handle: H) -> H:
        if self._closed:
            handle.close()
            raise RuntimeError("the memory session is closed")
        if len(self._handles) > 64:  # forget handles closed by their owner (cell changes)
            self._handles = [h for h in self._handles if not h.closed]
        self._handles.append(handle)
        return handle

    def publisher(
        self, key: str, congestion: Congestion, *, remote_only: bool = False
    ) -> Publisher:
        """A publisher on ``key`` (congestion control has no effect in memory); ``remote_only``:
        not delivered to this session's subscriptions."""
        return self._keep(_Publisher(self._bus, key, self if remote_only else None))

    def subscribe(self, key_expr: str, capacity: int) -> Inbox:
        """A pulled subscription keeping at most ``capacity`` samples (oldest dropped)."""
        inbox = self._keep(_Inbox(capacity))
        inbox._undo = self._bus.subscribe(key_expr, inbox.push, self)
        return inbox

    def subscribe_callback(
        self, key_expr: str, on_sample: Callable[[str, bytes], None]
    ) -> Closeable:
        """``on_sample(key, payload)`` for each sample, on the publisher's thread."""
        return self._keep(_Handle(self._bus.subscribe(key_expr, on_sample, self)))

    def is_closed(self) -> bool:
        """Whether this session is closed."""
        return self._closed

    def declare_token(self, key: str) -> Closeable:
        """A liveliness token on ``key``."""
        return self._keep(_Handle(self._bus.token(key)))

    def watch_liveliness(self, key_expr: str, on_change: Callable[[str, bool], None]) -> Closeable:
        """``on_change(key, alive)`` for the tokens matching ``key_expr`` (with history)."""
        return self._keep(_Handle(self._bus.watch(key_expr, on_change)))

    def serve(self, key: str, answer: Callable[[], bytes | None]) -> Closeable:
        """A queryable on ``key`` answering ``answer()``."""
        return self._keep(_Handle(self._bus.serve(key, answer)))

    def query(self, key: str, on_reply: Callable[[bytes], None], timeout_s: float) -> None:
        """Ask the queryables on ``key``; replies arrive before this returns."""
        if self._closed:
            raise RuntimeError("the memory session is closed")
        self._bus.query(key, on_reply)

    def close(self) -> None:
        """Undeclare everything of this session, newest first. Idempotent."""
        self._closed = True
        while self._handles:
            self._handles.pop().close()

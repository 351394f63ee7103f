"""The Zenoh adapter: a :class:`~protocols.bus.interface.Bus` on one Zenoh 1.x session.

Embedded default (no router, nothing to install): peer mode, multicast scouting off, listening on
``tcp/127.0.0.1:<port>`` and connecting to the endpoints given; peers then find each other by
gossip over those links and connect directly. Multi-host: ``client`` mode connected to a router
(a ``zenohd`` or a Python session in router mode), or peers connected to each other.

Consensus publishers use congestion control DROP (periodic; the estimator tolerates loss),
express in realtime (not batched: measured on loopback, batching added about 1 ms at 50 agents)
and QUEUED in lockstep (a process's pass leaves in one send batch behind its express round-done
marker: drone_agent/transport.Congestion); statuses are QUEUED (cheaper; nobody waits on them);
plans and commands use BLOCK. Consensus subscriptions are pulled ring channels
(bounded, oldest dropped): no Python runs on Zenoh's threads for them; the agent drains and
decodes them on its own thread. Liveliness, plan and queryable callbacks only store what they
get.

The session's lease (``transport/link/tx/lease``) is lowered so that a frozen peer's liveliness
tokens vanish within about ``lease_ms`` (a killed one's vanish at once, when its sockets close).

Never fork a process after it opened a session (the child hangs): start agents with
``subprocess`` or multiprocessing's spawn.
"""

from __future__ import annotations

import dataclasses
import json
import socket
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh

from protocols.bus.interface import Closeable, ClosesOnExit, Congestion, Inbox, Publisher
from protocols.secrets.swarm_secrets import RoleSecrets

_CONGESTION = {
    Congestion.DROP: zenoh.CongestionControl.DROP,
    Congestion.BLOCK: zenoh.CongestionControl.BLOCK,
    Congestion.QUEUED: zenoh.CongestionControl.DROP,
}
MODES = ("peer", "client", "router")


@dataclass(frozen=True)
class ZenohSettings:
    """How to open the session.

    ``mode``: ``peer``, ``client`` or ``router`` (``swarm router``). ``listen`` / ``connect``:
    endpoints such as ``tcp/127.0.0.1:7447`` (a client listens on nothing). ``lease_ms``: how
    long (ms) peers wait for this session's keep-alives before declaring it dead;
    ``keep_alive``: keep-alives per lease. ``multicast_scouting``: find peers by UDP multicast
    (off: it finds strangers on shared machines). ``connect_timeout_ms``: how long a client
    waits for its router to answer (long-running processes started on several hosts in any
    order). ``secrets``: the role's credentials (``swarm keys init``): TLS with a client
    certificate (mTLS) and user/password on every link, and (router) the swarm's access control;
    every endpoint must then be ``tls/``.
    """

    mode: str = "peer"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:0",)
    connect: tuple[str, ...] = ()
    lease_ms: int = 1000
    keep_alive: int = 4
    multicast_scouting: bool = False
    secrets: RoleSecrets | None = None
    #: a client waits up to this long (ms) for its router (0: one try, fail at once)
    connect_timeout_ms: int = 0
    #: how long (µs) a DROP publisher waits for room in a full send queue before it drops the
    #: message (None: Zenoh's 1 ms); lockstep agents wait longer, since a dropped consensus
    #: message changes the flight (a burst of declarations when a drone changes cell filled
    #: the queue on a loaded machine)
    drop_wait_us: int | None = None
    #: batches the send queue of data-priority messages (consensus, markers, status) holds per
    #: link (None: Zenoh's 2); an express message takes a batch of its own, so a process that
    #: publishes many agents' messages at once fills Zenoh's two at once, and DROP then waits
    #: (``drop_wait_us``) and drops; lockstep agents use a deeper queue
    tx_queue_batches: int | None = None

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"zenoh mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        if self.mode == "client" and not self.connect:
            raise ValueError("zenoh client mode needs at least one --zenoh-connect endpoint")
        for endpoint in (*self.listen, *self.connect):
            if not isinstance(endpoint, str) or "/" not in endpoint:
                raise ValueError(f"zenoh endpoint must look like tcp/HOST:PORT, got {endpoint!r}")
        if self.tx_queue_batches is not None and not 1 <= self.tx_queue_batches <= 64:
            raise ValueError(f"tx_queue_batches must be 1..64, got {self.tx_queue_batches}")
        if self.secrets is not None:
            plain = [e for e in (*self.listen, *self.connect) if not e.startswith("tls/")]
            if plain:
                raise ValueError(f"a secured session speaks TLS only: {plain[0]} is not tls/")
        if self.lease_ms < 100 or not 1 <= self.keep_alive <= self.lease_ms // 10:
            raise ValueError(
                f"lease_ms must be >= 100 and keep_alive 1..lease_ms/10, got "
                f"{self.lease_ms} and {self.keep_alive}"
            )

    def config(self) -> zenoh.Config:
        """The Zenoh configuration (JSON5 values) of these settings."""
        conf = zenoh.Config()
        listen = list(self.listen) if self.mode != "client" else []
        for key, value in (
            ("mode", self.mode),
            ("scouting/multicast/enabled", self.multicast_scouting),
            ("listen/endpoints", listen),
            ("connect/endpoints", list(self.connect)),
            ("transport/link/tx/lease", self.lease_ms),
            ("transport/link/tx/keep_alive", self.keep_alive),
            # a lost connect endpoint (a restarted ground station) is retried within a second
            (
                "connect/retry",
                {"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 2},
            ),
        ):
            conf.insert_json5(key, json.dumps(value))
        if self.connect_timeout_ms > 0:
            conf.insert_json5("connect/timeout_ms", json.dumps(self.connect_timeout_ms))
        if self.drop_wait_us is not None:
            key = "transport/link/tx/queue/congestion_control/drop/wait_before_drop"
            conf.insert_json5(key, json.dumps(self.drop_wait_us))
        if self.tx_queue_batches is not None:
            conf.insert_json5("transport/link/tx/queue/size/data", str(self.tx_queue_batches))
        if self.secrets is not None:
            from protocols.bus.zenoh_config import secure

            secure(conf, self.secrets, self.mode)
        return conf

    @property
    def secured(self) -> bool:
        """Whether the session uses TLS and credentials."""
        return self.secrets is not None


def open_client(endpoint: str, secrets: RoleSecrets | None = None) -> ZenohBus:
    """A short-lived client session on ``endpoint`` (for tools: operator commands, drills), with
    the credentials of ``secrets`` if given (a ``tcp/`` endpoint then becomes ``tls/``).

    ValueError for an endpoint that is not ``tcp/HOST:PORT``; ConnectionError if nothing answers
    or the router refuses the credential (the message says which).
    """
    from protocols.bus.zenoh_config import open_error, secured_endpoint

    if secrets is not None:
        endpoint = secured_endpoint(endpoint)
    settings = ZenohSettings(mode="client", listen=(), connect=(endpoint,), secrets=secrets)
    try:
        return ZenohBus.open(settings)
    except zenoh.ZError:
        raise ConnectionError(open_error(endpoint, secrets)) from None


def tcp_listen_free(port: int, host: str = "127.0.0.1") -> bool:
    """Whether a Zenoh session could listen on TCP ``host:port`` now: nobody listens there.

    Bound with SO_REUSEADDR as Zenoh binds its listeners, so the TIME_WAIT connections a swarm
    that just ended leaves on its port (for a minute) do not count as busy."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def free_loopback_endpoint() -> str:
    """``tcp/127.0.0.1:<port>`` with a port that was free a moment ago (for tests and tools)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


class _Declared:
    """Anything Zenoh declared; ``close`` undeclares it once."""

    def __init__(self, entity: Any) -> None:
        self._entity: Any = entity

    def close(self) -> None:
        entity, self._entity = self._entity, None
        if entity is not None:
            entity.undeclare()


class _Publisher(_Declared):
    def __init__(self, publisher: zenoh.Publisher) -> None:
        super().__init__(publisher)
        self._put = publisher.put

    def put(self, payload: bytes) -> None:
        try:
            self._put(payload)
        except zenoh.ZError as exc:
            raise RuntimeError(f"cannot publish: {exc}") from exc


class _Inbox(_Declared):
    def __init__(self, subscriber: zenoh.Subscriber[zenoh.Handler[zenoh.Sample]]) -> None:
        super().__init__(subscriber)
        self._recv = subscriber.try_recv

    def drain(self) -> list[tuple[str, bytes]]:
        out = []
        recv = self._recv
        try:
            while (sample := recv()) is not None:
                out.append((str(sample.key_expr), sample.payload.to_bytes()))
        except zenoh.ZError as exc:  # the subscriber or its session is gone
            raise RuntimeError(f"cannot receive: {exc}") from exc
        return out


class ZenohBus(ClosesOnExit):
    """One Zenoh session as a Bus. Open with :meth:`open` (or wrap an open session); close it
    after the transports that use it (closing undeclares everything of the session)."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session

    @classmethod
    def open(cls, settings: ZenohSettings | None = None) -> ZenohBus:
        """Open a session with ``settings`` (default: the embedded loopback peer). A client
        waits for its router (``connect_timeout_ms``) only while nothing answers there: a router
        that is up and refuses the session (a bad credential) fails it at once."""
        settings = settings or ZenohSettings()
        if settings.mode == "client" and settings.connect_timeout_ms > 0:
            from protocols.bus.zenoh_config import answers

            if answers(settings.connect[0]):
                settings = dataclasses.replace(settings, connect_timeout_ms=0)
        return cls(zenoh.open(settings.config()))

    def publisher(
        self, key: str, congestion: Congestion, *, remote_only: bool = False
    ) -> Publisher:
        """A declared publisher on ``key`` with the given congestion control; DROP publishers
        (periodic, latency-bound) are also *express*: sent at once, not batched (QUEUED is DROP
        without express: see Congestion). ``remote_only``: not delivered to this session's own
        subscribers (Zenoh's ``allowed_destination=Locality.REMOTE``)."""
        cc = _CONGESTION[congestion]
        express = congestion is Congestion.DROP
        where = zenoh.Locality.REMOTE if remote_only else zenoh.Locality.ANY
        return _Publisher(
            self.session.declare_publisher(
                key, congestion_control=cc, express=express, allowed_destination=where
            )
        )

    def subscribe(self, key_expr: str, capacity: int) -> Inbox:
        """A subscriber whose samples wait in a ring channel of ``capacity`` until drained."""
        handler: zenoh.handlers.RingChannel[zenoh.Sample] = zenoh.handlers.RingChannel(capacity)
        return _Inbox(self.session.declare_subscriber(key_expr, handler))

    def subscribe_callback(
        self, key_expr: str, on_sample: Callable[[str, bytes], None]
    ) -> Closeable:
        """``on_sample(key, payload)`` on a Zenoh callback thread for every sample."""

        def callback(sample: zenoh.Sample) -> None:
            on_sample(str(sample.key_expr), sample.payload.to_bytes())

        return _Declared(self.session.declare_subscriber(key_expr, callback))

    def is_closed(self) -> bool:
        """Whether the session is closed."""
        return bool(self.session.is_closed())

    def declare_token(self, key: str) -> Closeable:
        """A liveliness token on ``key``, alive as long as it and the session are."""
        return _Declared(self.session.liveliness().declare_token(key))

    def watch_liveliness(self, key_expr: str, on_change: Callable[[str, bool], None]) -> Closeable:
        """``on_change(key, alive)`` for every token matching ``key_expr`` (with history)."""

        def callback(sample: zenoh.Sample) -> None:
            on_change(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)

        liveliness = self.session.liveliness()
        return _Declared(liveliness.declare_subscriber(key_expr, callback, history=True))

    def serve(self, key: str, answer: Callable[[], bytes | None]) -> Closeable:
        """A queryable on ``key`` replying ``answer()`` on that same key (no reply when None)."""

        def callback(query: zenoh.Query) -> None:
            payload = answer()
            if payload is not None:
                query.reply(key, payload)

        return _Declared(self.session.declare_queryable(key, callback))

    def query(self, key: str, on_reply: Callable[[bytes], None], timeout_s: float) -> None:
        """Ask every queryable on ``key`` (all replies, no consolidation); returns at once."""

        def callback(reply: zenoh.Reply) -> None:
            if reply.ok is not None:
                on_reply(reply.ok.payload.to_bytes())

        self.session.get(
            key,
            callback,
            target=zenoh.QueryTarget.ALL,
            consolidation=zenoh.ConsolidationMode.NONE,
            timeout=timeout_s,
        )

    def close(self) -> None:
        """Close the session: every declaration of it goes (tokens vanish for everyone)."""
        if not self.session.is_closed():
            self.session.close()

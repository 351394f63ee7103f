"""The operator's link to a swarm: one Zenoh session, requests to the ground station's command
queryable (``swarm/<sid>/command``) and drills published to the agents (``swarm/<sid>/fault``).
The ``swarm`` commands and :class:`gcs.api.Swarm` send through it alike."""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING

from gcs.api.errors import NoGroundStation, UsageError

if TYPE_CHECKING:
    from gcs.station.commands import Reply, Request
    from protocols.bus.zenoh_bus import ZenohBus
    from protocols.faults import FaultCommand
    from protocols.secrets.swarm_secrets import RoleSecrets

#: How long the ground station gets to answer a request (wall s).
ANSWER_TIMEOUT_S = 2.0
#: Time given to a new publisher to reach the agents before publishing, and to flush after (s).
CONNECT_WAIT_S = 0.5
FLUSH_WAIT_S = 0.2


def role_secrets(
    secrets: RoleSecrets | str | Path | None, swarm_id: str, role: str = "operator"
) -> RoleSecrets | None:
    """``secrets`` as a role's credentials: a folder of ``swarm keys init`` (its ``role``), or
    credentials already loaded; UsageError (one line) when they do not fit ``swarm_id``."""
    if secrets is None or not isinstance(secrets, str | Path):
        return secrets
    from protocols.bus.zenoh_config import role_secrets as load

    try:
        return load(secrets, role, swarm_id)
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def refusal(secrets: RoleSecrets | None, kind: str, suffix: str, what: str) -> str | None:
    """Why ``secrets``' role may not send ``kind`` on ``swarm/<sid>/<suffix>`` (None: it may, or
    the network is open); checked before anything is sent, as the router would drop it."""
    from protocols.secrets.swarm_secrets import may

    if secrets is None or may(secrets.role, kind, suffix):
        return None
    return (
        f"refused: the {secrets.role!r} credential has no right to {what} "
        f"({kind} on swarm/{secrets.swarm_id}/{suffix}); only the operator credential has"
    )


class Link:
    """A client session on ``endpoint`` to swarm ``swarm_id`` (or a session of this process that
    the swarm meets at, ``bus``). NoGroundStation if nothing answers at the endpoint."""

    def __init__(
        self,
        endpoint: str,
        swarm_id: str = "swarm",
        secrets: RoleSecrets | None = None,
        bus: ZenohBus | None = None,
    ) -> None:
        from protocols.bus.zenoh_bus import open_client
        from protocols.wire.keys import SwarmKeys

        self.endpoint, self.swarm_id, self.secrets = endpoint, swarm_id, secrets
        try:
            self.keys = SwarmKeys(swarm_id, 1.0)
            self.bus = bus if bus is not None else open_client(endpoint, secrets)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        except ConnectionError as exc:
            raise NoGroundStation(f"no ground station: {exc}") from None

    def close(self) -> None:
        self.bus.close()

    def ask(self, request: Request, timeout_s: float = ANSWER_TIMEOUT_S) -> tuple[Reply, float]:
        """Send ``request`` to the ground station; its reply and the seconds from sending it to
        the reply's arrival. NoGroundStation if none answers within ``timeout_s``."""
        from gcs.station.commands import encode_request

        return self.ask_payload(encode_request(request), timeout_s)

    def ask_payload(
        self, payload: bytes, timeout_s: float = ANSWER_TIMEOUT_S
    ) -> tuple[Reply, float]:
        """As :meth:`ask`, for a request already encoded (or a malformed one, to test the
        ground station)."""
        from gcs.station.commands import CommandError, decode_reply

        denied = refusal(self.secrets, "query", "command", "send operator commands and drills")
        if denied is not None:
            raise UsageError(denied)
        sent = time.monotonic()
        replies = self.bus.session.get(self.keys.command, payload=payload, timeout=timeout_s)
        for reply in replies:
            if reply.ok is not None:
                elapsed = time.monotonic() - sent
                try:
                    return decode_reply(reply.ok.payload.to_bytes()), elapsed
                except CommandError as exc:
                    raise NoGroundStation(str(exc)) from None
        hint = "" if self.secrets is None else (
            f" (or the router refused the {self.secrets.role!r} credential)"
        )  # fmt: skip
        raise NoGroundStation(
            f"no ground station of swarm {self.swarm_id!r} answered within {timeout_s:g} s at "
            f"{self.endpoint}" + hint
        )

    def publish_fault(self, command: FaultCommand) -> None:
        """Publish a drill once, reliably, to every agent on the swarm's fault key."""
        from protocols.bus.interface import Congestion
        from protocols.wire.fault import encode_fault

        try:
            payload = encode_fault(command, self.swarm_id)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        denied = refusal(self.secrets, "put", "fault", "send drills")
        if denied is not None:
            raise UsageError(denied)
        publisher = self.bus.publisher(self.keys.fault, Congestion.BLOCK)
        try:
            time.sleep(CONNECT_WAIT_S)  # let the router learn the subscribers before the put
            publisher.put(payload)
            time.sleep(FLUSH_WAIT_S)
        finally:
            publisher.close()

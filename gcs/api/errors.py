"""The exceptions of :mod:`gcs.api`. ``str(exc)`` is the one line ``swarm`` prints for the same
mistake or refusal."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from gcs.station.commands import Reply


class SwarmError(Exception):
    """Anything :mod:`gcs.api` raises for a swarm that cannot do what was asked."""


class UsageError(SwarmError, ValueError):
    """A bad argument, named as the API and the ``swarm`` flag spell it."""


class NoGroundStation(SwarmError, ConnectionError):
    """Nobody answered at the endpoint, or no ground station of that swarm within the timeout."""


class CommandRefused(SwarmError):
    """The ground station refused the command; ``reason`` says why (as ``swarm`` prints it),
    ``reply`` is its whole answer and ``elapsed_s`` how long it took to come (s)."""

    def __init__(self, name: str, reply: Reply, elapsed_s: float) -> None:
        super().__init__(reply.reason)
        self.name = name
        self.reason = reply.reason
        self.reply = reply
        self.elapsed_s = elapsed_s


class StartError(SwarmError):
    """``swarm up`` could not bring the swarm up; the message is its last line."""


class WaitTimeout(SwarmError, TimeoutError):
    """A command's change did not arrive within the time given (wall seconds)."""


class Failsafe(SwarmError):
    """A vehicle failed safe or a drone was lost while waiting for a command to arrive."""


class Superseded(SwarmError):
    """Another plan replaced the command's plan before its change arrived."""

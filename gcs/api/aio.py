"""The asyncio form of :class:`gcs.api.Swarm`: the same methods, awaited. Each call runs the
synchronous implementation in a worker thread (:func:`asyncio.to_thread`), so an event loop (a
notebook's) keeps running while the swarm is asked or followed; there is one implementation."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

from gcs.api.swarm import WAIT_TIMEOUT_S, Command, Drill, Swarm

if TYPE_CHECKING:
    from gcs.api.report import FlightReport
    from gcs.api.state import Descriptors, Status
    from gcs.station.commands import Reply
    from protocols.secrets.swarm_secrets import RoleSecrets


class AsyncCommand:
    """An accepted command (:class:`gcs.api.Command`) whose ``wait`` is awaited."""

    def __init__(self, command: Command) -> None:
        self.command = command
        self.name, self.reply, self.elapsed_s = command.name, command.reply, command.elapsed_s

    @property
    def reason(self) -> str:
        return self.command.reason

    @property
    def seq(self) -> int:
        return self.command.seq

    async def wait(self, timeout_s: float = WAIT_TIMEOUT_S, poll_s: float = 0.1) -> Status:
        """As :meth:`gcs.api.Command.wait`."""
        return await asyncio.to_thread(self.command.wait, timeout_s, poll_s)


class AsyncSwarm:
    """``async with await AsyncSwarm.start(drones=4) as swarm: await (await
    swarm.takeoff(3)).wait()``; every method as :class:`gcs.api.Swarm`'s."""

    def __init__(self, swarm: Swarm) -> None:
        self.swarm = swarm

    @classmethod
    async def start(cls, scenario: str | Path | None = None, **kwargs: Any) -> AsyncSwarm:
        """As :meth:`gcs.api.Swarm.start`."""
        return cls(await asyncio.to_thread(Swarm.start, scenario, **kwargs))

    @classmethod
    async def connect(
        cls,
        endpoint: str = "tcp/127.0.0.1:7447",
        swarm_id: str = "swarm",
        secrets: RoleSecrets | str | Path | None = None,
        role: str = "operator",
    ) -> AsyncSwarm:
        """As :meth:`gcs.api.Swarm.connect`."""
        return cls(await asyncio.to_thread(Swarm.connect, endpoint, swarm_id, secrets, role))

    async def __aenter__(self) -> AsyncSwarm:
        return self

    async def __aexit__(
        self, _t: type[BaseException] | None, _e: BaseException | None, _tb: TracebackType | None
    ) -> None:
        await self.close()

    async def close(self) -> None:
        await asyncio.to_thread(self.swarm.close)

    @property
    def report(self) -> FlightReport | None:
        return self.swarm.report

    async def command(self, name: str, **kwargs: Any) -> AsyncCommand:
        return AsyncCommand(await asyncio.to_thread(self.swarm.command, name, **kwargs))

    async def takeoff(self, altitude_m: float, duration_s: float | None = None) -> AsyncCommand:
        return await self.command("takeoff", altitude_m=altitude_m, duration_s=duration_s)

    async def formation(self, centre: Any = None, **kwargs: Any) -> AsyncCommand:
        return await self.command("formation", centre=centre, **kwargs)

    async def move(self, north_m: float = 0.0, east_m: float = 0.0, up_m: float = 0.0,
                   duration_s: float | None = None) -> AsyncCommand:  # fmt: skip
        return await self.command(
            "move", north_m=north_m, east_m=east_m, up_m=up_m, duration_s=duration_s
        )

    async def rotate(self, delta_deg: float, duration_s: float | None = None) -> AsyncCommand:
        return await self.command("rotate", delta_deg=delta_deg, duration_s=duration_s)

    async def scale(self, factor: float, duration_s: float | None = None) -> AsyncCommand:
        return await self.command("scale", factor=factor, duration_s=duration_s)

    async def hold(self) -> AsyncCommand:
        return await self.command("hold")

    async def land(self) -> AsyncCommand:
        return await self.command("land")

    async def shutdown(self) -> Reply:
        return await asyncio.to_thread(self.swarm.shutdown)

    async def drill(self, name: str, **kwargs: Any) -> Drill:
        return await asyncio.to_thread(self.swarm.drill, name, **kwargs)

    async def status(self) -> Status:
        return await asyncio.to_thread(self.swarm.status)

    async def descriptors(self) -> Descriptors:
        return await asyncio.to_thread(self.swarm.descriptors)

    async def wait_ready(self, timeout_s: float = WAIT_TIMEOUT_S) -> Status:
        return await asyncio.to_thread(self.swarm.wait_ready, timeout_s)

    async def subscribe(
        self, period_s: float = 0.2, timeout_s: float | None = None
    ) -> AsyncIterator[Status]:
        """As :meth:`gcs.api.Swarm.subscribe`, an async iterator."""
        items = self.swarm.subscribe(period_s, timeout_s)
        while True:
            item: Status | None = await asyncio.to_thread(next, items, None)
            if item is None:
                return
            yield item

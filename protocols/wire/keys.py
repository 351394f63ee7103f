"""Zenoh key expressions of one swarm: every key lives under ``swarm/<swarm-id>/``.

==============================================  ===============================================
``swarm/<sid>/consensus/<cx>/<cy>/<cz>/<drone>``  consensus message of ``drone``, published from
                                                  spatial cell ``(cx, cy, cz)`` (loss-tolerant)
``swarm/<sid>/alive/<drone>``                     liveliness token of ``drone``'s agent
``swarm/<sid>/status/<drone>``                    agent status for the ground station
``swarm/<sid>/plan``                              the descriptor trajectory (publication and
                                                  queryable, so late joiners fetch it)
``swarm/<sid>/fault``                             link-fault commands for drills
``swarm/<sid>/command``                           the ground station's operator-command queryable
==============================================  ===============================================

Cells: ``cell = floor(position_ned_m / cell_size_m)`` per axis. With ``cell_size_m`` at least the
communication range, every drone within range of a drone is in one of the 27 cells of the 3x3x3
block around that drone's own cell, so an agent subscribes to those 27 keys (and re-subscribes
when it changes cell) and never has to receive the whole swarm.

A drone keeps its cell until it is ``hysteresis_m`` past the cell's border (:func:`track_cell`);
the cell size must then be at least the range plus twice the hysteresis.

Swarm ids are 1-32 characters from ``A-Z a-z 0-9 _ -``, starting with a letter or digit: safe as
a key chunk (no ``/ * $ # ?``) and on the wire. Pure: no Zenoh import.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass

ROOT = "swarm"
MAX_SWARM_ID_LEN = 32
MAX_DRONE_ID = 0xFFFF  # drone ids travel as uint16 on the wire
#: Drones in the largest swarm (MAVLink numbers its vehicles 1..250:
#: protocols.mavlink.conventions.MAX_VEHICLES, equal by test): what the payload limits allow for.
MAX_SWARM = 250
_SWARM_ID_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,31}")

Cell = tuple[int, int, int]
"""A spatial cell index (cx, cy, cz) along NED x, y, z."""


def validate_swarm_id(swarm_id: str) -> str:
    """Return ``swarm_id`` if it is a valid swarm id; ValueError saying what is wrong otherwise."""
    if not isinstance(swarm_id, str):
        raise ValueError(f"swarm id must be a string, got {type(swarm_id).__name__}")
    if not _SWARM_ID_RE.fullmatch(swarm_id):
        raise ValueError(
            f"swarm id {swarm_id!r} is not valid: use 1-{MAX_SWARM_ID_LEN} characters from "
            "A-Z a-z 0-9 _ -, starting with a letter or digit"
        )
    return swarm_id


def validate_drone_id(drone: int) -> int:
    """Return ``drone`` if it is a drone index 0..65535; ValueError otherwise."""
    if isinstance(drone, bool) or not isinstance(drone, int) or not 0 <= drone <= MAX_DRONE_ID:
        raise ValueError(f"drone id must be an integer 0..{MAX_DRONE_ID}, got {drone!r}")
    return drone


def cell_of(position_ned_m: Sequence[float], cell_size_m: float) -> Cell:
    """The cell (cx, cy, cz) holding a position (3,) NED in metres: ``floor(p / cell_size_m)``."""
    if len(position_ned_m) != 3:
        raise ValueError(f"position must have 3 components, got {len(position_ned_m)}")
    if not all(math.isfinite(float(p)) for p in position_ned_m):
        raise ValueError(f"position must be finite, got {list(position_ned_m)}")
    x, y, z = (math.floor(float(p) / cell_size_m) for p in position_ned_m)
    return (x, y, z)


def track_cell(
    current: Cell | None, position_ned_m: Sequence[float], cell_size_m: float, hysteresis_m: float
) -> Cell:
    """The cell to publish from: ``current`` while the position stays within ``hysteresis_m``
    (m) of it on every axis, else the cell of the position. Keeps a drone sitting on a boundary
    (e.g. on the ground at z = 0) from re-subscribing every tick. The published cell may then lag
    by up to ``hysteresis_m``; the 27-cell block still covers the range as long as
    ``cell_size_m >= comm_range_m + 2 * hysteresis_m`` (:func:`cell_size_for`)."""
    cell = cell_of(position_ned_m, cell_size_m)
    if current is None or cell == current:
        return cell
    lo = [c * cell_size_m - hysteresis_m for c in current]
    hi = [(c + 1) * cell_size_m + hysteresis_m for c in current]
    inside = all(a <= float(p) < b for a, p, b in zip(lo, position_ned_m, hi, strict=True))
    return current if inside else cell


def cell_size_for(comm_range_m: float, hysteresis_m: float = 0.0) -> float:
    """The smallest cell size (m) whose 27-cell blocks cover every drone within ``comm_range_m``
    (m), with cells tracked with ``hysteresis_m`` (m)."""
    return comm_range_m + 2.0 * hysteresis_m


def neighbourhood(cell: Cell) -> tuple[Cell, ...]:
    """The 27 cells of the 3x3x3 block centred on ``cell`` (itself included), sorted."""
    cx, cy, cz = cell
    return tuple(
        (cx + dx, cy + dy, cz + dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)
    )


@dataclass(frozen=True)
class SwarmKeys:
    """The keys of swarm ``swarm_id`` with spatial cells of ``cell_size_m`` metres.

    ``cell_size_m`` must be at least the communication range (see :meth:`for_range`) for the
    27-cell neighbourhood to cover every drone in range.
    """

    swarm_id: str
    cell_size_m: float

    def __post_init__(self) -> None:
        validate_swarm_id(self.swarm_id)
        if not (math.isfinite(self.cell_size_m) and self.cell_size_m > 0):
            raise ValueError(
                f"cell size must be a positive number of metres, got {self.cell_size_m}"
            )

    @classmethod
    def for_range(cls, swarm_id: str, comm_range_m: float, hysteresis_m: float = 0.0) -> SwarmKeys:
        """Keys whose cells are as small as :func:`cell_size_for` allows."""
        return cls(swarm_id, cell_size_for(comm_range_m, hysteresis_m))

    @property
    def prefix(self) -> str:
        """``swarm/<sid>``."""
        return f"{ROOT}/{self.swarm_id}"

    def cell(self, position_ned_m: Sequence[float]) -> Cell:
        """The cell of a position (3,) NED, m."""
        return cell_of(position_ned_m, self.cell_size_m)

    def consensus(self, cell: Cell, drone: int) -> str:
        """Key of ``drone``'s consensus message published from ``cell``."""
        cx, cy, cz = cell
        return f"{self.prefix}/consensus/{cx}/{cy}/{cz}/{validate_drone_id(drone)}"

    def consensus_cell(self, cell: Cell) -> str:
        """Key expression matching every drone's consensus message from one cell."""
        cx, cy, cz = cell
        return f"{self.prefix}/consensus/{cx}/{cy}/{cz}/*"

    def consensus_subscriptions(self, cell: Cell) -> tuple[str, ...]:
        """The 27 key expressions an agent in ``cell`` subscribes to (one per neighbour cell)."""
        return tuple(self.consensus_cell(c) for c in neighbourhood(cell))

    def consensus_all(self) -> str:
        """Every consensus message of the swarm (for tools and garbage tests, not for agents)."""
        return f"{self.prefix}/consensus/**"

    def alive(self, drone: int) -> str:
        """Liveliness token key of ``drone``'s agent."""
        return f"{self.prefix}/alive/{validate_drone_id(drone)}"

    def alive_all(self) -> str:
        """Key expression matching every liveliness token of the swarm."""
        return f"{self.prefix}/alive/*"

    def round_done(self, drone: int) -> str:
        """Key of the lockstep round-done markers of the agent process whose first hosted drone
        is ``drone`` (protocols/wire/round_done.py)."""
        return f"{self.prefix}/round/{validate_drone_id(drone)}"

    def round_done_all(self) -> str:
        """Key expression matching every agent process's round-done markers."""
        return f"{self.prefix}/round/*"

    def status(self, drone: int) -> str:
        """Status key of ``drone``'s agent."""
        return f"{self.prefix}/status/{validate_drone_id(drone)}"

    def status_all(self) -> str:
        """Key expression matching every agent's status."""
        return f"{self.prefix}/status/*"

    @property
    def plan(self) -> str:
        """The plan key: publications and the queryable of the current plan."""
        return f"{self.prefix}/plan"

    @property
    def fault(self) -> str:
        """Link-fault commands for drills."""
        return f"{self.prefix}/fault"

    @property
    def command(self) -> str:
        """The ground station's queryable of operator commands."""
        return f"{self.prefix}/command"

    def cell_of_key(self, key: str) -> Cell | None:
        """The cell a consensus key of this swarm was published from (whatever its drone id:
        :meth:`drone_of`); None if ``key`` is not one."""
        parts = key.split("/")
        if len(parts) != 7 or parts[:3] != [ROOT, self.swarm_id, "consensus"]:
            return None
        try:
            return (int(parts[3]), int(parts[4]), int(parts[5]))
        except ValueError:
            return None

    def drone_of(self, key: str) -> int | None:
        """The drone id that ends a consensus, alive or status key of this swarm; None if ``key``
        is not one (foreign swarm, other kind, malformed id)."""
        parts = key.split("/")
        if len(parts) < 4 or parts[0] != ROOT or parts[1] != self.swarm_id:
            return None
        shape = {"consensus": 7, "alive": 4, "status": 4}.get(parts[2])
        if shape != len(parts):
            return None
        last = parts[-1]
        if not (last.isascii() and last.isdigit()) or len(last) > 5:
            return None
        if len(last) > 1 and last[0] == "0":  # no leading zeros: one spelling per drone
            return None
        drone = int(last)
        return drone if drone <= MAX_DRONE_ID else None

"""The agent status message (Kind.STATUS): what each agent tells the ground station.

Status payloads have their own schema version, STATUS_VERSION (3), in the common header. Body
after the common header (``protocols.wire.format``), little-endian::

    u16 drone            drone index
    u32 round            control tick of the status
    f64 t_s              the vehicle's simulated time, s
    u8  mode             AgentMode
    u8  armed            0 or 1
    u8  health           Health flags
    u32 plan_seq         sequence number of the plan flown; 0xFFFFFFFF: none yet
    u32 takeoff_round    the control round at which the agent's swarm left the ground, as the
                         agent knows it (drone_agent/core/flight_phase.py, TakeoffClock);
                         0xFFFFFFFF: not flying / not said (from version 2)
    9 x f64 estimate     the agent's estimate of the swarm descriptors (m, rad, m^2); may be
                         NaN (a diverged estimate is reported as it is)
    7 x u64 counters     rx, rx_dropped_malformed, rx_dropped_wrong_swarm,
                         rx_dropped_wrong_version, tx, rejected_setpoints, rx_lost_radio
                         (from version 3: the messages the radio's limits dropped,
                         drone_agent/process/radio.py)
    u16 n_neighbours
    n x u16              the neighbours integrating this round, strictly increasing

Versions 1 and 2 (still decoded) are the same body without ``rx_lost_radio`` (0), and version 1
without ``takeoff_round`` too: its status has ``takeoff_round`` None.

The status batch (Kind.STATUS_BATCH, schema STATUS_BATCH_VERSION; issue 9, batched messaging):
the statuses one agent process's agents publish in one pass, in one Zenoh sample, on the status
key of its first drone (``swarm/<sid>/status/<first drone>``). A process hosting one agent (or
publishing one status in a pass) sends that status alone (Kind.STATUS): every reader takes both
kinds on the status keys (:func:`decode_statuses`). Body after the common header::

    u16 n                number of statuses (2..MAX_STATUS_BATCH)
    n x u32 length       byte length of each status
    n x status           complete status payloads (header included, any status version),
                         drones strictly increasing
"""

from __future__ import annotations

import itertools
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum, IntFlag

import numpy as np

from protocols.model.frames import FloatArray
from protocols.runtime.fast_dataclass import frozen_factory
from protocols.wire.format import (
    MAX_U32,
    Kind,
    Reason,
    WireError,
    check_ids,
    encode_header,
    expect_length,
    open_versioned,
    uint_ids,
)
from protocols.wire.keys import MAX_DRONE_ID

MAX_STATUS_BYTES = 8 * 1024
#: Schema version of status payloads sent (version 1 still decodes).
STATUS_VERSION = 3
STATUS_VERSIONS = (1, 2, 3)
#: Schema version of status batches.
STATUS_BATCH_VERSION = 1
#: Most statuses in one batch (one process's agents).
MAX_STATUS_BATCH = 256
_COUNT = struct.Struct("<H")
NO_PLAN = MAX_U32
#: A take-off round on the wire that says nothing (the status's ``takeoff_round`` is None).
NO_TAKEOFF = MAX_U32
N_ESTIMATE = 9
_MAX_U64 = 2**64 - 1
_FIXED_V1 = struct.Struct("<HIdBBBI9d6QH")
_FIXED_V2 = struct.Struct("<HIdBBBII9d6QH")
_FIXED = struct.Struct("<HIdBBBII9d7QH")
_FIXED_OF = {1: _FIXED_V1, 2: _FIXED_V2, 3: _FIXED}


class AgentMode(IntEnum):
    """What an agent is doing."""

    STARTING = 0  #: attached, waiting for its vehicle or the plan
    WARMUP = 1  #: consensus running on the ground, not armed
    READY = 2  #: converged; arms when the plan says fly
    FLYING = 3
    LANDING = 4  #: flying the landing plan down, or handed to the autopilot's LAND mode
    HOLDING = 5  #: no valid setpoint in the air: the autopilot holds its altitude
    LEAVING = 6  #: lost its vehicle; leaving the swarm
    LANDED = 7  #: back on the ground and disarmed after a landing; takes off on a FLY plan


class Health(IntFlag):
    """Health flags of an agent."""

    NONE = 0
    VEHICLE_LINK = 1  #: hears its vehicle
    ESTIMATE_FINITE = 2
    CONVERGED = 4  #: estimator settled (warm-up done)
    PLAN = 8  #: holds a plan
    SEPARATING = (
        16  #: its separation layer changed its command (drone_agent/core/separation/filter.py)
    )


#: each :class:`AgentMode` by its value (made once: an enum's call costs a microsecond)
MODE_OF = {int(m): m for m in AgentMode}
_HEALTH_MASK = sum(int(f) for f in Health)


@dataclass(frozen=True)
class StatusCounters:
    """Cumulative counts since the agent started (messages). ``rx`` counts what reached the
    agent; ``rx_lost_radio`` what the radio's limits dropped on the way (a full queue, a burst,
    distance: drone_agent/process/radio.py), not in ``rx``."""

    rx: int = 0
    rx_dropped_malformed: int = 0
    rx_dropped_wrong_swarm: int = 0
    rx_dropped_wrong_version: int = 0
    tx: int = 0
    rejected_setpoints: int = 0
    rx_lost_radio: int = 0

    def __post_init__(self) -> None:
        for name in self.__dataclass_fields__:  # (not astuple: it deep-copies, at 25 Hz a drone)
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= _MAX_U64:
                raise ValueError(f"counter {name} must be an integer >= 0, got {value!r}")


@dataclass(frozen=True, eq=False)
class AgentStatus:
    """One agent's status. ``estimate`` (9,) descriptors (m, rad, m^2), copied read-only;
    ``neighbours``: sorted ids; ``plan_seq`` None before the agent has a plan;
    ``takeoff_round``: the control round at which the agent's swarm left the ground, as the agent
    knows it (drone_agent/core/flight_phase.py, TakeoffClock); None: not flying or not said (a
    version-1 status)."""

    drone: int
    round: int
    t_s: float
    mode: AgentMode
    armed: bool
    health: Health
    estimate: FloatArray
    neighbours: tuple[int, ...]
    counters: StatusCounters
    plan_seq: int | None = None
    takeoff_round: int | None = None

    def __post_init__(self) -> None:
        estimate = np.array(self.estimate, dtype=np.float64)
        if estimate.shape != (N_ESTIMATE,):
            raise ValueError(f"estimate must have shape (9,), got {estimate.shape}")
        estimate.setflags(write=False)
        if not math.isfinite(self.t_s):
            raise ValueError(f"t_s must be finite, got {self.t_s!r}")
        if self.plan_seq is not None and not 0 <= self.plan_seq < NO_PLAN:
            raise ValueError(f"plan_seq must be 0..{NO_PLAN - 1} or None, got {self.plan_seq}")
        takeoff = self.takeoff_round
        if takeoff is not None:
            if (
                isinstance(takeoff, bool)
                or not isinstance(takeoff, int | np.integer)
                or not 0 <= takeoff < NO_TAKEOFF
            ):
                raise ValueError(
                    f"takeoff_round must be an integer 0..{NO_TAKEOFF - 1} or None, got {takeoff!r}"
                )
            object.__setattr__(self, "takeoff_round", int(takeoff))
        object.__setattr__(self, "estimate", estimate)
        object.__setattr__(self, "mode", AgentMode(self.mode))
        object.__setattr__(self, "health", Health(self.health))
        object.__setattr__(self, "neighbours", tuple(uint_ids(self.neighbours, "neighbour")))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, AgentStatus):
            return NotImplemented
        fields = ("drone", "round", "t_s", "mode", "armed", "health", "neighbours", "counters")
        return all(getattr(self, f) == getattr(other, f) for f in fields) and (
            self.plan_seq == other.plan_seq
            and self.takeoff_round == other.takeoff_round
            and np.array_equal(self.estimate, other.estimate, equal_nan=True)
        )


def encode_status(status: AgentStatus, swarm_id: str) -> bytes:
    """The payload (schema STATUS_VERSION) of ``status`` for swarm ``swarm_id``; ValueError if a
    field is out of range."""
    if not 0 <= status.drone <= MAX_DRONE_ID or not 0 <= status.round <= MAX_U32:
        raise ValueError(f"drone {status.drone} or round {status.round} out of range")
    plan_seq = NO_PLAN if status.plan_seq is None else status.plan_seq
    takeoff = status.takeoff_round
    if takeoff is None:
        takeoff = NO_TAKEOFF
    elif not 0 <= takeoff < NO_TAKEOFF:  # (as AgentStatus checks it, if set around its check)
        raise ValueError(f"takeoff_round must be 0..{NO_TAKEOFF - 1} or None, got {takeoff!r}")
    neighbours = status.neighbours
    return b"".join(
        (
            encode_header(Kind.STATUS, swarm_id, STATUS_VERSION),
            _FIXED.pack(
                status.drone,
                status.round,
                status.t_s,
                int(status.mode),
                int(status.armed),
                int(status.health),
                plan_seq,
                takeoff,
                *status.estimate.tolist(),
                *(getattr(status.counters, n) for n in status.counters.__dataclass_fields__),
                len(neighbours),
            ),
            struct.pack(f"<{len(neighbours)}H", *neighbours),
        )
    )


def decode_status(data: bytes, swarm_id: str, *, max_bytes: int = MAX_STATUS_BYTES) -> AgentStatus:
    """Decode a status payload (any of STATUS_VERSIONS) of swarm ``swarm_id``; WireError for
    anything malformed. A version-1 status has ``takeoff_round`` None; a status before version 3
    ``rx_lost_radio`` 0."""
    off, version = open_versioned(data, Kind.STATUS, swarm_id, max_bytes, STATUS_VERSIONS)
    layout = _FIXED_OF[version]
    if len(data) < off + layout.size:
        raise WireError(Reason.TRUNCATED, f"status: {len(data)} bytes, shorter than its fields")
    values = layout.unpack_from(data, off)
    if version == 1:
        values = (*values[:7], NO_TAKEOFF, *values[7:])
    drone, round_, t_s, mode, armed, health, plan_seq, takeoff = values[:8]
    n_counters = 7 if version >= 3 else 6
    estimate, counters = values[8:17], values[17 : 17 + n_counters]
    n = values[17 + n_counters]
    off += layout.size
    expect_length(data, off + 2 * n, "status")
    neighbours = struct.unpack_from(f"<{n}H", data, off)
    check_ids(neighbours, "neighbour")
    if not math.isfinite(t_s):
        raise WireError(Reason.NOT_FINITE, f"status time {t_s}")
    if armed > 1 or mode not in MODE_OF or health & ~_HEALTH_MASK:
        raise WireError(Reason.BAD_VALUE, f"status mode {mode}, armed {armed}, health {health}")
    # made as AgentStatus(...) makes it, without its checks again: the wire's fields meet them
    # (an agent's status comes at 25 Hz: a 100-drone swarm's decoding was a fifth of the ground
    # station's time, its checks and the IntFlag call most of it)
    vector = np.array(estimate, dtype=np.float64)
    vector.setflags(write=False)
    if n_counters < 7:
        counters = (*counters, 0)
    return _new_status(
        drone,
        round_,
        t_s,
        MODE_OF[mode],
        bool(armed),
        _health(health),
        vector,
        neighbours,
        _new_counters(*counters),
        None if plan_seq == NO_PLAN else plan_seq,
        None if takeoff == NO_TAKEOFF else takeoff,
    )


_new_status = frozen_factory(AgentStatus)
_new_counters = frozen_factory(StatusCounters)
_HEALTH_OF: dict[int, Health] = {}


def _health(value: int) -> Health:
    """``Health(value)``, made once per value (an IntFlag's call costs microseconds)."""
    got = _HEALTH_OF.get(value)
    if got is None:
        got = _HEALTH_OF[value] = Health(value)
    return got


def max_status_batch_bytes(max_status_bytes: int = MAX_STATUS_BYTES) -> int:
    """The largest status batch a reader with this status size limit accepts."""
    return 64 + MAX_STATUS_BATCH * (4 + max_status_bytes)


def encode_status_batch(payloads: Sequence[tuple[int, bytes]], swarm_id: str) -> bytes:
    """The batch of ``payloads``, (drone, status payload) pairs with drones strictly increasing;
    ValueError for fewer than two, more than MAX_STATUS_BATCH, or unsorted."""
    n = len(payloads)
    if not 2 <= n <= MAX_STATUS_BATCH:
        raise ValueError(f"a status batch holds 2..{MAX_STATUS_BATCH} statuses, got {n}")
    if any(a >= b for (a, _), (b, _) in itertools.pairwise(payloads)):
        raise ValueError("status batch drones must be strictly increasing")
    parts = [p for _, p in payloads]
    return b"".join(
        (
            encode_header(Kind.STATUS_BATCH, swarm_id, STATUS_BATCH_VERSION),
            _COUNT.pack(n),
            struct.pack(f"<{n}I", *(len(p) for p in parts)),
            *parts,
        )
    )


def decode_statuses(
    data: bytes, swarm_id: str, *, max_bytes: int = MAX_STATUS_BYTES
) -> list[AgentStatus]:
    """The statuses of a status payload or a status batch of swarm ``swarm_id`` (``max_bytes``:
    the limit of one status); WireError for anything malformed (a bad status in a batch rejects
    the whole batch: one process wrote it)."""
    if len(data) <= 2 or data[2] != Kind.STATUS_BATCH:
        return [decode_status(data, swarm_id, max_bytes=max_bytes)]
    off, _ = open_versioned(
        data,
        Kind.STATUS_BATCH,
        swarm_id,
        max_status_batch_bytes(max_bytes),
        (STATUS_BATCH_VERSION,),
    )
    if len(data) < off + _COUNT.size:
        raise WireError(Reason.TRUNCATED, f"status batch: {len(data)} bytes")
    (n,) = _COUNT.unpack_from(data, off)
    off += _COUNT.size
    if not 2 <= n <= MAX_STATUS_BATCH:
        raise WireError(Reason.BAD_VALUE, f"status batch of {n} statuses")
    if len(data) < off + 4 * n:
        raise WireError(Reason.TRUNCATED, f"status batch: {len(data)} bytes, {n} lengths")
    lengths = struct.unpack_from(f"<{n}I", data, off)
    off += 4 * n
    expect_length(data, off + sum(lengths), "status batch")
    out: list[AgentStatus] = []
    for length in lengths:
        status = decode_status(data[off : off + length], swarm_id, max_bytes=max_bytes)
        off += length
        if out and status.drone <= out[-1].drone:
            raise WireError(Reason.BAD_VALUE, "status batch drones must be strictly increasing")
        out.append(status)
    return out

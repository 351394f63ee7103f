"""A tick's streamed telemetry, every vehicle's at once: the same datagrams as sending each
vehicle's due messages one by one (:meth:`Channel.send`), made in a few array operations.

Each link side (the agents' or the ground station's) has per vehicle the messages due at the tick
(its stream schedule). One by one, every frame took a builder (the message's fields into a
payload) and a framing (header, trailing zeros cut, checksum) in Python: at 100 vehicles a
quarter of the simulator's time, and in lockstep every agent waits for it. Here a message that
has a row builder (:data:`sitl_sim.mavlink_edge.messages.Rows`: ATTITUDE, LOCAL_POSITION_NED,
ACTUATOR_OUTPUT_STATUS, ATTITUDE_TARGET, GLOBAL_POSITION_INT, unless the dialect builds it its own
way) is packed for all vehicles at once, once per tick for both sides; any other is built one by
one as before; then all the side's frames are framed in one compiled call
(:func:`protocols.mavlink.frame_batch.frame_many`) and queued vehicle by vehicle, in the order,
with the sequence numbers, that sending them one by one gives. A vehicle whose codec signs sends
its frames one by one (pymavlink signs them).
"""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"  # before any pymavlink import (DEPENDENCIES.md)

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import numpy.typing as npt
from pymavlink.dialects.v20 import common as mavlink

from protocols.mavlink.fast import payload_of
from protocols.mavlink.frame_batch import frames_of
from sitl_sim.mavlink_edge import messages
from sitl_sim.mavlink_edge.channel import Channel
from sitl_sim.mavlink_edge.dispatch import LinkSide

#: A message's payloads for every vehicle now (messages.Rows)
RowBuilder = Callable[[], messages.Rows]
_UNBUILT = object()


class TickTelemetry:
    """Sends a tick's due telemetry of a link side (module doc). ``builders``: each streamed
    message's one-by-one builder (vehicle -> message); ``rows``: the messages that also have a
    row builder (for every vehicle at once, the same bytes)."""

    def __init__(
        self,
        builders: Mapping[int, Callable[[int], Any]],
        rows: Mapping[int, RowBuilder],
    ) -> None:
        self._builders = builders
        self._rows = dict(rows)
        self._classes = {msg_id: mavlink.mavlink_map[msg_id] for msg_id in rows}
        self._made: dict[int, Any] = {}

    def new_tick(self) -> None:
        """The world moved on: rows are made again when next asked."""
        self._made.clear()

    def _rows_of(self, msg_id: int) -> messages.Rows:
        made = self._made.get(msg_id, _UNBUILT)
        if made is _UNBUILT:
            made = self._made[msg_id] = self._rows[msg_id]()
        return made

    def send(
        self, side: LinkSide, tick: int, silent: npt.NDArray[np.bool_], tick_message: int | None
    ) -> list[int]:
        """Queue every due message of ``side`` at ``tick`` (vehicles not ``silent`` with a peer);
        the vehicles that got ``tick_message``."""
        streams, channels = side.streams, side.channels
        got: list[int] = []
        # the vehicles that send, in order: framed here (True), or one by one (a signing codec)
        order: list[tuple[int, bool]] = []
        # vehicles by the due list they share (the shared schedule's, or their own)
        groups: dict[int, tuple[list[int], list[int]]] = {}
        signed: dict[int, list[Any]] = {}
        builders = self._builders
        shared, own = streams.shared.due(tick), streams.split
        for i, channel in enumerate(channels):
            if silent[i] or channel.endpoint.peer is None:
                continue
            schedule = own.get(i)
            due = shared if schedule is None else schedule.due(tick)
            if not due:
                continue
            if tick_message is not None and tick_message in due:
                got.append(i)
            if channel.codec.signing.sign_outgoing:
                order.append((i, False))
                signed[i] = [builders[msg_id](i) for msg_id in due]  # built in turn
                continue
            order.append((i, True))
            group = groups.get(id(due))
            if group is None:
                groups[id(due)] = ([i], due)
            else:
                group[0].append(i)
        if not order:
            return got
        data, ends, counts = self._frames(channels, groups)
        at = stop = 0  # the frames of the vehicles not queued yet, from ``at``
        endpoint = None  # the endpoint they go to (the GCS link's: one for all vehicles)
        for i, framed in order:
            channel = channels[i]
            if endpoint is not None and (not framed or channel.endpoint is not endpoint):
                endpoint.queue_frames(data, ends[at:stop], ends[at - 1] if at else 0)
                at, endpoint = stop, None  # the run so far goes out first
            if not framed:
                for msg in signed[i]:
                    channel.send(msg)
                continue
            endpoint = channel.endpoint
            n = counts[i]
            stop += n
            codec = channel.codec
            codec.seq = (codec.seq + n) & 0xFF
            channel.tx += n
        if endpoint is not None:
            endpoint.queue_frames(data, ends[at:stop], ends[at - 1] if at else 0)
        return got

    def _frames(
        self, channels: list[Channel], groups: dict[int, tuple[list[int], list[int]]]
    ) -> tuple[bytes, list[int], dict[int, int]]:
        """The frames of ``groups`` (vehicles sharing a due list), vehicle after vehicle in
        order, each vehicle's in its due order: their bytes, where each ends, and how many
        each vehicle has."""
        if not groups:  # (every vehicle signs)
            return b"", [], {}
        builders = self._builders
        payloads: list[bytes] = []
        placed: dict[int, int] = {}  # where each message's rows are in the payloads
        total = 0
        cols: list[tuple[npt.NDArray[np.int64], ...]] = []
        counts: dict[int, int] = {}
        for vehicles, due in groups.values():
            v = np.array(vehicles, dtype=np.int64)
            d = len(due)
            starts = np.empty((v.shape[0], d), dtype=np.int64)
            meta = np.empty((3, d), dtype=np.int64)  # size, id, CRC_EXTRA
            for j, msg_id in enumerate(due):
                rows = self._rows_of(msg_id) if msg_id in self._rows else None
                if rows is not None:
                    cls = self._classes[msg_id]
                    base = placed.get(msg_id)
                    if base is None:
                        base = placed[msg_id] = total
                        payloads.append(rows.tobytes())
                        total += rows.size
                    starts[:, j] = base + v * rows.shape[1]
                    size = rows.shape[1]
                else:  # one by one, as the vehicle's own builder makes it
                    for r, i in enumerate(vehicles):
                        cls, payload = payload_of(builders[msg_id](i))
                        starts[r, j] = total
                        payloads.append(payload)
                        total += len(payload)
                    size = cls.unpacker.size
                meta[:, j] = (size, cls.id, cls.crc_extra)
            for i in vehicles:
                counts[i] = d
            cols.append((
                np.repeat(v, d), np.tile(np.arange(d, dtype=np.int64), v.shape[0]),
                starts.reshape(-1), *np.tile(meta, v.shape[0]),
            ))  # fmt: skip
        vehicle, step, starts_all, sizes, ids, extras = (
            np.concatenate(c) if len(cols) > 1 else c[0] for c in zip(*cols, strict=True)
        )
        if len(groups) > 1:  # vehicle after vehicle (each one's frames stay in due order)
            by = np.argsort(vehicle, kind="stable")
            vehicle, step, starts_all, sizes, ids, extras = (
                a[by] for a in (vehicle, step, starts_all, sizes, ids, extras)
            )
        framed = sorted(counts)
        head = np.zeros((3, len(channels)), dtype=np.int64)  # seq, system, component
        head[:, framed] = [
            [channels[i].codec.seq for i in framed],
            [channels[i].codec.srcSystem for i in framed],
            [channels[i].codec.srcComponent for i in framed],
        ]
        data, ends = frames_of(
            np.frombuffer(b"".join(payloads), dtype=np.uint8), starts_all, sizes, ids, extras,
            (head[0, vehicle] + step) & 0xFF, head[1, vehicle], head[2, vehicle],
        )  # fmt: skip
        return data, ends, counts


def warm() -> None:
    """Load (or compile) the compiled parts now, so that a first tick does not pay for them: one
    frame and one quaternion."""
    one = np.ones(1, dtype=np.int64)
    frames_of(np.zeros(1, dtype=np.uint8), one - 1, one, one, one, one, one, one)
    messages.quaternions(np.zeros((3, 1)))

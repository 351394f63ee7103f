"""The ground station's part in drills: it records every link-fault command seen on
``swarm/<sid>/fault`` as a "drill" event, and injects vehicle crashes (``swarm drill crash``)
with MAV_CMD_INJECT_FAILURE sent to the vehicle through the simulator's GCS endpoint.

The Zenoh callback only queues payloads; :meth:`GcsDrills.drain` runs on the ground station's
loop. Times in events are simulated seconds.
"""

from __future__ import annotations

import threading
from collections import deque

from drone_agent.fault_drills import describe
from drone_agent.transport import Bus, Closeable
from gcs.commands import Reply
from gcs.events import EventLog
from gcs.telemetry import TelemetryReceiver
from protocols.keys import SwarmKeys
from protocols.wire import WireError
from protocols.wire_fault import decode_fault, fault_op

MAV_CMD_INJECT_FAILURE = 420
FAILURE_UNIT_SYSTEM_MOTOR = 101
FAILURE_TYPE_OFF = 1
ALL_MOTORS = 0
_MAX_QUEUED = 256


class GcsDrills:
    """Drill bookkeeping of one ground station (see the module doc)."""

    def __init__(
        self, bus: Bus, swarm_id: str, events: EventLog, telemetry: TelemetryReceiver
    ) -> None:
        self._swarm_id, self._events, self._telemetry = swarm_id, events, telemetry
        self._queue: deque[bytes] = deque(maxlen=_MAX_QUEUED)
        self._lock = threading.Lock()
        self.malformed = 0
        self._sub: Closeable = bus.subscribe_callback(
            SwarmKeys(swarm_id, 1.0).fault, self._on_sample
        )

    def _on_sample(self, _key: str, payload: bytes) -> None:  # Zenoh thread: enqueue only
        with self._lock:
            self._queue.append(bytes(payload))

    def drain(self, now_s: float) -> None:
        """Record the fault commands that came since the last call (at ``now_s``, s)."""
        if not self._queue:
            return
        with self._lock:
            payloads = list(self._queue)
            self._queue.clear()
        for payload in payloads:
            try:
                command = decode_fault(payload, self._swarm_id)
            except WireError as exc:
                self.malformed += 1
                self._events.record(
                    now_s, "drill", drill="malformed", accepted=False, reason=str(exc)
                )
                continue
            name = fault_op(command).name.lower()
            self._events.record(
                now_s, "drill", drill=name, what=describe(command), accepted=True, reason="sent"
            )

    def crash(self, drone: float, n_drones: int, now_s: float) -> Reply:
        """Stop every motor of vehicle ``drone`` (index 0..n_drones-1): MAV_CMD_INJECT_FAILURE
        (FAILURE_UNIT_SYSTEM_MOTOR, FAILURE_TYPE_OFF, all motors). Recorded as a "drill" event."""
        index = int(drone)
        if index != drone or not 0 <= index < n_drones:
            reply = Reply(False, f"drone must be an index 0..{n_drones - 1}, got {drone:g}")
        else:
            try:
                self._telemetry.send_command(
                    index,
                    MAV_CMD_INJECT_FAILURE,
                    FAILURE_UNIT_SYSTEM_MOTOR,
                    FAILURE_TYPE_OFF,
                    ALL_MOTORS,
                )
            except OSError as exc:
                reply = Reply(False, f"cannot reach vehicle {index}: {exc}")
            else:
                reply = Reply(True, f"all motors of vehicle {index} (system {index + 1}) stopped")
        self._events.record(
            now_s,
            "drill",
            drill="crash",
            drone=index if index == drone else drone,
            accepted=reply.accepted,
            reason=reply.reason,
        )
        return reply

    def close(self) -> None:
        """Stop listening for fault commands."""
        self._sub.close()

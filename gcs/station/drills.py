"""The ground station's part in drills: it records every link-fault command seen on
``swarm/<sid>/fault`` as a "drill" event, injects vehicle crashes (``swarm drill crash``) with
MAV_CMD_INJECT_FAILURE sent to the vehicle through the simulator's GCS endpoint, and kills a
drone's agent (``swarm drill dropout``) when ``swarm up`` told it the agents' process ids in its
run file (:data:`RUN_FILE` in the report's logs folder: ``{"agents": {"<drone>": pid}}``): a
process that runs that agent alone is killed (SIGKILL), as a companion computer dies; one that
hosts other drones' agents too is told to kill that one agent (the DROPOUT fault command, which
drops its liveliness token at once: to its neighbours the same as a killed process), so that
the other drones fly on.

The Zenoh callback only queues payloads; :meth:`GcsDrills.drain` runs on the ground station's
loop. Times in events are simulated seconds.
"""

from __future__ import annotations

import json
import os
import signal
import threading
from collections import deque
from collections.abc import Callable
from pathlib import Path

from drone_agent.process.fault_drills import describe
from gcs.report.events import EventLog
from gcs.station.commands import Reply
from gcs.station.telemetry import TelemetryReceiver
from protocols.bus.interface import Bus, Closeable, Congestion
from protocols.faults import Dropout, LinkCut, LinkRestore, Restart
from protocols.wire.fault import decode_fault, encode_fault, fault_op
from protocols.wire.format import WireError
from protocols.wire.keys import SwarmKeys

MAV_CMD_INJECT_FAILURE = 420
FAILURE_UNIT_SYSTEM_MOTOR = 101
FAILURE_TYPE_OFF = 1
ALL_MOTORS = 0
_MAX_QUEUED = 256
#: Written by ``swarm up`` next to its logs: which process runs each drone's agent.
RUN_FILE = "run.json"


class GcsDrills:
    """Drill bookkeeping of one ground station (see the module doc)."""

    def __init__(
        self, bus: Bus, swarm_id: str, events: EventLog, telemetry: TelemetryReceiver
    ) -> None:
        self._swarm_id, self._events, self._telemetry = swarm_id, events, telemetry
        self._queue: deque[bytes] = deque(maxlen=_MAX_QUEUED)
        self._lock = threading.Lock()
        self.malformed = 0
        key = SwarmKeys(swarm_id, 1.0).fault
        self._sub: Closeable = bus.subscribe_callback(key, self._on_sample)
        # remote_only: its own drill event is recorded once, by the dropout drill itself
        self._pub = bus.publisher(key, Congestion.BLOCK, remote_only=True)

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
            link: dict[str, object] = {}
            if isinstance(command, LinkCut | LinkRestore):  # the report shades link cuts
                link = {"link": [command.i, command.j]}
            if isinstance(command, LinkCut):
                link |= {"one_way": command.one_way, "duration_s": command.duration_s}
            if isinstance(command, Restart):  # the drone's dropout and return follow
                link = {"drone": command.drone, "gap_s": command.gap_s}
            self._events.record(
                now_s,
                "drill",
                drill=name,
                what=describe(command),
                accepted=True,
                reason="sent",
                **link,
            )

    def crash(self, drone: float, n_drones: int, now_s: float) -> Reply:
        """Stop every motor of vehicle ``drone`` (index 0..n_drones-1): MAV_CMD_INJECT_FAILURE
        (FAILURE_UNIT_SYSTEM_MOTOR, FAILURE_TYPE_OFF, all motors). Recorded as a "drill" event."""

        def stop_motors(index: int) -> Reply:
            try:
                self._telemetry.send_command(
                    index,
                    MAV_CMD_INJECT_FAILURE,
                    FAILURE_UNIT_SYSTEM_MOTOR,
                    FAILURE_TYPE_OFF,
                    ALL_MOTORS,
                )
            except OSError as exc:
                return Reply(False, f"cannot reach vehicle {index}: {exc}")
            return Reply(True, f"all motors of vehicle {index} (system {index + 1}) stopped")

        return self._on_drone("crash", drone, n_drones, now_s, stop_motors)

    def dropout(
        self,
        drone: float,
        n_drones: int,
        now_s: float,
        run_file: Path | None,
        alive: set[int] | None = None,
    ) -> Reply:
        """Kill drone ``drone``'s agent (module doc), its process found in ``run_file``; refused
        without one (the swarm was not started by ``swarm up``), and for an agent not in
        ``alive`` (the agents whose liveliness token is up; None: not checked)."""

        def kill(index: int) -> Reply:
            if run_file is None:
                return Reply(
                    False,
                    "dropout needs the agents' process ids: only a swarm started by swarm up "
                    "(or its ground station's --run-file) can be drilled this way",
                )
            if alive is not None and index not in alive:
                return Reply(False, f"the agent of drone {index} is not running")
            return _kill_agent(index, run_file, self._dropout)

        return self._on_drone("dropout", drone, n_drones, now_s, kill)

    def _on_drone(
        self,
        name: str,
        drone: float,
        n_drones: int,
        now_s: float,
        act: Callable[[int], Reply],
    ) -> Reply:
        """Check ``drone`` is an index 0..n_drones-1, ``act`` on it, record a "drill" event."""
        index = int(drone)
        if index != drone or not 0 <= index < n_drones:
            reply = Reply(False, f"drone must be an index 0..{n_drones - 1}, got {drone:g}")
        else:
            reply = act(index)
        self._events.record(
            now_s,
            "drill",
            drill=name,
            drone=index if index == drone else drone,
            accepted=reply.accepted,
            reason=reply.reason,
        )
        return reply

    def _dropout(self, drone: int) -> None:
        """Tell the process hosting drone ``drone``'s agent to kill that agent."""
        self._pub.put(encode_fault(Dropout(drone), self._swarm_id))

    def close(self) -> None:
        """Stop listening for fault commands."""
        self._sub.close()
        self._pub.close()


def _kill_agent(drone: int, run_file: Path, dropout: Callable[[int], None]) -> Reply:
    """Kill the agent of ``drone``: SIGKILL its process listed in ``run_file`` if it runs that
    agent alone, else ``dropout(drone)`` (the module doc)."""
    try:
        agents = json.loads(run_file.read_text())["agents"]
        pid = int(agents[str(drone)])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return Reply(False, f"no agent process known for drone {drone} in {run_file}: {exc}")
    together = sorted(int(d) for d, p in agents.items() if int(p) == pid)
    try:  # a recycled pid must not be killed: it has to be a swarm agent still
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        cmdline = []
    if cmdline and b"agent" not in cmdline:
        return Reply(False, f"the agent process of drone {drone} (pid {pid}) is not running")
    others = [d for d in together if d != drone]
    if others:
        dropout(drone)
        return Reply(
            True,
            f"agent of drone {drone} killed in its process (pid {pid}), which flies on with "
            f"drones {others}",
        )
    try:
        os.kill(pid, signal.SIGKILL)
    except ProcessLookupError:
        return Reply(False, f"the agent process of drone {drone} (pid {pid}) is not running")
    except PermissionError:
        return Reply(False, f"not allowed to kill the agent process of drone {drone} (pid {pid})")
    return Reply(True, f"agent process of drone {drone} (pid {pid}) killed")

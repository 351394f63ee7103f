"""Test harness for agents: real ``swarm agent`` processes, a Zenoh observer of their status and
liveliness, and scenario files written for a test."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from sitl_client import ENV, ROOT, free_port_block, free_udp_port, swarm_command

from protocols.bus.zenoh_bus import ZenohBus, ZenohSettings, free_loopback_endpoint
from protocols.model.descriptors import descriptors
from protocols.wire.keys import SwarmKeys
from protocols.wire.status import AgentMode, AgentStatus, decode_statuses

SWARM = "test"


@dataclass
class AgentProcess:
    """A running ``swarm agent`` process."""

    proc: subprocess.Popen[bytes]
    log: Path

    def kill(self) -> None:
        """SIGKILL: the process dies at once, as in a drop-out drill."""
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(5)

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        return int(self.proc.returncode)


@contextlib.contextmanager
def agent_process(
    tmp_path: Path, drone_ids: str, base_port: int, zenoh_args: list[str], *args: str
) -> Iterator[AgentProcess]:
    """Run ``swarm agent --drone-id IDS``; always stopped on exit."""
    log = tmp_path / f"agent-{drone_ids.replace(',', '_')}-{time.monotonic_ns()}.log"
    with log.open("wb") as f:
        proc = subprocess.Popen(
            swarm_command(
                "agent",
                "--drone-id",
                drone_ids,
                "--base-port",
                str(base_port),
                "--swarm-id",
                SWARM,
                "--quiet",
                *zenoh_args,
                *args,
            ),
            stdout=f,
            stderr=subprocess.STDOUT,
            env=ENV,
            cwd=ROOT,
        )
    agent = AgentProcess(proc, log)
    try:
        yield agent
    finally:
        agent.stop()


@dataclass
class Seen:
    """The newest status of a drone and when (wall, monotonic) it came."""

    status: AgentStatus
    at: float


@dataclass
class SwarmObserver:
    """A Zenoh peer that listens on ``endpoint`` (the agents connect to it) and records every
    agent's status and liveliness of swarm ``swarm_id``; with ``connect`` it also joins a swarm
    that listens there (e.g. ``swarm up``'s default tcp/127.0.0.1:7447)."""

    endpoint: str = field(default_factory=free_loopback_endpoint)
    swarm_id: str = SWARM
    connect: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        self._lock = threading.Lock()
        self.latest: dict[int, Seen] = {}
        self.alive: dict[int, bool] = {}
        self.changes: list[tuple[float, int, bool]] = []
        self.bus = ZenohBus.open(ZenohSettings(listen=(self.endpoint,), connect=self.connect))
        keys = SwarmKeys.for_range(self.swarm_id, 10.0)
        self._keys = keys
        self._subs = [
            self.bus.subscribe_callback(keys.status_all(), self._on_status),
            self.bus.watch_liveliness(keys.alive_all(), self._on_alive),
        ]

    @property
    def zenoh_args(self) -> list[str]:
        """Agent flags that make it join this observer."""
        return ["--zenoh-listen", "tcp/127.0.0.1:0", "--zenoh-connect", self.endpoint]

    def _on_status(self, _key: str, payload: bytes) -> None:
        try:  # one status, or a hosting process's batch of them
            statuses = decode_statuses(payload, self.swarm_id)
        except ValueError:
            return
        with self._lock:
            for status in statuses:
                self.latest[status.drone] = Seen(status, time.monotonic())

    def _on_alive(self, key: str, alive: bool) -> None:
        drone = int(key.rsplit("/", 1)[1])
        with self._lock:
            self.alive[drone] = alive
            self.changes.append((time.monotonic(), drone, alive))

    def statuses(self) -> dict[int, AgentStatus]:
        with self._lock:
            return {d: s.status for d, s in self.latest.items()}

    def wait_until(self, condition: Callable[[], bool], timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if condition():
                return True
            time.sleep(0.05)
        return condition()

    def close(self) -> None:
        for sub in self._subs:
            sub.close()
        self.bus.close()


@contextlib.contextmanager
def observer(swarm_id: str = SWARM, connect: tuple[str, ...] = ()) -> Iterator[SwarmObserver]:
    obs = SwarmObserver(swarm_id=swarm_id, connect=connect)
    try:
        yield obs
    finally:
        obs.close()


def up_with_a_frozen_agent(
    scenario: Path,
    report: Path,
    *flags: str,
    swarm_id: str,
    drones: int,
    freeze: int,
    frozen_s: float,
    flying_after_s: float,
    timeout_s: float = 300.0,
) -> tuple[int, str]:
    """``swarm up SCENARIO --report REPORT FLAGS`` on free ports, watched as a Zenoh peer: once
    all ``drones`` agents fly past ``flying_after_s`` of simulated time, the agent process
    hosting drone ``freeze`` is frozen (SIGSTOP) for ``frozen_s`` wall seconds, as a machine that
    cannot keep up freezes it, then resumed; the run's exit code and printed output."""
    base, gcs_port = free_port_block(drones), free_udp_port()
    with observer(swarm_id=swarm_id) as obs:
        proc = subprocess.Popen(
            swarm_command(
                # a process per drone (flags may say otherwise): one frozen agent, not all
                *("up", str(scenario), "--report", str(report), "--agents-per-process", "1"),
                *("--no-plots", "--no-recording"),
                *flags,
                *("--base-port", str(base), "--gcs-port", str(gcs_port)),
                *("--swarm-id", swarm_id, "--zenoh-connect", obs.endpoint),
            ),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            env=ENV,
            cwd=ROOT,
        )
        try:
            flying = obs.wait_until(
                lambda: len(obs.statuses()) == drones
                and all(s.mode == AgentMode.FLYING and s.t_s > flying_after_s
                        for s in obs.statuses().values()),
                timeout_s,
            )  # fmt: skip
            assert flying, obs.statuses()
            pid = json.loads((report / "logs" / "run.json").read_text())["agents"][str(freeze)]
            os.kill(pid, signal.SIGSTOP)
            time.sleep(frozen_s)
            os.kill(pid, signal.SIGCONT)
            out, _ = proc.communicate(timeout=timeout_s)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)
        assert all(s.mode == AgentMode.FLYING for s in obs.statuses().values()), obs.statuses()
    return proc.returncode, out.decode(errors="replace")


def write_scenario(
    path: Path,
    positions: list[tuple[float, float, float]],
    *,
    centre: tuple[float, float, float],
    spread: tuple[float, float, float],
    extra: str = "",
    duration_s: float = 600.0,
    settle_s: float = 20.0,
) -> Path:
    """A scenario holding the swarm at ``centre`` with ``spread``, plus ``extra`` TOML."""
    drones = "\n".join(f"[[drones]]\nposition_ned_m = {list(p)}\n" for p in positions)
    path.write_text(
        f'version = 1\nname = "{path.stem}"\nduration_s = {duration_s}\nsettle_s = {settle_s}\n\n'
        f"{drones}\n"
        f"[[trajectory.waypoints]]\nt_s = 0.0\ncentre_ned_m = {list(centre)}\n"
        f"spread_m = {list(spread)}\n\n[[trajectory.waypoints]]\nt_s = 10.0\n"
        f"centre_ned_m = {list(centre)}\nspread_m = {list(spread)}\n\n{extra}\n"
    )
    return path


GRID = [(float(x), float(y), 0.0) for x in (0.0, 3.0, 6.0) for y in (0.0, 2.0, 4.0)]


def truth_of(positions: list[tuple[float, float, float]]) -> np.ndarray:
    """The true descriptors of drones at rest at ``positions``."""
    return descriptors(np.array(positions, dtype=float))


def within_bound(estimate: np.ndarray, truth: np.ndarray) -> bool:
    """The agent issue's bound: 2 % of the true value, or 0.05 (m, m^2, rad) near zero."""
    rows = [0, 1, 2, 5, 6, 7, 8]  # centre, heading, variances (roll/pitch of a flat grid: ~0)
    err = np.abs(estimate[rows] - truth[rows])
    bound = np.maximum(0.02 * np.abs(truth[rows]), 0.05)
    return bool(np.all(err <= bound))

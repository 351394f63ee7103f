"""Test helpers for the SITL simulator: free ports, the ``swarm sim`` process, a MAVLink peer.

- :func:`free_port_block` finds ``n`` consecutive free UDP ports on 127.0.0.1 (so tests can run
  in parallel without clashing), :func:`free_udp_port` one.
- :func:`sim_process` runs ``swarm sim`` as a real process (output to files, never a full pipe)
  and always ends it: SIGTERM, then SIGKILL after a grace period.
- :class:`MavPeer` is a pymavlink codec over a plain UDP socket: an agent (component 191 of the
  vehicle's system id, talking to the vehicle's port) or a ground station listening on a port.
- :class:`AltitudePD` is a simple altitude hold on SET_ATTITUDE_TARGET (level attitude, thrust
  from a PD on altitude), echoing the telemetry tick as the lockstep handshake asks.
"""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"  # before any pymavlink import (DEPENDENCIES.md)

import contextlib
import itertools
import json
import math
import select
import signal
import socket
import subprocess
import sys
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol

from pymavlink.dialects.v20 import common as mavlink

from protocols.mavlink.signing import setup_signing

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "MAVLINK20": "1", "MPLBACKEND": "Agg", "PYTHONUNBUFFERED": "1"}
HOST = "127.0.0.1"
AGENT_COMPID = 191
G = 9.81


def free_udp_port() -> int:
    """A UDP port of 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((HOST, 0))
        return int(s.getsockname()[1])


def free_port_block(n: int, attempts: int = 50) -> int:
    """First of ``n`` consecutive UDP ports of 127.0.0.1 that are all free right now (the API's
    search, gcs.api.launch.free_udp_block)."""
    from gcs.api.launch import free_udp_block

    return free_udp_block(n, HOST, attempts)


@dataclass
class SimProcess:
    """A running ``swarm sim``: its process and output files."""

    proc: subprocess.Popen[bytes]
    stdout_path: Path
    stderr_path: Path
    base_port: int

    def stdout(self) -> str:
        return self.stdout_path.read_text(errors="replace")

    def stderr(self) -> str:
        return self.stderr_path.read_text(errors="replace")

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, sig: int = signal.SIGTERM, timeout_s: float = 10.0) -> int:
        """Send ``sig`` and wait for the exit code (SIGKILL after ``timeout_s``)."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        return int(self.proc.returncode)


def swarm_command(*args: str) -> list[str]:
    """The command line of ``swarm ARGS`` with this interpreter. On a pytest-xdist worker (the
    first part of ``make test``, two tests at once) a flight on the realtime clock is refused:
    its test belongs to the serial part (tests/conftest.py)."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        why = needs_the_machine_alone(args)
        if why:
            raise AssertionError(
                f"swarm {' '.join(args[:2])}: {why}; add its module to REALTIME_MODULES in "
                "tests/conftest.py (or, on the default ports, parametrise its clock) so that "
                "make test runs it alone"
            )
    return [sys.executable, "-m", "gcs.cli", *args]


def run_swarm(cwd: Path, *args: str, timeout_s: float = 600.0) -> str:
    """``swarm ARGS`` in ``cwd``, which must succeed; what it printed."""
    done = subprocess.run(
        swarm_command(*args), capture_output=True, text=True, env=ENV, cwd=cwd, timeout=timeout_s
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    return done.stdout


def simulate_metrics(cwd: Path, scenario: Path | str, *flags: str) -> dict[str, Any]:
    """``swarm simulate SCENARIO --report r --no-plots FLAGS`` in ``cwd``: its metrics.json (the
    report in ``cwd / "r"``)."""
    run_swarm(
        cwd, "simulate", str(scenario), "--report", "r", "--no-plots", "--no-recording", *flags
    )
    metrics: dict[str, Any] = json.loads((cwd / "r" / "metrics.json").read_text())
    return metrics


def needs_the_machine_alone(args: tuple[str, ...]) -> str | None:
    """Why ``swarm ARGS`` must not fly beside another test's flight, or None: the simulator on
    the realtime clock (``swarm sim``'s default; its agents keep its pace). Runs on the default
    ports are listed by module in tests/conftest.py (DEFAULT_PORT_MODULES): a ``swarm up``
    command line is often finished after this function returns."""
    clock = next((v for f, v in itertools.pairwise(args) if f == "--clock"), None)
    if args[:1] == ("sim",) and clock != "lockstep" and "--help" not in args:
        return "the simulator on the realtime clock"
    if args[:1] == ("up",) and clock == "realtime":
        return "swarm up on the realtime clock"
    return None


@contextlib.contextmanager
def sim_process(tmp_path: Path, *args: str, base_port: int | None = None) -> Iterator[SimProcess]:
    """Run ``swarm sim --base-port BASE ARGS``; always stopped (and reaped) on exit."""
    base = base_port if base_port is not None else free_port_block(_drones(args))
    out, err = tmp_path / f"sim-{base}.out", tmp_path / f"sim-{base}.err"
    with out.open("wb") as fo, err.open("wb") as fe:
        proc = subprocess.Popen(
            swarm_command("sim", "--base-port", str(base), *args),
            stdout=fo,
            stderr=fe,
            env=ENV,
            cwd=ROOT,
        )
    sim = SimProcess(proc, out, err, base)
    try:
        if "--quiet" not in args:
            _wait_started(sim)
        yield sim
    finally:
        sim.stop()


def _wait_started(sim: SimProcess, timeout_s: float = 60.0) -> None:
    """Until the simulator says it started (its ports are bound) or ends: a peer socket opened
    before that may be given one of the block's ports by the kernel (an ephemeral port), and the
    simulator would then fail to bind it."""
    from sitl_sim.launch import START_LINE_PREFIX

    end = time.monotonic() + timeout_s
    while sim.alive() and time.monotonic() < end:
        if START_LINE_PREFIX in sim.stdout():
            return
        time.sleep(0.05)


def _drones(args: tuple[str, ...]) -> int:
    for flag, value in itertools.pairwise(args):
        if flag == "--drones":
            return int(value)
    return 16


class MavPeer:
    """A MAVLink 2 peer on a UDP socket, speaking as ``sysid``/``compid``.

    ``remote``: where :meth:`send` goes (an agent's vehicle port); None: the address the last
    datagram came from (a ground station). ``bind_port`` 0 picks a free port.
    """

    def __init__(
        self,
        sysid: int,
        compid: int,
        remote: tuple[str, int] | None = None,
        bind_port: int = 0,
        signing_key: bytes | None = None,
        link_id: int = 1,
    ) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 21)
        self.sock.bind((HOST, bind_port))
        self.sock.setblocking(False)
        self.port = int(self.sock.getsockname()[1])
        self.remote = remote
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.mav.robust_parsing = True
        if signing_key is not None:
            setup_signing(self.mav, signing_key, link_id)
        self.sysid = sysid
        self._unread: deque[Any] = deque(maxlen=20_000)
        self.bad = 0

    def __enter__(self) -> MavPeer:
        return self

    def __exit__(
        self, t: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def close(self) -> None:
        self.sock.close()

    # -- sending -------------------------------------------------------------------------------
    def send(self, msg: Any) -> None:
        self.send_raw(msg.pack(self.mav))
        self.mav.seq = (self.mav.seq + 1) & 0xFF

    def send_raw(self, data: bytes) -> None:
        assert self.remote is not None, "no remote address yet"
        self.sock.sendto(data, self.remote)

    def heartbeat(self) -> None:
        self.send(
            self.mav.heartbeat_encode(
                mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 4
            )
        )

    def connect(self, timeout_s: float = 20.0) -> None:
        """Send HEARTBEATs until the vehicle answers (the simulator may still be starting)."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            self.heartbeat()
            if self.poll(0.2):
                return
        raise AssertionError(f"no answer from {self.remote} within {timeout_s} s")

    def command(self, target: int, command: int, *params: float) -> None:
        p = [float(v) for v in params] + [0.0] * (7 - len(params))
        self.send(self.mav.command_long_encode(target, 1, command, 0, *p))

    def setpoint(
        self,
        target: int,
        time_boot_ms: int,
        thrust: float,
        q: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0),
        type_mask: int = 0b111,
    ) -> None:
        self.send(
            self.mav.set_attitude_target_encode(
                time_boot_ms, target, 1, type_mask, list(q), 0.0, 0.0, 0.0, thrust
            )
        )

    # -- receiving -----------------------------------------------------------------------------
    def poll(self, timeout_s: float = 0.0) -> list[Any]:
        """Every pending message, waiting up to ``timeout_s`` for the first datagram (they also
        stay unread for :meth:`wait_for`)."""
        out: list[Any] = []
        ready, _, _ = select.select([self.sock], [], [], max(0.0, timeout_s))
        while ready:
            try:
                data, addr = self.sock.recvfrom(65535)
            except (BlockingIOError, ConnectionRefusedError):
                break
            if self.remote is None:
                self.remote = addr
            out += self._parse(data)
        self._unread.extend(out)
        return out

    def _parse(self, data: bytes) -> list[Any]:
        msgs = self.mav.parse_buffer(data) or []
        self.mav.buf, self.mav.buf_index = bytearray(), 0
        self.mav.expected_length = mavlink.HEADER_LEN_V1 + 2
        good = [m for m in msgs if m.get_type() != "BAD_DATA"]
        self.bad += len(msgs) - len(good)
        return good

    def collect(self, duration_s: float) -> list[Any]:
        """Everything received during ``duration_s``."""
        out: list[Any] = []
        end = time.monotonic() + duration_s
        while (left := end - time.monotonic()) > 0:
            out += self.poll(left)
        self._unread.clear()
        return out

    def wait_for(
        self, kind: str, timeout_s: float = 5.0, where: Callable[[Any], bool] = lambda m: True
    ) -> Any:
        """The next message of type ``kind`` satisfying ``where``, reading on from the last one
        returned (messages before it are consumed); AssertionError on timeout."""
        end = time.monotonic() + timeout_s
        while True:
            while self._unread:
                msg = self._unread.popleft()
                if msg.get_type() == kind and where(msg):
                    return msg
            left = end - time.monotonic()
            if left <= 0:
                raise AssertionError(f"no {kind} within {timeout_s} s")
            self.poll(left)

    def ack(self, command: int, timeout_s: float = 5.0) -> int:
        """The result of the next COMMAND_ACK of ``command``."""
        msg = self.wait_for("COMMAND_ACK", timeout_s, lambda m: m.command == command)
        return int(msg.result)


def of_system(messages: list[Any], sysid: int, kind: str | None = None) -> list[Any]:
    """The messages from ``sysid`` (of type ``kind``)."""
    return [
        m for m in messages if m.get_srcSystem() == sysid and (kind is None or m.get_type() == kind)
    ]


class ThrustLaw(Protocol):
    """Normalised thrust 0..1 from a LOCAL_POSITION_NED message."""

    def thrust(self, lpn: Any) -> float: ...


@dataclass
class FixedThrust:
    """A constant thrust (change ``value`` to change it)."""

    value: float

    def thrust(self, lpn: Any) -> float:
        return self.value


@dataclass
class AltitudePD:
    """Thrust for an altitude target: level attitude, PD on altitude (m) and climb rate (m/s),
    about the hover thrust (0.5 for the default vehicle, thrust-to-weight 2)."""

    target_m: float = 1.0
    kp: float = 6.0
    kd: float = 5.0
    hover: float = 0.5
    history: list[tuple[int, float, float]] = field(default_factory=list)

    def thrust(self, lpn: Any) -> float:
        altitude, climb = -float(lpn.z), -float(lpn.vz)
        self.history.append((int(lpn.time_boot_ms), altitude, climb))
        accel = self.kp * (self.target_m - altitude) - self.kd * climb
        return min(1.0, max(0.0, self.hover * (1.0 + accel / G)))


def roll_quat(roll_rad: float) -> tuple[float, float, float, float]:
    """Quaternion (w, x, y, z) of a pure roll (rad)."""
    return (math.cos(roll_rad / 2), math.sin(roll_rad / 2), 0.0, 0.0)


@dataclass
class Sample:
    """One tick of a vehicle as its agent saw it: simulated ms, altitude (m), roll (rad)."""

    time_boot_ms: int
    altitude_m: float
    roll_rad: float


class Pilot:
    """An agent for one vehicle: answers every telemetry tick with a SET_ATTITUDE_TARGET echoing
    its time_boot_ms; arms, switches to OFFBOARD, then holds ``pd.target_m`` with an altitude PD.
    ``roll_rad`` tilts the commanded attitude; ``silent`` stops answering (and commanding)."""

    def __init__(self, peer: MavPeer, sysid: int, pd: ThrustLaw | None = None) -> None:
        self.peer, self.sysid = peer, sysid
        self.pd = pd if pd is not None else AltitudePD()
        self.phase = "arm"
        self.roll_rad = 0.0
        self.silent = False
        self.offboard_ms: int | None = None
        self.samples: list[Sample] = []
        self.texts: list[str] = []
        self.heartbeats: list[Any] = []
        self.messages: list[Any] = []
        self._last_ms = -1
        self._roll = 0.0

    def handle(self, msgs: list[Any]) -> None:
        """React to what the vehicle sent."""
        self.messages += msgs
        for m in msgs:
            kind = m.get_type()
            if kind == "STATUSTEXT":
                self.texts.append(str(m.text))
            elif kind == "HEARTBEAT":
                self.heartbeats.append(m)
            elif kind == "ATTITUDE":
                self._roll = float(m.roll)
            elif kind == "COMMAND_ACK" and m.result == 0:
                if m.command == 400 and self.phase == "arming":
                    self.phase = "mode"
                elif m.command == 176 and self.phase == "switching":
                    self.phase = "fly"
            elif kind == "LOCAL_POSITION_NED" and m.time_boot_ms > self._last_ms:
                self._last_ms = int(m.time_boot_ms)
                self.samples.append(Sample(self._last_ms, -float(m.z), self._roll))
                if not self.silent:
                    self._answer(m)

    def _answer(self, lpn: Any) -> None:
        ms, thrust = int(lpn.time_boot_ms), 0.0
        if self.phase == "arm":
            self.peer.command(self.sysid, 400, 1)
            self.phase = "arming"
        elif self.phase == "mode":
            self.peer.command(self.sysid, 176, 1, 6)  # PX4 OFFBOARD
            self.phase = "switching"
        elif self.phase == "fly":
            if self.offboard_ms is None:
                self.offboard_ms = ms
            thrust = self.pd.thrust(lpn)
        self.peer.setpoint(self.sysid, ms, thrust, roll_quat(self.roll_rad))

    def flown_s(self) -> float:
        """Simulated seconds since OFFBOARD began (0 before)."""
        if self.offboard_ms is None or not self.samples:
            return 0.0
        return (self.samples[-1].time_boot_ms - self.offboard_ms) / 1000


def fly(
    pilots: list[Pilot],
    until: Callable[[], bool],
    timeout_s: float,
    meanwhile: Callable[[], None] | None = None,
) -> None:
    """Run the pilots until ``until()`` holds, calling ``meanwhile()`` between reads;
    AssertionError after ``timeout_s`` wall seconds."""
    for pilot in pilots:
        pilot.peer.heartbeat()  # tells the vehicle where its agent is
    end = time.monotonic() + timeout_s
    socks = {p.peer.sock: p for p in pilots}
    while not until():
        left = end - time.monotonic()
        if left <= 0:
            raise AssertionError(f"not done within {timeout_s} s")
        ready, _, _ = select.select(list(socks), [], [], min(left, 0.5))
        if meanwhile is not None:
            meanwhile()
        for sock in ready:
            pilot = socks[sock]
            pilot.handle(pilot.peer.poll(0.0))
        if not ready:
            for pilot in pilots:
                if not pilot.samples:
                    pilot.peer.heartbeat()

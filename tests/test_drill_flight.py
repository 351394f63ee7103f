"""Every drill typed through the CLI against one flying swarm (issue 8).

One module-scoped swarm is started the way a newcomer types it: ``swarm up hover.toml`` in a
working folder (default ports, default swarm id, the report in ./report, lockstep clock), and
every drill is typed with its defaults (``swarm drill loss 0.5``: no --zenoh-connect, no
--swarm-id). The scenario is nine drones on a 3 x 3 grid hovering at 3 m, without scripted faults.
The tests run in file order against that swarm and check each drill's *effect*, not only its
reply: agents' statuses over Zenoh (a peer joining the run's rendezvous), ``swarm status``, and at
the end the ground station's flight.tlog and events.jsonl.

The run holds the machine's default ports (UDP 14540+i, 14550, Zenoh tcp/127.0.0.1:7447) under
the lock file other runs on the machine use (``flock /tmp/quadswarm-default-ports.lock``).

Drill effects, as the algorithm has them (shared/ALGORITHM.md §3):
- link cut: the pair drop out of each other's neighbour lists; a one-way cut too, at both ends
  (rule 3), though only the receiving end stops getting messages;
- loss: fewer messages arrive (status rx counter, link quality in ``swarm status``);
- delay: messages arrive late, not lost: beyond the heard-set timeout (100 ms at 50 Hz: messages
  are then 6 ticks old) no link is integrated at all, at 60 ms they are;
- partition: no neighbour across the groups; the cross-group edge state is frozen (rule 4), so
  each group goes on estimating the whole swarm's descriptors rather than its own, and the
  groups' estimates split only once the swarm moves; heal: links across the groups again,
  estimates in agreement;
- crash: the vehicle falls, its agent leaves, the others fly on; dropout: the agent process is
  killed, the ground station logs dropout_detected; gcs-restart: the station comes back, its
  logs cover the whole flight.
"""

from __future__ import annotations

import contextlib
import fcntl
import itertools
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from agent_harness import GRID, within_bound, write_scenario
from sitl_client import ENV

from gcs.report.events import read_events
from gcs.report.tlog import read_tlog
from protocols.bus.zenoh_bus import ZenohBus, ZenohSettings, tcp_listen_free
from protocols.bus.zenoh_config import RENDEZVOUS_PORT
from protocols.mavlink.conventions import DEFAULT_BASE_PORT, DEFAULT_GCS_PORT
from protocols.model.descriptors import descriptors
from protocols.wire.keys import SwarmKeys
from protocols.wire.status import AgentMode, AgentStatus, decode_statuses

pytestmark = pytest.mark.slow

LOCK_FILE = Path("/tmp/quadswarm-default-ports.lock")
SWARM_ID = "swarm"  # swarm up's and swarm drill's default
ENDPOINT = f"tcp/127.0.0.1:{RENDEZVOUS_PORT}"
N = 9
ALTITUDE_M = 3.0
HOVER = [(x, y, -ALTITUDE_M) for x, y, _ in GRID]  # drone i at x = 3 (i // 3), y = 2 (i % 3)
TRUTH = descriptors(np.array(HOVER))
GROUP_A, GROUP_B = (0, 1, 2), (3, 4, 5, 6, 7, 8)
CRASHED, DROPPED = 8, 6
#: Wall-clock cap on waits measured in simulated seconds (lockstep slows down when the machine
#: is busy with other runs).
WALL_PER_SIM_S = 6.0


def _swarm_exe() -> list[str]:
    """``swarm`` as installed next to this interpreter (what a user types)."""
    exe = Path(sys.executable).with_name("swarm")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "gcs.cli"]


@dataclass
class Seen:
    """Statuses and liveliness changes of every agent, as a Zenoh peer of the run sees them."""

    history: list[AgentStatus] = field(default_factory=list)
    latest: dict[int, AgentStatus] = field(default_factory=dict)
    alive: dict[int, bool] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def on_status(self, _key: str, payload: bytes) -> None:
        try:  # one status, or a hosting process's batch of them
            statuses = decode_statuses(payload, SWARM_ID)
        except ValueError:
            return
        with self.lock:
            for status in statuses:
                self.history.append(status)
                self.latest[status.drone] = status

    def on_alive(self, key: str, alive: bool) -> None:
        with self.lock:
            self.alive[int(key.rsplit("/", 1)[1])] = alive


@dataclass
class Flight:
    """The swarm of this module: ``swarm up`` in ``cwd``, a Zenoh peer watching its agents."""

    cwd: Path
    proc: subprocess.Popen[bytes]
    out: Path
    seen: Seen = field(default_factory=Seen)
    bus: ZenohBus | None = None
    output: str = ""

    @property
    def report(self) -> Path:
        return self.cwd / "report"

    # -- what a user types ------------------------------------------------------------------
    def swarm(self, *args: str, timeout_s: float = 30.0) -> subprocess.CompletedProcess[str]:
        """``swarm ARGS`` typed in the run's folder, with every default."""
        return subprocess.run(
            [*_swarm_exe(), *args],
            capture_output=True,
            text=True,
            env=ENV,
            cwd=self.cwd,
            timeout=timeout_s,
        )

    def drill(self, *args: str) -> str:
        """``swarm drill ARGS``; its output (the drill must be accepted)."""
        done = self.swarm("drill", *args)
        assert done.returncode == 0, (args, done.stdout, done.stderr)
        return done.stdout

    def status_table(self) -> tuple[float, dict[int, dict[str, str]]]:
        """``swarm status``: simulated time and per drone its columns (link quality in %)."""
        done = self.swarm("status")
        assert done.returncode == 0, done.stdout + done.stderr
        t = float(done.stdout.split("t = ", 1)[1].split(" s", 1)[0])
        rows = {}
        for line in done.stdout.splitlines():
            parts = line.split()
            if not parts or not parts[0].isdigit():
                continue
            # the position takes 3 columns, or 1 ("-") when unknown: count from both ends
            err, nbrs, link, _fsafe, rx, _tx, _dropped, _radio = parts[-8:]
            rows[int(parts[0])] = {
                "alive": parts[1],
                "mode": parts[2],
                "armed": parts[3],
                "z": parts[6] if len(parts) == 15 else "-",
                "err": err,
                "nbrs": nbrs,
                "link": link,
                "rx": rx,
            }
        return t, rows

    # -- what the agents say ------------------------------------------------------------------
    def now(self) -> float:
        """The newest simulated time an agent reported (s)."""
        with self.seen.lock:
            return max((s.t_s for s in self.seen.latest.values()), default=0.0)

    def latest(self) -> dict[int, AgentStatus]:
        with self.seen.lock:
            return dict(self.seen.latest)

    def between(self, t0: float, t1: float) -> list[AgentStatus]:
        """Statuses of simulated times t0 <= t <= t1."""
        with self.seen.lock:
            return [s for s in self.seen.history if t0 <= s.t_s <= t1]

    def wait_sim(self, condition: Callable[[], bool], sim_s: float) -> bool:
        """Wait until ``condition()`` or ``sim_s`` simulated seconds have passed."""
        t_end, wall_end = self.now() + sim_s, time.monotonic() + WALL_PER_SIM_S * sim_s + 20.0
        while self.now() < t_end and time.monotonic() < wall_end:
            if condition():
                return True
            time.sleep(0.05)
        return condition()

    def pass_sim(self, sim_s: float) -> float:
        """Let ``sim_s`` simulated seconds pass; the time then."""
        self.wait_sim(lambda: False, sim_s)
        return self.now()

    def rx_per_round(self, t0: float, t1: float) -> dict[int, float]:
        """Messages each agent received per control round between t0 and t1 (status rx)."""
        first: dict[int, AgentStatus] = {}
        last: dict[int, AgentStatus] = {}
        for s in self.between(t0, t1):
            first.setdefault(s.drone, s)
            last[s.drone] = s
        return {
            d: (last[d].counters.rx - first[d].counters.rx) / (last[d].round - first[d].round)
            for d in first
            if last[d].round > first[d].round
        }

    def stop(self) -> int:
        """Ctrl-C to ``swarm up`` (once); its exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(120)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        self.output = self.out.read_text(errors="replace")
        return int(self.proc.returncode)


def _linked(st: dict[int, AgentStatus], i: int, j: int) -> tuple[bool, bool]:
    return j in st[i].neighbours, i in st[j].neighbours


def _all_within(flight: Flight) -> bool:
    st = flight.latest()
    return len(st) == N and all(within_bound(np.asarray(s.estimate), TRUTH) for s in st.values())


def _everyone_linked(flight: Flight) -> bool:
    st = flight.latest()
    return len(st) == N and all(len(s.neighbours) == N - 1 for s in st.values())


def _percent(text: str) -> float:
    return float(text.rstrip("%")) / 100.0 if text != "-" else float("nan")


# -- the swarm ---------------------------------------------------------------------------------
@contextlib.contextmanager
def _default_ports_lock() -> Iterator[None]:
    """The machine-wide lock of the default ports (the one ``flock`` takes; already ours when
    this test runs under ``flock /tmp/quadswarm-default-ports.lock pytest ...``), then the ports
    free: a run that did not take the lock may still be ending."""
    with LOCK_FILE.open("a") as f:
        deadline = time.monotonic() + 1200.0
        while True:
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if _lock_holders(LOCK_FILE) & _ancestors():
                    break  # we run under flock: the lock is ours already
                if time.monotonic() > deadline:
                    pytest.fail(f"the default ports stayed locked ({LOCK_FILE}) for 20 min")
                time.sleep(1.0)
        try:
            _wait_ports_free()
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def _lock_holders(path: Path) -> set[int]:
    """Process ids holding a flock on ``path`` (from /proc/locks)."""
    st = path.stat()
    me = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    try:
        lines = Path("/proc/locks").read_text().splitlines()
    except OSError:
        return set()
    return {int(p[4]) for p in (ln.split() for ln in lines) if len(p) > 5 and p[5] == me}


def _ancestors() -> set[int]:
    """This process and its ancestors."""
    pids, pid = set(), os.getpid()
    while pid > 1 and pid not in pids:
        pids.add(pid)
        try:
            pid = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            break
    return pids


def _wait_ports_free() -> None:
    udp = [*range(DEFAULT_BASE_PORT, DEFAULT_BASE_PORT + N), DEFAULT_GCS_PORT]
    deadline = time.monotonic() + 120.0
    while not (tcp_listen_free(RENDEZVOUS_PORT) and all(_udp_free(p) for p in udp)):
        if time.monotonic() > deadline:
            pytest.fail("the default ports (7447, 14540+, 14550) are held by another run")
        time.sleep(1.0)


def _udp_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _watch(flight: Flight) -> None:
    """Join the run's rendezvous as a Zenoh peer and record every agent's status."""
    keys = SwarmKeys.for_range(SWARM_ID, 10.0)
    endpoint = json.loads((flight.report / "logs" / "run.json").read_text())["zenoh"]
    bus = ZenohBus.open(ZenohSettings(listen=("tcp/127.0.0.1:0",), connect=(endpoint,)))
    flight.bus = bus
    bus.subscribe_callback(keys.status_all(), flight.seen.on_status)
    bus.watch_liveliness(keys.alive_all(), flight.seen.on_alive)


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Flight]:
    """``swarm up hover.toml`` in a fresh folder, flying and settled at 3 m."""
    cwd = tmp_path_factory.mktemp("drill_flight")
    write_scenario(
        cwd / "hover.toml",
        GRID,
        centre=(3.0, 2.0, -ALTITUDE_M),
        spread=(float(np.sqrt(6.0)), float(np.sqrt(8.0 / 3.0)), 0.0),
        duration_s=600.0,
        settle_s=10.0,
    )
    out = cwd / "swarm-up.out"
    with _default_ports_lock(), out.open("wb") as sink:
        proc = subprocess.Popen(
            [*_swarm_exe(), "up", "hover.toml"],
            stdout=sink,
            stderr=subprocess.STDOUT,
            env=ENV,
            cwd=cwd,
        )
        flight = Flight(cwd, proc, out)
        try:
            _start(flight)
            yield flight
        finally:
            flight.stop()
            if flight.bus is not None:
                flight.bus.close()


def _start(flight: Flight) -> None:
    run_file = flight.report / "logs" / "run.json"
    deadline = time.monotonic() + 60.0
    while not run_file.exists() and flight.proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.2)
    assert run_file.exists(), flight.out.read_text(errors="replace")
    # the default rendezvous, or the free port the run moved to when another run on the machine
    # held it (it says so): operator commands and drills typed in its folder find it either way
    said = flight.out.read_text(errors="replace")
    endpoint = json.loads(run_file.read_text())["zenoh"]
    assert endpoint == ENDPOINT or "was taken by another process" in said, (endpoint, said)
    deadline = time.monotonic() + 30.0
    while flight.swarm("status").returncode != 0:  # the ground station listens
        assert time.monotonic() < deadline, flight.out.read_text(errors="replace")
    _watch(flight)

    def settled() -> bool:
        st = flight.latest()
        return (
            len(st) == N
            and all(s.mode == AgentMode.FLYING for s in st.values())
            and flight.now() > 15.0
            and _all_within(flight)
            and _everyone_linked(flight)
        )

    deadline = time.monotonic() + 180.0
    while not settled():
        assert flight.proc.poll() is None, flight.out.read_text(errors="replace")
        assert time.monotonic() < deadline, {d: s.mode for d, s in flight.latest().items()}
        time.sleep(0.2)


# -- the drills, in order ----------------------------------------------------------------------
def test_timed_link_cut_drops_the_pair_and_restores_it(flight: Flight) -> None:
    """``swarm drill link-cut 0 1 --for-s 5``: 0 and 1 leave each other's neighbour lists (the
    others keep both) and are back 5 simulated seconds later."""
    t_sent = flight.now()
    reply = flight.drill("link-cut", "0", "1", "--for-s", "5")
    assert "sent link_cut 0<->1 for 5 s" in reply
    assert flight.wait_sim(lambda: _linked(flight.latest(), 0, 1) == (False, False), 3.0)
    st = flight.latest()
    assert set(st[0].neighbours) == set(st[1].neighbours) == set(range(2, N))
    assert all(0 in st[d].neighbours and 1 in st[d].neighbours for d in range(2, N))
    assert flight.wait_sim(lambda: _linked(flight.latest(), 0, 1) == (True, True), 8.0)
    # drone 0's statuses: the first without 1, then the first with 1 again
    zero = [s for s in flight.between(t_sent, flight.now()) if s.drone == 0]
    t_cut = next(s.t_s for s in zero if 1 not in s.neighbours)
    t_back = next(s.t_s for s in zero if s.t_s > t_cut and 1 in s.neighbours)
    # every status of the pair in between left the other out (the agent processes apply a
    # drill at the round they get it: a round or two apart)
    during = [s for s in flight.between(t_cut + 0.1, t_back - 0.1) if s.drone in (0, 1)]
    assert during and all((1 - s.drone) not in s.neighbours for s in during)
    print(f"link-cut --for-s 5: link down from t={t_cut:.2f} to t={t_back:.2f}")
    assert 4.9 < t_back - t_cut < 5.3
    assert flight.wait_sim(lambda: _everyone_linked(flight), 2.0)


def test_one_way_cut_takes_the_link_down_at_both_ends_and_clear_restores_it(
    flight: Flight,
) -> None:
    """``swarm drill link-cut 0 1 --one-way`` cuts 0 -> 1 only: drone 1 stops getting 0's
    messages, drone 0 still gets 1's, yet neither integrates the other (ALGORITHM.md §3 rule 3:
    a one-way link is down for both ends). ``swarm drill clear`` brings it back."""
    reply = flight.drill("link-cut", "0", "1", "--one-way")
    assert "sent link_cut 0->1" in reply
    try:
        assert flight.wait_sim(lambda: _linked(flight.latest(), 0, 1) == (False, False), 3.0)
        t0 = flight.pass_sim(2.0) - 2.0
        rates = flight.rx_per_round(t0, t0 + 2.0)
        during = [s for s in flight.between(t0, t0 + 2.0) if s.drone in (0, 1)]
        assert all((1 - s.drone) not in s.neighbours for s in during)
        print(f"link-cut --one-way: messages per round {rates}")
        assert 7.5 < rates[0] < 8.5  # 0 still hears 1 (and everyone else)
        assert 6.5 < rates[1] < 7.3  # 1 no longer hears 0
    finally:
        assert "sent clear" in flight.drill("clear")
    assert flight.wait_sim(lambda: _everyone_linked(flight), 3.0)


def test_loss_lowers_the_messages_received_and_the_link_quality(flight: Flight) -> None:
    """``swarm drill loss 0.5``: half of the messages arrive (status rx counters grow half as
    fast), the link quality ``swarm status`` shows falls to about 50 %; neighbours flicker; the
    estimates stay within the bound. ``swarm drill clear``: all back."""
    t0 = flight.pass_sim(1.5)  # the previous drill's clear well behind
    before = flight.rx_per_round(t0 - 1.5, t0)
    assert flight.wait_sim(
        lambda: all(_percent(r["link"]) > 0.9 for r in flight.status_table()[1].values()), 3.0
    ), flight.swarm("status").stdout
    assert "sent loss 0.5" in flight.drill("loss", "0.5")
    try:
        flight.pass_sim(1.0)  # applied, and the link quality's smoothing caught up
        t1 = flight.now()
        flight.pass_sim(3.0)
        rates = flight.rx_per_round(t1, t1 + 3.0)
        lossy = flight.between(t1, t1 + 3.0)
        _, table = flight.status_table()
        quality = {d: _percent(r["link"]) for d, r in table.items()}
        print(f"loss 0.5: messages per round {before} -> {rates}; link quality {quality}")
        assert all(7.5 < r < 8.5 for r in before.values()), before
        assert len(rates) == N and all(3.0 < r < 5.0 for r in rates.values()), rates
        assert all(0.3 < q < 0.7 for q in quality.values()), table
        counts = [len(s.neighbours) for s in lossy]
        assert np.mean(counts) < 6.0, np.mean(counts)  # rounds without a partner's message
        assert all(within_bound(np.asarray(s.estimate), TRUTH) for s in lossy)
    finally:
        assert "sent clear" in flight.drill("clear")
    t2 = flight.pass_sim(2.0)
    after = flight.rx_per_round(t2 - 1.0, t2)
    assert all(7.5 < r < 8.5 for r in after.values()), after
    assert flight.wait_sim(lambda: _everyone_linked(flight), 2.0)
    assert flight.wait_sim(
        lambda: all(_percent(r["link"]) > 0.9 for r in flight.status_table()[1].values()), 4.0
    )


def test_delay_makes_messages_late_not_lost(flight: Flight) -> None:
    """``swarm drill delay 100``: every message arrives 100 ms late, 6 control ticks after its
    round, beyond the 5-tick heard-set timeout; the link is still heard — by arrival
    (drone_agent/core/consensus/scalar.py, rule 3) — and each late value pairs with the own value of
    its round, so every agent keeps integrating its neighbours, every message still arrives (rx per
    round unchanged) and the estimates stay right. ``swarm drill delay 60``: 4 ticks, the same.
    ``swarm drill clear``: no delay."""
    try:
        for delay_ms in ("100", "60"):
            assert f"sent delay {delay_ms} ms" in flight.drill("delay", delay_ms)
            t0 = flight.pass_sim(1.0)  # the late messages' first rounds have paired
            flight.pass_sim(2.0)
            late = flight.between(t0, t0 + 2.0)
            rates = flight.rx_per_round(t0, t0 + 2.0)
            counts = [len(s.neighbours) for s in late]
            print(
                f"delay {delay_ms}: messages per round {rates}, neighbours per status mean "
                f"{np.mean(counts):.2f} min {min(counts)}"
            )
            assert all(7.5 < r < 8.5 for r in rates.values()), rates
            assert np.mean(counts) > 6.0 and min(counts) >= 4, counts
            assert all(s.mode == AgentMode.FLYING for s in late)
            assert all(within_bound(np.asarray(s.estimate), TRUTH) for s in late)
    finally:
        assert "sent clear" in flight.drill("clear")
    assert flight.wait_sim(lambda: _everyone_linked(flight), 3.0)
    assert _all_within(flight)


def _group_split(statuses: list[AgentStatus]) -> tuple[np.ndarray, np.ndarray]:
    """Per control round with every agent's status: how far apart the two groups' mean
    estimates are, and the largest disagreement within a group (each (R, 9), abs)."""
    by_round: dict[int, dict[int, np.ndarray]] = {}
    for s in statuses:
        by_round.setdefault(s.round, {})[s.drone] = np.asarray(s.estimate)
    between, within = [], []
    for est in (by_round[r] for r in sorted(by_round) if len(by_round[r]) == N):
        a, b = np.array([est[d] for d in GROUP_A]), np.array([est[d] for d in GROUP_B])
        between.append(np.abs(a.mean(axis=0) - b.mean(axis=0)))
        within.append(np.maximum(np.ptp(a, axis=0), np.ptp(b, axis=0)))
    return np.array(between), np.array(within)


def test_partition_splits_the_estimates_of_a_moving_swarm_and_heal_joins_them(
    flight: Flight,
) -> None:
    """``swarm drill partition --groups 0,1,2/3,4,5,6,7,8``: nobody has a neighbour in the other
    group and ``swarm status`` shows the groups' link quality fall (2 of 8 and 5 of 8 drones in
    range heard). The edge state across the cut is frozen (ALGORITHM.md §3 rule 4), so each
    group goes on estimating the whole swarm (not itself): while the swarm hovers, the estimates
    stay on the truth. Once it moves (``swarm move --north-m 2``), the groups' estimates split
    while each group agrees within itself; ``swarm drill partition --heal`` joins them again."""
    group = {d: set(GROUP_A if d in GROUP_A else GROUP_B) - {d} for d in range(N)}
    reply = flight.drill("partition", "--groups", "0,1,2/3,4,5,6,7,8")
    assert "sent partition 0,1,2/3,4,5,6,7,8" in reply
    try:
        assert flight.wait_sim(
            lambda: all(set(s.neighbours) == group[d] for d, s in flight.latest().items()), 3.0
        ), {d: s.neighbours for d, s in flight.latest().items()}
        t0 = flight.now()
        _, table = flight.status_table()
        hovering = flight.between(t0, flight.now())
        quality = {d: _percent(r["link"]) for d, r in table.items()}
        print(f"partition: link quality {quality}")
        assert all(q < 0.45 for d, q in quality.items() if d in GROUP_A), quality
        assert all(0.45 < q < 0.8 for d, q in quality.items() if d in GROUP_B), quality
        assert hovering and all(within_bound(np.asarray(s.estimate), TRUTH) for s in hovering)

        moved = flight.swarm("move", "--north-m", "2", "--duration-s", "4")
        assert moved.returncode == 0 and "accepted" in moved.stdout, moved.stdout + moved.stderr
        t1 = flight.now()
        flight.pass_sim(5.0)
        split = flight.between(t1, t1 + 5.0)
        assert all(set(s.neighbours) <= group[s.drone] for s in split)
        between, within = _group_split(split)
        centre_gap, length_gap = between[:, 0].max(), between[:, 6].max()
        print(
            f"partition while moving: groups' estimates apart up to {100 * centre_gap:.1f} cm "
            f"north, {length_gap:.3f} m^2 length variance; within a group median "
            f"{1000 * np.median(within[:, 0]):.2f} mm, {np.median(within[:, 6]):.4f} m^2"
        )
        assert centre_gap > 0.005 and length_gap > 0.05
        assert np.median(within[:, 0]) < 0.2 * centre_gap
        assert np.median(within[:, 6]) < 0.2 * length_gap
        assert all(s.mode == AgentMode.FLYING for s in split)
    finally:
        assert "sent partition healed" in flight.drill("partition", "--heal")
    assert flight.wait_sim(lambda: _everyone_linked(flight), 3.0)
    t2 = flight.pass_sim(3.0)
    between, _ = _group_split(flight.between(t2 - 1.0, t2))
    print(f"partition healed: groups apart {between.max(axis=0)[[0, 6]]} (north m, length m^2)")
    assert between[:, :3].max() < 0.002 and between[:, 6:].max() < 0.01
    moved_truth = descriptors(np.array(HOVER) + np.array([2.0, 0.0, 0.0]))
    assert all(within_bound(np.asarray(s.estimate), moved_truth) for s in flight.latest().values())


def test_crash_drops_the_vehicle_and_its_agent_the_others_fly_on(flight: Flight) -> None:
    """``swarm drill crash --drone 8``: the ground station stops its motors; its agent leaves the
    swarm (liveliness), nobody lists it any more, the eight others fly on."""
    reply = flight.drill("crash", "--drone", str(CRASHED))
    assert "drill crash: accepted" in reply and f"vehicle {CRASHED}" in reply
    assert flight.wait_sim(lambda: flight.seen.alive.get(CRASHED) is False, 3.0)
    others = [d for d in range(N) if d != CRASHED]
    assert flight.wait_sim(
        lambda: all(
            CRASHED not in flight.latest()[d].neighbours
            and len(flight.latest()[d].neighbours) == N - 2
            for d in others
        ),
        3.0,
    )
    # it fell: the ground station's last telemetry of it is on the ground (it then goes silent)
    assert flight.wait_sim(lambda: float(flight.status_table()[1][CRASHED]["z"]) > -0.5, 3.0)
    t, table = flight.status_table()
    print(f"crash: at t={t:.1f} row of {CRASHED}: {table[CRASHED]}")
    assert table[CRASHED]["alive"] == "no" and table[CRASHED]["armed"] == "no"
    assert all(table[d]["mode"] == "FLYING" and float(table[d]["z"]) < -2.5 for d in others)


def test_dropout_kills_the_agent_and_the_gcs_detects_it(flight: Flight) -> None:
    """``swarm drill dropout --drone 6``: the ground station has the process hosting drone 6's
    agent (all nine, by default; from swarm up's run file) kill that agent alone and logs
    dropout_detected; the seven others fly on, their process with them."""
    pid = json.loads((flight.report / "logs" / "run.json").read_text())["agents"][str(DROPPED)]
    reply = flight.drill("dropout", "--drone", str(DROPPED))
    assert "drill dropout: accepted" in reply and f"pid {pid}" in reply and "killed" in reply
    assert flight.wait_sim(lambda: flight.seen.alive.get(DROPPED) is False, 3.0)
    assert _running(pid)  # hosted: the process flies the others on
    assert flight.wait_sim(
        lambda: any(
            e["kind"] == "dropout_detected" and e["drone"] == DROPPED
            for e in read_events(flight.report / "events.jsonl")
        ),
        3.0,
    )
    survivors = [d for d in range(N) if d not in (CRASHED, DROPPED)]
    assert flight.wait_sim(
        lambda: all(len(flight.latest()[d].neighbours) == N - 3 for d in survivors), 3.0
    )
    assert all(flight.latest()[d].mode == AgentMode.FLYING for d in survivors)
    # typed again: refused, its agent is not running (logged as a refused drill)
    again = flight.swarm("drill", "dropout", "--drone", str(DROPPED))
    assert again.returncode == 1 and "not running" in again.stdout, again.stdout + again.stderr


def _running(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def test_gcs_restart_comes_back_and_the_swarm_flies_on(flight: Flight) -> None:
    """``swarm drill gcs-restart``: the ground station stops and swarm up starts it again; it
    answers ``swarm status`` with the simulated time carrying on and the seven survivors flying,
    and goes on from the current plan (the partition drill's move, plan 1): ``swarm hold``
    publishes plan 2."""
    t_before, _ = flight.status_table()
    assert "drill gcs-restart: accepted" in flight.drill("gcs-restart")
    survivors = [d for d in range(N) if d not in (CRASHED, DROPPED)]

    def back() -> bool:
        try:  # one ``swarm status`` a try (about a second of CPU each)
            t, table = flight.status_table()
        except AssertionError:  # no answer yet
            return False
        return t > t_before + 1.0 and all(table[d]["mode"] == "FLYING" for d in survivors)

    deadline = time.monotonic() + 90.0
    while not back():
        assert time.monotonic() < deadline and flight.proc.poll() is None, flight.output
        time.sleep(0.5)
    assert flight.proc.poll() is None  # swarm up kept the run going
    # the survivors' estimates re-converged on the seven of them (the table's error is against
    # the alive vehicles' true centre)

    def converged() -> bool:
        table = flight.status_table()[1]
        return all(float(table[d]["err"]) < 0.05 for d in survivors)

    assert flight.wait_sim(converged, 10.0), flight.swarm("status").stdout
    t, table = flight.status_table()
    errors = [table[d]["err"] for d in survivors]
    print(f"gcs-restart: at t={t:.1f} survivors' centre estimate errors (m) {errors}")
    held = flight.swarm("hold")
    assert held.returncode == 0 and "plan 2" in held.stdout, held.stdout + held.stderr


def test_the_logs_hold_every_drill_and_the_survivors_flew_to_the_end(flight: Flight) -> None:
    """Ctrl-C ends the run; the ground station's events.jsonl lists every drill in order, one
    crash (the drilled one), and flight.tlog covers the whole flight across the restart: the
    survivors at 3 m to the end, the crashed vehicle on the ground, the neighbour counts the
    agents logged changed with the drills, the restarted station flew the current plan."""
    flight.pass_sim(2.0)
    code = flight.stop()
    assert code == 1 and "swarm up: interrupted" in flight.output, flight.output
    events = read_events(flight.report / "events.jsonl")
    drills = [(e["drill"], e["accepted"]) for e in events if e["kind"] == "drill"]
    expected = [
        "link_cut",
        "link_cut",
        "clear",
        "loss",
        "clear",
        "delay",
        "delay",
        "clear",
        "partition",
        "partition",
        "crash",
        "dropout",
        "dropout",  # typed again: refused
        "gcs_restart",
    ]
    assert [d for d, _ in drills] == expected, drills
    assert [ok for _, ok in drills] == [True] * 12 + [False, True], drills  # 2nd dropout refused
    # the restarted station's clock carries on (vehicle and agent clocks may differ by a tick)
    times = [float(e["t_s"]) for e in events]
    assert all(b >= a - 0.5 for a, b in itertools.pairwise(times)), times
    cuts = [e for e in events if e["kind"] == "drill" and e["drill"] == "link_cut"]
    assert [(c["link"], c["one_way"], c["duration_s"]) for c in cuts] == [
        ([0, 1], False, 5.0),
        ([0, 1], True, None),
    ]
    kinds = [e["kind"] for e in events]
    metrics = json.loads((flight.report / "metrics.json").read_text())
    # the report's wall time is the whole run's, not the restarted station's alone
    started = next(e["wall_clock_s"] for e in events if e["kind"] == "run_start")
    restarted = next(e["wall_clock_s"] for e in events if e["kind"] == "gcs_restarted")
    assert metrics["wall_time_s"] > restarted - started, (metrics, started, restarted)
    assert kinds.count("gcs_stopped") == 1 and kinds.count("gcs_restarted") == 1
    assert metrics["plan_seq"] == 2  # the partition's move (1), the hold after the restart (2)
    assert sorted(d["sysid"] for d in metrics["drones_lost"]) == [DROPPED + 1, CRASHED + 1]
    assert {e["drone"] for e in events if e["kind"] == "crash"} == {CRASHED}
    assert any(e["kind"] == "dropout_detected" and e["drone"] == DROPPED for e in events)

    track = read_tlog(flight.report / "flight.tlog")
    assert sorted(track.vehicles) == list(range(1, N + 1))
    t_end = max(float(v.t_s[-1]) for v in track.vehicles.values())
    # the log's one hole is the restart: it opens where the station stopped (its length in
    # simulated seconds is the restart's wall time times the run's speed, several x in lockstep)
    t_stopped = next(float(e["t_s"]) for e in events if e["kind"] == "gcs_stopped")
    for d in (d for d in range(N) if d not in (CRASHED, DROPPED)):
        v = track.vehicles[d + 1]
        airborne = v.t_s > 15.0
        assert v.t_s[0] < 1.0 and v.t_s[-1] > t_end - 1.0, d
        holes = np.flatnonzero(np.diff(v.t_s) > 1.0)
        assert len(holes) <= 1 and all(abs(v.t_s[h] - t_stopped) < 1.0 for h in holes), (
            d,
            t_stopped,
            [(float(v.t_s[h]), float(v.t_s[h + 1])) for h in holes],
        )
        altitude = -v.position_ned_m[airborne, 2]
        assert altitude.min() > 2.5 and altitude.max() < 3.5, (d, altitude.min(), altitude.max())
    assert -track.vehicles[CRASHED + 1].position_ned_m[-1, 2] < 0.5
    # the restarted station flew the plan it found (the move 2 m north), not the scenario's: the
    # survivors' formation is centred there (the scenario's centre is 2 m south)
    alive = [d for d in range(N) if d not in (CRASHED, DROPPED)]
    end = track.resample(np.array([t_end - 0.5]), N)[0, alive]
    centre = end.mean(axis=0)
    assert abs(centre[0] - (TRUTH[0] + 2.0)) < 0.25 and abs(centre[1] - TRUTH[1]) < 0.25, centre
    # the dropped-out drone's vehicle was left to its failsafe: level hold, then it descends
    assert any(e["kind"] == "failsafe" and e["drone"] == DROPPED for e in events)
    assert -track.vehicles[DROPPED + 1].position_ned_m[-1, 2] < 2.0
    # the agents' own log of their neighbour counts saw the drills: none during delay 100, two
    # in group A during the partition, all eight when nothing is wrong
    counts = track.vehicles[1].status[:, 9]
    assert counts.max() == N - 1 and counts.min() == 0 and np.any(counts == 2)

"""The simulator's event loop: simulated time, telemetry out, MAVLink in, under either clock.

Each control tick ``k``: the world's state at ``k`` goes out as telemetry (each link at its own
rates, :mod:`sitl_sim.mavlink_edge.streams`); input is processed while the clock waits; then the
world steps to ``k + 1`` with the setpoints and commands received so far.

- ``realtime``: tick ``k + 1`` runs at its wall-clock deadline (:class:`sitl_sim.pacing.Pacer`).
- ``lockstep``: tick ``k + 1`` runs once every agent in the barrier has echoed tick ``k``
  (:mod:`sitl_sim.mavlink_edge.lockstep`); tick 0 waits up to the join timeout for the expected
  agents; while nobody holds the barrier, time runs paced as in realtime. While it waits, the
  current tick's state is re-sent to the awaited agents every :data:`RESEND_S` seconds (UDP may drop
  it), and a new agent address gets it at once.

The wall clock is injected (``time.monotonic`` by default) and only decides *when* things happen,
never *what*: in lockstep the telemetry depends on the seed and the agents' answers alone.

What the vehicles speak on the wire is the world's dialect (:mod:`sitl_sim.mavlink_edge.dialect`,
PX4 or ArduCopter), set up once here: the messages it builds its own way replace the PX4 builders,
and the barrier awaits an agent at a tick when the dialect's tick message (PX4: LOCAL_POSITION_NED,
ArduCopter: GLOBAL_POSITION_INT) of that tick went to it.
"""

from __future__ import annotations

import selectors
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from protocols.model.frames import FloatArray
from protocols.runtime.collector import flight_collector
from sitl_sim.mavlink_edge import map_telemetry, messages
from sitl_sim.mavlink_edge.commands import CommandHandler
from sitl_sim.mavlink_edge.dialect import sim_dialect
from sitl_sim.mavlink_edge.dispatch import Dispatcher, LinkSide
from sitl_sim.mavlink_edge.lockstep import LockstepBarrier
from sitl_sim.mavlink_edge.map_telemetry import MapFix
from sitl_sim.mavlink_edge.streams import (
    ACTUATOR_OUTPUT_STATUS,
    ATTITUDE,
    ATTITUDE_TARGET,
    EXTENDED_SYS_STATE,
    GLOBAL_POSITION_INT,
    GPS_RAW_INT,
    HEARTBEAT,
    HOME_POSITION,
    LOCAL_POSITION_NED,
    ODOMETRY,
    SYS_STATUS,
    StreamTable,
)
from sitl_sim.mavlink_edge.telemetry_out import TickTelemetry, warm
from sitl_sim.network import Network
from sitl_sim.pacing import Pacer, RateMeter
from sitl_sim.shard_sync import ShardSync
from sitl_sim.sim_config import ClockConfig
from sitl_sim.vehicle.autopilot import Severity, VehicleEvent
from sitl_sim.vehicle.tick_answers import AnswerStats, TickAnswers
from sitl_sim.vehicle.tunables import Tunables
from sitl_sim.vehicle.world import Snapshot, World

RESEND_S = 0.25
_MAX_WAIT_S = 0.05
_GCS = -1
_SHARDS = -2


@dataclass(frozen=True)
class Status:
    """One status line: simulated and wall time (s), real-time factor over the last interval,
    vehicles armed / flying / in failsafe / crashed, frames received, sent and rejected."""

    sim_s: float
    wall_s: float
    rtf: float
    armed: int
    flying: int
    failsafe: int
    crashed: int
    rx: int
    tx: int
    rejected: int
    lockstep_members: int | None
    #: realtime: share of the active agents' ticks answered in time, their worst lag (ms)
    in_time: float | None = None
    worst_lag_ms: float | None = None
    overloaded: bool = False


class SimServer:
    """Runs ``world`` behind ``network`` until :meth:`stop` or the clock's duration."""

    def __init__(
        self,
        world: World,
        tunables: Tunables,
        network: Network,
        clock: ClockConfig,
        wall_clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        on_status: Callable[[Status], None] | None = None,
        status_interval_s: float = 1.0,
        shard_sync: ShardSync | None = None,
    ) -> None:
        self.world, self.net, self.clock = world, network, clock
        #: lockstep across simulator shards (sitl_sim/shard_sync.py), None for a whole swarm
        self.shards = shard_sync
        self.wall, self.sleep = wall_clock, sleep
        self.on_status, self.status_interval_s = on_status, status_interval_s
        control_hz = world.config.control_hz
        n = world.n
        rates = network.config
        self.dialect = dialect = sim_dialect(world)
        self.agent = LinkSide(
            network.agent_channels,
            StreamTable(n, dialect.agent_rates(rates.agent_rates_hz), control_hz,
                        dialect.agent_phases),
        )  # fmt: skip
        self.gcs = LinkSide(
            network.gcs_channels,
            StreamTable(n, dialect.gcs_rates(rates.gcs_rates_hz), control_hz, dialect.gcs_phases),
        )
        lockstep = clock.mode == "lockstep"
        self.barrier = LockstepBarrier(clock.drop_timeout_s) if lockstep else None
        self.pacer = Pacer(1.0 / control_hz, clock.speedup)
        self.commands = CommandHandler(world, network.sysids, self.build, dialect.modes)
        self.answers = None if lockstep else TickAnswers(n, 1000.0 / control_hz)
        self.dispatch = Dispatcher(
            world, network.sysids, tunables, self.commands, self.agent, self.gcs,
            self.barrier, self.report, self._new_peer, self.answers, dialect.validate,
            dialect.on_heartbeat, dialect.quiet_unknown_params,
        )  # fmt: skip
        home = world.config.home
        self._builders: dict[int, Callable[[int], Any]] = {
            HEARTBEAT: lambda i: messages.heartbeat(world.autopilot, i),
            SYS_STATUS: lambda i: self.sys_status(i),
            ATTITUDE: lambda i: messages.attitude(self._snapshot, i),
            LOCAL_POSITION_NED: lambda i: messages.local_position_ned(self._snapshot, i),
            ATTITUDE_TARGET: lambda i: messages.attitude_target(world, i),
            ODOMETRY: lambda i: messages.truth_odometry(world, i),
            ACTUATOR_OUTPUT_STATUS: lambda i: messages.actuator_output_status(
                messages.time_usec(world), self._rotor_forces()[:, i]
            ),
            GLOBAL_POSITION_INT: lambda i: map_telemetry.global_position_int(
                self._snapshot, self._map_fix(), home, i
            ),
            GPS_RAW_INT: lambda i: map_telemetry.gps_raw_int(
                self._snapshot, self._map_fix(), world.config.position_noise_m, i
            ),
            HOME_POSITION: lambda i: map_telemetry.home_position(home, messages.time_usec(world)),
            EXTENDED_SYS_STATE: lambda i: map_telemetry.extended_sys_state(
                world.autopilot, self._snapshot, i
            ),
        }
        own = dialect.builders(self)
        self._builders.update(own)
        # the messages packed for every vehicle at once (the same bytes; not where the dialect
        # builds its own): sitl_sim/mavlink_edge/telemetry_out.py
        rows = {
            ATTITUDE: lambda: messages.attitude_rows(self._snapshot),
            LOCAL_POSITION_NED: lambda: messages.local_position_ned_rows(self._snapshot),
            ACTUATOR_OUTPUT_STATUS: lambda: messages.actuator_output_status_rows(
                messages.time_usec(world), self._rotor_forces()
            ),
            ATTITUDE_TARGET: lambda: messages.attitude_target_rows(world),
            GLOBAL_POSITION_INT: lambda: map_telemetry.global_position_int_rows(
                self._snapshot, self._map_fix(), home
            ),
        }
        warm()  # before the first tick: a first compile takes seconds
        self._telemetry = TickTelemetry(
            self._builders,
            {msg_id: build for msg_id, build in rows.items() if msg_id not in own},
        )
        #: the dialect's message that keys the barrier, and the tick's state re-sent
        self._tick_message = dialect.tick_message
        self._tick_state = dialect.tick_state
        if world.estimator is not None:  # the land detector's word first (sitl_sim/launch.py)
            self._tick_state = (EXTENDED_SYS_STATE, *self._tick_state)
        self._forces_tick = -1
        self._forces = np.zeros((4, n))
        self._snapshot: Snapshot = world.snapshot()
        self._fix: MapFix | None = None
        self._stopped = False
        self._load = 0.0
        self._idle_s = 0.0
        self._last_status_wall = 0.0
        self._selector: selectors.BaseSelector | None = None

    # -- public --------------------------------------------------------------------------------
    def stop(self) -> None:
        """Ask the loop to end (safe from a signal handler); it returns within ~50 ms."""
        self._stopped = True

    def build(self, i: int, msg_id: int) -> Any | None:
        """Streamed message ``msg_id`` of vehicle ``i`` now, None if not streamable."""
        builder = self._builders.get(msg_id)
        return None if builder is None else builder(i)

    def snapshot(self) -> Snapshot:
        """Every vehicle's telemetry at the current tick."""
        return self._snapshot

    def map_fix(self) -> MapFix:
        """Every vehicle's geodetic position at the current tick (computed once per tick)."""
        return self._map_fix()

    def sys_status(self, i: int, prearm_ok: bool | None = None) -> Any:
        """Vehicle ``i``'s SYS_STATUS now (``prearm_ok``:
        :func:`sitl_sim.mavlink_edge.messages.sys_status`)."""
        world = self.world
        counters = self.dispatch.counters[i]
        return messages.sys_status(
            world.autopilot, i, counters, self._load, world.battery, prearm_ok
        )

    def report(self, events: list[VehicleEvent]) -> None:
        """Send each event as a STATUSTEXT on every link of its vehicle, then a HEARTBEAT of
        each vehicle concerned: an event may have changed its armed state or mode (armed,
        landed, crashed, failsafe), which its agent and the GCS then learn at once rather than
        at the next 1 Hz heartbeat (a crashed vehicle may go silent before it)."""
        silent = self.world.autopilot.silent
        concerned: list[int] = []
        for event in events:
            if silent[event.vehicle]:
                continue
            msg = messages.statustext(int(event.severity), event.text)
            for side in (self.agent, self.gcs):
                channel = side.channels[event.vehicle]
                if channel.active:
                    channel.send(msg)
            if event.vehicle not in concerned:
                concerned.append(event.vehicle)
        for i in concerned:
            beat = self._builders[HEARTBEAT](i)
            for side in (self.agent, self.gcs):
                if side.channels[i].active:
                    side.channels[i].send(beat)

    def run(self) -> None:
        """Run until stopped or ``clock.duration_s`` of simulated time has passed."""
        with selectors.DefaultSelector() as selector:
            self._selector = selector
            for i, endpoint in enumerate(self.net.agent_endpoints):
                selector.register(endpoint.sock, selectors.EVENT_READ, i)
            if self.net.gcs_endpoint is not None:
                selector.register(self.net.gcs_endpoint.sock, selectors.EVENT_READ, _GCS)
            if self.shards is not None:
                selector.register(self.shards.sock, selectors.EVENT_READ, _SHARDS)
            try:
                with flight_collector():
                    self._loop()
            finally:
                self._selector = None

    # -- the loop ------------------------------------------------------------------------------
    def _loop(self) -> None:
        start = self.wall()
        self._last_status_wall = start
        meter = RateMeter(self.world.t_s, start)
        next_status = start + self.status_interval_s
        self.pacer.rebase(self.world.tick, start)
        sent_to = self._emit()
        if self.answers is not None:
            self.answers.sent(self.world.tick, sent_to)
        join_deadline = start + self.clock.join_timeout_s
        if self.barrier is None and self.clock.start_at_unix_s is not None:
            # a shard of a swarm: tick 0 at the agreed wall-clock time (sitl_sim/shard.py)
            self._poll_until(self.wall() + self.clock.start_at_unix_s - time.time())
            start = self.wall()
            meter = RateMeter(self.world.t_s, start)
            self.pacer.rebase(self.world.tick, start)
        elif self.barrier is None and self.clock.wait_agents > 0:
            self._await_agents(join_deadline)
            start = self.wall()
            meter = RateMeter(self.world.t_s, start)
            self.pacer.rebase(self.world.tick, start)
        while not self._stopped and not self._done():
            if self.barrier is None:
                self._poll_until(self.pacer.deadline(self.world.tick + 1))
            else:
                self.barrier.open_tick(self.world.tick, sent_to, self.wall())
                self._await_barrier(join_deadline)
                if self.shards is not None:
                    self._await_shards()
            if self._stopped:
                break
            self._step()
            sent_to = self._emit()
            if self.answers is not None:
                self.answers.sent(self.world.tick, sent_to)
            now = self.wall()
            self.pacer.keep_up(self.world.tick, now)
            if now >= next_status:
                self._status(meter, now, start)
                next_status = now + self.status_interval_s
        self.net.flush()

    def _done(self) -> bool:
        duration = self.clock.duration_s
        return duration is not None and self.world.t_s >= duration - 1e-9

    def _step(self) -> None:
        events = self.world.step()
        if events:
            self.report(events)
        if self.barrier is not None and self.barrier.members:
            # a crashed vehicle leaves the barrier at once: nobody waits for a wreck's agent
            crashed = self.world.autopilot.crashed
            for i in [m for m in self.barrier.members if crashed[m]]:
                self.barrier.leave(i)

    def _await_barrier(self, join_deadline: float) -> None:
        """Process input until the barrier lets tick ``k + 1`` run."""
        assert self.barrier is not None
        barrier, tick = self.barrier, self.world.tick
        next_resend = self.wall() + RESEND_S
        while not self._stopped:
            now = self.wall()
            dropped = barrier.expire(now)
            if dropped:
                self._dropped(dropped)
            joining = tick == 0 and len(barrier.members) < self.clock.wait_agents
            if joining and now < join_deadline:
                wait_until = join_deadline
            elif barrier.members:
                if barrier.complete:
                    return
                wait_until = barrier.deadline_wall_s() or now
            else:
                deadline = self.pacer.deadline(tick + 1)
                if now >= deadline:
                    return
                wait_until = deadline
            if now >= next_resend:
                self._resend(barrier.awaiting if barrier.members and not joining else None)
                next_resend = now + RESEND_S
            self._poll(min(wait_until, next_resend) - now)

    def _await_shards(self) -> None:
        """Lockstep across shards: announce this tick, then serve input until every other shard
        holds it too (sitl_sim/shard_sync.py)."""
        assert self.shards is not None
        tick = self.world.tick
        while not self._stopped:
            self.shards.announce(tick)
            if self.shards.ready(tick):
                return
            self._poll(0.01)

    def _await_agents(self, deadline: float) -> None:
        """Realtime: hold tick 0 (re-sending its state) until ``wait_agents`` agents have spoken
        or the join timeout passes, so that a swarm's plan starts when its agents are there."""
        next_resend = self.wall()
        while not self._stopped:
            now = self.wall()
            spoken = sum(1 for ch in self.agent.channels if ch.active)
            if spoken >= self.clock.wait_agents or now >= deadline:
                return
            if now >= next_resend:
                self._resend(None)
                next_resend = now + RESEND_S
            self._poll(min(deadline, next_resend) - now)

    def _agent_gone(self, vehicle: int) -> None:
        """Vehicle ``vehicle``'s agent closed its port (its process ended): nobody waits for it
        any more; it rejoins the barrier with its next echo, from whatever address."""
        text = "Agent gone: its port closed"
        if self.barrier is not None and vehicle in self.barrier.members:
            self.barrier.leave(vehicle)
            text = "Lockstep: agent gone, left the barrier"
        self.report([VehicleEvent(vehicle, Severity.WARNING, text)])
        self.net.flush()

    def _dropped(self, vehicles: list[int]) -> None:
        timeout = self.clock.drop_timeout_s
        text = f"Lockstep: agent silent {timeout:g} s, left the barrier"
        self.report([VehicleEvent(i, Severity.WARNING, text) for i in vehicles])
        self.net.flush()

    def _poll_until(self, deadline: float) -> None:
        """Realtime: sleep to ``deadline``, then act on everything received meanwhile (the
        physics only runs at tick boundaries, so reacting earlier would change nothing)."""
        while not self._stopped:
            remaining = deadline - self.wall()
            if remaining <= 0:
                self._poll(0.0)
                return
            t0 = self.wall()
            self.sleep(min(remaining, _MAX_WAIT_S))
            self._idle_s += self.wall() - t0

    def _poll(self, timeout: float) -> None:
        """Wait up to ``timeout`` s for input, act on every pending datagram, send the answers."""
        assert self._selector is not None
        t0 = self.wall()
        ready = self._selector.select(max(0.0, min(timeout, _MAX_WAIT_S)))
        self._idle_s += self.wall() - t0
        dispatch = self.dispatch
        for key, _ in ready:
            vehicle = key.data
            if vehicle == _SHARDS:
                assert self.shards is not None
                self.shards.receive()
            elif vehicle == _GCS:
                endpoint = self.net.gcs_endpoint
                assert endpoint is not None
                for data, _addr in endpoint.receive():
                    dispatch.gcs_datagram(data, endpoint.rx_codec)
            else:
                agent_endpoint = self.net.agent_endpoints[vehicle]
                for data, addr in agent_endpoint.receive():
                    dispatch.agent_datagram(vehicle, data, addr)
                if agent_endpoint.peer_gone:
                    agent_endpoint.peer_gone = False
                    self._agent_gone(vehicle)
        self.net.flush()

    # -- telemetry -----------------------------------------------------------------------------
    def _emit(self) -> list[int]:
        """Send the current tick's due telemetry; the vehicles whose agent got the tick's state."""
        world = self.world
        tick = world.tick
        self._snapshot = world.snapshot()
        silent = world.autopilot.silent
        self.agent.streams.shared.due(tick)
        self.gcs.streams.shared.due(tick)
        telemetry = self._telemetry
        telemetry.new_tick()
        sent_to = telemetry.send(self.agent, tick, silent, self._tick_message)
        self.net.flush()  # the agents' states leave first: in lockstep they wait for them
        telemetry.send(self.gcs, tick, silent, None)
        self.net.flush()
        return sent_to

    def _rotor_forces(self) -> FloatArray:
        """Rotor forces (4, N) N of the current tick, computed once per tick when first asked."""
        if self._forces_tick != self.world.tick:
            self._forces = messages.rotor_forces_n(self.world)
            self._forces_tick = self.world.tick
        return self._forces

    def _map_fix(self) -> MapFix:
        """Every vehicle's geodetic position at the current snapshot, converted once per tick."""
        if self._fix is None or self._fix.tick != self._snapshot.tick:
            self._fix = MapFix(self.world.config.home, self._snapshot)
        return self._fix

    def _new_peer(self, i: int) -> None:
        """A new agent address: give it the heartbeat and the current tick's state now."""
        channel = self.agent.channels[i]
        for msg_id in (HEARTBEAT, *self._tick_state):
            channel.send(self._builders[msg_id](i))

    def _resend(self, vehicles: set[int] | None) -> None:
        """Re-send the current tick's state to ``vehicles`` (None: every agent we know)."""
        silent = self.world.autopilot.silent
        targets = range(self.world.n) if vehicles is None else sorted(vehicles)
        for i in targets:
            channel = self.agent.channels[i]
            if channel.active and not silent[i]:
                for msg_id in self._tick_state:
                    channel.send(self._builders[msg_id](i))
        self.net.flush()

    # -- status --------------------------------------------------------------------------------
    def _status(self, meter: RateMeter, now: float, start: float) -> None:
        interval = max(now - self._last_status_wall, 1e-9)
        self._last_status_wall = now
        self._load = max(0.0, min(1.0, 1.0 - self._idle_s / interval))
        self._idle_s = 0.0
        rtf = meter.sample(self.world.t_s, now)
        stats = None if self.answers is None else self.answers.interval()
        if stats is not None:
            self._report_timing(stats)
        if self.on_status is not None:
            self.on_status(self.status(rtf, now - start, stats))

    def _report_timing(self, stats: AnswerStats) -> None:
        """Realtime: each active agent's share of ticks answered in time and worst lag to the
        GCS (NAMED_VALUE_FLOAT), and a STATUSTEXT on every link of a vehicle whose agent fell
        behind (:meth:`AnswerStats.late`), so that its failsafe, if it comes, is explained."""
        boot_ms = self.world.time_boot_ms()
        late: list[VehicleEvent] = []
        for i in np.flatnonzero(stats.active):
            share = stats.share(int(i))
            if share is None:
                continue
            lag_ms = stats.lag_ms(int(i))
            channel = self.gcs.channels[i]
            if channel.active:
                channel.send(messages.named_value(boot_ms, messages.AGENT_IN_TIME, share))
                channel.send(messages.named_value(boot_ms, messages.AGENT_LAG_MS, lag_ms))
            if stats.late(int(i)):
                text = f"Agent late: {share:.0%} of ticks in time, lag {lag_ms:.0f} ms"
                late.append(VehicleEvent(int(i), Severity.WARNING, text))
        if late:
            self.report(late)
        self.net.flush()

    def status(
        self, rtf: float = 0.0, wall_s: float = 0.0, stats: AnswerStats | None = None
    ) -> Status:
        """The counters now; ``stats``: the agents' timing of the last interval (realtime)."""
        ap = self.world.autopilot
        counters = [*self.dispatch.counters, self.dispatch.gcs_counters]
        tx = sum(c.tx for c in self.agent.channels) + sum(c.tx for c in self.gcs.channels)
        return Status(
            sim_s=self.world.t_s,
            wall_s=wall_s,
            rtf=rtf,
            armed=int(ap.armed.sum()),
            flying=int(ap.flying.sum()),
            failsafe=int(ap.failsafe.sum()),
            crashed=int(ap.crashed.sum()),
            rx=sum(c.rx for c in counters),
            tx=tx,
            rejected=sum(c.rejected for c in counters),
            lockstep_members=None if self.barrier is None else len(self.barrier.members),
            in_time=None if stats is None else stats.swarm_share,
            worst_lag_ms=None if stats is None else stats.worst_lag * stats.period_ms,
            overloaded=stats is not None and stats.overloaded,
        )

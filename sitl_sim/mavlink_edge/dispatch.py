"""Inbound MAVLink: route each received frame to its vehicle, check it, act on it, answer it.

- Agent endpoint of vehicle i: every frame is for vehicle i. The endpoint answers the address of
  the last valid frame. Frames addressed to another system count as wrong-target.
- GCS endpoint: frames are routed by ``target_system`` (0 = every vehicle; unknown ids count as
  wrong-target on the GCS link); frames without a target (HEARTBEAT, ...) are only counted.
- SET_ATTITUDE_TARGET must name the vehicle exactly; invalid setpoints are counted, never flown
  (the check is the dialect's, ``validate``: ArduCopter clamps the thrust to 0..1 first). On the
  agent link its ``time_boot_ms`` is the lockstep echo (:mod:`sitl_sim.mavlink_edge.lockstep`).
- COMMAND_LONG / COMMAND_INT get a COMMAND_ACK on the link they came on
(:mod:`sitl_sim.mavlink_edge.commands`),
  then any requested messages, then a STATUSTEXT with the reason of a refusal.
- The parameter protocol: PARAM_REQUEST_LIST, PARAM_REQUEST_READ, PARAM_SET -> PARAM_VALUE
  (a refused set answers the unchanged value and a STATUSTEXT saying why; a set of an unknown
  name gets the STATUSTEXT alone, or nothing where the dialect says so: ArduPilot ignores it).
- HEARTBEAT: only counted, unless the dialect watches them (``on_heartbeat(sender system id,
  vehicle)``, vehicle None for the GCS link: every vehicle): ArduCopter's GCS failsafe.
- TIMESYNC requests are answered with the simulated time (ns).
A crashed vehicle that went silent ignores everything.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from protocols.mavlink.conventions import AUTOPILOT_COMPID
from sitl_sim.mavlink_edge import messages
from sitl_sim.mavlink_edge.channel import Address, Channel, decode_datagram
from sitl_sim.mavlink_edge.commands import CommandHandler, CommandReply
from sitl_sim.mavlink_edge.lockstep import LockstepBarrier
from sitl_sim.mavlink_edge.messages import RxCounters
from sitl_sim.mavlink_edge.streams import StreamTable
from sitl_sim.vehicle.autopilot import Severity, VehicleEvent
from sitl_sim.vehicle.setpoint import AttitudeSetpoint, Rejection, validate_attitude_target
from sitl_sim.vehicle.tick_answers import TickAnswers
from sitl_sim.vehicle.tunables import SetStatus, Tunables
from sitl_sim.vehicle.world import World

#: A SET_ATTITUDE_TARGET's check: (quaternion w, x, y, z, thrust, type_mask) -> what to fly.
SetpointCheck = Callable[[Any, float, int], AttitudeSetpoint | Rejection]
#: A HEARTBEAT of system ``sysid`` reached vehicle ``i`` (None: every vehicle, the GCS link).
HeartbeatWatch = Callable[[int, int | None], None]


@dataclass
class LinkSide:
    """One kind of link (agent or GCS): every vehicle's channel on it and their schedules."""

    channels: list[Channel]
    streams: StreamTable


class Dispatcher:
    """Acts on received datagrams for every vehicle of ``world``.

    ``report`` sends vehicle events to every link; ``on_new_peer(i)`` is called when vehicle
    ``i``'s agent endpoint starts answering a new address; ``validate`` checks a setpoint (the
    dialect's; PX4's by default); ``on_heartbeat`` watches HEARTBEATs, ``quiet_unknown_params``
    ignores a PARAM_SET of an unknown name (module doc).
    """

    def __init__(
        self,
        world: World,
        sysids: Sequence[int],
        tunables: Tunables,
        commands: CommandHandler,
        agent: LinkSide,
        gcs: LinkSide,
        barrier: LockstepBarrier | None,
        report: Callable[[list[VehicleEvent]], None],
        on_new_peer: Callable[[int], None],
        answers: TickAnswers | None = None,
        validate: SetpointCheck = validate_attitude_target,
        on_heartbeat: HeartbeatWatch | None = None,
        quiet_unknown_params: bool = False,
    ) -> None:
        self.world = world
        self._validate = validate
        self._on_heartbeat = on_heartbeat
        self._quiet_unknown = quiet_unknown_params
        self.sysids = list(sysids)
        self.index_of = {sysid: i for i, sysid in enumerate(self.sysids)}
        self.tunables = tunables
        self.commands = commands
        self.agent, self.gcs = agent, gcs
        self.barrier = barrier
        self.answers = answers
        self.report = report
        self.on_new_peer = on_new_peer
        self.counters = [RxCounters() for _ in self.sysids]
        self.gcs_counters = RxCounters()
        self._handlers: dict[str, Callable[[int, Any, LinkSide, bool], None]] = {
            "SET_ATTITUDE_TARGET": self._setpoint,
            "COMMAND_LONG": self._command_long,
            "COMMAND_INT": self._command_int,
            "SET_MODE": self._set_mode,
            "PARAM_REQUEST_LIST": self._param_list,
            "PARAM_REQUEST_READ": self._param_read,
            "PARAM_SET": self._param_set,
            "TIMESYNC": self._timesync,
        }
        #: messages without a target the GCS link acts on (for every vehicle)
        self._untargeted: dict[str, Callable[[Any], None]] = {}
        if on_heartbeat is not None:
            self._handlers["HEARTBEAT"] = self._heartbeat
            self._untargeted["HEARTBEAT"] = lambda msg: on_heartbeat(msg.get_srcSystem(), None)

    # -- datagrams -----------------------------------------------------------------------------
    def agent_datagram(self, i: int, data: bytes, addr: Address) -> None:
        """A datagram on vehicle ``i``'s own port."""
        if self.world.autopilot.silent[i]:
            return
        endpoint = self.agent.channels[i].endpoint
        decoded = decode_datagram(endpoint.rx_codec, data)
        counters = self.counters[i]
        counters.malformed += decoded.malformed
        counters.signature_rejected += decoded.signature_rejected
        for msg in decoded.messages:
            target = getattr(msg, "target_system", None)
            if target is not None and target not in (0, self.sysids[i]):
                counters.wrong_target += 1
                continue
            if endpoint.peer != addr:  # answer whoever sent the last valid frame for us
                endpoint.peer = addr
                self.on_new_peer(i)
            counters.rx += 1
            handler = self._handlers.get(msg.get_type())
            if handler is not None:
                handler(i, msg, self.agent, True)

    def gcs_datagram(self, data: bytes, endpoint_rx_codec: Any) -> None:
        """A datagram on the GCS endpoint."""
        decoded = decode_datagram(endpoint_rx_codec, data)
        self.gcs_counters.malformed += decoded.malformed
        self.gcs_counters.signature_rejected += decoded.signature_rejected
        silent = self.world.autopilot.silent
        for msg in decoded.messages:
            target = getattr(msg, "target_system", None)
            handler = self._handlers.get(msg.get_type())
            if target is None or handler is None:
                self.gcs_counters.rx += 1
                if self._untargeted:
                    untargeted = self._untargeted.get(msg.get_type())
                    if untargeted is not None:
                        untargeted(msg)
                continue
            if target == 0:
                vehicles = [i for i in range(len(self.sysids)) if not silent[i]]
            elif target in self.index_of:
                vehicles = [] if silent[self.index_of[target]] else [self.index_of[target]]
            else:
                self.gcs_counters.wrong_target += 1
                continue
            for i in vehicles:
                self.counters[i].rx += 1
                handler(i, msg, self.gcs, False)

    # -- handlers: (vehicle, message, link it came on, from the agent endpoint) -----------------
    def _setpoint(self, i: int, msg: Any, side: LinkSide, from_agent: bool) -> None:
        if msg.target_system != self.sysids[i] or msg.target_component not in (0, AUTOPILOT_COMPID):
            self.counters[i].rx -= 1
            self.counters[i].wrong_target += 1
            return
        if from_agent:
            tick = self.world.tick_of_ms(int(msg.time_boot_ms))
            if self.barrier is not None:
                self.barrier.echo(i, tick)
            if self.answers is not None:
                self.answers.echo(i, tick)
        sp = self._validate(msg.q, msg.thrust, int(msg.type_mask))
        if isinstance(sp, Rejection):
            self.counters[i].setpoint_rejected += 1
            return
        self.world.autopilot.setpoint(i, sp, self.world.t_s)

    def _command_long(self, i: int, msg: Any, side: LinkSide, from_agent: bool) -> None:
        params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6)
        self._command(i, msg, (*params, msg.param7), side)

    def _command_int(self, i: int, msg: Any, side: LinkSide, from_agent: bool) -> None:
        params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.x, msg.y, msg.z)
        self._command(i, msg, params, side)

    def _command(self, i: int, msg: Any, params: Sequence[float], side: LinkSide) -> None:
        reply = self.commands.command(i, int(msg.command), params, side.streams)
        channel = side.channels[i]
        ack = messages.command_ack(
            int(msg.command), int(reply.outcome.result), msg.get_srcSystem(), msg.get_srcComponent()
        )
        channel.send(ack)
        self._finish(i, reply, channel)

    def _set_mode(self, i: int, msg: Any, side: LinkSide, from_agent: bool) -> None:
        reply = self.commands.set_custom_mode(i, int(msg.custom_mode))
        self._finish(i, reply, side.channels[i])

    def _finish(self, i: int, reply: CommandReply, channel: Channel) -> None:
        for extra in reply.messages:
            channel.send(extra)
        if reply.outcome.reason:
            channel.send(messages.statustext(Severity.WARNING, reply.outcome.reason))
        if reply.events:
            self.report(reply.events)

    def _heartbeat(self, i: int, msg: Any, side: LinkSide, from_agent: bool) -> None:
        assert self._on_heartbeat is not None
        self._on_heartbeat(msg.get_srcSystem(), i)

    def _param_list(self, i: int, msg: Any, side: LinkSide, from_agent: bool) -> None:
        for index in range(self.tunables.count):
            self._param_value(i, index, side.channels[i])

    def _param_read(self, i: int, msg: Any, side: LinkSide, from_agent: bool) -> None:
        index: int | None = int(msg.param_index)
        if index is None or index < 0:
            index = self.tunables.index_of(_param_name(msg.param_id))
        if index is not None and 0 <= index < self.tunables.count:
            self._param_value(i, index, side.channels[i])

    def _param_set(self, i: int, msg: Any, side: LinkSide, from_agent: bool) -> None:
        name = _param_name(msg.param_id)
        status = self.tunables.set(i, name, float(msg.param_value))
        channel = side.channels[i]
        if status == SetStatus.UNKNOWN and self._quiet_unknown:
            return
        if status != SetStatus.OK:
            channel.send(messages.statustext(Severity.WARNING, f"Param {name}: {status.value}"))
        index = self.tunables.index_of(name)
        if index is not None:
            self._param_value(i, index, channel)

    def _param_value(self, i: int, index: int, channel: Channel) -> None:
        tunables = self.tunables
        name, value = tunables.value(i, index)
        kind = tunables.param_type(index)
        channel.send(messages.param_value(name, value, index, tunables.count, kind))

    def _timesync(self, i: int, msg: Any, side: LinkSide, from_agent: bool) -> None:
        if int(msg.tc1) == 0:
            now_ns = self.world.tick * 1_000_000_000 // self.world.config.control_hz
            side.channels[i].send(messages.timesync(now_ns, int(msg.ts1)))


def _param_name(raw: Any) -> str:
    """A PARAM_* param_id (str or bytes, NUL-padded) as text."""
    if isinstance(raw, bytes | bytearray):
        raw = raw.decode("ascii", errors="replace")
    return str(raw).rstrip("\x00")

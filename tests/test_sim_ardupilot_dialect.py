"""``swarm sim --dialect ardupilot``: the simulator speaks ArduCopter's MAVLink
(sitl_sim/mavlink_edge/dialect.py, sitl_sim/vehicle/copter.py), and the default PX4 dialect is
unchanged.

Three layers: the ArduCopter flight core without sockets (the climb-rate reading, the angle boost,
arming and mode rules, GUID_TIMEOUT) against closed-form answers; a real ``swarm sim --dialect
ardupilot`` process in lockstep flown by a scripted pymavlink client (one flight, read by several
tests: readiness, modes, the climb-rate and thrust readings of SET_ATTITUDE_TARGET, parameters,
each vehicle's own origin, LAND); and the PX4 HEARTBEAT, on the wire and as bytes.
"""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"  # before any pymavlink import (DEPENDENCIES.md)

import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega
from pymavlink.dialects.v20 import common as mavlink

from protocols.mavlink.conventions import (
    EKF_BAD_FLAGS,
    EKF_READY_FLAGS,
    GPS_FIX_3D,
    GUID_OPTIONS_THRUST,
    MAV_AUTOPILOT_ARDUPILOTMEGA,
    MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
    MAV_MODE_FLAG_SAFETY_ARMED,
    MODE_HOLD,
    MSG_EKF_STATUS_REPORT,
    MSG_GPS_RAW_INT,
    MSG_SYS_STATUS,
    SYS_STATUS_PREARM_CHECK,
    CopterMode,
    Dialect,
)
from protocols.model.geodesy import GeoPoint, ned_to_geodetic
from sitl_sim.mavlink_edge import messages
from sitl_sim.mavlink_edge.dialect import CopterModes
from sitl_sim.physics.attitude_control import AttitudeGains
from sitl_sim.physics.vehicle_params import VehicleParams
from sitl_sim.vehicle.autopilot import Autopilot, AutopilotConfig, Mode, Result
from sitl_sim.vehicle.copter import (
    PREARM_TEXTS,
    READY_TEXT,
    CopterAutopilot,
    angle_boost,
    climb_rate_m_s,
)
from sitl_sim.vehicle.setpoint import AttitudeSetpoint, validate_attitude_target
from sitl_sim.vehicle.tunables import FleetAttitudeGains
from sitl_sim.vehicle.world import World, WorldConfig
from tests.sitl_client import HOST, MavPeer, free_udp_port, roll_quat, sim_process

ARM, SET_MODE, SET_INTERVAL = 400, 176, 511
CUSTOM = float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
GUIDED_NOGPS, BRAKE = int(CopterMode.GUIDED_NOGPS), int(CopterMode.BRAKE)
LAND = int(CopterMode.LAND)
CONTROL_HZ = 50


# -- the flight core, no sockets ---------------------------------------------------------------
@pytest.mark.parametrize(
    ("thrust", "climb_m_s"),
    [(0.5, 0.0), (1.0, 2.5), (0.0, -1.5), (0.6, 0.5), (0.25, -0.75), (1.7, 2.5), (-0.3, -1.5)],
)
def test_thrust_as_climb_rate(thrust: float, climb_m_s: float) -> None:
    """(t - 0.5) * 2 * WPNAV_SPEED_UP above 0.5, (0.5 - t) * 2 * WPNAV_SPEED_DN below (cm/s)."""
    got = climb_rate_m_s(np.array([thrust]), np.array([250.0]), np.array([150.0]))
    assert got[0] == pytest.approx(climb_m_s)


def test_angle_boost_divides_by_the_tilt_cosine_down_to_a_tenth() -> None:
    quats = np.array([roll_quat(0.0), roll_quat(math.radians(60)), roll_quat(math.radians(89))]).T
    boosted = angle_boost(np.array([0.3, 0.3, 0.05]), quats)
    np.testing.assert_allclose(boosted, [0.3, 0.6, 0.5], rtol=1e-12)


def test_copter_mode_numbers() -> None:
    modes = CopterModes()
    assert modes.mode_of_params(GUIDED_NOGPS, 0) == Mode.OFFBOARD
    assert modes.mode_of_params(LAND, 0) == Mode.LAND
    assert modes.mode_of_params(BRAKE, 0) == Mode.HOLD
    assert modes.mode_of_params(int(CopterMode.LOITER), 0) == Mode.HOLD
    denied = modes.mode_of_params(int(CopterMode.RTL), 0)
    assert isinstance(denied, str) and "RTL" in denied
    assert modes.params_of_custom(GUIDED_NOGPS) == (GUIDED_NOGPS, 0)


def _copter(n: int = 2, ready_s: float = 1.0) -> CopterAutopilot:
    return CopterAutopilot(n, AutopilotConfig(), np.zeros(n), 0.5, ready_s)


def test_arming_waits_for_the_ekf_and_an_armable_mode_not_for_setpoints() -> None:
    ap = _copter()
    ap.update(0.0, np.zeros(2), np.zeros(2))
    assert ap.set_mode(0, Mode.OFFBOARD, 0.0)[0].result == Result.ACCEPTED  # no setpoint stream
    outcome, events = ap.arm(0, 0.0)
    assert outcome.result == Result.FAILED and not ap.armed[0]
    assert [e.text for e in events] == list(PREARM_TEXTS)
    assert all(e.severity == 2 and e.text.startswith("PreArm: ") for e in events)
    mode_refused = ap.set_mode(1, Mode.LAND, 0.0)[0], ap.set_mode(1, Mode.HOLD, 0.5)[0]
    assert mode_refused[0].result == Result.ACCEPTED
    assert mode_refused[1].result == Result.FAILED and "requires position" in mode_refused[1].reason
    ready = ap.update(1.0, np.zeros(2), np.zeros(2))
    assert [(e.vehicle, e.text) for e in ready] == [(0, READY_TEXT), (1, READY_TEXT)]
    assert ap.update(1.02, np.zeros(2), np.zeros(2)) == []  # said once
    assert ap.arm(0, 1.0)[0].result == Result.ACCEPTED and ap.armed[0]
    outcome, events = ap.arm(1, 1.0)  # in LAND
    assert outcome.result == Result.FAILED and [e.text for e in events] == ["Arm: Mode not armable"]
    assert ap.set_mode(1, Mode.HOLD, 1.0)[0].result == Result.ACCEPTED  # BRAKE, now ready
    assert ap.arm(1, 1.0)[0].result == Result.FAILED


def test_guid_timeout_levels_and_holds_in_guided_nogps_without_a_failsafe() -> None:
    world = _world()
    ap = world.autopilot
    assert isinstance(ap, CopterAutopilot)
    _run(world, 1.0, None)  # EKF ready
    ap.set_mode(0, Mode.OFFBOARD, world.t_s)
    assert ap.arm(0, world.t_s)[0].result == Result.ACCEPTED
    _run(world, 3.0, 0.7)  # climb 1 m/s
    tilted = _setpoint(0.5, roll_quat(0.3))
    ap.setpoint(0, tilted, world.t_s)
    _run(world, 1.0, None)
    assert abs(world.snapshot().euler_rad[0][0] - 0.3) < 0.02  # still the last setpoint
    _run(world, 4.0, None)  # past GUID_TIMEOUT (3 s)
    z = -world.state[2, 0]
    _run(world, 2.0, None)
    assert ap.no_target[0] and ap.mode[0] == Mode.OFFBOARD and not ap.failsafe[0]
    assert abs(world.snapshot().euler_rad[0][0]) < 0.01  # level
    assert abs(-world.state[2, 0] - z) < 0.05 and -world.state[2, 0] > 2.0  # altitude held


def test_gcs_failsafe_lands_after_its_heartbeats_stop_and_clears_when_they_return() -> None:
    ap = _copter(3, ready_s=0.0)
    air, ground = np.array([-5.0, -5.0, 0.0]), np.zeros(3)
    ap.update(0.0, ground, np.zeros(3))
    for i in range(3):
        ap.set_mode(i, Mode.OFFBOARD, 0.0)
        ap.arm(i, 0.0)
    ap.gcs_sysid[:] = [1, 2, 3]
    ap.fs_gcs_enable[:] = [5, 7, 5]
    ap.update(1.0, air, np.zeros(3))
    ap.heartbeat_from(9, 1.0)  # nobody's GCS
    assert ap.update(30.0, air, np.zeros(3)) == []  # never heard its GCS: no failsafe
    ap.heartbeat_from(1, 30.0, 0)
    ap.heartbeat_from(2, 30.0)
    ap.heartbeat_from(3, 30.0, 1)  # vehicle 3's GCS, but on vehicle 2's link: not its
    ap.heartbeat_from(3, 30.0, 2)
    assert ap.update(35.0, air, np.zeros(3)) == []  # 5 s: not yet (FS_GCS_TIMEOUT)
    z = np.array([-5.0, -5.0, 0.0])  # vehicle 3 on the ground
    events = ap.update(35.1, z, np.zeros(3))
    assert [(e.vehicle, e.severity, e.text) for e in events] == [
        (0, 4, "GCS Failsafe"), (0, 6, "Mode LAND"),
        (1, 4, "GCS Failsafe"), (1, 6, "Mode BRAKE"),
        (2, 4, "GCS Failsafe - Disarming"),
    ]  # fmt: skip
    assert list(ap.mode) == [Mode.LAND, Mode.HOLD, Mode.OFFBOARD] and list(ap.armed) == [1, 1, 0]
    assert ap.failsafe.all()
    assert ap.update(36.0, z, np.zeros(3)) == []  # said once
    ap.heartbeat_from(1, 36.0)
    cleared = ap.update(36.02, z, np.zeros(3))
    assert [(e.vehicle, e.text) for e in cleared] == [(0, "GCS Failsafe Cleared")]
    assert ap.mode[0] == Mode.LAND and not ap.failsafe[0]  # the mode stays


def test_climb_rate_flight_and_ground_idle() -> None:
    world = _world()
    ap = world.autopilot
    _run(world, 1.0, None)
    ap.set_mode(0, Mode.OFFBOARD, world.t_s)
    ap.arm(0, world.t_s)
    _run(world, 1.0, 0.5)  # climb 0 on the ground: idle, stays down
    assert world.state[2, 0] == 0.0 and world.guidance.thrust[0] == 0.0 and ap.armed[0]
    _run(world, 4.0, 0.6)
    rate = _climb(world, 2.0, 0.6)
    assert rate == pytest.approx(0.5, abs=0.02)
    _run(world, 3.0, 0.5)
    assert _climb(world, 2.0, 0.5) == pytest.approx(0.0, abs=0.01)
    # a tilted attitude at 0.5 still holds the altitude (the vertical loop, angle-boosted)
    _run(world, 2.0, 0.5, roll_quat(0.35))
    assert _climb(world, 2.0, 0.5, roll_quat(0.35)) == pytest.approx(0.0, abs=0.02)
    assert abs(world.state[4, 0]) > 1.0  # ... while it accelerates east


def test_thrust_reading_hovers_at_mot_thst_hover_at_any_tilt() -> None:
    world = _world(params=VehicleParams(thrust_coeff=VehicleParams().thrust_coeff * 1.25))
    ap = world.autopilot
    assert isinstance(ap, CopterAutopilot)
    hover = float(ap.hover_throttle[0])
    assert hover == pytest.approx(0.4)  # 1 / thrust-to-weight 2.5
    _run(world, 1.0, None)
    ap.set_mode(0, Mode.OFFBOARD, world.t_s)
    ap.arm(0, world.t_s)
    _run(world, 6.0, 0.6)  # climb to ~2.5 m, then hold
    _run(world, 4.0, 0.5)
    ap.guid_options[0] = GUID_OPTIONS_THRUST
    assert _climb(world, 1.0, hover) == pytest.approx(0.0, abs=0.03)
    assert _climb(world, 1.0, hover, roll_quat(0.4)) == pytest.approx(0.0, abs=0.05)
    # in the climb-rate reading the same 0.4 would sink at 0.3 m/s; as a thrust, 0.44 climbs
    vz0 = -world.state[5, 0]
    _run(world, 1.0, hover * 1.1)
    assert -world.state[5, 0] - vz0 == pytest.approx(0.1 * 9.81, rel=0.05)


def _world(n: int = 2, params: VehicleParams | None = None) -> World:
    starts = np.array([[0.0, 0.0, 0.0], [4.0, 3.0, 0.0]])[:n]
    config = WorldConfig(dialect=Dialect.ARDUPILOT, ekf_ready_s=1.0)
    gains = FleetAttitudeGains(AttitudeGains(), n)
    vehicle = params if params is not None else VehicleParams()
    return World(vehicle, gains, starts, np.zeros(n), config, np.random.default_rng(0))


def _setpoint(thrust: float, q: tuple[float, float, float, float] = (1.0, 0, 0, 0)) -> Any:
    sp = validate_attitude_target(q, thrust, 7)
    assert isinstance(sp, AttitudeSetpoint)
    return sp


def _run(
    world: World, seconds: float, thrust: float | None, q: tuple[float, ...] = (1.0, 0, 0, 0)
) -> None:
    """Step ``seconds``, vehicle 0 getting ``thrust`` at attitude ``q`` every tick (None: no
    setpoint)."""
    for _ in range(round(seconds * world.config.control_hz)):
        if thrust is not None:
            world.autopilot.setpoint(0, _setpoint(thrust, q), world.t_s)  # type: ignore[arg-type]
        world.step()


def _climb(
    world: World, seconds: float, thrust: float, q: tuple[float, ...] = (1.0, 0, 0, 0)
) -> float:
    """Vehicle 0's mean climb rate (m/s) over ``seconds`` at ``thrust``."""
    z0 = world.state[2, 0]
    _run(world, seconds, thrust, q)
    return float(z0 - world.state[2, 0]) / seconds


# -- a real simulator process, lockstep ---------------------------------------------------------
HOME = GeoPoint(-33.8568, 151.2153, 42.5)
START_NED = ((10.0, -20.0, 0.0), (14.0, -17.0, 0.0))
SCENARIO = f"""
version = 1
duration_s = 60.0
[home]
lat_deg = {HOME.lat_deg}
lon_deg = {HOME.lon_deg}
alt_m = {HOME.alt_m}
[vehicle]
thrust_to_weight = 2.5
{"".join(f"[[drones]]{chr(10)}position_ned_m = {list(p)}{chr(10)}" for p in START_NED)}
[[trajectory.waypoints]]
t_s = 0.0
centre_ned_m = [0.0, 0.0, -2.0]
variance_m2 = [0.0, 0.0, 0.0]
[safety]
min_separation_m = 0.0
"""
READY_S = 1.0
HOVER = 0.4  # MOT_THST_HOVER of thrust-to-weight 2.5


def _copter_peer(sysid: int, port: int) -> MavPeer:
    """An agent-side peer decoding ArduPilot's messages too (EKF_STATUS_REPORT is not in
    common.xml)."""
    peer = MavPeer(sysid, 191, (HOST, port))
    peer.mav = ardupilotmega.MAVLink(None, srcSystem=sysid, srcComponent=191)
    peer.mav.robust_parsing = True
    return peer


@dataclass
class Flight:
    """What the scripted flight saw: every message per vehicle (and at the GCS), each with the
    tick (``time_boot_ms``) of the last GLOBAL_POSITION_INT on its link before it (or its own),
    and the tick of each step of the script (``marks``)."""

    received: dict[int, list[tuple[int, Any]]] = field(default_factory=lambda: {1: [], 2: []})
    gcs: list[Any] = field(default_factory=list)
    marks: dict[str, int] = field(default_factory=dict)
    stdout: str = ""

    def timed(
        self, sysid: int, kind: str, since: str | None = None, until: str | None = None
    ) -> list[tuple[int, Any]]:
        """(tick, message) of ``kind`` from ``sysid``, between two marks (inclusive)."""
        lo = self.marks[since] if since else -1
        hi = self.marks[until] if until else 1 << 40
        return [(t, m) for t, m in self.received[sysid] if m.get_type() == kind and lo <= t <= hi]

    def of(
        self, sysid: int, kind: str, since: str | None = None, until: str | None = None
    ) -> list[Any]:
        return [m for _, m in self.timed(sysid, kind, since, until)]

    def texts(self, sysid: int) -> list[tuple[int, int, str]]:
        return [(t, m.severity, m.text) for t, m in self.timed(sysid, "STATUSTEXT")]

    def acks(self, sysid: int, command: int) -> list[tuple[int, int]]:
        return [(t, m.result) for t, m in self.timed(sysid, "COMMAND_ACK") if m.command == command]

    def position(self, sysid: int, at: str) -> Any:
        """Vehicle ``sysid``'s GLOBAL_POSITION_INT of the tick of mark ``at``."""
        ms = self.marks[at]
        return next(m for m in self.of(sysid, "GLOBAL_POSITION_INT") if m.time_boot_ms == ms)

    def altitude(self, sysid: int, at: str) -> float:
        """Height (m) above its home (``relative_alt``) at mark ``at``."""
        return float(self.position(sysid, at).relative_alt) / 1000.0


class Script:
    """Vehicle 1's agent in lockstep: each new tick (GLOBAL_POSITION_INT of vehicle 1) runs the
    steps due at that time (commands go before the echo, as an agent sends them), then echoes
    the tick with the current thrust. Vehicle 2's link only sends commands (never a setpoint)."""

    def __init__(self, one: MavPeer, two: MavPeer, flight: Flight) -> None:
        self.one, self.two, self.flight = one, two, flight
        self.thrust = 0.5
        self.steps: list[tuple[int, str, Callable[[], None]]] = []
        self.tick_ms = {1: -1, 2: -1}  # the last tick seen on each link

    def at(self, ms: int, mark: str, action: Callable[[], None] = lambda: None) -> None:
        self.steps.append((ms, mark, action))

    def thrust_at(self, ms: int, mark: str, thrust: float) -> None:
        self.at(ms, mark, lambda: setattr(self, "thrust", thrust))

    def connect(self, timeout_s: float = 20.0) -> None:
        """HEARTBEATs until both vehicles answer (the simulator may still be starting); what
        they send meanwhile is tick 0's. No setpoint yet."""
        end = time.monotonic() + timeout_s
        waiting = {1: self.one, 2: self.two}
        while waiting:
            assert time.monotonic() < end, f"vehicles {sorted(waiting)} silent"
            for sysid, peer in list(waiting.items()):
                peer.heartbeat()
                got = peer.poll(0.1)
                self.flight.received[sysid] += [(0, m) for m in got]
                if got:
                    del waiting[sysid]

    def run(self, timeout_s: float) -> None:
        """Fly until every step is done."""
        end = time.monotonic() + timeout_s
        self.steps.sort(key=lambda step: step[0])
        while self.steps:
            assert time.monotonic() < end, f"flight not done by tick {self.tick_ms[1]} ms"
            for msg in self.two.poll(0.0):
                self._seen(2, msg)
            for msg in self.one.poll(0.2):
                self._seen(1, msg)

    def _seen(self, sysid: int, msg: Any) -> None:
        assert msg.get_type() != "BAD_DATA", f"bad frame from vehicle {sysid}: {msg}"
        tick = self.tick_ms[sysid]
        if msg.get_type() == "GLOBAL_POSITION_INT" and msg.time_boot_ms > tick:
            tick = self.tick_ms[sysid] = int(msg.time_boot_ms)
            if sysid == 1:
                while self.steps and self.steps[0][0] <= tick:
                    _, mark, action = self.steps.pop(0)
                    self.flight.marks[mark] = tick
                    action()
                self.one.setpoint(1, tick, self.thrust)
        self.flight.received[sysid].append((max(tick, 0), msg))


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Flight]:
    tmp = tmp_path_factory.mktemp("ardupilot")
    scenario = tmp / "copter.toml"
    scenario.write_text(SCENARIO)
    gcs = MavPeer(255, 190, bind_port=free_udp_port())
    gcs.mav = ardupilotmega.MAVLink(None, srcSystem=255, srcComponent=190)
    gcs.mav.robust_parsing = True
    args = ("--scenario", str(scenario), "--dialect", "ardupilot", "--ekf-ready-s", str(READY_S),
            "--clock", "lockstep", "--gcs", f"udp:{HOST}:{gcs.port}",
            "--join-timeout", "30")  # fmt: skip
    result = Flight()
    with gcs, sim_process(tmp, *args) as sim:
        one = _copter_peer(1, sim.base_port)
        two = _copter_peer(2, sim.base_port + 1)
        with one, two:
            _fly(Script(one, two, result))
        result.gcs = gcs.collect(0.3)
        result.stdout = sim.stdout()
    yield result


def _fly(s: Script) -> None:
    """The flight (marks in ms of simulated time)."""
    one, two = s.one, s.two
    s.connect()
    s.flight.marks["start"] = 0
    # tick 0, before any setpoint: status streams asked for, GUIDED_NOGPS, arming refused (EKF)
    for peer, sysid in ((one, 1), (two, 2)):
        for msg_id in (MSG_EKF_STATUS_REPORT, MSG_GPS_RAW_INT, MSG_SYS_STATUS):
            peer.command(sysid, SET_INTERVAL, msg_id, 100_000)  # 10 Hz
        peer.command(sysid, SET_MODE, CUSTOM, GUIDED_NOGPS)
        peer.command(sysid, ARM, 1)
    # vehicle 2: its agent as its GCS, landing on silence (as the project's agents set it up),
    # and a name of ArduCopter 4.7 it does not have (ignored)
    for name, value, kind in (("SYSID_MYGCS", 2.0, mavlink.MAV_PARAM_TYPE_INT16),
                              ("FS_GCS_ENABLE", 5.0, mavlink.MAV_PARAM_TYPE_INT8),
                              ("MAV_GCS_SYSID", 2.0, mavlink.MAV_PARAM_TYPE_INT16)):  # fmt: skip
        two.send(two.mav.param_set_encode(2, 1, name.encode(), value, kind))
    ready_ms = round(READY_S * 1000) + 200
    # vehicle 2's command first: it is then in its socket whenever vehicle 1's echo is in its
    # own, so the simulator acts on it before it steps
    s.at(
        ready_ms, "ready", lambda: (two.heartbeat(), two.command(2, ARM, 1), one.command(1, ARM, 1))
    )
    s.at(9000, "gcs_back", two.heartbeat)  # 7.8 s after its last one
    s.thrust_at(1500, "climb", 0.6)  # a climb rate of 0.5 m/s
    s.at(4500, "climb_measure")
    s.thrust_at(6500, "climb_end", 0.5)  # hold
    s.at(9500, "hold_measure")

    def thrust_reading() -> None:  # GUID_OPTIONS bit 3, then MOT_THST_HOVER: 1 / 2.5
        one.send(one.mav.param_set_encode(1, 1, b"GUID_OPTIONS", 8.0, mavlink.MAV_PARAM_TYPE_INT32))
        s.thrust = HOVER

    s.at(11500, "hold_end", thrust_reading)
    s.thrust_at(12500, "hover_end", HOVER * 1.1)  # 0.1 g more than the weight
    s.thrust_at(13500, "boost_end", HOVER)
    s.at(13520, "land", lambda: one.command(1, SET_MODE, CUSTOM, LAND))
    s.at(23000, "landed")
    s.run(timeout_s=120.0)


flown = pytest.mark.timeout(180)


@flown
def test_heartbeat_is_ardupilot_in_brake_then_guided_nogps(flight: Flight) -> None:
    first = flight.of(1, "HEARTBEAT")[0]
    assert first.autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA
    assert first.type == mavlink.MAV_TYPE_QUADROTOR
    assert first.custom_mode == BRAKE and first.base_mode == MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert first.system_status == mavlink.MAV_STATE_STANDBY
    armed = [m for m in flight.of(2, "HEARTBEAT") if m.base_mode & MAV_MODE_FLAG_SAFETY_ARMED]
    assert armed and armed[0].custom_mode == GUIDED_NOGPS
    assert armed[0].base_mode == MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | MAV_MODE_FLAG_SAFETY_ARMED
    assert armed[0].system_status == mavlink.MAV_STATE_ACTIVE
    assert "dialect ardupilot (EKF ready after 1 s)" in flight.stdout


@flown
def test_arming_before_the_ekf_is_ready_fails_with_prearm_texts(flight: Flight) -> None:
    for sysid in (1, 2):
        assert flight.acks(sysid, SET_MODE)[0] == (0, mavlink.MAV_RESULT_ACCEPTED)
        assert flight.acks(sysid, ARM)[0] == (0, mavlink.MAV_RESULT_FAILED)
        prearm = [(t, sev) for t, sev, text in flight.texts(sysid) if text.startswith("PreArm: ")]
        assert prearm == [(0, mavlink.MAV_SEVERITY_CRITICAL)] * len(PREARM_TEXTS)


@flown
def test_readiness_shows_in_ekf_gps_and_sys_status(flight: Flight) -> None:
    ready_ms = round(READY_S * 1000)
    for sysid in (1, 2):
        ekf = flight.timed(sysid, "EKF_STATUS_REPORT")
        before = [m.flags for t, m in ekf if t < ready_ms - 20]
        after = [m.flags for t, m in ekf if t >= ready_ms]
        assert len(before) >= 8 and len(after) >= 8  # 10 Hz, as asked
        assert all(f & EKF_READY_FLAGS != EKF_READY_FLAGS for f in before)
        assert set(after) == {EKF_READY_FLAGS | 0x100 | 0x200}
        assert not EKF_READY_FLAGS & EKF_BAD_FLAGS
        fixes = [(t, m.fix_type) for t, m in flight.timed(sysid, "GPS_RAW_INT")]
        assert {f for t, f in fixes if t < ready_ms - 20} == {mavlink.GPS_FIX_TYPE_NO_FIX}
        assert {f for t, f in fixes if t >= ready_ms} == {GPS_FIX_3D}
        # SYS_STATUS: at the GCS from tick 0 (1 Hz), on the agent link from its next 1 Hz tick
        at_gcs = [
            m for m in flight.gcs if (m.get_type(), m.get_srcSystem()) == ("SYS_STATUS", sysid)
        ]
        asked = flight.of(sysid, "SYS_STATUS")
        for msg in (*at_gcs, *asked):
            assert msg.onboard_control_sensors_present & SYS_STATUS_PREARM_CHECK
            assert msg.onboard_control_sensors_enabled & SYS_STATUS_PREARM_CHECK
        assert not at_gcs[0].onboard_control_sensors_health & SYS_STATUS_PREARM_CHECK  # tick 0
        assert not at_gcs[0].onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_SENSOR_GPS
        for msg in (at_gcs[-1], *asked):  # the agent's first one is of the tick the EKF is ready
            assert msg.onboard_control_sensors_health & SYS_STATUS_PREARM_CHECK
        said = [(t, sev) for t, sev, text in flight.texts(sysid) if text == READY_TEXT]
        assert said == [(ready_ms - 20, mavlink.MAV_SEVERITY_INFO)]  # before the tick's state
    # the ground station gets the EKF's status by default (1 Hz)
    assert {m.get_srcSystem() for m in flight.gcs if m.get_type() == "EKF_STATUS_REPORT"} == {1, 2}


@flown
def test_guided_nogps_arms_without_setpoints(flight: Flight) -> None:
    ready = flight.marks["ready"]
    assert flight.acks(2, ARM)[-1] == (ready, mavlink.MAV_RESULT_ACCEPTED)  # never sent one
    assert flight.acks(1, ARM)[-1] == (ready, mavlink.MAV_RESULT_ACCEPTED)
    assert not any(t == ready for t, _, text in flight.texts(2) if text.startswith("PreArm"))


@flown
def test_every_tick_carries_attitude_and_both_positions(flight: Flight) -> None:
    ticks = sorted({m.time_boot_ms for m in flight.of(1, "GLOBAL_POSITION_INT")})
    assert ticks == list(range(0, ticks[-1] + 1, 1000 // CONTROL_HZ))  # lockstep on it
    attitude = {m.time_boot_ms for m in flight.of(1, "ATTITUDE")}
    local = {m.time_boot_ms for m in flight.of(1, "LOCAL_POSITION_NED")}
    assert set(ticks) <= attitude and set(ticks) <= local
    assert ticks[-1] >= flight.marks["landed"]


@flown
def test_thrust_is_a_climb_rate_by_default(flight: Flight) -> None:
    climbed = flight.altitude(1, "climb_end") - flight.altitude(1, "climb_measure")
    assert climbed / 2.0 == pytest.approx(0.5, abs=0.02)  # thrust 0.6: 0.2 * 2.5 m/s
    held = flight.altitude(1, "hold_end") - flight.altitude(1, "hold_measure")
    assert abs(held) < 0.03  # thrust 0.5
    assert flight.altitude(1, "hold_end") == pytest.approx(2.5, abs=0.15)


@flown
def test_guid_options_thrust_bit_makes_thrust_a_thrust(flight: Flight) -> None:
    values = flight.of(1, "PARAM_VALUE", since="hold_end")
    options = [m for m in values if m.param_id == "GUID_OPTIONS"]
    assert options and options[0].param_value == 8.0
    assert options[0].param_type == mavlink.MAV_PARAM_TYPE_INT32
    hovered = flight.altitude(1, "hover_end") - flight.altitude(1, "hold_end")
    assert abs(hovered) < 0.03  # MOT_THST_HOVER hovers (as a climb rate it would sink 0.3 m/s)
    # 10 % above the hover throttle: 0.1 g up for 1 s (as a climb rate: a sink of 0.18 m/s)
    gained = (flight.position(1, "hover_end").vz - flight.position(1, "boost_end").vz) / 100.0
    assert gained == pytest.approx(0.981, abs=0.03)


@flown
def test_land_lands_and_disarms_staying_in_land(flight: Flight) -> None:
    assert flight.acks(1, SET_MODE)[-1] == (flight.marks["land"], mavlink.MAV_RESULT_ACCEPTED)
    last = flight.of(1, "HEARTBEAT")[-1]
    assert last.custom_mode == LAND and not last.base_mode & MAV_MODE_FLAG_SAFETY_ARMED
    assert any(text == "Landed, disarmed" for _, _, text in flight.texts(1))
    assert flight.altitude(1, "landed") == pytest.approx(0.0, abs=0.01)


@flown
def test_each_vehicle_has_its_own_origin_and_its_true_place_on_the_map(flight: Flight) -> None:
    lat, lon, alt = ned_to_geodetic(HOME, np.array(START_NED))
    for sysid in (1, 2):
        local = flight.of(sysid, "LOCAL_POSITION_NED")[0]
        assert (local.x, local.y, local.z) == (0.0, 0.0, 0.0)
        where = flight.of(sysid, "GLOBAL_POSITION_INT")[0]
        i = sysid - 1
        assert (where.lat, where.lon) == (round(lat[i] * 1e7), round(lon[i] * 1e7))
        assert where.alt == round(alt[i] * 1000) and where.relative_alt == 0
    # vehicle 1 flew: its local position is its displacement from its own start
    ms = flight.marks["hold_end"]
    local = next(m for m in flight.of(1, "LOCAL_POSITION_NED") if m.time_boot_ms == ms)
    assert -local.z == pytest.approx(flight.altitude(1, "hold_end"), abs=1e-3)
    assert abs(local.x) < 0.05 and abs(local.y) < 0.05
    homes = {(m.get_srcSystem(), m.latitude, m.longitude, m.altitude)
             for m in flight.gcs if m.get_type() == "HOME_POSITION"}  # fmt: skip
    assert homes == {(i + 1, round(lat[i] * 1e7), round(lon[i] * 1e7), 42500) for i in range(2)}


@flown
def test_gcs_failsafe_on_the_wire(flight: Flight) -> None:
    """Vehicle 2 took its agent as its GCS (SYSID_MYGCS 2, FS_GCS_ENABLE 5), heard it at "ready",
    then nothing: 5 s later it failed safe (armed on the ground: disarm); a heartbeat at
    "gcs_back" cleared it, and 5 s of silence after it set it again (disarmed: no action)."""
    values = {m.param_id: m for m in flight.of(2, "PARAM_VALUE")}
    assert set(values) == {"SYSID_MYGCS", "FS_GCS_ENABLE"}  # MAV_GCS_SYSID: no answer
    assert values["SYSID_MYGCS"].param_value == 2.0
    assert values["SYSID_MYGCS"].param_type == mavlink.MAV_PARAM_TYPE_INT16
    assert values["FS_GCS_ENABLE"].param_value == 5.0
    assert values["FS_GCS_ENABLE"].param_type == mavlink.MAV_PARAM_TYPE_INT8
    assert not any("MAV_GCS_SYSID" in text for _, _, text in flight.texts(2))
    lost, back = flight.marks["ready"] + 5000, flight.marks["gcs_back"]
    warning = mavlink.MAV_SEVERITY_WARNING
    texts = [(t, sev, text) for t, sev, text in flight.texts(2) if "GCS" in text]
    assert texts == [
        (lost, warning, "GCS Failsafe - Disarming"),
        (back, warning, "GCS Failsafe Cleared"),
        (back + 5000, warning, "GCS Failsafe"),
    ]
    beats = flight.timed(2, "HEARTBEAT")
    during = [m for t, m in beats if lost < t < back]
    assert during and all(m.system_status == mavlink.MAV_STATE_CRITICAL for m in during)
    assert not any(m.base_mode & MAV_MODE_FLAG_SAFETY_ARMED for m in during)
    after = [m for t, m in beats if back < t < back + 5000]
    assert after and all(m.system_status == mavlink.MAV_STATE_STANDBY for m in after)
    assert all(m.custom_mode == GUIDED_NOGPS for m in (*during, *after))  # the mode stays


# -- the default dialect: PX4, unchanged ---------------------------------------------------------
#: The HEARTBEAT of a disarmed PX4 vehicle in AUTO.LOITER, system 1, sequence 0, as the simulator
#: sent it before dialects existed.
PX4_HEARTBEAT = bytes.fromhex("fd09000000010100000000000403020c1d03032dc7")


def test_px4_heartbeat_bytes_are_unchanged() -> None:
    ap = Autopilot(1, AutopilotConfig(), np.zeros(1))
    codec = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    assert bytes(messages.heartbeat(ap, 0).pack(codec)) == PX4_HEARTBEAT


@pytest.mark.timeout(60)
def test_px4_is_the_default_dialect_on_the_wire(tmp_path: Path) -> None:
    args = ("--drones", "1", "--clock", "lockstep", "--gcs", "none")
    with sim_process(tmp_path, *args) as sim, MavPeer(1, 191, (HOST, sim.base_port)) as agent:
        agent.connect()
        beat = agent.wait_for("HEARTBEAT", 10.0)
        local = agent.wait_for("LOCAL_POSITION_NED", 10.0)
        stdout = sim.stdout()
    assert beat.autopilot == mavlink.MAV_AUTOPILOT_PX4 and beat.custom_mode == MODE_HOLD
    assert beat.base_mode == 29 and beat.type == mavlink.MAV_TYPE_QUADROTOR
    assert local.time_boot_ms == 0
    assert "dialect px4" in stdout

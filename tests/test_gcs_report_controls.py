"""The ground station's report rebuilds thrust and moments from the rotor forces the simulator
streams (ACTUATOR_OUTPUT_STATUS) and shades link cuts: the allocation against the mixer and the
dynamics, the tlog reader, and ``build_record`` on logs written with known forces and drills."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from agent_harness import write_scenario

from gcs.report.events import EventLog
from gcs.report.flight_record import LinkFault
from gcs.report.log_record import build_record, drill_link_faults, membership
from gcs.report.tlog import TlogWriter, read_tlog
from gcs.station.drills import GcsDrills
from protocols.bus.memory import MemoryBus
from protocols.faults import Clear, LinkCut, LinkRestore, Partition
from protocols.model.frames import G_M_S2
from protocols.model.trajectory import DescriptorTrajectory
from protocols.scenario.scenario_file import load_scenario
from protocols.wire.fault import encode_fault
from protocols.wire.keys import SwarmKeys
from sitl_sim.mavlink_edge.messages import actuator_output_status
from sitl_sim.physics.dynamics import wrench_from_rotor_speeds
from sitl_sim.physics.mixer import mix, rotor_forces_from_wrench, wrench_from_rotor_forces
from sitl_sim.physics.vehicle_params import VehicleParams

PARAMS = [VehicleParams(), VehicleParams(mass_kg=0.8, arm_m=0.2, drag_coeff=2e-8)]
SWARM = "swarm"


@pytest.mark.parametrize("params", PARAMS)
def test_allocation_inverts_the_mixer_and_matches_the_dynamics(params: VehicleParams) -> None:
    rng = np.random.default_rng(7)
    n = 50
    f_max = params.rotor_force_max_n
    thrust = rng.uniform(1.5, 2.5, n) * f_max  # room left for the moments: no saturation
    moments = np.stack(
        [
            rng.uniform(-0.2, 0.2, n) * f_max * params.arm_m,
            rng.uniform(-0.2, 0.2, n) * f_max * params.arm_m,
            rng.uniform(-0.2, 0.2, n) * f_max * params.yaw_moment_per_thrust_m,
        ]
    )
    speeds = mix(thrust, moments, params)
    forces = params.thrust_coeff * speeds**2
    got_thrust, got_moments = wrench_from_rotor_forces(forces, params)
    np.testing.assert_allclose(got_thrust, thrust, rtol=1e-9)
    np.testing.assert_allclose(got_moments, moments, rtol=1e-7, atol=1e-12)
    dyn_thrust, dyn_moments = wrench_from_rotor_speeds(speeds, params)
    np.testing.assert_allclose(got_thrust, dyn_thrust, rtol=1e-12)
    np.testing.assert_allclose(got_moments, dyn_moments, rtol=1e-12, atol=1e-15)
    exact = rotor_forces_from_wrench(thrust, moments, params)
    np.testing.assert_allclose(exact, forces, rtol=1e-9)


def test_allocation_of_single_rotors_follows_the_stated_order() -> None:
    """Rotor 1 left, 2 front, 3 right, 4 back (body FRD); 1 and 3 yaw positive."""
    p = VehicleParams()
    thrust, moments = wrench_from_rotor_forces(np.eye(4), p)
    np.testing.assert_allclose(thrust, np.ones(4))
    d, k = p.arm_m, p.yaw_moment_per_thrust_m
    expected = np.array([[d, 0, -d, 0], [0, d, 0, -d], [k, -k, k, -k]])
    np.testing.assert_allclose(moments, expected)


def _write_flight(
    path: Path,
    forces_of: dict[int, list[float]],
    t_end_s: float = 4.0,
    rate_hz: float = 25.0,
) -> None:
    """Vehicles hovering at 1 m: state and constant rotor forces (N) of each system id."""
    with TlogWriter(path) as log:
        for k in range(round(t_end_s * rate_hz) + 1):
            t = k / rate_hz
            for sysid, forces in forces_of.items():
                pos = np.array([2.0 * sysid, 0.0, -1.0])
                log.write_vehicle_sample(t, sysid, pos, np.zeros(3), np.zeros(3), np.zeros(3))
                msg = actuator_output_status(round(t * 1e6), np.array(forces))
                log.write_message(t, sysid, msg)


def test_read_tlog_collects_rotor_forces_per_system(tmp_path: Path) -> None:
    path = tmp_path / "flight.tlog"
    with TlogWriter(path) as log:
        for t_us, f0 in ((40_000, 1.0), (0, 0.5), (20_000, 0.75)):  # out of order
            log.write_message(t_us * 1e-6, 3, actuator_output_status(t_us, np.array([f0, 2, 3, 4])))
        log.write_vehicle_sample(0.0, 1, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
    track = read_tlog(path)
    assert set(track.vehicles) == {1, 3}
    three = track.vehicles[3]
    np.testing.assert_allclose(three.actuator_t_s, [0.0, 0.02, 0.04])
    np.testing.assert_allclose(three.rotor_forces_n[:, 0], [0.5, 0.75, 1.0])
    np.testing.assert_allclose(three.rotor_forces_n[:, 1:], [[2, 3, 4]] * 3)
    assert three.t_s.size == 0 and three.position_ned_m.shape == (0, 3)
    one = track.vehicles[1]  # no actuator message: empty, well shaped
    assert one.actuator_t_s.shape == (0,) and one.rotor_forces_n.shape == (0, 4)


def _plan(scenario_path: Path) -> DescriptorTrajectory:
    return load_scenario(scenario_path).trajectory()


def test_build_record_rebuilds_thrust_and_moments(tmp_path: Path) -> None:
    scenario_path = write_scenario(
        tmp_path / "s.toml",
        [(0.0, 0.0, 0.0), (0.0, 3.0, 0.0), (4.0, 0.0, 0.0)],
        centre=(0.0, 0.0, -1.0),
        spread=(4.0, 4.0, 0.0),
        extra="[vehicle]\nmass_kg = 0.5\narm_m = 0.12\n",
    )
    scenario = load_scenario(scenario_path)
    weight = 0.5 * G_M_S2
    hover = [weight / 4] * 4
    rolled = [weight / 4 + 0.1, weight / 4, weight / 4 - 0.1, weight / 4]  # l = 0.2 D
    _write_flight(tmp_path / "flight.tlog", {1: hover, 2: rolled})
    record = build_record(
        tmp_path / "flight.tlog",
        tmp_path / "none.jsonl",
        _plan(scenario_path),
        3,
        25.0,
        10.0,
        scenario,
    )
    assert record is not None
    np.testing.assert_allclose(record.thrust_n[:, :2], weight, rtol=1e-6)
    np.testing.assert_allclose(record.moments_nm[:, 0], 0.0, atol=1e-7)
    rolled_moments = np.broadcast_to([0.2 * 0.12, 0.0, 0.0], record.moments_nm[:, 1].shape)
    np.testing.assert_allclose(record.moments_nm[:, 1], rolled_moments, atol=1e-6)
    assert not record.thrust_n[:, 2].any() and not record.moments_nm[:, 2].any()  # never heard
    assert record.link_faults == []


def test_build_record_without_actuator_messages_keeps_zeros(tmp_path: Path) -> None:
    scenario_path = write_scenario(
        tmp_path / "s.toml",
        [(0.0, 0.0, 0.0), (0.0, 3.0, 0.0)],
        centre=(0.0, 0.0, -1.0),
        spread=(1.0, 1.0, 0.0),
    )
    with TlogWriter(tmp_path / "flight.tlog") as log:
        for k in range(20):
            log.write_vehicle_sample(k / 10, 1, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
    record = build_record(
        tmp_path / "flight.tlog", tmp_path / "none.jsonl", _plan(scenario_path), 2, 10.0, 5.0
    )
    assert record is not None
    assert not record.thrust_n.any() and not record.moments_nm.any()


def _drill_events(tmp_path: Path, drills: list[tuple[float, object]]) -> Path:
    """``events.jsonl`` as the ground station writes it: each fault command published on the
    swarm's fault key and recorded by :class:`GcsDrills` at simulated time ``t_s``."""
    bus = MemoryBus()
    path = tmp_path / "events.jsonl"
    with EventLog(path) as events:
        drills_log = GcsDrills(bus.session(), SWARM, events, None)  # type: ignore[arg-type]
        key = SwarmKeys(SWARM, 1.0).fault
        for t_s, command in drills:
            bus.deliver(key, encode_fault(command, SWARM))  # type: ignore[arg-type]
            drills_log.drain(t_s)
        bus.deliver(key, b"garbage")  # a malformed command is logged, not a cut
        drills_log.drain(9.0)
        drills_log.close()
    return path


def test_link_cut_drills_and_scenario_cuts_are_shaded(tmp_path: Path) -> None:
    scenario_path = write_scenario(
        tmp_path / "s.toml",
        [(0.0, 0.0, 0.0), (0.0, 3.0, 0.0), (4.0, 0.0, 0.0)],
        centre=(0.0, 0.0, -1.0),
        spread=(4.0, 4.0, 0.0),
        extra='[[faults]]\nt_s = 0.5\nkind = "link_cut"\ndrones = [0, 2]\nduration_s = 1.0\n',
    )
    events = _drill_events(
        tmp_path,
        [
            (1.0, LinkCut(0, 1, one_way=False, duration_s=1.5)),  # ends by itself at 2.5
            (1.2, LinkCut(1, 2, one_way=True)),  # until restored at 2.0
            (2.0, LinkRestore(2, 1)),
            (2.4, LinkCut(0, 2)),  # until the clear at 3.0
            (2.6, Partition(((0,), (1, 2)))),  # not a link cut
            (3.0, Clear()),
            (3.5, LinkCut(1, 0)),  # until the end of the record (4 s)
        ],
    )
    _write_flight(tmp_path / "flight.tlog", {1: [0.0] * 4, 2: [0.0] * 4, 3: [0.0] * 4})
    record = build_record(
        tmp_path / "flight.tlog",
        events,
        _plan(scenario_path),
        3,
        25.0,
        8.0,
        load_scenario(scenario_path),
    )
    assert record is not None
    assert record.link_faults == [
        LinkFault(0.5, 1.5, 0, 2),  # the scenario's own
        LinkFault(1.0, 2.5, 0, 1),
        LinkFault(1.2, 2.0, 1, 2, one_way=True),
        LinkFault(2.4, 3.0, 0, 2),
        LinkFault(3.5, 4.0, 1, 0),
    ]


def test_drill_link_faults_ignores_refused_and_unknown_events() -> None:
    events = [
        {"t_s": 1.0, "kind": "drill", "drill": "link_cut", "link": [0, 1], "accepted": 0},
        {"t_s": 1.0, "kind": "drill", "drill": "link_cut", "what": "no link", "accepted": True},
        {"t_s": 1.0, "kind": "command", "command": "goto", "accepted": True},
        {"t_s": 1.5, "kind": "drill", "drill": "link_restore", "accepted": True},
        {"t_s": 2.0, "kind": "drill", "drill": "link_cut", "link": [3, 4], "one_way": True,
         "duration_s": 60.0, "accepted": True},
    ]  # fmt: skip
    assert drill_link_faults(events, 10.0) == [LinkFault(2.0, 10.0, 3, 4, one_way=True)]


def test_agent_statuses_and_membership_come_from_the_logs(tmp_path: Path) -> None:
    """The report needs nothing but the files: estimates and neighbour counts from the AGENT
    records of the tlog, membership from joins, drop-outs and crashes in events.jsonl."""
    scenario_path = write_scenario(
        tmp_path / "s.toml",
        [(0.0, 0.0, 0.0), (0.0, 3.0, 0.0), (4.0, 0.0, 0.0)],
        centre=(0.0, 0.0, -1.0),
        spread=(4.0, 4.0, 0.0),
    )
    estimate = np.arange(9.0)
    with TlogWriter(tmp_path / "flight.tlog") as log:
        for k in range(50):
            t = k / 10
            for sysid in (1, 2, 3):
                p = np.array([sysid, 0.0, -1.0])
                log.write_vehicle_sample(t, sysid, p, np.zeros(3), np.zeros(3), np.zeros(3))
                values = np.array([*estimate * sysid, 2.0, 3.0, 1.0])
                if not (sysid == 3 and t >= 2.0):  # agent 3 falls silent at 2 s
                    log.write_agent_status(t, sysid, values)
    with EventLog(tmp_path / "events.jsonl") as events:
        for i in range(3):
            events.record(0.0, "agent_joined", drone=i)
        events.record(1.5, "crash", drone=1, severity=0, text="crashed")
        events.record(2.5, "dropout_detected", drone=2)
        events.record(3.0, "agent_joined", drone=1)  # a crashed drone does not come back
        events.record(3.5, "agent_joined", drone=2)  # one whose agent left does (restarted)
        events.record(4.0, "dropout_detected", drone=2)
    track = read_tlog(tmp_path / "flight.tlog")
    assert track.vehicles[2].status.shape == (50, 12)
    np.testing.assert_allclose(track.vehicles[2].status[0, :9], estimate * 2)
    record = build_record(
        tmp_path / "flight.tlog", tmp_path / "events.jsonl", _plan(scenario_path), 3, 10.0, 4.9
    )
    assert record is not None
    t = record.t_s
    np.testing.assert_allclose(record.estimate[10, 1], estimate * 2)
    assert (record.neighbours[:, 0] == 2).all()
    assert np.isnan(record.estimate[t >= 3.05, 2]).all()  # silent for more than MAX_AGE_S
    assert record.lost_at_s == {1: 1.5, 2: 4.0}  # lost by the end: since the last absence
    assert record.returns == [(2, 2.5, 3.5)]
    assert record.member[:, 0].all()
    assert (record.member[:, 1] == (t < 1.5 - 1e-9)).all()
    gap = (t >= 2.5 - 1e-9) & (t < 3.5 - 5e-4)
    assert (record.member[:, 2] == ((t < 4.0 - 1e-9) & ~gap)).all()


def test_membership_ignores_events_without_a_valid_drone() -> None:
    t = np.arange(0.0, 1.0, 0.1)
    events = [
        {"t_s": 0.0, "kind": "agent_joined", "drone": 0},
        {"t_s": 0.0, "kind": "agent_joined", "drone": 7},
        {"t_s": 0.2, "kind": "crash", "drone": "x"},
        {"t_s": 0.3, "kind": "command", "accepted": True},
    ]
    alive, lost = membership(events, t, 2)
    assert alive[:, 0].all() and not alive[:, 1].any() and lost == {}

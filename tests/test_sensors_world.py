"""Sensors that lie, in the vehicle model (sitl_sim/vehicle/world.py): the telemetry and the
agents get each vehicle's state estimate (sitl_sim/vehicle/estimate.py), the physics and the
report the truth; a simulator shard's vehicles err as in the whole swarm's world; the tlog keeps
both (ODOMETRY for the truth) and reads the truth back as the track; a scenario's [sensors] is
checked like every section; the agents take the land detector's word on the ground where the
altitude wanders. The statistics of the model itself: tests/test_state_estimate_model.py; both
runners flying it bit for bit alike: tests/test_lockstep_vs_simulate.py."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from sitl_client import ROOT

from drone_agent.core.flight_phase import VehicleView
from gcs.report.tlog import TlogWriter, read_tlog, vehicle_samples
from protocols.scenario.scenario_file import ScenarioError, load_scenario
from sitl_sim.physics.attitude_control import AttitudeGains
from sitl_sim.physics.dynamics import POS
from sitl_sim.physics.vehicle_params import VehicleParams
from sitl_sim.vehicle.config import sensors
from sitl_sim.vehicle.estimate import Sensors
from sitl_sim.vehicle.tunables import FleetAttitudeGains
from sitl_sim.vehicle.world import World, WorldConfig

LYING = Sensors(gnss_bias_m=0.5, position_noise_m=0.02, attitude_noise_rad=0.01, latency_s=0.04)


def _world(n: int, config: WorldConfig) -> World:
    positions = np.array([(2.0 * i, 0.0, 0.0) for i in range(n)])
    return World(
        VehicleParams(),
        FleetAttitudeGains(AttitudeGains(), n),
        positions,
        np.zeros(n),
        config,
        np.random.default_rng(0),
    )


def test_ideal_sensors_report_the_truth_and_draw_nothing() -> None:
    world = _world(3, WorldConfig())
    assert world.estimator is None and world.estimate() is None
    world.step()
    snap = world.snapshot()
    assert np.array_equal(np.array(snap.position_ned_m), world.state[POS].T)


def test_the_telemetry_carries_the_estimate_and_the_state_stays_the_truth() -> None:
    world = _world(4, WorldConfig(sensors=LYING, sensors_seed=3))
    for _ in range(100):
        world.step()
    truth = world.state[POS].copy()
    estimate = world.estimate()
    assert estimate is not None
    snap = world.snapshot()
    assert np.array_equal(np.array(snap.position_ned_m), estimate[0].T)
    assert np.array_equal(np.array(snap.velocity_ned_m_s), estimate[1].T)
    # on the ground, at rest: the truth is where they stand, the estimate off by about the bias
    assert np.allclose(truth[2], 0.0, atol=1e-6)
    off = np.abs(estimate[0] - truth)
    assert off.max() > 0.05 and off.max() < 3.0, off


def test_a_shards_vehicles_err_as_in_the_whole_swarms_world() -> None:
    whole = _world(4, WorldConfig(sensors=LYING, sensors_seed=7))
    positions = np.array([(4.0, 0.0, 0.0), (6.0, 0.0, 0.0)])  # vehicles 2 and 3 of the four
    shard = World(
        VehicleParams(),
        FleetAttitudeGains(AttitudeGains(), 2),
        positions,
        np.zeros(2),
        WorldConfig(sensors=LYING, sensors_seed=7, first_vehicle=2),
        np.random.default_rng(0),
    )
    for _ in range(30):
        whole.step()
        shard.step()
        a, b = whole.estimate(), shard.estimate()
        assert a is not None and b is not None
        for mine, theirs in zip(a, b, strict=True):
            assert np.array_equal(mine[:, 2:], theirs)


def test_the_tlog_reads_the_truth_back_as_the_track_and_keeps_what_was_reported(
    tmp_path: Path,
) -> None:
    path = tmp_path / "flight.tlog"
    truth = np.array([1.0, 2.0, -3.0])
    believed = truth + np.array([0.4, -0.3, 0.2])
    with TlogWriter(path) as log:
        for k in range(5):
            t = 0.02 * k
            log.write_vehicle_sample(t, 1, believed, np.zeros(3), np.array([0.0, 0.0, 0.1]),
                                     np.zeros(3))  # fmt: skip
            log.write_truth(t, 1, truth, np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3))
    v = read_tlog(path).vehicles[1]
    assert np.allclose(v.position_ned_m, truth, atol=1e-6)
    assert np.allclose(v.reported_position_ned_m, believed, atol=1e-6)
    assert np.allclose(v.euler_rad, 0.0) and v.t_s.size == 5
    assert {k[0] for k in vehicle_samples(path)} == {"LOCAL_POSITION_NED", "ATTITUDE", "ODOMETRY"}


def test_a_log_without_the_truth_reads_as_before(tmp_path: Path) -> None:
    path = tmp_path / "flight.tlog"
    with TlogWriter(path) as log:
        log.write_vehicle_sample(0.0, 1, np.ones(3), np.zeros(3), np.zeros(3), np.zeros(3))
    v = read_tlog(path).vehicles[1]
    assert np.allclose(v.position_ned_m, 1.0) and v.reported_t_s.size == 0


def _scenario(tmp_path: Path, section: str) -> Path:
    text = (ROOT / "scenarios" / "tilt9.toml").read_text()
    path = tmp_path / "sensors.toml"
    path.write_text(text + "\n[sensors]\n" + section + "\n")
    return path


def test_the_sensors_section_is_read_and_checked(tmp_path: Path) -> None:
    s = load_scenario(_scenario(tmp_path, "gnss_bias_m = 1.5\nlatency_s = 0.1\nrate_hz = 10"))
    assert sensors(s) == Sensors(gnss_bias_m=1.5, latency_s=0.1, rate_hz=10.0)
    assert sensors(load_scenario(ROOT / "scenarios" / "paper.toml")).ideal
    for bad, field in (
        ("gnss_bias_m = -1", "gnss_bias_m"),
        ("latency_s = 2.0", "latency_s"),
        ("gnss_bias_tau_s = 0", "gnss_bias_tau_s"),
        ("position_noise_m = nan", "position_noise_m"),
        ("gps = 1", "gps"),
    ):
        with pytest.raises(ScenarioError, match=field):
            load_scenario(_scenario(tmp_path, bad))


def test_on_the_ground_the_land_detector_decides_not_a_wandering_altitude() -> None:
    def view(altitude: float, on_ground: bool | None, armed: bool = False) -> VehicleView:
        return VehicleView(armed, False, False, False, altitude, on_ground)

    assert not view(0.4, on_ground=True).airborne  # its estimate says 0.4 m: it stands
    assert view(0.0, on_ground=False).airborne  # its estimate says 0 m: it flies
    assert view(0.0, on_ground=True, armed=True).airborne  # armed: never cut its motors
    assert view(0.4, on_ground=None).airborne and not view(0.05, None).airborne  # no word


def _with_consensus(tmp_path: Path, sensors_section: str, settle: str | None) -> Path:
    path = _scenario(tmp_path, sensors_section)
    if settle is not None:
        text = path.read_text().replace("[consensus]\n", f'[consensus]\nsettle = "{settle}"\n', 1)
        path.write_text(text)
    return path


def test_noisy_sensors_take_off_once_the_disagreement_stops_falling(tmp_path: Path) -> None:
    """5 cm of position noise and 5 cm/s of velocity noise keep the disagreement at 10 to 25 %
    for ever: with the 2 % rule alone (``settle = "agree"``) the swarm never leaves the ground, and
    ``swarm scenario check`` says so naming [sensors] and the way out; by default (``"auto"``) the
    plateau rule lets it leave at the end of its warm-up, as ideal sensors do."""
    from gcs.reference.simulate import ready_time_s
    from gcs.report.scenario_summary import takeoff_lines

    noise = "position_noise_m = 0.05\nvelocity_noise_m_s = 0.05"
    agree = load_scenario(_with_consensus(tmp_path, noise, "agree"))
    assert agree.consensus.settle == "agree"
    assert ready_time_s(agree, 15.0) is None
    (line,) = takeoff_lines(agree, None, 15.0)
    assert "not ready to leave the ground within 15 s" in line and "[sensors]" in line
    assert 'settle = "auto"' in line
    auto = load_scenario(_with_consensus(tmp_path, noise, None))
    ideal_s = ready_time_s(load_scenario(ROOT / "scenarios" / "tilt9.toml"), 15.0)
    ready_s = ready_time_s(auto, 15.0)
    assert ideal_s is not None and ready_s is not None and ready_s <= ideal_s + 1.0, (
        ready_s,
        ideal_s,
    )
    (line,) = takeoff_lines(auto, ready_s, 15.0)
    assert "[sensors]" not in line and "WARNING" not in line, line
    with pytest.raises(ScenarioError, match=r"consensus\.settle.*auto, agree, plateau"):
        load_scenario(_with_consensus(tmp_path, noise, "soon"))


def test_an_undefined_landed_state_says_nothing() -> None:
    from pymavlink.dialects.v20 import common

    from drone_agent.process.vehicle_link import VehicleStatus

    assert VehicleStatus().on_ground is None
    assert VehicleStatus(landed_state=common.MAV_LANDED_STATE_UNDEFINED).on_ground is None
    assert VehicleStatus(landed_state=common.MAV_LANDED_STATE_ON_GROUND).on_ground is True
    assert VehicleStatus(landed_state=common.MAV_LANDED_STATE_IN_AIR).on_ground is False

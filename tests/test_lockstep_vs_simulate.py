"""The distributed lockstep flight is the in-process one: a 3 x 3 grid as a newcomer generates it
(2.5 m apart, radio range 6 m, take-off, 20 % loss, an agent drop-out), in a breeze with gusts
(wind, turbulence and the vehicles' drag: the air is one field for both runners) with vehicles
that differ (mass, thrust and motor time constant spread, drawn from the seed in both; motors that
lag, their rotor speeds state the simulator keeps) and sensors that lie (a
wandering GNSS bias, attitude noise, a 25 Hz estimate 40 ms late: each vehicle's own errors, drawn
from the seed in both) over a radio with limits (a bandwidth cap and its queue, loss with distance
and in bursts, latency and jitter: each link's own draws, in ``swarm simulate``'s radio and in each
agent's link layer), flown by ``swarm up --clock lockstep`` and by ``swarm simulate``, logs
the same LOCAL_POSITION_NED and ATTITUDE (what the vehicles believed) and ODOMETRY (their true
state) for every vehicle whose agent flies, field by field at every ``time_boot_ms``.

A square grid's estimated heading is ill-conditioned (its spreads are equal: any axes will do),
so the last bit of any input shows: both runners must give the agents the same inputs, and
``swarm simulate`` gives them what ``swarm agent`` gets (gcs/reference/flight.py): the vehicle's
state in the telemetry's float32, the tick's time as time_boot_ms / 1000 (not k * dt), the
membership view of the lockstep round gate (the agents that finished round k - 1: a drone that
drops out at k is a member at k), and its vehicles take the setpoints as the simulator does (the
agent's quaternion in SET_ATTITUDE_TARGET's float32). Without any one of these this flight is
0.1 to 3 mm apart, and the 100-drone grid's heading flipped by 90 degrees at take-off. The vehicles
are one model in both (sitl_sim/vehicle/world.py: ``swarm simulate`` flies the simulator's World),
so the dropped drone's own failsafe landing (altitude hold, land, disarm on touchdown) is the same
to the last bit too. One agent process (across processes, a consensus message lost by the transport
under load would show here too). About a minute."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from sitl_client import ENV, free_port_block, free_udp_port, swarm_command

from gcs.report.tlog import vehicle_samples
from protocols.bus.zenoh_bus import ZenohBus, ZenohSettings, free_loopback_endpoint
from protocols.faults import Dropout
from protocols.scenario.scenario_file import load_scenario

pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]
DURATION_S = 20.0  # take-off at 3.5 s, 20 % loss from 9.5 s, the drop-out at 11.5 s
#: a light breeze with gusts, the drag that lets the vehicles feel it, and vehicles that differ
WINDY = """
[vehicle]
drag_xy_per_s = 0.4
drag_z_per_s = 0.15
motor_tau_s = 0.03

[vehicles]
mass_spread = 0.02
thrust_spread = 0.01
motor_tau_spread = 0.2

[environment]
wind_ned_m_s = [1.5, 1.0, 0.0]
turbulence_m_s = 0.5
turbulence_scale_m = 15.0

[sensors]
gnss_bias_m = 0.1
gnss_bias_tau_s = 300.0
attitude_noise_rad = 0.002
rate_hz = 25.0
latency_s = 0.04

[radio]
bandwidth_bytes_s = 45000.0
queue_messages = 3
loss_half_m = 9.0
burst_fraction = 0.05
burst_length = 4.0
latency_s = 0.02
jitter_s = 0.02
"""


def _run(*args: str, cwd: Path) -> None:
    done = subprocess.run(list(args), capture_output=True, text=True, env=ENV, cwd=cwd, timeout=600)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]


@pytest.fixture(scope="module")
def rendezvous() -> Iterator[str]:
    """A Zenoh peer the agents and ground station meet at (not the default port: no lock)."""
    endpoint = free_loopback_endpoint()
    with ZenohBus.open(ZenohSettings(listen=(endpoint,))):
        yield endpoint


def test_lockstep_flight_is_the_in_process_flight(tmp_path: Path, rendezvous: str) -> None:
    scenario = tmp_path / "grid9.toml"
    _run(
        *swarm_command("scenario", "new", "--drones", "9", "--layout", "grid"),
        *("--spacing-m", "2.5", "--range-m", "6", "--template", "turn-and-stretch"),
        *("--faults", "dropout=1,crash=1,loss=0.2", "--name", "grid9", "--seed", "0"),
        *("-o", str(scenario)),
        cwd=tmp_path,
    )
    with scenario.open("a") as f:
        f.write(WINDY)
    (dropout,) = [f.drone for f in load_scenario(scenario).faults if isinstance(f, Dropout)]
    _run(
        *swarm_command(
            "simulate", str(scenario), "--report", "sim", "--no-plots", "--no-recording"
        ),
        *("--duration-s", str(DURATION_S)),
        cwd=tmp_path,
    )
    base, gcs_port = free_port_block(9), free_udp_port()
    _run(
        *swarm_command("up", str(scenario), "--clock", "lockstep", "--agents-per-process", "9"),
        *("--duration-s", str(DURATION_S), "--report", "up", "--no-plots", "--no-recording"),
        *("--base-port", str(base), "--gcs-port", str(gcs_port), "--swarm-id", "div"),
        *("--zenoh-connect", rendezvous),
        cwd=tmp_path,
    )
    # --no-plots --no-recording: the report's figures without its PNGs and flight.rrd
    files = {p.name for p in (tmp_path / "up").iterdir()}
    assert {"flight.tlog", "events.jsonl", "metrics.json", "trajectory.json"} <= files, files
    assert not {f for f in files if f.endswith((".png", ".rrd"))}, files
    sim = vehicle_samples(tmp_path / "sim" / "flight.tlog")
    up = vehicle_samples(tmp_path / "up" / "flight.tlog")
    both = sim.keys() & up.keys()
    # every vehicle, the whole flight (a ground station that starts late on a loaded machine
    # misses the first samples of its run)
    assert len(both) >= 0.95 * 2 * 9 * round(DURATION_S * 25), len(both)
    differ = sorted((k[2], k) for k in both if sim[k] != up[k])
    assert not differ, (len(differ), differ[:3], [(sim[k], up[k]) for _, k in differ[:1]])
    # the dropped drone's vehicle landed on its failsafe within the flight, and that landing was
    # compared: down from the plan's 3 m to the ground, disarmed there
    # (the vehicles' true state, ODOMETRY: their LOCAL_POSITION_NED is what their sensors say)
    dropped = sorted(
        (t, -v[2]) for (msg, sysid, t), v in sim.items()
        if msg == "ODOMETRY" and sysid == dropout + 1 and (msg, sysid, t) in up
    )  # fmt: skip
    assert max(up_m for _, up_m in dropped) > 2.5 and dropped[-1][1] < 0.01, dropped[-1]
    events = [json.loads(line) for line in (tmp_path / "sim" / "events.jsonl").open()]
    landed = [e for e in events if e["kind"] == "disarmed" and e.get("drone") == dropout]
    assert landed and landed[0]["t_s"] < DURATION_S - 1.0, landed
    # it flew: every drone but the dropped one above 1 m from 9.5 s (the plan's 3 m)
    heights = [
        -v[2]
        for (msg, sysid, t), v in sim.items()
        if msg == "ODOMETRY" and t > 9.5e3 and sysid != dropout + 1
    ]
    assert min(heights) > 1.0
    # the agents flew on their vehicles' estimates, not the truth: every vehicle's reported
    # position is off its true one (the GNSS bias, 0.1 m standard deviation a component)
    off = [
        max(abs(a - b) for a, b in zip(v[:3], sim[("ODOMETRY", sysid, t)][:3], strict=True))
        for (msg, sysid, t), v in sim.items()
        if msg == "LOCAL_POSITION_NED" and ("ODOMETRY", sysid, t) in sim
    ]
    assert len(off) >= 9 * 25 * (DURATION_S - 1.0) and np.median(off) > 0.02, np.median(off)

"""Drills against a running swarm (issue 5): ``swarm drill link-cut`` / ``clear`` on nine agents
on the ground, malformed fault payloads ignored, and ``swarm drill crash`` in a flying swarm."""

from __future__ import annotations

import hashlib
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from agent_harness import (
    GRID,
    SWARM,
    SwarmObserver,
    agent_process,
    observer,
    truth_of,
    within_bound,
    write_scenario,
)
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink
from sitl_client import (
    ENV,
    HOST,
    ROOT,
    MavPeer,
    free_port_block,
    free_udp_port,
    sim_process,
    swarm_command,
)

from gcs.report.events import read_events
from gcs.report.tlog import read_tlog
from protocols.bus.interface import Congestion
from protocols.wire.keys import SwarmKeys
from protocols.wire.status import AgentMode

pytestmark = pytest.mark.slow
TRUTH = truth_of(GRID)


def drill(endpoint: str, *args: str) -> subprocess.CompletedProcess[str]:
    """Run ``swarm drill ARGS`` against the swarm reachable at ``endpoint``."""
    return subprocess.run(
        swarm_command("drill", *args, "--swarm-id", SWARM, "--zenoh-connect", endpoint),
        capture_output=True,
        text=True,
        env=ENV,
        cwd=ROOT,
        timeout=30,
    )


def _all_within(obs: SwarmObserver) -> bool:
    st = obs.statuses()
    return len(st) == 9 and all(within_bound(np.asarray(s.estimate), TRUTH) for s in st.values())


def _linked(obs: SwarmObserver, i: int, j: int) -> tuple[bool, bool]:
    st = obs.statuses()
    return j in st[i].neighbours, i in st[j].neighbours


def test_link_cut_and_clear_on_the_ground_and_malformed_commands_are_ignored(
    tmp_path: Path,
) -> None:
    scenario = write_scenario(
        tmp_path / "ground.toml", GRID, centre=(3.0, 2.0, 0.0), spread=(2.45, 1.63, 0.0)
    )
    base = free_port_block(9)
    with (
        observer() as obs,
        sim_process(
            tmp_path, "--scenario", str(scenario), "--gcs", "none", "--quiet", base_port=base
        ),
        agent_process(
            tmp_path, "0-8", base, obs.zenoh_args, "--scenario", str(scenario), "--no-arm"
        ) as agents,
    ):
        assert obs.wait_until(lambda: _all_within(obs), 30.0)
        assert _linked(obs, 0, 4) == (True, True)

        done = drill(obs.endpoint, "link-cut", "0", "4")
        assert done.returncode == 0, done.stderr
        assert "link_cut 0<->4" in done.stdout
        # both ends stop integrating each other; everyone stays within the bound meanwhile
        cut_seen = False
        end = time.monotonic() + 8.0
        while time.monotonic() < end:
            st = obs.statuses()
            assert all(within_bound(np.asarray(s.estimate), TRUTH) for s in st.values())
            if _linked(obs, 0, 4) == (False, False):
                if cut_seen and time.monotonic() > end - 5.0:
                    break
                cut_seen = True
            time.sleep(0.1)
        assert cut_seen and _linked(obs, 0, 4) == (False, False)
        assert 1 in obs.statuses()[0].neighbours  # only that link is cut

        # malformed fault payloads: counted, logged, ignored; the agents keep running
        pub = obs.bus.publisher(SwarmKeys(SWARM, 1.0).fault, Congestion.BLOCK)
        for payload in (b"", b"\x51\x01\x04\x04test\x09", b"\x51\x01\x04\x04test\x01\x00", b"junk"):
            pub.put(payload)
        pub.close()

        done = drill(obs.endpoint, "clear")
        assert done.returncode == 0, done.stderr
        assert obs.wait_until(lambda: _linked(obs, 0, 4) == (True, True), 8.0)
        assert obs.wait_until(lambda: _all_within(obs), 5.0)
        assert agents.proc.poll() is None
        log = agents.log.read_text()
        assert "fault drill at t=" in log and "link_cut 0<->4" in log and ": clear" in log
        assert "4 malformed so far" in log, log[-2000:]


#: Five drones: a 4 m x 3 m rectangle and its centre.
FIVE = [(0.0, 0.0, 0.0), (0.0, 3.0, 0.0), (4.0, 0.0, 0.0), (4.0, 3.0, 0.0), (2.0, 1.5, 0.0)]
#: The vehicle an unsigned peer attacks in the signed flight (drone 3, system id 4).
ATTACKED = 3
#: SET_ATTITUDE_TARGET type_mask: body rates ignored.
NO_RATES = 0b111
#: MAV_CMD_COMPONENT_ARM_DISARM's param2 that forces a disarm in flight.
FORCE = 21196


def _attack_unsigned(peer: MavPeer, rounds: int = 15) -> int:
    """``peer``, a plain pymavlink peer (no key), sends the flying vehicle ``ATTACKED`` what would
    bring it down if accepted: zero-thrust setpoints and forced disarms. Returns the frames sent."""
    sysid = ATTACKED + 1
    for _ in range(rounds):
        peer.setpoint(sysid, 0, 0.0, type_mask=NO_RATES)
        peer.command(sysid, 400, 0, FORCE)  # MAV_CMD_COMPONENT_ARM_DISARM: disarm, forced
        time.sleep(0.02)
    return 2 * rounds


def _vehicle_frames(tlog: Path) -> list[Any]:
    """Every frame the simulator's vehicles (component 1) sent, as the ground station logged it."""
    log = mavutil.mavlink_connection(str(tlog), dialect="common")
    frames = []
    while (msg := log.recv_match()) is not None:
        if msg.get_type() != "BAD_DATA" and msg.get_srcComponent() == 1:
            frames.append(msg)
    log.close()
    return frames


def _signed_with(msg: Any, key: bytes) -> bool:
    """Whether ``msg`` is a MAVLink 2 frame carrying a valid signature made with ``key``."""
    buf = bytes(msg.get_msgbuf())
    flagged = buf[0] == mavlink.PROTOCOL_MARKER_V2 and buf[2] & mavlink.MAVLINK_IFLAG_SIGNED
    return bool(flagged) and hashlib.sha256(key + buf[:-6]).digest()[:6] == buf[-6:]


def test_crash_drill_in_a_flying_signed_swarm(tmp_path: Path) -> None:
    """The whole run signs its MAVLink (swarm up --signing-key): the agents' setpoints and the
    ground station's crash command are both accepted by the signing simulator, and signing is
    shown on: an unsigned peer's setpoints and disarms to a flying vehicle are rejected and
    counted as signature failures (SYS_STATUS), and every vehicle frame in flight.tlog is signed
    with the key."""
    key = tmp_path / "swarm.key"
    key.write_text("5a" * 32)
    scenario = write_scenario(
        tmp_path / "hover.toml",
        FIVE,
        centre=(2.0, 1.5, -3.0),
        spread=(2.0, 1.5, 0.0),
        duration_s=24.0,
        settle_s=8.0,
    )
    base, gcs_port = free_port_block(5), free_udp_port()
    report = tmp_path / "report"
    with observer() as obs, MavPeer(ATTACKED + 1, 191, (HOST, base + ATTACKED)) as attacker:
        proc = subprocess.Popen(
            swarm_command(
                # the scenario's 24 s on the wall clock: after t = 10 s the three drills below
                # (each a new process) reach the ground station before the run ends, however
                # slowly a loaded machine starts them (lockstep ran ahead of them on CI)
                *("up", str(scenario), "--report", str(report), "--clock", "realtime"),
                *("--no-plots", "--no-recording"),
                *("--base-port", str(base), "--gcs-port", str(gcs_port)),
                *("--swarm-id", SWARM, "--zenoh-connect", obs.endpoint),
                *("--signing-key", str(key)),
            ),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            env=ENV,
            cwd=ROOT,
        )
        try:
            flying = obs.wait_until(
                lambda: all(s.mode == AgentMode.FLYING and s.t_s > 10.0
                            for s in obs.statuses().values()) and len(obs.statuses()) == 5,
                90.0,
            )  # fmt: skip
            assert flying, {d: (s.mode, s.t_s) for d, s in obs.statuses().items()}
            sent = _attack_unsigned(attacker)
            # a link-fault drill the ground station records (clear: changes nothing in flight)
            clear = drill(obs.endpoint, "clear")
            assert clear.returncode == 0, clear.stderr
            crash = drill(obs.endpoint, "crash", "--drone", "1")
            assert crash.returncode == 0, crash.stdout + crash.stderr
            assert "accepted" in crash.stdout
            refused = drill(obs.endpoint, "crash", "--drone", "7")
            assert refused.returncode == 1 and "refused" in refused.stdout
            out, _ = proc.communicate(timeout=120)
            # nobody answered the unsigned peer: its frames did not make it the vehicle's agent
            answered = {m.get_type() for m in attacker.poll(0.0)}
            assert not answered, f"vehicle {ATTACKED + 1} answered an unsigned peer: {answered}"
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)
    text = out.decode(errors="replace")
    assert proc.returncode == 0, text
    events = read_events(report / "events.jsonl")
    drills = [e for e in events if e["kind"] == "drill"]
    assert [(d["drill"], d["accepted"]) for d in drills] == [
        ("clear", True),
        ("crash", True),
        ("crash", False),
    ], drills
    crashes = [e for e in events if e["kind"] == "crash" and e["drone"] == 1]
    assert crashes and crashes[0]["t_s"] >= drills[1]["t_s"] - 0.2  # vehicle vs agents' clock
    assert "Failure injected: all motors off" in crashes[0]["text"]
    track = read_tlog(report / "flight.tlog")
    # it fell: its last telemetry (it goes silent on the ground) is at most a fall step above it
    assert -track.vehicles[2].position_ned_m[-1, 2] < 0.5
    assert any("hit the ground" in e["text"] for e in crashes)
    # the others fly on: drone 1's agent leaves the swarm on its vehicle's EMERGENCY text
    assert all(-track.vehicles[s].position_ned_m[-1, 2] > 2.0 for s in (1, 3, 4, 5))
    assert [e["drone"] for e in events if e["kind"] == "crash"] == [1] * len(crashes)
    # signing was on: the vehicles' own counters (SYS_STATUS, logged by the ground station)
    # count the unsigned frames as rejected signature failures, on the attacked vehicle only
    frames = _vehicle_frames(report / "flight.tlog")
    status = {m.get_srcSystem(): m for m in frames if m.get_type() == "SYS_STATUS"}  # newest
    assert sorted(status) == [1, 2, 3, 4, 5], sorted(status)
    attacked = status[ATTACKED + 1]
    assert 0.9 * sent <= attacked.errors_count3 <= sent, (sent, attacked)
    assert attacked.errors_comm >= attacked.errors_count3
    assert all(m.errors_count3 == 0 for s, m in status.items() if s != ATTACKED + 1), status
    # ... and all its telemetry is signed with the run's key
    secret = bytes.fromhex(key.read_text())
    assert len(frames) > 1000 and all(_signed_with(m, secret) for m in frames)

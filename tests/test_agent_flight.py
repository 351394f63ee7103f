"""Agents flying their vehicles in the real simulator: a hover, then a SIGKILLed agent whose
vehicle failsafes and lands while the others re-converge on the survivors (issue 4)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from agent_harness import agent_process, observer, write_scenario
from sitl_client import MavPeer, free_port_block, free_udp_port, of_system, sim_process

from protocols.wire.status import AgentMode

pytestmark = pytest.mark.slow
SQUARE = [(0.0, 0.0, 0.0), (0.0, 3.0, 0.0), (4.0, 0.0, 0.0), (4.0, 3.0, 0.0)]


def test_sigkilled_agent_vehicle_failsafes_and_the_others_fly_on(tmp_path: Path) -> None:
    scenario = write_scenario(
        tmp_path / "hover.toml", SQUARE, centre=(2.0, 1.5, -2.0), spread=(2.0, 1.5, 0.0)
    )
    base = free_port_block(4)
    gcs = MavPeer(255, 190, bind_port=free_udp_port())
    seen: list[Any] = []

    def pump() -> None:
        seen.extend(gcs.poll(0.0))

    with (
        gcs,
        observer() as obs,
        sim_process(
            tmp_path,
            "--scenario",
            str(scenario),
            "--clock",
            "lockstep",
            "--wait-agents",
            "4",
            "--gcs",
            f"udp:127.0.0.1:{gcs.port}",
            "--quiet",
            base_port=base,
        ),
        agent_process(tmp_path, "0-2", base, obs.zenoh_args, "--scenario", str(scenario)),
        agent_process(tmp_path, "3", base, obs.zenoh_args, "--scenario", str(scenario)) as lone,
    ):

        def flying() -> bool:
            pump()
            st = obs.statuses()
            return (
                len(st) == 4
                and all(s.mode == AgentMode.FLYING for s in st.values())
                and all(s.t_s > 12.0 for s in st.values())
            )

        assert obs.wait_until(flying, 60.0), {d: s.mode for d, s in obs.statuses().items()}
        positions = _latest_positions(seen)
        assert all(-positions[sysid][2] > 1.5 for sysid in range(1, 5)), positions
        # the lone agent dies
        killed = time.monotonic()
        lone.kill()
        assert obs.wait_until(lambda: obs.alive.get(3) is False, 2.0)
        dropped = next(t for t, d, alive in obs.changes if d == 3 and not alive)
        assert dropped - killed < 0.5

        # its vehicle: failsafe, descends, lands and disarms; the others fly on
        def landed() -> bool:
            pump()
            beats = of_system(seen, 4, "HEARTBEAT")
            pos = _latest_positions(seen).get(4)
            return (
                bool(beats)
                and not beats[-1].base_mode & 128
                and pos is not None
                and (-pos[2] < 0.1)
            )

        assert obs.wait_until(landed, 60.0)
        texts = [m.text.lower() for m in of_system(seen, 4, "STATUSTEXT")]
        assert any("failsafe" in t for t in texts), texts

        def survivors_agree() -> bool:
            pump()
            pos = _latest_positions(seen)
            centre = np.mean([pos[s][:3] for s in (1, 2, 3)], axis=0)
            st = obs.statuses()
            return all(
                np.abs(np.asarray(st[d].estimate)[:3] - centre).max() < 0.05 for d in (0, 1, 2)
            )

        assert obs.wait_until(survivors_agree, 20.0)
        pos = _latest_positions(seen)
        assert all(-pos[s][2] > 1.5 for s in (1, 2, 3))


def _latest_positions(messages: list[Any]) -> dict[int, np.ndarray]:
    """Each vehicle's newest LOCAL_POSITION_NED (by time_boot_ms) as (x, y, z, t_ms)."""
    newest: dict[int, Any] = {}
    for m in messages:
        if m.get_type() == "LOCAL_POSITION_NED":
            old = newest.get(m.get_srcSystem())
            if old is None or m.time_boot_ms >= old.time_boot_ms:
                newest[m.get_srcSystem()] = m
    return {s: np.array([m.x, m.y, m.z, m.time_boot_ms]) for s, m in newest.items()}

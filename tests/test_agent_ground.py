"""Agents over real Zenoh with the real simulator, on the ground (not armed): convergence,
drop-outs, link faults, garbage, start order, hosting (issue 4)."""

from __future__ import annotations

import contextlib
import os
import struct
import threading
import time
from pathlib import Path

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
from sitl_client import free_port_block, sim_process

from protocols.bus.interface import Congestion
from protocols.wire.consensus_message import ConsensusMessage
from protocols.wire.format import encode_consensus
from protocols.wire.keys import SwarmKeys
from protocols.wire.status import AgentStatus, decode_statuses

pytestmark = pytest.mark.slow
TRUTH = truth_of(GRID)


def _scenario(tmp_path: Path, extra: str = "") -> Path:
    return write_scenario(
        tmp_path / "ground.toml",
        GRID,
        centre=(3.0, 2.0, 0.0),
        spread=(2.45, 1.63, 0.0),
        extra=extra,
    )


def _all_within(obs, drones: list[int], truth: np.ndarray) -> bool:
    st = obs.statuses()
    return all(d in st and within_bound(np.asarray(st[d].estimate), truth) for d in drones)


def test_nine_agents_converge_on_the_ground_and_survive_a_sigkill(tmp_path: Path) -> None:
    scenario = _scenario(tmp_path)
    base = free_port_block(9)
    with (
        observer() as obs,
        sim_process(
            tmp_path, "--scenario", str(scenario), "--gcs", "none", "--quiet", base_port=base
        ),
        contextlib.ExitStack() as stack,
    ):
        procs = {
            d: stack.enter_context(
                agent_process(
                    tmp_path, str(d), base, obs.zenoh_args, "--scenario", str(scenario), "--no-arm"
                )
            )
            for d in range(9)
        }
        # start-up (9 interpreters importing zenoh on 2 cores) is not the estimator's time:
        # the clock starts once every agent has joined and reported
        assert obs.wait_until(lambda: len(obs.statuses()) == 9, 30.0)
        joined_s = max(s.t_s for s in obs.statuses().values())
        # converged within 10 s of the vehicles' (simulated) time: the estimator's rounds run on
        # it; the wall-clock wait is only a cap for a loaded machine
        assert obs.wait_until(lambda: _all_within(obs, list(range(9)), TRUTH), 60.0), {
            d: np.round(s.estimate, 3) for d, s in obs.statuses().items()
        }
        assert min(s.t_s for s in obs.statuses().values()) - joined_s <= 10.0
        assert all(s.counters.rx > 0 for s in obs.statuses().values())
        # SIGKILL drone 4's agent: everyone drops it at once and re-converges on the survivors
        killed_at, killed_s = time.monotonic(), max(s.t_s for s in obs.statuses().values())
        procs[4].kill()
        assert obs.wait_until(lambda: obs.alive.get(4) is False, 5.0)
        dropped_at = next(t for t, d, alive in obs.changes if d == 4 and not alive)
        # its closed connection, not the liveliness lease (1 s) running out; a loaded machine
        # may take a few hundred ms to notice
        assert dropped_at - killed_at < 1.0
        survivors = [d for d in range(9) if d != 4]
        truth = truth_of([GRID[d] for d in survivors])
        assert obs.wait_until(lambda: _all_within(obs, survivors, truth), 30.0), {
            d: np.round(s.estimate, 3) for d, s in obs.statuses().items()
        }
        assert min(obs.statuses()[d].t_s for d in survivors) - killed_s <= 10.0
        assert all(4 not in obs.statuses()[d].neighbours for d in survivors)


class StatusLog:
    """Every status the agents publish (the observer keeps only the newest), by drone."""

    def __init__(self, obs: SwarmObserver) -> None:
        self._lock = threading.Lock()
        self.by_drone: dict[int, list[AgentStatus]] = {}
        self._sub = obs.bus.subscribe_callback(
            SwarmKeys.for_range(SWARM, 10.0).status_all(), self._on_status
        )

    def _on_status(self, _key: str, payload: bytes) -> None:
        with contextlib.suppress(ValueError):
            for status in decode_statuses(payload, SWARM):  # one, or a process's batch
                with self._lock:
                    self.by_drone.setdefault(status.drone, []).append(status)

    def since(self, t_s: float) -> dict[int, list[AgentStatus]]:
        """The statuses of simulated time ``t_s`` on."""
        with self._lock:
            return {d: [s for s in ss if s.t_s >= t_s] for d, ss in self.by_drone.items()}

    def close(self) -> None:
        self._sub.close()


def test_link_cut_loss_and_delay_leave_no_lasting_bias(tmp_path: Path) -> None:
    """From t = 0.5 s: link 0-4 cut, 5 % loss and 20 ms of delay on every link. The faults take
    effect (the cut pair never integrate each other, every other link does; lost messages make
    edges skip rounds) and leave no lasting bias."""
    faults = (
        '[[faults]]\nt_s = 0.5\nkind = "link_cut"\ndrones = [0, 4]\n\n'
        '[[faults]]\nt_s = 0.5\nkind = "loss"\nprobability = 0.05\n\n'
        '[[faults]]\nt_s = 0.5\nkind = "delay"\ndelay_ms = 20.0\n'
    )
    scenario = _scenario(tmp_path, faults)
    base = free_port_block(9)
    with (
        observer() as obs,
        sim_process(
            tmp_path,
            *("--scenario", str(scenario), "--gcs", "none", "--quiet"),
            *("--clock", "lockstep", "--wait-agents", "9"),
            base_port=base,
        ),
        agent_process(
            tmp_path, "0-8", base, obs.zenoh_args, "--scenario", str(scenario), "--no-arm"
        ),
    ):
        log = StatusLog(obs)
        assert obs.wait_until(lambda: _all_within(obs, list(range(9)), TRUTH), 30.0)
        # once settled it stays within the bound, and the error does not build up (no bias)
        errors = []
        end = time.monotonic() + 6.0
        while time.monotonic() < end:
            st = obs.statuses()
            assert all(within_bound(np.asarray(s.estimate), TRUTH) for s in st.values())
            errors.append(
                max(
                    float(np.abs(np.asarray(s.estimate)[[0, 1, 6, 7]] - TRUTH[[0, 1, 6, 7]]).max())
                    for s in st.values()
                )
            )
            time.sleep(0.1)
        assert np.mean(errors[-10:]) < 0.02
        log.close()
    # the faults took effect (statuses after the first second of simulated time)
    seen = log.since(1.0)
    assert sorted(seen) == list(range(9)) and min(len(ss) for ss in seen.values()) > 50
    for me, cut in ((0, 4), (4, 0)):
        lists = [set(s.neighbours) for s in seen[me]]
        assert not any(cut in n for n in lists), me  # the cut pair never integrate each other
        assert set().union(*lists) == set(range(9)) - {me, cut}  # every other link does
    # loss: a lost message makes its edge skip that round, so 5 % of the neighbour slots come up
    # empty on top of the rounds missed on a loaded machine (measured: 5.9-7.1 % with the loss,
    # 2.0-2.7 % without it, while another flight loaded the machine). The 20 ms delay is not
    # visible from outside; tests/test_reference_flight.py shows it delays every message.
    expected = skipped = 0
    for me, statuses in seen.items():
        others = set(range(9)) - {me} - ({4} if me == 0 else {0} if me == 4 else set())
        for status in statuses:
            expected += len(others)
            skipped += len(others - set(status.neighbours))
    assert 0.035 < skipped / expected < 0.25, skipped / expected


def test_garbage_on_the_consensus_keys_is_dropped_and_counted(tmp_path: Path) -> None:
    scenario = _scenario(tmp_path)
    base = free_port_block(9)
    with (
        observer() as obs,
        sim_process(
            tmp_path, "--scenario", str(scenario), "--gcs", "none", "--quiet", base_port=base
        ),
        agent_process(
            tmp_path, "0-8", base, obs.zenoh_args, "--scenario", str(scenario), "--no-arm"
        ) as p,
    ):
        assert obs.wait_until(lambda: _all_within(obs, list(range(9)), TRUTH), 30.0)
        keys = SwarmKeys.for_range(SWARM, 10.0)
        cell = keys.cell((3.0, 2.0, 0.0))
        msg = ConsensusMessage(
            sender=3, round=10**6, gamma=np.full(18, 1e3), edge_sums={}, heard=frozenset(), degree=0
        )
        valid = encode_consensus(msg, (3.0, 2.0, 0.0), SWARM)
        wrong_version = valid[:1] + bytes([99]) + valid[2:]
        not_a_number = valid[:-8] + struct.pack("<d", float("nan"))
        other_swarm = encode_consensus(msg, (3.0, 2.0, 0.0), "another")
        garbage = [os.urandom(n) for n in (1, 7, 64, 500, 3000)]
        garbage += [wrong_version, not_a_number, other_swarm, valid[:-3]]
        pub = obs.bus.publisher(keys.consensus(cell, 3), Congestion.BLOCK)
        for _ in range(20):
            for payload in garbage:
                pub.put(payload)
            time.sleep(0.05)
        time.sleep(1.0)
        assert p.proc.poll() is None
        time.sleep(0.5)
        statuses = obs.statuses()
        assert sum(s.counters.rx_dropped_malformed for s in statuses.values()) > 0
        assert sum(s.counters.rx_dropped_wrong_version for s in statuses.values()) > 0
        assert sum(s.counters.rx_dropped_wrong_swarm for s in statuses.values()) > 0
        assert _all_within(obs, list(range(9)), TRUTH)


def test_agents_started_one_by_one_converge_the_same(tmp_path: Path) -> None:
    # neither by index nor by position: corners, centre, edges, back and forth
    order = [8, 0, 4, 2, 6, 1, 7, 3, 5]
    scenario = _scenario(tmp_path)
    base = free_port_block(9)
    with (
        observer() as obs,
        sim_process(
            tmp_path, "--scenario", str(scenario), "--gcs", "none", "--quiet", base_port=base
        ),
        contextlib.ExitStack() as stack,
    ):
        for d in order:
            stack.enter_context(
                agent_process(
                    tmp_path, str(d), base, obs.zenoh_args, "--scenario", str(scenario), "--no-arm"
                )
            )
            time.sleep(0.7)
        assert obs.wait_until(lambda: _all_within(obs, list(range(9)), TRUTH), 25.0)


def test_hosted_in_three_processes_gives_the_same_estimates(tmp_path: Path) -> None:
    scenario = _scenario(tmp_path)
    base = free_port_block(9)
    with (
        observer() as obs,
        sim_process(
            tmp_path, "--scenario", str(scenario), "--gcs", "none", "--quiet", base_port=base
        ),
        contextlib.ExitStack() as stack,
    ):
        for ids in ("0-2", "3-5", "6-8"):
            stack.enter_context(
                agent_process(
                    tmp_path, ids, base, obs.zenoh_args, "--scenario", str(scenario), "--no-arm"
                )
            )
        assert obs.wait_until(lambda: _all_within(obs, list(range(9)), TRUTH), 25.0)

        def settled() -> bool:
            estimates = np.array([np.asarray(s.estimate) for s in obs.statuses().values()])
            return bool(np.abs(estimates[:, [0, 1, 6, 7]] - TRUTH[[0, 1, 6, 7]]).max() < 0.01)

        # hosted or not, every agent settles on the same (true) descriptors
        assert obs.wait_until(settled, 10.0)


def test_agents_with_mavlink_signing(tmp_path: Path) -> None:
    """The simulator and the agents share a signing key: the agents hear their vehicles (signed
    telemetry) and their signed setpoints are accepted: lockstep time advances."""
    key = tmp_path / "key.hex"
    key.write_text(os.urandom(32).hex())
    positions = GRID[:4]
    scenario = write_scenario(
        tmp_path / "signed.toml", positions, centre=(1.5, 1.0, 0.0), spread=(1.5, 1.0, 0.0)
    )
    truth = truth_of(positions)
    base = free_port_block(4)
    with (
        observer() as obs,
        sim_process(
            tmp_path,
            "--scenario",
            str(scenario),
            "--gcs",
            "none",
            "--signing-key",
            str(key),
            "--clock",
            "lockstep",
            "--wait-agents",
            "4",
            "--quiet",
            base_port=base,
        ),
        agent_process(
            tmp_path,
            "0-3",
            base,
            obs.zenoh_args,
            "--scenario",
            str(scenario),
            "--no-arm",
            "--signing-key",
            str(key),
        ),
    ):
        assert obs.wait_until(lambda: _all_within(obs, [0, 1, 2, 3], truth), 25.0)
        # lockstep time only advances on accepted (signed) setpoint echoes
        assert obs.wait_until(lambda: min(s.t_s for s in obs.statuses().values()) > 2.0, 20.0)

"""Overload is visible (realtime): an agent that answers its vehicle's ticks late is measured by
the simulator (sitl_sim/vehicle/tick_answers.py): its share of ticks answered in time and its lag go
to the GCS as NAMED_VALUE_FLOAT, an "Agent late" STATUSTEXT warns on its links, and the status line
says OVERLOAD and what to do; an agent that keeps up is not blamed."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from tests.sitl_client import HOST, MavPeer, Pilot, fly, free_udp_port, sim_process

pytestmark = pytest.mark.timeout(90)


class LatePilot(Pilot):
    """Answers only every other tick, with the stamp of the tick before: always one tick late."""

    def _answer(self, lpn: Any) -> None:
        ms = int(lpn.time_boot_ms)
        if (ms // 20) % 2 == 1:
            self.peer.setpoint(self.sysid, ms - 20, 0.0, (1.0, 0.0, 0.0, 0.0))


def test_a_late_agent_is_measured_reported_and_the_status_line_says_overload(
    tmp_path: Path,
) -> None:
    gcs = MavPeer(255, 190, bind_port=free_udp_port())
    args = ("--drones", "2", "--clock", "realtime", "--gcs", f"udp:{HOST}:{gcs.port}")
    with gcs, sim_process(tmp_path, *args) as sim:
        gcs.wait_for("HEARTBEAT", 20.0)
        prompt = MavPeer(1, 191, remote=(HOST, sim.base_port))
        late = MavPeer(2, 191, remote=(HOST, sim.base_port + 1))
        with prompt, late:
            pilots = [Pilot(prompt, 1), LatePilot(late, 2)]
            seen: list[Any] = []
            fly(pilots, lambda: len(pilots[0].samples) > 250, 60.0,
                meanwhile=lambda: seen.extend(gcs.poll(0.0)))  # fmt: skip
        seen += gcs.collect(1.2)
        status = sim.stdout()
    values: dict[tuple[int, str], list[float]] = {}
    for m in seen:
        if m.get_type() == "NAMED_VALUE_FLOAT":
            name = m.name if isinstance(m.name, str) else m.name.decode()
            values.setdefault((m.get_srcSystem(), name.rstrip("\0")), []).append(float(m.value))
    # the prompt agent: (nearly) every tick in time; the late one: none, a tick behind
    assert min(values[(1, "agt_intime")][1:]) > 0.8, values
    assert max(values[(2, "agt_intime")][1:]) < 0.1, values
    assert min(values[(2, "agt_lag_ms")][1:]) >= 20.0, values
    texts = [(m.get_srcSystem(), str(m.text)) for m in seen if m.get_type() == "STATUSTEXT"]
    late_texts = [s for s, text in texts if text.startswith("Agent late")]
    assert late_texts and set(late_texts) == {2}, texts
    assert "agents in time" in status and "OVERLOAD" in status, status[-1500:]
    assert "--clock lockstep" in status

"""A restarted ground station's clock: what it hears before any timed telemetry is stamped where
its clock left off, not at 0."""

from __future__ import annotations

import json
import socket
import time
from pathlib import Path

from pymavlink.dialects.v20 import common

from gcs.station.ground_station import GcsOptions, GroundStation
from protocols.bus.zenoh_bus import ZenohSettings
from protocols.scenario.scenario_file import load_scenario

ROOT = Path(__file__).resolve().parents[1]


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def test_a_restarted_station_stamps_an_untimed_text_at_its_clock_not_at_zero(
    tmp_path: Path,
) -> None:
    """The gcs-restart drill: the station restarted at 68.32 s heard a vehicle's STATUSTEXT
    ("Failsafe: landed, disarmed") before any timed message and recorded it at t = 0.0, after
    events at 68.32 s (the drill's events went back in time; seen in make test)."""
    report = tmp_path / "report"
    report.mkdir()
    last = {"t_s": 68.32, "kind": "gcs_restarted", "scenario": "paper", "end_s": 200.0}
    (report / "events.jsonl").write_text(json.dumps(last) + "\n")
    port = _free_udp_port()
    options = GcsOptions(
        scenario=load_scenario(ROOT / "scenarios" / "paper.toml"),
        report_dir=report,
        zenoh=ZenohSettings(),
        gcs_port=port,
        resume=True,
        plots=False,
    )
    with (
        GroundStation(options) as station,  # waits for the swarm's plan (none here: ~10 s)
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as vehicle,
    ):
        codec = common.MAVLink(None, srcSystem=7, srcComponent=1)
        msg = codec.statustext_encode(common.MAV_SEVERITY_NOTICE, b"Failsafe: landed, disarmed")
        vehicle.sendto(msg.pack(codec), ("127.0.0.1", port))
        texts = []
        deadline = time.monotonic() + 5.0
        while not texts and time.monotonic() < deadline:
            texts = station.telemetry.poll()
            time.sleep(0.01)
    assert [(t.t_s, t.drone, t.text) for t in texts] == [(68.32, 6, "Failsafe: landed, disarmed")]

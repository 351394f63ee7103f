"""The formation's orientation tracks the plan, judged from flight.tlog alone
(tests/orientation_judge.py), in ``swarm simulate`` and, for the tilt, distributed (``swarm up``:
real child processes, UDP MAVLink, Zenoh), with bars at 2x the figures docs/measured.md quotes:

- scenarios/tilt9.toml: 9 drones (3 x 3 grid, radio range 10 m) climb to 6 m and tilt their
  planar formation to roll 10 deg, pitch 15 deg, heading 30 deg between t = 10 and 25 s: the
  plane normal and the length axis within 0.2 deg of the command during the tilt and 0.02 deg
  from 5 s after it ends (measured 0.10 and 0.010 deg);
- scenarios/turn45_16.toml: 16 drones (radio range 6 m) turn 45 deg while their length spread
  stretches 15 % in 12 s: the heading lags by at most 0.6 deg at any time and 0.12 deg once the
  plan holds (measured 0.28 and 0.063 deg);
- the paper flight's per-drone tilt bar (25 deg) holds through the take-off with the new gains,
  and the summary and metrics.json report heading, pitch and roll errors."""

from __future__ import annotations

import json
import socket
import subprocess
from pathlib import Path

import pytest
from orientation_judge import orientation_track
from sitl_client import ENV, ROOT, free_port_block, free_udp_port, swarm_command

pytestmark = pytest.mark.slow

TILT = ROOT / "scenarios" / "tilt9.toml"
TURN = ROOT / "scenarios" / "turn45_16.toml"
TILT_END_S = 25.0  # the tilt command ends
TURN_START_S, TURN_END_S = 11.5, 23.5
#: the distributed tilt flight stops here (the bar needs 5 s after the command and a little more)
UP_TILT_S = 33.0
#: the turn is judged to here
TURN_JUDGED_TO_S = 29.5


def _simulate(scenario: Path, out: Path) -> str:
    done = subprocess.run(
        swarm_command(
            "simulate", str(scenario), "--report", str(out), "--no-plots", "--no-recording"
        ),
        capture_output=True,
        text=True,
        env=ENV,
        cwd=ROOT,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout


def _free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _up(scenario: Path, out: Path, n: int, *extra: str) -> str:
    # a Zenoh router of this run's own on a free port: swarm up's default rendezvous takes the
    # default port when it is free, where another swarm on this machine may meet ours
    done = subprocess.run(
        swarm_command(
            "up",
            str(scenario),
            "--report",
            str(out),
            "--no-plots",
            "--no-recording",
            "--base-port",
            str(free_port_block(n)),
            "--gcs-port",
            str(free_udp_port()),
            "--agents-per-process",
            "4",
            "--router",
            f"tcp/127.0.0.1:{_free_tcp_port()}",
            "--only",
            "router,gcs,sim,agents",
            *extra,
        ),
        capture_output=True,
        text=True,
        env=ENV,
        cwd=ROOT,
        timeout=900,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout


@pytest.fixture(scope="module")
def flights(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, str]]:
    """The three flights: (report folder, printed summary) by name. The turn flies in
    ``swarm simulate`` only: the tilt shows the distributed runner on an orientation plan (a
    heading too), and a lockstep ``swarm up`` flies ``swarm simulate``'s flight bit for bit
    (tests/test_lockstep_repeats.py)."""
    root = tmp_path_factory.mktemp("orientation")
    return {
        "simulate tilt": (root / "st", _simulate(TILT, root / "st")),
        "simulate turn": (root / "su", _simulate(TURN, root / "su")),
        "up tilt": (root / "ut", _up(TILT, root / "ut", 9, "--duration-s", str(UP_TILT_S))),
    }


@pytest.mark.parametrize("how", ["simulate", "up"])
def test_a_tilted_planar_formation_follows_the_tilt_and_is_on_it_5_s_after(
    flights: dict[str, tuple[Path, str]], how: str
) -> None:
    report, _ = flights[f"{how} tilt"]
    end = UP_TILT_S if how == "up" else None
    track = orientation_track(report, TILT, end_s=end)
    normal, length, _ = track.worst(TILT_END_S + 5.0)
    assert normal <= 0.02 and length <= 0.02, (normal, length)
    # and on the way: the formation follows the tilt, it does not wait for it to end
    normal, length, _ = track.worst(10.0, TILT_END_S)
    assert normal <= 0.2 and length <= 0.2, (normal, length)


def test_a_heading_turn_with_a_stretch_lags_a_fraction_of_a_degree(
    flights: dict[str, tuple[Path, str]],
) -> None:
    report, _ = flights["simulate turn"]
    track = orientation_track(report, TURN, end_s=TURN_JUDGED_TO_S)
    _, _, anytime = track.worst(TURN_START_S)
    _, _, holding = track.worst(TURN_END_S)
    assert anytime <= 0.6 and holding <= 0.12, (anytime, holding)


@pytest.mark.parametrize("name", ["simulate tilt", "up tilt"])
def test_the_summary_and_metrics_report_orientation_errors(
    flights: dict[str, tuple[Path, str]], name: str
) -> None:
    report, printed = flights[name]
    metrics = json.loads((report / "metrics.json").read_text())
    for angle in ("heading", "pitch", "roll"):
        assert f"{angle} tracking, steady" in printed and f"{angle} tracking, all" in printed
        for block in ("tracking", "tracking_steady"):
            stat = metrics[block][f"{angle}_deg"]
            assert stat["rms"] is not None and 0.0 <= stat["rms"] <= stat["max"] < 1.0, stat
    assert metrics["max_tilt_deg"]["value"] <= 25.0, metrics["max_tilt_deg"]
    assert metrics["collisions"]["count"] == 0

"""The ``swarm`` command's handling of user mistakes: one line, exit code 2, no traceback."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "MAVLINK20": "1", "MPLBACKEND": "Agg"}


def _swarm(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "gcs.cli", *args],
        capture_output=True,
        text=True,
        env=ENV,
        cwd=ROOT,
        timeout=120,
    )


@pytest.mark.parametrize(
    "content,needle",
    [
        (None, "no such file"),
        ("version = 1\n[[drones]\n", "line"),
        ("version = 7\n", "version"),
        ("version = 1\n[[drones]]\nposition_ned_m = [0, 0, 0]\n", "drones"),
    ],
    ids=["missing", "broken-toml", "bad-version", "one-drone"],
)
def test_bad_scenario_is_one_line_and_exit_2(
    tmp_path: Path, content: str | None, needle: str
) -> None:
    path = tmp_path / "s.toml"
    if content is not None:
        path.write_text(content)
    proc = _swarm("simulate", str(path), "--report", str(tmp_path / "r"))
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("swarm: error: ") and needle in lines[0]
    assert "Traceback" not in proc.stderr


def test_bad_flag_values_are_refused(tmp_path: Path) -> None:
    proc = _swarm(
        "simulate", "scenarios/paper.toml", "--duration-s", "-3", "--report", str(tmp_path)
    )
    assert proc.returncode == 2 and "--duration-s" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_unwritable_report_folder(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("")
    proc = _swarm(
        "simulate", "scenarios/paper.toml", "--report", str(blocker / "sub"), "--duration-s", "1"
    )
    assert proc.returncode == 2 and "report folder" in proc.stderr


def test_short_flight_writes_a_report(tmp_path: Path) -> None:
    """Without plots and recording: the four logs, no PNG, and no flight.rrd, not even an
    earlier flight's left in the folder (swarm replay would open it as this one's)."""
    (tmp_path / "flight.rrd").write_bytes(b"RRF2 an earlier flight")
    proc = _swarm(
        "simulate",
        "scenarios/paper.toml",
        "--report",
        str(tmp_path),
        "--duration-s",
        "5",
        "--no-plots",
        "--no-recording",
        "--progress",
        "off",
    )
    assert proc.returncode == 0, proc.stderr
    for name in ("flight.tlog", "events.jsonl", "metrics.json", "trajectory.json"):
        assert (tmp_path / name).stat().st_size > 0
    assert not (tmp_path / "flight.rrd").exists() and not list(tmp_path.glob("*.png"))
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["startup_s"] > 0 and metrics["wall_time_s"] > 0  # the process's start-up


def test_help_explains_units() -> None:
    proc = _swarm("simulate", "--help")
    assert proc.returncode == 0 and "report" in proc.stdout


#: What a process of one subcommand imports only when that subcommand runs: every ``swarm``
#: process builds every subcommand's parser, and a lockstep flight starts a dozen of them.
MACHINERY = (
    "numpy", "numba", "zenoh", "pymavlink", "matplotlib", "rerun", "drone_agent.core.agent_core",
    "drone_agent.process.host", "drone_agent.process.hosted_agent",
    "drone_agent.process.vehicle_link", "protocols.bus.zenoh_bus", "gcs.station", "gcs.report",
    "gcs.reference", "gcs.cli.session", "protocols.scenario.scenario_file",
    "protocols.scenario.generator", "protocols.scenario.layout", "sitl_sim.server",
    "sitl_sim.sim_config", "sitl_sim.vehicle.world",
)  # fmt: skip


def test_a_flight_without_plots_or_recording_loads_neither_library() -> None:
    """``swarm simulate --no-plots --no-recording`` starts without matplotlib (~0.3 s) and Rerun
    (~0.6 s with pyarrow and pandas): the in-process runner imports them only to use them."""
    code = (
        "import json, sys\n"
        "import gcs.reference.simulate, gcs.cli.main\n"
        "heavy = ('matplotlib', 'rerun', 'pandas')\n"
        "print(json.dumps(sorted(m for m in heavy if m in sys.modules)))"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=60
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == []


def test_building_the_parsers_imports_no_machinery() -> None:
    """Every help text of ``swarm`` (the parsers of all subcommands, as ``swarm X --help``
    builds them) in a fresh process: none of the subcommands' machinery is imported."""
    code = (
        "import argparse, json, sys\n"
        "from gcs.cli.main import _parser\n"
        "def helps(p):\n"
        "    yield p.format_help()\n"
        "    for a in p._actions:\n"
        "        if isinstance(a, argparse._SubParsersAction):\n"
        "            for sub in a.choices.values():\n"
        "                yield from helps(sub)\n"
        "texts = list(helps(_parser()))\n"
        f"machinery = {MACHINERY!r}\n"
        "loaded = sorted(m for m in sys.modules\n"
        "                if any(m == h or m.startswith(h + '.') for h in machinery))\n"
        "print(json.dumps({'helps': len(texts), 'loaded': loaded}))\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=60
    )
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["helps"] > 30  # every subcommand's, and the drills', keys' and scenario's own
    assert out["loaded"] == []

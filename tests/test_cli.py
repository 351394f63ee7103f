"""The ``swarm`` command's handling of user mistakes: one line, exit code 2, no traceback."""

from __future__ import annotations

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
    proc = _swarm(
        "simulate",
        "scenarios/paper.toml",
        "--report",
        str(tmp_path),
        "--duration-s",
        "5",
        "--no-plots",
        "--progress",
        "off",
    )
    assert proc.returncode == 0, proc.stderr
    for name in ("flight.tlog", "events.jsonl", "metrics.json", "trajectory.json"):
        assert (tmp_path / name).stat().st_size > 0


def test_help_explains_units() -> None:
    proc = _swarm("simulate", "--help")
    assert proc.returncode == 0 and "report" in proc.stdout

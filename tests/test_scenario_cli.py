"""``swarm scenario new`` and ``swarm scenario check`` as a user types them: mistakes are one
line naming the field or option with exit code 2 (never a traceback), ``check`` sums a scenario
up, and what ``new`` writes (and the small library scenarios) fly in ``swarm simulate``, judged
from the report's flight.tlog: every drone airborne at the plan's altitude, none lost, none
closer than 1.5 m to another, the swarm's centre where the plan says."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from paper_flight import min_airborne_separation

from gcs.report.tlog import read_tlog
from protocols.scenario.scenario_file import load_scenario

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "MAVLINK20": "1", "MPLBACKEND": "Agg"}
TLOG_GRID_HZ = 25.0


def _swarm(*args: str, cwd: Path = ROOT, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "gcs.cli", *args],
        capture_output=True,
        text=True,
        env={**ENV, "PYTHONPATH": str(ROOT)},
        cwd=cwd,
        timeout=timeout,
    )


def _one_line_error(proc: subprocess.CompletedProcess[str]) -> str:
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("swarm: error: ")
    return lines[0]


# --- check -------------------------------------------------------------------------------------


GOOD = """version = 1
duration_s = 20.0
[[drones]]
position_ned_m = [0.0, 0.0, 0.0]
[[drones]]
position_ned_m = [3.0, 0.0, 0.0]
[[trajectory.waypoints]]
t_s = 0.0
centre_ned_m = [1.5, 0.0, 0.0]
spread_m = [1.5, 0.0, 0.0]
"""


@pytest.mark.parametrize(
    ("content", "needles"),
    [
        (None, ["no such file"]),
        ("version = 1\n[[drones]\n", ["invalid TOML", "line 2"]),
        (GOOD.replace("duration_s = 20.0", "duration_s = -1"), ["duration_s", "> 0"]),
        (GOOD.replace("[3.0, 0.0, 0.0]", "[0.2, 0.0, 0.0]"), ["drones[1].position_ned_m"]),
        (GOOD + "[comms]\nrange = 5\n", ["comms.range", "did you mean 'range_m'"]),
        (GOOD + '[[faults]]\nt_s = 5.0\nkind = "crash"\ndrone = 7\n', ["faults[0].drone"]),
        (
            GOOD.replace("spread_m = [1.5, 0.0, 0.0]", "spread_m = [0.3, 0.0, 0.0]"),
            ["trajectory.waypoints[0]", "cannot hold 2 drones 1 m apart"],
        ),
        (
            GOOD.replace("[1.5, 0.0, 0.0]\nspread", "[1.5, 0.0, -90.0]\nspread"),
            ["trajectory.waypoints", "geofence", "altitude 90.0 m"],
        ),
    ],
    ids=[
        "missing",
        "broken-toml",
        "bad-duration",
        "too-close",
        "typo",
        "bad-drone",
        "too-tight",
        "fence",
    ],
)
def test_check_names_the_field_and_exits_2(
    tmp_path: Path, content: str | None, needles: list[str]
) -> None:
    path = tmp_path / "s.toml"
    if content is not None:
        path.write_text(content)
    line = _one_line_error(_swarm("scenario", "check", str(path)))
    for needle in needles:
        assert needle in line, line


def test_check_a_directory_or_binary_file_is_one_line(tmp_path: Path) -> None:
    assert "cannot read" in _one_line_error(_swarm("scenario", "check", str(tmp_path)))
    blob = tmp_path / "b.toml"
    blob.write_bytes(b"\xff\xfe\x00junk")
    assert "not UTF-8" in _one_line_error(_swarm("scenario", "check", str(blob)))


def test_check_sums_a_scenario_up() -> None:
    proc = _swarm("scenario", "check", "scenarios/large_grid25.toml")
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert "valid (version 1)" in out
    assert "drones     25; closest two on the ground 2.50 m apart" in out
    assert "duration   45 s" in out
    assert "range 6 m: connected at the start; neighbours per drone min 7 / mean 12.0 / max 20" in (
        out
    )
    assert "agent drop-out, drone" in out and "vehicle crash, drone" in out
    assert "20% loss on every link" in out
    assert "waypoints  6, t = 0..45 s" in out
    assert "keep the drones at least 2.50 m apart" in out
    assert "the plan stays inside the ground station's geofence" in out


def test_check_says_when_the_radio_graph_is_split(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text(GOOD + "[comms]\nrange_m = 2.0\n")
    proc = _swarm("scenario", "check", str(path))
    assert proc.returncode == 0, proc.stderr
    assert "NOT connected: 2 parts" in proc.stdout


# --- new ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--drones", "1"], "--drones: need 2..250"),
        (["--drones", "300"], "--drones: need 2..250"),
        (["--drones", "9", "--range-m", "2"], "--range-m: at 2 m the radio graph"),
        (["--drones", "9", "--spacing-m", "0.5"], "--spacing-m: 0.5 m is below"),
        (["--drones", "9", "--faults", "meteor"], "--faults: 'meteor' is not a fault kind"),
        (["--drones", "9", "--duration-s", "10"], "--duration-s: the turn-and-stretch"),
        (["--drones", "25", "--layout", "line"], "spread 18.0 m exceeds the limit of 15 m"),
    ],
)
def test_new_refuses_what_it_cannot_make(tmp_path: Path, args: list[str], needle: str) -> None:
    out = tmp_path / "s.toml"
    line = _one_line_error(_swarm("scenario", "new", *args, "-o", str(out)))
    assert needle in line, line
    assert not out.exists()


def test_new_does_not_overwrite_without_force(tmp_path: Path) -> None:
    out = tmp_path / "s.toml"
    out.write_text("mine")
    assert "--force" in _one_line_error(_swarm("scenario", "new", "--drones", "4", "-o", str(out)))
    assert out.read_text() == "mine"
    proc = _swarm("scenario", "new", "--drones", "4", "-o", str(out), "--force")
    assert proc.returncode == 0, proc.stderr
    assert load_scenario(out).n_drones == 4


def test_new_without_a_file_prints_the_toml() -> None:
    proc = _swarm("scenario", "new", "--drones", "6", "--layout", "circle", "--template", "hover")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("# hover-circle6: 6 drones, circle layout")
    assert proc.stdout.count("[[drones]]") == 6


def test_the_header_command_makes_the_same_file_again(tmp_path: Path) -> None:
    args = ["--drones", "20", "--layout", "random", "--faults", "dropout,loss=0.1", "--seed", "3"]
    proc = _swarm("scenario", "new", *args, "--template", "survey", "-o", "a.toml", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("wrote a.toml\na.toml: valid (version 1)")
    text = (tmp_path / "a.toml").read_text()
    command = text.splitlines()[2].removeprefix("#   ").split()
    assert command[:3] == ["swarm", "scenario", "new"] and command[-2:] == ["-o", "a.toml"]
    (tmp_path / "a.toml").unlink()
    assert _swarm(*command[1:], cwd=tmp_path).returncode == 0
    assert (tmp_path / "a.toml").read_text() == text


def test_help_explains_templates_layouts_and_faults() -> None:
    proc = _swarm("scenario", "new", "--help")
    assert proc.returncode == 0
    text = " ".join(proc.stdout.split())
    for needle in ("grid (rows along east)", "lawnmower", "30 deg turn", "dropout[=K]", "loss[=P]",
                   "radio range, m", "min_separation_m"):  # fmt: skip
        assert needle in text, needle
    check = _swarm("scenario", "check", "--help")
    assert "connected" in check.stdout and "exit code 2" in " ".join(check.stdout.split())


# --- flights -----------------------------------------------------------------------------------


def _fly(scenario: Path, report: Path, duration_s: float) -> None:
    proc = _swarm(
        "simulate", str(scenario), "--duration-s", str(duration_s), "--report", str(report),
        "--no-plots", "--no-recording", "--progress", "off", timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr


def _check_flight(scenario_path: Path, report: Path, duration_s: float) -> None:
    """From flight.tlog alone, from 2 s after the climb: every drone sends telemetry and flies
    within 0.25 m of the plan's altitude (none lost or fallen), the swarm's centre within 0.1 m
    of the plan's; over the whole flight no two airborne drones closer than 1.5 m (issue 10's
    bar). Measured: altitude 0.5 mm, centre 1.4 cm (during the move), separation 2.47 m
    (grid16_turn); a staggered 12-drone line on a 6 m range fails it (1.26 m)."""
    sc = load_scenario(scenario_path)
    t = np.arange(0.0, duration_s + 1e-9, 1.0 / TLOG_GRID_HZ)
    x = read_tlog(report / "flight.tlog").resample(t, sc.n_drones)
    plan = sc.trajectory().evaluate_many(t)[0]
    up = sc.waypoints[2].t_s  # the climb's end: the generator's third waypoint
    flying = t >= up + 2.0
    altitude = -x[flying, :, 2]
    assert np.all(np.isfinite(altitude)), "a vehicle went silent"
    altitude_error = np.abs(altitude + plan[flying, 2][:, None])
    assert altitude_error.max() < 0.25, altitude_error.max()
    assert min_airborne_separation(x) > 1.5
    centre_error = np.linalg.norm(x[flying].mean(axis=1) - plan[flying, :3], axis=1)
    assert centre_error.max() < 0.1, centre_error.max()


@pytest.mark.slow
def test_a_new_25_drone_grid_flies(tmp_path: Path) -> None:
    out = tmp_path / "grid25.toml"
    proc = _swarm("scenario", "new", "--drones", "25", "--layout", "grid", "-o", str(out))
    assert proc.returncode == 0, proc.stderr
    _fly(out, tmp_path / "report", 20.0)
    _check_flight(out, tmp_path / "report", 20.0)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "duration_s"), [("grid16_turn", 25.0), ("survey25", 20.0), ("ring12", 25.0)]
)
def test_a_library_scenario_flies(tmp_path: Path, name: str, duration_s: float) -> None:
    path = ROOT / "scenarios" / f"{name}.toml"
    _fly(path, tmp_path, duration_s)
    _check_flight(path, tmp_path, duration_s)

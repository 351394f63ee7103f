"""``swarm up --ardupilot-bin`` and the dialect flags refuse what cannot fly, in one line, before
anything starts (no ArduPilot binary needed: a stand-in executable file where one is named), and
the instances ``swarm up`` would start are placed where the scenario puts the drones."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gcs.cli.ardupilot_sitl import GCS_STREAM_PARAMS, homes, vehicle_children
from protocols.model.geodesy import geodetic_to_ned
from protocols.scenario.scenario_file import load_scenario

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "scenarios" / "ardupilot4.toml"


def _up(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "gcs.cli", "up", str(SCENARIO), *args],
        cwd=ROOT, env={**os.environ, **(env or {})}, capture_output=True, text=True, timeout=60,
    )  # fmt: skip


@pytest.fixture(scope="module")
def fake_binary(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("ap") / "arducopter"
    path.write_text("#!/bin/sh\nexit 1\n")
    path.chmod(0o755)
    return path


@pytest.mark.parametrize(
    ("flags", "said"),
    [
        (["--ardupilot-bin", "/nonexistent/arducopter"], "no executable file there"),
        (["--clock", "lockstep"], "real time only"),
        (["--speedup", "5"], "--speedup 1 only"),
        (["--dialect", "ardupilot"], "ArduCopter speaks its own"),
        (["--ardupilot-defaults", "/nonexistent.parm"], "no such parameter file"),
        (["--router", "tcp/127.0.0.1:7447"], "one host"),
    ],
)
def test_what_ardupilot_sitl_cannot_do_is_refused_in_one_line(
    fake_binary: Path, tmp_path: Path, flags: list[str], said: str
) -> None:
    binary = [] if "--ardupilot-bin" in flags else ["--ardupilot-bin", str(fake_binary)]
    done = _up(*binary, *flags, "--report", str(tmp_path / "r"))
    assert done.returncode != 0
    assert said in done.stderr and "Traceback" not in done.stderr, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1


def test_the_environment_variable_names_the_binary_and_the_flags_are_checked(
    fake_binary: Path, tmp_path: Path
) -> None:
    done = _up("--clock", "lockstep", "--report", str(tmp_path / "r"),
               env={"ARDUPILOT_SITL": str(fake_binary)})  # fmt: skip
    assert done.returncode != 0 and "real time only" in done.stderr
    done = _up("--ardupilot-defaults", str(SCENARIO), "--report", str(tmp_path / "r"))
    assert done.returncode != 0 and "goes with --ardupilot-bin" in done.stderr


def test_each_instance_starts_where_the_scenario_puts_its_drone(
    fake_binary: Path, tmp_path: Path
) -> None:
    scenario = load_scenario(SCENARIO)
    children = vehicle_children(fake_binary, scenario, [14540, 14541, 14542, 14543], 14550,
                                tmp_path, None)  # fmt: skip
    places = homes(scenario)
    for i, child in enumerate(children):
        argv = child.argv
        assert argv[argv.index("--sysid") + 1] == str(i + 1)
        assert argv[argv.index("-I") + 1] == str(i)
        assert argv[argv.index("--serial0") + 1] == f"udpclient:127.0.0.1:{14540 + i}"
        assert argv[argv.index("--serial1") + 1] == "udpclient:127.0.0.1:14550"
        lat, lon, alt, yaw = (float(v) for v in argv[argv.index("--home") + 1].split(","))
        assert (lat, lon, alt, yaw) == pytest.approx(places[i], abs=1e-9)
        ned = geodetic_to_ned(scenario.home, lat, lon, alt)[0]
        assert np.allclose(ned, scenario.positions_ned_m()[i], atol=1e-3)  # the layout holds
        assert child.cwd == tmp_path / f"ardupilot-{i}"
        params = (child.cwd / "quadswarm.parm").read_text().split("\n")
        assert "MAV2_POSITION 25" in params and "SR1_POSITION 25" in params
        assert len([p for p in params if p]) == len(GCS_STREAM_PARAMS)


@pytest.mark.parametrize(
    "role", [["agent", "--drone-id", "0"], ["gcs", "--scenario", str(SCENARIO)]]
)
def test_a_swarm_epoch_that_is_no_unix_time_is_refused(role: list[str]) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "gcs.cli", *role, "--swarm-epoch", "nan"],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 2 and "must be a Unix time in seconds" in done.stderr, done.stderr

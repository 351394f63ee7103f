"""``swarm sweep`` (gcs/reference/sweep.py, gcs/cli/sweep.py, gcs/report/sweep_report.py): the
grid of flights, the factors' changes to the scenario, where each bar first breaks, and the plain
command end to end: two flights of the tilt scenario, still air and a 3 m/s wind, in parallel,
judged from their own flight.tlog."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from sitl_client import ENV, ROOT, swarm_command

from gcs.reference.sweep import (
    BARS,
    DRAG_XY,
    SweepError,
    breaks,
    grid,
    parse_vary,
)
from gcs.report.tlog import vehicle_samples
from protocols.faults import Loss
from protocols.scenario.scenario_file import load_scenario

TILT9 = ROOT / "scenarios" / "tilt9.toml"


@pytest.mark.parametrize(
    ("flags", "words"),
    [
        ([], "at least one --vary"),
        (["gusts=1,2"], "unknown factor 'gusts' (known: wind_m_s, wind_from_deg"),
        (["wind_m_s"], "expected NAME=V1,V2"),
        (["wind_m_s=1,strong"], "must be numbers"),
        (["wind_m_s=1,45"], "45 is outside 0..30 m/s"),
        (["loss=0.2", "loss=0.3"], "given twice"),
    ],
)
def test_a_wrong_vary_says_what_is_wrong(flags: list[str], words: str) -> None:
    with pytest.raises(SweepError, match="") as err:
        parse_vary(flags)
    assert words in str(err.value), str(err.value)


def test_the_help_lists_every_factor() -> None:
    from gcs.cli.sweep import EPILOG
    from gcs.reference.sweep import FACTORS

    listed = [line.split()[0] for line in EPILOG.split("factors (--vary")[1].splitlines()[1:]
              if line.startswith("  ") and not line.startswith("   ")]  # fmt: skip
    assert listed == list(FACTORS)


def test_the_grid_and_what_each_factor_changes() -> None:
    vary = parse_vary(["wind_m_s=0,3", "loss=0,0.2", "turbulence_m_s=0.5"])
    runs = grid(vary, seeds=2, first_seed=7)
    assert len(runs) == 2 * 2 * 1 * 2 and {r.seed for r in runs} == {7, 8}
    assert len({r.name for r in runs}) == len(runs)
    base = load_scenario(TILT9)
    windy = next(r for r in runs if dict(r.values) == {"wind_m_s": 3.0, "loss": 0.2,
                                                       "turbulence_m_s": 0.5})  # fmt: skip
    s = windy.scenario(base, duration_s=35.0)
    assert s.environment.wind_ned_m_s == (0.0, 3.0, 0.0)  # a still scenario's wind: from the west
    assert s.environment.turbulence_m_s == 0.5
    assert s.vehicle.drag_xy_per_s == DRAG_XY  # moving air needs drag: a small quadcopter's
    assert s.duration_s == 35.0 and s.seed == windy.seed
    assert [f for f in s.faults if isinstance(f, Loss)] == [Loss(0.2, t_s=0.0)]
    # the direction factor keeps the speed; the speed factor keeps the direction
    both = grid(parse_vary(["wind_m_s=2", "wind_from_deg=0"]), 1, 0)[0].scenario(base, None)
    assert np.allclose(both.environment.wind_ned_m_s, (-2.0, 0.0, 0.0))  # from the north: south


def test_a_bar_breaks_at_the_first_value_that_misses_it_alone() -> None:
    vary = {"wind_m_s": [0.0, 2.0, 4.0], "loss": [0.0, 0.5]}
    good = {"centroid_rms_m": 0.1, "consensus_rms_m": 0.01, "collisions": 0,
            "drones_lost_unplanned": 0,
            "min_separation_m": 2.0}  # fmt: skip
    rows = [
        {"wind_m_s": w, "loss": p, "seed": 0, **good,
         "centroid_rms_m": 0.2 * w + (1.0 if p else 0.0)}
        for w in vary["wind_m_s"] for p in vary["loss"]
    ]  # fmt: skip
    found = breaks(rows, vary)
    # alone (loss 0): the centre misses 0.5 m first at 4 m/s; (loss alone, at wind 0: at 0.5)
    assert found["wind_m_s"]["centroid_rms_m <= 0.5"] == 4.0
    assert found["loss"]["centroid_rms_m <= 0.5"] == 0.5
    assert all(v is None for k, v in found["wind_m_s"].items() if not k.startswith("centroid"))
    assert str(BARS[0]) == "centroid_rms_m <= 0.5"


def test_swarm_sweep_flies_the_grid_and_says_where_the_swarm_stops_holding(tmp_path: Path) -> None:
    """The plain command: ``swarm sweep scenarios/tilt9.toml --vary wind_m_s=0,3 --out sw``
    (default seeds and jobs; the first 35 s of the flight). The windy flight's vehicles are
    pushed downwind in their own telemetry, the still one's are not; the table says the centre
    bar breaks at 3 m/s."""
    done = subprocess.run(
        [*swarm_command("sweep", str(TILT9), "--vary", "wind_m_s=0,3", "--duration-s", "35",
                        "--out", "sw")],
        capture_output=True, text=True, env=ENV, cwd=tmp_path, timeout=900,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    out = tmp_path / "sw"
    data = json.loads((out / "sweep.json").read_text())
    assert [(r["wind_m_s"], r["seed"]) for r in data["rows"]] == [(0.0, 0), (3.0, 0)]
    assert data["breaks"]["wind_m_s"]["centroid_rms_m <= 0.5"] == 3.0
    assert data["breaks"]["wind_m_s"]["collisions <= 0"] is None
    assert "First breaks: centroid_rms_m <= 0.5 at 3." in (out / "sweep.md").read_text()
    assert (out / "sweep_wind_m_s.png").stat().st_size > 10_000
    calm, windy = (data["rows"][k]["centroid_rms_m"] for k in (0, 1))
    assert calm < 0.05 < 0.5 < windy
    plan_east = load_scenario(TILT9).trajectory().evaluate(0.0)[0][1]
    for wind, folder, drift in ((0.0, "wind_m_s=0_seed=0", (-0.05, 0.05)),
                                (3.0, "wind_m_s=3_seed=0", (0.5, 5.0))):  # fmt: skip
        samples = vehicle_samples(out / folder / "flight.tlog")
        east = [v[1] for (msg, _s, t), v in samples.items()
                if msg == "LOCAL_POSITION_NED" and t > 25_000]  # fmt: skip
        assert drift[0] < np.mean(east) - plan_east < drift[1], (wind, np.mean(east))
    # one line for a mistake, nothing flown
    bad = subprocess.run(
        [*swarm_command("sweep", str(TILT9), "--vary", "wind_m_s=0,3", "--duration-s", "10",
                        "--out", "bad")],
        capture_output=True, text=True, env=ENV, cwd=tmp_path, timeout=60,
    )  # fmt: skip
    lines = bad.stderr.strip().splitlines()
    assert (
        bad.returncode == 2 and len(lines) == 1 and "--duration-s must be in (30, 40]" in lines[0]
    )
    assert not (tmp_path / "bad").exists()

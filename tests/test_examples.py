"""The examples in examples/ run as a user runs them: the gain sweep writes its plot after its
lockstep flights (two gains; two of its five default seeds, the flights being alike) with the
numbers it printed, and the pytest example passes under the installed plugin."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from sitl_client import ENV, ROOT

pytestmark = pytest.mark.slow
EXAMPLES = ROOT / "examples"


def test_the_gain_sweep_flies_every_seed_and_plots(tmp_path: Path) -> None:
    out = subprocess.run(
        [sys.executable, str(EXAMPLES / "gain_sweep.py"), "--out", str(tmp_path / "sweep"),
         "--seeds", "3"],
        capture_output=True, text=True, env=ENV, cwd=tmp_path, timeout=900,
    )  # fmt: skip
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    runs = re.findall(r"rho (\S+) seed (\d): shape estimate error (\S+) m² RMS", out.stdout)
    assert sorted((rho, int(seed)) for rho, seed, _ in runs) == sorted(
        (rho, seed) for rho in ("1", "4") for seed in (3,)
    )
    assert all(0 <= float(rms) < 1.0 for _, _, rms in runs)
    # each figure is the one metrics.json holds for its flight
    for rho, seed, rms in runs:
        metrics = json.loads(
            (tmp_path / "sweep" / f"rho{rho}-seed{seed}" / "metrics.json").read_text()
        )
        assert f"{metrics['consensus']['shape_m2']['rms']:.4f}" == rms
    assert (tmp_path / "sweep" / "gain_sweep.png").stat().st_size > 10_000


def test_the_pytest_example_passes_with_the_plugin(tmp_path: Path) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--rootdir", str(tmp_path),
         str(EXAMPLES / "test_swarm_example.py")],
        capture_output=True, text=True, env=ENV, cwd=tmp_path, timeout=600,
    )  # fmt: skip
    assert out.returncode == 0, out.stdout[-3000:]
    assert "1 passed" in out.stdout
